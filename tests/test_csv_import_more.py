"""convert-csv: accelerometer columns with their unit, the truth from a second CSV at its own
stamps, and an output named as the user wrote it (a ``.mcap`` is one file, else a bag folder).
Driven through the command; what it wrote is read back with the log reader and scipy."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import assert_names
from drone_logs import ximu3_convert_argv
from scipy.spatial.transform import Rotation

from imu_dcm.gyro.rest_rule import GRAVITY_M_S2
from imu_dcm.logio import read_log
from imu_dcm.replay.__main__ import main

N = 401  # 4 s at 100 Hz
RATE_DEG_S = 30.0


@pytest.fixture
def csvs(tmp_path):
    """gyro.csv: a 30 °/s spin about z, the accelerometer reading +1 g on z (in g); truth.csv:
    the closed-form attitude (w, x, y, z) at every other stamp only."""
    t_ms = np.arange(N) * 10
    gyro = tmp_path / "gyro.csv"
    lines = ["t_ms,gx,gy,gz,ax,ay,az"]
    lines += [f"{t},0,0,{RATE_DEG_S},0.01,-0.02,1.0" for t in t_ms]
    gyro.write_text("\n".join(lines) + "\n")
    truth = tmp_path / "truth.csv"
    rows = ["stamp,qw,qx,qy,qz"]
    for t in t_ms[::2]:
        x, y, z, w = (
            float(v)
            for v in Rotation.from_euler("z", RATE_DEG_S * t / 1000, degrees=True).as_quat()
        )
        rows.append(f"{t},{w!r},{x!r},{y!r},{z!r}")
    truth.write_text("\n".join(rows) + "\n")
    return gyro, truth


ARGS = ["--time-col", "t_ms", "--time-units", "ms", "--gyro-cols", "gx,gy,gz"]
ARGS += ["--gyro-units", "deg/s"]
ACCEL = ["--accel-cols", "ax,ay,az", "--accel-units", "g"]
TRUTH = ["--truth-cols", "qw,qx,qy,qz", "--truth-order", "wxyz", "--truth-time-col", "stamp"]


def test_a_dot_mcap_output_is_one_file_with_accel_and_a_joined_truth(csvs, tmp_path, capsys):
    gyro, truth = csvs
    out = tmp_path / "out" / "x.mcap"
    argv = ["convert-csv", str(gyro), str(out), *ARGS, *ACCEL, "--truth-csv", str(truth), *TRUTH]
    assert main(argv) == 0
    assert capsys.readouterr().out.strip() == f"wrote {out}"
    assert out.is_file() and sorted(p.name for p in out.parent.iterdir()) == ["x.mcap"]
    log = read_log(out)
    # g converted with the standard gravity, exactly as given
    want = np.tile([0.01, -0.02, 1.0], (N, 1)) * GRAVITY_M_S2
    np.testing.assert_allclose(log.imu.accel_b, want, rtol=1e-15)
    assert len(log.truth.t_ns) == (N + 1) // 2  # every other stamp, at its own stamps
    assert np.array_equal(log.truth.t_ns, log.imu.t_ns[::2])
    s = tmp_path / "s.json"
    assert main([str(out), "--rerun", "off", "--summary-json", str(s)]) == 0
    got = json.loads(s.read_text())
    assert got["bias_segments"] == []  # it spins throughout: no rest
    assert got["rms_error_deg"] < 1e-6  # a constant rate: magnus4 exact, truth exact


def test_a_folder_output_is_a_bag(csvs, tmp_path):
    gyro, _ = csvs
    out = tmp_path / "bag"
    assert main(["convert-csv", str(gyro), str(out), *ARGS, *ACCEL]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["bag.mcap", "metadata.yaml"]
    assert read_log(out).imu.accel_b is not None


@pytest.mark.parametrize(
    ("extra", "facts"),
    [
        (["--accel-cols", "ax,ay,az"], ("--accel-cols", "--accel-units", "'ax,ay,az'")),
        (["--truth-csv", "TRUTH"], ("--truth-cols", "--truth-order", "--truth-csv", "truth.csv")),
        (["--truth-time-col", "stamp"], ("--truth-csv", "--truth-time-col")),
    ],
)
def test_incomplete_options_are_one_line_and_write_nothing(csvs, tmp_path, capsys, extra, facts):
    gyro, truth = csvs
    extra = [str(truth) if x == "TRUTH" else x for x in extra]
    out = tmp_path / "x.mcap"
    assert main(["convert-csv", str(gyro), str(out), *ARGS, *extra]) == 2
    assert_names(capsys.readouterr().err, *facts)
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == [
        "gyro.csv",
        "truth.csv",
    ]


def test_an_existing_mcap_needs_force_and_must_be_ours(csvs, tmp_path, capsys):
    gyro, _ = csvs
    out = tmp_path / "x.mcap"
    out.write_bytes(b"\x89MCAP0\r\nsomeone else's")
    assert main(["convert-csv", str(gyro), str(out), *ARGS]) == 2
    assert main(["convert-csv", str(gyro), str(out), *ARGS, "--force"]) == 2
    err = capsys.readouterr().err
    assert str(out) in err and "not written by imu_dcm" in err  # the file named, and why
    assert out.read_bytes() == b"\x89MCAP0\r\nsomeone else's"


def test_ximu3_two_files_convert_and_the_quaternion_is_sensor_to_earth(tmp_path):
    out = tmp_path / "xio.mcap"
    argv = ximu3_convert_argv(out)
    assert main(argv) == 0
    log = read_log(out)
    assert len(log.imu.t_ns) == 921 and len(log.truth.t_ns) == 921  # the README: 18.6 s at 50 Hz
    # At the starting rest, q_w_b maps the accelerometer (specific force, pointing up) to +z of
    # a z-up world: the file's W,X,Y,Z is sensor to earth, i.e. q_w_b as the replay needs it.
    up = Rotation.from_quat(log.truth.q_w_b[:25]).apply(log.imu.accel_b[:25]).mean(axis=0)
    assert np.linalg.norm(up[:2]) < 0.02 * GRAVITY_M_S2 and up[2] == pytest.approx(
        GRAVITY_M_S2, rel=0.01
    )
    s = tmp_path / "s.json"
    assert main([str(out), "--rerun", "off", "--summary-json", str(s)]) == 0
    assert json.loads(s.read_text())["rest_confirmed"] is True  # still, by the accelerometer

"""convert-csv --truth-estimate-of: a truth that is a device's own estimate (the x-IMU3's AHRS)
is stored as such in the bag (``custom_data`` key ``imu_dcm.estimate_of:<topic>``) and the
replay, ``info`` and batch's ``truth_kind`` say so; a single ``.mcap`` carries its
``custom_data`` in its rosbag2 metadata record. Driven through the commands."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from conftest import assert_names
from drone_logs import ximu3_convert_argv
from scipy.spatial.transform import Rotation

from imu_dcm.errors import ImuDcmWarning
from imu_dcm.logio import read_log
from imu_dcm.logio.ros.truth import ESTIMATE_OF_KEY
from imu_dcm.replay.__main__ import main
from imu_dcm.replay.kinds import ESTIMATE, INDEPENDENT

ARGS = ["--time-col", "t_ms", "--time-units", "ms", "--gyro-cols", "gx,gy,gz"]
ARGS += ["--gyro-units", "deg/s", "--truth-cols", "qw,qx,qy,qz", "--truth-order", "wxyz"]


@pytest.fixture
def spin(tmp_path):
    """A 30 °/s spin about z for 4 s at 100 Hz with its closed-form attitude (w, x, y, z)."""
    path = tmp_path / "spin.csv"
    rows = ["t_ms,gx,gy,gz,qw,qx,qy,qz"]
    for k in range(401):
        x, y, z, w = Rotation.from_euler("z", 0.3 * k, degrees=True).as_quat().tolist()
        rows.append(f"{10 * k},0,0,30,{w!r},{x!r},{y!r},{z!r}")
    path.write_text("\n".join(rows) + "\n")
    return path


def _said(out, tmp_path, capsys) -> tuple[str, str, str, str]:
    """(estimate_of as read, the replay's stdout, info's truth line, batch's truth_kind)."""
    capsys.readouterr()
    who = read_log(out).truth.estimate_of
    s = tmp_path / "s.json"
    assert main([str(out), "--rerun", "off", "--summary-json", str(s)]) == 0
    replay = capsys.readouterr().out
    assert json.loads(s.read_text())["truth_estimate_of"] == who
    assert main(["info", str(out)]) == 0
    info = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("truth ")]
    table = tmp_path / "t.csv"
    assert main(["batch", str(out), "--table", str(table), "--force"]) == 0
    with open(table, newline="") as f:
        (row,) = list(csv.DictReader(f))
    return who, replay, "\n".join(info), row["truth_kind"]


@pytest.mark.parametrize("name", ["x.mcap", "bag"])
def test_the_mark_reaches_replay_info_and_batch(spin, tmp_path, capsys, name):
    out = tmp_path / name
    argv = ["convert-csv", str(spin), str(out), *ARGS, "--truth-estimate-of", "the test rig"]
    assert main(argv) == 0
    who, replay, info, kind = _said(out, tmp_path, capsys)
    assert who == "the test rig's own estimate"
    assert "truth is   the test rig's own estimate, not an independent reference" in replay
    assert "(the test rig's own estimate)" in info
    assert kind == ESTIMATE
    assert read_log(out).custom_data[ESTIMATE_OF_KEY + "/ground_truth/orientation"] == who


def test_without_the_option_the_truth_stays_an_independent_reference(spin, tmp_path, capsys):
    out = tmp_path / "x.mcap"
    assert main(["convert-csv", str(spin), str(out), *ARGS]) == 0
    who, replay, info, kind = _said(out, tmp_path, capsys)
    assert who == "" and "truth is" not in replay and "own estimate" not in info
    assert kind == INDEPENDENT


def test_a_single_mcap_carries_its_custom_data(spin, tmp_path):
    out = tmp_path / "x.mcap"
    assert main(["convert-csv", str(spin), str(out), *ARGS]) == 0
    # no metadata.yaml beside it: read from the MCAP's rosbag2 metadata record
    assert sorted(p.name for p in tmp_path.iterdir()) == ["spin.csv", "x.mcap"]
    assert read_log(out).custom_data["imu_dcm.converted_from"] == "spin.csv"


def test_a_damaged_metadata_record_costs_only_the_metadata(spin, tmp_path):
    out = tmp_path / "x.mcap"
    argv = ["convert-csv", str(spin), str(out), *ARGS, "--truth-estimate-of", "the test rig"]
    assert main(argv) == 0
    data = out.read_bytes()
    assert data.count(b"custom_data:\n") == 1
    out.write_bytes(data.replace(b"custom_data:\n", b"custom_data: [\n"))  # YAML that fails
    with pytest.warns(ImuDcmWarning, match="metadata record at byte .* is damaged") as got:
        log = read_log(out)
    assert "estimate" in str(got[0].message)  # the user learns what was lost
    assert log.custom_data == {} and len(log.imu.t_ns) == 401 and len(log.truth.t_ns) == 401


@pytest.mark.parametrize(
    ("extra", "said"),
    [
        (["--truth-estimate-of", "the rig"], "no --truth-cols"),
        ([*ARGS[8:], "--truth-estimate-of", " "], "empty name"),
    ],
)
def test_the_option_needs_a_truth_and_a_name(spin, tmp_path, capsys, extra, said):
    out = tmp_path / "x.mcap"
    assert main(["convert-csv", str(spin), str(out), *ARGS[:8], *extra]) == 2
    err = capsys.readouterr().err
    assert_names(err, "--truth-estimate-of", "--truth-cols", said)
    assert not out.exists()


def test_ximu3_quaternion_is_marked_as_the_devices_own_estimate(tmp_path, capsys):
    out = tmp_path / "xio.mcap"
    argv = ximu3_convert_argv(out)
    assert main([*argv, "--truth-estimate-of", "the x-IMU3"]) == 0
    who, replay, info, kind = _said(out, tmp_path, capsys)
    assert who == "the x-IMU3's own estimate"
    assert "truth is   the x-IMU3's own estimate, not an independent reference" in replay
    assert "(the x-IMU3's own estimate)" in info and kind == ESTIMATE
    assert np.isfinite(read_log(out).truth.q_w_b).all()


def test_a_lone_broad_mcap_declares_what_its_bag_folder_does(broad_dir, tmp_path):
    """A rosbag2-written ``.mcap`` away from its ``metadata.yaml`` keeps its custom_data (the
    movement intervals ``--score-window declared`` scores), from its rosbag2 metadata record."""
    import shutil

    from imu_dcm.logio import read_custom_data

    trial = "02_undisturbed_slow_rotation_B"
    lone = tmp_path / f"{trial}.mcap"
    shutil.copyfile(broad_dir / trial / f"{trial}.mcap", lone)
    want = read_custom_data(broad_dir / trial)
    key = "broad.movement_intervals_stamp_ns"
    assert key in want
    assert read_log(lone).custom_data == want

"""The data_synth command line: logs readable by mcap and rosbags, truth and metadata as promised,
same seed same bytes, one-line errors with exit status 2, atomic and non-clobbering output."""

from __future__ import annotations

import hashlib
import json
import os
import stat
import subprocess
import sys
import warnings

import numpy as np
import pytest
from conftest import own_stderr
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

import data_synth
from data_synth.budget import JobTooLarge
from data_synth.cli import main
from data_synth.gyro import DEFAULT_EPOCH_NS
from data_synth.reference_scheme import reference_top

TOPICS = ("/imu/data", "/ground_truth/orientation", "/ground_truth/angular_velocity")


def _read(folder):
    """Stamps and values per topic, decoded by mcap + mcap_ros2 (one decoder)."""
    (mcap_file,) = folder.glob("*.mcap")
    out: dict[str, tuple[list, list]] = {t: ([], []) for t in TOPICS}
    with open(mcap_file, "rb") as f:
        for _, ch, _, m in make_reader(
            f, decoder_factories=[DecoderFactory()]
        ).iter_decoded_messages():
            st = m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
            if ch.topic == "/imu/data":
                v = m.angular_velocity
                row = [v.x, v.y, v.z]
            elif ch.topic == "/ground_truth/orientation":
                q = m.quaternion
                row = [q.x, q.y, q.z, q.w]
            else:
                v = m.vector
                row = [v.x, v.y, v.z]
            out[ch.topic][0].append(st)
            out[ch.topic][1].append(row)
    return {k: (np.array(s, dtype=np.int64), np.array(v)) for k, (s, v) in out.items()}


def _custom_data(folder) -> dict[str, str]:
    from ruamel.yaml import YAML

    meta = YAML(typ="safe").load((folder / "metadata.yaml").read_text())
    return meta["rosbag2_bagfile_information"]["custom_data"]


def test_heavy_top_log_holds_gyro_truth_and_metadata(tmp_path, capsys):
    out = tmp_path / "top"
    argv = [
        "heavy-top",
        "--motion",
        "wavy",
        "--rate",
        "500",
        "--duration",
        "0.5",
        "--out",
        str(out),
    ]
    assert main(argv) == 0
    assert capsys.readouterr().out.strip() == str(out)
    got = _read(out)
    t_ns = DEFAULT_EPOCH_NS + np.arange(251, dtype=np.int64) * 2_000_000
    traj = data_synth.simulate("heavy-top", duration_s=0.5, motion="wavy")
    # Sample instants are defined by the stamps: t_s = (t_ns - epoch) · 1e-9 (data_synth.gyro).
    q_true, w_true = traj.at((t_ns - DEFAULT_EPOCH_NS) * 1e-9)
    for topic in TOPICS:
        assert np.array_equal(got[topic][0], t_ns)  # realistic epoch, exact 2 ms grid
    # The log holds exactly what the Python API gives (same solver, same times).
    assert np.array_equal(got["/imu/data"][1], w_true)
    assert np.array_equal(got["/ground_truth/angular_velocity"][1], w_true)
    assert np.array_equal(got["/ground_truth/orientation"][1], q_true)
    meta = _custom_data(out)
    assert all(k.startswith("data_synth.") for k in meta)
    assert meta["data_synth.scene"] == "heavy-top"
    assert json.loads(meta["data_synth.params"]) == json.loads(json.dumps(traj.params))
    assert json.loads(meta["data_synth.gyro.model"]) == {}
    assert meta["data_synth.command"].startswith("python -m data_synth heavy-top --motion wavy")


def test_log_is_readable_by_rosbags(tmp_path):
    out = tmp_path / "cone"
    assert main(["coning", "--rate", "200", "--duration", "0.2", "--out", str(out)]) == 0
    with AnyReader([out], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        imu = [
            reader.deserialize(raw, c.msgtype)
            for c, _, raw in reader.messages()
            if c.topic == "/imu/data"
        ]
    assert counts == dict.fromkeys(TOPICS, 41)
    assert imu[0].orientation_covariance[0] == -1.0
    assert imu[0].linear_acceleration_covariance[0] == -1.0
    assert imu[0].header.frame_id == "imu"


def test_same_seed_same_bytes_other_seed_other_bytes(tmp_path):
    common = [
        "free-body",
        "--case",
        "intermediate",
        "--rate",
        "200",
        "--duration",
        "1",
        "--gyro-noise-density",
        "1e-3",
        "--gyro-bias-walk",
        "1e-4",
        "--stamp-jitter",
        "1e-4",
        "--gyro-quantization",
        "1e-4",
    ]

    def digest(name, seed):
        out = tmp_path / name
        assert main([*common, "--seed", str(seed), "--out", str(out)]) == 0
        return hashlib.sha256((out / f"{name}.mcap").read_bytes()).hexdigest()

    # The folder name is the .mcap name (rosbag2 layout), so equal names for equal bytes.
    a = digest("run", 3)
    (tmp_path / "first").mkdir()
    (tmp_path / "run").rename(tmp_path / "first" / "run")
    assert digest("run", 3) == a
    (tmp_path / "run").rename(tmp_path / "second")
    assert digest("run", 4) != a


def test_delta_angle_log_writes_mean_rates_and_initial_truth(tmp_path):
    out = tmp_path / "da"
    assert (
        main(
            [
                "coning",
                "--rate",
                "100",
                "--duration",
                "1",
                "--gyro-output",
                "delta-angle",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    got = _read(out)
    traj = data_synth.simulate("coning", duration_s=1.0)
    t = np.arange(101) / 100.0
    assert got["/imu/data"][0].size == 100 and got["/ground_truth/orientation"][0].size == 101
    assert got["/ground_truth/orientation"][0][0] == DEFAULT_EPOCH_NS  # attitude at t = 0 too
    # angular_velocity = Δθ / Δt, the mean rate over each 10 ms interval.
    assert np.allclose(got["/imu/data"][1], traj.delta_angles(t) / 0.01, rtol=0, atol=1e-12)
    assert "data_synth.gyro.note" in _custom_data(out)


def test_reference_scheme_log_holds_the_scheme_output(tmp_path):
    out = tmp_path / "ref"
    assert (
        main(
            [
                "heavy-top",
                "--scheme",
                "reference",
                "--rate",
                "1000",
                "--duration",
                "0.2",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    got = _read(out)
    run = reference_top(0.2, 1000.0)
    assert np.array_equal(got["/imu/data"][1], run.omega_b)
    assert _custom_data(out)["data_synth.scheme"] == "reference"


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["heavy-top", "--rate", "-5", "--duration", "1", "--out", "x"], "--rate"),
        (["heavy-top", "--rate", "abc", "--duration", "1", "--out", "x"], "--rate"),
        (
            ["heavy-top", "--motion", "wobbly", "--rate", "5", "--duration", "1", "--out", "x"],
            "--motion",
        ),
        (["spinning-plate", "--rate", "5"], "SCENE"),
        (["coning", "--rate", "5", "--duration", "1"], "--out"),
        (
            ["free-body", "--omega", "1,2", "--rate", "5", "--duration", "1", "--out", "x"],
            "--omega",
        ),
        (
            ["coning", "--gyro-bias", "0,0,nan", "--rate", "5", "--duration", "1", "--out", "x"],
            "--gyro-bias",
        ),
        (["heavy-top", "--bogus", "--rate", "5", "--duration", "1", "--out", "x"], "--bogus"),
    ],
)
def test_bad_option_one_line_exit_2(tmp_path, capsys, argv, needle):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and needle in err and "Traceback" not in err


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["coning", "--half-angle-deg", "95", "--rate", "5", "--duration", "1"], "half_angle_deg"),
        (
            ["heavy-top", "--motion", "steady", "--spin-hz", "1", "--rate", "5", "--duration", "1"],
            "steady precession",
        ),
        (
            [
                "heavy-top",
                "--motion",
                "sleeping",
                "--tilt-deg",
                "5",
                "--rate",
                "5",
                "--duration",
                "1",
            ],
            "sleeping",
        ),
        (
            [
                "heavy-top",
                "--scheme",
                "reference",
                "--gyro-output",
                "delta-angle",
                "--rate",
                "5",
                "--duration",
                "1",
            ],
            "--scheme reference",
        ),
    ],
)
def test_bad_value_one_line_exit_2_and_no_output(tmp_path, capsys, argv, needle):
    out = tmp_path / "never"
    assert main([*argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and needle in err
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_existing_output_not_overwritten_without_force(tmp_path, capsys):
    out = tmp_path / "log"
    argv = ["coning", "--rate", "50", "--duration", "0.2", "--out", str(out)]
    assert main(argv) == 0
    before = (out / "log.mcap").read_bytes()
    capsys.readouterr()
    assert main(argv) == 2
    assert "--force" in capsys.readouterr().err
    assert (out / "log.mcap").read_bytes() == before
    assert main([*argv[:-2], "--freq-hz", "3", "--out", str(out), "--force"]) == 0
    assert (out / "log.mcap").read_bytes() != before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["log"]


def test_python_dash_m_entry_point(tmp_path):
    ok = subprocess.run(
        [
            sys.executable,
            "-m",
            "data_synth",
            "coning",
            "--rate",
            "20",
            "--duration",
            "0.5",
            "--out",
            str(tmp_path / "c"),
        ],
        check=False,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert ok.returncode == 0, ok.stderr
    bad = subprocess.run(
        [sys.executable, "-m", "data_synth", "coning", "--rate", "0"],
        check=False,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert bad.returncode == 2
    assert own_stderr(bad.stderr).count("\n") == 1 and "--rate" in bad.stderr


# Jobs that cannot finish, bad integers, file-system errors: refused up front, one line, exit 2.
@pytest.mark.parametrize(
    "argv, needles",
    [
        # 1e10 and 1e9 samples at 5 µs each (data_synth.budget): 14 h and 83 min; the memory is
        # one block's, whatever the length
        (["coning", "--rate", "1e10", "--duration", "1"], ["1e+10 samples", "MiB and 13.9 h"]),
        (["coning", "--rate", "1e7", "--duration", "100"], ["1e+09 samples", "83.3 min"]),
        (["heavy-top", "--scheme", "reference", "--rate", "1e6", "--duration", "100"], ["h for"]),
        # the ODE would need ~1e10 (spin) and ~1e30 (|omega|) steps: measured by a 200-step probe
        (
            ["heavy-top", "--spin-hz", "1e9", "--rate", "100", "--duration", "1"],
            ["ODE steps", "days"],
        ),
        (["free-body", "--omega=1e30,0,0", "--rate", "100", "--duration", "1"], ["ODE steps"]),
        (["free-body", "--omega=1e300,0,0", "--rate", "100", "--duration", "1"], ["ODE"]),
        (["heavy-top", "--rate", "100", "--duration", "1e9"], ["2^31 s"]),
        (["coning", "--rate", "1e-300", "--duration", "1e300"], ["2^31 s"]),
        (
            ["coning", "--rate", "100", "--duration", "1", "--epoch-ns", "2147483647500000000"],
            ["2^31 s"],
        ),
        (
            ["coning", "--rate", "100", "--duration", "1", "--gyro-quantization", "3e-308"],
            ["quantization_rad_s"],
        ),
        (
            ["coning", "--rate", "100", "--duration", "1", "--gyro-quantization", "5e-324"],
            ["quantization_rad_s"],
        ),
        (
            ["coning", "--rate", "100", "--duration", "1", "--gyro-noise-density", "1e308"],
            ["finite gyro output"],
        ),
        (["coning", "--rate", "100", "--duration", "1", "--max-memory-gib", "1e-6"], ["samples"]),
    ],
)
def test_impossible_job_refused_up_front_one_line_exit_2(tmp_path, capsys, argv, needles):
    out = tmp_path / "never"
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no raw RuntimeWarning reaches the user
        assert main([*argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and all(n in err for n in needles), err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    "flag, value",
    [("--seed", "-1"), ("--epoch-ns", str(2**63)), ("--epoch-ns", "-1"), ("--seed", "1.5")],
)
def test_bad_integer_option_one_line_exit_2(tmp_path, capsys, flag, value):
    with pytest.raises(SystemExit) as exc:
        main(
            ["coning", "--rate", "10", "--duration", "1", flag, value, "--out", str(tmp_path / "x")]
        )
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and flag in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


def test_file_system_error_one_line_exit_2(tmp_path, capsys):
    (tmp_path / "file").write_bytes(b"not a folder")
    argv = ["coning", "--rate", "10", "--duration", "0.5", "--out", str(tmp_path / "file" / "x")]
    assert main(argv) == 2
    assert capsys.readouterr().err.count("\n") == 1
    assert (tmp_path / "file").read_bytes() == b"not a folder"


def test_force_replaces_only_a_bag_data_synth_wrote(tmp_path, capsys):
    argv = ["coning", "--rate", "10", "--duration", "0.5", "--force", "--out"]
    precious = tmp_path / "precious"  # a user's folder: never deleted by --force
    precious.mkdir()
    (precious / "notes.txt").write_text("keep me")
    plain = tmp_path / "plain.txt"
    plain.write_text("keep me too")
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    for target in (precious, plain, fifo):
        assert main([*argv, str(target)]) == 2
        assert "written by python -m data_synth" in capsys.readouterr().err
    assert (precious / "notes.txt").read_text() == "keep me"
    assert plain.read_text() == "keep me too" and stat.S_ISFIFO(fifo.lstat().st_mode)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fifo", "plain.txt", "precious"]
    ours = tmp_path / "ours"
    assert main([*argv, str(ours)]) == 0 and main([*argv, str(ours)]) == 0  # its own bag: ok


@pytest.mark.parametrize(
    "scene, kw, duration_s",
    [
        ("heavy-top", {"motion": "looping"}, 3.0),
        ("heavy-top", {"motion": "cusp", "spin_hz": 60.0}, 1.0),
        ("free-body", {"case": "intermediate"}, 20.0),
    ],
)
def test_ode_step_estimate_tracks_the_real_solve(scene, kw, duration_s):
    # The refusal rests on the 200-step probe's extrapolation: it must track the real solve.
    # DOP853 spends 12 right-hand-side calls per accepted step (plus rejections), so nfev / 12
    # bounds the real step count from above; the estimate must sit within 3x of it.
    with pytest.raises(JobTooLarge) as exc:
        data_synth.simulate(scene, duration_s, max_steps=1, **kw)
    real_steps = data_synth.simulate(scene, duration_s, **kw).nfev / 12
    assert real_steps / 3 < exc.value.steps < 3 * real_steps

"""The replay command line: ``main([...])`` for every bad input (one line, exit 2, no
traceback), the outputs (--summary-json, --out), convert-csv, and one real subprocess run on
the shipped BROAD trial."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import assert_quiet, estimate_bag
from mcap.reader import make_reader
from mcap.writer import Writer as McapWriter
from mcap_ros2.decoder import DecoderFactory
from scipy.spatial.transform import Rotation
from test_logio import write_imu_bag  # tests/ is on sys.path (pytest rootdir conftest)

from imu_dcm.logio import resolve_mcap_path
from imu_dcm.logio.writers import StampedSeries, write_bag
from imu_dcm.replay.__main__ import main

REPO = Path(__file__).resolve().parents[1]
SHIPPED = REPO / "replay" / "broad_07_undisturbed_fast_rotation_B"
T0_NS = 1_700_000_000_000_000_000
SUMMARY_KEYS = {  # issue 4's list
    "samples",
    "duration_s",
    "imu_topic",
    "truth_topic",
    "method",
    "bias_rad_s",
    "rms_error_deg",
    "max_error_deg",
    "elapsed_s",
}


@pytest.fixture(scope="module")
def coning_log(tmp_path_factory) -> Path:
    """Coning at 400 Hz for 2 s with truth at every sample.

    Closed form: q(t) = exp(Ωt ẑ) exp(β x̂) exp(-Ωt ẑ), body rate in closed form too.
    """
    t = np.arange(0, 2.0, 1 / 400)
    beta, big_omega = np.radians(10.0), 2 * np.pi * 2.0
    q = (
        Rotation.from_rotvec(np.outer(big_omega * t, [0, 0, 1]))
        * Rotation.from_rotvec([beta, 0, 0])
        * Rotation.from_rotvec(np.outer(-big_omega * t, [0, 0, 1]))
    ).as_quat()
    w = (
        big_omega
        * np.c_[
            -np.sin(beta) * np.sin(big_omega * t),
            np.sin(beta) * np.cos(big_omega * t),
            np.full_like(t, np.cos(beta) - 1),
        ]
    )
    t_ns = T0_NS + np.round(t * 1e9).astype(np.int64)
    out = tmp_path_factory.mktemp("cli") / "coning"
    return write_bag(
        out,
        imu=StampedSeries(t_ns, w, "imu"),
        quaternions={"/ground_truth/orientation": StampedSeries(t_ns, q, "world")},
    )


def _error_lines(err: str) -> list[str]:
    return [x for x in err.splitlines() if x.strip()]


def _assert_one_line_error(capsys, argv, pattern):
    code = main(argv)
    _out, err = capsys.readouterr()
    lines = _error_lines(err)
    assert code == 2, err
    assert "Traceback" not in err
    assert len(lines) == 1 and lines[0].startswith("imu-dcm-replay: error: Expected"), lines
    assert pattern in lines[0]


def test_replay_writes_summary_json_and_estimate_bag(coning_log, tmp_path, capsys):
    js = tmp_path / "s.json"
    out = tmp_path / "est"
    before = sorted((p.name, p.stat().st_size, p.stat().st_mtime_ns) for p in coning_log.iterdir())
    code = main(
        [
            str(coning_log),
            "--rerun",
            "off",
            "--bias",
            "none",
            "--summary-json",
            str(js),
            "--out",
            str(out),
        ]
    )
    text, err = capsys.readouterr()
    assert code == 0, err
    s = json.loads(js.read_text())
    assert set(s) >= SUMMARY_KEYS
    assert s["samples"] == 800 and s["imu_topic"] == "/imu/data"
    assert s["truth_topic"] == "/ground_truth/orientation" and s["method"] == "magnus4"
    # magnus4 at y = Ω·dt = 0.031 on a 10° cone: drift ~β²Ω y⁴/960 per s, far below 1e-4°
    assert s["max_error_deg"] < 1e-4
    assert "error      total RMS" in text and "heading RMS" in text
    # the estimate bag, read back with the reference decoder
    q_bag, t_bag = estimate_bag(out)
    assert len(q_bag) == 800
    np.testing.assert_array_equal(np.diff(t_bag), 2_500_000)  # the gyro stamps, 400 Hz
    assert (Rotation.from_quat(q_bag[-1]).magnitude()) > 0  # a real attitude, not identity
    after = sorted((p.name, p.stat().st_size, p.stat().st_mtime_ns) for p in coning_log.iterdir())
    assert before == after  # the input is never modified
    # an existing --out is not overwritten without --force
    _assert_one_line_error(capsys, [str(coning_log), "--rerun", "off", "--out", str(out)], "")
    assert main([str(coning_log), "--rerun", "off", "--out", str(out), "--force", "--quiet"]) == 0


def test_rerun_save_hand_off(coning_log, tmp_path, capsys):
    rrd = tmp_path / "view.rrd"
    code = main([str(coning_log), "--rerun", f"save:{rrd}", "--quiet"])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert rrd.is_file() and rrd.stat().st_size > 0
    assert str(rrd) in out


def test_bad_inputs_one_line_exit_2(tmp_path, capsys):
    _assert_one_line_error(capsys, [str(tmp_path / "missing"), "--rerun", "off"], "no such file")
    (tmp_path / "g.mcap").write_bytes(b"GARBAGE!" * 100)
    _assert_one_line_error(capsys, [str(tmp_path / "g.mcap"), "--rerun", "off"], "MCAP file")
    (tmp_path / "e.mcap").write_bytes(b"")
    _assert_one_line_error(capsys, [str(tmp_path / "e.mcap"), "--rerun", "off"], "empty file")
    t_ns = T0_NS + np.arange(5, dtype=np.int64) * 10**7
    only_vec = write_bag(
        tmp_path / "vec", vectors={"/wind": StampedSeries(t_ns, np.zeros((5, 3)), "world")}
    )
    _assert_one_line_error(
        capsys,
        [str(only_vec), "--rerun", "off"],
        "got /wind (geometry_msgs/msg/Vector3Stamped, cdr, 5)",
    )
    with open(tmp_path / "pb.mcap", "wb") as f:
        w = McapWriter(f)
        w.start("", "test")
        cid = w.register_channel(
            "/imu", "protobuf", w.register_schema("foxglove.Imu", "protobuf", b"x")
        )
        w.add_message(cid, log_time=1, data=b"\x08\x01", publish_time=1)
        w.finish()
    _assert_one_line_error(capsys, [str(tmp_path / "pb.mcap"), "--rerun", "off"], "'protobuf'")
    imu = StampedSeries(t_ns, np.zeros((5, 3)), "imu")
    late = write_bag(
        tmp_path / "late",
        imu=imu,
        quaternions={
            "/truth": StampedSeries(t_ns + 10**10, np.tile([0, 0, 0, 1.0], (5, 1)), "world")
        },
    )
    _assert_one_line_error(capsys, [str(late), "--rerun", "off"], "to overlap the gyro")
    _assert_one_line_error(
        capsys, [str(late), "--rerun", "off", "--init-quat", "1,2"], "--init-quat x,y,z,w"
    )
    _assert_one_line_error(capsys, [str(late), "--rerun", "bogus"], "--rerun")
    _assert_one_line_error(capsys, [str(late), "--rerun", "off", "--imu-topic", "/x"], "'/x'")


def test_nan_samples_and_truncation_warn_but_replay(coning_log, tmp_path, capsys):
    t = np.arange(0, 1.0, 0.01)
    t_ns = T0_NS + np.round(t * 1e9).astype(np.int64)
    w = np.zeros((len(t), 3))
    w[[10, 20, 30]] = np.nan
    nan_log = write_imu_bag(tmp_path / "nan.mcap", t_ns, w)  # our writer refuses NaN
    js = tmp_path / "n.json"
    assert main([str(nan_log), "--rerun", "off", "--summary-json", str(js)]) == 0
    _, err = capsys.readouterr()
    assert "warning: /imu/data: dropped 3 samples with NaN/Inf rates" in err
    assert json.loads(js.read_text())["dropped_nonfinite"] == 3
    data = resolve_mcap_path(coning_log).read_bytes()
    (tmp_path / "cut.mcap").write_bytes(data[: len(data) // 2])
    assert main([str(tmp_path / "cut.mcap"), "--rerun", "off", "--quiet"]) in (0, 2)
    _, err = capsys.readouterr()
    assert "Traceback" not in err and "truncated or corrupt" in err


def test_convert_csv_wxyz_deg_ms_round_trip(tmp_path, capsys):
    # 90°/s about body z for 2 s from identity; truth written scalar-first (wxyz) in the CSV.
    t = np.arange(0, 2.0, 0.005)
    half = np.radians(90.0) * t / 2
    rows = np.c_[
        t * 1e3,
        np.zeros_like(t),
        np.zeros_like(t),
        np.full_like(t, 90.0),
        np.cos(half),
        np.zeros_like(t),
        np.zeros_like(t),
        np.sin(half),
    ]
    csv = tmp_path / "log.csv"
    np.savetxt(csv, rows, delimiter=",", header="t_ms,gx,gy,gz,qw,qx,qy,qz", comments="")
    bag = tmp_path / "bag"
    argv = [
        "convert-csv",
        str(csv),
        str(bag),
        "--time-col",
        "t_ms",
        "--time-unit",
        "ms",
        "--gyro-cols",
        "gx,gy,gz",
        "--gyro-units",
        "deg/s",
        "--truth-cols",
        "qw,qx,qy,qz",
    ]
    _assert_one_line_error(capsys, argv, "--truth-order")  # the order must be named
    assert main([*argv, "--truth-order", "wxyz"]) == 0
    js = tmp_path / "s.json"
    assert main([str(bag), "--rerun", "off", "--bias", "none", "--summary-json", str(js)]) == 0
    s = json.loads(js.read_text())
    # constant axis: exact up to round-off; a wrong quaternion order would be ~180° off
    assert s["max_error_deg"] < 1e-6 and s["samples"] == 400
    assert s["duration_s"] == pytest.approx(1.995)
    _assert_one_line_error(
        capsys,
        [
            "convert-csv",
            str(csv),
            str(tmp_path / "b2"),
            "--time-col",
            "time",
            "--time-unit",
            "s",
            "--gyro-cols",
            "gx,gy,gz",
            "--gyro-units",
            "rad/s",
        ],
        "'time'",
    )


def test_subprocess_replays_shipped_trial(tmp_path):
    js = tmp_path / "s.json"
    env = dict(os.environ, PYTHONWARNINGS="default")  # every warning shown, once
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "imu_dcm.replay",
            str(SHIPPED),
            "--rerun",
            "off",
            "--summary-json",
            str(js),
        ],
        check=False,
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env=env,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    assert_quiet(proc.stderr)  # no warning of ours, and no progress bar when not a terminal
    s = json.loads(js.read_text())
    assert s["samples"] == 52518 and s["truth_topic"] == "/ground_truth/orientation"
    # gyro-only, bias removed at rest, over 3 minutes: BROAD's own gyro-only baselines stay
    # within ~10° on undisturbed trials; an unremoved 0.3 °/s bias would give ~30°
    assert 0.5 < s["rms_error_deg"] < 10.0
    assert "imu        /imu/data (sensor_msgs/msg/Imu): 52518 samples" in proc.stdout


def test_progress_bar_only_on_a_terminal():
    import io

    from imu_dcm.app.progress import Progress

    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    tty = Terminal()
    bar = Progress(tty, delay_s=0.0)
    bar("read", 0.5)
    bar("read", 1.0)
    bar.close()
    assert "read       [###############...............]  50.0%" in tty.getvalue()
    assert tty.getvalue().endswith("\r")  # the line is wiped at the end
    pipe = io.StringIO()  # not a terminal: nothing at all
    quiet = Progress(pipe, delay_s=0.0)
    quiet("read", 0.5)
    quiet.close()
    assert pipe.getvalue() == ""


def test_prefilter_writes_filtered_rate_to_out_bag(coning_log, tmp_path, capsys):
    out = tmp_path / "pf"
    code = main(
        [
            str(coning_log),
            "--rerun",
            "off",
            "--bias",
            "none",
            "--prefilter",
            "kalman",
            "--gyro-noise-density",
            "1e-4",
            "--angular-accel",
            "50",
            "--out",
            str(out),
            "--quiet",
        ]
    )
    assert code == 0, capsys.readouterr().err
    counts: dict[str, int] = {}
    with open(resolve_mcap_path(out), "rb") as f:
        for _, ch, _, _ in make_reader(
            f, decoder_factories=[DecoderFactory()]
        ).iter_decoded_messages():
            counts[ch.topic] = counts.get(ch.topic, 0) + 1
    assert counts == {"/estimate/orientation": 800, "/estimate/angular_velocity": 800}
    _assert_one_line_error(
        capsys,
        [str(coning_log), "--rerun", "off", "--angular-accel", "5"],
        "--prefilter kalman or rts",
    )


def test_bad_option_is_one_line_without_usage_dump(coning_log, capsys):
    # argparse's own errors (unknown choice) follow the same one-line rule as ours.
    assert main([str(coning_log), "--method", "euler"]) == 2
    lines = _error_lines(capsys.readouterr().err)
    assert len(lines) == 1 and lines[0].startswith("imu-dcm-replay: error: argument --method")


def test_summary_keeps_small_errors_visible_and_says_when_no_rest(coning_log, capsys):
    # Pure coning with exact rates at this log's rate: magnus4 is accurate to far below 0.01 deg,
    # and the cone never rests. The summary must not round the error to "0.00°" nor print a zero
    # vector as if a bias had been measured.
    assert main([str(coning_log), "--rerun", "off"]) == 0
    text = capsys.readouterr().out
    line = next(x for x in text.splitlines() if x.startswith("bias"))
    assert "no rest found: the stillest 0.50 s, at " in line and "no bias removed" in line, line
    line = next(x for x in text.splitlines() if x.startswith("error"))
    rms = float(line.split("total RMS ")[1].split("°")[0])
    assert 0.0 < rms < 0.01, line


def test_a_gap_is_reported_once(tmp_path, capsys):
    # clean_imu names the gap; the integrator must not report the same gap a second time.
    t = np.arange(0.0, 2.0, 0.01)
    t = t[(t < 0.9) | (t > 1.3)]
    t_ns = (1_700_000_000_000_000_000 + np.round(t * 1e9)).astype(np.int64)
    log = write_bag(
        tmp_path / "gappy", imu=StampedSeries(t_ns, np.tile([0.1, 0.2, 0.3], (len(t), 1)), "imu")
    )
    assert main([str(log), "--rerun", "off"]) == 0
    err = capsys.readouterr().err
    assert err.count("gap") == 1 and "0.890 s (+0.420 s)" in err, err


def test_help_loads_no_numerical_stack(tmp_path):
    # --help must stay fast: it may not import what only a replay needs (asserted on the set of
    # imported modules, not on a time).
    code = (
        "import runpy, sys\n"
        "sys.argv = ['imu-dcm-replay', '--help']\n"
        "try:\n"
        "    runpy.run_module('imu_dcm.replay', run_name='__main__')\n"
        "except SystemExit:\n"
        "    pass\n"
        "heavy = {'numpy', 'scipy', 'numba', 'rerun', 'mcap', 'mcap_ros2', 'rosbags'}\n"
        "print(sorted({m.split('.')[0] for m in sys.modules} & heavy))\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        timeout=120,
        check=False,
        env=dict(os.environ, PYTHONPATH=str(REPO)),
    )
    assert proc.returncode == 0, proc.stderr
    assert "--truth-offset" in proc.stdout and proc.stdout.strip().endswith("[]"), proc.stdout

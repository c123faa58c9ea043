"""Outputs of the replay command and convert-csv: nothing a user points them at is destroyed.

Every case asserts one error line and exit 2 (no traceback), the input bytes unchanged, special
files still special, and no partial output; plus the TUM export read back against the closed-form
coning truth."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from data_synth.analytic import coning_attitude, coning_rates
from imu_dcm.logio.writers import StampedSeries, write_bag
from imu_dcm.outputs import OutputError, check_output_dir, is_own_bag
from imu_dcm.replay.__main__ import main

T0_NS = 1_700_000_000_000_000_000


def _coning(t):
    """Pure coning, half-angle 10°, 2 Hz: the closed forms of data_synth.analytic."""
    return coning_attitude(t, np.radians(10.0), 2.0), coning_rates(t, np.radians(10.0), 2.0)


@pytest.fixture
def bag(tmp_path) -> Path:
    """Coning at 200 Hz for 1 s with truth at every sample (a fresh copy per test)."""
    t = np.arange(0, 1.0, 1 / 200)
    q, w = _coning(t)
    t_ns = T0_NS + np.round(t * 1e9).astype(np.int64)
    (tmp_path / "in").mkdir()
    return write_bag(
        tmp_path / "in" / "bag",
        imu=StampedSeries(t_ns, w, "imu"),
        quaternions={"/ground_truth/orientation": StampedSeries(t_ns, q, "world")},
    )


def _snapshot(folder: Path) -> list:
    return sorted((p.name, p.read_bytes()) for p in folder.iterdir())


def _fails(capsys, argv, pattern) -> None:
    code = main(argv)
    err = capsys.readouterr().err
    lines = [x for x in err.splitlines() if x.strip() and "warning:" not in x]
    assert code == 2, err
    assert "Traceback" not in err
    assert len(lines) == 1 and lines[0].startswith("imu-dcm-replay: error: Expected"), lines
    assert pattern in lines[0], lines[0]


def test_outputs_that_would_destroy_the_input_are_refused(bag, tmp_path, capsys):
    before = _snapshot(bag)
    mcap = bag / "bag.mcap"
    off = ["--rerun", "off"]
    _fails(capsys, [str(bag), *off, "--summary-json", str(bag / "metadata.yaml")], "input")
    _fails(capsys, [str(bag), *off, "--summary-json", str(bag / "new.json")], "input folder")
    _fails(capsys, [str(mcap), *off, "--summary-json", str(mcap)], "other than the input")
    _fails(capsys, [str(bag), *off, "--out", str(bag.parent), "--force"], "contain the input")
    _fails(capsys, [str(bag), *off, "--out", str(bag), "--force"], "other than the input")
    _fails(capsys, [str(bag), *off, "--export-tum", str(bag)], "input")
    _fails(capsys, [str(bag), "--rerun", f"save:{bag / 'v.rrd'}"], "input folder")
    assert _snapshot(bag) == before


def test_force_replaces_only_a_bag_this_tool_wrote(bag, tmp_path, capsys):
    mine = tmp_path / "notes"
    mine.mkdir()
    (mine / "todo.txt").write_text("keep me")
    _fails(capsys, [str(bag), "--rerun", "off", "--out", str(mine), "--force"], "only a bag")
    assert (mine / "todo.txt").read_text() == "keep me"
    out = tmp_path / "est"
    assert main([str(bag), "--rerun", "off", "--out", str(out), "--quiet"]) == 0
    assert is_own_bag(out)
    assert main([str(bag), "--rerun", "off", "--out", str(out), "--force", "--quiet"]) == 0
    (out / "extra.txt").write_text("a user's file inside")
    _fails(capsys, [str(bag), "--rerun", "off", "--out", str(out), "--force"], "only a bag")
    assert (out / "extra.txt").exists()
    with pytest.raises(OutputError, match="not to exist"):
        check_output_dir(out, ())


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="no /dev/full")
def test_special_files_stay_special(bag, tmp_path, capsys):
    link = tmp_path / "view.rrd"
    link.symlink_to("/dev/full")  # a .rrd name that leads to the device
    (tmp_path / "tum").mkdir()
    (tmp_path / "tum" / "truth.tum").symlink_to("/dev/full")
    for argv in (
        ["--summary-json", "/dev/full"],
        ["--out", "/dev/full", "--force"],
        ["--rerun", f"save:{link}"],
        ["--export-tum", str(tmp_path / "tum")],
    ):
        rerun = [] if "--rerun" in argv else ["--rerun", "off"]
        _fails(capsys, [str(bag), *rerun, *argv], "")
    assert stat.S_ISCHR(os.stat("/dev/full").st_mode)
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    _fails(capsys, [str(fifo), "--rerun", "off"], "special file")  # never blocks reading it
    _fails(capsys, [str(bag), "--rerun", "off", "--summary-json", str(fifo)], "FIFO")


def test_output_errors_are_one_line(bag, tmp_path, capsys, monkeypatch):
    folder = tmp_path / "a_folder"
    folder.mkdir()
    _fails(capsys, [str(bag), "--rerun", "off", "--summary-json", str(folder)], "folder")
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    _fails(
        capsys,
        [str(bag), "--rerun", "off", "--summary-json", str(a_file / "no" / "s.json")],
        "Not a directory",
    )
    from imu_dcm.outputs import write as outputs

    # a read-only folder (root ignores permission bits, so the check is simulated)
    monkeypatch.setattr(outputs.os, "access", lambda *a, **k: False)
    _fails(
        capsys,
        [str(bag), "--rerun", "off", "--summary-json", str(tmp_path / "s.json")],
        "read-only",
    )
    monkeypatch.undo()

    def refuse(*a, **k):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(outputs.tempfile, "mkstemp", refuse)
    _fails(
        capsys,
        [str(bag), "--rerun", "off", "--summary-json", str(tmp_path / "s.json")],
        "PermissionError",
    )
    assert not (tmp_path / "s.json").exists()


def test_every_option_is_checked_before_any_output(bag, tmp_path, capsys):
    out, js = tmp_path / "est", tmp_path / "s.json"
    outs = ["--out", str(out), "--summary-json", str(js), "--export-tum", str(tmp_path / "tum")]
    _fails(capsys, [str(bag), *outs, "--rerun", "bogus"], "--rerun")
    (tmp_path / "a_file").write_text("x")
    _fails(
        capsys,
        [str(bag), *outs, "--rerun", f"save:{tmp_path / 'a_file' / 'nowhere' / 'v.rrd'}"],
        "Not a directory",
    )
    _fails(capsys, [str(bag), *outs, "--rerun", "off", "--truth-offset", "soon"], "--truth-offset")
    _fails(capsys, [str(bag), *outs, "--rerun", "off", "--bias", "1,2"], "bias")
    assert main([str(bag), *outs, "--rerun", "off", "--method", "rk45"]) == 2
    assert "argument --method" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file", "in"]  # nothing written


def test_export_tum_reads_back_against_the_closed_form_truth(bag, tmp_path, capsys):
    tum = tmp_path / "tum"
    assert main([str(bag), "--rerun", "off", "--bias", "none", "--export-tum", str(tum)]) == 0
    out_text = capsys.readouterr().out
    assert f"written    {tum / 'estimate.tum'}, {tum / 'truth.tum'}" in out_text
    est = np.loadtxt(tum / "estimate.tum")
    truth = np.loadtxt(tum / "truth.tum")
    t = np.arange(0, 1.0, 1 / 200)
    q_ref, _ = _coning(t)
    for rows in (est, truth):
        assert rows.shape == (200, 8)  # t x y z qx qy qz qw, every sample
        # stamps: seconds of the log's clock; float64 of 1.7e9 s resolves ~0.24 µs
        np.testing.assert_allclose(rows[:, 0] - T0_NS * 1e-9, t, rtol=0, atol=1e-6)
        np.testing.assert_array_equal(rows[:, 1:4], 0.0)  # attitude only: zero position
    ang_truth = (Rotation.from_quat(truth[:, 4:]) * Rotation.from_quat(q_ref).inv()).magnitude()
    assert np.max(ang_truth) < 1e-12  # written with 17 significant digits
    ang_est = (Rotation.from_quat(est[:, 4:]) * Rotation.from_quat(q_ref).inv()).magnitude()
    # magnus4 on a 10° cone at 200 Hz: y = Ω·dt = 0.063; drift far below 1e-3°
    assert np.degrees(np.max(ang_est)) < 1e-3


def _csv(tmp_path, text: bytes, name="log.csv") -> Path:
    p = tmp_path / "csvdir" / name
    p.parent.mkdir(exist_ok=True)
    p.write_bytes(text)
    return p


def test_convert_csv_bad_files_are_one_line(tmp_path, capsys):
    head = b"t,gx,gy,gz\n"
    good = head + b"0,0,0,0.1\n0.01,0,0,0.1\n0.02,0,0,0.1\n"
    args = [
        "--time-col",
        "t",
        "--time-unit",
        "s",
        "--gyro-cols",
        "gx,gy,gz",
        "--gyro-units",
        "rad/s",
    ]

    def run(csv: Path, pattern: str, *extra: str, out: Path | None = None) -> None:
        target = out or tmp_path / "bag"
        _fails(capsys, ["convert-csv", str(csv), str(target), *args, *extra], pattern)
        assert not (tmp_path / "bag").exists()

    run(_csv(tmp_path, head + b"0,0,0,0.1\n0.01,0,0\n"), "4 fields per row")  # ragged
    run(_csv(tmp_path, head + b"0,0,0,0.1\n0.01,0,zero,0\n"), "'zero' on line 3")
    run(_csv(tmp_path, good), "one character", "--delimiter", ";;")
    run(_csv(tmp_path, good), "one character", "--delimiter", "")
    run(_csv(tmp_path, b"t,gx,gy,gz\n0,0,\xff\xfe,0\n"), "UTF-8")
    run(_csv(tmp_path, b"t,gx,gy,gz," + b"h" * 200_000 + b"\n0,0,0,0,0\n"), "field")
    csv = _csv(tmp_path, good)
    before = csv.read_bytes()
    run(csv, "contain the input", "--force", out=csv.parent)  # would delete the CSV
    run(csv, "other than the input", "--force", out=csv)
    assert csv.read_bytes() == before
    assert main(["convert-csv", str(csv), str(tmp_path / "bag"), *args]) == 0
    assert is_own_bag(tmp_path / "bag")


def test_outputs_do_not_overwrite_each_other(bag, tmp_path, capsys):
    out = tmp_path / "est"
    _fails(
        capsys,
        [str(bag), "--rerun", "off", "--out", str(out), "--summary-json", str(out / "s.json")],
        "separate paths",
    )
    _fails(
        capsys,
        [
            str(bag),
            "--rerun",
            "off",
            "--summary-json",
            str(tmp_path / "t" / "truth.tum"),
            "--export-tum",
            str(tmp_path / "t"),
        ],
        "separate paths",
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in"]
    tum = tmp_path / "tum"  # a summary beside the TUM files is fine
    tum.mkdir()
    assert (
        main(
            [
                str(bag),
                "--rerun",
                "off",
                "--quiet",
                "--export-tum",
                str(tum),
                "--summary-json",
                str(tum / "summary.json"),
            ]
        )
        == 0
    )
    assert sorted(p.name for p in tum.iterdir()) == ["estimate.tum", "summary.json", "truth.tum"]


def test_a_log_file_named_inside_its_bag_folder_protects_the_folder(bag, capsys):
    before = _snapshot(bag)
    _fails(
        capsys,
        [str(bag / "bag.mcap"), "--rerun", "off", "--summary-json", str(bag / "metadata.yaml")],
        "input folder",
    )
    assert _snapshot(bag) == before

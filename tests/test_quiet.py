"""Quiet when healthy: a healthy log prints no ``warning:`` line (the reader's findings go to one
``notes`` line); every option that would be ignored is refused or said in one line; and
``python -m imu_dcm`` lists the commands. Driven as a user runs the commands."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
from conftest import REPO_ROOT, STRANGERS, assert_names, need_data

from imu_dcm.replay.__main__ import main

HEALTHY = ("px4_fmuv5_flight.ulg", "sample_px4_events.ulg", "ardupilot_sitl_plane_flight.BIN")
SHIPPED = REPO_ROOT / "replay" / "broad_07_undisturbed_fast_rotation_B"
TOP = REPO_ROOT / "replay" / "heavy_top_cusp_2000hz"


def _run(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(REPO_ROOT)}
    env.pop("DISPLAY", None)
    return subprocess.run(
        [sys.executable, "-m", *args], capture_output=True, text=True, env=env, timeout=120
    )


@pytest.mark.parametrize("name", HEALTHY)
def test_a_healthy_drone_log_prints_notes_and_no_warning(name):
    path = need_data(STRANGERS / name)
    run = _run("imu_dcm.replay", str(path), "--rerun", "off")
    assert run.returncode == 0, run.stderr
    assert "warning:" not in run.stderr + run.stdout
    (notes,) = [x for x in run.stdout.splitlines() if x.startswith("notes      ")]
    assert "used " in notes  # which gyro the reader took, said once


def test_the_shipped_trial_prints_no_warning():
    run = _run("imu_dcm.replay", str(SHIPPED), "--rerun", "off")
    assert run.returncode == 0 and "warning:" not in run.stderr + run.stdout


@pytest.mark.parametrize(
    ("argv", "facts"),  # the option refused, the modes it needs, the mode given
    [
        (["--rerun", "off", "--keep-viewer"], ("--keep-viewer", "serve", "--rerun off")),
        (["--rerun", "SAVE", "--realtime"], ("--realtime", "spawn", "serve", "--rerun save:")),
        (["--rerun", "off", "--realtime"], ("--realtime", "spawn", "serve", "--rerun off")),
    ],
)
def test_an_option_that_would_be_ignored_is_refused(tmp_path, capsys, argv, facts):
    rrd = tmp_path / "x.rrd"
    argv = [f"save:{rrd}" if a == "SAVE" else a for a in argv]
    assert main([str(TOP), *argv]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1
    assert_names(err, *facts)
    assert list(tmp_path.iterdir()) == []


def test_init_quat_beside_a_truth_is_said_in_one_line(capsys):
    assert main([str(TOP), "--rerun", "off", "--init-quat", "0,0,0.6,0.8"]) == 0
    said = [x for x in capsys.readouterr().err.splitlines() if "--init-quat" in x]
    assert len(said) == 1 and "starts from the truth's attitude" in said[0]
    assert (
        main([str(TOP), "--rerun", "off", "--init-quat", "0,0,0.6,0.8", "--truth-topic", "none"])
        == 0
    )
    assert "--init-quat" not in capsys.readouterr().err  # used: nothing to say


def test_python_m_imu_dcm_lists_the_commands():
    run = _run("imu_dcm")
    assert run.returncode == 0, run.stderr
    for command in (
        "imu_dcm.replay LOG",
        "replay info",
        "replay batch",
        "convert-csv",
        "imu_dcm.live",
        "data_synth",
    ):
        assert command in run.stdout, command
    wrong = _run("imu_dcm", "replay")
    assert wrong.returncode == 2
    assert_names(wrong.stderr, "'replay'", "python -m imu_dcm.replay")  # the word, the commands

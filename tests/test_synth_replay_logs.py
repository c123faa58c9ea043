"""The synthetic logs shipped under replay/ are what their COMMAND.txt makes.

Bytes can differ in the last bits between scipy/BLAS builds (the truth is an ODE solution), so the
check is on decoded values: identical stamps, truth within the simulator's own accuracy, and gyro
samples equal up to one quantization step where a step boundary falls between two builds.
"""

from __future__ import annotations

import shlex
from pathlib import Path

import numpy as np
import pytest

from data_synth.cli import main
from imu_dcm.logio import read_log

REPO_ROOT = Path(__file__).resolve().parents[1]

LOGS = ("heavy_top_cusp_2000hz", "heavy_top_wavy_noisy_400hz", "free_body_flip_100hz_delta")
PREFIX = ["python", "-m", "data_synth"]


@pytest.mark.parametrize("name", LOGS)
def test_shipped_log_is_reproduced_by_its_command(name, tmp_path, monkeypatch, capsys):
    shipped = REPO_ROOT / "replay" / name
    argv = shlex.split((shipped / "COMMAND.txt").read_text())
    assert argv[:3] == PREFIX and argv[argv.index("--out") + 1] == f"replay/{name}"
    # Run the same command line from a scratch folder: same relative --out, same metadata.
    (tmp_path / "replay").mkdir()
    monkeypatch.chdir(tmp_path)
    assert main(argv[3:]) == 0
    made, kept = read_log(tmp_path / "replay" / name), read_log(shipped)
    assert made.custom_data == kept.custom_data
    np.testing.assert_array_equal(made.imu.t_ns, kept.imu.t_ns)
    np.testing.assert_array_equal(made.truth.t_ns, kept.truth.t_ns)
    # Truth: DOP853 at 1e-12 tolerances; builds differ far below 1e-9.
    q_made, q_kept = made.truth.q_w_b, kept.truth.q_w_b
    assert np.max(np.abs(np.abs(np.sum(q_made * q_kept, axis=1)) - 1.0)) < 1e-9
    # Gyro: same noise stream (seeded); a quantized sample may sit one step away (1.065e-3 rad/s
    # in the noisy log) when the true rate lies within rounding distance of a step boundary.
    diff = np.abs(made.imu.omega_b - kept.imu.omega_b)
    assert np.max(diff) < 1.1e-3
    assert np.mean(diff > 1e-9) < 1e-3
    # The shipped logs stay small (issue: <= 5 MB each).
    assert sum(p.stat().st_size for p in shipped.iterdir()) <= 5 * 1024 * 1024

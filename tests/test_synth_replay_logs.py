"""The synthetic logs shipped under replay/ are exactly what their COMMAND.txt makes."""

from __future__ import annotations

import hashlib
import shlex
from pathlib import Path

import pytest

from data_synth.cli import main

REPO_ROOT = Path(__file__).resolve().parents[1]

LOGS = ("heavy_top_cusp_2000hz", "heavy_top_wavy_noisy_400hz", "free_body_flip_100hz_delta")
PREFIX = ["python", "-m", "data_synth"]


@pytest.mark.parametrize("name", LOGS)
def test_shipped_log_is_reproduced_byte_for_byte(name, tmp_path, monkeypatch, capsys):
    shipped = REPO_ROOT / "replay" / name
    argv = shlex.split((shipped / "COMMAND.txt").read_text())
    assert argv[:3] == PREFIX and argv[argv.index("--out") + 1] == f"replay/{name}"
    # Run the same command line from a scratch folder: same relative --out, same metadata.
    (tmp_path / "replay").mkdir()
    monkeypatch.chdir(tmp_path)
    assert main(argv[3:]) == 0
    for f in (f"{name}.mcap", "metadata.yaml"):
        made = hashlib.sha256((tmp_path / "replay" / name / f).read_bytes()).hexdigest()
        assert made == hashlib.sha256((shipped / f).read_bytes()).hexdigest(), f
    # The shipped logs stay small (issue: <= 5 MB each).
    assert sum(p.stat().st_size for p in shipped.iterdir()) <= 5 * 1024 * 1024

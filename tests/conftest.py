"""Shared test fixtures: where the real BROAD recordings are, and the repository root."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]
# The BROAD bags live beside the repository (../shared/data/broad); IMU_DCM_BROAD_DIR overrides.
BROAD_DIR = Path(
    os.environ.get("IMU_DCM_BROAD_DIR", REPO_ROOT.parent / "shared" / "data" / "broad")
)
BROAD_TRIALS = (
    "02_undisturbed_slow_rotation_B",
    "05_undisturbed_slow_rotation_with_breaks_B",
    "07_undisturbed_fast_rotation_B",
    "15_undisturbed_fast_translation_A",
    "21_undisturbed_fast_combined",
    "25_disturbed_tapping_B",
)


@pytest.fixture(scope="session")
def broad_dir() -> Path:
    """Folder holding the six BROAD bags; skips the test when it is not beside the repository."""
    if not all((BROAD_DIR / t / "metadata.yaml").is_file() for t in BROAD_TRIALS):
        pytest.skip("BROAD bags not found under ../shared/data/broad (set IMU_DCM_BROAD_DIR)")
    return BROAD_DIR


@pytest.fixture(scope="session")
def repo_root() -> Path:
    return REPO_ROOT

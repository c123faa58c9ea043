"""The six BROAD recordings (real IMU, optical truth): gyro-only replay with the bias removed
at rest must reach BROAD's movement phases within 6.0° mean RMS.

Reference figures (issue 4): an oracle that knows the annotated rest phase gets 5.6°, no bias
correction 32.9°. Movement intervals come from each bag's metadata (``custom_data``
``broad.movement_intervals_index``, first/last sample index, inclusive); sample k is stamped
``1700000000 s + k · 3.5 ms`` (BROAD's README). Skips when ../shared/data/broad is missing.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import BROAD_TRIALS

from imu_dcm.logio import read_custom_data
from imu_dcm.metrics import rms
from imu_dcm.replay import replay

pytestmark = [pytest.mark.broad, pytest.mark.slow]


def movement_rms_deg(result, bag) -> float:
    """RMS total error over the movement phases of a BROAD bag (samples with truth only)."""
    meta = read_custom_data(bag)
    intervals = json.loads(meta["broad.movement_intervals_index"])
    epoch_ns = 1_700_000_000_000_000_000
    period_ns = int(meta["broad.sample_period_ns"])
    k = (result.t_ns - epoch_ns) // period_ns
    inside = np.zeros(len(k), dtype=bool)
    for first, last in intervals:
        inside |= (k >= first) & (k <= last)
    err = result.error.total_deg[inside]
    return rms(err[np.isfinite(err)])


def test_broad_movement_rms_with_bias_auto(broad_dir):
    # Prints docs/benchmarks.md's BROAD table (run with -s). Both columns are measured here, in
    # one run.
    rows = []
    for trial in BROAD_TRIALS:
        auto = replay(broad_dir / trial, bias="auto")
        none = replay(broad_dir / trial, bias="none")
        # every bag starts with seconds of rest before the truth appears: rest is found there
        assert auto.bias.segments and auto.bias.segments[0].start_s == 0.0, trial
        rows.append(
            (
                trial,
                len(auto.bias.segments),
                movement_rms_deg(auto, broad_dir / trial),
                movement_rms_deg(none, broad_dir / trial),
            )
        )
    mean_auto = float(np.mean([r[2] for r in rows]))
    mean_none = float(np.mean([r[3] for r in rows]))
    print("\n| trial | rest segments | RMS, --bias auto | RMS, --bias none |")
    print("|---|---:|---:|---:|")
    for trial, nseg, a, n in rows:
        print(f"| {trial} | {nseg} | {a:.2f}° | {n:.2f}° |")
    print(f"| **mean** | | **{mean_auto:.2f}°** | {mean_none:.2f}° |")
    assert mean_auto <= 6.0, rows  # issue 4's target (the annotated-rest oracle: 5.6°)
    # without correction the 0.1–0.5 °/s biases dominate (issue 4 quotes 32.9°)
    assert mean_none > 3 * mean_auto, rows

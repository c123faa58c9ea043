"""Batch keeps kinds of truth apart: a table column, and one mean per kind in the summary line.

ArduPilot's SIM is the simulator's attitude (an independent reference); PX4's vehicle_attitude
is its own EKF's estimate (the strangers' README); a bag written without truth has none.
"""

from __future__ import annotations

import csv
import statistics

import numpy as np
from conftest import STRANGERS, need_data

from imu_dcm.logio.writers import StampedSeries, write_bag
from imu_dcm.replay.__main__ import main

LOGS = (
    "ardupilot_sitl_plane_flight.BIN",
    "ardupilot_sitl_plane_ground.BIN",
    "sample_px4_events.ulg",
)


def test_the_table_and_the_summary_separate_kinds_of_truth(tmp_path, capsys):
    paths = [STRANGERS / n for n in LOGS]
    need_data(*paths)
    t_ns = 10**9 + np.arange(500, dtype=np.int64) * 10_000_000
    plain = write_bag(tmp_path / "plain", imu=StampedSeries(t_ns, np.zeros((500, 3)), "imu"))
    table = tmp_path / "t.csv"
    code = main(["batch", *map(str, paths), str(plain), "--table", str(table), "--jobs", "1"])
    assert code == 0
    with open(table, newline="") as f:
        rows = {r["path"].rsplit("/", 1)[-1]: r for r in csv.DictReader(f)}
    kinds = {k: r["truth_kind"] for k, r in rows.items()}
    assert kinds == {
        "ardupilot_sitl_plane_flight.BIN": "independent reference",
        "ardupilot_sitl_plane_ground.BIN": "independent reference",
        "sample_px4_events.ulg": "the vehicle's own estimate",
        "plain": "none",
    }
    ref = [float(rows[n]["rms_error_deg"]) for n in LOGS[:2]]
    own = float(rows[LOGS[2]]["rms_error_deg"])
    out = capsys.readouterr().out
    assert (
        f"RMS error by kind of truth: independent reference, 2 logs: mean "
        f"{statistics.fmean(ref):.4g}°, median {statistics.median(ref):.4g}°; the vehicle's own "
        f"estimate, 1 log: mean {own:.4g}°, median {own:.4g}°"
    ) in out
    md = table.with_suffix(".md").read_text()
    assert "| log | truth |" in md and "| the vehicle's own estimate |" in md

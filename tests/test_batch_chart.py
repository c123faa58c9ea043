"""The batch chart stays readable with 30 logs: bars sorted by error and named, one colour per
log, the error axis fitted to the values. Driven through the batch command; the figure is then
rebuilt from the table it wrote and its axes inspected."""

from __future__ import annotations

import numpy as np
import pytest

from imu_dcm.logio.writers import StampedSeries, write_bag
from imu_dcm.replay.__main__ import main
from imu_dcm.replay.table import read_curves, read_table

N_LOGS, N = 30, 200  # 2 s at 100 Hz each


@pytest.fixture
def thirty(tmp_path):
    """30 still logs with truth; log k has a gyro bias about z of (k + 10) x 0.5 °/s, so its
    error grows as b t and the logs' RMS errors are ordered by k (and span a factor 3.9)."""
    t_ns = 10**9 + np.arange(N, dtype=np.int64) * 10_000_000
    q = np.tile([0.0, 0.0, 0.0, 1.0], (N, 1))
    paths = []
    for k in range(N_LOGS):
        w = np.tile([0.0, 0.0, np.radians(0.5 * (k + 10))], (N, 1))
        paths.append(
            write_bag(
                tmp_path / f"log{k:02d}",
                imu=StampedSeries(t_ns, w, "imu"),
                quaternions={"/ground_truth/orientation": StampedSeries(t_ns, q, "world")},
            )
        )
    return paths


def test_thirty_logs_are_sorted_named_coloured_and_fitted(thirty, tmp_path):
    pytest.importorskip("matplotlib")
    from imu_dcm.replay.batch_chart import chart_figure

    table = tmp_path / "t.csv"
    argv = ["batch", *map(str, thirty), "--table", str(table), "--jobs", "1", "--bias", "none"]
    assert main([*argv, "--mounting", "none"]) == 0
    assert table.with_suffix(".png").stat().st_size > 20_000
    rows = read_table(table)
    fig = chart_figure(rows, read_curves(table))
    bars_ax = fig.axes[0]
    ticks = sorted(bars_ax.get_yticklabels(), key=lambda t: -t.get_position()[1])
    # bars from the top: largest error first, i.e. log29 ... log00
    assert [t.get_text() for t in ticks] == [f"log{k:02d}" for k in reversed(range(N_LOGS))]
    bars = sorted(bars_ax.patches, key=lambda p: -p.get_y())  # top to bottom
    widths = [b.get_width() for b in bars]
    assert widths == sorted(widths, reverse=True) and len(widths) == N_LOGS
    colours = {tuple(np.round(b.get_facecolor(), 3)) for b in bars}
    assert len(colours) == N_LOGS  # no colour repeats
    lo, hi = bars_ax.get_xlim()
    largest = max(r.rms_error_deg for r in rows)
    assert bars_ax.get_xscale() == "linear"  # a factor 3.9, not decades
    assert lo == 0 and largest < hi <= 1.2 * largest

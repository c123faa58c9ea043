"""The chart of a batch replay: RMS error per log, and every log's error over time on one axis.

Drawn with matplotlib's object API onto an Agg canvas (no pyplot, no global backend change).
matplotlib is optional (``pip install 'imu_dcm[bench]'``): :func:`chart_available` says whether
it is installed.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from imu_dcm.outputs import claim_output, claimed_path
from imu_dcm.outputs.signatures import signature
from imu_dcm.replay.table import Curve, LogRow, short_names, summary_line

__all__ = ["INSTALL_HINT", "chart_available", "write_chart"]

INSTALL_HINT = "pip install 'imu_dcm[bench]' (or pip install matplotlib)"
#: Up to this many logs the top panel names each log; beyond, it shows the sorted RMS values.
MAX_NAMED = 40


def chart_available() -> bool:
    return importlib.util.find_spec("matplotlib") is not None


def write_chart(path: str | Path, rows: Sequence[LogRow], curves: dict[str, Curve]) -> Path:
    """Draw the batch chart to ``path`` (PNG, signed ``Software: imu_dcm ...`` in its metadata).

    Top: total RMS attitude error of each log, deg, largest first, each bar labelled with the
    log's name and value (failed logs and logs without truth last, said as such); a log scale
    only when the values span more than a factor 20, the axis fitted to them. Bottom: the total
    error over time of every log with a curve, deg, log scale, seconds since each log's first
    sample.
    """

    fig = chart_figure(rows, curves)
    claim = claim_output(path, "chart", what="the chart")  # new or this tool's own PNG
    with claimed_path(claim) as tmp:  # whole or not at all, signed in its PNG metadata
        fig.savefig(tmp, format="png", dpi=110, metadata={"Software": signature("batch chart")})
    return claim.path


def chart_figure(rows: Sequence[LogRow], curves: dict[str, Curve]):
    """The matplotlib ``Figure`` :func:`write_chart` saves (axes: the bars, then the curves)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    rows = sorted_rows(rows)
    names = short_names([r.path for r in rows])
    named = len(rows) <= MAX_NAMED
    top_h = 0.28 * len(rows) + 1.6 if named else 3.0
    fig = Figure(figsize=(10, top_h + 4.5), layout="constrained")
    FigureCanvasAgg(fig)
    ax_rms, ax_t = fig.subplots(2, 1, height_ratios=[top_h, 4.5])
    fig.suptitle(summary_line(rows), fontsize=9, wrap=True)
    colors = log_colors(len(rows))
    _rms_panel(ax_rms, rows, names, colors, named)
    _curves_panel(ax_t, rows, names, colors, curves)
    return fig


def sorted_rows(rows: Sequence[LogRow]) -> list[LogRow]:
    """Logs with an RMS error, largest first; then logs without truth; then failed logs."""

    def key(r: LogRow):
        if r.rms_error_deg is not None:
            return (0, -r.rms_error_deg)
        return (2 if r.failed else 1, 0.0)

    return sorted(rows, key=key)


def log_colors(n: int) -> list:
    """``n`` colours, all different: matplotlib's ten, then evenly spaced hues beyond ten (the
    bars, labelled with each log's name, are the legend of the curves below)."""
    if n <= 10:
        return [f"C{k}" for k in range(n)]
    from matplotlib import colormaps

    cmap = colormaps["turbo"]
    return [cmap(0.05 + 0.9 * k / (n - 1)) for k in range(n)]


def _rms_panel(ax, rows: Sequence[LogRow], names: list[str], colors: list[str], named: bool):
    """Top panel: one bar per log with its value or why it has none (``named``), or, for many
    logs, the sorted RMS values; log scale either way."""
    rms = np.array([np.nan if r.rms_error_deg is None else r.rms_error_deg for r in rows])
    good = rms[np.isfinite(rms) & (rms > 0)]
    floor = float(good.min()) / 3 if len(good) else 1e-3
    top = float(good.max()) if len(good) else 1.0
    if named:
        wide = len(good) > 1 and top / float(good.min()) > 20  # a log axis only for decades
        floor = floor if wide else 0.0
        _rms_bars(ax, rows, names, colors, rms, floor if wide else top * 0.01)
        if wide:
            ax.set_xscale("log")
            ax.set_xlim(floor, top * 2.5)  # room for the value labels, no more
        else:
            ax.set_xlim(0, top * 1.18)
    else:
        order = np.sort(good)
        ax.plot(np.arange(1, len(order) + 1), order, ".", ms=3)
        ax.set_xlabel(
            f"logs sorted by RMS error ({len(rows) - len(good)} failed or without truth not shown)"
        )
        ax.set_yscale("log")
        ax.set_ylim(floor, top * 3)
    ax.set_title("RMS attitude error per log, deg", fontsize=10, loc="left")
    ax.grid(True, which="major", alpha=0.3)


def _rms_bars(ax, rows, names, colors, rms, floor: float) -> None:
    """A bar per log with truth, labelled with its value; failed logs and logs without truth
    say so where their bar would be."""
    y = np.arange(len(rows))[::-1]
    has = np.isfinite(rms) & (rms > 0)
    ax.barh(y[has], rms[has], color=[c for c, h in zip(colors, has, strict=False) if h])
    for yi, r, v in zip(y, rows, rms, strict=False):
        if r.failed:
            ax.text(
                floor, yi, "  failed: " + r.error[:90], va="center", fontsize=7, color="firebrick"
            )
        elif not np.isfinite(v):
            ax.text(floor, yi, "  no truth", va="center", fontsize=7, color="gray")
        else:
            ax.text(v, yi, f" {v:.3g}°", va="center", fontsize=7)
    ax.set_yticks(y, names, fontsize=7)
    ax.set_ylim(-0.6, len(rows) - 0.4)


def _curves_panel(ax, rows, names, colors, curves: dict[str, Curve]) -> None:
    """Bottom panel: every log's error curve (log scale), a legend when there are few."""
    from matplotlib.collections import LineCollection

    segs, seg_colors, labels = [], [], []
    for k, (name, r) in enumerate(zip(names, rows, strict=False)):
        c = curves.get(r.path)
        if c is None or not len(c.t_s):
            continue
        t, e = np.asarray(c.t_s, float), np.asarray(c.error_deg, float)
        ok = np.isfinite(e) & (e > 0)
        if ok.sum() < 2:
            continue
        segs.append(np.column_stack([t[ok], e[ok]]))
        seg_colors.append(colors[k])
        labels.append(name)
    if segs:
        alpha = 0.9 if len(segs) <= 20 else max(0.15, 20 / len(segs))
        ax.add_collection(LineCollection(segs, colors=seg_colors, linewidths=1.0, alpha=alpha))
        allpts = np.concatenate(segs)
        ax.set_xlim(0, float(allpts[:, 0].max()) * 1.02 or 1.0)
        low = max(float(np.percentile(allpts[:, 1], 1)), float(allpts[:, 1].max()) * 1e-4)
        ax.set_ylim(low / 2, float(allpts[:, 1].max()) * 1.5)
        if len(segs) <= 12:
            from matplotlib.lines import Line2D

            handles = [Line2D([], [], color=c) for c in seg_colors]
            ax.legend(handles, labels, fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    else:
        ax.set_xlim(0, 1)
        ax.set_ylim(1e-3, 1)
        ax.text(
            0.5,
            0.5,
            "no log with an error curve",
            ha="center",
            va="center",
            transform=ax.transAxes,
            color="gray",
        )
    ax.set_yscale("log")
    ax.set_xlabel("time since the log's first sample, s")
    ax.set_ylabel("total attitude error, deg")
    colours = "" if len(segs) <= 12 else ", colours as in the bars above"
    ax.set_title(
        f"error over time, every log (largest error per time bin{colours})", fontsize=10, loc="left"
    )
    ax.grid(True, which="major", alpha=0.3)

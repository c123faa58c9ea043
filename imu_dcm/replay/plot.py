"""A picture of one replay (``--plot FILE.png|.svg``) and of several methods on one log
(``--compare`` with ``--plot``), drawn headless with matplotlib's Agg canvas.

Only :func:`check_plot` is light: it checks the path and that matplotlib is installed, before
the log is read. matplotlib is imported when a figure is drawn, never by a replay without
``--plot``.

The replay figure: top, the attitude error (total, inclination, heading, deg) over time (s since
the first gyro sample), the scored segments shaded, truth jumps and gyro gaps marked and named,
the statistics in a corner; bottom, the gyro rates as read (rad/s, gyro axes) with the rests
whose mean is the bias shaded. Long logs are drawn as per-pixel min/max envelopes (every spike
stays visible; a 1 h log draws as fast as a short one).
"""

from __future__ import annotations

import importlib.util
import os
from collections.abc import Mapping
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from imu_dcm.errors import InputError
from imu_dcm.outputs import claim_output, save_figure

__all__ = ["PLOT_EXTRA", "check_plot", "new_figure", "plot_compare", "plot_replay"]

#: What installs matplotlib for ``--plot``.
PLOT_EXTRA = "pip install 'imu_dcm[plot]'"
_FORMATS = (".png", ".svg")
#: Points per drawn line: the envelope of this many bins (two points each) replaces longer series.
_BINS = 2000
_ERROR_COLOURS = {"total": "black", "inclination": "tab:blue", "heading": "tab:orange"}
_AXIS_COLOURS = ("tab:red", "tab:green", "tab:blue")
_DPI = 110
_SCORED = "#e8f4e8"  # background of the scored segments


def check_plot(path: str, inputs, flag: str = "--plot"):
    """Check a figure path (``.png`` or ``.svg``, new or a figure of this tool's: the output
    rule of :mod:`imu_dcm.outputs`) and that matplotlib is installed; returns its claim, to
    pass to :func:`plot_replay` / :func:`plot_compare` as their ``path``.

    Raises
    ------
    InputError
        Another suffix, or matplotlib missing (naming the extra that installs it).
    OutputError
        An unsafe target or a file this tool did not write (:func:`imu_dcm.outputs.claim_output`).
    """
    suffix = os.path.splitext(path)[1].lower()
    if suffix not in _FORMATS:
        raise InputError(f"Expected {flag} FILE.png or FILE.svg, got {path!r}")
    if importlib.util.find_spec("matplotlib") is None:
        raise InputError(f"Expected matplotlib for {flag}, got none installed: {PLOT_EXTRA}")
    return claim_output(path, "figure", inputs, what=f"{flag} file")


def new_figure(width_in: float, height_in: float):
    """A headless matplotlib figure, inches (matplotlib, an optional extra, loads here)."""
    import matplotlib

    matplotlib.use("Agg", force=False)  # headless; a figure never opens a window
    from matplotlib.figure import Figure

    return Figure(figsize=(width_in, height_in), dpi=_DPI, layout="constrained")


def envelope(t: NDArray, y: NDArray, bins: int = _BINS) -> tuple[NDArray, NDArray]:
    """``(t, y)`` thinned for drawing: per time bin, its min and max (NaN kept as breaks).

    Series of at most ``2 · bins`` points come back unchanged.
    """
    n = len(t)
    if n <= 2 * bins:
        return t, y
    edges = np.linspace(0, n, bins + 1).astype(np.int64)
    starts = edges[:-1]
    with np.errstate(invalid="ignore"):
        yy = np.where(np.isfinite(y), y, np.nan)
        lo = np.fmin.reduceat(yy, starts)
        hi = np.fmax.reduceat(yy, starts)
    tt = np.repeat(t[starts], 2)
    out = np.empty(2 * bins)
    out[0::2], out[1::2] = lo, hi
    return tt, out


def _log_name(path: str) -> str:
    """The log's name: its file, or ``folder/file`` for a file of a bag folder."""
    p = Path(str(path).rstrip("/"))
    if (p.parent / "metadata.yaml").is_file():
        return f"{p.parent.name}/{p.name}"
    return p.name


def _title(s) -> str:
    name = _log_name(s.path)
    truth = s.truth_topic or "no truth"
    if s.truth_estimate_of:
        truth += f" ({s.truth_estimate_of})"
    return f"{name}: {s.method} against {truth}"


def _stats_text(ev: dict) -> str:
    rows = []
    for key, label in (("total", "total"), ("inclination", "incl."), ("heading", "heading")):
        st, d = ev[f"{key}_deg"], ev["drift"][key]
        rows.append(
            f"{label:8s} RMS {st['rms']:6.2f}°  p95 {st['p95']:6.2f}°  max {st['max']:6.2f}°  "
            f"drift {d['rate_deg_h']:+8.1f} °/h"
        )
    chk = ev["bias_check"]
    if chk["doubtful"]:
        rows.append(f"bias DOUBTFUL: residual drift {chk['ratio']:.0%} of the bias removed")
    return "\n".join(rows)


def _mark_events(ax, s, label: bool) -> None:
    """Truth jumps (red lines, named) and gyro gaps (grey bands) on ``ax``."""
    for j in s.truth_jumps:
        ax.axvline(j["t0_s"], color="tab:red", lw=1.0, ls="--")
        if label:
            ax.annotate(  # low on the axes: the statistics and the legend hold the top
                f"truth jump {j['truth_deg']:.0f}°",
                (j["t0_s"], 0.02),
                xycoords=("data", "axes fraction"),
                xytext=(-3, 0),
                textcoords="offset points",
                va="bottom",
                ha="right",
                fontsize=8,
                color="tab:red",
                rotation=90,
            )
    for t0, length in s.gaps:
        ax.axvspan(t0, t0 + length, color="0.5", alpha=0.35, lw=0)
        if label:
            ax.annotate(
                f"gyro gap {length:.2g} s",
                (t0 + length, 0.5),
                xycoords=("data", "axes fraction"),
                xytext=(2, 0),
                textcoords="offset points",
                va="center",
                fontsize=8,
                color="0.3",
                rotation=90,
            )


def _scored_spans(result) -> list[tuple[float, float]]:
    s = result.summary
    if s.scored_segments:
        return [(x["start_s"], x["end_s"]) for x in s.scored_segments if x["samples"]]
    has = np.isfinite(result.error.total_deg)
    if not has.any():
        return []
    k = np.flatnonzero(has)
    return [(float(result.t_s[k[0]]), float(result.t_s[k[-1]]))]


def _error_panel(ax, result) -> None:
    s, t = result.summary, result.t_s
    for a, b in _scored_spans(result):
        ax.axvspan(a, b, color=_SCORED, lw=0, zorder=0)
    err = result.error
    for key, y in (  # total first: it bounds the other two, so its peaks stay in view
        ("total", err.total_deg),
        ("inclination", err.inclination_deg),
        ("heading", err.heading_deg),
    ):
        ax.plot(*envelope(t, y), color=_ERROR_COLOURS[key], lw=0.8, label=key)
    ax.axvspan(np.nan, np.nan, color=_SCORED, label="scored")
    _mark_events(ax, s, label=True)
    ax.set_ylabel("attitude error (°)")
    top = np.nanmax(err.total_deg) if np.isfinite(err.total_deg).any() else 1.0
    ax.set_ylim(0, 1.3 * top)  # head room for the statistics and the legend
    if s.evaluation:
        ax.text(
            0.005,
            0.98,
            _stats_text(s.evaluation),
            transform=ax.transAxes,
            va="top",
            ha="left",
            family="monospace",
            fontsize=8,
            bbox={"boxstyle": "round", "fc": "white", "ec": "0.7", "alpha": 0.9},
        )
        ax.legend(loc="upper right", fontsize=8, ncols=4)
    else:
        ax.text(0.5, 0.5, "not scored: no truth", transform=ax.transAxes, ha="center")
    ax.grid(alpha=0.3)


def _gyro_panel(ax, result) -> None:
    s, t = result.summary, result.t_s
    for seg in s.bias_segments:
        ax.axvspan(seg["start_s"], seg["end_s"], color="gold", alpha=0.35, lw=0)
    for i, axis in enumerate("xyz"):
        ax.plot(*envelope(t, result.omega_raw_b[:, i]), color=_AXIS_COLOURS[i], lw=0.6,
                label=f"ω {axis}")  # fmt: skip
    _mark_events(ax, s, label=False)
    if s.bias_segments:
        ax.axvspan(np.nan, np.nan, color="gold", alpha=0.35, label="rest (bias)")
    ax.legend(loc="upper right", fontsize=8, ncols=4)
    ax.set_ylabel("gyro rate as read (rad/s)")
    ax.set_xlabel("time since the first gyro sample (s)")
    ax.grid(alpha=0.3)


def plot_replay(result, path: str | os.PathLike) -> Path:
    """Draw one replay (:class:`imu_dcm.replay.summary.ReplayResult`) to ``path`` (.png/.svg).

    Written whole or not at all (:func:`imu_dcm.outputs.save_figure`); returns the path.
    """
    fig = new_figure(12.0, 7.0)
    top, bottom = fig.subplots(2, 1, sharex=True, height_ratios=(3, 2))
    _error_panel(top, result)
    _gyro_panel(bottom, result)
    t = result.t_s
    bottom.set_xlim(float(t[0]), float(t[-1]))
    fig.suptitle(_title(result.summary), fontsize=11)
    return save_figure(fig, path)


def binned_rms(t: NDArray, y: NDArray, bins: int) -> tuple[NDArray, NDArray]:
    """Bin centres and the RMS of the finite ``y`` in each of ``bins`` equal time bins (NaN
    where a bin holds none)."""
    edges = np.linspace(t[0], t[-1], bins + 1)
    k = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, bins - 1)
    ok = np.isfinite(y)
    sq = np.bincount(k[ok], weights=y[ok] ** 2, minlength=bins)
    n = np.bincount(k[ok], minlength=bins)
    with np.errstate(invalid="ignore", divide="ignore"):
        return 0.5 * (edges[:-1] + edges[1:]), np.sqrt(sq / n)


def plot_compare(result, errors: Mapping[str, NDArray], path: str | os.PathLike) -> Path:
    """Draw the total error of every method of a ``--compare`` run on one log.

    ``errors`` maps each method's name to its total error, deg, on ``result.t_s`` (NaN where
    unscored); ``result`` is the first method's replay (for the title, events and time axis).
    Each line is the error's RMS over 400 equal time bins, so that methods whose errors
    oscillate over each other stay apart; a log scale when the methods' RMS differ by over 30x.
    """
    fig = new_figure(12.0, 5.5)
    ax = fig.subplots()
    t = result.t_s
    for a, b in _scored_spans(result):
        ax.axvspan(a, b, color=_SCORED, lw=0, zorder=0)
    overall = []
    for name, y in errors.items():
        finite = y[np.isfinite(y)]
        rms = float(np.sqrt(np.mean(finite**2))) if finite.size else float("nan")
        overall.append(rms)
        ax.plot(*binned_rms(t, y, 400), lw=1.2, label=f"{name} (RMS {rms:.3g}°)")
    _mark_events(ax, result.summary, label=True)
    good = [r for r in overall if np.isfinite(r) and r > 0]
    if good and max(good) > 30 * min(good):
        ax.set_yscale("log")
    else:
        ax.set_ylim(bottom=0)
    ax.set_ylabel(f"total attitude error, RMS per {(t[-1] - t[0]) / 400:.2g} s (°)")
    ax.set_xlabel("time since the first gyro sample (s)")
    ax.set_xlim(float(t[0]), float(t[-1]))
    ax.legend(loc="upper left", fontsize=8)
    ax.grid(alpha=0.3, which="both")
    s = result.summary
    fig.suptitle(
        f"{_log_name(s.path)}: methods against {s.truth_topic or 'no truth'}",
        fontsize=11,
    )
    return save_figure(fig, path)

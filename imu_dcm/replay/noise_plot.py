"""The Allan plot of ``imu-dcm-replay noise --plot``: the deviation of each axis (log-log) with
the fitted lines of the three terms, drawn headless (matplotlib's Agg canvas)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from imu_dcm.gyro.allan import B_FACTOR
from imu_dcm.outputs import save_figure
from imu_dcm.replay.plot import new_figure

__all__ = ["plot_allan"]

_COLOURS = ("tab:red", "tab:green", "tab:blue")


def plot_allan(report, path: str | os.PathLike, name: str) -> Path:
    """Draw ``report`` (:class:`imu_dcm.replay.noise_cli.NoiseReport`) to ``path``.

    Per axis: the Allan deviation (rad/s) against τ (s), the −½ line ``N/√τ``, the floor
    ``0.664 B`` and the +½ line ``K √(τ/3)`` (dashed where the record does not reach it), each
    read-off point marked.
    """
    fig = new_figure(9.0, 6.5)
    ax = fig.subplots()
    for axis, f, colour in zip("xyz", report.fits, _COLOURS, strict=True):
        tau = f.tau_s
        ax.loglog(tau, f.adev, "o-", ms=3, lw=1.2, color=colour, label=f"gyro {axis}")
        ax.loglog(tau, f.N.value / np.sqrt(tau), ":", lw=0.9, color=colour)
        walk = "--" if f.K.reached else (0, (1, 4))  # dotted sparse: only a bound
        ax.loglog(tau, f.K.value * np.sqrt(tau / 3.0), ls=walk, lw=0.9, color=colour)
        ax.axhline(B_FACTOR * f.B.value, color=colour, lw=0.6, alpha=0.5)
        for term, y in ((f.N, f.N.value / np.sqrt(f.N.tau_s)), (f.B, B_FACTOR * f.B.value)):
            ax.plot(term.tau_s, y, "s", ms=7, mfc="none", color=colour)
        ax.plot(f.K.tau_s, f.K.value * np.sqrt(f.K.tau_s / 3.0), "^", ms=7, mfc="none",
                color=colour)  # fmt: skip
    lo = min(float(np.min(f.adev)) for f in report.fits)
    hi = max(float(np.max(f.adev)) for f in report.fits)
    ax.set_ylim(lo / 3.0, hi * 3.0)
    ax.plot([], [], "k:", lw=0.9, label="N/√τ (angle random walk, slope −½)")
    ax.plot([], [], "k-", lw=0.6, alpha=0.5, label="0.664 B (bias instability floor)")
    ax.plot([], [], "k--", lw=0.9, label="K√(τ/3) (rate random walk, slope +½)")
    ax.plot([], [], "ks", mfc="none", label="where N and B are read")
    ax.plot([], [], "k^", mfc="none", label="where K is read")
    ax.legend(loc="upper right", fontsize=8)
    ax.set_xlabel("cluster time τ (s)")
    ax.set_ylabel("Allan deviation σ(τ) (rad/s)")
    ax.grid(alpha=0.3, which="both")
    stretch = "whole log" if report.whole else f"rest {report.start_s:.1f}..{report.end_s:.1f} s"
    fig.suptitle(
        f"{name}: {report.topic} at {report.rate_hz:.0f} Hz, {stretch} "
        f"({report.samples / report.rate_hz:.0f} s)",
        fontsize=11,
    )
    return save_figure(fig, path)

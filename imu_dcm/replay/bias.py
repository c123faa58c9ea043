"""Gyro bias from rest: find the still segments of a log and estimate the bias in each.

A gyro at rest measures its bias plus noise. A sample is *at rest* when it lies in a window of
at least ``min_duration_s`` (0.5 s) whose mean rate magnitude is below ``max_rate_rad_s`` and
whose per-axis standard deviation is below ``max_std_rad_s``. Consecutive rest samples form a
rest segment; the bias of a segment is the mean rate over it, leaving out one window next to
each motion (windows that straddle a slow start of motion still pass the thresholds). The bias applied to a sample is
that of the latest rest segment that began at or before it (so the estimate is *updated at each
rest*); samples before the first rest use the first segment's bias.

Conventions: ``omega_b`` (N, 3) body rate in body axes, rad/s; ``t_s`` (N,) seconds,
increasing. Bias vectors are in the same frame and unit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imu_dcm.errors import InputError

__all__ = ["BiasEstimate", "RestConfig", "RestSegment", "detect_rest", "estimate_bias"]


@dataclass(frozen=True)
class RestConfig:
    """Thresholds of the rest detector.

    Attributes
    ----------
    min_duration_s : shortest rest that counts, s (default 0.5).
    max_rate_rad_s : largest magnitude of the window-mean rate, rad/s (default 0.035 ≈ 2 °/s;
        above the largest MEMS biases seen, far below deliberate motion).
    max_std_rad_s : largest per-axis standard deviation in the window, rad/s (default 0.01 ≈
        0.6 °/s; 2–5x the noise of a consumer gyro at a few hundred Hz).
    """

    min_duration_s: float = 0.5
    max_rate_rad_s: float = 0.035
    max_std_rad_s: float = 0.01


@dataclass(frozen=True)
class RestSegment:
    """One rest segment: sample indices ``[start, stop)``, times (s) and its bias (rad/s)."""

    start: int
    stop: int
    start_s: float
    end_s: float
    bias_rad_s: tuple[float, float, float]


@dataclass(frozen=True)
class BiasEstimate:
    """Bias applied at each sample and the rest segments it came from.

    Attributes
    ----------
    bias_b : float64 (N, 3) — bias subtracted from each sample, body axes, rad/s.
    segments : the rest segments found (empty when none).
    mode : "auto", "none" or "fixed".
    """

    bias_b: NDArray[np.float64]
    segments: tuple[RestSegment, ...]
    mode: str


def _window_samples(t_s: NDArray, duration_s: float) -> int:
    dt = float(np.median(np.diff(t_s))) if len(t_s) > 1 else 1.0
    return max(2, int(np.ceil(duration_s / dt)))


def detect_rest(omega_b: ArrayLike, t_s: ArrayLike, config: RestConfig | None = None) -> NDArray:
    """Boolean mask (N,) of samples at rest (see the module docstring for the rule).

    Parameters
    ----------
    omega_b : array_like, shape (N, 3)
        Body rates, rad/s.
    t_s : array_like, shape (N,)
        Sample times, s, increasing.
    config : RestConfig, optional
    """
    cfg = config or RestConfig()
    w = np.asarray(omega_b, dtype=float)
    t = np.asarray(t_s, dtype=float)
    if w.ndim != 2 or w.shape[1] != 3 or len(t) != len(w):
        raise InputError(f"Expected omega_b (N, 3) and t_s (N,), got {w.shape} and {t.shape}")
    n = len(w)
    win = _window_samples(t, cfg.min_duration_s)
    rest = np.zeros(n, dtype=bool)
    if n < win:
        return rest
    c1 = np.concatenate([np.zeros((1, 3)), np.cumsum(w, axis=0)])
    c2 = np.concatenate([np.zeros((1, 3)), np.cumsum(w * w, axis=0)])
    mean = (c1[win:] - c1[:-win]) / win  # window starting at i: samples [i, i + win)
    var = np.maximum((c2[win:] - c2[:-win]) / win - mean * mean, 0.0)
    still = (np.linalg.norm(mean, axis=1) < cfg.max_rate_rad_s) & np.all(
        var < cfg.max_std_rad_s**2, axis=1
    )
    # a sample is at rest when any still window covers it: spread each still start over win
    cover = np.zeros(n + 1, dtype=np.int64)
    starts = np.flatnonzero(still)
    np.add.at(cover, starts, 1)
    np.add.at(cover, starts + win, -1)
    rest[:] = np.cumsum(cover[:-1]) > 0
    return rest


def _segments(mask: NDArray[np.bool_]) -> list[tuple[int, int]]:
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1).tolist(), np.flatnonzero(edges == -1).tolist()))


def estimate_bias(
    omega_b: ArrayLike,
    t_s: ArrayLike,
    mode: str | ArrayLike = "auto",
    config: RestConfig | None = None,
) -> BiasEstimate:
    """The gyro bias to subtract at each sample.

    Parameters
    ----------
    omega_b : array_like, shape (N, 3)
        Body rates, rad/s (all samples, also those without truth: rest is found everywhere).
    t_s : array_like, shape (N,)
        Sample times, s, increasing.
    mode : "auto", "none" or array_like (3,)
        ``"auto"``: from rest segments, updated at each one (zero if there is no rest);
        ``"none"``: zero; a vector: that constant bias in rad/s.
    config : RestConfig, optional
        Rest detector thresholds (auto only).

    Returns
    -------
    BiasEstimate
    """
    w = np.asarray(omega_b, dtype=float)
    t = np.asarray(t_s, dtype=float)
    n = len(w)
    if isinstance(mode, str) and mode == "none":
        return BiasEstimate(np.zeros((n, 3)), (), "none")
    if not isinstance(mode, str):
        b = np.asarray(mode, dtype=float)
        if b.shape != (3,) or not np.all(np.isfinite(b)):
            raise InputError(f"Expected a bias of 3 finite values in rad/s, got {mode!r}")
        return BiasEstimate(np.broadcast_to(b, (n, 3)).copy(), (), "fixed")
    if mode != "auto":
        raise InputError(f"Expected bias 'auto', 'none' or x,y,z in rad/s, got {mode!r}")
    cfg = config or RestConfig()
    mask = detect_rest(w, t, cfg)
    trim = _window_samples(t, cfg.min_duration_s)
    segs = []
    for a, b in _segments(mask):
        # Windows that straddle the start of a slow motion still pass the thresholds: leave
        # out one window next to motion (not at the ends of the log) when enough remains.
        lo = a + trim if a > 0 else a
        hi = b - trim if b < n else b
        if hi - lo < trim:
            lo, hi = a + (b - a) // 4, b - (b - a) // 4
        bias = w[lo:hi].mean(axis=0)
        segs.append(RestSegment(a, b, float(t[a]), float(t[b - 1]), tuple(bias.tolist())))
    bias_b = np.zeros((n, 3))
    if segs:
        starts = np.array([s.start for s in segs])
        values = np.array([s.bias_rad_s for s in segs])
        k = np.clip(np.searchsorted(starts, np.arange(n), side="right") - 1, 0, len(segs) - 1)
        bias_b = values[k]
    return BiasEstimate(bias_b, tuple(segs), "auto")

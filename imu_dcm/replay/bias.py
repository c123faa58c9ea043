"""Gyro bias from rest: the bias of each still segment of a log, applied sample by sample.

Rest segments come from :func:`imu_dcm.rest.detect_rest` (re-exported here with
:class:`~imu_dcm.rest.RestConfig`). The bias of a segment is the mean rate over it, leaving out
one window next to each motion (windows that straddle a slow start of motion still pass the
thresholds). The bias applied to a sample is that of the latest rest segment that began at or
before it (so the estimate is *updated at each rest*); samples before the first rest use the
first segment's bias.

Conventions: ``omega_b`` (N, 3) body rate in body axes, rad/s; ``t_s`` (N,) seconds,
increasing. Bias vectors are in the same frame and unit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imu_dcm.errors import InputError
from imu_dcm.rest import RestConfig, detect_rest, runs, window_samples

__all__ = ["BiasEstimate", "RestConfig", "RestSegment", "detect_rest", "estimate_bias"]


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
    trim = window_samples(t, cfg.min_duration_s)
    segs = []
    for a, b in runs(mask):
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

"""Gyro bias from rest: the bias of each still segment of a log, applied sample by sample.

Rest segments come from :func:`imu_dcm.rest.detect_rest` (re-exported here with
:class:`~imu_dcm.rest.RestConfig`). The bias of a segment is the mean rate over it, leaving out
one window next to each motion (windows that straddle a slow start of motion still pass the
thresholds). Where the log has an accelerometer, it confirms the stillness (see
:mod:`imu_dcm.rest`). The bias applied to a sample follows :data:`BIAS_RULE`:

* ``"latest"``: that of the latest rest segment that began at or before it (the estimate is
  *updated at each rest*); samples before the first rest use the first segment's bias;
* ``"interpolate"``: linear in time between the middles of the two rest segments around it
  (replay is offline, so the later rest is known), constant before the first and after the last.

Both were measured on the six BROAD trials (docs/replay.md); the better one is the default.

Conventions: ``omega_b`` (N, 3) body rate in body axes, rad/s; ``t_s`` (N,) seconds,
increasing. Bias vectors are in the same frame and unit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imu_dcm.errors import InputError
from imu_dcm.rest import RestConfig, detect_rest, explain_no_rest, runs, window_samples

__all__ = [
    "BIAS_RULES",
    "BiasEstimate",
    "RestConfig",
    "RestSegment",
    "detect_rest",
    "estimate_bias",
]

#: How the bias between rests is applied, and the default (measured, see the module docstring).
BIAS_RULES = ("latest", "interpolate")
BIAS_RULE = "interpolate"


@dataclass(frozen=True)
class RestSegment:
    """One rest segment: sample indices ``[start, stop)``, times (s) and its bias (rad/s).

    ``lo``, ``hi``: the samples ``[lo, hi)`` whose mean is the bias.
    """

    start: int
    stop: int
    start_s: float
    end_s: float
    bias_rad_s: tuple[float, float, float]
    lo: int = 0
    hi: int = 0


@dataclass(frozen=True)
class BiasEstimate:
    """Bias applied at each sample and the rest segments it came from.

    Attributes
    ----------
    bias_b : float64 (N, 3) — bias subtracted from each sample, body axes, rad/s.
    segments : the rest segments found (empty when none).
    mode : "auto", "none" or "fixed".
    confirmed : True when an accelerometer confirmed the stillness of the rests.
    no_rest : why no rest was found ("" when found, or not "auto").
    """

    bias_b: NDArray[np.float64]
    segments: tuple[RestSegment, ...]
    mode: str
    confirmed: bool = False
    no_rest: str = ""


def estimate_bias(
    omega_b: ArrayLike,
    t_s: ArrayLike,
    mode: str | ArrayLike = "auto",
    config: RestConfig | None = None,
    accel_b: ArrayLike | None = None,
    rule: str | None = None,
) -> BiasEstimate:
    """The gyro bias to subtract at each sample.

    Parameters
    ----------
    omega_b : array_like, shape (N, 3)
        Body rates, rad/s (all samples, also those without truth: rest is found everywhere).
    t_s : array_like, shape (N,)
        Sample times, s, increasing.
    mode : "auto", "none" or array_like (3,)
        ``"auto"``: from rest segments (zero if there is no rest); ``"none"``: zero; a vector:
        that constant bias in rad/s.
    config : RestConfig, optional
        Rest detector thresholds (auto only).
    accel_b : array_like, shape (N, 3), optional
        Accelerometer on the same rows, m/s², finite: confirms stillness (auto only).
    rule : "latest" or "interpolate", optional
        How the bias between rests is applied (default :data:`BIAS_RULE`).

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
    rule = rule or BIAS_RULE
    if rule not in BIAS_RULES:
        raise InputError(f"Expected a bias rule in {BIAS_RULES}, got {rule!r}")
    cfg = config or RestConfig()
    segs = _rest_segments(w, t, cfg, accel_b)
    if not segs:
        why = explain_no_rest(w, t, cfg, accel_b)
        return BiasEstimate(np.zeros((n, 3)), (), "auto", accel_b is not None, why)
    return BiasEstimate(_bias_at(segs, t, rule), tuple(segs), "auto", accel_b is not None)


def _rest_segments(
    w: NDArray, t: NDArray, cfg: RestConfig, accel_b: ArrayLike | None
) -> list[RestSegment]:
    n = len(w)
    mask = detect_rest(w, t, cfg, accel_b)
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
        segs.append(RestSegment(a, b, float(t[a]), float(t[b - 1]), tuple(bias.tolist()), lo, hi))
    return segs


def _bias_at(segs: list[RestSegment], t: NDArray, rule: str) -> NDArray[np.float64]:
    """The bias at every sample from the rest segments, by ``rule``."""
    values = np.array([s.bias_rad_s for s in segs])
    if rule == "interpolate":
        mid = np.array([0.5 * (t[s.lo] + t[s.hi - 1]) for s in segs])
        return np.stack([np.interp(t, mid, values[:, k]) for k in range(3)], axis=1)
    starts = np.array([s.start for s in segs])
    k = np.clip(np.searchsorted(starts, np.arange(len(t)), side="right") - 1, 0, len(segs) - 1)
    return values[k]

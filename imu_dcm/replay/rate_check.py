"""Does the truth's rotation rate follow the gyro's? The body rate implied by the truth against
the gyro, frame-free.

* :func:`check_truth` — the rate norms (frame-free, so a constant mounting rotation does not
  matter) are correlated over time shifts of up to ±:data:`MAX_SHIFT_S`; the best shift, its
  correlation and the residual rate error are returned (:class:`TruthCheck`). A truth that does
  not follow the gyro (correlation below :data:`MIN_CORRELATION`, or, when a rate norm hardly
  varies and cannot be correlated, a still truth under a clearly turning gyro) is not the IMU's
  attitude: wheel odometry in ``base_link`` under an IMU that also tilts, or another body's pose.
* :func:`rate_grid` — the gyro's and the truth's rotations over the steps of one time grid (the
  mounting estimate's input); :func:`integrated_rate` — the gyro's turn up to given stamps.

Conventions: ``q_w_b`` ``[x, y, z, w]``; rates rad/s; ``t_ns`` int64 stamps.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from imu_dcm._kernels.calls import integrated_rate as kernel_integrated_rate
from imu_dcm.arrays import median_diff, row_finite, row_norm
from imu_dcm.gyro.resample import slerp_truth, step_rotvecs

__all__ = [
    "MAX_SHIFT_S",
    "MIN_CORRELATION",
    "STILL_RAD_S",
    "RateGrid",
    "TruthCheck",
    "check_truth",
    "integrated_rate",
    "lagged_correlation",
    "rate_grid",
]

#: A truth whose rate norm correlates less than this with the gyro's does not follow it.
MIN_CORRELATION = 0.6
#: Time shifts searched between truth and gyro, s (each way).
MAX_SHIFT_S = 0.5
#: Below this spread of the rate norm (rad/s) a series is taken as still.
STILL_RAD_S = 0.05


@dataclass(frozen=True)
class TruthCheck:
    """How well the truth's rotation rate follows the gyro's.

    Attributes
    ----------
    checked : bool — False when there was too little overlap or motion to tell.
    follows : bool — the truth moves with the gyro (True when unchecked: no evidence against).
    shift_s : float or None — time shift to add to the truth stamps that best aligns the rates.
    correlation : float or None — Pearson correlation of the rate norms at ``shift_s``.
    residual_rad_s : float or None — RMS of (gyro − truth) rate norm at ``shift_s``, rad/s.
    gyro_rms_rad_s : float or None — RMS of the gyro rate norm over the same samples, rad/s.
    """

    checked: bool
    follows: bool
    shift_s: float | None = None
    correlation: float | None = None
    residual_rad_s: float | None = None
    gyro_rms_rad_s: float | None = None

    def describe(self) -> str:
        """One clause for a person: shift, correlation and residual."""
        if not self.checked:
            return "too little overlap or motion to compare the rates"
        if self.correlation is None:
            return (
                f"rate norms nearly constant: residual {self.residual_rad_s:.3f} rad/s "
                f"(gyro RMS {self.gyro_rms_rad_s:.3f} rad/s)"
            )
        return (
            f"rate-norm correlation {self.correlation:.2f} at a shift of "
            f"{self.shift_s * 1e3:+.1f} ms, residual {self.residual_rad_s:.3f} rad/s "
            f"(gyro RMS {self.gyro_rms_rad_s:.3f} rad/s)"
        )


def lagged_correlation(
    g: NDArray[np.float64], h: NDArray[np.float64], valid: NDArray[np.bool_], lags: int
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Pearson correlation of ``g[i + k]`` with ``h[i]`` over the valid ``i``, k = -lags..lags.

    Each lag's six pair sums (count, Σa, Σa², Σb, Σb², Σab) of the series centred on their
    means (the correlation does not change, and the sums keep their digits): the sums over
    ``h``'s rows alone are its whole sums less the at most ``lags`` rows a lag leaves out at
    the ends, and so are those over ``g``'s rows when every row is valid; the products are
    one dot product per lag (three with invalid rows). Linear in the series for the few lags
    searched. Returns (correlation (2 lags + 1,), 0 where a series is constant; the number of
    pairs per lag).
    """
    n = len(g)
    v = valid.astype(float)
    every = bool(valid.all())
    gc = g - (float(np.mean(g[valid])) if valid.any() else 0.0)
    hc = np.where(valid, h - (float(np.mean(h[valid])) if valid.any() else 0.0), 0.0)
    gg, hh = gc * gc, hc * hc
    whole = {name: float(np.sum(x)) for name, x in (("v", v), ("h", hc), ("hh", hh))}
    if every:
        whole.update(g=float(np.sum(gc)), gg=float(np.sum(gg)))
    sums = np.zeros((2 * lags + 1, 6))  # count, Σa, Σa², Σb, Σb², Σab
    for j, k in enumerate(range(-lags, lags + 1)):
        if abs(k) >= n:
            continue
        i0, i1 = max(-k, 0), n - max(k, 0)  # h's rows i; g's rows i + k
        a = slice(i0 + k, i1 + k)

        def kept(name, x, lo, hi):
            return whole[name] - float(np.sum(x[:lo])) - float(np.sum(x[hi:]))

        if every:
            sa, saa = kept("g", gc, i0 + k, i1 + k), kept("gg", gg, i0 + k, i1 + k)
        else:
            sa, saa = float(np.dot(v[i0:i1], gc[a])), float(np.dot(v[i0:i1], gg[a]))
        sums[j] = (
            kept("v", v, i0, i1), sa, saa, kept("h", hc, i0, i1), kept("hh", hh, i0, i1),
            float(np.dot(hc[i0:i1], gc[a])),
        )  # fmt: skip
    cnt, sa, saa, sb, sbb, sab = sums.T
    count = np.rint(cnt).astype(np.int64)
    safe = np.maximum(cnt, 1.0)
    cov = sab - sa * sb / safe
    var = np.maximum(saa - sa * sa / safe, 0.0) * np.maximum(sbb - sb * sb / safe, 0.0)
    scale = np.sqrt(var)
    tiny = scale <= 1e-12 * np.maximum(np.sqrt(saa * sbb), 1e-300)
    corr = np.where(tiny, 0.0, cov / np.where(tiny, 1.0, scale))
    return corr, count


def integrated_rate(
    t_ns: NDArray[np.int64], omega_b: NDArray[np.float64], at_ns: NDArray[np.int64]
) -> NDArray[np.float64]:
    """The trapezoid integral of the rate from the first gyro sample to each of ``at_ns``
    (linear between samples), rad (K, 3); differences give the turn over short intervals.
    Any number of columns: ``omega_b`` (N, C) gives (K, C).

    One compiled pass over the samples up to the last stamp asked for
    (:func:`imu_dcm._kernels.calls.integrated_rate`), the stamps taken in order."""
    at = np.asarray(at_ns, dtype=np.int64)
    w = np.ascontiguousarray(omega_b, dtype=float)
    out = np.empty((len(at), w.shape[1]))
    if np.all(at[1:] >= at[:-1]):
        kernel_integrated_rate(t_ns, w, at, out)
        return out
    order = np.argsort(at, kind="stable")
    kernel_integrated_rate(t_ns, w, at[order], out)
    back = np.empty_like(out)
    back[order] = out
    return back


@dataclass(slots=True, frozen=True)
class RateGrid:
    """Gyro and truth rotations over the steps of one time grid (truth stamps as given).

    ``edges_ns`` int64 (K + 1,) grid edges; ``dt_s`` float (K,) step lengths; ``gyro_rotvec``
    (K, 3) the gyro's rotation over each step (trapezoid integral of the rate, gyro axes, rad);
    ``truth_rotvec`` (K, 3) the truth's body-frame rotation over each step (truth body axes,
    rad), NaN where the truth does not cover the step; ``step_s`` the grid step.
    """

    edges_ns: NDArray[np.int64]
    dt_s: NDArray[np.float64]
    gyro_rotvec: NDArray[np.float64]
    truth_rotvec: NDArray[np.float64]
    step_s: float


def rate_grid(
    t_ns: NDArray[np.int64],
    omega_b: NDArray[np.float64],
    truth_t_ns: NDArray[np.int64],
    q_w_b: NDArray[np.float64],
    min_step_s: float = 0.01,
) -> RateGrid | None:
    """Gyro and truth rotations on a grid of steps of ``max(min_step_s, 2 truth steps, gyro
    step)`` over their overlap; None when they overlap in fewer than 24 steps. The step is
    the evidence's, whatever the log's length: the grid of a 10 h log is as fine as a
    minute's (its arrays, ~130 bytes a step, are a tenth of the gyro's at 1 kHz)."""
    tt = np.asarray(truth_t_ns, dtype=np.int64)
    if len(t_ns) < 4 or len(tt) < 4:
        return None
    lo, hi = max(int(t_ns[0]), int(tt.min())), min(int(t_ns[-1]), int(tt.max()))
    if hi <= lo:
        return None
    sorted_tt = tt if np.all(tt[1:] >= tt[:-1]) else np.sort(tt)
    span_s = (hi - lo) * 1e-9
    dt = min_step_s
    # the median steps count only above that floor; where the longest steps stay under it,
    # so do the medians (no partition of every step)
    if 2 * float(np.diff(sorted_tt).max()) * 1e-9 > dt or float(np.diff(t_ns).max()) * 1e-9 > dt:
        dt = max(dt, 2 * median_diff(sorted_tt) * 1e-9, median_diff(t_ns) * 1e-9)
    edges = lo + np.round(np.arange(0.0, span_s, dt) * 1e9).astype(np.int64)
    if len(edges) < 24:
        return None
    te = (edges - t_ns[0]) * 1e-9
    angle = integrated_rate(t_ns, omega_b, edges)
    q = slerp_truth(tt, q_w_b, edges)
    rot = step_rotvecs(q, row_finite(q))  # the shortest arcs; NaN where uncovered
    return RateGrid(edges, np.diff(te), np.diff(angle, axis=0), rot, dt)


def check_truth(
    t_ns: NDArray[np.int64],
    omega_b: NDArray[np.float64],
    truth_t_ns: NDArray[np.int64],
    q_w_b: NDArray[np.float64],
) -> TruthCheck:
    """Compare the truth's rotation-rate norm with the gyro's over time shifts.

    Parameters
    ----------
    t_ns : int64 (N,), strictly increasing — gyro stamps.
    omega_b : float64 (N, 3) — gyro rates, rad/s, body axes (bias left in: it is small).
    truth_t_ns : int64 (M,) — truth stamps on the same clock.
    q_w_b : float64 (M, 4) — truth ``[x, y, z, w]``.

    Returns
    -------
    TruthCheck
        On the grid of :func:`rate_grid` (mean rates over steps of at least 10 ms).
    """
    grid = rate_grid(t_ns, omega_b, truth_t_ns, q_w_b)
    if grid is None:
        return TruthCheck(False, True)
    dt = grid.step_s
    g = row_norm(grid.gyro_rotvec) / grid.dt_s
    h = row_norm(grid.truth_rotvec) / grid.dt_s  # NaN where uncovered
    valid = np.isfinite(h)
    if valid.sum() < 20:
        return TruthCheck(False, True)
    g0, h0 = g[valid], h[valid]
    resid0 = float(np.sqrt(np.mean((g0 - h0) ** 2)))
    g_rms0 = float(np.sqrt(np.mean(g0**2)))
    if np.std(g0) < STILL_RAD_S or np.std(h0) < STILL_RAD_S:
        # A norm that hardly varies (a still body, a steady spin) has no shape to correlate:
        # only one still under the other clearly turning is evidence against it (either way:
        # an all-zero gyro under a turning truth is no gyro of that body)
        still_truth, still_gyro = float(np.mean(h0)) < STILL_RAD_S, float(np.mean(g0)) < STILL_RAD_S
        turning_g, turning_t = (
            float(np.mean(g0)) > 10 * STILL_RAD_S,
            float(np.mean(h0)) > 10 * STILL_RAD_S,
        )
        against = (still_truth and turning_g) or (still_gyro and turning_t)
        return TruthCheck(True, not against, None, None, resid0, g_rms0)
    span_s = (grid.edges_ns[-1] - grid.edges_ns[0]) * 1e-9
    lags = int(min(MAX_SHIFT_S, span_s / 4) / dt)
    corr, count = lagged_correlation(g, h, valid, lags)
    ok = count >= 20
    if not ok.any():
        return TruthCheck(False, True)
    j = int(np.argmax(np.where(ok, corr, -np.inf)))
    k, c = j - lags, float(corr[j])
    n = len(g)
    m = valid[max(-k, 0) : n - max(k, 0)]
    a = g[max(k, 0) : n + min(k, 0)][m]  # g[i + k] against h[i]
    b = h[max(-k, 0) : n - max(k, 0)][m]
    resid, g_rms = float(np.sqrt(np.mean((a - b) ** 2))), float(np.sqrt(np.mean(a**2)))
    shift = k * dt
    if 0 < j < len(corr) - 1 and ok[j - 1] and ok[j + 1]:  # parabola through the peak
        y0, y2 = float(corr[j - 1]), float(corr[j + 1])
        den = y0 - 2 * c + y2
        if den < 0:
            shift += 0.5 * (y0 - y2) / den * dt
    return TruthCheck(True, c >= MIN_CORRELATION, shift, c, resid, g_rms)

"""Attitude error metrics: total, inclination and heading, in degrees.

The error of an estimate ``q_est`` against a truth ``q_true`` (both ``q_w_b``, body to world,
``[x, y, z, w]``) is the world-frame rotation ``q_e = q_est ⊗ q_true*`` that carries the true
attitude onto the estimate. Its angle is the total error. Split about the world vertical (ENU,
z up) by swing-twist: the **heading** error is the twist of ``q_e`` about world z,
``2 atan2(|e_z|, |e_w|)``, and the **inclination** error is the remaining swing,
``2 acos(sqrt(e_w² + e_z²))`` (the tilt of the estimated vertical; BROAD's definitions).

As vectors: the **world error** ``e_w = log(q_est ⊗ q_true*)`` (rad, world axes:
``R_est = exp(e_w×) R_true``) and the **body error** ``e_b = log(q_true* ⊗ q_est)`` (rad, body
axes: ``R_est = R_true exp(e_b×)``, i.e. the rotation vector of ``R_trueᵀ R_est``); ``e_w =
R_true e_b``. A gyro bias ``δb`` left in the rates makes ``e_b`` grow as ``δb t`` while the body
is still, with the same sign.

Statistics of an error series (:func:`error_stats`) and the drift rate, a least-squares line
through the error's growth (:func:`drift_fit`), are plain numpy over the scored samples.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imu_dcm.arrays import BLOCK_ROWS
from imu_dcm.so3 import product_planes, quat_checked_norm

__all__ = [
    "AttitudeError",
    "DriftFit",
    "DriftSums",
    "ErrorStats",
    "attitude_error_deg",
    "body_error_rad",
    "drift_fit",
    "error_planes_rad",
    "error_stats",
    "error_vector_planes",
    "rms",
    "world_error_rad",
]

#: Seconds per hour, for drift rates in °/h.
S_PER_H = 3600.0


@dataclass(frozen=True)
class AttitudeError:
    """Per-sample attitude errors in degrees, each of shape ``(N,)``.

    Attributes
    ----------
    total_deg : angle of ``q_est ⊗ q_true*``, deg, in [0, 180].
    inclination_deg : tilt part (swing about a horizontal axis), deg.
    heading_deg : part about the world vertical (twist about world z), deg.
    """

    total_deg: NDArray[np.float64]
    inclination_deg: NDArray[np.float64]
    heading_deg: NDArray[np.float64]


def attitude_error_deg(q_est: ArrayLike, q_true: ArrayLike) -> AttitudeError:
    """Total, inclination and heading error of ``q_est`` against ``q_true``.

    Parameters
    ----------
    q_est, q_true : array_like, shape (..., 4)
        Attitudes ``q_w_b`` as ``[x, y, z, w]``; broadcast against each other; sign-insensitive.

    Returns
    -------
    AttitudeError
    """
    # Each angle below is a ratio of components, the same for scaled quaternions: the norms
    # are only checked (zero or NaN refused), not divided out.
    q_est, q_true = np.asarray(q_est, dtype=float), np.asarray(q_true, dtype=float)
    quat_checked_norm(q_est)
    quat_checked_norm(q_true)
    ex, ey, ez, ew = np.abs(product_planes(q_est, q_true, conj_q=True))
    total = 2.0 * np.arctan2(np.sqrt(ex * ex + ey * ey + ez * ez), ew)
    heading = 2.0 * np.arctan2(ez, ew)
    # swing angle: 2 atan2(|(ex, ey)|, |(ew, ez)|) — equal to 2 acos(sqrt(ew²+ez²)), better
    # conditioned near zero.
    inclination = 2.0 * np.arctan2(np.sqrt(ex * ex + ey * ey), np.sqrt(ew * ew + ez * ez))
    return AttitudeError(np.degrees(total), np.degrees(inclination), np.degrees(heading))


def rms(x: ArrayLike) -> float:
    """Root mean square of an array (NaN if empty)."""
    x = np.asarray(x, dtype=float).ravel()
    return float(np.sqrt(_dot(x, x) / x.size)) if x.size else float("nan")


def error_vector_planes(
    q_est: ArrayLike, q_true: ArrayLike, angle_rad: ArrayLike | None = None
) -> NDArray:
    """World and body error vectors together, as planes ``(6, ...)``, rad: rows 0-2 ``e_w``,
    rows 3-5 ``e_b``.

    ``q_est ⊗ q_true*`` and ``q_true* ⊗ q_est`` share their scalar part (the dot product) and
    so their angle, and their vector parts differ only in the sign of ``v_est × v_true``:
    ``w_t v_e − w_e v_t ∓ v_e × v_t``. One pass gives both, written in place into one array
    (few temporaries: on long logs, fresh memory costs more than the arithmetic).
    ``angle_rad``, optional: the error angle when already known (the total error of
    :func:`attitude_error_deg`, in rad), saving its computation.
    """
    E, T = np.broadcast_arrays(_planes4(q_est), _planes4(q_true))
    shape = E.shape[1:]
    (ex, ey, ez, ew), (tx, ty, tz, tw) = E.reshape(4, -1), T.reshape(4, -1)  # 0-d: 1-D
    out = np.empty((6, ex.size))
    tmp = np.empty(ex.size)
    for k, (e, t, (a, b, c, d)) in enumerate(
        ((ex, tx, (ey, tz, ez, ty)), (ey, ty, (ez, tx, ex, tz)), (ez, tz, (ex, ty, ey, tx)))
    ):
        lin, cross = out[k], out[3 + k]
        np.multiply(tw, e, out=lin)
        lin -= np.multiply(ew, t, out=tmp)
        np.multiply(a, b, out=cross)
        cross -= np.multiply(c, d, out=tmp)
        np.add(lin, cross, out=tmp)  # body: L + c
        lin -= cross  # world: L - c
        cross[...] = tmp
    w = ex * tx
    w += ey * ty
    w += ez * tz
    w += ew * tw
    s = np.einsum("i...,i...->...", out[:3], out[:3])
    np.sqrt(s, out=s)
    # log of a quaternion that is unit up to rounding: angle and axis are ratios of
    # components, so no normalisation is needed; q and -q give the same vector (sign of w)
    aw = np.abs(w)
    if angle_rad is None:
        theta = 2.0 * np.arctan2(s, aw)
    else:
        theta = np.asarray(angle_rad, dtype=float).reshape(-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.divide(theta, s, out=2.0 / aw, where=s > 0.0)
    np.copysign(scale, w, out=scale)
    out *= scale
    return out.reshape(6, *shape)


def _planes4(q: ArrayLike) -> NDArray:
    """The components as planes ``(4, ...)``: strided views of the rows, not copies (each is
    read a few times only; a copy costs as much as the reads)."""
    return np.moveaxis(np.asarray(q, dtype=float), -1, 0)


def error_planes_rad(q_est: ArrayLike, q_true: ArrayLike, frame: str = "world") -> NDArray:
    """World (``frame="world"``) or body (``"body"``) error vectors as planes, shape (3, ...), rad.

    The components ``x, y, z`` as contiguous rows (for the statistics, which use them one at a
    time); :func:`world_error_rad` and :func:`body_error_rad` give them as ``(..., 3)`` rows.
    """
    e = error_vector_planes(q_est, q_true)
    return e[:3] if frame == "world" else e[3:]


def world_error_rad(q_est: ArrayLike, q_true: ArrayLike) -> NDArray[np.float64]:
    """World-frame error vector ``e_w = log(q_est ⊗ q_true*)``, rad, shape (..., 3).

    ``R_est = exp(e_w×) R_true``: the rotation, in world axes (ENU), that carries the true
    attitude onto the estimate. Its z component is the signed heading error for small errors.
    """
    return np.moveaxis(error_planes_rad(q_est, q_true, "world"), 0, -1)


def body_error_rad(q_est: ArrayLike, q_true: ArrayLike) -> NDArray[np.float64]:
    """Body-frame error vector ``e_b = log(q_true* ⊗ q_est)``, rad, shape (..., 3).

    ``R_est = R_true exp(e_b×)`` (the rotation vector of ``R_trueᵀ R_est``): the error in the
    body's own axes, the frame in which a gyro bias acts.
    """
    return np.moveaxis(error_planes_rad(q_est, q_true, "body"), 0, -1)


@dataclass(frozen=True, slots=True)
class ErrorStats:
    """Statistics of one error series (same unit as the series; NaN when empty).

    Attributes
    ----------
    rms, mean, median, std : root mean square, mean, median, population standard deviation.
    p95 : 95th percentile (linear interpolation between order statistics, numpy's default).
    max : largest value.
    samples : number of values.
    """

    rms: float
    mean: float
    median: float
    std: float
    p95: float
    max: float
    samples: int


def _dot(a: NDArray, b: NDArray) -> float:
    """``a · b`` of 1-D arrays without BLAS (numpy's einsum loop): a threaded BLAS ``ddot`` on a
    loaded machine spins threads that cost more CPU than the sum."""
    return float(np.einsum("i,i->", a, b))


def error_stats(x: ArrayLike) -> ErrorStats:
    """:class:`ErrorStats` of the finite values ``x`` (1-D; NaN entries are refused upstream).

    The median and the 95th percentile interpolate linearly between order statistics at
    ``q (n − 1)`` (numpy's default), from one partial sort.
    """
    x = np.asarray(x, dtype=float).ravel()
    n = x.size
    if not n:
        nan = float("nan")
        return ErrorStats(nan, nan, nan, nan, nan, nan, 0)
    pos = np.array([0.5, 0.95]) * (n - 1)
    lo = np.floor(pos).astype(np.int64)
    hi = np.minimum(lo + 1, n - 1)
    part = np.partition(x, np.unique(np.r_[lo, hi, n - 1]))
    q = part[lo] + (part[hi] - part[lo]) * (pos - lo)
    top = float(part[n - 1])
    del part  # the sorted copy goes before the deviations' blocks come
    mean = float(np.mean(x))
    ss = 0.0  # Σ (x - mean)², a block at a time
    for a in range(0, n, BLOCK_ROWS):
        d = x[a : a + BLOCK_ROWS] - mean
        ss += _dot(d, d)
    return ErrorStats(
        rms=rms(x),
        mean=mean,
        median=float(q[0]),
        std=float(np.sqrt(ss / n)),
        p95=float(q[1]),
        max=top,
        samples=int(n),
    )


@dataclass(frozen=True, slots=True)
class DriftFit:
    """A straight line through an error's growth: one slope per series, fitted jointly.

    Attributes
    ----------
    slope : ndarray, shape (k,)
        Growth rate of each series, unit of the series per second.
    stderr : ndarray, shape (k,)
        Standard error of each slope, from the residuals as if independent. The residuals of
        an integrated error are correlated, so this is a lower bound on the real uncertainty.
    ss_res, ss_tot : ndarray, shape (k,)
        Residual sum of squares of each series, and its sum of squares about its segment means.
    samples : int
        Values fitted per series.
    """

    slope: NDArray[np.float64]
    stderr: NDArray[np.float64]
    ss_res: NDArray[np.float64]
    ss_tot: NDArray[np.float64]
    samples: int

    def r2(self, rows=slice(None)) -> float:
        """Coefficient of determination of the series ``rows`` together:
        ``1 − Σ ss_res / Σ ss_tot`` (1 for a straight line, near 0 for no trend; NaN without
        spread)."""
        tot = float(np.sum(self.ss_tot[rows]))
        return 1.0 - float(np.sum(self.ss_res[rows])) / tot if tot > 0 else float("nan")


def _centred(x: NDArray, starts: NDArray, counts: NDArray) -> NDArray:
    """``x`` (..., N) less the mean of its segment (one pass when there is one segment)."""
    if len(starts) == 1:
        return x - np.mean(x, axis=-1, keepdims=True)
    means = np.add.reduceat(x, starts, axis=-1) / counts
    return x - np.repeat(means, counts, axis=-1)


def drift_fit(t_s: ArrayLike, e: ArrayLike, segment: ArrayLike | None = None) -> DriftFit:
    """Least-squares drift rate of each series of ``e`` against time, one slope per series
    shared by every segment.

    Each segment (an integration re-anchored to the truth) gets its own intercept and all
    share the slope: ``e = c_seg + slope · t``.

    Parameters
    ----------
    t_s : array_like, shape (N,)
        Sample times, s.
    e : array_like, shape (N,) or (k, N)
        Error values, one series per row (any unit; the slope is that unit per second).
    segment : array_like of int, shape (N,), optional
        Segment label of each sample, non-decreasing (default: one segment).

    Returns
    -------
    DriftFit
        NaN slopes when fewer than 3 samples or no spread in time.
    """
    e2 = np.atleast_2d(np.asarray(e, dtype=float))
    fit = DriftSums(t_s, len(e2), segment)
    fit.add(0, e2)
    return fit.fit()


class DriftSums:
    """:func:`drift_fit` from the series handed over a block of samples at a time: the sums
    the fit needs, so that no whole-log copy of the series is held.

    Parameters
    ----------
    t_s : array_like, shape (N,)
        Sample times, s.
    series : int
        How many series (rows of each block).
    segment : array_like of int, shape (N,), optional
        Segment label of each sample, non-decreasing (default: one segment).
    """

    def __init__(self, t_s: ArrayLike, series: int, segment: ArrayLike | None = None) -> None:
        t = np.asarray(t_s, dtype=float)
        self.n = n = len(t)
        if segment is None or n == 0:
            self.starts = np.zeros(1 if n else 0, dtype=np.int64)
        else:
            seg = np.asarray(segment)
            self.starts = np.flatnonzero(np.r_[True, seg[1:] != seg[:-1]])
        self.counts = np.diff(np.r_[self.starts, n])
        self.tc = _centred(t, self.starts, self.counts) if n else t
        self.stt = _dot(self.tc, self.tc)
        # Σ tc = 0 in every segment, so the slope needs no centred copy of e; and the sum of
        # squares about the segment means is Σ e² − Σ_seg (Σ_seg e)² / n_seg (no copy either)
        self.e_tc = np.zeros(series)
        self.e_e = np.zeros(series)
        self.seg_sums = np.zeros((series, max(len(self.starts), 1)))

    def add(self, a: int, e: NDArray) -> None:
        """The series' values ``e`` (series, m) at samples ``[a, a + m)``."""
        m = e.shape[-1]
        self.e_tc += np.einsum("ij,j->i", e, self.tc[a : a + m])
        self.e_e += np.einsum("ij,ij->i", e, e)
        if len(self.starts) <= 1:
            self.seg_sums[:, 0] += e.sum(-1)
            return
        first = int(np.searchsorted(self.starts, a, side="right")) - 1
        cut = self.starts[(self.starts > a) & (self.starts < a + m)] - a  # segments in the block
        k = np.r_[0, cut]
        self.seg_sums[:, first : first + len(k)] += np.add.reduceat(e, k, axis=-1)

    def fit(self) -> DriftFit:
        n, stt = self.n, self.stt
        dof = n - len(self.starts) - 1
        nan = np.full(len(self.e_tc), np.nan)
        if dof < 1 or stt <= 0.0:
            return DriftFit(nan, nan, nan, nan, n)
        slope = self.e_tc / stt
        ss_tot = self.e_e - np.sum(self.seg_sums**2 / self.counts, axis=-1)
        ss_tot = np.maximum(ss_tot, 0.0)
        ss_res = np.maximum(ss_tot - slope * slope * stt, 0.0)
        return DriftFit(slope, np.sqrt(ss_res / dof / stt), ss_res, ss_tot, n)

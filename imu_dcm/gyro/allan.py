"""Overlapping Allan deviation of a rate signal, and the noise terms read off it.

For a rate record ``y_k`` sampled at ``rate_hz`` and cluster time ``tau = m / rate_hz``, with
``θ_k = Σ_{j<k} y_j / rate_hz`` the integrated angle,
``σ²(τ) = Σ_k (θ_{k+2m} − 2 θ_{k+m} + θ_k)² / (2 τ² (N − 2m))`` (IEEE Std 952 overlapping
estimator). White rate noise of density ``N`` (rad/s/√Hz, the angle random walk) gives
``σ(τ) = N / √τ``, so ``N = σ(1 s)`` on the −½ slope.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imu_dcm.errors import InputError

__all__ = [
    "B_FACTOR",
    "AllanFit",
    "NoiseTerm",
    "allan_deviation",
    "fit_noise",
    "noise_density_from_allan",
    "octave_clusters",
    "relative_uncertainty",
]

#: Bias instability B from the flat floor: ``σ_min = sqrt(2 ln 2 / π) B ≈ 0.664 B`` (IEEE 952).
B_FACTOR = float(np.sqrt(2.0 * np.log(2.0) / np.pi))
#: A local log-log slope within this of -1/2 (+1/2) belongs to the white-noise (random-walk) line.
SLOPE_TOL = 0.15


def allan_deviation(
    y: ArrayLike, rate_hz: float, m: ArrayLike | None = None
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Overlapping Allan deviation of ``y`` along axis 0.

    Parameters
    ----------
    y : array_like, shape (N,) or (N, k)
        Rate samples (any unit; the deviation has the same unit).
    rate_hz : float
        Sample rate, Hz.
    m : array_like of int, optional
        Cluster sizes in samples; default: about 10 per decade from 1 to ``N // 9``.

    Returns
    -------
    tau_s : ndarray, shape (M,)
        Cluster times, s.
    adev : ndarray, shape (M,) or (M, k)
        Allan deviation at each ``tau_s``.
    """
    y = np.asarray(y, dtype=float)
    n = y.shape[0]
    if not np.isfinite(rate_hz) or rate_hz <= 0:
        raise InputError(f"Expected `rate_hz` > 0, got {rate_hz}")
    if n < 9:
        raise InputError(f"Expected at least 9 samples for an Allan deviation, got {n}")
    if not np.all(np.isfinite(y)):
        row_ok = np.isfinite(y).all(axis=tuple(range(1, y.ndim)))
        raise InputError(
            f"Expected finite samples, got a NaN/Inf at index {int(np.argmin(row_ok))}"
        )
    if m is None:
        m = np.unique(
            np.logspace(0, np.log10(n // 9), 10 * max(1, int(np.log10(n // 9)) + 1)).astype(int)
        )
    m = np.asarray(m, dtype=int)
    if np.any(m < 1) or np.any(2 * m >= n):
        raise InputError(f"Expected cluster sizes 1 <= m < N/2 = {n / 2}, got {m.min()}..{m.max()}")
    dt = 1.0 / rate_hz
    theta = np.concatenate([np.zeros((1,) + y.shape[1:]), np.cumsum(y, axis=0) * dt])
    adev = []
    for mi in m:
        d = theta[2 * mi :] - 2.0 * theta[mi:-mi] + theta[: -2 * mi]
        tau = mi * dt
        adev.append(np.sqrt(np.sum(d * d, axis=0) / (2.0 * tau * tau * (n + 1 - 2 * mi))))
    return m * dt, np.asarray(adev)


def noise_density_from_allan(y: ArrayLike, rate_hz: float) -> NDArray[np.float64] | float:
    """Angle-random-walk density (unit/√Hz) from the short-τ end of the Allan deviation.

    Fits ``σ(τ) = N / √τ`` over clusters of 1 to ~10 samples (where white noise dominates);
    returns ``N``, one per column of ``y``.
    """
    tau, adev = allan_deviation(y, rate_hz, m=np.arange(1, 11))
    est = np.median(adev * np.sqrt(tau).reshape((-1,) + (1,) * (adev.ndim - 1)), axis=0)
    return est


def octave_clusters(n: int) -> NDArray[np.int64]:
    """Cluster sizes 1, 2, 4, ... up to ``n // 9`` (every τ has at least 9 clusters)."""
    top = max(1, n // 9)
    return 2 ** np.arange(int(np.log2(top)) + 1)


def relative_uncertainty(n: int, m: ArrayLike) -> NDArray[np.float64]:
    """Relative standard error of an Allan deviation from ``n // m`` clusters:
    ``1 / sqrt(2 (n/m − 1))`` (IEEE Std 952, annex C; the overlapping estimator does somewhat
    better at m > 1), and ``sqrt(3 / (4 (n − 1)))`` at m = 1 (derived for white noise)."""
    m = np.asarray(m, dtype=float)
    k = np.asarray(n, dtype=float) / m
    rel = 1.0 / np.sqrt(2.0 * np.maximum(k - 1.0, 1.0))
    # m = 1: the n - 1 first differences share samples (white noise: Var(σ̂²)/σ⁴ = 3/n, not
    # 2/n), so the plain cluster count understates the error by sqrt(3/2)
    return np.where(m == 1, np.sqrt(0.75 / np.maximum(k - 1.0, 1.0)), rel)


@dataclass(frozen=True, slots=True)
class NoiseTerm:
    """One noise term read off the Allan deviation.

    Attributes
    ----------
    value : float
        N in rad/s/√Hz, B in rad/s, K in rad/s²/√Hz (for rad/s input).
    tau_s : float
        Cluster time the value was read at, s.
    rel_uncertainty : float
        Relative standard error from the clusters at ``tau_s``.
    reached : bool
        False when the record never shows the term's slope: then ``value`` is only an upper
        bound (read at the longest τ).
    """

    value: float
    tau_s: float
    rel_uncertainty: float
    reached: bool


@dataclass(frozen=True, slots=True)
class AllanFit:
    """Allan deviation of one axis and the three standard terms (IEEE Std 952).

    ``N`` from the −½ slope (``σ = N/√τ``, read as ``σ √τ`` at the shortest τ on that line),
    ``B`` from the floor (``σ_min / 0.664``), ``K`` from the +½ slope (``σ = K √(τ/3)``, read as
    ``√(3 (σ² − N²/τ) / τ)`` at the shortest τ on that line, past the floor).
    """

    tau_s: NDArray[np.float64]
    adev: NDArray[np.float64]
    N: NoiseTerm
    B: NoiseTerm
    K: NoiseTerm


def _slopes(tau: NDArray, adev: NDArray) -> NDArray:
    return np.gradient(np.log(adev), np.log(tau))


def fit_noise(tau_s: ArrayLike, adev: ArrayLike, n: int) -> AllanFit:
    """Read N, B and K off one axis's Allan deviation at octave cluster times.

    Parameters
    ----------
    tau_s, adev : array_like, shape (M,)
        Cluster times (s) and deviations (rad/s) from :func:`allan_deviation`.
    n : int
        Samples in the record (for the uncertainties).
    """
    tau, sig = np.asarray(tau_s, dtype=float), np.asarray(adev, dtype=float)
    slope = _slopes(tau, sig)
    unc = relative_uncertainty(n, np.round(tau / tau[0]))
    white = np.flatnonzero(np.abs(slope + 0.5) <= SLOPE_TOL)
    i = int(white[0]) if len(white) else 0  # the most clusters on the -1/2 line
    N = NoiseTerm(float(sig[i] * np.sqrt(tau[i])), float(tau[i]), float(unc[i]), bool(len(white)))
    j = int(np.argmin(sig))
    floor = 0 < j < len(sig) - 1  # a floor that turns up again
    B = NoiseTerm(float(sig[j] / B_FACTOR), float(tau[j]), float(unc[j]), floor)
    walk = np.flatnonzero((np.abs(slope - 0.5) <= SLOPE_TOL) & (np.arange(len(sig)) > j))
    k = int(walk[0]) if len(walk) else len(sig) - 1
    # σ² = N²/τ + K² τ/3 on the +½ line's near end: the white noise's share is taken out
    # (N is known to far better than K), so K is not read high where the two still mix
    # (not reached: σ² >= K² τ/3 at the longest τ makes σ √(3/τ) an upper bound)
    s2 = sig[k] ** 2
    rest = max(s2 - N.value**2 / tau[k], 0.0) if len(walk) else s2
    K = NoiseTerm(
        float(np.sqrt(rest * 3.0 / tau[k])),
        float(tau[k]),
        float(unc[k] * s2 / rest) if rest > 0 else float("inf"),
        bool(len(walk)),
    )
    return AllanFit(tau, sig, N, B, K)

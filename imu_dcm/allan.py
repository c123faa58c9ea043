"""Overlapping Allan deviation of a rate signal, and the noise terms read off it.

For a rate record ``y_k`` sampled at ``rate_hz`` and cluster time ``tau = m / rate_hz``, with
``θ_k = Σ_{j<k} y_j / rate_hz`` the integrated angle,
``σ²(τ) = Σ_k (θ_{k+2m} − 2 θ_{k+m} + θ_k)² / (2 τ² (N − 2m))`` (IEEE Std 952 overlapping
estimator). White rate noise of density ``N`` (rad/s/√Hz, the angle random walk) gives
``σ(τ) = N / √τ``, so ``N = σ(1 s)`` on the −½ slope.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imu_dcm.errors import InputError

__all__ = ["allan_deviation", "noise_density_from_allan"]


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

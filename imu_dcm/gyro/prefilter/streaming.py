"""Streaming twin of ``prefilter(..., "kalman")``: one gyro sample at a time."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imu_dcm.errors import InputError
from imu_dcm.gyro.prefilter._linear import motion_order, process_noise, q_scale, transition_matrices
from imu_dcm.gyro.prefilter.config import PRIOR_SCALE, PrefilterConfig, check_config


class StreamingRateFilter:
    """Causal rate filter fed one gyro sample at a time: the streaming twin of ``"kalman"``.

    The same model and equations as ``prefilter(..., "kalman", config)`` (a test asserts that
    both agree); it keeps only the state ``(d, 3)``, its covariance and the last stamp. Both
    noise parameters must be given (nothing is estimated from a log that has not arrived yet);
    the bias state is not supported here.

    Parameters
    ----------
    config : PrefilterConfig
        With ``noise_density_rad_s_sqrt_hz`` and ``angular_accel_rad_s2`` set.

    Examples
    --------
    >>> f = StreamingRateFilter(PrefilterConfig(noise_density_rad_s_sqrt_hz=1e-3,
    ...                                         angular_accel_rad_s2=5.0))
    >>> omega_f_b, std_rad_s = f.update([0.1, 0.0, -0.2], 0.0)
    """

    def __init__(self, config: PrefilterConfig) -> None:
        check_config(config)
        if config.noise_density_rad_s_sqrt_hz is None or config.angular_accel_rad_s2 is None:
            raise InputError(
                "Expected `noise_density_rad_s_sqrt_hz` and `angular_accel_rad_s2` given for "
                f"streaming, got {config.noise_density_rad_s_sqrt_hz!r} and "
                f"{config.angular_accel_rad_s2!r}"
            )
        if config.estimate_bias:
            raise InputError("Expected `estimate_bias=False` for streaming, got True")
        self.config = config
        self._nm = motion_order(config.model)
        self._q = q_scale(config.model, config.angular_accel_rad_s2)
        self._h = np.zeros(self._nm)
        self._h[0] = 1.0
        self._x: NDArray | None = None  # (d, 3)
        self._P: NDArray | None = None  # (d, d)
        self._t: float | None = None

    def update(self, omega_b: ArrayLike, t_s: float) -> tuple[NDArray, float]:
        """Add one sample; return the filtered rate (3,) rad/s and its std, rad/s.

        Parameters
        ----------
        omega_b : array_like, shape (3,)
            Measured body rate, body axes, rad/s.
        t_s : float
            Its time, s, later than the previous sample's.
        """
        z = np.asarray(omega_b, dtype=float)
        if z.shape != (3,) or not np.isfinite(z).all():
            raise InputError(f"Expected `omega_b` three finite rates, got {omega_b!r}")
        t = float(t_s)
        if not math.isfinite(t) or (self._t is not None and t <= self._t):
            raise InputError(f"Expected `t_s` finite and > {self._t!r}, got {t_s!r}")
        dens2 = self.config.noise_density_rad_s_sqrt_hz**2
        if self._t is None:
            self._t = t
            self._x = np.zeros((self._nm, 3))
            self._x[0] = z
            return z.copy(), math.nan  # the first sample: its dt (and so its noise) is unknown
        dt = t - self._t
        if self._P is None:
            # the batch filter's prior at its sample 0 uses the first step's dt (dt_full[0])
            sig, h = math.sqrt(dens2 / dt), dt
            spread = [sig, math.sqrt(2.0) * sig / h, math.sqrt(6.0) * sig / h**2][: self._nm]
            P = np.diag((PRIOR_SCALE * np.array(spread)) ** 2)
            z0 = self._x[0].copy()
            Ph = P @ self._h
            K = Ph / (float(self._h @ Ph) + dens2 / dt)
            self._x = self._x + np.outer(K, z0 - self._x[0])
            self._P = P - np.outer(K, Ph)
        F = transition_matrices(np.array([dt]), self._nm, False)[0]
        Q = process_noise(np.array([dt]), self._nm, self._q, False, 0.0)[0]
        x = F @ self._x
        P = F @ self._P @ F.T + Q
        Ph = P @ self._h
        K = Ph / (float(self._h @ Ph) + dens2 / dt)
        self._x = x + np.outer(K, z - x[0])
        P = P - np.outer(K, Ph)
        self._P = 0.5 * (P + P.T)
        self._t = t
        return self._x[0].copy(), math.sqrt(self._P[0, 0])

"""Model-based variant: Euler's equations of a rigid body with known inertia (filterpy UKF)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imu_dcm.errors import InputError
from imu_dcm.gyro.prefilter.config import (
    PRIOR_SCALE,
    PrefilterConfig,
    PrefilterResult,
    check_positive,
    check_prefilter_mode,
    check_rates,
)


def _euler_rates_dot(w: NDArray, inertia: NDArray, torque_b: NDArray | None) -> NDArray:
    """``ω̇ = I⁻¹ (τ − ω × I ω)``, principal inertias ``inertia`` (3,), rates ``w`` (..., 3)."""
    h = w * inertia  # angular momentum, body axes
    x, y, z = w[..., 0], w[..., 1], w[..., 2]
    acc = -np.stack(
        [
            y * h[..., 2] - z * h[..., 1],
            z * h[..., 0] - x * h[..., 2],
            x * h[..., 1] - y * h[..., 0],
        ],
        axis=-1,
    )  # -(ω × I ω), np.cross is slow
    if torque_b is not None:
        acc = acc + torque_b
    return acc / inertia


def _euler_step(w: NDArray, dt: float, inertia: NDArray, torque_b: NDArray | None) -> NDArray:
    """One classical Runge-Kutta step of Euler's equations over ``dt`` (rows of ``w``)."""
    k1 = _euler_rates_dot(w, inertia, torque_b)
    k2 = _euler_rates_dot(w + 0.5 * dt * k1, inertia, torque_b)
    k3 = _euler_rates_dot(w + 0.5 * dt * k2, inertia, torque_b)
    k4 = _euler_rates_dot(w + dt * k3, inertia, torque_b)
    return w + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


def euler_prefilter(
    omega_b: ArrayLike,
    t_s: ArrayLike,
    inertia_kg_m2: ArrayLike,
    mode: str = "rts",
    *,
    noise_density_rad_s_sqrt_hz: float,
    torque_noise_n_m_sqrt_hz: float,
    torque_b: ArrayLike | None = None,
) -> PrefilterResult:
    """Filter or smooth body rates with Euler's equations as the process model (known inertia).

    The state is the body rate ``ω`` (body axes, rad/s); between samples it follows
    ``I ω̇ = τ − ω × I ω`` (one RK4 step per sample interval) with ``τ`` the known torque (zero
    for a torque-free body) plus white torque noise of density ``torque_noise_n_m_sqrt_hz``
    (N·m/√Hz): the unmodelled torques. Measurements are ``z = ω + v``, ``v`` white of density
    ``noise_density_rad_s_sqrt_hz``. The forward pass is ``filterpy.kalman.UnscentedKalmanFilter``
    (Merwe sigma points); ``rts`` adds the unscented RTS smoother (Särkkä 2008), written out
    because filterpy's ``UnscentedKalmanFilter.rts_smoother`` applies one ``Q`` and the step into
    ``k`` rather than out of it, which is wrong for uneven stamps.

    Unlike the generic model (:func:`prefilter`), this one knows how the rate must evolve, so it
    can average the noise over many samples without lagging the motion.

    Parameters
    ----------
    omega_b : array_like, shape (N, 3)
        Measured body rate, body (principal) axes, rad/s.
    t_s : array_like, shape (N,)
        Sample times, s, strictly increasing.
    inertia_kg_m2 : array_like, shape (3,)
        Principal moments of inertia about the body axes, kg·m².
    mode : {"kalman", "rts"}
    noise_density_rad_s_sqrt_hz : float
        Gyro white-noise density, rad/s/√Hz.
    torque_noise_n_m_sqrt_hz : float
        Density of the unmodelled torque, N·m/√Hz.
    torque_b : array_like, shape (3,), optional
        Known constant torque in body axes, N·m (default: none).

    Returns
    -------
    PrefilterResult
        ``angular_accel_b`` from Euler's equations at the estimate; ``config`` holds the noise
        density; ``summary["model"] == "euler"`` with the inertia and torque noise.
    """
    omega_b, t_s = check_rates(omega_b, t_s)
    check_prefilter_mode(mode)
    inertia = _vector3("inertia_kg_m2", inertia_kg_m2, positive=True)
    check_positive("noise_density_rad_s_sqrt_hz", noise_density_rad_s_sqrt_hz, allow_none=False)
    check_positive("torque_noise_n_m_sqrt_hz", torque_noise_n_m_sqrt_hz, allow_none=False)
    tau = None if torque_b is None else _vector3("torque_b", torque_b, positive=False)
    body = _Body(inertia, tau, (torque_noise_n_m_sqrt_hz / inertia) ** 2)
    X, P, Xm, Pm, C = _ukf_forward(omega_b, t_s, body, noise_density_rad_s_sqrt_hz)
    if mode == "rts":
        _unscented_rts(X, P, Xm, Pm, C)
    summary = {
        "mode": mode,
        "model": "euler",
        "engine": "filterpy UKF",
        "n_samples": len(t_s),
        "inertia_kg_m2": inertia.tolist(),
        "torque_noise_n_m_sqrt_hz": float(torque_noise_n_m_sqrt_hz),
        "noise_density_rad_s_sqrt_hz": float(noise_density_rad_s_sqrt_hz),
        "noise_source": "given",
    }
    return PrefilterResult(
        omega_b=X,
        rate_std_rad_s=np.sqrt(np.diagonal(P, axis1=1, axis2=2)).copy(),
        angular_accel_b=_euler_rates_dot(X, inertia, tau),
        bias_b=None,
        rest=None,
        mode=mode,
        config=PrefilterConfig(noise_density_rad_s_sqrt_hz=float(noise_density_rad_s_sqrt_hz)),
        summary=summary,
    )


def _vector3(name: str, value: ArrayLike, positive: bool) -> NDArray:
    """``value`` as three finite floats (all > 0 when ``positive``), else InputError."""
    v = np.asarray(value, dtype=float)
    if v.shape != (3,) or not np.isfinite(v).all() or (positive and not (v > 0).all()):
        what = "three finite values > 0" if positive else "three finite values"
        raise InputError(f"Expected `{name}` {what}, got {value!r}")
    return v


@dataclass(frozen=True)
class _Body:
    """The process model: principal inertias (3,) kg·m², the known torque (3,) N·m or None, and
    the rate random-walk density per axis that the torque noise gives, rad²/s³."""

    inertia: NDArray
    torque_b: NDArray | None
    rate_walk: NDArray

    def step(self, w: NDArray, dt: float) -> NDArray:
        return _euler_step(w, dt, self.inertia, self.torque_b)


def _make_ukf(body: _Body, dt_s: float):
    """filterpy's UKF on the body rate, its process the Euler step of every sigma point at once;
    the sigma points before and after the step are kept for the smoother's cross-covariance."""
    from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

    class _UKF(UnscentedKalmanFilter):
        def compute_process_sigmas(self, dt, fx=None, **fx_args):
            self.sig_in = self.points_fn.sigma_points(self.x, self.P)
            self.sig_out = body.step(self.sig_in, dt)
            self.sigmas_f = self.sig_out.copy()

    points = MerweScaledSigmaPoints(3, alpha=0.1, beta=2.0, kappa=0.0)
    return _UKF(dim_x=3, dim_z=3, dt=dt_s, hx=lambda x: x, fx=body.step, points=points)


def _ukf_forward(
    omega_b: NDArray, t_s: NDArray, body: _Body, noise_density: float
) -> tuple[NDArray, NDArray, NDArray, NDArray, NDArray]:
    """The unscented filter's pass: filtered means (N, 3) and covariances (N, 3, 3), prior means
    and covariances, and the cross-covariance of ``x_{k-1}`` (filtered) and ``x_k`` (prior)."""
    n = len(t_s)
    dt = np.diff(t_s)
    ukf = _make_ukf(body, float(np.median(dt)))
    r0 = noise_density**2 / float(dt[0])
    ukf.x = omega_b[0].copy()
    ukf.P = np.eye(3) * r0 * PRIOR_SCALE**2
    X = np.empty((n, 3))
    P = np.empty((n, 3, 3))
    Xm = np.empty((n, 3))
    Pm = np.empty((n, 3, 3))
    C = np.empty((n, 3, 3))
    for k in range(n):
        if k > 0:
            ukf.Q = np.diag(body.rate_walk * dt[k - 1])
            ukf.predict(dt=float(dt[k - 1]))
            Xm[k], Pm[k] = ukf.x, ukf.P
            d_in = ukf.sig_in - X[k - 1]
            d_out = ukf.sig_out - Xm[k]
            C[k] = (ukf.Wc[:, None] * d_in).T @ d_out
        r = noise_density**2 / float(dt[max(k - 1, 0)])
        ukf.update(omega_b[k], R=np.eye(3) * r)
        X[k], P[k] = ukf.x, ukf.P
    return X, P, Xm, Pm, C


def _unscented_rts(X: NDArray, P: NDArray, Xm: NDArray, Pm: NDArray, C: NDArray) -> None:
    """The unscented RTS smoother (Särkkä 2008), backwards over the filter's pass, in place."""
    for k in range(len(X) - 2, -1, -1):
        G = C[k + 1] @ np.linalg.inv(Pm[k + 1])
        X[k] = X[k] + G @ (X[k + 1] - Xm[k + 1])
        P[k] = P[k] + G @ (P[k + 1] - Pm[k + 1]) @ G.T

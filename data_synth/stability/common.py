"""What the stability scenes share: the methods compared, closed-form truths, scoring."""

from __future__ import annotations

import math
import warnings

import numpy as np
from numpy.typing import NDArray

import imu_dcm
from data_synth.analytic import coning_attitude, coning_rates, zxz_quat
from data_synth.scenes import HeavyTopParams, box_inertia
from imu_dcm.metrics import attitude_error_deg

#: The imu_dcm methods compared in the scenes (``rotvec_sum`` has its own scene).
DCM_METHODS = ("start", "end", "trapezoid", "coning", "magnus4")

#: The heavy top of :class:`data_synth.scenes.HeavyTopParams` (20 Hz spin, 54.57° tilt).
TOP = HeavyTopParams()

#: Principal inertias (kg m²) of the free box, edges 2.0, 1.5, 1.0 m, 1 kg (docs/design.md).
BOX_INERTIA = box_inertia((2.0, 1.5, 1.0), 1.0)

_EPS = float(np.finfo(float).eps)


# ----------------------------------------------------------------------------------------------
# Closed-form motions
# ----------------------------------------------------------------------------------------------


def zxz_truth(
    phi: NDArray, theta: NDArray, psi: NDArray, dphi: NDArray, dtheta: NDArray, dpsi: NDArray
) -> tuple[NDArray, NDArray]:
    """Attitude and body rate of a motion given by ZXZ Euler angles and their rates.

    Parameters
    ----------
    phi, theta, psi : ndarray, shape (N,)
        Precession, nutation and spin angles, rad (intrinsic ZXZ, ``R_w_b = Rz Rx Rz``).
    dphi, dtheta, dpsi : ndarray, shape (N,)
        Their time derivatives, rad/s.

    Returns
    -------
    q_w_b : ndarray, shape (N, 4)
        Body-to-world quaternions ``[x, y, z, w]``.
    omega_b : ndarray, shape (N, 3)
        Body rate in body axes, rad/s (Goldstein 4-125):
        ``ω1 = φ̇ sinθ sinψ + θ̇ cosψ``, ``ω2 = φ̇ sinθ cosψ − θ̇ sinψ``, ``ω3 = φ̇ cosθ + ψ̇``.
    """
    phi, theta, psi, dphi, dtheta, dpsi = np.broadcast_arrays(phi, theta, psi, dphi, dtheta, dpsi)
    s, c = np.sin(psi), np.cos(psi)
    omega_b = np.stack(
        [
            dphi * np.sin(theta) * s + dtheta * c,
            dphi * np.sin(theta) * c - dtheta * s,
            dphi * np.cos(theta) + dpsi,
        ],
        axis=-1,
    )
    return zxz_quat(phi, theta, psi), omega_b


def coning_truth(t_s: NDArray, half_angle_rad: float, freq_rad_s: float) -> tuple[NDArray, NDArray]:
    """Pure coning ``R_w_b(t) = Rz(Ωt) Rx(β) Rz(−Ωt)``: ``(q_w_b (N, 4), omega_b (N, 3) rad/s)``.

    The closed form of :mod:`data_synth.analytic`, with ``Ω`` in rad/s.
    """
    freq_hz = freq_rad_s / (2.0 * math.pi)
    return coning_attitude(t_s, half_angle_rad, freq_hz), coning_rates(t_s, half_angle_rad, freq_hz)


def _uniform_t(rate_hz: float, duration_s: float) -> NDArray:
    n = round(duration_s * rate_hz) + 1
    return np.arange(n) / rate_hz


def _integrate_q(omega_b: NDArray, t_s: NDArray, q0: NDArray, method: str) -> NDArray:
    if method == "rotvec_sum":  # used on purpose here: silence its "wrong method" warning
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", imu_dcm.ImuDcmWarning)
            return imu_dcm.integrate(omega_b, t_s, q0, method).as_quat()
    return imu_dcm.integrate(omega_b, t_s, q0, method).as_quat()


def _err_deg(q_est: NDArray, q_true: NDArray) -> NDArray:
    """Total attitude error, deg; 180 where the estimate is not finite (a failed method)."""
    q_est = np.asarray(q_est, dtype=float)
    ok = np.all(np.isfinite(q_est), axis=-1)
    safe = np.where(ok[..., None], q_est, np.array([0.0, 0.0, 0.0, 1.0]))
    return np.where(ok, attitude_error_deg(safe, q_true).total_deg, 180.0)


def _wrap_deg(angle_rad: NDArray) -> NDArray:
    a = np.mod(np.asarray(angle_rad), 2.0 * np.pi)
    return np.degrees(np.minimum(a, 2.0 * np.pi - a))

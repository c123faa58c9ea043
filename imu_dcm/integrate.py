"""Batch DCM integration of body rates: ``R_{i+1} = R_i · exp([φ_i×])`` (DESIGN.md §4).

FOUNDATION VERSION: correct increments, sequential product. To be replaced by the vectorised
blocked prefix product (issue 2).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from imu_dcm.so3 import as_quat_xyzw, exp_quat, quat_multiply, quat_normalize

METHODS = ("start", "end", "trapezoid", "coning", "magnus4", "rotvec_sum")


def _midpoint_rates(omega_b: NDArray, t_s: NDArray) -> NDArray:
    """Rate at each step's mid-time by cubic Lagrange interpolation through 4 neighbours."""
    n = len(t_s)
    if n < 4:
        return 0.5 * (omega_b[:-1] + omega_b[1:])
    i = np.arange(n - 1)
    j0 = np.clip(i - 1, 0, n - 4)
    idx = j0[:, None] + np.arange(4)[None, :]  # (n-1, 4)
    tn = t_s[idx]
    x = 0.5 * (t_s[:-1] + t_s[1:])
    w = np.ones((n - 1, 4))
    for j in range(4):
        for k in range(4):
            if k != j:
                w[:, j] *= (x - tn[:, k]) / (tn[:, j] - tn[:, k])
    return np.einsum("nj,njk->nk", w, omega_b[idx])


def increments(omega_b: NDArray, t_s: NDArray, method: str) -> NDArray:
    """Rotation-vector increments ``φ_i`` (rad, body frame), shape (N-1, 3)."""
    dt = np.diff(t_s)[:, None]
    w0, w1 = omega_b[:-1], omega_b[1:]
    if method == "start":
        return w0 * dt
    if method == "end":
        return w1 * dt
    if method == "trapezoid":
        return 0.5 * (w0 + w1) * dt
    if method == "coning":
        return 0.5 * (w0 + w1) * dt + dt * dt / 12.0 * np.cross(w0, w1)
    if method == "magnus4":
        wm = _midpoint_rates(omega_b, t_s)
        return dt / 6.0 * (w0 + 4.0 * wm + w1) + dt * dt / 12.0 * np.cross(w0, w1)
    raise ValueError(f"Expected method in {METHODS}, got {method!r}")


def integrate(omega_b: ArrayLike, t_s: ArrayLike, q0, method: str = "magnus4") -> Rotation:
    """Attitude ``q_w_b`` at every sample time from body rates (placeholder implementation)."""
    omega_b = np.asarray(omega_b, dtype=float)
    t_s = np.asarray(t_s, dtype=float)
    q = as_quat_xyzw(q0)
    if method == "rotvec_sum":
        phi = np.concatenate([np.zeros((1, 3)), np.cumsum(omega_b[1:] * np.diff(t_s)[:, None], axis=0)])
        return Rotation.from_quat(quat_multiply(q, exp_quat(phi)))
    dq = exp_quat(increments(omega_b, t_s, method))
    out = np.empty((len(t_s), 4))
    out[0] = q
    for i in range(len(dq)):
        q = quat_multiply(q, dq[i])
        out[i + 1] = q
    return Rotation.from_quat(quat_normalize(out))

"""Reference integrators: first-order and deliberately wrong ones, kept to be measured against.

Every function here integrates gyro rates the way other code commonly does, so that tests and
benchmarks can show where those ways fail. None of them is what :func:`imu_dcm.integrate`
computes; use that for attitude.

* :func:`reference_loop`: the plain DCM recursion ``R ← R · CK(ω dt)``, one numpy 3x3 product
  per step with the rate at the *end* of the step (first order; Savage, *Strapdown Analytics*,
  2000, ch. 7, without its coning correction). :func:`reference_ck` is its step matrix written
  with the Cayley–Klein (Euler) parameters (Goldstein, *Classical Mechanics*, §4-5).
* :func:`scipy_loop`: scipy ``Rotation`` composed per sample (the same rule).
* :func:`truncated_first_order`: the truncated quaternion step ``q ← q + ½ q ⊗ [ω dt, 0]``
  (how many complementary filters step), normalised or not.
* :func:`euler_zxz_integrate`: ZXZ Euler angles from body rates (Goldstein 4-125 inverted), which
  are singular where ``sin θ = 0`` (gimbal lock).

Conventions (docs/design.md): quaternions Hamilton ``[x, y, z, w]``; ``q_w_b`` maps body to
world; ``omega_b`` is the body rate relative to the world in body axes, rad/s; increments multiply
on the right; ``t_s`` seconds, strictly increasing.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

__all__ = [
    "euler_zxz_integrate",
    "reference_ck",
    "reference_loop",
    "scipy_loop",
    "truncated_first_order",
]


def reference_ck(omega_dt: NDArray) -> NDArray:
    """The step matrix ``CK(dΩ)`` of the plain DCM loop (right-handed, active), one 3x3 matrix.

    ``a = cos(|dΩ|/2)`` and ``(b, c, d) = axis · sin(|dΩ|/2)`` (the Cayley–Klein / Euler
    parameters), laid out as the rotation matrix in Euler parameters (Goldstein, *Classical
    Mechanics*, 2nd ed., §4-5); equal to Rodrigues ``exp([dΩ×])``.

    Parameters
    ----------
    omega_dt : ndarray, shape (3,)
        Rotation vector ``ω dt``, rad, body frame.

    Returns
    -------
    ndarray, shape (3, 3)
    """
    angle = np.linalg.norm(omega_dt)
    if angle == 0.0:
        return np.eye(3)
    a = np.cos(angle / 2.0)
    b, c, d = omega_dt / angle * np.sin(angle / 2.0)
    return np.array(
        [
            [a * a + b * b - c * c - d * d, 2 * (b * c - a * d), 2 * (b * d + a * c)],
            [2 * (b * c + a * d), a * a + c * c - b * b - d * d, 2 * (c * d - a * b)],
            [2 * (b * d - a * c), 2 * (c * d + a * b), a * a + d * d - b * b - c * c],
        ]
    )


def reference_loop(omega_b: NDArray, t_s: NDArray, q0: NDArray) -> NDArray:
    """The plain DCM loop, numpy 3x3 per step: ``R_{i+1} = R_i · CK(ω_{i+1} dt)``.

    The rate at the *end* of each step over the step's real ``dt`` (first order), as a short
    textbook program writes it (``TrackMat <- TrackMat @ CK(w[i] * h)``); the matrix is stored
    once per step.
    """
    omega_b = np.asarray(omega_b, dtype=float)
    dt = np.diff(np.asarray(t_s, dtype=float))
    n = len(omega_b)
    track = Rotation.from_quat(q0).as_matrix()
    out = np.empty((n, 3, 3))
    out[0] = track
    for i in range(1, n):
        track = np.dot(track, reference_ck(omega_b[i, :] * dt[i - 1]))
        out[i] = track
    return Rotation.from_matrix(out).as_quat()


def scipy_loop(omega_b: NDArray, t_s: NDArray, q0: NDArray) -> NDArray:
    """scipy ``Rotation`` composition per sample: ``r <- r * Rotation.from_rotvec(ω_{i+1} dt)``."""
    omega_b = np.asarray(omega_b, dtype=float)
    dt = np.diff(np.asarray(t_s, dtype=float))
    out = np.empty((len(omega_b), 4))
    r = Rotation.from_quat(q0)
    out[0] = r.as_quat()
    for i in range(1, len(omega_b)):
        r = r * Rotation.from_rotvec(omega_b[i] * dt[i - 1])
        out[i] = r.as_quat()
    return out


def truncated_first_order(
    omega_b: NDArray, t_s: NDArray, q0: NDArray, normalise: bool = True
) -> NDArray:
    """First-order truncated quaternion update, per sample (how imufusion-style filters step).

    ``q_{i+1} = q_i + ½ q_i ⊗ [ω_{i+1} dt, 0]``, then normalised (unless ``normalise=False``):
    the rate at the end of the step, as in :func:`reference_loop`, so the only difference
    from the ``end`` method is truncating ``exp`` to first order.

    Returns
    -------
    ndarray, shape (N, 4)
        ``q_w_b`` ``[x, y, z, w]``; not unit when ``normalise=False``.
    """
    w = np.asarray(omega_b, dtype=float).tolist()
    t = np.asarray(t_s, dtype=float).tolist()
    out = np.empty((len(t), 4))
    x, y, z, s = (float(v) for v in q0)
    out[0] = (x, y, z, s)
    for i in range(1, len(t)):
        h = 0.5 * (t[i] - t[i - 1])
        a, b, c = w[i][0] * h, w[i][1] * h, w[i][2] * h
        # q ⊗ [a, b, c, 0] (Hamilton, scalar last)
        x, y, z, s = (
            x + s * a + y * c - z * b,
            y + s * b + z * a - x * c,
            z + s * c + x * b - y * a,
            s - x * a - y * b - z * c,
        )
        if normalise:
            n = math.sqrt(x * x + y * y + z * z + s * s)
            x, y, z, s = x / n, y / n, z / n, s / n
        out[i] = (x, y, z, s)
    return out


def _zxz_rates(ang: Sequence[float], w: Sequence[float]) -> tuple[float, float, float]:
    """ZXZ Euler-angle rates from body rates; singular at sin θ = 0 (returns inf/nan there)."""
    _phi, theta, psi = ang
    s, c = math.sin(psi), math.cos(psi)
    st = math.sin(theta)
    num = w[0] * s + w[1] * c
    if st == 0.0:
        dphi = math.copysign(math.inf, num) if num != 0.0 else math.nan
    else:
        dphi = num / st
    return dphi, w[0] * c - w[1] * s, w[2] - dphi * math.cos(theta)


def euler_zxz_integrate(omega_b: NDArray, t_s: NDArray, angles0: Sequence[float]) -> NDArray:
    """Integrate ZXZ Euler angles from body rates with Heun's rule (second order, per sample).

    ``x_{i+1} = x_i + dt/2 (f(x_i, ω_i) + f(x_i + dt f(x_i, ω_i), ω_{i+1}))`` with
    ``φ̇ = (ω1 sinψ + ω2 cosψ)/sinθ``, ``θ̇ = ω1 cosψ − ω2 sinψ``, ``ψ̇ = ω3 − φ̇ cosθ``: the
    Euler-angle kinematics, singular where ``sin θ = 0``. Same samples and order as the DCM
    ``trapezoid`` method, so the comparison isolates the parametrisation.

    Returns
    -------
    ndarray, shape (N, 3)
        ``(φ, θ, ψ)`` at every sample, rad; NaN/inf once the singularity is hit.
    """
    w = np.asarray(omega_b, dtype=float).tolist()
    t = np.asarray(t_s, dtype=float).tolist()
    out = np.empty((len(t), 3))
    x = [float(a) for a in angles0]
    out[0] = x
    for i in range(len(t) - 1):
        dt = t[i + 1] - t[i]
        k1 = _zxz_rates(x, w[i])
        xp = [x[j] + dt * k1[j] for j in range(3)]
        k2 = _zxz_rates(xp, w[i + 1])
        x = [x[j] + 0.5 * dt * (k1[j] + k2[j]) for j in range(3)]
        out[i + 1] = x
    return out

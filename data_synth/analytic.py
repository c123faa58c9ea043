"""Closed-form motions: pure coning, the torque-free symmetric top, the torque-free box (Jacobi
elliptic functions) and the heavy symmetric top (elliptic cos θ(t), steady precession).

Conventions (docs/design.md): ``q_w_b`` Hamilton ``[x, y, z, w]``, body to world; ``omega_b`` body
rate relative to the world in body axes, rad/s; ``t_s`` seconds; world ENU, z up. Euler angles of
the top are z-x-z, ``R_w_b = Rz(φ) Rx(θ) Rz(ψ)`` (φ precession, θ nutation from the vertical,
ψ spin), so ``R_w_b(0) = Rx(tilt)`` is ``φ = ψ = 0, θ = tilt`` and (Goldstein 4-125)
``ω1 = φ̇ sinθ sinψ + θ̇ cosψ``, ``ω2 = φ̇ sinθ cosψ − θ̇ sinψ``, ``ω3 = φ̇ cosθ + ψ̇``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import ellipj, ellipk, ellipkinc, elliprf, elliprj

from data_synth.rigid_body import Trajectory
from imu_dcm.errors import InputError
from imu_dcm.so3 import exp_quat, quat_conjugate, quat_multiply, quat_rotate

__all__ = [
    "ConingTrajectory",
    "HeavyTopInvariants",
    "box_attitude_elliptic",
    "box_omega_elliptic",
    "coning_attitude",
    "coning_rates",
    "heavy_top_cos_theta",
    "heavy_top_invariants",
    "steady_precession_rates",
    "symmetric_free_top",
]


def axis_quat(axis: int, angle_rad: ArrayLike) -> NDArray[np.float64]:
    """Quaternions ``[x, y, z, w]`` of rotations by ``angle_rad`` (shape (N,)) about a coordinate
    axis (0 = x, 1 = y, 2 = z); shape (N, 4)."""
    a = np.asarray(angle_rad, dtype=float)
    q = np.zeros(a.shape + (4,))
    q[..., axis] = np.sin(0.5 * a)
    q[..., 3] = np.cos(0.5 * a)
    return q


def zxz_quat(phi: ArrayLike, theta: ArrayLike, psi: ArrayLike) -> NDArray[np.float64]:
    """``q_w_b`` of intrinsic ZXZ Euler angles, ``Rz(φ) · Rx(θ) · Rz(ψ)``, shape (N, 4) xyzw."""
    return quat_multiply(quat_multiply(axis_quat(2, phi), axis_quat(0, theta)), axis_quat(2, psi))


# --------------------------------------------------------------------------------------------
# Pure coning
# --------------------------------------------------------------------------------------------


def coning_attitude(t_s: ArrayLike, half_angle_rad: float, freq_hz: float) -> NDArray[np.float64]:
    """``q_w_b(t)`` of pure coning, ``R_w_b(t) = Rz(Ωt) Rx(β) Rz(−Ωt)``, ``Ω = 2π freq_hz``.

    The body z axis sweeps a cone of half-angle ``β`` about world z at ``Ω``; shape (N, 4).
    """
    wt = 2.0 * math.pi * freq_hz * np.asarray(t_s, dtype=float)
    qx = axis_quat(0, np.full_like(wt, half_angle_rad))
    return quat_multiply(quat_multiply(axis_quat(2, wt), qx), axis_quat(2, -wt))


def coning_rates(t_s: ArrayLike, half_angle_rad: float, freq_hz: float) -> NDArray[np.float64]:
    """Body rate of pure coning, ``ω_b = Ω (−sinβ sinΩt, sinβ cosΩt, cosβ − 1)``, rad/s, (N, 3)."""
    om = 2.0 * math.pi * freq_hz
    wt = om * np.asarray(t_s, dtype=float)
    sb, cb = math.sin(half_angle_rad), math.cos(half_angle_rad)
    return om * np.stack([-sb * np.sin(wt), sb * np.cos(wt), np.full_like(wt, cb - 1.0)], axis=-1)


class ConingTrajectory(Trajectory):
    """Pure coning with closed-form attitude, rate and delta angles (docs/design.md, "The rotation
    vector of a step": coning).

    Parameters
    ----------
    duration_s : float
        Length, s.
    half_angle_deg : float
        Cone half-angle ``β``, deg.
    freq_hz : float
        Coning frequency ``Ω / 2π``, Hz (signed: negative cones the other way).
    """

    def __init__(self, duration_s: float, half_angle_deg: float = 10.0, freq_hz: float = 5.0):
        for name, v in (
            ("duration_s", duration_s),
            ("half_angle_deg", half_angle_deg),
            ("freq_hz", freq_hz),
        ):
            if not math.isfinite(v):
                raise InputError(f"Expected finite `{name}`, got {v!r}")
        if duration_s <= 0:
            raise InputError(f"Expected `duration_s` > 0, got {duration_s!r}")
        if not 0.0 <= half_angle_deg < 90.0:
            raise InputError(f"Expected `half_angle_deg` in [0, 90), got {half_angle_deg!r}")
        self.scene = "coning"
        self.duration_s = float(duration_s)
        self.half_angle_rad = math.radians(half_angle_deg)
        self.freq_hz = float(freq_hz)
        self.params: dict[str, Any] = {
            "half_angle_deg": float(half_angle_deg),
            "freq_hz": float(freq_hz),
        }

    def at(self, t_s: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        t = self._check_times(t_s)
        return (
            coning_attitude(t, self.half_angle_rad, self.freq_hz),
            coning_rates(t, self.half_angle_rad, self.freq_hz),
        )

    def delta_angles(self, t_s: ArrayLike) -> NDArray[np.float64]:
        t = self._check_times(t_s, increasing=True)
        om = 2.0 * math.pi * self.freq_hz
        a, b = om * t[:-1], om * t[1:]
        sb, cb = math.sin(self.half_angle_rad), math.cos(self.half_angle_rad)
        # ∫ -sinβ Ω sin(Ωt) = sinβ (cos b − cos a) = −2 sinβ sin((a+b)/2) sin((b−a)/2), written in
        # product form so that short intervals do not lose digits to cancellation.
        s_half = np.sin(0.5 * (b - a))
        mid = 0.5 * (a + b)
        return np.stack(
            [
                -2.0 * sb * np.sin(mid) * s_half,
                2.0 * sb * np.cos(mid) * s_half,
                (cb - 1.0) * om * (t[1:] - t[:-1]),
            ],
            axis=-1,
        )


# --------------------------------------------------------------------------------------------
# Torque-free symmetric top (I1 = I2)
# --------------------------------------------------------------------------------------------


def symmetric_free_top(
    t_s: ArrayLike, i1_kg_m2: float, i3_kg_m2: float, omega0_b: ArrayLike, q0_w_b: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Closed-form torque-free motion of a symmetric body (``I1 = I2``).

    ``ω_b = L_b / I1 − Ω_b ẑ`` with ``Ω_b = (I3 − I1) ω3 / I1``: the body turns about the fixed
    world angular momentum at ``|L| / I1`` and about its own symmetry axis at ``−Ω_b``, so
    ``R_w_b(t) = exp(t |L|/I1 [n_w×]) R_w_b(0) Rz(−Ω_b t)`` with ``n_w = L_w / |L|``, and
    ``ω_b(t) = Rz(Ω_b t) (ω1(0), ω2(0), ·) + ω3 ẑ``.

    Parameters
    ----------
    t_s : array_like, shape (N,)
    i1_kg_m2, i3_kg_m2 : float
        Transverse and axial moments, kg·m².
    omega0_b : array_like, shape (3,)
        Initial body rate, rad/s.
    q0_w_b : array_like, shape (4,)
        Initial attitude ``[x, y, z, w]``.

    Returns
    -------
    q_w_b : ndarray, shape (N, 4)
    omega_b : ndarray, shape (N, 3)
    """
    t = np.asarray(t_s, dtype=float)
    w0 = np.asarray(omega0_b, dtype=float)
    q0 = np.asarray(q0_w_b, dtype=float)
    l_b = np.array([i1_kg_m2 * w0[0], i1_kg_m2 * w0[1], i3_kg_m2 * w0[2]])
    l_norm = float(np.linalg.norm(l_b))
    n_w = quat_rotate(q0, l_b) / l_norm
    rate_l = l_norm / i1_kg_m2
    omega_body_axis = (i3_kg_m2 - i1_kg_m2) * w0[2] / i1_kg_m2
    q_l = exp_quat(t[:, None] * rate_l * n_w[None, :])
    q = quat_multiply(quat_multiply(q_l, q0), axis_quat(2, -omega_body_axis * t))
    c, s = np.cos(omega_body_axis * t), np.sin(omega_body_axis * t)
    omega = np.stack(
        [c * w0[0] - s * w0[1], s * w0[0] + c * w0[1], np.full_like(t, w0[2])], axis=-1
    )
    return q, omega


# --------------------------------------------------------------------------------------------
# Torque-free asymmetric body: Jacobi elliptic rates
# --------------------------------------------------------------------------------------------

#: ``R_b_b'`` of the relabelled frame ``(x', y', z') = (z, −y, x)`` (180° about (1, 0, 1)/√2),
#: used when the body rotates on the minor-axis side of the separatrix (``M² < 2 E I2``).
_SWAP = np.array([[0.0, 0.0, 1.0], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0]])
_Q_SWAP = np.array([math.sqrt(0.5), 0.0, math.sqrt(0.5), 0.0])


def _box_side(inertia_kg_m2: ArrayLike, omega0_b: ArrayLike) -> bool:
    """Validate a torque-free asymmetric body; True when it turns on the ``I1`` side."""
    inertia = np.asarray(inertia_kg_m2, dtype=float)
    w = np.asarray(omega0_b, dtype=float)
    if inertia.shape != (3,) or not inertia[0] < inertia[1] < inertia[2] or inertia[0] <= 0:
        raise InputError(f"Expected 0 < I1 < I2 < I3, got {inertia.tolist()}")
    if w.shape != (3,) or not np.all(np.isfinite(w)):
        raise InputError(f"Expected `omega0_b` three finite rates, got {w.tolist()}")
    two_e = float(np.sum(inertia * w * w))
    m2 = float(np.sum((inertia * w) ** 2))
    if abs(m2 - two_e * inertia[1]) <= 1e-12 * m2:
        raise InputError(
            f"Expected M² != 2 E I2 (not on the separatrix), got M² = {m2}, "
            f"2 E I2 = {two_e * inertia[1]}"
        )
    return m2 < two_e * inertia[1]


def _box_elements(inertia: NDArray, w: NDArray) -> dict[str, float]:
    """Elliptic elements of ``ω = (s1 A1 cn, s2 A2 sn, s3 A3 dn)(λ t + τ0 | m)``.

    Valid in a frame whose third axis is the one ω stays near: ``I1 < I2 < I3`` with
    ``M² > 2 E I2``, or ``I1 > I2 > I3`` with ``M² < 2 E I2`` (all square-root arguments are
    then positive). Signs from Euler's equations with ``d cn = −sn dn``, ``d sn = cn dn``:
    ``s2 = s1 s3 sign(I3 − I1)``.
    """
    i1, i2, i3 = (float(v) for v in inertia)
    two_e = i1 * w[0] ** 2 + i2 * w[1] ** 2 + i3 * w[2] ** 2
    m2 = (i1 * w[0]) ** 2 + (i2 * w[1]) ** 2 + (i3 * w[2]) ** 2
    a1sq = (two_e * i3 - m2) / (i1 * (i3 - i1))
    a2sq = (two_e * i3 - m2) / (i2 * (i3 - i2))
    a3sq = (m2 - two_e * i1) / (i3 * (i3 - i1))
    lam = math.sqrt((i3 - i2) * (m2 - two_e * i1) / (i1 * i2 * i3))
    m = (i2 - i1) * (two_e * i3 - m2) / ((i3 - i2) * (m2 - two_e * i1))
    s3 = 1.0 if w[2] >= 0 else -1.0
    s1 = 1.0
    s2 = s1 * s3 * (1.0 if i3 > i1 else -1.0)
    a1, a2 = math.sqrt(a1sq), math.sqrt(a2sq)
    # Amplitude am(τ0): sin = sn(τ0), cos = cn(τ0); τ0 = F(am | m), extended by 2K per π.
    am0 = math.atan2(w[1] / (s2 * a2), w[0] / (s1 * a1))
    k = round(am0 / math.pi)
    tau0 = 2.0 * k * float(ellipk(m)) + float(ellipkinc(am0 - k * math.pi, m))
    return {
        "i1": i1,
        "i2": i2,
        "i3": i3,
        "m2": m2,
        "a1sq": a1sq,
        "a2sq": a2sq,
        "a1": a1,
        "a2": a2,
        "a3": math.sqrt(a3sq),
        "lam": lam,
        "m": m,
        "s1": s1,
        "s2": s2,
        "s3": s3,
        "am0": am0,
        "tau0": tau0,
    }


def _omega_core(t: NDArray, e: dict[str, float]) -> NDArray[np.float64]:
    sn, cn, dn, _ = ellipj(e["lam"] * t + e["tau0"], e["m"])
    return np.stack(
        [e["s1"] * e["a1"] * cn, e["s2"] * e["a2"] * sn, e["s3"] * e["a3"] * dn], axis=-1
    )


def box_omega_elliptic(
    t_s: ArrayLike, inertia_kg_m2: ArrayLike, omega0_b: ArrayLike
) -> NDArray[np.float64]:
    """Body rate of a torque-free asymmetric body by Jacobi elliptic functions (docs/design.md,
    "Ground truth").

    For ``I1 < I2 < I3`` and ``M² > 2 E I2`` (the body turns on the major-axis side of the
    separatrix): ``ω = (s1 A1 cn, s2 A2 sn, s3 A3 dn)(λ t + τ0 | m)``, with the amplitudes,
    ``λ`` and ``m`` of docs/design.md ("Ground truth") and the phase ``τ0`` and signs fitted to
    ``omega0_b``. For ``M² < 2 E I2`` the same solution in the relabelled frame ``(z, −y, x)``
    (``dn`` on x).

    Parameters
    ----------
    t_s : array_like, shape (N,)
    inertia_kg_m2 : array_like, shape (3,)
        Principal moments, strictly increasing, kg·m².
    omega0_b : array_like, shape (3,)
        Initial body rate, rad/s, not on the separatrix (``M² ≠ 2 E I2``).

    Returns
    -------
    ndarray, shape (N, 3), rad/s
    """
    t = np.asarray(t_s, dtype=float)
    inertia = np.asarray(inertia_kg_m2, dtype=float)
    w = np.asarray(omega0_b, dtype=float)
    if _box_side(inertia, w):
        return _omega_core(t, _box_elements(inertia[::-1], _SWAP @ w)) @ _SWAP
    return _omega_core(t, _box_elements(inertia, w))


def _legendre_pi(n: float, phi: NDArray, m: float) -> NDArray:
    """Incomplete elliptic integral of the third kind ``Π(n; φ | m)`` for any real ``φ``.

    ``Π = s R_F(c², 1 − m s², 1) + (n/3) s³ R_J(c², 1 − m s², 1, 1 − n s²)`` (Carlson forms,
    ``s = sin φ``, ``c = cos φ``) on ``|φ| <= π/2``, extended by ``Π(φ + kπ) = Π(φ) + 2k Π(n|m)``.
    """
    k = np.round(phi / np.pi)
    p = phi - k * np.pi
    s, c = np.sin(p), np.cos(p)
    a, b = c * c, 1.0 - m * s * s
    inc = s * elliprf(a, b, 1.0) + n / 3.0 * s**3 * elliprj(a, b, 1.0, 1.0 - n * s * s)
    complete = float(elliprf(0.0, 1.0 - m, 1.0) + n / 3.0 * elliprj(0.0, 1.0 - m, 1.0, 1.0 - n))
    return inc + 2.0 * k * complete


def _attitude_core(
    t: NDArray, e: dict[str, float], w0: NDArray, q0: NDArray
) -> NDArray[np.float64]:
    i1, i2, i3 = e["i1"], e["i2"], e["i3"]
    big_m = math.sqrt(e["m2"])
    a, b = i1 * e["a1sq"], i2 * e["a2sq"] - i1 * e["a1sq"]
    c, d = i1 * i1 * e["a1sq"], i2 * i2 * e["a2sq"] - i1 * i1 * e["a1sq"]
    _, _, _, am = ellipj(e["lam"] * t + e["tau0"], e["m"])
    n = -d / c  # c + d sn² > 0 everywhere, so 1 − n sn² > 0: Π has no pole on the path
    phi = big_m * b / d * t + big_m * (a - b * c / d) / (c * e["lam"]) * (
        _legendre_pi(n, am, e["m"]) - _legendre_pi(n, np.array([e["am0"]]), e["m"])[0]
    )
    w = _omega_core(t, e)
    theta = np.arccos(np.clip(i3 * w[:, 2] / big_m, -1.0, 1.0))
    psi = np.arctan2(i1 * w[:, 0], i2 * w[:, 1])
    q_l_b = zxz_quat(phi, theta, psi)
    th0 = math.acos(max(-1.0, min(1.0, i3 * w0[2] / big_m)))
    ps0 = math.atan2(i1 * w0[0], i2 * w0[1])
    q_l_b0 = quat_multiply(axis_quat(0, th0), axis_quat(2, ps0))
    q_w_l = quat_multiply(q0, quat_conjugate(q_l_b0))
    return quat_multiply(q_w_l, q_l_b)


def box_attitude_elliptic(
    t_s: ArrayLike, inertia_kg_m2: ArrayLike, omega0_b: ArrayLike, q0_w_b: ArrayLike
) -> NDArray[np.float64]:
    """Attitude of a torque-free asymmetric body in closed form (elliptic integrals).

    In a frame ``L`` with z along the angular momentum, the z-x-z Euler angles of the body are
    ``cos θ = I3 ω3 / M``, ``ψ = atan2(I1 ω1, I2 ω2)`` (algebraic in the elliptic rates of
    :func:`box_omega_elliptic`) and ``φ̇ = M (I1 ω1² + I2 ω2²)/(I1² ω1² + I2² ω2²)``. With
    ``ω1 = A1 cn, ω2 = A2 sn`` this is ``M (a + b sn²)/(c + d sn²)``, whose integral is
    ``M b/d t + M (a − b c/d)/(c λ) [Π(−d/c; am(λt + τ0)) − Π(−d/c; am(τ0))]`` (van Zon &
    Schofield, J. Comput. Phys. 225, 2007), with Π in Carlson's forms. Then
    ``R_w_b(t) = R_w_L Rz(φ) Rx(θ) Rz(ψ)``, ``R_w_L`` fixed by ``q0_w_b`` and ``φ(0) = 0``.
    On the minor-axis side (``M² < 2 E I2``) the same in the frame ``(z, −y, x)``.

    Parameters
    ----------
    t_s : array_like, shape (N,)
    inertia_kg_m2 : array_like, shape (3,)
        ``I1 < I2 < I3``, kg·m².
    omega0_b : array_like, shape (3,)
        Initial body rate, rad/s (``M² ≠ 2 E I2``).
    q0_w_b : array_like, shape (4,)
        Initial attitude ``[x, y, z, w]``.

    Returns
    -------
    ndarray, shape (N, 4)
        ``q_w_b(t)``.
    """
    t = np.asarray(t_s, dtype=float)
    inertia = np.asarray(inertia_kg_m2, dtype=float)
    w = np.asarray(omega0_b, dtype=float)
    q0 = np.asarray(q0_w_b, dtype=float)
    if _box_side(inertia, w):
        w_p = _SWAP @ w  # body rates in the relabelled frame; q_w_b' = q_w_b ⊗ q_swap
        q_p = _attitude_core(t, _box_elements(inertia[::-1], w_p), w_p, quat_multiply(q0, _Q_SWAP))
        return quat_multiply(q_p, quat_conjugate(_Q_SWAP))
    return _attitude_core(t, _box_elements(inertia, w), w, q0)


# --------------------------------------------------------------------------------------------
# Heavy symmetric top
# --------------------------------------------------------------------------------------------


def steady_precession_rates(
    i1_kg_m2: float, i3_kg_m2: float, omega3_rad_s: float, mgl_n_m: float, tilt_rad: float
) -> tuple[float, float]:
    """Steady-precession rates ``φ̇`` (slow, fast), rad/s, of a heavy symmetric top.

    Roots of ``I1 cosθ0 φ̇² − I3 ω3 φ̇ + M g l = 0``; real when
    ``(I3 ω3)² ≥ 4 I1 M g l cosθ0``. For ``cosθ0 = 0`` only the slow root exists (``fast`` is
    ``inf``).

    Raises
    ------
    InputError
        When no real root exists (the top is too slow for steady precession at this tilt).
    """
    c = math.cos(tilt_rad)
    p = i3_kg_m2 * omega3_rad_s
    if abs(c) < 1e-15:
        return mgl_n_m / p, math.inf
    disc = p * p - 4.0 * i1_kg_m2 * mgl_n_m * c
    if disc < 0:
        raise InputError(
            f"Expected (I3 ω3)² >= 4 I1 M g l cos(tilt) for steady precession, got "
            f"{p * p:.6g} < {4.0 * i1_kg_m2 * mgl_n_m * c:.6g}"
        )
    r = math.sqrt(disc)
    # Numerically stable pair: the small root as 2c/(−b ± √disc).
    big = (p + math.copysign(r, p)) / (2.0 * i1_kg_m2 * c)
    small = mgl_n_m / (i1_kg_m2 * c * big)
    return (small, big) if abs(small) <= abs(big) else (big, small)


@dataclass(frozen=True)
class HeavyTopInvariants:
    """Goldstein's constants of a heavy symmetric top (all per unit ``I1``).

    ``u = cos θ`` obeys ``u̇² = f(u) = (1 − u²)(α − β u) − (b − a u)²`` and
    ``φ̇ = (b − a u)/(1 − u²)``.

    Attributes
    ----------
    a : float
        ``I3 ω3 / I1``, 1/s.
    b : float
        ``L_z / I1``, 1/s (world-vertical angular momentum).
    alpha : float
        ``2 E' / I1`` with ``E' = E − ½ I3 ω3²``, 1/s².
    beta : float
        ``2 M g l / I1``, 1/s².
    roots : tuple of float
        Roots ``u1 <= u2 <= u3`` of ``f`` (``u1, u2`` in [−1, 1] are the turning points).
    """

    a: float
    b: float
    alpha: float
    beta: float
    roots: tuple[float, float, float]


def heavy_top_invariants(
    i1_kg_m2: float,
    i3_kg_m2: float,
    mgl_n_m: float,
    tilt_rad: float,
    omega3_rad_s: float,
    precession0_rad_s: float,
    nutation0_rad_s: float = 0.0,
) -> HeavyTopInvariants:
    """Constants of motion and turning points from the initial Euler-angle state."""
    u0 = math.cos(tilt_rad)
    s2 = 1.0 - u0 * u0
    a = i3_kg_m2 * omega3_rad_s / i1_kg_m2
    beta = 2.0 * mgl_n_m / i1_kg_m2
    b = precession0_rad_s * s2 + a * u0
    alpha = nutation0_rad_s**2 + precession0_rad_s**2 * s2 + beta * u0
    # f(u) = β u³ − (α + a²) u² + (2ab − β) u + (α − b²)
    roots = np.sort(np.roots([beta, -(alpha + a * a), 2.0 * a * b - beta, alpha - b * b]).real)
    return HeavyTopInvariants(
        a, b, alpha, beta, (float(roots[0]), float(roots[1]), float(roots[2]))
    )


def heavy_top_cos_theta(
    t_s: ArrayLike, inv: HeavyTopInvariants, start_at_upper: bool = True
) -> NDArray[np.float64]:
    """``cos θ(t)`` of the heavy top by Jacobi's ``sn``: ``u = u1 + (u2 − u1) sn²(λ(t−t0) | m)``.

    ``λ = ½ √(β (u3 − u1))``, ``m = (u2 − u1)/(u3 − u1)``. The top starts at rest in ``θ``
    (``θ̇(0) = 0``) at its upper turning point ``u2`` (``start_at_upper``, ``t0 = −K/λ``) or its
    lower one ``u1`` (``t0 = 0``).
    """
    u1, u2, u3 = inv.roots
    lam = 0.5 * math.sqrt(inv.beta * (u3 - u1))
    m = (u2 - u1) / (u3 - u1)
    shift = float(ellipk(m)) if start_at_upper else 0.0
    sn, _, _, _ = ellipj(lam * np.asarray(t_s, dtype=float) + shift, m)
    return u1 + (u2 - u1) * sn * sn

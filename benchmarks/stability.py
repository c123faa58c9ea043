"""Stability study: small scenes where attitude integration methods fail, and where they do not.

Eight scenes (issue 6), each a pure function returning a frozen result that both the charts
(:func:`run`) and ``tests/test_stability.py`` use:

1. :func:`gimbal_lock` — integrating ZXZ Euler angles (the reference document's comparison
   method) past ``θ = 0`` against the DCM recursion, as the body's z axis passes the vertical.
2. :func:`rotvec_sum_shortcut` — the rotation-vector-sum shortcut (the reference document's
   eq. 13) under coning, against its analytic error ``(1 − cos β) Ω t``.
3. :func:`large_steps` — steps with ``|ω| dt`` from 0.01 to 3 rad.
4. :func:`long_run` and :func:`naive_dcm_drift` — 10⁷ steps: error against truth, and how far the
   reference document's un-normalised 3x3 product leaves SO(3).
5. :func:`free_box` — flips about the free box's intermediate axis (Dzhanibekov), checked by
   conservation of the world angular momentum.
6. :func:`steady_top` — the sleeping top and the fast top at high spin (closed-form steady
   precession).
7. :func:`noise_growth` — attitude-error growth under white rate noise (``√T``) and bias (``T``).
8. :func:`truncated_update` — the first-order truncated quaternion step
   ``q ← normalise(q + ½ q ⊗ [ω dt, 0])`` against the exact exponential.

Conventions (DESIGN.md §3): quaternions Hamilton ``[x, y, z, w]``; ``q_w_b`` maps body to world;
``omega_b`` is the body rate relative to the world in body axes, rad/s; increments multiply on
the right, ``q_{i+1} = q_i ⊗ exp(φ_i)``; world ENU, z up; times ``t_s`` in seconds. ZXZ Euler
angles ``(φ, θ, ψ)`` are intrinsic: ``R_w_b = Rz(φ) · Rx(θ) · Rz(ψ)``.

The truths here are closed forms (coning, steady precession, composed fixed-axis rotations) or
conservation laws, so every scene is independent of the simulator in ``data_synth``.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

import imu_dcm
from data_synth.analytic import coning_attitude, coning_rates, steady_precession_rates
from data_synth.scenes import HeavyTopParams, box_inertia, free_body
from imu_dcm.metrics import attitude_error_deg
from imu_dcm.so3 import exp_matrix, quat_multiply

__all__ = [
    "DCM_METHODS",
    "coning_truth",
    "euler_zxz_integrate",
    "free_box",
    "gimbal_lock",
    "gimbal_motion",
    "large_steps",
    "long_run",
    "naive_dcm_drift",
    "noise_growth",
    "rotvec_sum_shortcut",
    "run",
    "steady_top",
    "truncated_first_order",
    "truncated_update",
    "zxz_quat",
    "zxz_truth",
]

#: The imu_dcm methods compared in the scenes (``rotvec_sum`` has its own scene).
DCM_METHODS = ("start", "end", "trapezoid", "coning", "magnus4")

#: The reference document's heavy top (DESIGN.md §5), as data_synth defines it.
TOP = HeavyTopParams()

#: Principal inertias (kg m²) of the free box, edges 2.0, 1.5, 1.0 m, 1 kg (DESIGN.md §5).
BOX_INERTIA = box_inertia((2.0, 1.5, 1.0), 1.0)

_EPS = float(np.finfo(float).eps)


# ----------------------------------------------------------------------------------------------
# Closed-form motions
# ----------------------------------------------------------------------------------------------

def _axis_quat(angle_rad: NDArray, axis: int) -> NDArray:
    """Quaternions ``[x, y, z, w]`` of rotations by ``angle_rad`` (shape (N,)) about a body axis."""
    a = np.asarray(angle_rad, dtype=float)
    q = np.zeros(a.shape + (4,))
    q[..., axis] = np.sin(0.5 * a)
    q[..., 3] = np.cos(0.5 * a)
    return q


def zxz_quat(phi: NDArray, theta: NDArray, psi: NDArray) -> NDArray:
    """``q_w_b`` of intrinsic ZXZ Euler angles, ``Rz(φ) · Rx(θ) · Rz(ψ)``, shape (N, 4) xyzw."""
    return quat_multiply(quat_multiply(_axis_quat(phi, 2), _axis_quat(theta, 0)),
                         _axis_quat(psi, 2))


def zxz_truth(phi: NDArray, theta: NDArray, psi: NDArray, dphi: NDArray, dtheta: NDArray,
              dpsi: NDArray) -> tuple[NDArray, NDArray]:
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
    omega_b = np.stack([dphi * np.sin(theta) * s + dtheta * c,
                        dphi * np.sin(theta) * c - dtheta * s,
                        dphi * np.cos(theta) + dpsi], axis=-1)
    return zxz_quat(phi, theta, psi), omega_b


def coning_truth(t_s: NDArray, half_angle_rad: float, freq_rad_s: float) -> tuple[NDArray, NDArray]:
    """Pure coning ``R_w_b(t) = Rz(Ωt) Rx(β) Rz(−Ωt)``: ``(q_w_b (N, 4), omega_b (N, 3) rad/s)``.

    The closed form of :mod:`data_synth.analytic` (DESIGN.md §5), with ``Ω`` in rad/s.
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


# ----------------------------------------------------------------------------------------------
# 1. Gimbal lock: ZXZ Euler angles past θ = 0
# ----------------------------------------------------------------------------------------------

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


@dataclass(frozen=True)
class GimbalLockResult:
    """Scene 1. Errors (deg) of Euler-angle and DCM integration of the same samples.

    Attributes
    ----------
    closest_deg : closest approach of the body z axis to the world vertical (min θ), deg.
    rate_hz : sample rate, Hz.
    t_s : (N,) sample times, s.
    theta_deg : (N,) true nutation angle θ, deg.
    euler_err_deg, dcm_err_deg : (N,) total attitude error of Euler-angle (Heun) and DCM
        ``trapezoid`` integration, deg (180 where the Euler angles became NaN/inf).
    """

    closest_deg: float
    rate_hz: float
    t_s: NDArray
    theta_deg: NDArray
    euler_err_deg: NDArray
    dcm_err_deg: NDArray

    @property
    def euler_max_deg(self) -> float:
        return float(np.max(self.euler_err_deg))

    @property
    def dcm_max_deg(self) -> float:
        return float(np.max(self.dcm_err_deg))


#: Gimbal-lock scene motion: tilt rate about world-ish y (rad/s), spin about body z (rad/s), s.
GIMBAL_TILT_RATE, GIMBAL_SPIN_RATE, GIMBAL_DURATION_S = 0.5, 2.0, 2.0


def gimbal_motion(t_s: NDArray, closest_rad: float) -> tuple[NDArray, NDArray]:
    """Smooth motion whose z axis passes ``closest_rad`` from the vertical at mid-time.

    ``R_w_b(t) = Rx(ε) · Ry(a(t)) · Rz(s t)`` with ``a = c (t − T/2)``; the body rate is
    ``ω_b = (c sin st, c cos st, s)`` (constant magnitude, smooth), while the ZXZ angle φ swings by
    ~π within ``~ε/c`` seconds of the closest approach.
    """
    t_s = np.asarray(t_s, dtype=float)
    c, s = GIMBAL_TILT_RATE, GIMBAL_SPIN_RATE
    a = c * (t_s - 0.5 * GIMBAL_DURATION_S)
    b = s * t_s
    q = quat_multiply(quat_multiply(_axis_quat(np.full_like(t_s, closest_rad), 0),
                                    _axis_quat(a, 1)), _axis_quat(b, 2))
    w = np.stack([c * np.sin(b), c * np.cos(b), np.full_like(t_s, s)], axis=-1)
    return q, w


def gimbal_lock(closest_deg: float, rate_hz: float) -> GimbalLockResult:
    """Scene 1: Euler-angle (ZXZ, Heun) against DCM ``trapezoid`` through near-gimbal-lock."""
    t = _uniform_t(rate_hz, GIMBAL_DURATION_S)
    q_true, w = gimbal_motion(t, math.radians(closest_deg))
    ang0 = Rotation.from_quat(q_true[0]).as_euler("ZXZ")
    ang = euler_zxz_integrate(w, t, ang0)
    with np.errstate(invalid="ignore", over="ignore"):
        q_euler = zxz_quat(ang[:, 0], ang[:, 1], ang[:, 2])
    theta = np.degrees(np.arccos(np.clip(Rotation.from_quat(q_true).as_matrix()[:, 2, 2], -1, 1)))
    return GimbalLockResult(closest_deg, rate_hz, t, theta, _err_deg(q_euler, q_true),
                            _err_deg(_integrate_q(w, t, q_true[0], "trapezoid"), q_true))


# ----------------------------------------------------------------------------------------------
# 2. The rotation-vector-sum shortcut (eq. 13)
# ----------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class RotvecSumResult:
    """Scene 2. Coning with half-angle β at Ω; errors (deg) over time.

    Attributes
    ----------
    t_s : (N,) times, s.
    rotvec_sum_err_deg, magnus4_err_deg : (N,) total error of eq. 13 and of ``magnus4``, deg.
    predicted_deg : (N,) analytic error of eq. 13 at whole cone cycles, ``(1 − cos β) Ω t``
        wrapped to [0, 180] deg (valid where ``t`` is a whole number of cycles).
    fixed_axis_err_deg : max error of eq. 13 for a fixed-axis rotation (commuting), deg.
    """

    t_s: NDArray
    rotvec_sum_err_deg: NDArray
    magnus4_err_deg: NDArray
    predicted_deg: NDArray
    fixed_axis_err_deg: float


def _wrap_deg(angle_rad: NDArray) -> NDArray:
    a = np.mod(np.asarray(angle_rad), 2.0 * np.pi)
    return np.degrees(np.minimum(a, 2.0 * np.pi - a))


def rotvec_sum_shortcut(half_angle_deg: float = 30.0, freq_hz: float = 1.0,
                        rate_hz: float = 1000.0, duration_s: float = 5.0) -> RotvecSumResult:
    """Scene 2: eq. 13 ``R = R0 · exp(Σ ω dt)`` under coning and under a fixed-axis rotation."""
    t = _uniform_t(rate_hz, duration_s)
    beta, big_w = math.radians(half_angle_deg), 2.0 * math.pi * freq_hz
    q_true, w = coning_truth(t, beta, big_w)
    err_sum = _err_deg(_integrate_q(w, t, q_true[0], "rotvec_sum"), q_true)
    err_m4 = _err_deg(_integrate_q(w, t, q_true[0], "magnus4"), q_true)
    pred = _wrap_deg((1.0 - math.cos(beta)) * big_w * t)
    # Commuting case: a fixed body axis at 2 rad/s, truth exp(ω t).
    axis = np.array([1.0, 2.0, 2.0]) / 3.0
    wf = np.tile(2.0 * axis, (len(t), 1))
    qf = Rotation.from_rotvec(t[:, None] * wf).as_quat()
    fixed = float(np.max(_err_deg(_integrate_q(wf, t, qf[0], "rotvec_sum"), qf)))
    return RotvecSumResult(t, err_sum, err_m4, pred, fixed)


# ----------------------------------------------------------------------------------------------
# 3. Large steps, 8. truncated first-order updates
# ----------------------------------------------------------------------------------------------

def truncated_first_order(omega_b: NDArray, t_s: NDArray, q0: NDArray,
                          normalise: bool = True) -> NDArray:
    """First-order truncated quaternion update, per sample (how imufusion-style filters step).

    ``q_{i+1} = q_i + ½ q_i ⊗ [ω_{i+1} dt, 0]``, then normalised (unless ``normalise=False``):
    the rate at the end of the step, as the reference document's rule, so the only difference
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
        x, y, z, s = (x + s * a + y * c - z * b, y + s * b + z * a - x * c,
                      z + s * c + x * b - y * a, s - x * a - y * b - z * c)
        if normalise:
            n = math.sqrt(x * x + y * y + z * z + s * s)
            x, y, z, s = x / n, y / n, z / n, s / n
        out[i] = (x, y, z, s)
    return out


#: Large-step scene motion (steady precession): φ̇ rad/s, θ rad, ψ̇ rad/s; duration s.
LARGE_PHI_RATE, LARGE_TILT, LARGE_PSI_RATE, LARGE_DURATION_S = 2 * np.pi, np.radians(30), 0.2 * np.pi, 5.0


def _large_step_motion(t_s: NDArray) -> tuple[NDArray, NDArray]:
    n = len(t_s)
    return zxz_truth(LARGE_PHI_RATE * t_s, np.full(n, LARGE_TILT), LARGE_PSI_RATE * t_s,
                     np.full(n, LARGE_PHI_RATE), np.zeros(n), np.full(n, LARGE_PSI_RATE))


@dataclass(frozen=True)
class LargeStepsResult:
    """Scene 3. Max error (deg) per method against step size ``|ω| dt`` (rad).

    Attributes
    ----------
    step_rad : (K,) ``|ω| dt`` of each run, rad.
    err_deg : dict method -> (K,) max total error over the run, deg. Methods: ``DCM_METHODS``
        and ``truncated`` (first-order truncated update, normalised).
    max_norm_dev : dict method -> (K,) max ``| |q| − 1 |`` of the returned quaternions.
    """

    step_rad: NDArray
    err_deg: dict[str, NDArray]
    max_norm_dev: dict[str, NDArray]


def large_steps(steps_rad: Sequence[float] = tuple(np.geomspace(0.01, 3.0, 13))) -> LargeStepsResult:
    """Scene 3: steady precession (|ω| constant, ω turning in the body at ψ̇ = |φ̇|/10)."""
    w_norm = float(np.linalg.norm(_large_step_motion(np.zeros(1))[1][0]))
    names = DCM_METHODS + ("truncated",)
    err = {m: np.empty(len(steps_rad)) for m in names}
    dev = {m: np.empty(len(steps_rad)) for m in names}
    for k, step in enumerate(steps_rad):
        dt = step / w_norm
        t = np.arange(int(LARGE_DURATION_S / dt) + 1) * dt
        q_true, w = _large_step_motion(t)
        for m in names:
            if m == "truncated":
                q = truncated_first_order(w, t, q_true[0])
            else:
                q = _integrate_q(w, t, q_true[0], m)
            err[m][k] = np.max(_err_deg(q, q_true))
            dev[m][k] = np.max(np.abs(np.linalg.norm(q, axis=1) - 1.0))
    return LargeStepsResult(np.asarray(steps_rad, dtype=float), err, dev)


@dataclass(frozen=True)
class TruncatedResult:
    """Scene 8. Constant spin ``|ω|`` about a fixed axis, ``n_steps`` steps of ``|ω| dt``.

    Attributes
    ----------
    step_rad : (K,) step angles ``|ω| dt``, rad.
    truncated_err_deg, exact_err_deg : (K,) final error of the truncated update (normalised) and
        of the exact exponential (``end`` method), deg.
    predicted_deg : (K,) analytic error of the truncated update: each normalised step turns by
        ``2 atan(|ω| dt / 2)`` instead of ``|ω| dt``, so ``n (|ω|dt − 2 atan(|ω|dt/2))``, wrapped.
    unnormalised_norm, predicted_norm : (K,) final ``|q|`` without normalisation, and its law
        ``(1 + (|ω| dt)²/4)^(n/2)``.
    n_steps : number of steps.
    """

    step_rad: NDArray
    truncated_err_deg: NDArray
    exact_err_deg: NDArray
    predicted_deg: NDArray
    unnormalised_norm: NDArray
    predicted_norm: NDArray
    n_steps: int


def truncated_update(steps_rad: Sequence[float] = tuple(np.geomspace(0.001, 1.0, 10)),
                     n_steps: int = 1000) -> TruncatedResult:
    """Scene 8: the truncated step against the exact exponential on a fixed-axis spin."""
    axis = np.array([2.0, -1.0, 2.0]) / 3.0
    rate_rad_s = 10.0
    q0 = np.array([0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)])  # 90° about z
    tr, ex, pr, nn, pn = (np.empty(len(steps_rad)) for _ in range(5))
    for k, step in enumerate(steps_rad):
        t = np.arange(n_steps + 1) * (step / rate_rad_s)
        w = np.tile(rate_rad_s * axis, (n_steps + 1, 1))
        q_true = quat_multiply(q0, Rotation.from_rotvec(rate_rad_s * t[:, None] * axis).as_quat())
        tr[k] = _err_deg(truncated_first_order(w, t, q0), q_true)[-1]
        ex[k] = _err_deg(_integrate_q(w, t, q0, "end"), q_true)[-1]
        pr[k] = _wrap_deg(n_steps * (step - 2.0 * math.atan(0.5 * step)))
        nn[k] = np.linalg.norm(truncated_first_order(w, t, q0, normalise=False)[-1])
        pn[k] = (1.0 + 0.25 * step * step) ** (0.5 * n_steps)
    return TruncatedResult(np.asarray(steps_rad, float), tr, ex, pr, nn, pn, n_steps)


# ----------------------------------------------------------------------------------------------
# 4. Long runs
# ----------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class LongRunResult:
    """Scene 4. ``n_steps`` steps of coning through the batch integrator, in chunks.

    Attributes
    ----------
    n_steps, rate_hz, method : run size, sample rate (Hz), imu_dcm method.
    step_idx : (K,) step index at each checkpoint (chunk ends).
    err_deg : (K,) total error against the closed-form coning truth at the checkpoints, deg.
    orthonormality : (K,) ``max |Rᵀ R − I|`` of the integrator's attitude as a matrix.
    """

    n_steps: int
    rate_hz: float
    method: str
    step_idx: NDArray
    err_deg: NDArray
    orthonormality: NDArray


#: Long-run coning: half-angle rad, frequency rad/s.
LONG_BETA, LONG_OMEGA = math.radians(1.0), 2.0 * math.pi * 0.5


def long_run(n_steps: int = 10_000_000, rate_hz: float = 1000.0, method: str = "coning",
             chunk: int = 1_000_000) -> LongRunResult:
    """Scene 4: integrate ``n_steps`` coning steps chunk by chunk (each chunk starts where the last
    ended, its first sample shared), comparing with the closed form at every chunk end."""
    q = coning_truth(np.zeros(1), LONG_BETA, LONG_OMEGA)[0][0]
    idx, errs, orth = [], [], []
    start = 0
    while start < n_steps:
        stop = min(start + chunk, n_steps)
        t = np.arange(start, stop + 1) / rate_hz
        _q_true, w = coning_truth(t, LONG_BETA, LONG_OMEGA)
        q = _integrate_q(w, t, q, method)[-1]
        q_true_end = coning_truth(t[-1:], LONG_BETA, LONG_OMEGA)[0][0]
        r = Rotation.from_quat(q).as_matrix()
        idx.append(stop)
        errs.append(float(_err_deg(q, q_true_end)))
        orth.append(float(np.max(np.abs(r.T @ r - np.eye(3)))))
        start = stop
    return LongRunResult(n_steps, rate_hz, method, np.array(idx), np.array(errs), np.array(orth))


@dataclass(frozen=True)
class NaiveDcmResult:
    """Scene 4b. The reference document's loop, ``R ← R · CK(ω dt)``, never re-orthonormalised.

    Attributes
    ----------
    step_idx : (K,) checkpoints (step counts).
    orthonormality : (K,) ``max |Rᵀ R − I|`` at the checkpoints.
    err_deg : (K,) attitude error of the (orthonormalised) matrix against the coning truth, deg.
    """

    step_idx: NDArray
    orthonormality: NDArray
    err_deg: NDArray


def naive_dcm_drift(n_steps: int, rate_hz: float = 1000.0, n_checkpoints: int = 12,
                    chunk: int = 100_000) -> NaiveDcmResult:
    """Scene 4b: sequential 3x3 products of Rodrigues matrices (``end`` rule), no correction."""
    checks = np.unique(np.geomspace(10, n_steps, n_checkpoints).astype(int))
    r = Rotation.from_quat(coning_truth(np.zeros(1), LONG_BETA, LONG_OMEGA)[0][0]).as_matrix()
    orth, errs = [], []
    ci = 0
    for start in range(0, n_steps, chunk):
        stop = min(start + chunk, n_steps)
        t = np.arange(start, stop + 1) / rate_hz
        _q, w = coning_truth(t, LONG_BETA, LONG_OMEGA)
        ck = exp_matrix(w[1:] * np.diff(t)[:, None])
        for j in range(stop - start):
            r = r @ ck[j]
            if ci < len(checks) and start + j + 1 == checks[ci]:
                orth.append(float(np.max(np.abs(r.T @ r - np.eye(3)))))
                u, _s, vt = np.linalg.svd(r)
                q_true = coning_truth(t[j + 1:j + 2], LONG_BETA, LONG_OMEGA)[0]
                errs.append(float(_err_deg(Rotation.from_matrix(u @ vt).as_quat(), q_true[0])))
                ci += 1
    return NaiveDcmResult(checks, np.array(orth), np.array(errs))


# ----------------------------------------------------------------------------------------------
# 5. Free box, intermediate axis
# ----------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class FreeBoxResult:
    """Scene 5. Dzhanibekov flips of the free box; attitude checked by conservation of ``L_w``.

    Attributes
    ----------
    rate_hz : sample rate, Hz.
    t_s : (N,) times, s.
    y_along_l : (N,) true ``ŷ_b · L̂`` (``I2 ω2 / |L|``): the body y axis along the angular momentum;
        flips between ±1.
    l_drift_deg : dict method -> (N,) angle between the estimated world angular momentum
        ``R_w_b I ω_b`` and its initial value, deg (0 for an exact attitude).
    flips_true : number of sign changes of ``ω2`` (the flips).
    flips_est : dict method -> sign changes of ``(R_w_b ŷ_b) · L̂_w(0)``.
    """

    rate_hz: float
    t_s: NDArray
    y_along_l: NDArray
    l_drift_deg: dict[str, NDArray]
    flips_true: int
    flips_est: dict[str, int]


FREE_BOX_OMEGA0 = (0.05, 3.0, 0.05)


def free_box(rate_hz: float, duration_s: float = 30.0,
             methods: Sequence[str] = DCM_METHODS) -> FreeBoxResult:
    """Scene 5: integrate the flipping box's rates; L_w must stay fixed, flips must match ω2."""
    t = _uniform_t(rate_hz, duration_s)
    _q, w = free_body(duration_s, "intermediate", omega0_b=FREE_BOX_OMEGA0).at(t)
    l_b = w * BOX_INERTIA
    l_norm = np.linalg.norm(l_b, axis=1)
    q0 = np.array([0.0, 0.0, 0.0, 1.0])
    l_w0 = l_b[0] / l_norm[0]
    drift, flips = {}, {}
    for m in methods:
        r = imu_dcm.integrate(w, t, q0, m)
        lw = r.apply(l_b) / l_norm[:, None]
        # atan2 of |cross| and dot: arccos would floor at sqrt(2 eps) ~ 2e-8 rad near 0.
        drift[m] = np.degrees(np.arctan2(np.linalg.norm(np.cross(lw, l_w0), axis=1), lw @ l_w0))
        y_w = r.apply(np.array([0.0, 1.0, 0.0]))
        flips[m] = int(np.count_nonzero(np.diff(np.sign(y_w @ l_w0))))
    flips_true = int(np.count_nonzero(np.diff(np.sign(w[:, 1]))))
    return FreeBoxResult(rate_hz, t, BOX_INERTIA[1] * w[:, 1] / l_norm, drift, flips_true, flips)


# ----------------------------------------------------------------------------------------------
# 6. Sleeping top and fast top at high spin
# ----------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class SteadyTopResult:
    """Scene 6. The heavy top in steady precession (or sleeping), closed-form truth.

    Attributes
    ----------
    kind : ``"sleeping"`` (tilt 0), ``"fast"`` or ``"slow"`` (precession root).
    spin_hz : body spin ``ω3 / 2π``, Hz.
    precession_rad_s : φ̇, rad/s (0 when sleeping).
    rates_hz : (K,) sample rates, Hz.
    err_deg : dict method -> (K,) max total error over the run, deg. Methods: ``DCM_METHODS``,
        ``truncated`` and ``euler_zxz`` (NaN-producing runs count 180°).
    """

    kind: str
    spin_hz: float
    precession_rad_s: float
    rates_hz: NDArray
    err_deg: dict[str, NDArray]


def steady_top(kind: str, spin_hz: float, rates_hz: Sequence[float], duration_s: float = 1.0,
               methods: Sequence[str] = DCM_METHODS + ("truncated", "euler_zxz")
               ) -> SteadyTopResult:
    """Scene 6: the top spinning at ``spin_hz`` (body z), sleeping or in steady precession."""
    w3 = 2.0 * math.pi * spin_hz
    if kind == "sleeping":
        tilt, dphi = 0.0, 0.0
    else:
        tilt = math.radians(TOP.tilt_deg)
        slow, fast = steady_precession_rates(TOP.i1_kg_m2, TOP.i3_kg_m2, w3, TOP.mgl_n_m, tilt)
        dphi = fast if kind == "fast" else slow
    dpsi = w3 - dphi * math.cos(tilt)
    err = {m: np.empty(len(rates_hz)) for m in methods}
    for k, rate in enumerate(rates_hz):
        t = _uniform_t(rate, duration_s)
        n = len(t)
        q_true, w = zxz_truth(dphi * t, np.full(n, tilt), dpsi * t, np.full(n, dphi),
                              np.zeros(n), np.full(n, dpsi))
        for m in methods:
            if m == "truncated":
                q = truncated_first_order(w, t, q_true[0])
            elif m == "euler_zxz":
                ang = euler_zxz_integrate(w, t, (0.0, tilt, 0.0))
                with np.errstate(invalid="ignore", over="ignore"):
                    q = zxz_quat(ang[:, 0], ang[:, 1], ang[:, 2])
            else:
                q = _integrate_q(w, t, q_true[0], m)
            err[m][k] = np.max(_err_deg(q, q_true))
    return SteadyTopResult(kind, spin_hz, dphi, np.asarray(rates_hz, float), err)


# ----------------------------------------------------------------------------------------------
# 7. Noise and bias
# ----------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class NoiseGrowthResult:
    """Scene 7. Attitude-error growth under rate noise and bias, across seeds.

    Attributes
    ----------
    t_s : (K,) checkpoint times, s.
    white_rms_deg : (K,) RMS over seeds of the total error with white noise only, deg.
    bias_deg : (K,) error with a constant bias only, deg.
    white_law_deg : (K,) ``density · √(3 T)`` (3-axis angle random walk), deg.
    bias_law_deg : (K,) ``|b| T``, deg.
    white_exponent, bias_exponent : least-squares slopes of log error against log T.
    n_seeds : seeds in the RMS.
    """

    t_s: NDArray
    white_rms_deg: NDArray
    bias_deg: NDArray
    white_law_deg: NDArray
    bias_law_deg: NDArray
    white_exponent: float
    bias_exponent: float
    n_seeds: int


def noise_growth(density_rad_s_sqrt_hz: float = 1e-3, bias_rad_s: Sequence[float] = (2e-4, -1e-4, 2e-4),
                 rate_hz: float = 100.0, duration_s: float = 100.0, n_seeds: int = 200,
                 seed: int = 7, method: str = "end") -> NoiseGrowthResult:
    """Scene 7: a gyro at rest (true ``ω_b = 0``, attitude identity) with noise, then with bias.

    White noise of density ``N`` (rad/s/√Hz) has per-sample σ = ``N √rate``; the attitude error is
    a 3-axis random walk with ``E[θ²] = 3 N² T``. A constant bias ``b`` turns the body by ``|b| T``.
    The default method ``end`` sums independent samples, so the law holds from the first sample
    (``trapezoid`` averages neighbours: ``E[θ²] = 3 N² (T − dt/2)``).
    """
    t = _uniform_t(rate_hz, duration_s)
    checks = np.unique(np.geomspace(1, len(t) - 1, 12).astype(int))
    rng = np.random.default_rng(seed)
    sigma = density_rad_s_sqrt_hz * math.sqrt(rate_hz)
    q0 = np.array([0.0, 0.0, 0.0, 1.0])
    sq = np.zeros(len(checks))
    for _ in range(n_seeds):
        w = rng.normal(0.0, sigma, size=(len(t), 3))
        e = _err_deg(_integrate_q(w, t, q0, method)[checks], q0)
        sq += e * e
    white = np.sqrt(sq / n_seeds)
    b = np.asarray(bias_rad_s, dtype=float)
    bias_err = _err_deg(_integrate_q(np.tile(b, (len(t), 1)), t, q0, method)[checks], q0)
    tc = t[checks]
    white_law = np.degrees(density_rad_s_sqrt_hz * np.sqrt(3.0 * tc))
    bias_law = np.degrees(np.linalg.norm(b) * tc)
    we = float(np.polyfit(np.log(tc), np.log(white), 1)[0])
    be = float(np.polyfit(np.log(tc), np.log(bias_err), 1)[0])
    return NoiseGrowthResult(tc, white, bias_err, white_law, bias_law, we, be, n_seeds)


# ----------------------------------------------------------------------------------------------
# Charts and table
# ----------------------------------------------------------------------------------------------

_MARKERS = {"start": "v", "end": "^", "trapezoid": "s", "coning": "D", "magnus4": "o",
            "truncated": "x", "euler_zxz": "P", "rotvec_sum": "*"}
_LABELS = {"start": "imu_dcm start (1st order)", "end": "imu_dcm end (1st, ref. doc. rule)",
           "trapezoid": "imu_dcm trapezoid (2nd)", "coning": "imu_dcm coning (2nd)",
           "magnus4": "imu_dcm magnus4 (4th)", "truncated": "truncated q + ½q⊗ωdt, normalised",
           "euler_zxz": "ZXZ Euler angles (Heun)", "rotvec_sum": "rotvec_sum (eq. 13)"}


def _fmt(x: float) -> str:
    if not np.isfinite(x):
        return "nan"
    if x == 0:
        return "0"
    return f"{x:.2g}" if abs(x) < 1e-2 or abs(x) >= 1e4 else f"{x:.3g}"


def _floor(y: NDArray, lo: float = 1e-13) -> NDArray:
    """Errors clipped from below for log axes (an exact 0 is shown at ``lo``)."""
    return np.maximum(np.asarray(y, dtype=float), lo)


def run(out_dir: str | Path, quick: bool = False,
        progress: Callable[[str], None] = print) -> list[str]:
    """Run all eight scenes, write ``stability_*.png`` into ``out_dir``; return markdown lines.

    ``quick`` uses fewer points and 10⁶ instead of 10⁷ steps in the long run.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out_dir)
    md: list[str] = ["## Stability scenes", ""]

    # 1. gimbal lock --------------------------------------------------------------------------
    progress("stability 1/8: gimbal lock (Euler angles vs DCM)")
    closest = [0.0, 0.01, 0.1, 1.0, 10.0, 30.0] if quick else [0.0, 0.003, 0.01, 0.03, 0.1, 0.3,
                                                                  1.0, 3.0, 10.0, 30.0]
    g_rates = (100.0, 1000.0)
    gl = {(c, r): gimbal_lock(c, r) for c in closest for r in g_rates}
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(12, 4.6))
    ex = gl[(0.0, 1000.0)]
    a1.semilogy(ex.t_s, _floor(ex.euler_err_deg), "P-", ms=3, markevery=100,
                label="ZXZ Euler angles (Heun)")
    a1.semilogy(ex.t_s, _floor(ex.dcm_err_deg), "s-", ms=3, markevery=100,
                label="DCM, imu_dcm trapezoid")
    a1b = a1.twinx()
    a1b.plot(ex.t_s, ex.theta_deg, "k:", lw=1)
    a1b.set_ylabel("true θ (z axis from vertical), deg (dotted)")
    a1.set_xlabel("time, s")
    a1.set_ylabel("attitude error, deg")
    a1.set_title("Axis through the vertical (θ = 0), 1000 Hz")
    a1.legend(loc="upper left", fontsize=8)
    cs = np.array([max(c, 1e-3) for c in closest])
    for r, ls in zip(g_rates, ("--", "-")):
        a2.loglog(cs, _floor([gl[(c, r)].euler_max_deg for c in closest]), "P" + ls,
                  label=f"Euler angles, {r:.0f} Hz")
        a2.loglog(cs, _floor([gl[(c, r)].dcm_max_deg for c in closest]), "s" + ls,
                  label=f"DCM trapezoid, {r:.0f} Hz")
    a2.set_xlabel("closest approach of z axis to vertical, deg (0 plotted at 1e-3)")
    a2.set_ylabel("max attitude error, deg")
    a2.set_title("Error against closeness to gimbal lock")
    a2.legend(fontsize=8)
    fig.suptitle("Scene 1: gimbal lock — same samples, same order, Euler angles vs DCM")
    fig.tight_layout()
    fig.savefig(out / "stability_gimbal_lock.png", dpi=110)
    plt.close(fig)
    md += ["### 1. Gimbal lock (chart `stability_gimbal_lock.png`)", "",
           ("Body z axis passing ε from the vertical (R = Rx(ε)·Ry(0.5 (t−1))·Rz(2t), 2 s); "
           "ZXZ Euler angles integrated with Heun's rule vs imu_dcm `trapezoid` (both 2nd order, "
           "same samples). Max total error, deg:"), "",
           "| closest approach ε, deg | rate, Hz | Euler angles | DCM trapezoid |",
           "|---|---|---|---|"]
    for c in closest:
        for r in g_rates:
            g = gl[(c, r)]
            md.append(f"| {c:g} | {r:.0f} | {_fmt(g.euler_max_deg)} | {_fmt(g.dcm_max_deg)} |")
    md.append("")

    # 2. rotvec_sum ---------------------------------------------------------------------------
    progress("stability 2/8: rotation-vector-sum shortcut (eq. 13)")
    rs = rotvec_sum_shortcut()
    fig, ax = plt.subplots(figsize=(8, 4.6))
    ax.plot(rs.t_s, rs.rotvec_sum_err_deg, "-", label="rotvec_sum (eq. 13), wraps at 180°")
    whole = np.isclose(rs.t_s, np.round(rs.t_s))
    ax.plot(rs.t_s[whole], rs.predicted_deg[whole], "ko", mfc="none",
            label="analytic (1 − cos β) Ω t at whole cycles")
    ax.plot(rs.t_s, rs.magnus4_err_deg, "-",
            label=f"imu_dcm magnus4 (max {_fmt(rs.magnus4_err_deg.max())}°)")
    ax.set_xlabel("time, s")
    ax.set_ylabel("attitude error, deg")
    ax.set_title("Scene 2: eq. 13 under coning (β = 30°, 1 Hz, 1000 Hz samples)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "stability_rotvec_sum.png", dpi=110)
    plt.close(fig)
    md += ["### 2. Rotation-vector sum, eq. 13 (chart `stability_rotvec_sum.png`)", "",
           (f"Coning β = 30°, 1 Hz, 1000 Hz, 5 s: eq. 13 max error "
           f"{_fmt(rs.rotvec_sum_err_deg.max())}° (analytic (1 − cos β)Ωt: "
           f"{_fmt(rs.predicted_deg[-1])}° at 5 s, measured {_fmt(rs.rotvec_sum_err_deg[-1])}°); "
           f"magnus4 {_fmt(rs.magnus4_err_deg.max())}°. Fixed axis (commuting): eq. 13 "
           f"{_fmt(rs.fixed_axis_err_deg)}°."), ""]

    # 3. large steps --------------------------------------------------------------------------
    progress("stability 3/8: large steps |ω|dt 0.01..3 rad")
    ls_res = large_steps(tuple(np.geomspace(0.01, 3.0, 7 if quick else 13)))
    fig, ax = plt.subplots(figsize=(9, 5))
    for m, e in ls_res.err_deg.items():
        ax.loglog(ls_res.step_rad, _floor(e), marker=_MARKERS[m], label=_LABELS[m])
    ax.set_xlabel("step |ω| dt, rad")
    ax.set_ylabel("max attitude error over 5 s, deg")
    ax.set_title("Scene 3: large steps (precession dφ/dt = 2π rad/s, θ = 30°, "
                 "dψ/dt = 0.2π rad/s)")
    ax.legend(fontsize=8, loc="lower right")
    ax.grid(True, which="major", alpha=0.3)
    fig.tight_layout()
    fig.savefig(out / "stability_large_steps.png", dpi=110)
    plt.close(fig)
    names = list(ls_res.err_deg)
    md += ["### 3. Large steps (chart `stability_large_steps.png`)", "",
           ("Max total error (deg) over 5 s of steady precession; every imu_dcm quaternion stays "
           f"unit to {_fmt(max(ls_res.max_norm_dev[m].max() for m in DCM_METHODS))}."), "",
           "| \\|ω\\| dt, rad | " + " | ".join(names) + " |", "|---" * (len(names) + 1) + "|"]
    for k, s in enumerate(ls_res.step_rad):
        md.append(f"| {s:.3g} | " + " | ".join(_fmt(ls_res.err_deg[m][k]) for m in names) + " |")
    md.append("")

    # 4. long run -----------------------------------------------------------------------------
    n_long = 1_000_000 if quick else 10_000_000
    progress(f"stability 4/8: long run, {n_long:.0e} steps (batch, chunked)")
    lr = long_run(n_long, method="magnus4", chunk=n_long // 10)
    lr2 = long_run(n_long, method="trapezoid", chunk=n_long // 10)
    n_naive = 100_000 if quick else n_long
    progress(f"stability 4/8: reference document's un-normalised 3x3 loop, {n_naive:.0e} steps")
    nd = naive_dcm_drift(n_naive)
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(12, 4.6))
    a1.loglog(lr.step_idx, _floor(lr.err_deg), "o-", label="imu_dcm magnus4, error")
    a1.loglog(lr2.step_idx, _floor(lr2.err_deg), "s-", label="imu_dcm trapezoid, error")
    a1.loglog(nd.step_idx, _floor(nd.err_deg), "^-", label="ref. doc. 3x3 loop (end rule), error")
    a1.set_xlabel("steps (1000 Hz)")
    a1.set_ylabel("attitude error, deg")
    a1.set_title("Error against truth (coning β = 1°, 0.5 Hz)")
    a1.legend(fontsize=8)
    a2.loglog(lr.step_idx, _floor(lr.orthonormality, 1e-17), "o-",
              label="imu_dcm magnus4 (unit quaternion)")
    a2.loglog(nd.step_idx, _floor(nd.orthonormality, 1e-17), "^-",
              label="ref. doc. 3x3 loop, no re-orthonormalisation")
    a2.loglog(nd.step_idx, nd.step_idx * _EPS, "k:", label="N·ε (linear roundoff)")
    a2.loglog(nd.step_idx, np.sqrt(nd.step_idx) * _EPS, "k--", label="√N·ε (random walk)")
    a2.set_xlabel("steps")
    a2.set_ylabel("max |RᵀR − I| (exact 0 plotted at 1e-17)")
    a2.set_title("Orthonormality")
    a2.legend(fontsize=8)
    fig.suptitle(f"Scene 4: long runs, up to {n_long:.0e} steps")
    fig.tight_layout()
    fig.savefig(out / "stability_long_run.png", dpi=110)
    plt.close(fig)
    md += ["### 4. Long runs (chart `stability_long_run.png`)", "",
           (f"Coning β = 1°, 0.5 Hz, 1000 Hz, {n_long:.0e} steps ({n_long / 1000:.0f} s), batch "
           "integrator in chunks of 10⁶: "
           f"magnus4 final error {_fmt(lr.err_deg[-1])}°, trapezoid {_fmt(lr2.err_deg[-1])}°, "
           f"max |RᵀR − I| {_fmt(lr.orthonormality.max())}. The reference document's 3x3 loop "
           f"without re-orthonormalisation after {n_naive:.0e} steps: |RᵀR − I| = "
           f"{_fmt(nd.orthonormality[-1])}, error {_fmt(nd.err_deg[-1])}°."), ""]

    # 5. free box -----------------------------------------------------------------------------
    progress("stability 5/8: free box, intermediate-axis flips")
    fb_rates = (20.0, 100.0) if quick else (20.0, 50.0, 100.0, 1000.0)
    fbs = {r: free_box(r) for r in fb_rates}
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(12, 4.6))
    f1 = fbs[100.0]
    a1.plot(f1.t_s, f1.y_along_l, "k-", label="body y along L (truth, I2 ω2/|L|)")
    a1.set_xlabel("time, s")
    a1.set_ylabel("ŷ_b · L̂")
    a1.set_title(f"Flips: {f1.flips_true} in 30 s (ω0 = (0.05, 3, 0.05) rad/s)")
    a1.legend(fontsize=8)
    for m in DCM_METHODS:
        a2.semilogy(f1.t_s, _floor(f1.l_drift_deg[m]), marker=_MARKERS[m], markevery=300, ms=4,
                    label=_LABELS[m])
    a2.set_xlabel("time, s")
    a2.set_ylabel("drift of world angular momentum direction, deg")
    a2.set_title("Conservation of L_w, 100 Hz")
    a2.legend(fontsize=8)
    fig.suptitle("Scene 5: free box (2 × 1.5 × 1 m) about its intermediate axis")
    fig.tight_layout()
    fig.savefig(out / "stability_free_box.png", dpi=110)
    plt.close(fig)
    md += ["### 5. Free box, intermediate axis (chart `stability_free_box.png`)", "",
           ("Max drift of the world angular-momentum direction over 30 s, deg (a conservation "
           "law: exact attitude gives 0), and flips seen (truth: "
           f"{fbs[fb_rates[0]].flips_true}):"), "",
           "| rate, Hz | " + " | ".join(DCM_METHODS) + " |", "|---" * (len(DCM_METHODS) + 1) + "|"]
    for r, f in fbs.items():
        md.append(f"| {r:.0f} | " + " | ".join(
            f"{_fmt(f.l_drift_deg[m].max())} ({f.flips_est[m]})" for m in DCM_METHODS) + " |")
    md.append("")

    # 6. tops ---------------------------------------------------------------------------------
    progress("stability 6/8: sleeping top and fast top at high spin")
    top_rates = (200.0, 1000.0, 5000.0) if quick else (200.0, 500.0, 1000.0, 2000.0, 5000.0)
    tops = [steady_top("sleeping", 100.0, top_rates), steady_top("fast", 20.0, top_rates),
            steady_top("fast", 100.0, top_rates), steady_top("slow", 100.0, top_rates)]
    fig, axes = plt.subplots(1, len(tops), figsize=(16, 4.8), sharey=True)
    for ax, tp in zip(axes, tops):
        for m, e in tp.err_deg.items():
            ax.loglog(tp.rates_hz, _floor(e), marker=_MARKERS[m], label=_LABELS[m])
        ax.set_xlabel("sample rate, Hz")
        ax.set_xticks(tp.rates_hz, [f"{r:g}" for r in tp.rates_hz])
        ax.minorticks_off()
        ax.set_title(f"{tp.kind} top, spin {tp.spin_hz:g} Hz\n"
                     f"precession dφ/dt = {tp.precession_rad_s:.3g} rad/s")
        ax.grid(True, alpha=0.3)
    axes[0].set_ylabel("max attitude error over 1 s, deg (NaN → 180)")
    h, lab = axes[0].get_legend_handles_labels()
    fig.legend(h, lab, loc="lower center", ncol=4, fontsize=8)
    fig.suptitle("Scene 6: heavy top, sleeping and steady precession (closed-form truth)")
    fig.tight_layout(rect=(0, 0.1, 1, 1))
    fig.savefig(out / "stability_tops.png", dpi=110)
    plt.close(fig)
    tm = list(tops[0].err_deg)
    md += ["### 6. Sleeping top and fast top (chart `stability_tops.png`)", "",
           ("Max total error over 1 s, deg (180 = the method produced NaN). In steady "
           "precession the Euler-angle rates are constant, so Euler-angle integration is exact "
           "there (roundoff only); the sleeping top sits on its singularity θ = 0. Spin 100 Hz "
           "sampled at 200 Hz is |ω| dt ≈ π per step."), "",
           "| top | rate, Hz | " + " | ".join(tm) + " |", "|---" * (len(tm) + 2) + "|"]
    for tp in tops:
        for k, r in enumerate(tp.rates_hz):
            md.append(f"| {tp.kind}, {tp.spin_hz:g} Hz spin | {r:.0f} | "
                      + " | ".join(_fmt(tp.err_deg[m][k]) for m in tm) + " |")
    md.append("")

    # 7. noise --------------------------------------------------------------------------------
    progress("stability 7/8: noise and bias growth laws")
    ng = noise_growth(n_seeds=50 if quick else 200)
    fig, ax = plt.subplots(figsize=(8, 5))
    ax.loglog(ng.t_s, ng.white_rms_deg, "o", label=f"white noise, RMS of {ng.n_seeds} seeds")
    ax.loglog(ng.t_s, ng.white_law_deg, "k--", label="N √(3T)")
    ax.loglog(ng.t_s, ng.bias_deg, "s", label="constant bias")
    ax.loglog(ng.t_s, ng.bias_law_deg, "k:", label="|b| T")
    ax.set_xlabel("integration time T, s")
    ax.set_ylabel("attitude error, deg")
    ax.set_title(f"Scene 7: N = 1e-3 rad/s/√Hz, |b| = 3e-4 rad/s, 100 Hz\n"
                 f"fitted exponents {ng.white_exponent:.3f} (white), {ng.bias_exponent:.3f} (bias)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "stability_noise.png", dpi=110)
    plt.close(fig)
    md += ["### 7. Noise and bias (chart `stability_noise.png`)", "",
           (f"Gyro at rest, 100 Hz, 100 s: white noise error grows as T^{ng.white_exponent:.3f} "
           f"(law 0.5; RMS of {ng.n_seeds} seeds), bias error as T^{ng.bias_exponent:.3f} "
           "(law 1)."), ""]

    # 8. truncated ----------------------------------------------------------------------------
    progress("stability 8/8: first-order truncated updates vs exact exponential")
    tr = truncated_update()
    fig, ax = plt.subplots(figsize=(8, 5))
    ax.loglog(tr.step_rad, _floor(tr.truncated_err_deg), "x-", label="truncated, normalised")
    ax.loglog(tr.step_rad, _floor(tr.predicted_deg), "k--",
              label="n (|ω|dt − 2 atan(|ω|dt/2)) (analytic)")
    ax.loglog(tr.step_rad, _floor(tr.exact_err_deg), "o-", label="exact exponential (imu_dcm end)")
    ax.set_xlabel("step |ω| dt, rad")
    ax.set_ylabel(f"error after {tr.n_steps} steps, deg")
    ax.set_title("Scene 8: fixed-axis spin, truncated first-order step vs exact exp")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "stability_truncated.png", dpi=110)
    plt.close(fig)
    md += ["### 8. Truncated first-order update (chart `stability_truncated.png`)", "",
           f"Fixed-axis spin, {tr.n_steps} steps; error, deg, and |q| without normalisation:", "",
           "| \\|ω\\| dt, rad | truncated | analytic | exact exp | unnormalised \\|q\\| |",
           "|---|---|---|---|---|"]
    for k, s in enumerate(tr.step_rad):
        md.append(f"| {s:.3g} | {_fmt(tr.truncated_err_deg[k])} | {_fmt(tr.predicted_deg[k])} "
                  f"| {_fmt(tr.exact_err_deg[k])} | {_fmt(tr.unnormalised_norm[k])} |")
    md.append("")
    return md

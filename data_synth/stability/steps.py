"""Stability scenes about the parametrisation and the step: gimbal lock, the rotation-vector
sum, large steps, the truncated update, and long runs (scenes 1-4 and 8)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from data_synth.analytic import axis_quat, zxz_quat
from data_synth.stability.common import (
    DCM_METHODS,
    _err_deg,
    _integrate_q,
    _uniform_t,
    _wrap_deg,
    coning_truth,
    zxz_truth,
)
from imu_dcm.integrator.reference import euler_zxz_integrate, truncated_first_order
from imu_dcm.so3 import exp_matrix, quat_multiply

# ----------------------------------------------------------------------------------------------
# 1. Gimbal lock: ZXZ Euler angles past θ = 0
# ----------------------------------------------------------------------------------------------


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
    q = quat_multiply(
        quat_multiply(axis_quat(0, np.full_like(t_s, closest_rad)), axis_quat(1, a)),
        axis_quat(2, b),
    )
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
    return GimbalLockResult(
        closest_deg,
        rate_hz,
        t,
        theta,
        _err_deg(q_euler, q_true),
        _err_deg(_integrate_q(w, t, q_true[0], "trapezoid"), q_true),
    )


# ----------------------------------------------------------------------------------------------
# 2. The rotation-vector-sum shortcut R0 · exp(Σ ω dt)
# ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class RotvecSumResult:
    """Scene 2. Coning with half-angle β at Ω; errors (deg) over time.

    Attributes
    ----------
    t_s : (N,) times, s.
    rotvec_sum_err_deg, magnus4_err_deg : (N,) total error of the rotation-vector sum and of
        ``magnus4``, deg.
    predicted_deg : (N,) analytic error of the rotation-vector sum at whole cone cycles,
        ``(1 − cos β) Ω t`` wrapped to [0, 180] deg (valid where ``t`` is a whole number of
        cycles).
    fixed_axis_err_deg : max error of the rotation-vector sum for a fixed-axis rotation
        (commuting), deg.
    """

    t_s: NDArray
    rotvec_sum_err_deg: NDArray
    magnus4_err_deg: NDArray
    predicted_deg: NDArray
    fixed_axis_err_deg: float


def rotvec_sum_shortcut(
    half_angle_deg: float = 30.0,
    freq_hz: float = 1.0,
    rate_hz: float = 1000.0,
    duration_s: float = 5.0,
) -> RotvecSumResult:
    """Scene 2: the shortcut ``R = R0 · exp(Σ ω dt)`` under coning and about a fixed axis."""
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

#: Large-step scene motion (steady precession): φ̇ rad/s, θ rad, ψ̇ rad/s; duration s.
LARGE_PHI_RATE, LARGE_TILT, LARGE_PSI_RATE, LARGE_DURATION_S = (
    2 * np.pi,
    np.radians(30),
    0.2 * np.pi,
    5.0,
)


def _large_step_motion(t_s: NDArray) -> tuple[NDArray, NDArray]:
    n = len(t_s)
    return zxz_truth(
        LARGE_PHI_RATE * t_s,
        np.full(n, LARGE_TILT),
        LARGE_PSI_RATE * t_s,
        np.full(n, LARGE_PHI_RATE),
        np.zeros(n),
        np.full(n, LARGE_PSI_RATE),
    )


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


def large_steps(
    steps_rad: Sequence[float] = tuple(np.geomspace(0.01, 3.0, 13)),
) -> LargeStepsResult:
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


def truncated_update(
    steps_rad: Sequence[float] = tuple(np.geomspace(0.001, 1.0, 10)), n_steps: int = 1000
) -> TruncatedResult:
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


def long_run(
    n_steps: int = 10_000_000,
    rate_hz: float = 1000.0,
    method: str = "coning",
    chunk: int = 1_000_000,
) -> LongRunResult:
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
    """Scene 4b. The plain DCM loop, ``R ← R · CK(ω dt)``, never re-orthonormalised.

    Attributes
    ----------
    step_idx : (K,) checkpoints (step counts).
    orthonormality : (K,) ``max |Rᵀ R − I|`` at the checkpoints.
    err_deg : (K,) attitude error of the (orthonormalised) matrix against the coning truth, deg.
    """

    step_idx: NDArray
    orthonormality: NDArray
    err_deg: NDArray


def naive_dcm_drift(
    n_steps: int, rate_hz: float = 1000.0, n_checkpoints: int = 12, chunk: int = 100_000
) -> NaiveDcmResult:
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
                q_true = coning_truth(t[j + 1 : j + 2], LONG_BETA, LONG_OMEGA)[0]
                errs.append(float(_err_deg(Rotation.from_matrix(u @ vt).as_quat(), q_true[0])))
                ci += 1
    return NaiveDcmResult(checks, np.array(orth), np.array(errs))


# ----------------------------------------------------------------------------------------------

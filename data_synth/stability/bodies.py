"""Stability scenes about bodies and sensors: the free box's flips, the sleeping and the fast
top, and the growth of noise and bias (scenes 5-7)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

import imu_dcm
from data_synth.analytic import steady_precession_rates, zxz_quat
from data_synth.scenes import free_body
from data_synth.stability.common import (
    BOX_INERTIA,
    DCM_METHODS,
    TOP,
    _err_deg,
    _integrate_q,
    _uniform_t,
    zxz_truth,
)
from imu_dcm.integrator.reference import euler_zxz_integrate, truncated_first_order

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


def free_box(
    rate_hz: float, duration_s: float = 30.0, methods: Sequence[str] = DCM_METHODS
) -> FreeBoxResult:
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


def steady_top(
    kind: str,
    spin_hz: float,
    rates_hz: Sequence[float],
    duration_s: float = 1.0,
    methods: Sequence[str] = DCM_METHODS + ("truncated", "euler_zxz"),
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
        q_true, w = zxz_truth(
            dphi * t, np.full(n, tilt), dpsi * t, np.full(n, dphi), np.zeros(n), np.full(n, dpsi)
        )
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


def noise_growth(
    density_rad_s_sqrt_hz: float = 1e-3,
    bias_rad_s: Sequence[float] = (2e-4, -1e-4, 2e-4),
    rate_hz: float = 100.0,
    duration_s: float = 100.0,
    n_seeds: int = 200,
    seed: int = 7,
    method: str = "end",
) -> NoiseGrowthResult:
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

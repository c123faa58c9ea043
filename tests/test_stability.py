"""Stability scenes of ``data_synth.stability``: each asserts the behaviour its chart shows.

Truths are closed forms (coning, steady precession, fixed-axis rotation, composed axis rotations)
or conservation laws, independent of the integrators. Bounds come from the methods' theory
(truncation orders, analytic error laws, roundoff growth) and are explained where they are set.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from data_synth import stability as st

EPS = float(np.finfo(float).eps)


def _order(err_coarse: float, err_fine: float, refine: float) -> float:
    """Observed convergence order from errors at step h and h / refine."""
    return math.log(err_coarse / err_fine) / math.log(refine)


# 1. Gimbal lock ---------------------------------------------------------------------------------


def test_gimbal_lock_euler_angles_fail_at_the_pole_where_the_dcm_keeps_its_order():
    # DCM trapezoid: per step the increment misses the Magnus vector by at most
    # dt³/12 (|ω̈| + |ω × ω̇|); with ω = (c sin st, c cos st, s): |ω̇| = cs, |ω̈| = cs²,
    # |ω × ω̇| = |ω| cs. Summed over T/dt steps: T dt² (cs² + |ω| cs)/12. The O(dt) relative
    # remainder is covered by 1 % (|ω| dt ≤ 0.004 here).
    c, s, big_t = st.GIMBAL_TILT_RATE, st.GIMBAL_SPIN_RATE, st.GIMBAL_DURATION_S
    w_norm = math.hypot(c, s)
    for rate in (500.0, 1000.0, 2000.0):
        dt = 1.0 / rate
        bound_deg = math.degrees(big_t * dt * dt * (c * s * s + w_norm * c * s) / 12.0) * 1.01
        through = st.gimbal_lock(0.0, rate)
        assert through.dcm_max_deg <= bound_deg
        # Euler angles through θ = 0 (same samples, same order): the 1/sin θ pole makes the
        # error at least 100x the DCM's second-order bound at every rate.
        assert through.euler_max_deg >= 100.0 * bound_deg
    # Away from the pole (closest approach 30°) the Euler-angle integration is a smooth ODE and
    # converges at its order, 2: halving dt divides the error by 4 (order 2 ± 0.1).
    far = [st.gimbal_lock(30.0, r).euler_max_deg for r in (500.0, 1000.0)]
    assert abs(_order(far[0], far[1], 2.0) - 2.0) < 0.1


# 2. Rotation-vector sum (Xiaoliang 2014, eq. 13) -----------------------------------------------


def test_rotvec_sum_error_is_the_analytic_coning_drift_and_zero_for_a_fixed_axis():
    res = st.rotvec_sum_shortcut(half_angle_deg=30.0, freq_hz=1.0, rate_hz=1000.0, duration_s=5.0)
    whole = np.isclose(res.t_s, np.round(res.t_s))
    # At whole cone cycles the true attitude is back to R0 while Σ ω dt = (0, 0, (cos β − 1) Ω t)
    # (the transverse sines sum to zero over whole cycles): error = (1 − cos β) Ω t exactly,
    # up to roundoff of 5000 terms (1e-9 deg is ~1e-11 rad).
    np.testing.assert_allclose(res.rotvec_sum_err_deg[whole], res.predicted_deg[whole], atol=1e-9)
    assert res.rotvec_sum_err_deg[-1] > 100.0  # 0.134 Ω t = 4.2 rad at 5 s: wrong by ~119°
    # Commuting motion: Xiaoliang's eq. 13 is exact (roundoff only).
    assert res.fixed_axis_err_deg < 1e-9
    # magnus4 on the same samples: 4th-order coning drift ~ β² Ω y⁴ / 960 per second with
    # y = Ω dt = 6.3e-3 gives ~1e-11 rad; 1e-6 deg (1.7e-8 rad) leaves room for roundoff.
    assert res.magnus4_err_deg.max() < 1e-6


# 3. Large steps --------------------------------------------------------------------------------


def test_large_steps_stay_on_so3_and_keep_their_orders():
    steps = (0.01, 0.02, 3.0)
    res = st.large_steps(steps)
    for m in st.DCM_METHODS:
        # Exact exponentials and Hamilton products keep |q| = 1 to roundoff at any step size.
        assert res.max_norm_dev[m].max() < 1e-14
        # Every method stays finite even at |ω| dt = 3 rad (the error is bounded by 180°).
        assert np.all(np.isfinite(res.err_deg[m]))
    expected = {"start": 1, "end": 1, "trapezoid": 2, "coning": 2, "magnus4": 4}
    for m, p in expected.items():
        # Halving the step at |ω| dt = 0.01-0.02 is deep in the asymptotic range: order ± 0.1.
        assert abs(_order(res.err_deg[m][1], res.err_deg[m][0], 2.0) - p) < 0.1
    # At 3 rad per step the truncated first-order step turns by 2 atan(1.5) = 1.97 rad instead
    # of 3: it is worse than every exact-exponential method.
    assert res.err_deg["truncated"][-1] > max(res.err_deg[m][-1] for m in st.DCM_METHODS)


# 4. Long runs ----------------------------------------------------------------------------------


def test_ten_million_steps_error_is_roundoff_bounded():
    n = 10_000_000
    res = st.long_run(n, rate_hz=1000.0, method="magnus4", chunk=2_000_000)
    # Truncation: magnus4 coning drift ~ β² Ω y⁴ / 960 rad/s with β = 1°, y = Ω dt = 3.1e-3:
    # ~1e-15 rad/s, 1e-11 rad over 1e4 s. Roundoff: each step's increment and product add a few
    # ε of rotation, so the error after N steps is at most ~4 N ε rad; the closed-form truth
    # at Ω t = 3e4 rad is good to ~1e-11 rad.
    assert res.step_idx[-1] == n
    assert res.err_deg[-1] < math.degrees(4.0 * n * EPS)
    # The attitude stays a rotation: |Rᵀ R − I| at roundoff level.
    assert res.orthonormality.max() < 10 * EPS


def test_unnormalised_dcm_product_leaves_so3_no_faster_than_linear_roundoff():
    n = 50_000
    res = st.naive_dcm_drift(n, n_checkpoints=6, chunk=n)
    # Each 3x3 product rounds every entry by ≤ γ3 ≈ 3ε relative; RᵀR − I picks up ≤ ~2·3ε per
    # step, plus the Rodrigues matrix's own ~ε defect: at most ~10 N ε after N steps.
    assert np.all(res.orthonormality <= 10 * res.step_idx * EPS)
    assert res.orthonormality[-1] > 0.0


# 5. Free box, intermediate axis -----------------------------------------------------------------


def test_free_box_flips_are_tracked_and_angular_momentum_converges_at_each_order():
    coarse, fine = st.free_box(100.0), st.free_box(200.0)
    # Euler's equations flip ω2 twice in 30 s from ω0 = (0.05, 3, 0.05) rad/s (period of the
    # elliptic solution ~23 s, first flip at ~7 s); every method must see the same flips of the
    # body y axis against the (fixed) world angular momentum.
    assert coarse.flips_true == 2
    for m in st.DCM_METHODS:
        assert coarse.flips_est[m] == coarse.flips_true
    # Conservation of L_w: its drift converges at the method's order (± 0.15; 100 → 200 Hz).
    expected = {"start": 1, "end": 1, "trapezoid": 2, "coning": 2, "magnus4": 4}
    for m, p in expected.items():
        o = _order(coarse.l_drift_deg[m].max(), fine.l_drift_deg[m].max(), 2.0)
        assert abs(o - p) < 0.15, (m, o)


# 6. Sleeping top, fast top ---------------------------------------------------------------------


def test_sleeping_top_is_exact_for_the_dcm_and_singular_for_euler_angles():
    # Spin 100 Hz sampled at 200 Hz: |ω| dt = π per step. A fixed axis makes every exact-exp
    # method exact (roundoff: 400 products, 1e-9 deg ≈ 2e-11 rad).
    res = st.steady_top("sleeping", 100.0, (200.0, 1000.0))
    for m in st.DCM_METHODS:
        assert res.err_deg[m].max() < 1e-9
    # Euler angles start at θ = 0, where φ̇ = 0/0: the integration produces NaN (scored 180°).
    assert np.all(res.err_deg["euler_zxz"] == 180.0)


def test_fast_top_at_high_spin_converges_at_each_methods_order():
    # Fast steady precession at 20 Hz spin: φ̇ = 82.6 rad/s; ω_b cones at ψ̇ = 78 rad/s.
    res = st.steady_top(
        "fast", 20.0, (2000.0, 4000.0), duration_s=0.5, methods=st.DCM_METHODS + ("euler_zxz",)
    )
    # Steady precession of the heavy top (Goldstein, Classical Mechanics, 2nd ed., §5-7; θ̇ = 0):
    # the gravity torque M g l sin θ equals the rate of change of the angular momentum, giving
    #     I1 cos θ φ̇² − I3 ω3 φ̇ + M g l = 0,
    # with ω3 = φ̇ cos θ + ψ̇ the body spin. The top: M = 1 kg, l = 0.04 m, g = 9.8 m/s²,
    # I1 = 0.002 kg m², I3 = 0.0008 kg m², θ = 54.57°, ω3 = 2π · 20 rad/s. The fast top is the
    # larger root, (I3 ω3 + √((I3 ω3)² − 4 I1 cos θ M g l)) / (2 I1 cos θ) = 82.6 rad/s.
    i1, i3, mgl = 0.002, 0.0008, 1.0 * 9.8 * 0.04
    cos_t, w3 = math.cos(math.radians(54.57)), 2.0 * math.pi * 20.0
    fast = (i3 * w3 + math.sqrt((i3 * w3) ** 2 - 4.0 * i1 * cos_t * mgl)) / (2.0 * i1 * cos_t)
    assert res.precession_rad_s == pytest.approx(fast, rel=1e-12)
    assert res.precession_rad_s == pytest.approx(82.6, abs=0.1)
    expected = {"start": 1, "end": 1, "trapezoid": 2, "coning": 2, "magnus4": 4}
    for m, p in expected.items():
        assert abs(_order(res.err_deg[m][0], res.err_deg[m][1], 2.0) - p) < 0.15, m
    # In steady precession the Euler-angle rates are constant, so Heun integrates them exactly:
    # the only error is roundoff (1e-8 deg).
    assert res.err_deg["euler_zxz"].max() < 1e-8


# 7. Noise and bias -----------------------------------------------------------------------------


def test_noise_and_bias_error_growth_laws():
    n_seeds = 200
    res = st.noise_growth(
        density_rad_s_sqrt_hz=1e-3,
        bias_rad_s=(2e-4, -1e-4, 2e-4),
        rate_hz=100.0,
        duration_s=100.0,
        n_seeds=n_seeds,
        seed=11,
    )
    # White noise: θ² / (N² T) is chi-square with 3 dof (mean 3, var 6); the mean of 200 seeds has
    # relative std sqrt(6/200)/3 = 5.8 %, so the RMS ~2.9 %. 4 sigma: 12 % at every checkpoint
    # (each is a sum of Gaussian steps, chi-square 3 from the first sample on).
    np.testing.assert_allclose(res.white_rms_deg, res.white_law_deg, rtol=0.12)
    # Exponent over T = 0.01..100 s (4 decades): a 12 % error at the ends moves the fitted slope
    # by at most log(1.12/0.88)/log(1e4) ≈ 0.03; 0.5 ± 0.05.
    assert abs(res.white_exponent - 0.5) < 0.05
    # Constant bias at rest: a fixed-axis rotation, integrated exactly: |b| T to roundoff.
    np.testing.assert_allclose(res.bias_deg, res.bias_law_deg, rtol=1e-9)
    assert abs(res.bias_exponent - 1.0) < 1e-9


# 8. Truncated first-order update ----------------------------------------------------------------


def test_truncated_update_matches_its_analytic_angle_deficit():
    res = st.truncated_update(steps_rad=(0.001, 0.01, 0.1, 0.5, 2.0), n_steps=1000)
    # Each normalised truncated step turns by 2 atan(|ω|dt/2), not |ω|dt, about the same axis:
    # after n steps the error is n (|ω|dt − 2 atan(|ω|dt/2)) (wrapped). The truncated update is
    # a different computation (per-sample Python loop), so agreement is to roundoff of 1000
    # steps, 1e-9 deg.
    np.testing.assert_allclose(res.truncated_err_deg, res.predicted_deg, atol=1e-9, rtol=1e-9)
    # The exact exponential on a fixed axis has no truncation error at any step, even 2 rad.
    assert res.exact_err_deg.max() < 1e-9
    # Without normalisation |q| grows by sqrt(1 + (|ω|dt)²/4) per step.
    np.testing.assert_allclose(res.unnormalised_norm, res.predicted_norm, rtol=1e-12)

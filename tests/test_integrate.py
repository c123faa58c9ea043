"""Batch integrator: analytic truth, conventions against scipy, convergence orders, bad input."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from conftest import raises_naming
from scipy.spatial.transform import Rotation

from imu_dcm import GapWarning, ImuDcmError, ImuDcmWarning, InputError
from imu_dcm.integrator.batch import METHODS, increments, integrate, integrate_delta

STEP_METHODS = tuple(m for m in METHODS if m != "rotvec_sum")
EPS = np.finfo(float).eps


def rounding_bound(n_steps: int) -> float:
    """Bound on the rounding a chain of ``n`` steps collects: two roundings of ~eps per step
    (the exponential and the product), summed linearly (measured 0.02-0.3 n eps here)."""
    return 2.0 * n_steps * EPS


Q0 = Rotation.from_euler("xyz", [0.4, -0.7, 2.0]).as_quat()


def angle_rad(r_a: Rotation, r_b: Rotation) -> np.ndarray:
    """Angle of the rotation between two attitudes, rad (scipy as the oracle)."""
    return (r_a.inv() * r_b).magnitude()


def uneven_stamps(n: int, dt: float, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.concatenate([[0.3], 0.3 + np.cumsum(rng.uniform(0.5 * dt, 1.5 * dt, n - 1))])


# -- analytic truth ---------------------------------------------------------------------------


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("uneven", [False, True])
def test_constant_axis_rotation_is_exact(method, uneven):
    # A rate constant in the body has the closed form q(t) = q0 ⊗ exp(ω (t - t0)) and every
    # rule integrates it exactly: all increments are parallel, the coning terms vanish, the
    # magnus4 weights sum to dt. What is left is 2000 steps of rounding.
    n = 2001
    t = uneven_stamps(n, 1e-3, seed=1) if uneven else np.linspace(0.3, 2.3, n)
    omega = np.array([0.7, -1.1, 2.9])  # rad/s, |ω| = 3.2 rad/s, 6.4 rad in total
    truth = Rotation.from_quat(Q0) * Rotation.from_rotvec(np.outer(t - t[0], omega))
    ctx = pytest.warns(ImuDcmWarning) if method == "rotvec_sum" else warnings.catch_warnings()
    with ctx:
        got = integrate(np.tile(omega, (n, 1)), t, Q0, method)
    assert len(got) == n
    assert angle_rad(got, truth).max() <= rounding_bound(n - 1)


@pytest.mark.parametrize("uneven", [False, True])
def test_magnus4_exact_for_cubic_rate_about_fixed_axis(uneven):
    # About a fixed axis the attitude angle is ∫|ω|; with a cubic rate, Simpson's rule on the
    # cubic-interpolated mid-point is exact, and so are the one-sided end steps (the ghost
    # samples lie on the same cubic). Uneven stamps test the real-stamp weights. Trapezoid is
    # not exact here (its error ~ h² |ω''| T / 12 ~ 1e-7 rad), so the check can fail.
    n = 301
    t = uneven_stamps(n, 2e-3, seed=2) if uneven else np.linspace(0.3, 0.9, n)
    axis = np.array([2.0, -1.0, 2.0]) / 3.0
    c = (0.5, -3.0, 8.0, -6.0)  # rate magnitude c0 + c1 s + c2 s² + c3 s³, s = t - t0
    s = t - t[0]
    rate = c[0] + c[1] * s + c[2] * s**2 + c[3] * s**3
    angle = c[0] * s + c[1] * s**2 / 2 + c[2] * s**3 / 3 + c[3] * s**4 / 4
    truth = Rotation.from_quat(Q0) * Rotation.from_rotvec(np.outer(angle, axis))
    got = integrate(np.outer(rate, axis), t, Q0, "magnus4")
    assert angle_rad(got, truth).max() <= rounding_bound(n - 1)
    trap = integrate(np.outer(rate, axis), t, Q0, "trapezoid")
    assert angle_rad(trap, truth).max() > 1e-9


def coning_truth(t: np.ndarray, beta: float, om: float) -> tuple[Rotation, np.ndarray]:
    """Pure coning: R(t) = Rz(Ωt) Rx(β) Rz(−Ωt) and its body rate."""
    rz = Rotation.from_rotvec(np.outer(om * t, [0.0, 0.0, 1.0]))
    r = rz * Rotation.from_rotvec([beta, 0.0, 0.0]) * rz.inv()
    omega_b = om * np.column_stack(
        [
            -np.sin(beta) * np.sin(om * t),
            np.sin(beta) * np.cos(om * t),
            np.full_like(t, np.cos(beta) - 1.0),
        ]
    )
    return r, omega_b


@pytest.mark.parametrize(
    "method, order, rates_hz",
    [
        ("start", 1, (50, 100, 200, 400)),
        ("end", 1, (50, 100, 200, 400)),
        ("trapezoid", 2, (50, 100, 200, 400)),
        ("coning", 2, (50, 100, 200, 400)),
        ("magnus4", 4, (25, 50, 100, 200)),
    ],
)
def test_coning_convergence_order(method, order, rates_hz):
    # Half-angle 0.3 rad at 2 Hz for 1 s. The chosen rates are in the asymptotic range (the
    # measured orders are stable to ±0.05 there) and the smallest error (magnus4, 200 Hz,
    # ~4e-7 rad) is six orders above rounding, so the order is the method's, not noise's.
    beta, om = 0.3, 2.0 * np.pi * 2.0
    errs = []
    for rate in rates_hz:
        t = np.linspace(0.0, 1.0, rate + 1)
        truth, omega_b = coning_truth(t, beta, om)
        got = integrate(omega_b, t, truth[0], method)
        errs.append(angle_rad(got, truth).max())
    measured = -np.diff(np.log(errs)) / np.log(2.0)
    assert np.all(np.abs(measured - order) <= 0.2), measured
    assert min(errs) > 1e-10


def test_coning_term_halves_trapezoid_error_and_rotvec_sum_fails():
    # Under coning, the h²/12 ω_i × ω_{i+1} term cancels part of the trapezoid's drift (measured
    # ratio ~2); the eq.-13 shortcut ignores non-commutativity and is wrong by O(1) of β².
    t = np.linspace(0.0, 1.0, 201)
    truth, omega_b = coning_truth(t, 0.3, 2.0 * np.pi * 2.0)
    e_trap = angle_rad(integrate(omega_b, t, truth[0], "trapezoid"), truth).max()
    e_con = angle_rad(integrate(omega_b, t, truth[0], "coning"), truth).max()
    assert e_con < 0.6 * e_trap
    with pytest.warns(ImuDcmWarning, match="rotvec_sum"):
        e_sum = angle_rad(integrate(omega_b, t, truth[0], "rotvec_sum"), truth).max()
    assert e_sum > 100 * e_trap


# -- conventions ----------------------------------------------------------------------------


@pytest.mark.parametrize("method", STEP_METHODS)
def test_90_deg_about_z_is_scalar_last(method):
    t = np.linspace(0.0, 1.0, 101)
    got = integrate(np.tile([0.0, 0.0, np.pi / 2], (101, 1)), t, [0, 0, 0, 1], method)
    np.testing.assert_allclose(
        got.as_quat()[-1], [0.0, 0.0, np.sqrt(0.5), np.sqrt(0.5)], atol=rounding_bound(100)
    )
    # Columns of R_w_b are the body axes in world: body x now points along world y.
    np.testing.assert_allclose(got.as_matrix()[-1][:, 0], [0.0, 1.0, 0.0], atol=rounding_bound(100))


def test_increments_multiply_on_the_right_like_scipy():
    # scipy as oracle: r_{i+1} = r_i * Rotation.from_rotvec(h_i ω_i) composed one by one
    # (body increments on the right). Random rates and uneven stamps; 500 steps of rounding.
    rng = np.random.default_rng(3)
    n = 501
    t = uneven_stamps(n, 1e-2, seed=3)
    omega = rng.normal(scale=2.0, size=(n, 3))
    r = Rotation.from_quat(Q0)
    ref = [r]
    for i in range(n - 1):
        r = r * Rotation.from_rotvec(omega[i] * (t[i + 1] - t[i]))
        ref.append(r)
    ref = Rotation.concatenate(ref)
    assert angle_rad(integrate(omega, t, Q0, "start"), ref).max() <= rounding_bound(n - 1)
    # The left product (world-frame increments) differs by O(1): the check can fail.
    left = Rotation.from_rotvec(omega[0] * (t[1] - t[0])) * Rotation.from_quat(Q0)
    assert angle_rad(left, ref[1]) > 1e-3


def test_large_steps_use_the_exact_exponential():
    # Steps of 1e-9 to 60 rad (coarse sampling of a fast spin) mix the series and sin/cos
    # branches in one array; scipy's composition is the oracle, and no warning may be raised.
    n = 60
    t = np.arange(n) * 0.5
    omega = np.outer(np.geomspace(2e-9, 120.0, n), [0.48, -0.6, 0.64])
    r = Rotation.from_quat(Q0)
    ref = [r]
    for i in range(n - 1):
        r = r * Rotation.from_rotvec(omega[i] * 0.5)
        ref.append(r)
    # A step of θ rad rounds to ~θ eps: the bound sums max(1, θ) per step.
    theta = np.linalg.norm(omega[:-1] * 0.5, axis=1)
    bound = 2.0 * EPS * np.maximum(1.0, theta).sum()
    assert angle_rad(integrate(omega, t, Q0, "start"), Rotation.concatenate(ref)).max() <= bound


def test_q0_forms_agree():
    t = np.linspace(0.0, 1.0, 11)
    w = np.tile([0.1, 0.2, 0.3], (11, 1))
    a = integrate(w, t, Q0).as_quat()
    b = integrate(w, t, Rotation.from_quat(Q0).as_matrix()).as_quat()
    c = integrate(w, t, Rotation.from_quat(Q0)).as_quat()
    np.testing.assert_allclose(a, b, atol=1e-14)
    np.testing.assert_allclose(a, c, atol=1e-14)


def test_magnus4_interior_weights_are_classic():
    # Uniform steps: φ = h/24 (−ω_{i−1} + 13 ω_i + 13 ω_{i+1} − ω_{i+2}) + h²/12 ω_i × ω_{i+1}.
    rng = np.random.default_rng(4)
    w = rng.normal(size=(12, 3))
    h = 0.01
    phi = increments(w, h * np.arange(12), "magnus4")
    i = np.arange(1, 10)
    want = h / 24 * (-w[i - 1] + 13 * w[i] + 13 * w[i + 1] - w[i + 2]) + h * h / 12 * np.cross(
        w[i], w[i + 1]
    )
    np.testing.assert_allclose(phi[1:10], want, rtol=0, atol=1e-15)


# -- orthonormality ---------------------------------------------------------------------------


def test_orthonormal_after_ten_million_random_steps():
    # 10^7 random steps (10 chained batches of 10^6, to keep memory near 1 GB at most): the
    # kernel pulls |q| back to 1 after every product, so R = R(q) stays orthonormal to rounding
    # (a few eps) instead of drifting with the number of products (n eps = 2e-9 here).
    rng = np.random.default_rng(5)
    q = Q0
    worst = 0.0
    n = 1_000_001
    t = np.arange(n) * 1e-3
    for _ in range(10):
        omega = rng.normal(scale=3.0, size=(n, 3))
        r = integrate(omega, t, q, "trapezoid")
        mats = r[::9973].as_matrix()
        mats = np.concatenate([mats, r[-1:].as_matrix()])
        err = np.abs(np.einsum("nji,njk->nik", mats, mats) - np.eye(3)).max()
        worst = max(worst, err)
        q = r[-1].as_quat()
    assert worst <= 1e-12


# -- delta angles ---------------------------------------------------------------------------


def coning_delta(tb: np.ndarray, beta: float, om: float) -> np.ndarray:
    """Exact ∫ω_b over [tb_k, tb_{k+1}] for pure coning (closed form)."""
    c0, c1 = np.cos(om * tb[:-1]), np.cos(om * tb[1:])
    s0, s1 = np.sin(om * tb[:-1]), np.sin(om * tb[1:])
    sb = np.sin(beta)
    return np.column_stack(
        [sb * (c1 - c0), sb * (s1 - s0), om * (np.cos(beta) - 1.0) * (tb[1:] - tb[:-1])]
    )


@pytest.mark.parametrize(
    "method, order",
    [("plain", 1), ("one_plus_previous", 2), ("two_sample", 2), ("three_sample", 2)],
)
def test_delta_angle_methods_converge_on_coning(method, order):
    # Delta angles are exact integrals, so the error is only the coning (non-commutativity)
    # error: first order without correction, higher with. The drift per step is the cone-axis
    # drift β²Ω y^(order+1)/...; orders measured from 120 to 960 intervals.
    beta, om = 0.3, 2.0 * np.pi * 2.0
    errs = []
    for n in (120, 240, 480, 960):
        tb = np.linspace(0.0, 1.0, n + 1)
        truth, _ = coning_truth(tb, beta, om)
        got = integrate_delta(coning_delta(tb, beta, om), tb, truth[0], method)
        m = {"two_sample": 2, "three_sample": 3}.get(method, 1)
        errs.append(angle_rad(got, truth[::m]).max())
    measured = -np.diff(np.log(errs)) / np.log(2.0)
    assert np.all(measured >= order - 0.2), (measured, errs)


def test_delta_corrections_beat_plain_and_handle_uneven_intervals():
    beta, om = 0.3, 2.0 * np.pi * 2.0
    tb = uneven_stamps(601, 1.0 / 600, seed=6)
    truth, _ = coning_truth(tb, beta, om)
    d = coning_delta(tb, beta, om)
    e_plain = angle_rad(integrate_delta(d, tb, truth[0], "plain"), truth).max()
    e_opp = angle_rad(integrate_delta(d, tb, truth[0], "one_plus_previous"), truth).max()
    e_two = angle_rad(integrate_delta(d, tb, truth[0], "two_sample"), truth[::2]).max()
    assert e_opp < 0.05 * e_plain
    assert e_two < 0.05 * e_plain


def test_delta_constant_axis_exact_and_result_at_set_ends():
    tb = np.linspace(0.0, 1.2, 13)
    d = np.tile([0.0, 0.0, 0.1], (12, 1))  # 1 rad about z over 1.2 s
    got = integrate_delta(d, tb, [0, 0, 0, 1], "three_sample")
    assert len(got) == 5
    np.testing.assert_allclose(got.magnitude(), [0.0, 0.3, 0.6, 0.9, 1.2], atol=1e-14)
    with pytest.raises(InputError, match="multiple of 3"):
        integrate_delta(d[:11], tb[:12], [0, 0, 0, 1], "three_sample")


# -- bad input ------------------------------------------------------------------------------

T5 = np.arange(5) * 0.01
W5 = np.zeros((5, 3))


@pytest.mark.parametrize(
    "omega, t, match",
    [
        (np.zeros((5, 2)), T5, r"shape \(N, 3\), got \(5, 2\)"),
        (np.zeros(5), T5, r"shape \(N, 3\), got \(5,\)"),
        (W5, T5[:4], r"length N = 5"),
        (W5, T5[:, None], r"`t_s` of shape \(N,\)"),
        (np.zeros((1, 3)), T5[:1], r"at least 2 stamps"),
        (np.array([["a", "b", "c"]] * 5), T5, r"real numbers"),
        (W5.astype(complex), T5, r"real numbers"),
        (W5, T5.astype(object), r"real numbers"),
    ],
)
def test_bad_shapes_and_dtypes(omega, t, match):
    with pytest.raises(InputError, match=match):
        integrate(omega, t, [0, 0, 0, 1])


def test_errors_are_value_errors_of_the_project():
    with pytest.raises(ValueError):
        integrate(np.zeros((5, 2)), T5, [0, 0, 0, 1])
    with pytest.raises(ImuDcmError):
        integrate(W5, T5, [0, 0, 0, 1], method="rk4")


def test_non_finite_sample_names_first_row():
    w = W5.copy()
    w[3, 1] = np.nan
    w[4, 0] = np.inf
    with pytest.raises(InputError, match=r"finite `omega_b`, got \[0.0, nan, 0.0\] at row 3"):
        integrate(w, T5, [0, 0, 0, 1])
    t = T5.copy()
    t[2] = np.inf
    with pytest.raises(InputError, match=r"t_s\[2\] = inf"):
        integrate(W5, t, [0, 0, 0, 1])


def test_non_increasing_stamps_name_index_and_values():
    t = np.array([0.0, 0.01, 0.02, 0.02, 0.04])
    with pytest.raises(InputError, match=r"t_s\[3\] = 0.02 s after t_s\[2\] = 0.02 s"):
        integrate(W5, t, [0, 0, 0, 1])
    with pytest.raises(InputError, match=r"t_s\[1\] = -1.0 s after t_s\[0\] = 0.0 s"):
        integrate(W5[:2], [0.0, -1.0], [0, 0, 0, 1])


def test_unknown_method_and_bad_q0():
    with raises_naming(InputError, "method", "'magnus4'", "'euler'"):
        integrate(W5, T5, [0, 0, 0, 1], method="euler")
    with pytest.raises(InputError, match="q0"):
        integrate(W5, T5, [0, 0, 1])
    with pytest.raises(InputError, match="method"):
        integrate_delta(W5[:4], T5, [0, 0, 0, 1], method="magnus4")


def test_gap_warns_with_its_time():
    t = np.concatenate([np.arange(100) * 0.01, 1.5 + np.arange(100) * 0.01])
    w = np.zeros((200, 3))
    with pytest.warns(
        GapWarning, match=r"1 gap\(s\) longer than 5x the median step at 0.990 s \(\+0.510 s\)"
    ):
        integrate(w, t, [0, 0, 0, 1])
    # 4x the median is not a gap.
    t2 = np.concatenate([np.arange(100) * 0.01, 1.03 + np.arange(100) * 0.01])
    integrate(w, t2, [0, 0, 0, 1])


def test_three_sample_warns_on_uneven_intervals():
    # Its coefficients (9/20, 27/40) are derived for equal intervals; 1 % spread is tolerated.
    d = np.tile([0.0, 0.0, 0.01], (6, 1))
    tb = np.linspace(0.0, 0.06, 7)
    tb[1] += 2e-5  # intervals differ by 0.4 %: no warning
    integrate_delta(d, tb, [0, 0, 0, 1], "three_sample")
    with pytest.warns(ImuDcmWarning, match="equal intervals"):
        integrate_delta(d, [0.0, 0.01, 0.02, 0.04, 0.05, 0.06, 0.07], [0, 0, 0, 1], "three_sample")


def test_delta_input_checks():
    with pytest.raises(InputError, match=r"length N \+ 1 = 5"):
        integrate_delta(W5[:4], T5[:4], [0, 0, 0, 1])
    with pytest.raises(InputError, match="dtheta_b"):
        integrate_delta(np.full((4, 3), np.nan), T5, [0, 0, 0, 1])

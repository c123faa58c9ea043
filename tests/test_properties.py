"""Property tests (hypothesis) for the rotation maths the integrator is built on.

scipy ``Rotation`` is the oracle throughout; shapes (), (1,) and (3, 2) check the vectorised
functions keep leading axes.
"""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.spatial.transform import Rotation

from imu_dcm._kernels import integrator
from imu_dcm.integrator.batch import integrate, integrate_delta
from imu_dcm.so3 import exp_quat, log_quat, quat_angle_rad, quat_multiply

EPS = np.finfo(float).eps
SHAPES = st.sampled_from([(), (1,), (3, 2)])
unit = st.floats(-1.0, 1.0, allow_nan=False)


def directions(shape):
    """Non-zero direction vectors of a leading shape, normalised."""
    return (
        arrays(float, shape + (3,), elements=unit)
        .filter(lambda v: np.all(np.linalg.norm(v, axis=-1) > 1e-3))
        .map(lambda v: v / np.linalg.norm(v, axis=-1, keepdims=True))
    )


@st.composite
def rotvecs(draw, lo: float, hi: float):
    """Rotation vectors of angle in [lo, hi] rad and a random leading shape."""
    shape = draw(SHAPES)
    axis = draw(directions(shape))
    angle = draw(arrays(float, shape, elements=st.floats(lo, hi)))
    return axis * np.asarray(angle)[..., None]


def stack_parts(parts):
    return np.stack(np.broadcast_arrays(*parts), axis=-1)


@settings(deadline=None)
@given(rotvecs(0.0, 1e-6))
def test_exp_log_round_trip_near_zero(phi):
    # Near 0 the Taylor branches are used; relative accuracy must hold (no 0/0, no cancellation).
    back = log_quat(exp_quat(phi))
    assert back.shape == phi.shape
    np.testing.assert_allclose(back, phi, rtol=1e-12, atol=1e-300)


@settings(deadline=None)
@given(rotvecs(1e-3, np.pi - 1e-3))
def test_exp_log_round_trip_generic(phi):
    np.testing.assert_allclose(log_quat(exp_quat(phi)), phi, rtol=1e-12, atol=1e-14)


@settings(deadline=None)
@given(rotvecs(np.pi - 1e-6, np.pi - 1e-9))
def test_exp_log_round_trip_near_pi(phi):
    # Just below π the axis is still defined; the log recovers the vector to ~eps / sin(θ/2).
    np.testing.assert_allclose(log_quat(exp_quat(phi)), phi, atol=1e-9)


@settings(deadline=None)
@given(rotvecs(0.0, 3.0))
def test_exp_quat_matches_scipy(phi):
    # Both branches of the exponential (series up to 0.5 rad, sin/cos above) against scipy;
    # each component is a handful of roundings (8 eps).
    q = exp_quat(phi)
    assert q.shape == phi.shape[:-1] + (4,)
    ref = Rotation.from_rotvec(phi.reshape(-1, 3)).as_quat().reshape(q.shape)
    np.testing.assert_allclose(q, ref, atol=8 * EPS)


@settings(deadline=None)
@given(st.floats(0.0, 3.0), st.floats(-1.0, 1.0), st.floats(-1.0, 1.0), st.floats(-1.0, 1.0))
def test_kernel_exp_equals_so3_exp(angle, x, y, z):
    # The compiled kernel's private exponential and so3's vectorised one follow one policy.
    v = np.array([x, y, z])
    v = v / np.linalg.norm(v) if np.linalg.norm(v) > 1e-3 else np.array([0.0, 0.0, 1.0])
    phi = angle * v
    qk = np.array(integrator.exp_quat(float(phi[0]), float(phi[1]), float(phi[2])))
    np.testing.assert_allclose(qk, exp_quat(phi), atol=4 * EPS)


@settings(deadline=None)
@given(rotvecs(0.0, np.pi), rotvecs(0.0, np.pi))
def test_q_and_minus_q_are_the_same_rotation(phi_a, phi_b):
    q = exp_quat(phi_a)
    assert np.all(quat_angle_rad(q, -q) <= 1e-7)  # atan2 form: exact 0 up to rounding
    t = np.linspace(0.0, 0.1, 5)
    w = np.tile(phi_b.reshape(-1, 3)[0], (5, 1))
    q0 = q.reshape(-1, 4)[0]
    a = integrate(w, t, q0).as_quat()
    b = integrate(w, t, -q0).as_quat()
    assert np.all(quat_angle_rad(a, b) <= 1e-14)


@settings(deadline=None)
@given(rotvecs(0.0, np.pi), rotvecs(0.0, np.pi))
def test_quat_multiply_is_scipy_composition(phi_a, phi_b):
    qa = exp_quat(phi_a)
    qb = np.broadcast_to(exp_quat(phi_b).reshape(-1, 4)[0], qa.shape)  # a's shape, any b
    got = quat_multiply(qa, qb)
    ref = Rotation.from_quat(qa.reshape(-1, 4)) * Rotation.from_quat(qb.reshape(-1, 4))
    assert np.all(quat_angle_rad(got.reshape(-1, 4), ref.as_quat()) <= 1e-14)
    qk = np.array(
        [
            integrator.quat_mul(tuple(a), tuple(b))
            for a, b in zip(qa.reshape(-1, 4).tolist(), qb.reshape(-1, 4).tolist(), strict=False)
        ]
    )
    assert np.all(quat_angle_rad(qk, ref.as_quat()) <= 1e-14)


@settings(deadline=None, max_examples=50)
@given(st.integers(1, 300), st.integers(0, 2**32 - 1))
def test_product_chain_equals_scipy_chain(m, seed):
    # integrate_delta("plain") is the bare recursion q_{k+1} = q_k ⊗ exp(Δθ_k): scipy composes
    # the same chain one by one. m products of about an eps each: bound 4 m eps.
    rng = np.random.default_rng(seed)
    rv = rng.normal(scale=0.3, size=(m, 3))
    q0 = Rotation.from_rotvec(rng.normal(size=3))
    got = integrate_delta(rv, np.arange(m + 1) * 0.01, q0, "plain").as_quat()
    r = q0
    ref = [r.as_quat()]
    for v in rv:
        r = r * Rotation.from_rotvec(v)
        ref.append(r.as_quat())
    assert got.shape == (m + 1, 4)
    assert np.all(quat_angle_rad(got, np.array(ref)) <= 4 * m * EPS)


@settings(deadline=None, max_examples=30)
@given(st.integers(3, 200), st.integers(0, 2**32 - 1))
def test_trapezoid_record_splits_at_any_sample(n, seed):
    # Two-point rules are Markov: integrating a record in two pieces (the second starting from
    # the first's last attitude) gives the whole record's result, to the rounding of n steps.
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.5, 1.5, n)) * 1e-2
    w = rng.normal(size=(n, 3))
    k = int(rng.integers(1, n - 1))
    whole = integrate(w, t, [0, 0, 0, 1], "trapezoid").as_quat()
    first = integrate(w[: k + 1], t[: k + 1], [0, 0, 0, 1], "trapezoid").as_quat()
    second = integrate(w[k:], t[k:], first[-1], "trapezoid").as_quat()
    assert np.all(quat_angle_rad(whole[k:], second) <= 2 * n * EPS)

"""Rotation maths against scipy Rotation as the independent oracle."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from imu_dcm.errors import InputError
from imu_dcm.so3 import (
    as_quat_xyzw,
    exp_matrix,
    exp_quat,
    log_quat,
    quat_as_matrix,
    quat_from_matrix,
    quat_multiply,
    quat_rotate,
)

SQRT_HALF = np.sqrt(0.5)


def test_90_deg_about_z_is_xyzw_0_0_r_r():
    q = exp_quat([0.0, 0.0, np.pi / 2])
    np.testing.assert_allclose(q, [0.0, 0.0, SQRT_HALF, SQRT_HALF], atol=1e-15)
    # body x maps to world y under an active 90 deg yaw
    np.testing.assert_allclose(quat_rotate(q, [1.0, 0.0, 0.0]), [0.0, 1.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(exp_matrix([0.0, 0.0, np.pi / 2])[:, 0], [0.0, 1.0, 0.0], atol=1e-15)


def test_exp_and_product_match_scipy():
    rng = np.random.default_rng(1)
    a, b = rng.normal(size=(2, 100, 3))
    qa, qb = exp_quat(a), exp_quat(b)
    ra, rb = Rotation.from_rotvec(a), Rotation.from_rotvec(b)
    np.testing.assert_allclose(exp_matrix(a), ra.as_matrix(), atol=1e-14)
    got = Rotation.from_quat(quat_multiply(qa, qb))
    assert np.max((got.inv() * (ra * rb)).magnitude()) < 1e-14


def test_as_quat_rejects_bad_attitudes():
    with pytest.raises(InputError, match="shape"):
        as_quat_xyzw(np.zeros(3))
    with pytest.raises(InputError, match="rotation matrix"):
        as_quat_xyzw(2 * np.eye(3))


EPS = np.finfo(float).eps


def _rotations() -> Rotation:
    """Random rotations and the hard cases: identity, tiny angles, angles near π (every
    branch of Markley's method), 90° about z."""
    rng = np.random.default_rng(7)
    axes = rng.normal(size=(60, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.concatenate([np.zeros(5), 1e-9 * rng.random(15), np.pi - 1e-9 * rng.random(20)])
    special = np.concatenate([axes[:40] * angles[:, None], np.eye(3) * np.pi, [[0, 0, np.pi / 2]]])
    return Rotation.concatenate(
        [Rotation.random(500, random_state=rng), Rotation.from_rotvec(special)]
    )


def test_quat_as_matrix_matches_scipy_and_90_deg_about_z():
    r = _rotations()
    # each entry is a sum of three products of unit-bounded terms: a few ulps
    np.testing.assert_allclose(quat_as_matrix(r.as_quat()), r.as_matrix(), rtol=0, atol=8 * EPS)
    # body x is world y under an active 90 deg yaw: the first column
    m = quat_as_matrix([0.0, 0.0, SQRT_HALF, SQRT_HALF])
    np.testing.assert_allclose(m[:, 0], [0.0, 1.0, 0.0], atol=4 * EPS)
    # a quaternion that is not unit is normalised, and leading shapes are kept
    np.testing.assert_allclose(quat_as_matrix(3.0 * r.as_quat()), r.as_matrix(), atol=8 * EPS)
    assert quat_as_matrix(r.as_quat().reshape(-1, 1, 4)).shape == (len(r), 1, 3, 3)


def test_quat_from_matrix_matches_scipy_with_its_sign():
    r = _rotations()
    m = r.as_matrix()
    q = quat_from_matrix(m)
    want = Rotation.from_matrix(m).as_quat()
    sign = np.where(np.sum(q * want, axis=-1) < 0, -1.0, 1.0)[:, None]
    # each component is a sum of matrix entries (few ulps) over a norm of at least 1/2
    np.testing.assert_allclose(q, sign * want, rtol=0, atol=8 * EPS)
    # the largest component is positive (Markley's choice, which scipy keeps)
    assert np.all(q[np.arange(len(q)), np.argmax(np.abs(q), axis=-1)] > 0)
    np.testing.assert_allclose(
        quat_from_matrix([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]),
        [0.0, 0.0, SQRT_HALF, SQRT_HALF],
        atol=4 * EPS,
    )
    np.testing.assert_allclose(quat_from_matrix(np.diag([1.0, -1.0, -1.0])), [1, 0, 0, 0])
    assert quat_from_matrix(m.reshape(-1, 1, 3, 3)).shape == (len(r), 1, 4)


def test_quat_from_matrix_takes_the_nearest_rotation_of_a_noisy_matrix():
    r = Rotation.random(200, random_state=np.random.default_rng(3))
    noisy = r.as_matrix() + 1e-5 * np.random.default_rng(4).normal(size=(200, 3, 3))
    u, _, vt = np.linalg.svd(noisy)
    nearest = Rotation.from_matrix(u @ vt)  # the orthogonal Procrustes solution
    got = Rotation.from_quat(quat_from_matrix(noisy))
    # both are the SVD's projection: they differ by rounding only (SVD of a 3x3, ~1e-15)
    assert np.max((got.inv() * nearest).magnitude()) < 1e-13
    # and the noise moved the rotation by about its size, not more
    assert np.max((got.inv() * r).magnitude()) < 1e-4


def test_log_quat_of_half_turns_matches_scipy_without_warnings():
    # w == 0 exactly: the small-angle series must not be evaluated there (it divides by w)
    q = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, SQRT_HALF, SQRT_HALF, 0.0], [0.0, 0.0, 1.0, 0.0]])
    got = log_quat(q)
    np.testing.assert_allclose(np.linalg.norm(got, axis=-1), np.pi, rtol=0, atol=4 * EPS)
    np.testing.assert_allclose(got, Rotation.from_quat(q).as_rotvec(), rtol=0, atol=8 * EPS)


def test_row_helpers_equal_numpy_reductions_over_the_last_axis():
    from imu_dcm.arrays import BLOCK_ROWS, row_finite, row_max, row_norm

    rng = np.random.default_rng(11)
    # the last two are taken BLOCK_ROWS rows at a time (a partial block at the end)
    for shape in [
        (4,),
        (50, 4),
        (7, 3),
        (3, 5, 2),
        (0, 4),
        (2 * BLOCK_ROWS + 3, 4),
        (BLOCK_ROWS + 1, 3),
    ]:
        a = rng.normal(size=shape) * 10.0 ** rng.integers(-8, 8, size=shape)
        if a.size > 4:
            a.flat[[1, 5, a.size - 1]] = np.nan
            a.flat[[3, a.size // 2]] = np.inf
        want = np.linalg.norm(a, axis=-1)
        # a sum of at most four squares in another order: a few ulps apart
        np.testing.assert_allclose(row_norm(a), want, rtol=4 * EPS, atol=0)
        np.testing.assert_array_equal(row_finite(a), np.all(np.isfinite(a), axis=-1))
        if a.shape[0]:
            np.testing.assert_array_equal(row_max(a), np.max(a, axis=-1))  # NaN where NaN
    # rows as they lie: every other column of a wider array, columns reversed, a transpose
    wide = rng.normal(size=(1000, 8))
    wide.flat[rng.integers(0, wide.size, 40)] = np.nan
    wide.flat[rng.integers(0, wide.size, 40)] = -np.inf
    for view in (wide[:, 1::2], wide[:, ::-1][:, :3], wide[:4].T, wide[::3, :4]):
        want = np.linalg.norm(view, axis=-1)
        np.testing.assert_allclose(row_norm(view), want, rtol=4 * EPS, atol=0)
        np.testing.assert_array_equal(row_finite(view), np.all(np.isfinite(view), axis=-1))
    # of integers and float32 too (by numpy, column by column)
    np.testing.assert_array_equal(row_finite(np.arange(12).reshape(3, 4)), [True] * 3)
    f4 = np.array([[1, np.nan], [2, 3]], np.float32)
    np.testing.assert_array_equal(row_finite(f4), [False, True])


def test_product_planes_of_conjugates_and_the_angle_between_attitudes():
    from imu_dcm.so3 import product_planes, quat_angle_rad

    r = _rotations()
    s = Rotation.random(len(r), random_state=np.random.default_rng(12))
    p, q = r.as_quat(), s.as_quat()
    for conj_p, conj_q in [(False, False), (True, False), (False, True), (True, True)]:
        want = (r.inv() if conj_p else r) * (s.inv() if conj_q else s)
        got = Rotation.from_quat(np.moveaxis(product_planes(p, q, conj_p, conj_q), 0, -1))
        assert np.max((got.inv() * want).magnitude()) < 1e-14
    # the angle between attitudes: scipy's magnitude of a* ⊗ b, whatever the signs and norms
    want = (r.inv() * s).magnitude()
    got = quat_angle_rad(-3.0 * p, 0.5 * q)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-14)
    yaw90 = [0.0, 0.0, SQRT_HALF, SQRT_HALF]
    assert abs(quat_angle_rad([0.0, 0.0, 0.0, 1.0], yaw90) - np.pi / 2) < 4 * EPS
    with pytest.raises(InputError, match="non-zero norm"):
        quat_angle_rad(p[:3], np.zeros((3, 4)))


@pytest.mark.parametrize("n", [1, 2, 3, 4, 7, 10, 101, 1000])
def test_median_and_percentile_equal_numpy_bit_for_bit(n):
    # The replay's median and percentiles skip numpy's masked-array import; they must give
    # numpy's own values exactly (even counts, ties, ints, every percentile rule branch).
    from imu_dcm.arrays import median, percentile

    rng = np.random.default_rng(n)
    columns = rng.normal(size=(n, 3))[:, 1]  # a strided view
    for a in (rng.normal(size=n) * 1e3, np.round(rng.normal(size=n) * 3), rng.integers(0, 5, n),
              columns):  # fmt: skip
        before = a.copy()
        assert median(a) == float(np.median(a))
        for q in (0, 1, 25, 50, 75, 99, 99.9, 100, *rng.uniform(0, 100, 5)):
            assert percentile(a, q) == float(np.percentile(a, q)), q
        assert np.array_equal(a, before)  # partially sorted on a copy of its own
        own = np.array(a, dtype=np.float64)  # partially sorted itself, when asked
        assert median(own.copy(), overwrite_input=True) == float(np.median(a))
    assert np.isnan(median([1.0, np.nan, 2.0])) and np.isnan(percentile([np.nan], 50))
    assert np.isnan(median([])) and np.isnan(percentile([], 50))


@pytest.mark.parametrize("n", [1, 2, 3, 4, 7, 10, 101, 1000])
def test_median_diff_is_numpys_median_of_the_steps(n):
    # The median step, partially sorted in place: numpy's median of np.diff exactly, for int64
    # stamps (ns) and float times, and the input left as it was.
    from imu_dcm.arrays import median_diff

    rng = np.random.default_rng(n)
    epoch = np.int64(1_700_000_000_123_456_789)  # ns since 1970: beyond float64's 2^53
    for t in (
        np.cumsum(rng.integers(1, 9, n)),
        np.cumsum(rng.uniform(0, 1, n)),
        epoch + np.cumsum(rng.integers(1, 9, n)),
    ):
        before = t.copy()
        want = float(np.median(np.diff(t))) if n > 1 else np.nan
        got = median_diff(t)
        assert got == want or (np.isnan(got) and np.isnan(want))
        assert np.array_equal(t, before)


def test_true_span_is_the_first_last_and_count_of_the_trues():
    # One stretch or several, at the ends or inside, none: what np.flatnonzero's ends and
    # length give, without its index of every row.
    from imu_dcm.arrays import true_span

    rng = np.random.default_rng(9)
    for mask in (rng.random(1000) < 0.3, np.r_[np.zeros(5), np.ones(7), np.zeros(3)] > 0,
                 np.ones(4, bool), np.array([True])):  # fmt: skip
        idx = np.flatnonzero(mask)
        assert true_span(mask) == (idx[0], idx[-1], len(idx))
    assert true_span(np.zeros(6, bool)) is None and true_span([]) is None


def test_attitude_errors_row_by_row_are_scipys_swing_and_twist():
    # The replay's per-sample score (one compiled pass over rows) against scipy: the total is
    # the magnitude of q_est ⊗ q_true*; the inclination the angle of its swing s (the shortest
    # rotation taking world z where it goes), the heading that of its twist s⁻¹ ⊗ e about z.
    # Any sign and scale of either quaternion, and angles from 1e-9 rad to π.
    from imu_dcm._kernels.calls import attitude_errors
    from imu_dcm.metrics import AttitudeError, attitude_error_deg

    def compiled(q_est, q_true):
        out = np.empty((3, len(q_est)))
        assert attitude_errors(q_est, q_true, out) == -1
        return AttitudeError(*out)

    rng = np.random.default_rng(12)
    n = 5000
    q_true = Rotation.random(n, random_state=3)
    size = np.logspace(-9, np.log10(np.pi), n)[:, None]
    axis = rng.normal(size=(n, 3))
    e = Rotation.from_rotvec(axis / np.linalg.norm(axis, axis=1, keepdims=True) * size)
    q_est = e * q_true
    a, b = q_est.as_quat(), q_true.as_quat()
    a[::3] *= -2.5
    b[1::4] *= -0.5
    got = compiled(a, b)
    np.testing.assert_allclose(got.total_deg, np.degrees(e.magnitude()), rtol=1e-8, atol=1e-12)
    z = np.array([0.0, 0.0, 1.0])
    v = e.apply(z)
    cross = np.cross(z, v)
    tilt = np.arctan2(np.linalg.norm(cross, axis=1), v[:, 2])
    swing = Rotation.from_rotvec(
        np.where(
            tilt[:, None] > 0, cross / np.maximum(np.linalg.norm(cross, axis=1), 1e-300)[:, None], 0
        )
        * tilt[:, None]
    )
    twist = swing.inv() * e
    assert np.allclose(twist.apply(z), z, atol=1e-9)  # a rotation about z indeed
    np.testing.assert_allclose(got.inclination_deg, np.degrees(tilt), rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(got.heading_deg, np.degrees(twist.magnitude()), rtol=1e-7, atol=1e-9)
    # the compiled rows and numpy's planes (the same formulas; libm's arctangent and numpy's
    # SIMD one may differ by an ulp or two) agree to a few ulp
    planes = attitude_error_deg(a, b)
    for f in ("total_deg", "inclination_deg", "heading_deg"):
        np.testing.assert_allclose(getattr(got, f), getattr(planes, f), rtol=1e-15, atol=0)
    # a zero or NaN quaternion: its row is named, and the replay's score refuses it by name
    from imu_dcm.replay.core import _row_errors

    for bad in (np.zeros(4), np.full(4, np.nan)):
        c = b.copy()
        c[n // 2] = bad
        assert attitude_errors(a, c, np.empty((3, n))) == n // 2
        with pytest.raises(InputError, match="finite non-zero norm"):
            _row_errors(a, c)


def test_the_angle_between_attitudes_row_by_row_is_scipys_relative_rotation():
    # the compiled rows (the sampling check's) and numpy's planes: scipy's magnitude of
    # q_a⁻¹ q_b at any sign and scale, angles from 1e-9 rad to π, a zero or NaN quaternion
    # named or refused whichever row it is in
    from imu_dcm._kernels.calls import quat_angles
    from imu_dcm.so3 import quat_angle_rad

    rng = np.random.default_rng(14)
    n = 4000
    a = Rotation.random(n, random_state=4)
    rv = rng.normal(size=(n, 3))
    rv *= (np.logspace(-9, np.log10(np.pi), n) / np.linalg.norm(rv, axis=1))[:, None]
    b = a * Rotation.from_rotvec(rv)
    qa, qb = a.as_quat() * rng.choice([-3.0, 0.5], (n, 1)), b.as_quat()
    want = (a.inv() * b).magnitude()
    got = np.empty(n)
    assert quat_angles(qa, qb, got) == -1
    np.testing.assert_allclose(got, want, rtol=1e-8, atol=8 * EPS)
    np.testing.assert_allclose(quat_angle_rad(qa, qb), want, rtol=1e-8, atol=8 * EPS)
    # the rows' pass and numpy's planes: the same formula (arctangents an ulp or two apart)
    np.testing.assert_allclose(got, quat_angle_rad(qa, qb), rtol=1e-15, atol=0)
    for bad in (np.zeros(4), np.full(4, np.nan)):
        c = qb.copy()
        c[n - 1] = bad
        assert quat_angles(qa, c, np.empty(n)) == n - 1
        with pytest.raises(InputError, match="finite non-zero norm"):
            quat_angle_rad(qa, c)

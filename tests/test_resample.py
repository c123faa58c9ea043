"""Tests of the attitude resampler (imu_dcm.gyro.resample.slerp_truth), which replay and live share.

Oracle: scipy's Slerp on the same samples; and gaps counted in truth steps by hand.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from imu_dcm.errors import InputError
from imu_dcm.gyro.resample import slerp_truth, step_rotvecs
from imu_dcm.so3 import log_quat, quat_multiply

T0_NS = 1_700_000_000_000_000_000
EPS = np.finfo(float).eps


def test_slerp_truth_matches_scipy_slerp_inside_coverage():
    rng = np.random.default_rng(3)
    tt = T0_NS + np.arange(12, dtype=np.int64) * 10_000_000  # 100 Hz truth
    q = Rotation.random(12, random_state=4).as_quat()
    q[::3] *= -1  # sign flips must not matter (shortest arc)
    t = np.sort(rng.integers(tt[0] - 5_000_000, tt[-1] + 5_000_000, 200))
    out = slerp_truth(tt, q, t)
    inside = (t >= tt[0]) & (t <= tt[-1])
    assert np.all(np.isnan(out[~inside]))  # outside coverage: no truth
    ref = Slerp((tt - tt[0]) * 1e-9, Rotation.from_quat(q))((t[inside] - tt[0]) * 1e-9)
    # same rotation up to sign; 1e-12 is float64 round-off of a few quaternion products
    ang = (Rotation.from_quat(out[inside]) * ref.inv()).magnitude()
    assert np.max(ang) < 1e-12
    # at the truth stamps: the samples themselves, up to the round-off of re-normalising
    np.testing.assert_allclose(slerp_truth(tt, q, tt), q, rtol=0, atol=1e-15)


def test_slerp_truth_never_bridges_gaps_longer_than_two_samples():
    tt = T0_NS + np.array([0, 1, 2, 4, 5, 9, 10], dtype=np.int64) * 10_000_000
    q = Rotation.from_rotvec(np.outer(np.arange(7), [0, 0, 0.1])).as_quat()
    t = T0_NS + np.arange(0, 101, 5, dtype=np.int64) * 1_000_000  # every 5 ms
    out = slerp_truth(tt, q, t)
    ok = np.isfinite(out[:, 3])
    t_ms = (t - T0_NS) // 1_000_000
    # 20..40 ms: one missing sample (a 2-step gap) is bridged; 50..90 ms (4 steps) is not
    assert np.all(ok[(t_ms >= 0) & (t_ms <= 50)])
    assert not np.any(ok[(t_ms > 50) & (t_ms < 90)])
    assert np.all(ok[t_ms >= 90])


@pytest.mark.parametrize(
    ("steps_ms", "bridged"),
    [
        ([10, 20, 10, 10], [True] * 4),  # none over twice the shortest: every step, at once
        ([10, 21, 15, 15, 15], [True] * 5),  # over twice the shortest, within twice the median
        ([10, 31, 15, 15, 15], [True, False, True, True, True]),  # over twice the median
    ],
)
def test_slerp_truth_bridges_each_step_by_twice_the_median(steps_ms, bridged):
    tt = T0_NS + np.cumsum([0, *steps_ms]).astype(np.int64) * 1_000_000
    q = Rotation.from_rotvec(np.outer(np.arange(len(tt)), [0, 0, 0.1])).as_quat()
    mid = (tt[:-1] + tt[1:]) // 2  # one query inside each step
    np.testing.assert_array_equal(np.isfinite(slerp_truth(tt, q, mid)[:, 3]), bridged)


def test_slerp_truth_halfway_to_90_deg_about_z_is_45_deg_about_z():
    # the convention at the boundary: [x, y, z, w], scalar last; halfway is half the angle
    tt = T0_NS + np.array([0, 10_000_000], dtype=np.int64)
    q = np.array([[0.0, 0.0, 0.0, 1.0], [0.0, 0.0, np.sqrt(0.5), np.sqrt(0.5)]])
    out = slerp_truth(tt, q, T0_NS + np.array([5_000_000], dtype=np.int64))
    want = Rotation.from_euler("z", 45, degrees=True).as_quat()
    # a log, an exp and one product of unit quaternions: a few ulps of 1 each (2e-16)
    np.testing.assert_allclose(out[0], want, rtol=0, atol=2e-15)


def test_slerp_truth_of_queries_in_any_order_or_in_pieces_is_the_same(monkeypatch):
    """Queries resampled shuffled, in pieces of 7, or far apart (found by bisection rather than
    by walking from the last one's step) give the sorted result bit for bit, across a gap and
    both ends: each query depends on its own stamp only."""
    rng = np.random.default_rng(5)
    tt = np.cumsum(rng.integers(9_000_000, 11_000_000, 3000)).astype(np.int64)
    tt[1500:] += 500_000_000  # a gap that is never bridged
    q = Rotation.random(3000, random_state=6).as_quat()
    t = np.sort(rng.integers(tt[0] - 10**8, tt[-1] + 10**8, 10000)).astype(np.int64)
    t = np.sort(np.concatenate([t, tt[::30]]))  # some queries exactly on truth samples
    whole = slerp_truth(tt, q, t)
    assert np.isnan(whole).any() and np.isfinite(whole).any()
    k = rng.permutation(len(t))
    np.testing.assert_array_equal(slerp_truth(tt, q, t[k]), whole[k])
    pieces = [slerp_truth(tt, q, t[a : a + 7]) for a in range(0, len(t), 7)]
    np.testing.assert_array_equal(np.concatenate(pieces), whole)
    sparse = slice(0, None, 97)  # ~300 truth steps apart
    np.testing.assert_array_equal(slerp_truth(tt, q, t[sparse]), whole[sparse])


def test_step_rotvecs_are_scipys_relative_rotations_of_consecutive_rows():
    # steps of every size: none, below the series bound, ordinary, near a half turn; the rows'
    # signs and norms are arbitrary (both are the same attitude)
    rng = np.random.default_rng(21)
    n = 400
    axes = rng.normal(size=(n - 1, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.concatenate(
        [np.zeros(20), 1e-7 * rng.random(100), rng.random(200), np.pi - 1e-3 * rng.random(79)]
    )
    rng.shuffle(angles)
    steps = Rotation.from_rotvec(axes * angles[:, None])
    r = [Rotation.random(random_state=rng)]
    for s in steps:
        r.append(r[-1] * s)
    r = Rotation.concatenate(r)
    q = r.as_quat() * rng.choice([-1.0, 1.0], size=(n, 1)) * rng.uniform(0.5, 2.0, size=(n, 1))
    ok = np.ones(n, bool)
    got = step_rotvecs(q, ok)
    want = (r[:-1].inv() * r[1:]).as_rotvec()
    # each product component is four products of unit-size numbers (a few ulps), and the
    # logarithm's gain is at most 2 per unit of the vector part (theta/sin(theta/2) <= pi)
    np.testing.assert_allclose(got, want, rtol=0, atol=32 * EPS)
    # the numpy path (log of the product of the conjugate) gives the same numbers
    np.testing.assert_allclose(
        got, log_quat(quat_multiply(q[:-1] * [-1, -1, -1, 1], q[1:])), rtol=0, atol=8 * EPS
    )
    # a row not to be used makes both its steps NaN; the others are untouched
    ok[7] = False
    got2 = step_rotvecs(q, ok)
    assert np.isnan(got2[6:8]).all()
    np.testing.assert_array_equal(np.delete(got2, [6, 7], axis=0), np.delete(got, [6, 7], axis=0))
    # into a given array, and a zero quaternion refused
    out = np.empty((n - 1, 3))
    assert step_rotvecs(q, np.ones(n, bool), out=out) is out
    q[3] = 0.0
    with pytest.raises(InputError, match="non-zero norm"):
        step_rotvecs(q, np.ones(n, bool))


def _turning(rng, n: int):
    """A truth that turns by steps of every size (signs and norms of its rows arbitrary), its
    scipy rotations, and stamps of uneven steps, s."""
    axes = rng.normal(size=(n - 1, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.concatenate([np.zeros(10), 1e-7 * rng.random(90), 0.01 * rng.random(n - 101)])
    rng.shuffle(angles)
    r = [Rotation.random(random_state=rng)]
    for s in Rotation.from_rotvec(axes * angles[:, None]):
        r.append(r[-1] * s)
    r = Rotation.concatenate(r)
    q = r.as_quat() * rng.choice([-1.0, 1.0], size=(n, 1)) * rng.uniform(0.5, 2.0, size=(n, 1))
    return q, r, np.cumsum(rng.uniform(0.8e-3, 1.2e-3, n))


def test_second_steps_are_the_changes_between_scipys_consecutive_step_rotations():
    # the truth's noise reads |d_{k+1} - d_k| of consecutive usable steps: those of a row that
    # is missing, or of a step marked unusable (a jump), are skipped, the rest kept in order
    from imu_dcm._kernels.calls import second_steps

    rng = np.random.default_rng(22)
    n = 600
    q, r, _ = _turning(rng, n)
    ok = np.ones(n, bool)
    ok[[50, 51, 300]] = False
    q[[50, 51, 300]] = np.nan
    step_ok = rng.random(n - 1) > 0.05
    d = (r[:-1].inv() * r[1:]).as_rotvec()
    usable = ok[:-1] & ok[1:] & step_ok
    pairs = np.flatnonzero(usable[:-1] & usable[1:])
    want = np.abs(d[pairs + 1] - d[pairs]).T
    out = np.full((3, n - 2), -1.0)
    assert second_steps(q, ok, step_ok, out) == len(pairs)
    np.testing.assert_allclose(out[:, : len(pairs)], want, rtol=0, atol=64 * EPS)


def test_rate_ratios_are_the_gyros_mean_rate_over_scipys_step_rate_where_the_truth_moves():
    from imu_dcm._kernels.calls import rate_ratios

    rng = np.random.default_rng(23)
    n = 600
    q, r, t = _turning(rng, n)
    ok = np.ones(n, bool)
    ok[[10, 400]] = False
    w = rng.normal(size=(n, 3))
    d = (r[:-1].inv() * r[1:]).as_rotvec()
    rate = np.linalg.norm(d, axis=1) / np.diff(t)
    moving = 2.0
    keep = np.flatnonzero(ok[:-1] & ok[1:] & (rate > moving))
    assert 100 < len(keep) < n - 100  # some steps turn faster than that, some slower
    want = np.linalg.norm(0.5 * (w[keep] + w[keep + 1]), axis=1) / rate[keep]
    out = np.full(n - 1, -1.0)
    assert rate_ratios(w, t, q, ok, moving, out) == len(keep)
    # a step's rotation is within 32 ulp of 1 of scipy's (see above), and a moving step turns
    # at least moving * 0.8 ms = 1.6e-3 rad: its rate within 32 EPS / 1.6e-3 = 4.4e-12 relative
    np.testing.assert_allclose(out[: len(keep)], want, rtol=32 * EPS / 1.6e-3 + 8 * EPS)


@pytest.mark.parametrize("m", [2, 3, 50, 599])
def test_window_rates_are_the_norms_of_scipys_mean_step_rates(m):
    # the rest rule's |omega_T| of every window of m rows: the norm of the mean of the steps'
    # rates over its m - 1 steps (scipy's relative rotations over the stamps' steps), NaN for
    # a window with a step next to a missing row
    from imu_dcm.gyro.rest_evidence import truth_rates

    rng = np.random.default_rng(24)
    n = 600
    q, r, t = _turning(rng, n)
    q[[100, 101, 450]] = np.nan
    rate = (r[:-1].inv() * r[1:]).as_rotvec() / np.diff(t)[:, None]
    bad = np.zeros(n - 1, bool)
    bad[[99, 100, 101, 449, 450]] = True  # the steps touching a missing row
    want = np.array(
        [
            np.nan if bad[a : a + m - 1].any() else np.linalg.norm(rate[a : a + m - 1].mean(axis=0))
            for a in range(n - m + 1)
        ]
    )
    got = truth_rates(q, t, m)
    assert np.array_equal(np.isnan(got), np.isnan(want))
    # each step's rate within 32 EPS / 0.8 ms of scipy's; each running sum, of up to n rates
    # below 0.01 rad / 0.8 ms = 12.5 rad/s, within n ulp of its largest value, n * 12.5: a
    # window's mean, their difference over m - 1, within 2 n EPS n 12.5 / (m - 1)
    tol = 32 * EPS / 0.8e-3 + 2 * n * EPS * n * 12.5 / (m - 1)
    np.testing.assert_allclose(got, want, rtol=0, atol=tol)

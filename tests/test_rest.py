"""imu_dcm.gyro.rest, rest_rule and windows: the windowed statistics and run finding that rest
detection, the bias and the pre-filter's noise estimate share. Truth: direct numpy computations
and hand-made masks."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import raises_naming

from imu_dcm.arrays import row_max, row_norm
from imu_dcm.errors import InputError
from imu_dcm.gyro.rest import (
    detect_rest,
    quietest_std,
)
from imu_dcm.gyro.rest_rule import RestConfig, longest_run, runs, window_samples
from imu_dcm.gyro.windows import min_steps, window_norms, windowed_mean_var


def test_windowed_mean_var_equals_direct_windows():
    rng = np.random.default_rng(0)
    x = rng.normal(3.0, 0.5, size=(500, 3))
    m = 25
    mean, var = windowed_mean_var(x, m)
    direct = np.stack([x[i : i + m] for i in range(len(x) - m + 1)])
    assert mean.shape == var.shape == (len(x) - m + 1, 3)
    # running sums of n = 500 terms of size ~3: rounding ~ n eps |x| on the mean, and the
    # variance is a difference of squares ~9 (n eps 9 relative to var 0.25 at worst)
    eps = np.finfo(float).eps
    np.testing.assert_allclose(mean, direct.mean(axis=1), rtol=0, atol=len(x) * eps * 10)
    np.testing.assert_allclose(var, direct.var(axis=1), rtol=0, atol=len(x) * eps * 100)
    assert np.all(var >= 0.0)


@pytest.mark.parametrize("m", [1, 25, 700, 3000])
def test_window_norms_are_the_norms_of_the_windows(m):
    # One compiled pass with the running sums of windowed_mean_var (each row added to the sum
    # before it, in order): the largest variance is its bytes; the norm adds the mean's three
    # squares in order, numpy's einsum in its own, so the two are a rounding or two apart
    x = np.random.default_rng(m).normal(0.3, 0.2, size=(3000, 3))
    x[2900] = np.nan  # from there on every window is NaN, as in numpy's sums
    mean, var = windowed_mean_var(x, m)
    norm, max_var = window_norms(x, m)
    assert max_var.tobytes() == row_max(var).tobytes()
    np.testing.assert_allclose(norm, row_norm(mean), rtol=2 * np.finfo(float).eps, atol=0)
    assert np.array_equal(np.isnan(norm), np.isnan(row_norm(mean)))
    # the smallest positive step of each column, NaN steps none
    d = np.abs(np.diff(x, axis=0))
    want = np.where(d > 0, d, np.inf).min(axis=0)
    np.testing.assert_array_equal(min_steps(x), want)
    assert np.isinf(min_steps(np.ones((5, 2)))).all()


def test_runs_and_longest_run():
    mask = np.array([0, 1, 1, 0, 0, 1, 1, 1, 0, 1], dtype=bool)
    assert runs(mask) == [(1, 3), (5, 8), (9, 10)]
    assert longest_run(mask) == (5, 8)
    assert runs(np.zeros(4, bool)) == [] and longest_run(np.zeros(4, bool)) == (0, 0)
    assert runs(np.ones(3, bool)) == [(0, 3)]
    # ties: the first of equal runs
    assert longest_run(np.array([1, 1, 0, 1, 1], dtype=bool)) == (0, 2)


def test_window_samples_rounds_up_and_keeps_two():
    t = np.arange(100) * 0.01
    assert window_samples(t, 0.5) == 50
    assert window_samples(t, 0.505) == 51
    assert window_samples(t, 0.001) == 2


def test_quietest_std_finds_the_noise_floor_of_the_quiet_part():
    # 4 s of noise sigma = 0.01 rad/s, then 4 s of a 1 rad/s sine on top: the quietest 0.5 s
    # window lies in the noise alone. A window's std has a spread of 1/sqrt(2*100) = 7 %; the
    # smallest of the quiet part's ~14 independent windows lies at most 3.5 spreads (25 %) low,
    # and the largest of three axes can only raise it: (0.0075, 0.0105) fails a window that
    # reaches into the motion (std ~0.7 rad/s) or a wrong window length.
    rng = np.random.default_rng(1)
    t = np.arange(1600) / 200.0
    w = rng.normal(0.0, 0.01, size=(1600, 3))
    w[800:] += np.sin(2 * math.pi * t[800:, None])
    assert 0.0075 < quietest_std(w, t, 0.5) < 0.0105


def test_detect_rest_marks_the_still_segment_only():
    rng = np.random.default_rng(2)
    t = np.arange(2000) / 200.0
    w = rng.normal(0.0, 0.002, size=(2000, 3))
    w[1000:, 2] += 1.0  # turning at 1 rad/s after 5 s
    rest = detect_rest(w, t, RestConfig())
    assert rest[:990].all() and not rest[1000:].any()
    with raises_naming(InputError, "omega_b", "(N, 3)", "(2000, 2)"):
        detect_rest(w[:, :2], t)


def test_gyro_windows_kept_for_a_second_judgement_are_those_of_the_rates_asked_for():
    # A replay judges rest twice on the same rates (the gyro alone, then with its truth): the
    # kept windows give that judgement exactly, and other rates or windows are made anew.
    from imu_dcm.gyro.rest import GyroWindows, judge_rest

    rng = np.random.default_rng(4)
    t = np.arange(4000) * 0.005
    w = rng.normal(0.0, 0.002, size=(4000, 3))
    w[1500:2500] += [0.3, -0.2, 0.1]  # motion between two rests
    kept = GyroWindows()
    first = judge_rest(w, t, windows=kept)
    assert first == judge_rest(w, t, windows=kept) == judge_rest(w, t)
    assert len(first.segments) == 2
    moved = w + [0.0, 0.0, 0.5]  # other rates: no rest at 0.5 rad/s, whatever was kept
    assert judge_rest(moved, t, windows=kept) == judge_rest(moved, t)
    assert judge_rest(moved, t, windows=kept).segments == []

"""Offline (imu_dcm.gyro.rest.rest_segments) and live (imu_dcm.gyro.rest_causal.CausalRestBias) run
one rest
rule: on a log of rests of known samples, short and long, both find each rest and its bias as
computed here from the construction alone (which samples rest, one window off each side, or the
middle half when less than a window would remain)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_rest_agreement import rests_log as rests_log_at_200hz

from imu_dcm.errors import InputError
from imu_dcm.gyro.rest import rest_segments
from imu_dcm.gyro.rest_causal import CausalRestBias
from imu_dcm.replay.bias import estimate_bias

SIGMA = 0.002  # gyro noise, rad/s
BIAS = np.array([0.004, -0.002, 0.003])  # rad/s
TURN = 1.0  # rad/s about z while moving: any window holding a moving sample is far off the floor
#: rest lengths, s: at 200 Hz (m = 100) 0.9 s and 1.4 s keep under a window after trimming one
#: window each side (their middle half), 1.6 s and 6.0 s keep 120 and 1000 samples
RESTS_S = (0.9, 1.4, 1.6, 6.0)


def rests_log(rate_hz: float, seed: int):
    """Motion, then each rest of RESTS_S followed by 1 s of motion. Returns w, t and the rests'
    ``[a, b)`` sample ranges."""
    rng = np.random.default_rng(seed)
    n_move = int(rate_hz)
    parts, spans, k = [], [], 0
    for i, dur in enumerate((None, *RESTS_S)):
        if i:  # a rest
            n = int(round(dur * rate_hz))
            parts.append(rng.normal(0.0, SIGMA, (n, 3)) + BIAS)
            spans.append((k, k + n))
            k += n
        move = rng.normal(0.0, SIGMA, (n_move, 3)) + BIAS
        move[:, 2] += TURN
        parts.append(move)
        k += n_move
    w = np.concatenate(parts)
    return w, np.arange(len(w)) / rate_hz, spans


def expected_span(a: int, b: int, m: int) -> tuple[int, int]:
    """The samples whose mean is the bias, from the rule's words: one window off each side next
    to motion; the middle half when less than a window would remain."""
    if (b - m) - (a + m) >= m:
        return a + m, b - m
    quarter = (b - a) // 4
    return a + quarter, b - quarter


@pytest.mark.parametrize(("rate_hz", "seed"), [(200.0, 1), (200.0, 2), (333.0, 3)])
def test_offline_and_live_find_each_rest_and_its_bias_short_and_long(rate_hz, seed):
    w, t, spans = rests_log(rate_hz, seed)
    m = math.ceil(round(0.5 * rate_hz, 6))  # the rule's window: 0.5 s of samples
    offline, _conflict = rest_segments(w, t)
    live = CausalRestBias()
    live.update_many(w, t)
    live.finish()
    eps = np.finfo(float).eps
    for found in (offline, live.segments):
        assert [(s.start, s.stop) for s in found] == spans
        for s, (a, b) in zip(found, spans, strict=True):
            lo, hi = expected_span(a, b, m)
            assert (s.lo, s.hi) == (lo, hi), (a, b)
            assert (s.start_s, s.end_s) == (t[a], t[b - 1])
            # the mean of hi - lo samples, summed in another order: rounding <= n eps |w|
            want = w[lo:hi].mean(axis=0)
            np.testing.assert_allclose(s.bias_rad_s, want, rtol=0, atol=4 * (hi - lo) * eps * 0.01)
            # and it is the true bias to within 5 standard errors of the mean (per axis)
            assert np.all(np.abs(np.array(s.bias_rad_s) - BIAS) < 5 * SIGMA / math.sqrt(hi - lo))
    # short rests took their middle half, long ones lost one window each side
    length = [b - a for a, b in spans]
    assert [s.hi - s.lo for s in offline] == [
        n - 2 * (n // 4) if n < 3 * m else n - 2 * m for n in length
    ]
    assert length[0] < length[1] < 3 * m < length[2] < length[3]  # both kinds are tried


# -- rests that disagree (the agreement rule, causal) ----------------------------------------

RATE_HZ = 200.0
M = 100  # the rule's window at 200 Hz: 0.5 s
REST_S = 4.0  # each rest: 800 samples, 600 of them its bias (one window off each side)
#: a slow turn the window rule takes for rest: z at 5 standard errors of a window's mean over
#: the bias (0.057 °/s: at the floor, under the 2 °/s a gyro-only rest allows)
TURN_OFF = np.array([0.0, 0.0, 5 * SIGMA / math.sqrt(M)])


def agreement_log(offsets, seed: int):
    """1 s of motion, then each rest of REST_S at ``BIAS + offset`` followed by 1 s of motion
    (:func:`test_rest_agreement.rests_log`: over each rest's bias span the noise has mean 0 and
    sample std SIGMA exactly, so each rest's bias is ``BIAS + offset`` and its noise
    SIGMA / √n). Returns w, t, each rest's ``[a, b)`` and its bias span ``[lo, hi)``."""
    return rests_log_at_200hz([(REST_S, BIAS + off) for off in offsets], seed)


def run_live(w, t):
    live = CausalRestBias()
    applied = live.update_many(w, t)
    live.finish()
    return live, applied


def test_a_slow_turn_after_three_agreeing_rests_is_not_used():
    zero = np.zeros(3)
    w, t, spans = agreement_log([zero, zero, zero, TURN_OFF, zero], seed=7)
    live, applied = run_live(w, t)
    # the turn passed the window rule: five segments, each where the construction put it
    assert [(s.start, s.stop) for s in live.segments] == [(a, b) for a, b, _lo, _hi in spans]
    assert live.agreement.used == [True, True, True, False, True]
    # reported, with its distance from the two before it: 5 SE of a window over √(2) SE of a rest
    ((i, noises),) = live.agreement.outliers
    se = SIGMA / math.sqrt(REST_S * RATE_HZ - 2 * M)
    assert i == 3 and noises == pytest.approx(TURN_OFF[2] / (math.sqrt(2) * se), rel=1e-6)
    line = live.agreement.result().line
    a3, b3 = spans[3][:2]
    assert f"{t[a3]:.2f}-{t[b3 - 1]:.2f} s" in line and "not used" in line, line
    # the final bias is the rests' at BIAS, within their noise
    assert np.all(np.abs(np.array(live.bias_rad_s) - BIAS) < 4 * se)
    # from the turn's close (its last window's end) to the next rest's first estimate, the
    # bias applied is the rest before it's, not the turn's
    a4 = spans[4][0]
    between = applied[b3 - 1 + M : a4 + 2 * M]
    assert len(between) and np.all(np.abs(between - BIAS) < 4 * se)
    assert np.all(np.abs(between[:, 2] - BIAS[2] - TURN_OFF[2]) > 4 * se)  # not the turn's


def test_rests_that_agree_change_nothing(monkeypatch):
    # Independent draws at one bias: every rest used, and the bias applied to every sample is
    # bit for bit the one without the agreement rule (it never finds an outlier).
    rng = np.random.default_rng(11)
    w, t, spans = rests_log(RATE_HZ, 11)
    w = np.concatenate([w, rng.normal(0.0, SIGMA, (800, 3)) + BIAS])  # a fifth rest, at the end
    t = np.arange(len(w)) / RATE_HZ
    live, applied = run_live(w, t)
    assert len(live.segments) == 5 and all(live.agreement.used)
    assert live.agreement.result().line == ""
    monkeypatch.setattr("imu_dcm.gyro.rest_agreement.outlier", lambda *_a, **_k: None)
    before, applied_before = run_live(w, t)
    assert np.array_equal(applied, applied_before)
    assert live.segments == before.segments and live.bias_rad_s == before.bias_rad_s


@pytest.mark.parametrize("where", [2, 3])
def test_offline_and_live_find_the_same_outlier(where):
    # An interior rest off by a slow turn, between rests that agree (two or more before it):
    # replay's pass over the whole log and live's, rest by rest, leave out the same one.
    offsets = [np.zeros(3)] * 5
    offsets[where] = TURN_OFF
    w, t, spans = agreement_log(offsets[: where + 2], seed=20 + where)
    offline = estimate_bias(w, t, "auto").agreement
    live, _applied = run_live(w, t)
    a, b = spans[where][:2]
    assert [(o["start_s"], o["end_s"]) for o in offline["outliers"]] == [(t[a], t[b - 1])]
    live_out = live.agreement.result().as_dict(live.segments)
    assert [(o["start_s"], o["end_s"]) for o in live_out["outliers"]] == [(t[a], t[b - 1])]
    assert live_out["outliers"][0]["noises"] == pytest.approx(
        offline["outliers"][0]["noises"], rel=1e-9
    )


# -- the accelerometer (a live source that carries it) ---------------------------------------

G = 9.80665
SIGMA_A = 0.02  # accelerometer noise, m/s²


def still_accel(n: int, rng) -> np.ndarray:
    """A still accelerometer: gravity along +z (specific force up) and its noise."""
    return rng.normal(0.0, SIGMA_A, (n, 3)) + [0.0, 0.0, G]


def shaken_log(seed: int):
    """2 s rest, 2 s of a body that accelerates and vibrates without rotating (gyro at its
    floor: bias and noise only; accelerometer 4 m/s² forward plus a 2 m/s² vibration at 13 Hz,
    |mean a| - g = 0.8 m/s² and std 1.4 m/s², far beyond its floor of 0.02), 1 s of turn, 2 s
    rest, 1 s of turn. Returns w, a, t and the rests' ``[a, b)``."""
    rng = np.random.default_rng(seed)
    n_r, n_v, n_m = 400, 400, 200
    gyro = [rng.normal(0.0, SIGMA, (n, 3)) + BIAS for n in (n_r, n_v, n_m, n_r, n_m)]
    for i in (2, 4):
        gyro[i][:, 2] += TURN
    acc = [still_accel(n, rng) for n in (n_r, n_v, n_m, n_r, n_m)]
    tv = np.arange(n_v) / RATE_HZ
    acc[1][:, 0] += 4.0 + 2.0 * np.cos(2 * math.pi * 13.0 * tv)
    w, a = np.concatenate(gyro), np.concatenate(acc)
    r2 = n_r + n_v + n_m
    return w, a, np.arange(len(w)) / RATE_HZ, [(0, n_r), (r2, r2 + n_r)]


@pytest.mark.parametrize("batch", [1, 37, 10_000])
def test_a_shaken_body_at_the_gyro_floor_is_not_rest_live_or_offline(batch):
    w, a, t, spans = shaken_log(seed=31)
    live = CausalRestBias()
    for i in range(0, len(w), batch):
        live.update_many(w[i : i + batch], t[i : i + batch], a[i : i + batch])
    live.finish()
    offline, _conflict = rest_segments(w, t, accel_b=a)
    # the shaking is not rest: the two rests, where the construction put them, live and offline
    assert [(s.start, s.stop) for s in live.segments] == spans
    assert [(s.start, s.stop, s.lo, s.hi) for s in live.segments] == [
        (s.start, s.stop, s.lo, s.hi) for s in offline
    ]
    for s in (*live.segments, *offline):
        assert s.evidence == ("gyro floor", "accelerometer")
    eps = np.finfo(float).eps
    for s, o in zip(live.segments, offline, strict=True):
        np.testing.assert_allclose(s.bias_rad_s, o.bias_rad_s, rtol=0, atol=4 * s.hi * eps * 0.01)
    # the gyro alone takes the shaking for rest: its first rest runs on through it
    alone = CausalRestBias()
    alone.update_many(w, t)
    alone.finish()
    assert alone.segments[0].start == 0 and alone.segments[0].stop == 2 * spans[0][1]


def test_a_true_rest_with_the_accelerometer_says_so_and_has_the_constructions_bias():
    offsets = [np.zeros(3), np.array([0.001, 0.0, -0.001]), np.zeros(3)]
    w, t, spans = agreement_log(offsets, seed=41)
    a = still_accel(len(w), np.random.default_rng(42))
    live = CausalRestBias()
    live.update_many(w, t, a)
    live.finish()
    offline, _conflict = rest_segments(w, t, accel_b=a)
    for found in (live.segments, offline):
        assert [(s.start, s.stop, s.lo, s.hi) for s in found] == spans
        for s, off in zip(found, offsets, strict=True):
            assert s.evidence == ("gyro floor", "accelerometer")
            # over the bias span the noise has mean 0: the bias is the construction's
            np.testing.assert_allclose(s.bias_rad_s, BIAS + off, rtol=0, atol=1e-15)


def test_without_the_accelerometer_the_gyro_judges_alone_as_before():
    # no accelerometer: the gyro-only rule (evidence "gyro floor" alone), whether None is
    # passed or nothing, sample by sample or in one batch, bit for bit
    w, t, spans = rests_log(RATE_HZ, 5)
    one = CausalRestBias()
    applied = one.update_many(w, t)
    one.finish()
    each = CausalRestBias()
    applied_each = np.array([each.update(tuple(x), s, None) for x, s in zip(w, t, strict=True)])
    each.finish()
    assert np.array_equal(applied, applied_each)
    assert one.segments == each.segments
    assert [(s.start, s.stop) for s in one.segments] == spans
    assert all(s.evidence == ("gyro floor",) for s in one.segments)
    offline, _conflict = rest_segments(w, t)
    assert [(s.start, s.stop, s.lo, s.hi, s.evidence) for s in offline] == [
        (s.start, s.stop, s.lo, s.hi, s.evidence) for s in one.segments
    ]


def test_the_accelerometer_comes_with_every_batch_or_with_none():
    w, t, _spans = rests_log(RATE_HZ, 6)
    live = CausalRestBias()
    live.update_many(w[:10], t[:10], still_accel(10, np.random.default_rng(0)))
    with pytest.raises(InputError, match="every batch or with none"):
        live.update_many(w[10:20], t[10:20])


def test_a_sample_without_an_accelerometer_reading_breaks_the_rest_it_falls_in():
    w, t, spans = agreement_log([np.zeros(3)], seed=43)
    a = still_accel(len(w), np.random.default_rng(44))
    (a0, b0, _lo, _hi) = spans[0]
    k = (a0 + b0) // 2
    a[k] = np.nan  # this sample came without one: no window holding it is rest
    live = CausalRestBias()
    live.update_many(w, t, a)
    live.finish()
    assert [(s.start, s.stop) for s in live.segments] == [(a0, k), (k + 1, b0)]

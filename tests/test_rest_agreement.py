"""Rests that disagree beyond their noise are not all rests: each case is built from rests of
known samples and known bias, and the bound is the rests' own standard errors (sample std over
√n), computed here from the construction."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from imu_dcm.logio.types import ImuSeries, LogData
from imu_dcm.replay import replay
from imu_dcm.replay.bias import estimate_bias
from imu_dcm.replay.summary import format_summary

RATE_HZ = 200.0
M = 100  # the rule's window at 200 Hz: 0.5 s
SIGMA = 0.002  # gyro noise, rad/s
BIAS = np.array([0.004, -0.002, 0.003])  # rad/s
TURN = 1.0  # rad/s about z between rests: never still


def rests_log(rests, seed: int):
    """1 s of motion, then each rest ``(duration_s, bias)`` followed by 1 s of motion. Returns
    w, t and each rest's ``[a, b)`` and bias span ``[lo, hi)`` (one window off each side)."""
    rng = np.random.default_rng(seed)
    n_move = int(RATE_HZ)
    parts, spans, k = [], [], 0
    for rest in (None, *rests):
        if rest is not None:
            dur, bias = rest
            n = int(round(dur * RATE_HZ))
            x = rng.normal(0.0, SIGMA, (n, 3))
            # over the bias span the noise has mean 0 and sample std SIGMA exactly
            span = x[M : n - M]
            x[M : n - M] = (span - span.mean(axis=0)) / span.std(axis=0, ddof=1) * SIGMA
            parts.append(x + bias)
            spans.append((k, k + n, k + M, k + n - M))
            k += n
        move = rng.normal(0.0, SIGMA, (n_move, 3)) + BIAS
        move[:, 2] += TURN
        parts.append(move)
        k += n_move
    w = np.concatenate(parts)
    return w, np.arange(len(w)) / RATE_HZ, spans


def se(lo: int, hi: int) -> float:
    """The standard error of a rest's bias per axis: SIGMA / √n (the sample std is SIGMA)."""
    return SIGMA / math.sqrt(hi - lo)


def test_a_slow_turn_between_two_rests_that_agree_is_not_used():
    # Standing, then a 3 s "rest" yawing at 0.3 °/s (a hover, a slow turn: at the floor and
    # under the 2 °/s a gyro-only rest allows), then standing again.
    h = math.radians(0.3)
    w, t, spans = rests_log([(4.0, BIAS), (3.0, BIAS + [0, 0, h]), (5.0, BIAS)], seed=1)
    est = estimate_bias(w, t, "auto")
    (a0, b0, lo0, hi0), (a1, b1, lo1, hi1), (a2, b2, lo2, hi2) = spans
    assert [(s.start, s.stop) for s in est.segments] == [(a0, b0), (a2, b2)]
    line = est.agreement["line"]
    assert f"{t[a1]:.2f}-{t[b1 - 1]:.2f} s" in line and "not used" in line, line
    (out,) = est.agreement["outliers"]
    assert (out["start_s"], out["end_s"]) == (t[a1], t[b1 - 1])
    # its distance from the nearer neighbour, in noises: h / √(se₁² + se_j²), the smaller
    want = min(h / math.hypot(se(lo1, hi1), se(lo, hi)) for lo, hi in ((lo0, hi0), (lo2, hi2)))
    assert out["noises"] == pytest.approx(want, rel=1e-6)
    # the bias applied everywhere is the standing one's, to within 5 standard errors
    assert np.all(np.abs(est.bias_b - BIAS) < 5 * se(lo2, hi2))


@pytest.mark.parametrize("seed", range(5))
def test_rests_of_one_bias_agree(seed):
    # The same bias at four rests (noise of independent draws): all used, nothing said.
    rng = np.random.default_rng(100 + seed)
    w, t, spans = rests_log([(float(rng.uniform(2, 6)), BIAS) for _ in range(4)], seed=seed)
    est = estimate_bias(w, t, "auto")
    assert len(est.segments) == 4 and est.agreement["line"] == ""
    assert est.agreement["outliers"] == [] and est.agreement["disagree"] == []


@pytest.mark.parametrize(("noises", "said"), [(3.9, False), (4.1, True)])
def test_two_rests_disagree_beyond_four_of_their_noises_and_both_are_used(noises, said):
    # Two rests whose biases differ on z by `noises` times √(se₁² + se₂²): beyond 4 (the rest
    # rule's spreads) they disagree. With two nothing tells which is wrong: both are used.
    n1, n2 = 4.0, 3.0
    lo_hi = [(M, int(n1 * RATE_HZ) - M), (M, int(n2 * RATE_HZ) - M)]
    d = noises * math.hypot(*(se(lo, hi) for lo, hi in lo_hi))
    w, t, spans = rests_log([(n1, BIAS), (n2, BIAS + [0, 0, d])], seed=7)
    est = estimate_bias(w, t, "auto")
    assert len(est.segments) == 2 and est.agreement["outliers"] == []
    assert bool(est.agreement["line"]) is said
    if said:
        ((_, _, got),) = [
            (p["first_s"], p["second_s"], p["noises"]) for p in est.agreement["disagree"]
        ]
        assert got == pytest.approx(noises, rel=1e-6)
        assert "all used" in est.agreement["line"]


def test_replay_says_which_rest_it_did_not_use():
    # The slow turn between two rests through replay: the summary JSON and its line.
    h = math.radians(0.3)
    w, t, spans = rests_log([(4.0, BIAS), (3.0, BIAS + [0, 0, h]), (5.0, BIAS)], seed=2)
    t_ns = 1_000_000_000 + np.arange(len(w), dtype=np.int64) * 5_000_000
    imu = ImuSeries(t_ns, t_ns, w, None, "/imu", "sensor_msgs/msg/Imu", "imu")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = replay(LogData("turns.mcap", imu, None, ()))
    s = res.summary
    assert len(s.bias_segments) == 2
    agreement = s.to_dict()["rest_agreement"]
    assert agreement["evidence"] == "the rests' own sample std and lengths"
    a1, b1 = spans[1][:2]
    ((start, end),) = [(o["start_s"], o["end_s"]) for o in agreement["outliers"]]
    assert start == pytest.approx(t[a1], abs=1e-9) and end == pytest.approx(t[b1 - 1], abs=1e-9)
    line = next(x for x in format_summary(s).splitlines() if x.startswith("rests      "))
    assert "biases disagree beyond their noise" in line and "not used" in line

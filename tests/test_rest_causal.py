"""Offline (imu_dcm.gyro.rest.rest_segments) and live (imu_dcm.gyro.rest_causal.CausalRestBias) run
one rest
rule: on a log of rests of known samples, short and long, both find each rest and its bias as
computed here from the construction alone (which samples rest, one window off each side, or the
middle half when less than a window would remain)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from imu_dcm.gyro.rest import rest_segments
from imu_dcm.gyro.rest_causal import CausalRestBias

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

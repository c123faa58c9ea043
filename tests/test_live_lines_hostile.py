"""Line sources: a hostile line is one malformed line, never a crash or a value."""

from __future__ import annotations

import pytest

from imu_dcm.live.lines import parse_lines

GOOD = b"0.010,0,0,1"


@pytest.mark.parametrize(
    "bad",
    [
        b'{"t_s": 0.5, "omega_b": ' + b"[" * 30_000 + b"]" * 30_000 + b"}",  # RecursionError
        b'{"t_s": "1e999999999", "omega_b": [0, 0, 1]}',  # decimal.Overflow
        b"1e999999999,0,0,1",
        b"1e999990,0,0,1",  # in range of the decimal context, a million digits as an int
        b'{"t_s": 0.5, "omega_b": [true, 0, 0]}',  # true is no rate of 1
        b'{"t_s": 0.5, "omega_b": ["1.5", 0, 0]}',
        b'{"t_s": 0.5, "omega_b": [0, 0, 1], "q_w_b": [0, 0, 0, true]}',
    ],
)
def test_a_hostile_line_is_one_malformed_line(bad):
    t, w, tt, q, malformed = parse_lines([GOOD, bad, GOOD.replace(b"0.010", b"0.020")])
    assert malformed == 1
    assert t.tolist() == [10_000_000, 20_000_000] and w.tolist() == [[0, 0, 1]] * 2
    assert len(tt) == len(q) == 0

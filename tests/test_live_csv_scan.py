"""The compiled CSV line scan (:func:`imu_dcm._kernels.scan_csv`) and the bulk parse on it
(:func:`imu_dcm.live.lines.parse_csv_blob`) against independent oracles: Python's ``Decimal``
for the exact stamps, Python's ``float`` for the rates; any line not of the plain form sends
the batch to the line-by-line parser."""

from __future__ import annotations

from decimal import Decimal

import numpy as np
import pytest

from imu_dcm._kernels import scan_csv
from imu_dcm.live.lines import TIME_UNITS, parse_csv_blob, parse_lines


def _decimal_ns(text: str, unit: str) -> int:
    return int(Decimal(text) * TIME_UNITS[unit])


@pytest.mark.parametrize("unit", ["s", "ms", "us", "ns"])
def test_stamps_exact_and_rates_as_float(unit):
    rng = np.random.default_rng(7)
    digits = len(str(TIME_UNITS[unit])) - 1
    stamps, rows = [], []
    for _ in range(500):
        whole = int(rng.integers(0, 10 ** int(rng.integers(1, 10))))
        n_frac = int(rng.integers(0, digits + 1))
        frac = "".join(str(d) for d in rng.integers(0, 10, n_frac))
        stamp = f"{whole}.{frac}" if n_frac or rng.random() < 0.3 else str(whole)
        rates = rng.standard_normal(3) * 10.0 ** rng.integers(-20, 20, 3)
        fields = [repr(float(r)) for r in rates]
        stamps.append(stamp)
        rows.append(f"{stamp},{','.join(fields)}")
    blob = "\n".join(rows).encode()
    t_ns, w, bad = parse_csv_blob(blob, time_units=unit)
    assert bad == 0
    assert t_ns.tolist() == [_decimal_ns(s, unit) for s in stamps]
    expect = [[float(f) for f in r.split(",")[1:]] for r in rows]
    assert np.array_equal(w, np.array(expect))  # bit for bit: both correctly rounded


def test_blank_lines_spaces_and_crlf():
    t, text, rows = scan_csv(b"1.5,1,2,3\r\n\n  \n 2.25 ,4,5,6\n", TIME_UNITS["s"], 9)
    assert rows == 2 and t.tolist() == [1_500_000_000, 2_250_000_000]
    t_ns, w, bad = parse_csv_blob(b"1.5,1,2,3\r\n\n 2.25 ,4,5,6\n")
    assert t_ns.tolist() == [1_500_000_000, 2_250_000_000] and bad == 0
    assert w.tolist() == [[1, 2, 3], [4, 5, 6]]


@pytest.mark.parametrize(
    "line",
    [
        b"t_s,gx,gy,gz",  # a header
        b'{"t_ns": 1, "omega_b": [0, 0, 0]}',  # JSON
        b"1,2,3",  # three fields
        b"1,2,3,4,5",  # five fields
        b"-1.5,0,0,0",  # a negative stamp
        b"1.0000000001,0,0,0",  # a decimal beyond the ns
        b"1e3,0,0,0",  # an exponent in the stamp
        b"9223372036.854775808,0,0,0",  # 2**63 ns
    ],
)
def test_a_line_not_plain_sends_the_batch_line_by_line(line):
    blob = b"1,0,0,0\n" + line + b"\n2,0,0,0"
    assert scan_csv(blob, TIME_UNITS["s"], 9)[2] < 0
    assert parse_csv_blob(blob) is None


def test_the_largest_stamp_and_a_rate_that_is_no_number():
    assert scan_csv(b"9223372036.854775807,0,0,0", TIME_UNITS["s"], 9)[0].tolist() == [2**63 - 1]
    assert parse_csv_blob(b"1,0,0,0\n2,0,x,0") is None  # the line-by-line parser counts it
    t, _, _, _, bad = parse_lines([b"1,0,0,0", b"2,0,x,0"])
    assert t.tolist() == [1_000_000_000] and bad == 1


def test_non_finite_rates_are_rows_the_pipeline_judges():
    # not malformed: the pipeline drops and counts them with every other non-finite rate
    blob = b"1,0,0,1\n2,nan,0,0\n3,0,inf,0\n4,1,1,1\n5,1.7e308,0,0"
    t_ns, w, bad = parse_csv_blob(blob, gyro_units="deg/s")
    assert bad == 0 and t_ns.tolist() == [k * 1_000_000_000 for k in range(1, 6)]
    assert np.array_equal(w[[0, 3]], np.radians([[0, 0, 1], [1, 1, 1]]))
    assert np.isnan(w[1, 0]) and np.isinf(w[2, 1]) and w[4, 0] == np.radians(1.7e308)


def test_built_scan_equals_numba_compile():
    from imu_dcm._kernels import entries

    blob = b"1700000026.5055,0.25,-1e-3,7\n\n12,1,2,3\n"
    t, text, rows = scan_csv(blob, TIME_UNITS["s"], 9)
    jit = entries.compiled("csv_scan")(np.frombuffer(blob, np.uint8).copy(), 10**9, 9)
    assert jit[0].tolist() == t.tolist() == [1700000026505500000, 12_000_000_000]
    assert jit[1].tobytes() == text == b"0.25,-1e-3,7,1,2,3," and jit[2] == rows == 2

"""Line samples for the UDP and stdin sources: CSV ``t,gx,gy,gz`` or JSON lines.

CSV: ``t,gx,gy,gz`` with the stamp in ``time_units`` (s, ms, us or ns) and the rates in
``gyro_units`` (rad/s or deg/s), body axes. A first line with letters (a header) is skipped. JSON:
an object with the stamp as ``t_ns`` (int, ns) or ``t_s`` (s), the rates as ``omega_b`` (or
``gyro``) ``[x, y, z]`` or ``gx``, ``gy``, ``gz`` in ``gyro_units``, and optionally a truth
``q_w_b`` ``[x, y, z, w]`` (a line with a stamp and ``q_w_b`` only is a truth sample). Stamps are
parsed as exact decimals (``1700000026.505500000`` s is exactly 1700000026505500000 ns; a float64
would round it to ~0.2 µs).

Anything else — wrong field count, not a number, a non-finite stamp or quaternion — is a
malformed line: :func:`parse_lines` counts it and goes on. A line whose rates are NaN or Inf is a
sample, not a malformed line: the pipeline drops and counts it with the other non-finite rates
(one count, ``NaN/Inf``, whatever the source).
"""

from __future__ import annotations

import json
import math
import warnings
from decimal import Decimal, DecimalException

import numpy as np
from numpy.typing import NDArray

from imu_dcm._kernels import scan_csv

__all__ = ["TIME_UNITS", "parse_csv_blob", "parse_lines", "time_unit_hint"]

#: Nanoseconds per unit of a CSV stamp.
TIME_UNITS = {"s": 1_000_000_000, "ms": 1_000_000, "us": 1_000, "ns": 1}
DEG = math.pi / 180.0


#: The range's ends are inclusive: a step is a difference of float64 seconds, exact to ~1e-16
#: of the stamps' magnitude; 1e-6 relative is far above that and far below a unit's factor.
_STEP_ROUNDING = 1e-6


def time_unit_hint(median_step_s: float, max_step_s: float, time_units: str | None) -> str | None:
    """One line when the steps are of no IMU (a rate below 1 Hz or above 100 kHz, the ends
    included in the range, or a step of hours), naming the likely stamp unit; None when they
    look like an IMU's.

    ``time_units``: the unit the stamps were declared in (None: the source's own stamps). The
    likely unit is the one that makes the median step 0.1-100 ms (10 Hz to 10 kHz).
    """
    if median_step_s > 1.0 * (1 + _STEP_ROUNDING) or median_step_s < 1e-5 * (1 - _STEP_ROUNDING):
        got = f"a median step of {median_step_s:.6g} s ({1.0 / median_step_s:.6g} Hz)"
    elif max_step_s > 3600.0:
        got = f"a step of {max_step_s / 3600.0:.3g} h"
    else:
        return None
    line = f"Expected the steps of an IMU (1 Hz to 100 kHz, no step of hours), got {got}"
    if time_units is None:
        return f"{line}: the source's stamps are not an IMU's"
    fits = [
        u
        for u, ns in TIME_UNITS.items()
        if u != time_units and 1e-4 <= median_step_s * ns / TIME_UNITS[time_units] <= 0.1
    ]
    if not fits:
        return f"{line}: check the unit of the stamps (--time-units)"
    return f"{line}: stamps in {fits[0]} declared as {time_units}? (--time-units {fits[0]})"


def _stamp_ns(text, scale: int) -> int:
    """An exact decimal (str) or a number to integer ns; raises ValueError."""
    if isinstance(text, bool):
        raise TypeError("a bool is no stamp")
    if isinstance(text, int):
        return text * scale
    try:
        d = Decimal(text.strip() if isinstance(text, str) else repr(float(text)))
        if not d.is_finite():
            raise ValueError("non-finite stamp")
        d *= scale
    except (DecimalException, TypeError, ValueError, OverflowError):
        # 1e999999999 s overflows the decimal context: no stamp, not a crash
        raise ValueError(f"not a stamp: {text!r:.40}") from None
    if not 0 <= d < 2**63:  # before int(): 1e999990 s would be a million digits
        raise ValueError("stamp out of range")
    return int(d.to_integral_value())


def _json_number(v) -> float:
    """A JSON number as a float; a bool, a string or null is no rate (``true`` is not 1)."""
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise TypeError(f"not a number: {v!r:.40}")
    return float(v)


def _parse_json(obj, gyro_scale: float) -> tuple[int, list[float], list[float] | None]:
    if not isinstance(obj, dict):
        raise TypeError("not an object")
    if "t_ns" in obj:
        t = obj["t_ns"]
        if not isinstance(t, int) or isinstance(t, bool):
            raise ValueError("t_ns not an integer")
        t_ns = t
    elif "t_s" in obj:
        t_ns = _stamp_ns(obj["t_s"], 1_000_000_000)
    else:
        raise ValueError("no t_ns or t_s")
    q = obj.get("q_w_b")
    w = obj.get("omega_b", obj.get("gyro"))
    if w is None and "gx" in obj:
        w = [obj["gx"], obj["gy"], obj["gz"]]
    if w is None and q is not None:
        omega = None  # a truth-only line
    elif not isinstance(w, list) or len(w) != 3:
        raise ValueError("omega_b not 3 numbers")
    else:
        omega = [_json_number(v) * gyro_scale for v in w]
    if q is not None:
        if not isinstance(q, list) or len(q) != 4:
            raise ValueError("q_w_b not 4 numbers")
        q = [_json_number(v) for v in q]
    return t_ns, omega, q


def parse_lines(
    lines: list[bytes], *, gyro_units: str = "rad/s", time_units: str = "s", first: bool = False
) -> tuple[NDArray, NDArray, NDArray, NDArray, int]:
    """Parse sample lines: a batch of plain CSV lines in one pass, anything else line by line.

    Parameters
    ----------
    lines : list of bytes
        One sample per line (no line ends needed; blank lines are ignored).
    gyro_units : {"rad/s", "deg/s"}
        Unit of the rates; converted to rad/s.
    time_units : {"s", "ms", "us", "ns"}
        Unit of CSV stamps (JSON names its unit by key).
    first : bool
        ``lines[0]`` is the first line of the stream (a header there is skipped, not counted).

    Returns
    -------
    t_ns : int64 (n,)
    omega_b : float64 (n, 3), rad/s, body axes
    truth_t_ns : int64 (m,)
    truth_q_w_b : float64 (m, 4), ``[x, y, z, w]``
    malformed : int
        Lines that are neither a CSV sample nor a JSON sample (non-finite rates are returned
        as they are: the pipeline counts them).

    Notes
    -----
    A batch of plain CSV lines (``digits[.digits]`` stamps, four fields each) is parsed as
    arrays; a batch with any other line (JSON, a header, a malformed line) goes line by line, so
    that a bad line is counted alone and the good lines around it are kept.
    """
    gyro_scale = DEG if gyro_units == "deg/s" else 1.0
    t_scale = TIME_UNITS[time_units]
    head: list[bytes] = []
    if first and lines:
        head, lines = lines[:1], lines[1:]
    lines = [ln for ln in lines if ln.strip()]
    bulk = _parse_csv_bulk(b"\n".join(lines), gyro_scale, t_scale) if lines else None
    if bulk is None:
        return _parse_each(head + lines, gyro_scale, t_scale, first=bool(head))
    t, w, bad = bulk
    if head:
        t0, w0, tt, q, bad0 = _parse_each(head, gyro_scale, t_scale, first=True)
        t, w, bad = np.concatenate([t0, t]), np.concatenate([w0, w]), bad + bad0
        return t, w, tt, q, bad
    return t, w, np.zeros(0, np.int64), np.zeros((0, 4)), bad


def parse_csv_blob(
    blob: bytes, *, gyro_units: str = "rad/s", time_units: str = "s"
) -> tuple[NDArray, NDArray, int] | None:
    """Plain CSV lines ``t,gx,gy,gz`` (lines end in ``\\n``; blank lines are skipped; no header)
    in one pass: ``(t_ns, omega_b, malformed)``, non-finite rates returned as they are; None
    when a line is not of that form (then :func:`parse_lines` judges the lines one by one).

    The stamps are read exactly and the line structure checked by one compiled scan
    (:func:`imu_dcm._kernels.scan_csv`); the rates by one float parse of them all, correctly
    rounded as Python's ``float``."""
    return _parse_csv_bulk(blob, DEG if gyro_units == "deg/s" else 1.0, TIME_UNITS[time_units])


def _parse_csv_bulk(blob: bytes, gyro_scale: float, t_scale: int):
    """:func:`parse_csv_blob` scaling the rates by ``gyro_scale``: ``(t_ns, omega, malformed)``
    or None."""
    digits = len(str(t_scale)) - 1  # decimals a stamp may carry: 9 for s, 0 for ns
    t_ns, text, rows = scan_csv(blob, t_scale, digits)
    if rows < 0:
        return None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)  # numpy's word for "stopped early"
            w = np.fromstring(text, dtype=np.float64, sep=",")
    except ValueError:
        return None
    if len(w) != 3 * rows:
        return None  # a rate field that is not a number
    w = w.reshape(rows, 3)
    if gyro_scale != 1.0:
        with np.errstate(over="ignore"):  # 1.7e308 deg/s: inf, dropped by the pipeline
            w *= gyro_scale
    return t_ns, w, 0


def _parse_each(
    lines: list[bytes], gyro_scale: float, t_scale: int, *, first: bool
) -> tuple[NDArray, NDArray, NDArray, NDArray, int]:
    """:func:`parse_lines` one line at a time (JSON, headers, malformed lines)."""
    ts: list[int] = []
    ws: list[list[float]] = []
    tts: list[int] = []
    qs: list[list[float]] = []
    bad = 0
    for i, raw in enumerate(lines):
        line = raw.strip()
        if not line:
            continue
        try:
            t_ns, omega, q = _parse_one(line, gyro_scale, t_scale, header_ok=i == 0 and first)
        except (ValueError, KeyError, TypeError, UnicodeDecodeError, OverflowError):
            bad += 1
            continue
        if t_ns is None:
            continue  # a CSV header
        if q is not None:
            tts.append(t_ns)
            qs.append(q)
        if omega is not None:
            ts.append(t_ns)
            ws.append(omega)
    return (
        np.array(ts, dtype=np.int64),
        np.array(ws, dtype=float).reshape(-1, 3),
        np.array(tts, dtype=np.int64),
        np.array(qs, dtype=float).reshape(-1, 4),
        bad,
    )


def _parse_one(line: bytes, gyro_scale: float, t_scale: int, *, header_ok: bool):
    """One stripped line -> ``(t_ns, omega or None, q or None)``; ``(None, None, None)`` for a
    header; raises ValueError (or another parse error) for a malformed line."""
    if line[:1] == b"{":
        try:
            obj = json.loads(line)
        except RecursionError:  # nested deeper than Python's stack, within the 64 KiB a line has
            raise ValueError("JSON nested too deep") from None
        t_ns, omega, q = _parse_json(obj, gyro_scale)
    else:
        parts = line.split(b",")
        if len(parts) != 4:
            if header_ok and any(c.isalpha() for c in line.decode(errors="replace")):
                return None, None, None
            raise ValueError("not 4 fields")
        try:
            t_ns = _stamp_ns(parts[0].decode("ascii"), t_scale)
        except (ValueError, UnicodeDecodeError):
            if header_ok:
                return None, None, None
            raise
        omega = [float(p) * gyro_scale for p in parts[1:]]
        q = None
    if not 0 <= t_ns < 2**63:
        raise ValueError("stamp out of range")
    if q is not None and not all(math.isfinite(v) for v in q):
        raise ValueError("non-finite quaternion")
    return t_ns, omega, q

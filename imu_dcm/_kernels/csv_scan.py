"""The live CSV line scanner, written for numba: plain ``t,gx,gy,gz`` lines in one pass, the
stamps as exact integer ns (:mod:`imu_dcm.live.lines` parses the rates it copies out), and its
entry point (:data:`ENTRIES`).

Imported only to compile, like :mod:`imu_dcm._kernels.integrator`.
"""

from __future__ import annotations

import numpy as np

from imu_dcm._kernels.jit import inline, njit

__all__ = ["ENTRIES", "SIGNATURE", "csv_scan"]

SIGNATURE = "Tuple((int64[::1], uint8[::1], int64))(uint8[::1], int64, int64)"
_INT64_MAX = 9223372036854775807


@inline
def _is_space(c) -> bool:
    return c == 32 or c == 9 or c == 13


@njit
def _stamp_ns(b, lo: int, hi: int, scale: int, digits: int) -> int:
    """The stamp ``digits[.digits]`` of ``b[lo:hi]`` (spaces around it allowed, at most
    ``digits`` decimals) as exact integer ns, or -1 for any other form or for 2**63 ns or
    more."""
    while lo < hi and _is_space(b[lo]):
        lo += 1
    while hi > lo and _is_space(b[hi - 1]):
        hi -= 1
    whole = np.int64(0)
    k = lo
    while k < hi and 48 <= b[k] <= 57:
        d = np.int64(b[k] - 48)
        if whole > (_INT64_MAX - d) // 10:
            return -1
        whole = whole * 10 + d
        k += 1
    if k == lo:
        return -1
    frac = np.int64(0)
    n_frac = 0
    if k < hi and b[k] == 46:  # "."
        k += 1
        while k < hi and 48 <= b[k] <= 57 and n_frac < digits:
            frac = frac * 10 + np.int64(b[k] - 48)
            n_frac += 1
            k += 1
    if k != hi:
        return -1  # another character, or more decimals than the unit holds
    for _ in range(n_frac, digits):
        frac *= 10
    if whole > (_INT64_MAX - frac) // scale:
        return -1
    return whole * scale + frac


def csv_scan(b, scale: int, digits: int):
    """Plain CSV lines ``t,gx,gy,gz`` of the bytes ``b`` (a uint8 array; lines end in
    ``\\n``, blank lines skipped) in one pass: the stamps as exact integer ns (``t`` in units
    of ``scale`` ns with at most ``digits`` decimals), the rate fields copied as text, each
    followed by a comma (for one float parse of them all), and the number of lines; or, at
    the first line not of that form, ``-1 - its index`` among the lines (the caller then judges
    the lines one by one)."""
    n = len(b)
    t = np.empty(n // 4 + 1, np.int64)  # a line holds 4 bytes at least ("1,,,")
    text = np.empty(n + 1, np.uint8)
    rows = 0
    out = 0
    lo = 0
    line = 0
    while lo < n:
        hi = lo
        while hi < n and b[hi] != 10:
            hi += 1
        a = lo
        while a < hi and _is_space(b[a]):
            a += 1
        if a < hi:  # not a blank line
            c1 = a
            while c1 < hi and b[c1] != 44:
                c1 += 1
            if c1 == hi or b[a] == 123:  # one field, or "{": JSON
                return t[:0], text[:0], -1 - line
            stamp = _stamp_ns(b, a, c1, scale, digits)
            commas = 0
            for k in range(c1 + 1, hi):
                commas += b[k] == 44
            if stamp < 0 or commas != 2:
                return t[:0], text[:0], -1 - line
            t[rows] = stamp
            rows += 1
            for k in range(c1 + 1, hi):
                text[out] = b[k]
                out += 1
            text[out] = 44
            out += 1
            line += 1
        lo = hi + 1
    return t[:rows], text[:out], rows


#: ``name -> (function, signature)`` of this kernel's entry point.
ENTRIES = {"csv_scan": (csv_scan, SIGNATURE)}

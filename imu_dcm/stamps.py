"""Stamps no IMU produces: a sample rate below 1 Hz or above 100 kHz, steps of an hour, a log
lasting days. Usually a time unit declared wrongly (ms read as s); :func:`timing_doubt` names
the unit that would make the log plausible.

Conventions: stamps int64 nanoseconds; units ``s, ms, us, ns`` as in ``--time-units``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from imu_dcm.so3 import median

__all__ = ["NS_PER_UNIT", "timing_doubt"]

#: Nanoseconds per time unit.
NS_PER_UNIT = {"s": 1_000_000_000, "ms": 1_000_000, "us": 1_000, "ns": 1}
#: Sample rates an IMU produces, Hz.
MIN_RATE_HZ, MAX_RATE_HZ = 1.0, 100_000.0
#: Longest plausible step (s) and log (s).
MAX_STEP_S, MAX_DURATION_S = 3600.0, 2 * 86400.0
#: The rate a corrected unit should give, Hz (the middle of common IMU rates, in log scale).
_TYPICAL_HZ = 200.0


def timing_doubt(t_ns: ArrayLike, unit: str = "s") -> tuple[str, str | None] | None:
    """Why these stamps are no IMU's, and the time unit that would fix them, or None.

    Parameters
    ----------
    t_ns : array_like, int64 (N,)
        Stamps as read (after the declared unit was applied), increasing.
    unit : str
        The unit the stamps were declared in.

    Returns
    -------
    (clause, unit or None), or None when the timing is plausible. ``clause`` reads
    "0.20 Hz (median step 5.000 s) over 19995.000 s; as ms: 200.0 Hz over 20.0 s".
    """
    t = np.asarray(t_ns, dtype=np.int64)
    if len(t) < 3:
        return None
    step_s = median(np.diff(t)) * 1e-9
    span_s = float(t[-1] - t[0]) * 1e-9
    if step_s <= 0:
        return None
    rate = 1.0 / step_s
    if MIN_RATE_HZ <= rate <= MAX_RATE_HZ and step_s <= MAX_STEP_S and span_s <= MAX_DURATION_S:
        return None
    clause = f"{rate:.3g} Hz (median step {_seconds(step_s)}) over {_seconds(span_s)}"
    best, best_off = None, np.inf
    for other, ns in NS_PER_UNIT.items():
        k = ns / NS_PER_UNIT[unit]
        r, span = rate / k, span_s * k
        if other == unit or not (MIN_RATE_HZ <= r <= MAX_RATE_HZ) or span > MAX_DURATION_S:
            continue
        off = abs(np.log(r / _TYPICAL_HZ))
        if off < best_off:
            best, best_off = other, off
    if best is None:
        return clause, None
    k = NS_PER_UNIT[best] / NS_PER_UNIT[unit]
    return f"{clause}; as {best}: {rate / k:.4g} Hz over {_seconds(span_s * k)}", best


def _seconds(x: float) -> str:
    if x >= 86400:
        return f"{x / 86400:.1f} days"
    if x >= 3600:
        return f"{x / 3600:.1f} h"
    return f"{x:.4g} s"

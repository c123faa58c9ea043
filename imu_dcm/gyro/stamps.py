"""Stamps no IMU produces: a sample rate below 1 Hz or above 100 kHz, steps of an hour, a log
lasting days, or a rate under 10 Hz that the gyro's own content contradicts. Usually a time
unit declared wrongly (ms read as s); :func:`timing_doubt` names the unit that would make the
log plausible.

The content test (with the rates given): at a step ``dt`` a gyro resolves a motion only while
it turns well under a radian per sample. Rates that turn a median of more than
:data:`MAX_STEP_RAD` per sample at the declared step, yet change little from one sample to the
next (lag-1 autocorrelation of the three axes together over :data:`MIN_SMOOTH`: the motion is
resolved), were
sampled faster than declared.

Conventions: stamps int64 nanoseconds; units ``s, ms, us, ns`` as in ``--time-units``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from imu_dcm.arrays import median, median_diff

__all__ = ["NS_PER_UNIT", "timing_doubt"]

#: Nanoseconds per time unit.
NS_PER_UNIT = {"s": 1_000_000_000, "ms": 1_000_000, "us": 1_000, "ns": 1}
#: Sample rates an IMU produces, Hz.
MIN_RATE_HZ, MAX_RATE_HZ = 1.0, 100_000.0
#: Longest plausible step (s) and log (s).
MAX_STEP_S, MAX_DURATION_S = 3600.0, 2 * 86400.0
#: Below this rate, Hz, the gyro's content must agree with the step (see the module docstring).
CONTENT_RATE_HZ = 10.0
#: A median turn per sample above this, rad, is not resolved at the declared step.
MAX_STEP_RAD = 0.5
#: Lag-1 autocorrelation above this: the samples are smooth, the motion resolved.
MIN_SMOOTH = 0.9
#: The rate a corrected unit should give, Hz (the middle of common IMU rates, in log scale).
_TYPICAL_HZ = 200.0


def _content_contradicts(step_s: float, omega_b: ArrayLike) -> str:
    """The clause when smooth rates turn more than :data:`MAX_STEP_RAD` per declared step."""
    w = np.asarray(omega_b, dtype=float)
    if w.ndim != 2 or len(w) < 10:
        return ""
    turn = median(np.linalg.norm(w, axis=1)) * step_s
    d = w - w.mean(axis=0)
    den = float(np.sum(d * d))
    if turn <= MAX_STEP_RAD or den <= 0:
        return ""
    rho = float(np.sum(d[1:] * d[:-1])) / den  # the axes together: the moving ones weigh most
    if rho <= MIN_SMOOTH:
        return ""
    return (
        f"; the gyro turns a median {turn:.2f} rad per step yet its samples are smooth "
        f"(lag-1 autocorrelation {rho:.3f})"
    )


def timing_doubt(
    t_ns: ArrayLike, unit: str = "s", omega_b: ArrayLike | None = None
) -> tuple[str, str | None] | None:
    """Why these stamps are no IMU's, and the time unit that would fix them, or None.

    Parameters
    ----------
    t_ns : array_like, int64 (N,)
        Stamps as read (after the declared unit was applied), increasing.
    unit : str
        The unit the stamps were declared in.
    omega_b : array_like (N, 3), optional
        The gyro's rates, rad/s, on the same rows: judges a rate under 10 Hz by its content.

    Returns
    -------
    (clause, unit or None), or None when the timing is plausible. ``clause`` reads
    "0.20 Hz (median step 5.000 s) over 19995.000 s; as ms: 200.0 Hz over 20.0 s".
    """
    t = np.asarray(t_ns, dtype=np.int64)
    if len(t) < 3:
        return None
    step_s = median_diff(t) * 1e-9
    span_s = float(t[-1] - t[0]) * 1e-9
    if step_s <= 0:
        return None
    rate = 1.0 / step_s
    content = ""
    if omega_b is not None and rate < CONTENT_RATE_HZ:
        content = _content_contradicts(step_s, omega_b)
    if (
        MIN_RATE_HZ <= rate <= MAX_RATE_HZ
        and step_s <= MAX_STEP_S
        and span_s <= MAX_DURATION_S
        and not content
    ):
        return None
    clause = f"{rate:.3g} Hz (median step {_seconds(step_s)}) over {_seconds(span_s)}{content}"
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

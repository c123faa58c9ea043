"""Which samples the error is scored on: all, a window, or the intervals the log declares.

``score_window`` (a keyword of :func:`imu_dcm.replay.replay`, ``--score-window``):

* ``"all"`` (the default): every sample with truth and estimate;
* ``(t0_s, t1_s)``: those between ``t0_s`` and ``t1_s`` (inclusive), seconds from the log's
  start (the first gyro stamp, the origin of every time the replay prints);
* ``"declared"``: those inside the intervals the log's metadata declares
  (:mod:`imu_dcm.logio.intervals`, e.g. BROAD's movement phases); a log that declares none is
  refused in one line.

The window chooses what is scored, not what is integrated: the estimate still starts at the
first gyro sample inside the truth's coverage.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from imu_dcm.errors import InputError, LogError
from imu_dcm.logio.intervals import declared_intervals

WORDS = ("all", "declared")


def check_score_window(window) -> str | tuple[float, float]:
    """``"all"``, ``"declared"`` or ``(t0_s, t1_s)`` with finite ``t0_s < t1_s``.

    Raises
    ------
    InputError
        Another word, or not two finite increasing numbers.
    """
    if isinstance(window, str):
        if window not in WORDS:
            raise InputError(f"Expected score window all, declared or T0:T1 s, got {window!r}")
        return window
    try:
        t0, t1 = (float(x) for x in window)
    except (TypeError, ValueError):
        raise InputError(f"Expected score window (t0_s, t1_s), got {window!r}") from None
    if not (math.isfinite(t0) and math.isfinite(t1) and t0 < t1):
        raise InputError(f"Expected a score window T0:T1 with finite T0 < T1 s, got {t0}:{t1}")
    return (t0, t1)


def parse_score_window(text: str) -> str | tuple[float, float]:
    """The command line's ``--score-window`` (``all``, ``declared`` or ``T0:T1``)."""
    if text in WORDS:
        return text
    parts = text.split(":")
    try:
        if len(parts) != 2:
            raise ValueError
        return check_score_window((float(parts[0]), float(parts[1])))
    except ValueError:
        raise InputError(
            f"Expected --score-window all, declared or T0:T1 (seconds from the log's start), "
            f"got {text!r}"
        ) from None


def window_mask(
    window: str | tuple[float, float],
    t_ns: NDArray[np.int64],
    custom_data: dict[str, str],
    where: str,
) -> tuple[NDArray[np.bool_] | None, str]:
    """The samples ``window`` scores (None: all) and how the summary says it.

    Parameters
    ----------
    window : the checked window (:func:`check_score_window`).
    t_ns : int64 (N,) — the gyro stamps, ns; ``t_ns[0]`` is the log's start.
    custom_data : the log's metadata (``LogData.custom_data``).
    where : the log, for the refusal's line.
    """
    if window == "all":
        return None, "all"
    t_s = (t_ns - t_ns[0]) * 1e-9
    if window != "declared":
        t0, t1 = window
        return (t_s >= t0) & (t_s <= t1), f"{t0:g}:{t1:g} s"
    found = declared_intervals(custom_data)
    if not found:
        raise LogError(
            f"Expected intervals declared in the log's metadata (a custom_data key ending in "
            f"intervals_stamp_ns) for --score-window declared, got none in {where}"
        )
    inside = np.zeros(len(t_ns), dtype=bool)
    total = 0.0
    for a, b in found[0].spans_ns:
        inside |= (t_ns >= a) & (t_ns <= b)
        total += (b - a) * 1e-9
    n = len(found[0].spans_ns)
    return inside, f"declared {found[0].name}: {n} interval{'s' if n != 1 else ''}, {total:.2f} s"

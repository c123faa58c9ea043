"""The options of :func:`imu_dcm.replay.replay`, checked once where they enter.

Typed values only: text such as ``"x,y,z"`` is parsed by the command line.
"""

from __future__ import annotations

import math

import numpy as np

from imu_dcm.errors import InputError
from imu_dcm.integrate import METHODS
from imu_dcm.so3 import as_quat_xyzw

__all__ = ["GYRO_UNITS", "PREFILTERS", "TIME_BASES", "check_options"]

TIME_BASES = ("auto", "header", "log")
GYRO_UNITS = ("rad/s", "deg/s")
PREFILTERS = ("kalman", "rts")


def check_options(
    path, time, method, bias, gyro_units, init_q_w_b, prefilter, truth_offset_s
) -> tuple[str | np.ndarray, np.ndarray | None, float | str]:
    """Validate every option of :func:`imu_dcm.replay.replay` once, before the log is read.

    Returns
    -------
    (bias, q_init, truth_offset_s)
        ``bias`` "auto", "none" or a float64 (3,) array, rad/s; ``q_init`` a unit ``[x, y, z, w]``
        or None; the offset as given (seconds or "auto").

    Raises
    ------
    InputError
        A value out of its set or not finite. (A special file as the log is refused by the
        reader, from its ``stat``, before a byte is read.)
    """
    if time not in TIME_BASES:
        raise InputError(f"Expected time in {TIME_BASES}, got {time!r}")
    if method not in METHODS:
        raise InputError(f"Expected method in {METHODS}, got {method!r}")
    if gyro_units is not None and gyro_units not in GYRO_UNITS:
        raise InputError(f"Expected gyro units 'rad/s', 'deg/s' or None, got {gyro_units!r}")
    if prefilter is not None and prefilter not in PREFILTERS:
        raise InputError(f"Expected prefilter None, 'kalman' or 'rts', got {prefilter!r}")
    if isinstance(bias, str):
        if bias not in ("auto", "none"):
            raise InputError(f"Expected bias 'auto', 'none' or 3 numbers (rad/s), got {bias!r}")
    else:
        try:
            bias = np.asarray(bias, dtype=float)
        except (TypeError, ValueError):
            raise InputError(f"Expected bias as 3 finite numbers (rad/s), got {bias!r}") from None
        if bias.shape != (3,) or not np.all(np.isfinite(bias)):
            raise InputError(f"Expected bias as 3 finite numbers (rad/s), got {bias!r}")
    q_init = None if init_q_w_b is None else as_quat_xyzw(init_q_w_b, "init_q_w_b")
    if isinstance(truth_offset_s, str):
        if truth_offset_s != "auto":
            raise InputError(f"Expected truth offset 'auto' or seconds, got {truth_offset_s!r}")
    elif (
        not isinstance(truth_offset_s, (int, float))
        or not math.isfinite(truth_offset_s)
        or abs(truth_offset_s) > 1e6
    ):
        raise InputError(
            f"Expected a finite truth offset in s (|x| <= 1e6), got {truth_offset_s!r}"
        )
    return bias, q_init, truth_offset_s

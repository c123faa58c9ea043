"""The checks of the two values every run is given: the gyro bias and the start attitude.

One check of each, used by the replay (:func:`imu_dcm.replay.replay`, batch), by live
(:func:`imu_dcm.live.run`) and by the bias estimate (:func:`imu_dcm.replay.bias.estimate_bias`),
so a value one refuses the others refuse too, in the same words. The command lines parse the
text (:mod:`imu_dcm.app.options`) and hand the numbers to these checks before any I/O.

* a bias: ``"auto"`` (from rest), ``"none"`` (zero) or 3 finite numbers, rad/s in body axes,
  each within :data:`imu_dcm.gyro.rates.MAX_RATE_RAD_S` (a bias above any gyro's rate is a unit or
  typing mistake);
* a start attitude ``init_q_w_b``: a unit quaternion ``[x, y, z, w]`` (scalar last), finite and
  not zero (normalised here), or a rotation matrix ``R_w_b`` or a single scipy ``Rotation``
  (:func:`imu_dcm.so3.as_quat_xyzw`); None means "from the truth, else the identity".
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imu_dcm.errors import InputError
from imu_dcm.gyro.rates import MAX_RATE_RAD_S
from imu_dcm.so3 import as_quat_xyzw

__all__ = ["BIAS_WORDS", "check_bias", "check_init_q_w_b"]

#: The bias given as a word: estimated from rest, or none removed.
BIAS_WORDS = ("auto", "none")


def check_bias(bias: str | ArrayLike, name: str = "bias") -> str | NDArray[np.float64]:
    """``bias`` checked: ``"auto"``, ``"none"`` or a float64 (3,) array, rad/s.

    Raises
    ------
    InputError
        Another word; not 3 finite numbers; a component above
        :data:`~imu_dcm.gyro.rates.MAX_RATE_RAD_S` in magnitude (``name`` is named in the message).
    """
    if isinstance(bias, str):
        if bias in BIAS_WORDS:
            return bias
        raise InputError(f"Expected {name} 'auto', 'none' or x,y,z in rad/s, got {bias!r}")
    try:
        b = np.array(bias, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"Expected {name} as 3 finite numbers (rad/s), got {bias!r}") from None
    if b.shape != (3,) or not np.all(np.isfinite(b)):
        raise InputError(f"Expected {name} as 3 finite numbers (rad/s), got {b.tolist()}")
    if np.any(np.abs(b) > MAX_RATE_RAD_S):
        raise InputError(
            f"Expected {name} within ±{MAX_RATE_RAD_S:g} rad/s per axis (no gyro's rate is "
            f"larger: deg/s or a typing slip?), got {b.tolist()}"
        )
    return b


def check_init_q_w_b(q_w_b: ArrayLike | None, name: str = "init_q_w_b") -> NDArray | None:
    """The start attitude checked: None, or a unit float64 ``[x, y, z, w]`` (module doc).

    Raises
    ------
    InputError
        Not finite, zero, or neither 4 numbers, a rotation matrix nor a single ``Rotation``.
    """
    return None if q_w_b is None else as_quat_xyzw(q_w_b, name)

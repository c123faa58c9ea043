"""The settings of one replay as one typed, frozen value (:class:`ReplaySettings`).

:func:`imu_dcm.replay.replay` checks its keywords once (:func:`imu_dcm.replay.options.check_options`
and :func:`check_mounting`) and hands the pipeline this object instead of a long argument list.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imu_dcm.errors import InputError
from imu_dcm.rest import RestConfig
from imu_dcm.so3 import as_quat_xyzw

__all__ = ["MOUNTING_MODES", "ReplaySettings", "check_mounting"]

MOUNTING_MODES = ("auto", "none")


@dataclass(frozen=True, eq=False)
class ReplaySettings:
    """How one log is replayed (see :func:`imu_dcm.replay.replay` for each field's meaning).

    ``bias`` is "auto", "none" or a float64 (3,) rad/s; ``q_init`` a unit ``[x, y, z, w]`` or
    None; ``truth_offset_s`` seconds or "auto"; ``mounting`` "auto", "none" or a unit
    ``q_t_g`` ``[x, y, z, w]`` (gyro frame into the truth's body frame).
    """

    imu_topic: str | None = None
    truth_topic: str | None = None
    truth_frame: str | None = None
    time: str = "auto"
    method: str = "magnus4"
    bias: str | NDArray[np.float64] = "auto"
    gyro_units: str = "rad/s"
    q_init: NDArray[np.float64] | None = None
    prefilter: str | None = None
    prefilter_config: object = None
    truth_offset_s: float | str = 0.0
    rest_config: RestConfig | None = None
    mounting: str | NDArray[np.float64] = "auto"


def check_mounting(mounting: str | ArrayLike) -> str | NDArray[np.float64]:
    """``"auto"``, ``"none"`` or a unit quaternion ``[x, y, z, w]`` (normalised here).

    Raises
    ------
    InputError
        Another word, or not 4 finite numbers with a non-zero norm.
    """
    if isinstance(mounting, str):
        if mounting not in MOUNTING_MODES:
            raise InputError(
                f"Expected mounting 'auto', 'none' or a quaternion x,y,z,w, got {mounting!r}"
            )
        return mounting
    return as_quat_xyzw(mounting, "mounting")

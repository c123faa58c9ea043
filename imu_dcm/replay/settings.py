"""The settings of one replay as one typed, frozen value (:class:`ReplaySettings`).

:func:`imu_dcm.replay.replay` checks its keywords once (:func:`imu_dcm.replay.options.check_options`
and :func:`check_mounting`) and hands the pipeline this object instead of a long argument list.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imu_dcm.errors import InputError
from imu_dcm.gyro.rest_rule import RestConfig
from imu_dcm.so3 import as_quat_xyzw

__all__ = ["MOUNTING_MODES", "ReplaySettings", "check_mounting"]

MOUNTING_MODES = ("auto", "none")


@dataclass(frozen=True, eq=False)
class ReplaySettings:
    """How one log is replayed (the keywords of :func:`imu_dcm.replay.replay`, checked).

    Attributes
    ----------
    imu_topic, truth_topic : str or None
        Channel choices (see the log reader); ``truth_topic="none"`` ignores any truth. A truth
        named here is scored even when its rate does not follow the gyro (the summary says so);
        an automatically picked one is chosen among the log's attitude candidates by how its
        rate follows the gyro, and dropped with a warning when none does.
    truth_frame : str or None
        Child frame of a transform truth (``/tf``), passed to the reader.
    time : {"auto", "header", "log"}
        Stamp source; ``"auto"`` prefers the header stamps
        (:func:`imu_dcm.replay.truth.choose_time`).
    method : str
        Integrator method, one of :data:`imu_dcm.integrator.batch.METHODS` (default ``"magnus4"``).
    bias : "auto", "none" or float64 (3,)
        Gyro bias, rad/s (:func:`imu_dcm.replay.bias.estimate_bias`).
    gyro_units : {"rad/s", "deg/s"}
        Unit of the log's rates; deg/s are converted (rad/s is checked for deg/s evidence).
    init_q_w_b : float64 (4,) or None
        Initial ``q_w_b`` ``[x, y, z, w]`` when the log has no truth (default identity).
    prefilter : {None, "kalman", "rts"}
        Gyro pre-filter (:mod:`imu_dcm.gyro.prefilter`), applied after bias removal.
    prefilter_config : PrefilterConfig or None
    truth_offset_s : float or "auto"
        Added to the truth stamps, s; ``"auto"``: the shift that best aligns the truth's rate
        with the gyro's. The best shift is reported either way.
    rest_config : RestConfig or None
        Rest thresholds (:mod:`imu_dcm.gyro.rest_rule`).
    mounting : "auto", "none" or float64 (4,)
        The rotation ``q_t_g`` ``[x, y, z, w]`` from the gyro's frame into the truth's body
        frame (:mod:`imu_dcm.replay.mounting`). ``"auto"``: estimated, and applied when the
        motion determines it and it exceeds a few degrees; ``"none"``: estimated and reported,
        never applied; a quaternion: applied as given (and compared with the estimate).
    score_window : "all", "declared" or (t0_s, t1_s)
        The samples the error is scored on (:mod:`imu_dcm.replay.window`): all (default), the
        intervals the log's metadata declares, or seconds from the log's start.
    truth_convention : str
        How the truth's quaternions are read (:mod:`imu_dcm.replay.convention`): ``"auto"``
        (as read unless the fit determines another clearly), or one of ``"as-is"``,
        ``"conjugate"``, ``"w-first"``, ``"w-last"``, applied as stated.
    """

    imu_topic: str | None = None
    truth_topic: str | None = None
    truth_frame: str | None = None
    time: str = "auto"
    method: str = "magnus4"
    bias: str | NDArray[np.float64] = "auto"
    gyro_units: str = "rad/s"
    init_q_w_b: NDArray[np.float64] | None = None
    prefilter: str | None = None
    prefilter_config: object = None
    truth_offset_s: float | str = 0.0
    rest_config: RestConfig | None = None
    mounting: str | NDArray[np.float64] = "auto"
    score_window: str | tuple[float, float] = "all"
    truth_convention: str = "auto"


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

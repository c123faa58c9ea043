"""Frames of drone logs (PX4, ArduPilot, MAVLink) into the toolkit's, in one place.

Autopilots state body vectors in FRD (x forward, y right, z down) and the world in NED; PX4 and
MAVLink write attitude quaternions ``[w, x, y, z]`` (FRD to NED), ArduPilot Euler angles (roll,
pitch, yaw in degrees, the aerospace 3-2-1 sequence: ``R_ned_frd = Rz(yaw) Ry(pitch) Rx(roll)``).
The toolkit works in body FLU and world ENU with ``[x, y, z, w]``; both the gyro and the truth
are converted, so they stay consistent:

* ``omega_flu = (x, -y, -z)`` of ``omega_frd`` (the same for the accelerometer);
* ``q_enu_flu = q_enu_ned ⊗ q_ned_frd ⊗ q_frd_flu``, ``q_enu_ned = [√½, √½, 0, 0]`` (180° about
  the north-east bisector), ``q_frd_flu = [1, 0, 0, 0]`` (180° about x).

A vehicle facing north (yaw 0) is therefore 90° about z in ENU, and one facing east the identity.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imu_dcm.so3 import quat_multiply

__all__ = [
    "FLU_FROM_FRD",
    "LOG_AXES",
    "Q_ENU_NED",
    "Q_FRD_FLU",
    "in_log_axes",
    "q_enu_flu",
    "q_wxyz_from_euler_deg",
]


_HALF = np.sqrt(0.5)
Q_ENU_NED = np.array([_HALF, _HALF, 0.0, 0.0])  # [x, y, z, w]
Q_FRD_FLU = np.array([1.0, 0.0, 0.0, 0.0])
FLU_FROM_FRD = np.array([1.0, -1.0, -1.0])
#: A log's body axes -> the per-axis signs that take its vectors to FLU (their own inverse).
LOG_AXES = {"FRD": FLU_FROM_FRD}


def in_log_axes(v_flu: ArrayLike, log_axes: str) -> tuple[float, float, float] | None:
    """A body vector in FLU, shape (3,), in the log's own axes ``log_axes`` (a key of
    :data:`LOG_AXES`); None when ``log_axes`` is "" (the log's axes are the toolkit's)."""
    if not log_axes:
        return None
    return tuple(float(x) for x in np.asarray(v_flu, dtype=np.float64) * LOG_AXES[log_axes])


def q_enu_flu(q_wxyz_ned_frd: ArrayLike) -> NDArray[np.float64]:
    """Autopilot quaternions ``[w, x, y, z]`` (FRD to NED), shape (..., 4), as ``q_w_b``
    ``[x, y, z, w]`` (FLU to ENU)."""
    q = np.asarray(q_wxyz_ned_frd, dtype=np.float64)
    q_ned_frd = np.concatenate([q[..., 1:4], q[..., :1]], axis=-1)
    return quat_multiply(quat_multiply(Q_ENU_NED, q_ned_frd), Q_FRD_FLU)


def q_wxyz_from_euler_deg(roll: ArrayLike, pitch: ArrayLike, yaw: ArrayLike) -> NDArray:
    """``[w, x, y, z]`` of ``Rz(yaw) Ry(pitch) Rx(roll)`` (angles in degrees, FRD to NED)."""
    h = np.radians(np.stack([roll, pitch, yaw], axis=-1).astype(np.float64)) / 2.0
    c, s = np.cos(h), np.sin(h)
    cr, cp, cy = c[..., 0], c[..., 1], c[..., 2]
    sr, sp, sy = s[..., 0], s[..., 1], s[..., 2]
    return np.stack(
        [
            cy * cp * cr + sy * sp * sr,
            cy * cp * sr - sy * sp * cr,
            cy * sp * cr + sy * cp * sr,
            sy * cp * cr - cy * sp * sr,
        ],
        axis=-1,
    )

"""The CDR messages the bag writer lays out, and their ``ros2msg`` definitions.

* IMU rates: ``sensor_msgs/msg/Imu``, ``angular_velocity`` = ``omega_b`` (rad/s, body axes);
  ``orientation = (0, 0, 0, 1)`` with ``orientation_covariance[0] = -1`` (no orientation);
  ``linear_acceleration_covariance[0] = -1`` unless an acceleration is given.
* Quaternions: ``geometry_msgs/msg/QuaternionStamped``, ``[x, y, z, w]`` as given (``q_w_b``).
* Vectors: ``geometry_msgs/msg/Vector3Stamped``.

The payloads have a fixed layout (a header and float64), so they are built in bulk with numpy,
one row of bytes per message. Live's recorder writes the same messages.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["MSG_DEFINITIONS", "cdr_messages", "imu_doubles"]

_SEP = "=" * 80 + "\n"
_HEADER_DEFS = (
    _SEP
    + "MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n"
    + _SEP
    + "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n"
)
_QUAT_DEF = _SEP + "MSG: geometry_msgs/Quaternion\nfloat64 x\nfloat64 y\nfloat64 z\nfloat64 w\n"
_VEC_DEF = _SEP + "MSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z\n"
#: ``ros2msg`` schema text of each message type (the concatenated form rosbag2 and rosbags write).
MSG_DEFINITIONS: dict[str, str] = {
    "sensor_msgs/msg/Imu": (
        "std_msgs/Header header\ngeometry_msgs/Quaternion orientation\n"
        "float64[9] orientation_covariance\ngeometry_msgs/Vector3 angular_velocity\n"
        "float64[9] angular_velocity_covariance\ngeometry_msgs/Vector3 linear_acceleration\n"
        "float64[9] linear_acceleration_covariance\n" + _HEADER_DEFS + _QUAT_DEF + _VEC_DEF
    ),
    "geometry_msgs/msg/QuaternionStamped": (
        "std_msgs/Header header\ngeometry_msgs/Quaternion quaternion\n" + _HEADER_DEFS + _QUAT_DEF
    ),
    "geometry_msgs/msg/Vector3Stamped": (
        "std_msgs/Header header\ngeometry_msgs/Vector3 vector\n" + _HEADER_DEFS + _VEC_DEF
    ),
}


def cdr_messages(
    t_ns: NDArray[np.int64], frame_id: str, doubles: NDArray[np.float64]
) -> NDArray[np.uint8]:
    """CDR (little-endian) payloads of ``Header`` + ``k`` float64, one row of bytes per message."""
    n, k = doubles.shape
    frame = frame_id.encode("utf-8") + b"\0"
    # Offsets are relative to the payload after the 4-byte encapsulation header (CDR alignment).
    body_off = 8 + 4 + len(frame)  # stamp (sec, nanosec), string length, string + NUL
    body_off += (-body_off) % 8  # float64 aligned to 8
    size = 4 + body_off + 8 * k
    buf = np.zeros((n, size), dtype=np.uint8)
    buf[:, 1] = 1  # encapsulation CDR_LE: 00 01 00 00
    sec = (t_ns // 1_000_000_000).astype("<i4")
    nsec = (t_ns % 1_000_000_000).astype("<u4")
    buf[:, 4:8] = sec.view(np.uint8).reshape(n, 4)
    buf[:, 8:12] = nsec.view(np.uint8).reshape(n, 4)
    buf[:, 12:16] = np.frombuffer(np.uint32(len(frame)).astype("<u4").tobytes(), np.uint8)
    buf[:, 16 : 16 + len(frame)] = np.frombuffer(frame, np.uint8)
    payload = np.ascontiguousarray(doubles, dtype="<f8").view(np.uint8)
    buf[:, 4 + body_off :] = payload.reshape(n, 8 * k)
    return buf


def imu_doubles(
    rates: NDArray[np.float64],
    accel: NDArray[np.float64] | None,
    gyro_cov: NDArray[np.float64] | None,
) -> NDArray[np.float64]:
    """The 37 float64 of ``sensor_msgs/Imu`` after its header, one row per sample."""
    n = rates.shape[0]
    d = np.zeros((n, 37))
    d[:, 3] = 1.0  # orientation (0, 0, 0, 1), flagged unknown below
    d[:, 4] = -1.0  # orientation_covariance[0] = -1: no orientation estimate
    d[:, 13:16] = rates
    if gyro_cov is not None:
        d[:, 16:25] = gyro_cov.reshape(1, 9)
    if accel is None:
        d[:, 28] = -1.0  # linear_acceleration_covariance[0] = -1: no acceleration
    else:
        d[:, 25:28] = accel
    return d

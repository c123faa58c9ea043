"""Which channels can be the IMU and the truth, and the decoder of their payloads into columns.

IMU: ``sensor_msgs/Imu`` (ROS 1 or ROS 2), a vendor type holding an ``Imu`` field, a JSON
channel with ``angular_velocity {x, y, z}``, or - when there is none of these - a
``geometry_msgs/Vector3Stamped`` topic whose name says gyro ("gyr", "angular_vel" or "imu"; any
other one when named with ``imu_topic``). Truth: a ``geometry_msgs`` quaternion, pose or transform
type or ``nav_msgs/Odometry``; else ``/tf`` / ``/tf_static``; else the Imu's own orientation.
:func:`plan` tells a container what to keep; :class:`ChannelDecoder` decodes each kept batch.
Picking among the kept channels is :mod:`imu_dcm.logio.ros.imu` and
:mod:`imu_dcm.logio.ros.truth`. Several channels of one topic are merged in file order
(:func:`merge`).
"""

from __future__ import annotations

import re
import struct
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from imu_dcm.errors import LogError
from imu_dcm.logio.ros.cdr import Scratch, decode
from imu_dcm.logio.ros.collect import Collected, Columns, Conn, Payloads
from imu_dcm.logio.ros.schema import Defs, definitions, norm_type
from imu_dcm.logio.ros.tf import TF_TYPE, child_frame, is_static_tf

__all__ = [
    "IMU_TYPE",
    "KNOWN_ENCODINGS",
    "NOT_GYRO",
    "TRUTH_MOTION",
    "TRUTH_TYPES",
    "VEC3_TYPE",
    "ChannelDecoder",
    "by_topic",
    "describe",
    "gyro_name",
    "imu_path",
    "is_truth",
    "merge",
    "plan",
]

IMU_TYPE = "sensor_msgs/msg/Imu"
VEC3_TYPE = "geometry_msgs/msg/Vector3Stamped"
#: Truth message types and the field path of the quaternion ``q_w_b`` inside each.
TRUTH_TYPES = {
    "geometry_msgs/msg/QuaternionStamped": "quaternion",
    "geometry_msgs/msg/PoseStamped": "pose.orientation",
    "geometry_msgs/msg/PoseWithCovarianceStamped": "pose.pose.orientation",
    "geometry_msgs/msg/TransformStamped": "transform.rotation",
    "nav_msgs/msg/Odometry": "pose.pose.orientation",
}
#: Where a truth type carries the body's position (m, parent frame) and, for odometry, its
#: angular rate (rad/s, the child's body frame, REP 105): rest evidence (``imu_dcm.gyro.rest``).
TRUTH_MOTION = {
    "geometry_msgs/msg/PoseStamped": ("pose.position", ""),
    "geometry_msgs/msg/PoseWithCovarianceStamped": ("pose.pose.position", ""),
    "geometry_msgs/msg/TransformStamped": ("transform.translation", ""),
    "nav_msgs/msg/Odometry": ("pose.pose.position", "twist.twist.angular"),
}
KNOWN_ENCODINGS = ("cdr", "ros1", "json")
NOT_GYRO = ("/estimate", "/ground_truth")  # Vector3Stamped topics that are not a gyro
#: A Vector3Stamped topic is taken as the gyro unasked only when its name says so.
_GYRO_NAME = re.compile(r"gyr|angular_vel|imu", re.IGNORECASE)


def gyro_name(topic: str) -> bool:
    return bool(_GYRO_NAME.search(topic)) and not topic.startswith(NOT_GYRO)


def imu_path(conn: Conn) -> str | None:
    """Field path of the Imu inside ``conn``'s type ("" for a bare Imu), "vec3", or None."""
    t = norm_type(conn.msgtype)
    if conn.encoding not in ("cdr", "ros1"):
        return None
    if t == IMU_TYPE:
        return ""
    if t == VEC3_TYPE:
        return "vec3"
    if "Imu" not in conn.schema_text:
        return None
    try:
        defs, root = definitions(conn)
    except LogError:
        return None
    return _find_imu(defs, root, 0)


def _find_imu(defs: Defs, root: str, depth: int) -> str | None:
    if root == IMU_TYPE:
        return ""
    if depth > 4 or root not in defs:
        return None
    for f in defs[root]:
        if f.array is None and f.base in defs:
            sub = _find_imu(defs, f.base, depth + 1)
            if sub is not None:
                return f.name if sub == "" else f"{f.name}.{sub}"
    return None


def is_truth(conn: Conn) -> bool:
    t = norm_type(conn.msgtype)
    return conn.encoding in ("cdr", "ros1") and (t in TRUTH_TYPES or t == TF_TYPE)


def _raw(p: Payloads) -> Payloads:
    return p


class ChannelDecoder:
    """Decodes batches of one channel's payloads into the columns its role needs.

    With ``lend``, a vector field (``omega``, ``q`` ...) may be a view of the decoder's words,
    valid until its next batch: for a caller that copies each batch at once (a
    :class:`~imu_dcm.logio.ros.collect.Sink` into its channel's arrays), which saves copying
    every vector twice. Without it, every field is an array of its own.
    """

    def __init__(self, conn: Conn, role: str, path: str = "", lend: bool = False):
        self.conn, self.role, self.path = conn, role, path
        self.lend = lend
        self.ready: tuple | None = None
        self.error: LogError | None = None
        self.scratch = Scratch()

    def _setup(self) -> tuple:
        defs, root = definitions(self.conn)
        if self.role == "truth":
            q = TRUTH_TYPES[root]
            want = {f"{q}.{a}": ("f8", 1) for a in "xyzw"}
            for path in TRUTH_MOTION.get(root, ()):
                want.update({f"{path}.{a}": ("f8", 1) for a in "xyz" if path})
            want.update({"header.stamp.sec": ("i8", 1), "header.stamp.nanosec": ("i8", 1)})
        elif self.path == "vec3":
            want = {"header.stamp.sec": ("i8", 1), "header.stamp.nanosec": ("i8", 1)}
            want.update({"vector." + a: ("f8", 1) for a in "xyz"})
        else:
            want = _imu_want(self.path, _field_names(defs, root, self.path))
        return defs, root, want

    def __call__(self, p: Payloads) -> Columns:
        if self.ready is None and self.error is None:
            try:
                self.ready = self._setup()
            except LogError as exc:
                self.error = exc
        if self.error is not None:
            z = np.zeros(0, np.int64)
            return Columns(z, z, {}, {}, self.error, len(p))
        defs, root, want = self.ready
        out, good = decode(self.conn, defs, root, p, want, self.scratch)
        frames = {"type": root}
        if good.any() and (self.role == "truth" or self.path in ("", "vec3")):
            # only a bare message has its header's frame_id at a fixed place
            frames["frame_id"] = _frame_id(self.conn, p, good)
            if root in ("nav_msgs/msg/Odometry", "geometry_msgs/msg/TransformStamped"):
                frames["child_frame_id"] = child_frame(self.conn, p, good)
        every = bool(good.all())

        def rows(a: NDArray) -> NDArray:
            return a if every else a[good]

        def vector(names: list[str]) -> NDArray:
            return _vector([out[k] for k in names], self.lend)

        if self.role == "truth":
            q = TRUTH_TYPES[root]
            fields = {
                "t_ns": rows(_stamp(out, "header.")),
                "q": rows(vector([f"{q}.{a}" for a in "xyzw"])),
            }
            for key, path in zip(("p", "w"), TRUTH_MOTION.get(root, ("", "")), strict=True):
                if path:
                    fields[key] = rows(vector([f"{path}.{a}" for a in "xyz"]))
        elif self.path == "vec3":
            fields = {
                "t_ns": rows(_stamp(out, "header.")),
                "omega": rows(vector(["vector." + a for a in "xyz"])),
            }
        else:
            pre = self.path + "." if self.path else ""
            fields = {
                "t_ns": rows(_stamp(out, pre + "header.")),
                "omega": rows(vector([pre + "angular_velocity." + a for a in "xyz"])),
            }
            # a batch whose messages all flag no acceleration holds none (its rows join as NaN)
            no_acc = out.get(pre + "linear_acceleration_covariance")
            if no_acc is not None and not (no_acc := no_acc == -1.0).all():
                accel = vector([pre + "linear_acceleration." + a for a in "xyz"])
                accel[no_acc] = np.nan
                fields["accel"] = rows(accel)
            if pre + "angular_velocity_covariance" in out:  # -1 marks no gyro: 1 byte a row
                fields["gyro_flagged"] = rows(out[pre + "angular_velocity_covariance"] == -1.0)
            flagged = out[pre + "orientation_covariance"] == -1.0
            if not flagged.all():
                quat = vector([pre + "orientation." + a for a in "xyzw"])
                quat[flagged] = np.nan
                fields["quat"] = rows(quat)
        return Columns(
            rows(p.order), rows(p.log_time), fields, frames, None, int(len(p) - good.sum())
        )


def plan(imu_topic: str | None, truth_topic: str | None) -> Callable[[Conn], object]:
    """What a container must do with each channel: skip it (None), keep it raw, or decode it.

    Only channels that can be the IMU or the truth are kept, and ``/tf_static`` (for the
    mounting); the IMU and truth types are decoded batch by batch, so their raw payloads never
    pile up.
    """

    def role(c: Conn):
        imu_ok = imu_topic is None or c.topic == imu_topic
        truth_ok = truth_topic is None or c.topic == truth_topic
        if truth_topic == "none":
            truth_ok = False
        if c.encoding == "json":
            return _raw if imu_ok else None
        if imu_ok:
            path = imu_path(c)
            if path is not None and (path != "vec3" or imu_topic is not None or gyro_name(c.topic)):
                return ChannelDecoder(c, "imu", path, lend=True)
        if truth_ok and is_truth(c):
            if norm_type(c.msgtype) == TF_TYPE:
                return _raw
            return ChannelDecoder(c, "truth", lend=True)
        if c.topic in (imu_topic, truth_topic):
            return _raw  # named but of an unexpected type: kept to say so
        if is_static_tf(c):
            return _raw  # the mounting between the IMU's frame and the truth's (few messages)
        return None

    return role


def describe(conns: list[Conn]) -> str:
    if not conns:
        return "no channels"
    return ", ".join(
        f"{c.topic} ({c.msgtype or 'no schema'}, {c.encoding}, {c.count})" for c in conns
    )


def by_topic(got: Collected) -> dict[str, list[Conn]]:
    out: dict[str, list[Conn]] = {}
    for c in got.conns:
        out.setdefault(c.topic, []).append(c)
    return out


def merge(rows: list[tuple[NDArray[np.int64], list[NDArray]]]) -> list[NDArray]:
    """Concatenate per-channel arrays of one topic and order them by file-order key."""
    if len(rows) == 1:
        return rows[0][1]
    order = np.concatenate([r[0] for r in rows])
    idx = np.argsort(order, kind="stable")
    out = []
    for k in range(len(rows[0][1])):
        parts = [r[1][k] for r in rows]
        out.append(None if any(x is None for x in parts) else np.concatenate(parts)[idx])
    return out


def _frame_id(c: Conn, p: Payloads, good: NDArray[np.bool_]) -> str:
    """frame_id of the first good message whose header comes first in the payload."""
    idx = np.flatnonzero(good)
    if not len(idx):
        return ""
    s = int(p.start[idx[0]])
    ros1 = c.encoding == "ros1"
    try:
        (n,) = struct.unpack_from("<I", p.buf, s + 12)
        raw = p.buf[s + 16 : s + 16 + n].tobytes()
    except struct.error:
        return ""
    raw = raw if ros1 else raw.rstrip(b"\x00")
    return raw.decode("utf-8", errors="replace")


def _vector(leaves: list[NDArray], lend: bool) -> NDArray:
    """The leaves (N,) side by side as one (N, k) array: with ``lend``, a view where they are
    adjacent columns of one array of words (the decoder's); else (or where they are not) a
    copy."""
    first = leaves[0]
    step = first.itemsize
    adjacent = lend and first.ndim == 1 and all(
        v.dtype == first.dtype and v.shape == first.shape and v.strides == first.strides
        and v.base is not None and v.base is first.base
        and v.__array_interface__["data"][0] == first.__array_interface__["data"][0] + k * step
        for k, v in enumerate(leaves)
    )  # fmt: skip
    if not adjacent:
        return np.stack(leaves, axis=1)
    return np.lib.stride_tricks.as_strided(
        first, (len(first), len(leaves)), (first.strides[0], step), writeable=True
    )


def _stamp(out: dict, prefix: str) -> NDArray[np.int64]:
    sec = out[prefix + "stamp.sec"].astype(np.int64, copy=False)  # decoded as int64 already
    t = sec * 1_000_000_000
    t += out[prefix + "stamp.nanosec"]
    return t


def _field_names(defs: Defs, root: str, path: str) -> set[str]:
    """Field names of the message type at ``path`` inside ``root`` (empty when unknown)."""
    t = root
    for part in path.split(".") if path else ():
        t = next((f.base for f in defs.get(t, ()) if f.name == part), "")
    return {f.name for f in defs.get(t, ())}


#: Imu fields decoded when the message's definition has them (vendor Imu types may not).
_OPTIONAL = ("angular_velocity_covariance", "linear_acceleration", "linear_acceleration_covariance")


def _imu_want(path: str, names: set[str]) -> dict[str, tuple[str, int]]:
    p = path + "." if path else ""
    want = {p + "header.stamp.sec": ("i8", 1), p + "header.stamp.nanosec": ("i8", 1)}
    want.update({p + "orientation." + a: ("f8", 1) for a in "xyzw"})
    want[p + "orientation_covariance"] = ("f8", 1)  # first element only
    want.update({p + "angular_velocity." + a: ("f8", 1) for a in "xyz"})
    if "angular_velocity_covariance" in names:
        want[p + "angular_velocity_covariance"] = ("f8", 1)  # first element: -1 marks no gyro
    if all(f in names for f in _OPTIONAL[1:]):
        want[p + "linear_acceleration_covariance"] = ("f8", 1)  # first element: -1 marks none
        want.update({p + "linear_acceleration." + a: ("f8", 1) for a in "xyz"})
    return want

"""Truth from ``/tf`` and ``/tf_static`` (``tf2_msgs/TFMessage``), and child frame ids.

Each TFMessage holds a sequence of TransformStamped, decoded here message by message (CDR with
alignment, or ROS 1 packed). The truth is the transform whose child frame moves: the one
``truth_frame`` names, else the only moving one, else the one whose child is the IMU's frame.
Its rotation maps the child (body) frame to the parent (world) frame: ``q_w_b``.

The transforms of ``/tf_static`` (a topic named ``tf_static``, in any namespace) are also kept
as :class:`~imu_dcm.logio.types.StaticTransform` (:func:`static_transforms`): the replay
composes the mounting between the IMU's frame and the truth's body frame from them. A constant
transform on ``/tf`` is not static: only ``/tf_static`` declares one.
"""

from __future__ import annotations

import struct

import numpy as np

from imu_dcm.errors import LogError
from imu_dcm.logio.ros.collect import Collected, Conn, Payloads
from imu_dcm.logio.ros.schema import norm_type
from imu_dcm.logio.types import StaticTransform, TruthSeries

__all__ = [
    "TF_TYPE",
    "child_frame",
    "is_static_tf",
    "moving_children",
    "static_transforms",
    "tf_rows",
    "tf_truth",
]


TF_TYPE = "tf2_msgs/msg/TFMessage"
#: tf2 refuses a quaternion whose squared norm is further than this from 1; so does the reader.
_NORM2_TOL = 0.01


def is_static_tf(conn: Conn) -> bool:
    """``conn`` is a ``tf_static`` topic (``/tf_static``, ``/robot/tf_static``) of TFMessages."""
    return (
        conn.encoding in ("cdr", "ros1")
        and norm_type(conn.msgtype) == TF_TYPE
        and conn.topic.rstrip("/").rsplit("/", 1)[-1] == "tf_static"
    )


def child_frame(c: Conn, p: Payloads, good) -> str:
    """child_frame_id right after the header (Odometry, TransformStamped)."""
    idx = np.flatnonzero(good)
    if not len(idx):
        return ""
    try:
        rows = tf_rows(
            p.buf[int(p.start[idx[0]]) : int(p.start[idx[0]] + p.length[idx[0]])].tobytes(),
            c.encoding == "ros1",
            single=True,
        )
        return rows[0][2] if rows else ""
    except (struct.error, ValueError):
        return ""


def tf_rows(raw: bytes, ros1: bool, single: bool = False) -> list[tuple]:
    """(stamp ns, parent, child, q xyzw) of each TransformStamped in a TFMessage payload."""
    base = 0 if ros1 else 4
    o = 0

    def al(n: int) -> None:
        nonlocal o
        if not ros1:
            o = (o + n - 1) & ~(n - 1)

    def u32() -> int:
        nonlocal o
        al(4)
        (v,) = struct.unpack_from("<I", raw, base + o)
        o += 4
        return v

    def string() -> str:
        nonlocal o
        n = u32()
        s = raw[base + o : base + o + n]
        if len(s) != n:
            raise ValueError("string past the end")
        o += n
        return (s if ros1 else s.rstrip(b"\x00")).decode("utf-8", errors="replace")

    count = 1 if single else u32()
    if count > len(raw) // 60 + 1:
        raise ValueError("transform count beyond the payload")
    out = []
    for _ in range(count):
        if ros1:
            u32()  # seq
        sec, nsec = u32(), u32()
        parent, child = string(), string()
        if single:
            return [(0, parent, child, None)]
        al(8)
        v = struct.unpack_from("<7d", raw, base + o)
        o += 56
        out.append((sec * 1_000_000_000 + nsec, parent, child, v[3:7]))
    return out


def _transforms(got: Collected, conns: list[Conn]):
    """Every transform in the messages of ``conns``: ``(payloads, index, stamp_ns, parent,
    child, q_xyzw)``; a message that does not decode is passed over."""
    for c in conns:
        p = got.payloads.get(c.id) or Payloads.empty()
        for i in range(len(p)):
            try:
                rows = tf_rows(p.payload(i), c.encoding == "ros1")
            except (struct.error, ValueError):
                continue
            for stamp, par, ch, quat in rows:
                yield p, i, stamp, par, ch, quat


def static_transforms(got: Collected) -> tuple[StaticTransform, ...]:
    """The transforms of the log's ``tf_static`` topics, one per child frame: the last one in
    file order (a later static transform replaces an earlier one, as in tf2), sorted by child.
    A rotation that is not finite or not of unit norm (tf2 refuses those) is left out."""
    rows = []
    for p, i, _stamp, par, ch, quat in _transforms(got, [c for c in got.conns if is_static_tf(c)]):
        q = np.asarray(quat, dtype=np.float64)
        n2 = float(q @ q)
        if np.isfinite(n2) and abs(n2 - 1.0) <= _NORM2_TOL:
            rows.append((int(p.order[i]), par, ch, tuple((q / np.sqrt(n2)).tolist())))
    last = {ch: StaticTransform(par, ch, q) for _o, par, ch, q in sorted(rows, key=lambda r: r[0])}
    return tuple(last[ch] for ch in sorted(last))


def moving_children(got: Collected, conns: list[Conn]) -> list[str]:
    """Child frames of the transforms in ``conns`` whose rotation changes, sorted."""
    rot: dict[str, list] = {}
    for *_, ch, quat in _transforms(got, conns):
        rot.setdefault(ch, []).append(quat)
    return sorted(
        ch for ch, qs in rot.items() if np.ptp(np.asarray(qs, dtype=float), axis=0).max() > 1e-12
    )


def tf_truth(
    got: Collected, conns: list[Conn], imu_frame: str, truth_frame: str | None, auto: bool
) -> TruthSeries | None:
    t, lt, order, parent, child, q = [], [], [], [], [], []
    for p, i, stamp, par, ch, quat in _transforms(got, conns):
        t.append(stamp)
        lt.append(int(p.log_time[i]))
        order.append(int(p.order[i]))
        parent.append(par)
        child.append(ch)
        q.append(quat)
    if not t:
        return None
    q_arr = np.asarray(q, dtype=np.float64)
    child_arr = np.asarray(child)
    children = sorted(set(child))
    moving = [ch for ch in children if np.ptp(q_arr[child_arr == ch], axis=0).max() > 1e-12]
    topics = "/".join(sorted({c.topic for c in conns}))
    if truth_frame is not None:
        if truth_frame not in children:
            raise LogError(
                f"Expected a transform to child frame {truth_frame!r} in {topics}, got "
                f"children {', '.join(children)}"
            )
        pick = truth_frame
    elif not moving:
        return None
    elif len(moving) == 1:
        pick = moving[0]
    elif imu_frame.strip("/") in [m.strip("/") for m in moving]:
        pick = next(m for m in moving if m.strip("/") == imu_frame.strip("/"))
    else:
        raise LogError(
            f"Expected one moving frame in {topics}, got {len(moving)}: "
            f"{', '.join(moving)} (choose with --truth-frame)"
        )
    m = child_arr == pick
    idx = np.flatnonzero(m)
    idx = idx[np.argsort(np.asarray(order)[idx], kind="stable")]
    par = parent[int(idx[0])]
    return TruthSeries(
        np.asarray(t, np.int64)[idx],
        np.asarray(lt, np.int64)[idx],
        q_arr[idx],
        topics,
        TF_TYPE,
        par,
        pick,
        auto,
    )

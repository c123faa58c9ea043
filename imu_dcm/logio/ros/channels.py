"""Which channels are the IMU and the truth, and their decoding into series.

IMU: ``sensor_msgs/Imu`` (ROS 1 or ROS 2), a vendor type holding an ``Imu`` field, a JSON
channel with ``angular_velocity {x, y, z}``, or - when there is none of these - a
``geometry_msgs/Vector3Stamped`` topic whose name says gyro ("gyr", "angular_vel" or "imu"; any
other one when named with ``imu_topic``). Truth: a ``geometry_msgs`` quaternion, pose or transform
type or ``nav_msgs/Odometry``; else the transform in ``/tf`` / ``/tf_static`` whose child frame
moves (``truth_frame`` chooses where several do); else the Imu's own orientation. Several channels
of one topic are merged in file order.
"""

from __future__ import annotations

import re
import struct
from collections.abc import Callable
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from imu_dcm.errors import LogError
from imu_dcm.logio.ros.cdr import decode
from imu_dcm.logio.ros.collect import Collected, Columns, Conn, Payloads
from imu_dcm.logio.ros.json_imu import is_json_imu, json_imu_columns, json_msg
from imu_dcm.logio.ros.schema import Defs, definitions, norm_type
from imu_dcm.logio.ros.tf import TF_TYPE, child_frame, is_static_tf, moving_children, tf_truth
from imu_dcm.logio.types import ImuSeries, TruthSeries
from imu_dcm.rest import GRAVITY_M_S2
from imu_dcm.so3 import median, percentile, row_finite, row_norm

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
#: angular rate (rad/s, the child's body frame, REP 105): rest evidence (``imu_dcm.rest``).
TRUTH_MOTION = {
    "geometry_msgs/msg/PoseStamped": ("pose.position", ""),
    "geometry_msgs/msg/PoseWithCovarianceStamped": ("pose.pose.position", ""),
    "geometry_msgs/msg/TransformStamped": ("transform.translation", ""),
    "nav_msgs/msg/Odometry": ("pose.pose.position", "twist.twist.angular"),
}
KNOWN_ENCODINGS = ("cdr", "ros1", "json")
_NOT_GYRO = ("/estimate", "/ground_truth")  # Vector3Stamped topics that are not a gyro
#: A Vector3Stamped topic is taken as the gyro unasked only when its name says so.
_GYRO_NAME = re.compile(r"gyr|angular_vel|imu", re.IGNORECASE)


def _gyro_name(topic: str) -> bool:
    return bool(_GYRO_NAME.search(topic)) and not topic.startswith(_NOT_GYRO)


_INT64 = 2**63


# ----------------------------------------------------------------------------- roles
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


class _Decoder:
    """Decodes batches of one channel's payloads into the columns its role needs."""

    def __init__(self, conn: Conn, role: str, path: str = ""):
        self.conn, self.role, self.path = conn, role, path
        self.ready: tuple | None = None
        self.error: LogError | None = None

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
        out, good = decode(self.conn, defs, root, p, want)
        frames = {"type": root}
        if good.any() and (self.role == "truth" or self.path in ("", "vec3")):
            # only a bare message has its header's frame_id at a fixed place
            frames["frame_id"] = _frame_id(self.conn, p, good)
            if root in ("nav_msgs/msg/Odometry", "geometry_msgs/msg/TransformStamped"):
                frames["child_frame_id"] = child_frame(self.conn, p, good)
        every = bool(good.all())

        def rows(a: NDArray) -> NDArray:
            return a if every else a[good]

        if self.role == "truth":
            q = TRUTH_TYPES[root]
            fields = {
                "t_ns": rows(_stamp(out, "header.")),
                "q": rows(np.stack([out[f"{q}.{a}"] for a in "xyzw"], axis=1)),
            }
            for key, path in zip(("p", "w"), TRUTH_MOTION.get(root, ("", "")), strict=True):
                if path:
                    fields[key] = rows(np.stack([out[f"{path}.{a}"] for a in "xyz"], axis=1))
        elif self.path == "vec3":
            fields = {
                "t_ns": rows(_stamp(out, "header.")),
                "omega": rows(np.stack([out["vector." + a] for a in "xyz"], axis=1)),
            }
        else:
            pre = self.path + "." if self.path else ""
            fields = {
                "t_ns": rows(_stamp(out, pre + "header.")),
                "omega": rows(
                    np.stack([out[pre + "angular_velocity." + a] for a in "xyz"], axis=1)
                ),
            }
            # a batch whose messages all flag no acceleration holds none (its rows join as NaN)
            no_acc = out.get(pre + "linear_acceleration_covariance")
            if no_acc is not None and not (no_acc := no_acc == -1.0).all():
                accel = np.stack([out[pre + "linear_acceleration." + a] for a in "xyz"], axis=1)
                accel[no_acc] = np.nan
                fields["accel"] = rows(accel)
            if pre + "angular_velocity_covariance" in out:  # -1 marks no gyro: 1 byte a row
                fields["gyro_flagged"] = rows(out[pre + "angular_velocity_covariance"] == -1.0)
            flagged = out[pre + "orientation_covariance"] == -1.0
            if not flagged.all():
                quat = np.stack([out[pre + "orientation." + a] for a in "xyzw"], axis=1)
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
            if path is not None and (
                path != "vec3" or imu_topic is not None or _gyro_name(c.topic)
            ):
                return _Decoder(c, "imu", path)
        if truth_ok and is_truth(c):
            if norm_type(c.msgtype) == TF_TYPE:
                return _raw
            return _Decoder(c, "truth")
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


def _by_topic(got: Collected) -> dict[str, list[Conn]]:
    out: dict[str, list[Conn]] = {}
    for c in got.conns:
        out.setdefault(c.topic, []).append(c)
    return out


# ------------------------------------------------------------------------------- IMU
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


def _stamp(out: dict, prefix: str) -> NDArray[np.int64]:
    sec = out[prefix + "stamp.sec"].astype(np.int64)
    nsec = out[prefix + "stamp.nanosec"].astype(np.int64)
    return sec * 1_000_000_000 + nsec


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


def _imu_columns(c: Conn, data):
    """(order, t_ns, log_t_ns, omega, quat, accel, gyro_flagged, dropped, type, frame) of a
    channel.

    ``quat`` and ``accel`` are None where the channel has none; ``gyro_flagged`` (bool) marks
    messages whose ``angular_velocity_covariance[0]`` is -1 (an absent gyro).
    """
    if c.encoding == "json":
        t_ns, omega, _, good, typ, frame = json_imu_columns(c, data)
        n = int(good.sum())
        return (
            data.order[good],
            t_ns[good],
            data.log_time[good],
            omega[good],
            None,
            None,
            np.full(n, np.nan),
            int(len(data) - n),
            typ,
            frame,
        )
    if data.error is not None:
        raise data.error
    f = data.fields
    n = len(data)
    return (
        data.order,
        f.get("t_ns", np.zeros(n, np.int64)),
        data.log_time,
        f.get("omega", np.zeros((n, 3))),
        f.get("quat"),
        f.get("accel"),
        f.get("gyro_flagged", np.zeros(n, bool)),
        data.dropped,
        data.frames.get("type", ""),
        data.frames.get("frame_id", ""),
    )


def _merge(rows: list[tuple[NDArray[np.int64], list[NDArray]]]) -> list[NDArray]:
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


#: Rows whose norms judge a gyro candidate (a long log is judged on every k-th row: the
#: quartiles of 131 072 norms are within ~0.5 % of the whole log's).
_DOUBT_ROWS = 1 << 17


def gyro_doubt(got: Collected, conns: list[tuple[Conn, str]]) -> str | None:
    """Why the decoded samples of a gyro candidate are no gyro's, or None when they may be.

    Refused: messages that all mark the angular velocity absent (Imu
    ``angular_velocity_covariance[0] = -1``), and rates whose norm stays at g (9.81, within 1)
    with a spread under 10 %: an accelerometer published as a Vector3Stamped.
    """
    omegas, covs = [], []
    for c, _path in conns:
        data = got.payloads.get(c.id)
        if not isinstance(data, Columns) or data.error is not None:
            continue
        omegas.append(data.fields.get("omega", np.zeros((0, 3))))
        covs.append(data.fields.get("gyro_flagged", np.zeros(len(data), bool)))
    flagged = np.concatenate(covs) if covs else np.zeros(0, bool)
    if len(flagged) and np.all(flagged == True):  # noqa: E712 (a NaN-filled join is not True)
        return "its messages mark the angular velocity absent (angular_velocity_covariance[0] = -1)"
    w = omegas[0] if len(omegas) == 1 else np.concatenate([np.zeros((0, 3)), *omegas])
    w = w[:: len(w) // _DOUBT_ROWS + 1]  # quartiles of norms: every k-th row tells them
    norm = row_norm(w)[row_finite(w)]
    if len(norm) < 10:
        return None
    med = median(norm)
    spread = percentile(norm, 75) - percentile(norm, 25)
    if abs(med - GRAVITY_M_S2) < 1.0 and spread < 0.1 * med:
        return (
            f"|omega| stays at {med:.2f} (interquartile {spread:.2f}), the 9.81 m/s² of gravity: "
            f"an accelerometer, not a gyro"
        )
    return None


def _alternatives(got: Collected, usable: list[str], refused: set[str]) -> str:
    """The channels that could be the gyro instead, for a refusal's line."""
    if usable:
        return f"; {', '.join(usable)} would work"
    vec = sorted(
        {c.topic for c in got.conns if norm_type(c.msgtype) == VEC3_TYPE and c.topic not in refused}
    )
    vec = [t for t in vec if not t.startswith(_NOT_GYRO)]
    if vec:
        return f"; try {', '.join(vec)} with --imu-topic"
    return "; no other channel of the log holds angular rates"


def pick_imu(got: Collected, imu_topic: str | None) -> tuple[str, list[tuple[Conn, str]]]:
    """The IMU topic and its channels with their Imu field paths (LogError when unclear)."""
    return pick_imu_judged(got, imu_topic)[:2]


def pick_imu_judged(
    got: Collected, imu_topic: str | None
) -> tuple[str, list[tuple[Conn, str]], tuple[str, ...]]:
    """:func:`pick_imu` with the gyro judgement: candidates that are no gyro are refused with
    one line each (returned as notes when another channel serves, a LogError otherwise)."""
    if imu_topic is not None:
        out = _named_imu(got, imu_topic)
        doubt = gyro_doubt(got, out)
        if doubt:
            raise LogError(
                f"Expected a gyro on {imu_topic}, got {doubt}" + _alternatives(got, [], {imu_topic})
            )
        return imu_topic, out, ()
    found, gyro = _imu_candidates(got)
    refused = {t: d for t, cs in {**gyro, **found}.items() if (d := gyro_doubt(got, cs))}
    found = {t: cs for t, cs in found.items() if t not in refused}
    gyro = {t: cs for t, cs in gyro.items() if t not in refused}
    found = found or gyro
    if not found and refused:
        topic, why = next(iter(sorted(refused.items())))
        raise LogError(
            f"Expected a gyro channel, got {topic}: {why}" + _alternatives(got, [], set(refused))
        )
    if not found:
        unknown = [c for c in got.conns if c.encoding not in KNOWN_ENCODINGS]
        if unknown:
            raise LogError(
                f"Expected message encoding cdr or json, got {unknown[0].encoding!r} "
                f"on {unknown[0].topic}"
            )
        raise LogError(
            f"Expected an IMU channel (sensor_msgs/msg/Imu or a type with an Imu "
            f"field; a geometry_msgs/msg/Vector3Stamped gyro named with --imu-topic), "
            f"got {describe(got.conns)}"
        )
    if len(found) > 1:
        raise LogError(
            f"Expected one IMU channel, got {len(found)}: {', '.join(sorted(found))} "
            f"(choose with --imu-topic)"
        )
    topic = next(iter(found))
    notes = tuple(
        f"{t}: refused as the gyro: {d}; using {topic}" for t, d in sorted(refused.items())
    )
    return topic, found[topic], notes


def _named_imu(got: Collected, imu_topic: str) -> list[tuple[Conn, str]]:
    conns = _by_topic(got).get(imu_topic)
    if not conns:
        raise LogError(f"Expected IMU topic {imu_topic!r} in the log, got {describe(got.conns)}")
    out = []
    for c in conns:
        if c.encoding not in KNOWN_ENCODINGS:
            raise LogError(
                f"Expected message encoding cdr, ros1 or json on {imu_topic}, got {c.encoding!r}"
            )
        path = "json" if c.encoding == "json" else imu_path(c)
        if path is None:
            raise LogError(
                f"Expected IMU messages on {imu_topic}, got "
                f"{c.msgtype or 'no schema'} ({c.encoding})"
            )
        out.append((c, path))
    return out


def _imu_candidates(got: Collected) -> tuple[dict, dict]:
    """IMU-typed channels and gyro-named Vector3Stamped channels, by topic."""
    found: dict[str, list[tuple[Conn, str]]] = {}
    gyro: dict[str, list[tuple[Conn, str]]] = {}
    for topic, conns in _by_topic(got).items():
        for c in conns:
            if c.encoding == "json":
                p = got.payloads.get(c.id)
                if p is not None and len(p) and is_json_imu(json_msg(p.payload(0))):
                    found.setdefault(topic, []).append((c, "json"))
                continue
            path = imu_path(c)
            if path == "vec3":
                if _gyro_name(topic):
                    gyro.setdefault(topic, []).append((c, path))
            elif path is not None:
                found.setdefault(topic, []).append((c, path))
    return found, gyro


def read_imu(got: Collected, topic: str, conns: list[tuple[Conn, str]]) -> tuple[ImuSeries, int]:
    """The IMU series of ``topic`` (its channels merged) and the count of undecodable ones."""
    rows, dropped, typ, frame = [], 0, "", ""
    for c, path in conns:
        data = got.payloads.get(c.id)
        if data is None:
            data = (
                Payloads.empty()
                if c.encoding == "json"
                else _Decoder(c, "imu", path)(Payloads.empty())
            )
        order, t_ns, log_t, omega, quat, accel, flag, drop, typ_c, frame_c = _imu_columns(c, data)
        dropped += drop
        typ, frame = typ or typ_c, frame or frame_c
        if quat is None and len(conns) > 1:
            quat = np.full((len(t_ns), 4), np.nan)
        if accel is None and len(conns) > 1:
            accel = np.full((len(t_ns), 3), np.nan)
        rows.append((order, [t_ns, log_t, omega, quat, accel, flag]))
    t_ns, log_t, omega, quat, accel, flag = _merge(rows)
    if quat is not None and not np.isfinite(quat).any():
        quat = None
    if accel is not None and not np.isfinite(accel).any():
        accel = None
    return ImuSeries(
        t_ns.astype(np.int64, copy=False),
        log_t.astype(np.int64, copy=False),
        omega,
        quat,
        topic,
        typ,
        frame,
        accel_b=accel,
        gyro_absent=bool(len(flag)) and bool(np.all(flag == True)),  # noqa: E712
    ), dropped


# ----------------------------------------------------------------------------- truth
def _read_truth_topic(got: Collected, topic: str, conns: list[Conn], auto: bool) -> TruthSeries:
    rows, typ, frame, child = [], "", "", ""
    for c in conns:
        data = got.payloads.get(c.id)
        if data is None:
            data = _Decoder(c, "truth")(Payloads.empty())
        if data.error is not None:
            raise data.error
        n = len(data)
        rows.append(
            (
                data.order,
                [
                    data.fields.get("t_ns", np.zeros(n, np.int64)),
                    data.log_time,
                    data.fields.get("q", np.zeros((n, 4))),
                    data.fields.get("p"),
                    data.fields.get("w"),
                ],
            )
        )
        typ = typ or data.frames.get("type") or norm_type(c.msgtype)
        frame = frame or data.frames.get("frame_id", "")
        child = child or data.frames.get("child_frame_id", "")
    t_ns, log_t, q, p_w, omega_b = _merge(rows)
    return TruthSeries(
        t_ns.astype(np.int64, copy=False),
        log_t.astype(np.int64, copy=False),
        q,
        topic,
        typ,
        frame,
        child,
        auto,
        p_w=p_w,
        omega_b=omega_b,
    )


def imu_truth(imu: ImuSeries, required: bool) -> TruthSeries | None:
    """The Imu's own orientation as truth where it is given (covariance[0] != -1, unit norm)."""
    q = imu.orientation_xyzw
    if q is None:
        if required:
            raise LogError(
                f"Expected an orientation on {imu.topic} (orientation_covariance[0] "
                f"!= -1), got none"
            )
        return None
    norm = np.linalg.norm(q, axis=1)
    ok = np.isfinite(norm) & (np.abs(norm - 1.0) < 1e-3)  # all-zero quaternions are not truth
    if not ok.any():
        if required:
            raise LogError(f"Expected unit orientation quaternions on {imu.topic}, got none")
        return None
    if not required and ok.sum() > 1 and np.all(q[ok] == q[ok][0]):
        # A constant quaternion (typically the default 0,0,0,1 behind a garbage covariance
        # instead of the -1 flag) is no estimate; it is used only when asked for by topic.
        return None
    return TruthSeries(
        imu.t_ns[ok],
        imu.log_t_ns[ok],
        q[ok] / norm[ok, None],
        imu.topic,
        imu.type,
        imu.frame_id,
        "",
        not required,
    )


def read_truth(
    got: Collected, imu: ImuSeries, truth_topic: str | None, truth_frame: str | None
) -> TruthSeries | None:
    """The truth series chosen by the policy in the module docstring (None when there is none)."""
    return read_truths(got, imu, truth_topic, truth_frame)[0]


#: Who estimated a truth of this type (its ``estimate_of``), when it is no independent reference.
_ESTIMATED_BY = {"nav_msgs/msg/Odometry": "odometry (an estimate, often wheels and the IMU)"}
IMU_ESTIMATE = "the IMU's own orientation"
#: A bag's ``custom_data`` key ``imu_dcm.estimate_of:<topic>`` says whose own estimate the truth
#: on ``<topic>`` is (convert-csv's ``--truth-estimate-of``); its value becomes ``estimate_of``.
ESTIMATE_OF_KEY = "imu_dcm.estimate_of:"


def declared_estimates(
    truths: tuple[TruthSeries | None, ...], custom_data: dict[str, str]
) -> tuple[TruthSeries | None, ...]:
    """``truths`` with ``estimate_of`` set where the bag's ``custom_data`` declares it for the
    truth's topic (:data:`ESTIMATE_OF_KEY`); a mark the reader already gave is kept."""
    return tuple(
        replace(t, estimate_of=custom_data[ESTIMATE_OF_KEY + t.topic])
        if t is not None and not t.estimate_of and custom_data.get(ESTIMATE_OF_KEY + t.topic)
        else t
        for t in truths
    )


def read_truths(
    got: Collected, imu: ImuSeries, truth_topic: str | None, truth_frame: str | None
) -> tuple[TruthSeries | None, tuple[TruthSeries, ...]]:
    """The truth and, when it was picked automatically, every other attitude candidate.

    Candidates, in the order of preference of the module docstring: the truth topics (not under
    ``/estimate``), each moving frame of ``/tf``, the Imu's own orientation. Odometry and the
    Imu's orientation carry ``estimate_of``. The replay judges which one follows the gyro.
    """
    if truth_topic == "none":
        return None, ()
    topics = _by_topic(got)
    if truth_topic is not None:
        return _named_truth(got, imu, topics, truth_topic, truth_frame), ()
    tf = [c for c in got.conns if c.encoding in ("cdr", "ros1") and norm_type(c.msgtype) == TF_TYPE]
    if truth_frame is not None:  # a frame names a transform
        if not tf:
            raise LogError(
                f"Expected /tf or /tf_static for truth frame {truth_frame!r}, got "
                f"{describe(got.conns)}"
            )
        return tf_truth(got, tf, imu.frame_id, truth_frame, auto=False), ()
    found = [
        _marked(_read_truth_topic(got, t, cs, auto=True))
        for t, cs in sorted(topics.items())
        if not t.startswith("/estimate")
        and all(is_truth(c) and norm_type(c.msgtype) != TF_TYPE for c in cs)
    ]
    if tf:
        found += [tf_truth(got, tf, imu.frame_id, ch, auto=True) for ch in moving_children(got, tf)]
    own = imu_truth(imu, required=False)
    if own is not None:
        found.append(replace(own, estimate_of=IMU_ESTIMATE))
    if not found:
        return None, ()
    return found[0], tuple(found[1:])


def _marked(t: TruthSeries) -> TruthSeries:
    who = _ESTIMATED_BY.get(t.type, "")
    return replace(t, estimate_of=who) if who else t


def _named_truth(got, imu, topics, truth_topic: str, truth_frame: str | None):
    """The truth the caller named by topic (its type checked)."""
    if truth_topic == imu.topic:
        return replace(imu_truth(imu, required=True), estimate_of=IMU_ESTIMATE)
    conns = topics.get(truth_topic)
    if not conns:
        raise LogError(
            f"Expected truth topic {truth_topic!r} in the log, got {describe(got.conns)}"
        )
    for c in conns:
        if not is_truth(c):
            raise LogError(
                f"Expected truth messages on {truth_topic}, got "
                f"{c.msgtype or 'no schema'} ({c.encoding})"
            )
    if all(norm_type(c.msgtype) == TF_TYPE for c in conns):
        tf = tf_truth(got, conns, imu.frame_id, truth_frame, auto=False)
        if tf is None:
            raise LogError(f"Expected a moving transform in {truth_topic}, got none")
        return tf
    return _marked(_read_truth_topic(got, truth_topic, conns, auto=False))

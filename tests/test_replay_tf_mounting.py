"""The mounting a log declares in ``/tf_static``: read, composed along the static tree, applied,
and compared with the motion's estimate.

Each log is built from a slice of the shipped BROAD trial: its gyro (and accelerometer) turned
by a known mounting ``R_body_imu`` (``omega_imu = R_body_imuᵀ omega_body``) and written by the
project's writer with IMU ``frame_id`` ``imu_link``; the truth becomes a ``/tf`` transform
``world -> base_link`` or a PoseStamped in ``world``, and ``/tf_static`` carries the mounting,
both serialised by rosbags (an independent writer). scipy's ``Rotation`` is the oracle.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO_ROOT
from mcap.reader import make_reader
from mcap.writer import Writer as McapWriter
from scipy.spatial.transform import Rotation

from imu_dcm.logio import ImuSeries, LogData, StaticTransform, TruthSeries, read_log
from imu_dcm.logio.writers import StampedSeries, write_bag
from imu_dcm.replay import replay
from imu_dcm.replay.mounting_tf import static_rotation

TRIAL = REPO_ROOT / "replay" / "broad_07_undisturbed_fast_rotation_B"
#: 20 s .. 70 s of the trial: 6.5 s of rest (the bias), then 43.5 s of fast turning.
SLICE_S = (20.0, 70.0)
RZ90 = Rotation.from_quat([0.0, 0.0, np.sqrt(0.5), np.sqrt(0.5)])  # 90° about z
EPS = np.finfo(float).eps


@pytest.fixture(scope="module")
def trial():
    """The slice of the shipped trial (gyro, accelerometer, truth), as read."""
    log = read_log(TRIAL)
    t0 = log.imu.t_ns.min()
    lo, hi = (t0 + np.int64(s * 1e9) for s in SLICE_S)
    k = (log.imu.t_ns >= lo) & (log.imu.t_ns < hi)
    j = (log.truth.t_ns >= lo) & (log.truth.t_ns < hi)
    return {
        "t_ns": log.imu.t_ns[k],
        "omega": log.imu.omega_b[k],
        "accel": log.imu.accel_b[k],
        "truth_t_ns": log.truth.t_ns[j],
        "q_w_b": log.truth.q_w_b[j],
    }


def _typestore():
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE)


def _tf_message(store, t_ns: int, links) -> bytes:
    """A CDR TFMessage of ``(parent, child, q_xyzw)`` transforms, zero translation."""
    ty = store.types
    sec, nsec = divmod(int(t_ns), 1_000_000_000)
    out = []
    for parent, child, q in links:
        hdr = ty["std_msgs/msg/Header"](ty["builtin_interfaces/msg/Time"](sec, nsec), parent)
        rot = ty["geometry_msgs/msg/Quaternion"](*(float(x) for x in q))
        tr = ty["geometry_msgs/msg/Transform"](ty["geometry_msgs/msg/Vector3"](0.0, 0.0, 0.0), rot)
        out.append(ty["geometry_msgs/msg/TransformStamped"](hdr, child, tr))
    msg = ty["tf2_msgs/msg/TFMessage"](out)
    return bytes(store.serialize_cdr(msg, "tf2_msgs/msg/TFMessage"))


def _pose_message(store, t_ns: int, q) -> bytes:
    ty = store.types
    sec, nsec = divmod(int(t_ns), 1_000_000_000)
    hdr = ty["std_msgs/msg/Header"](ty["builtin_interfaces/msg/Time"](sec, nsec), "world")
    pose = ty["geometry_msgs/msg/Pose"](
        ty["geometry_msgs/msg/Point"](0.0, 0.0, 0.0),
        ty["geometry_msgs/msg/Quaternion"](*(float(x) for x in q)),
    )
    msg = ty["geometry_msgs/msg/PoseStamped"](hdr, pose)
    return bytes(store.serialize_cdr(msg, "geometry_msgs/msg/PoseStamped"))


def _imu_messages(trial, tmp: Path, r_body_imu: Rotation, frame: str) -> list[tuple]:
    """The turned IMU written by the project's writer, as (topic, type, text, t_ns, payload)."""
    bag = write_bag(
        tmp / "imu_bag",
        imu=StampedSeries(trial["t_ns"], r_body_imu.inv().apply(trial["omega"]), frame),
        imu_linear_acceleration=r_body_imu.inv().apply(trial["accel"]),
    )
    out = []
    with open(next(bag.glob("*.mcap")), "rb") as f:
        for schema, channel, m in make_reader(f).iter_messages():
            out.append((channel.topic, schema.name, schema.data, m.log_time, m.data))
    return out


def build_log(
    trial,
    tmp: Path,
    r_body_imu: Rotation,
    static,
    truth: str = "tf",
    frame: str = "imu_link",
    constant=(),
) -> Path:
    """A single-file MCAP: the turned IMU, the truth (``"tf"``: ``/tf`` world -> base_link;
    ``"pose"``: ``/pose`` PoseStamped in world), and ``static`` = [(parent, child, q)] on
    ``/tf_static`` (none when empty); ``frame`` is the IMU's frame_id; ``constant`` links are
    sent with every ``/tf`` message."""
    store = _typestore()
    msgs = _imu_messages(trial, tmp, r_body_imu, frame)
    typ = "tf2_msgs/msg/TFMessage" if truth == "tf" else "geometry_msgs/msg/PoseStamped"
    topic = "/tf" if truth == "tf" else "/pose"
    text = store.generate_msgdef(typ, ros_version=2)[0].encode()
    for t, q in zip(trial["truth_t_ns"].tolist(), trial["q_w_b"], strict=True):
        raw = (
            _tf_message(store, t, [("world", "base_link", q), *constant])
            if truth == "tf"
            else _pose_message(store, t, q)
        )
        msgs.append((topic, typ, text, t, raw))
    if static:
        tf_text = store.generate_msgdef("tf2_msgs/msg/TFMessage", ros_version=2)[0].encode()
        t0 = int(trial["t_ns"][0])
        raw = _tf_message(store, t0, static)
        msgs.append(("/tf_static", "tf2_msgs/msg/TFMessage", tf_text, t0, raw))
    msgs.sort(key=lambda m: m[3])
    path = tmp / f"{truth}_{len(static)}.mcap"
    with open(path, "wb") as f:
        w = McapWriter(f)
        w.start("ros2", "test")
        schemas, channels = {}, {}
        for topic_, sname, sdata, t, data in msgs:
            if sname not in schemas:
                schemas[sname] = w.register_schema(sname, "ros2msg", sdata)
            if topic_ not in channels:
                channels[topic_] = w.register_channel(topic_, "cdr", schemas[sname])
            w.add_message(channels[topic_], log_time=t, data=data, publish_time=t)
        w.finish()
    return path


def _replay(path, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return replay(path, **kw)


def _line(res) -> str:
    return next(w for w in res.summary.warnings if w.startswith("mounting ("))


def _rounding_bound_deg(trial) -> float:
    """How far rounding alone may move the RMS between two replays of the same rates, one of
    them turned by a mounting and turned back (degrees).

    The rates differ by a few ulps of |ω| (two rotations applied, a composed quaternion), so
    the attitudes drift apart by at most ``∫ |δω| dt`` ≤ 32 eps ∫ |ω| dt; the integrator's own
    rounding differs between the two runs by at most a few eps per step (32 eps N). The RMS of
    the per-sample errors moves by at most the largest per-sample change.
    """
    dt = np.diff(trial["t_ns"]) * 1e-9
    path_rad = float(np.sum(np.linalg.norm(trial["omega"][1:], axis=1) * dt))
    return float(np.degrees(32 * EPS * (path_rad + len(dt))))


@pytest.fixture(scope="module")
def tmp(tmp_path_factory):
    return tmp_path_factory.mktemp("tf_mounting")


@pytest.fixture(scope="module")
def clean(trial, tmp):
    """The unturned slice, the IMU in the truth's body frame (no mounting to find)."""
    path = build_log(trial, _mkdir(tmp / "clean"), Rotation.identity(), [], frame="base_link")
    return _replay(path)


def _mkdir(p: Path) -> Path:
    p.mkdir(parents=True, exist_ok=True)
    return p


# ---------------------------------------------------------------------------- the tree
def test_static_rotation_composes_along_the_tree_like_scipy():
    # base_link -> mount -> imu_link, and a sibling base_link -> camera; edges in both senses
    q1, q2, q3 = Rotation.random(3, random_state=np.random.default_rng(4))
    static = (
        StaticTransform("/base_link", "mount", tuple(q1.as_quat())),
        StaticTransform("mount", "/imu_link", tuple(q2.as_quat())),
        StaticTransform("base_link", "camera", tuple(q3.as_quat())),
    )
    tol = 8 * EPS
    r, chain = static_rotation(static, "base_link", "/imu_link")
    assert chain == ("base_link", "mount", "imu_link")
    assert (r * (q1 * q2).inv()).magnitude() < tol
    r, chain = static_rotation(static, "imu_link", "base_link")  # walked up: the inverse
    assert chain == ("imu_link", "mount", "base_link")
    assert (r * (q1 * q2)).magnitude() < tol
    r, chain = static_rotation(static, "camera", "imu_link")  # through the common ancestor
    assert chain == ("camera", "base_link", "mount", "imu_link")
    assert (r * (q3.inv() * q1 * q2).inv()).magnitude() < tol
    # 90° about z: a vector on the child's x axis is the parent's y axis
    one = (StaticTransform("base_link", "imu_link", tuple(RZ90.as_quat())),)
    r, _ = static_rotation(one, "base_link", "imu_link")
    np.testing.assert_allclose(r.apply([1.0, 0.0, 0.0]), [0.0, 1.0, 0.0], atol=4 * EPS)
    assert static_rotation(static, "base_link", "elsewhere") is None


def test_the_reader_keeps_only_tf_static_the_last_per_child(trial, tmp):
    d = _mkdir(tmp / "reader")
    wrong, right = Rotation.from_rotvec([0.3, 0, 0]), RZ90
    path = build_log(
        trial,
        d,
        RZ90,
        [("base_link", "imu_link", wrong.as_quat()), ("base_link", "imu_link", right.as_quat())],
    )
    log = read_log(path)
    assert len(log.static_transforms) == 1
    s = log.static_transforms[0]
    assert (s.parent, s.child) == ("base_link", "imu_link")
    assert (Rotation.from_quat(s.q_xyzw) * right.inv()).magnitude() < 4 * EPS
    # a constant transform on /tf is not static: only /tf_static declares one
    plain = build_log(
        trial,
        _mkdir(tmp / "reader_none"),
        RZ90,
        [],
        constant=[("base_link", "imu_link", right.as_quat())],
    )
    got = read_log(plain)
    assert got.static_transforms == () and got.truth.child_frame_id == "base_link"
    res = _replay(got)
    assert res.summary.mounting_tf is None and res.summary.mounting_used == "estimated"


# ---------------------------------------------------------------------------- the replay
def test_tf_static_mounting_is_applied_and_agrees_with_the_estimate(trial, tmp, clean):
    path = build_log(trial, _mkdir(tmp / "one"), RZ90, [("base_link", "imu_link", RZ90.as_quat())])
    res = _replay(path)
    s = res.summary
    tf = s.mounting_tf
    assert (tf["imu_frame"], tf["body_frame"], tf["body_frame_from"]) == (
        "imu_link",
        "base_link",
        "child_frame_id",
    )
    assert tf["chain"] == ["base_link", "imu_link"]
    assert (Rotation.from_quat(tf["q_t_g"]) * RZ90.inv()).magnitude() < 4 * EPS
    assert abs(tf["angle_deg"] - 90.0) < 1e-12
    assert s.mounting_used == "tf" and s.mounting_applied and tf["applied"]
    # the estimate is recovered within 1° (see test_replay_judgement); so they agree
    est = Rotation.from_quat(s.mounting["q_t_g"])
    assert (
        tf["agrees"]
        and abs(tf["angle_to_estimate_deg"] - np.degrees((est * RZ90.inv()).magnitude())) < 1e-9
    )
    assert tf["angle_to_estimate_deg"] < 1.0 and tf["compared_on"] == "rotation"
    line = _line(res)
    assert line.startswith("mounting (imu_link -> base_link): /tf_static (base_link -> imu_link)")
    assert "they agree" in line and "applied the /tf_static one" in line
    assert abs(s.rms_error_deg - clean.summary.rms_error_deg) <= _rounding_bound_deg(trial)


def test_a_two_link_chain_and_a_pose_truth_give_the_same_mounting(trial, tmp, clean):
    # base_link -> mount -> imu_link, a generic first link: the composed rotation is 90° about z
    q1 = Rotation.from_rotvec([0.4, -0.7, 1.1])
    q2 = q1.inv() * RZ90
    links = [("base_link", "mount", q1.as_quat()), ("mount", "imu_link", q2.as_quat())]
    res = _replay(build_log(trial, _mkdir(tmp / "chain"), RZ90, links))
    tf = res.summary.mounting_tf
    assert tf["chain"] == ["base_link", "mount", "imu_link"]
    assert (Rotation.from_quat(tf["q_t_g"]) * RZ90.inv()).magnitude() < 16 * EPS
    assert res.summary.mounting_used == "tf" and tf["agrees"]
    assert abs(res.summary.rms_error_deg - clean.summary.rms_error_deg) <= _rounding_bound_deg(
        trial
    )
    # a PoseStamped truth names no body frame: the root of the static tree above imu_link
    path = build_log(trial, _mkdir(tmp / "pose"), RZ90, links, truth="pose")
    pose = _replay(path)
    tf = pose.summary.mounting_tf
    assert (tf["body_frame"], tf["body_frame_from"]) == ("base_link", "static root")
    assert pose.summary.mounting_used == "tf" and "they agree" in _line(pose)
    assert abs(pose.summary.rms_error_deg - res.summary.rms_error_deg) <= _rounding_bound_deg(trial)
    # /tf_static is read when the truth is named too
    named = _replay(path, truth_topic="/pose")
    assert named.summary.mounting_tf["chain"] == ["base_link", "mount", "imu_link"]


def test_a_generic_mounting_scores_as_the_unturned_gyro(trial, tmp):
    # Not an axis permutation: per-axis rest statistics change under it, so both replays run
    # without bias removal, and only rounding separates them.
    r = Rotation.from_rotvec([0.9, -0.4, 0.6])
    base = _replay(
        build_log(trial, _mkdir(tmp / "g0"), Rotation.identity(), [], frame="base_link"),
        bias="none",
    )
    res = _replay(
        build_log(trial, _mkdir(tmp / "g1"), r, [("base_link", "imu_link", r.as_quat())]),
        bias="none",
    )
    tf = res.summary.mounting_tf
    assert (Rotation.from_quat(tf["q_t_g"]) * r.inv()).magnitude() < 4 * EPS
    assert res.summary.mounting_used == "tf" and tf["agrees"]
    assert abs(res.summary.rms_error_deg - base.summary.rms_error_deg) <= _rounding_bound_deg(trial)


def test_a_wrong_tf_static_is_reported_as_disagreeing_and_the_estimate_is_used(trial, tmp, clean):
    wrong = RZ90 * RZ90  # declared 180° about z where the IMU is at 90°
    path = build_log(
        trial, _mkdir(tmp / "wrong"), RZ90, [("base_link", "imu_link", wrong.as_quat())]
    )
    res = _replay(path)
    s = res.summary
    tf = s.mounting_tf
    assert tf["agrees"] is False and not tf["applied"] and s.mounting_used == "estimated"
    e = np.degrees((Rotation.from_quat(s.mounting["q_t_g"]) * RZ90.inv()).magnitude())
    assert e < 1.0  # the estimate is the true mounting ...
    assert abs(tf["angle_to_estimate_deg"] - 90.0) <= e + 1e-9  # ... 90° from the declared one
    line = _line(res)
    assert "they DISAGREE by 9" in line and "applied the motion's estimate" in line
    # scored with the estimate: a frame error e moves each attitude error by at most 2e
    assert abs(s.rms_error_deg - clean.summary.rms_error_deg) <= 2 * e + 1e-9
    # none: neither applied, both reported
    off = _replay(path, mounting="none")
    assert off.summary.mounting_used == "" and not off.summary.mounting_applied
    assert "neither applied" in _line(off) and off.summary.mounting_tf["agrees"] is False
    assert off.summary.rms_error_deg > 10 * clean.summary.rms_error_deg
    # a given quaternion is applied and compared with both
    given = _replay(path, mounting=RZ90.as_quat())
    assert given.summary.mounting_used == "given"
    assert "/tf_static (base_link -> imu_link) gives 180.0°" in _line(given)
    assert "90.0° from the given one" in _line(given)


def test_one_determined_axis_is_compared_where_it_goes():
    # A robot that only yaws, its IMU with y along the robot's vertical and turned 30° about it
    # (/tf_static says so): the motion fixes only where gyro y goes (to truth z), so the
    # comparison is on that axis and agrees, although the smallest rotation the estimate
    # reports is 30° from the declared one. The declared one is exact: far below 0.01°.
    rate, n = 200.0, 6000
    t = np.arange(n) / rate
    t_ns = (t * 1e9).astype(np.int64)
    psi = 2.0 * np.sin(0.5 * t)
    omega_t = np.stack([np.zeros(n), np.zeros(n), np.cos(0.5 * t)], axis=1)
    q = Rotation.from_rotvec(np.outer(psi, [0, 0, 1])).as_quat()
    q_t_g = Rotation.from_rotvec([np.pi / 2, 0, 0]) * Rotation.from_rotvec([0, np.radians(30), 0])
    imu = ImuSeries(t_ns, t_ns, q_t_g.inv().apply(omega_t), None, "/imu", "Imu", "imu_link")
    truth = TruthSeries(t_ns, t_ns, q, "/odom", "nav_msgs/msg/Odometry", "odom", "base_link", True)
    static = (StaticTransform("base_link", "imu_link", tuple(q_t_g.as_quat())),)
    log = LogData(TRIAL, imu, truth, (), static_transforms=static)
    res = _replay(log, bias="none")
    s = res.summary
    assert s.mounting["axes_determined"] == 1
    full = np.degrees((Rotation.from_quat(s.mounting["q_t_g"]) * q_t_g.inv()).magnitude())
    assert full > 25.0  # the whole rotations differ by the unseen turn about the axis
    tf = s.mounting_tf
    assert tf["compared_on"] == "axis" and tf["angle_to_estimate_deg"] < 0.1 and tf["agrees"]
    assert s.mounting_used == "tf" and s.rms_error_deg < 0.01
    assert "on the axis the motion determines" in _line(res)


def test_summary_text_names_the_declared_mounting(trial, tmp):
    from imu_dcm.replay.summary import format_summary

    path = build_log(trial, _mkdir(tmp / "text"), RZ90, [("base_link", "imu_link", RZ90.as_quat())])
    text = format_summary(_replay(path).summary)
    line = next(x for x in text.splitlines() if x.startswith("mounting   /tf_static"))
    assert "base_link -> imu_link: 90.0°" in line and "(agree): applied" in line

"""Tests of the log reader (imu_dcm.logio): MCAP walking, bulk CDR decoding, channel policy.

Oracles: the values written into small bags made here with ``mcap_ros2.writer`` (an independent
CDR serialiser), and the ``mcap`` + ``mcap_ros2`` per-message decoder on the shipped BROAD trial.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import raises_naming
from mcap.reader import make_reader
from mcap.writer import Writer as McapWriter
from mcap_ros2.decoder import DecoderFactory
from mcap_ros2.writer import Writer as Ros2Writer

from imu_dcm.errors import ImuDcmWarning, LogError
from imu_dcm.logio import read_log, resolve_mcap_path

SHIPPED = Path(__file__).resolve().parents[1] / "replay" / "broad_07_undisturbed_fast_rotation_B"

HEADER = """
================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
"""
QUAT = """
================================================================================
MSG: geometry_msgs/Quaternion
float64 x
float64 y
float64 z
float64 w
"""
VEC3 = """
================================================================================
MSG: geometry_msgs/Vector3
float64 x
float64 y
float64 z
"""
POINT = """
================================================================================
MSG: geometry_msgs/Point
float64 x
float64 y
float64 z
"""
POSE = """
================================================================================
MSG: geometry_msgs/Pose
Point position
Quaternion orientation
"""
IMU_FIELDS = """std_msgs/Header header
geometry_msgs/Quaternion orientation
float64[9] orientation_covariance # -1 in [0]: no orientation
geometry_msgs/Vector3 angular_velocity
float64[9] angular_velocity_covariance
geometry_msgs/Vector3 linear_acceleration
float64[9] linear_acceleration_covariance
"""
IMU_DEF = IMU_FIELDS + HEADER + QUAT + VEC3
IMU_SECTION = "\n" + "=" * 80 + "\nMSG: sensor_msgs/Imu\n" + IMU_FIELDS
# A vendor wrapper: a header, a string and a byte before the Imu field shift its offset.
WRAPPER_DEF = (
    "std_msgs/Header header\nstring device_name\nuint8 status\nuint8 STATUS_OK=0\n"
    "sensor_msgs/Imu imu\nfloat32 temperature\n" + IMU_SECTION + HEADER + QUAT + VEC3
)
QSTAMPED_DEF = "std_msgs/Header header\ngeometry_msgs/Quaternion quaternion\n" + HEADER + QUAT
POSE_STAMPED_DEF = (
    "std_msgs/Header header\ngeometry_msgs/Pose pose\n" + HEADER + POSE + POINT + QUAT
)
TRANSFORM_DEF = (
    "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/Transform transform\n"
    + HEADER
    + "\n"
    + "=" * 80
    + "\nMSG: geometry_msgs/Transform\nVector3 translation\n"
    "Quaternion rotation\n" + VEC3 + QUAT
)
ODOM_DEF = (
    "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/PoseWithCovariance pose\n"
    "geometry_msgs/TwistWithCovariance twist\n"
    + HEADER
    + "\n"
    + "=" * 80
    + "\nMSG: geometry_msgs/PoseWithCovariance\nPose pose\n"
    "float64[36] covariance\n"
    + POSE
    + POINT
    + QUAT
    + "\n"
    + "=" * 80
    + "\nMSG: geometry_msgs/TwistWithCovariance\nTwist twist\n"
    "float64[36] covariance\n"
    + "\n"
    + "=" * 80
    + "\nMSG: geometry_msgs/Twist\nVector3 linear\nVector3 angular\n"
    + VEC3
)
MAG_DEF = (
    "std_msgs/Header header\ngeometry_msgs/Vector3 magnetic_field\nfloat64[9] "
    "magnetic_field_covariance\n" + HEADER + VEC3
)

T0_NS = 1_700_000_000_000_000_000


def _stamp(t_ns: int) -> dict:
    return {"sec": int(t_ns // 1_000_000_000), "nanosec": int(t_ns % 1_000_000_000)}


def _imu_msg(t_ns: int, w, frame: str = "imu", q=(0.0, 0.0, 0.0, 1.0), cov0: float = -1.0):
    return {
        "header": {"stamp": _stamp(t_ns), "frame_id": frame},
        "orientation": dict(zip("xyzw", map(float, q), strict=False)),
        "orientation_covariance": [cov0] + [0.0] * 8,
        "angular_velocity": dict(zip("xyz", map(float, w), strict=False)),
        "angular_velocity_covariance": [0.0] * 9,
        "linear_acceleration": {"x": 0.0, "y": 0.0, "z": 9.81},
        "linear_acceleration_covariance": [0.0] * 9,
    }


def _samples(n: int = 50, seed: int = 0):
    rng = np.random.default_rng(seed)
    t_ns = T0_NS + np.arange(n, dtype=np.int64) * 5_000_000
    return t_ns, rng.normal(0.0, 1.0, (n, 3))


def write_imu_bag(
    path: Path, t_ns, omega, frames=None, extra=None, quats=None, cov0=-1.0, log_offset_ns: int = 0
):
    """An MCAP with /imu/data (Imu); ``frames`` varies frame_id length per message."""
    with open(path, "wb") as f:
        w = Ros2Writer(f)
        schema = w.register_msgdef("sensor_msgs/msg/Imu", IMU_DEF)
        for i, t in enumerate(t_ns):
            frame = frames[i % len(frames)] if frames else "imu"
            q = quats[i] if quats is not None else (0.0, 0.0, 0.0, 1.0)
            w.write_message(
                "/imu/data",
                schema,
                _imu_msg(int(t), omega[i], frame, q, cov0),
                log_time=int(t) + log_offset_ns,
                publish_time=int(t),
            )
        if extra:
            extra(w)
        w.finish()
    return path


def test_variable_frame_id_lengths_decode_exactly(tmp_path):
    # frame_id lengths 0..9 move the 8-byte aligned doubles by different paddings per message;
    # the bulk decoder must reproduce the written float64 values bit for bit.
    t_ns, omega = _samples(60)
    frames = ["", "a", "ab", "abc", "/imu", "imu_l", "imu_li", "/imu_lin", "imu_link0", "x" * 9]
    p = write_imu_bag(tmp_path / "f.mcap", t_ns, omega, frames, log_offset_ns=-12_345)
    log = read_log(p)
    np.testing.assert_array_equal(log.imu.omega_b, omega)
    np.testing.assert_array_equal(log.imu.t_ns, t_ns)
    np.testing.assert_array_equal(log.imu.log_t_ns, t_ns - 12_345)
    assert log.imu.topic == "/imu/data" and log.imu.type == "sensor_msgs/msg/Imu"
    assert log.truth is None  # covariance[0] == -1 everywhere: no orientation given


def test_bulk_decode_matches_mcap_ros2_on_shipped_broad_trial():
    # Oracle: the reference per-message decoder over the first 20 s of the shipped recording.
    end = T0_NS + 20_000_000_000
    ref_t, ref_w = [], []
    with open(resolve_mcap_path(SHIPPED), "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, _, _, m in reader.iter_decoded_messages(topics=["/imu/data"], ending_before=end):
            ref_t.append(m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec)
            ref_w.append([m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z])
    log = read_log(SHIPPED)
    k = len(ref_t)
    assert k > 5000
    np.testing.assert_array_equal(log.imu.t_ns[:k], np.array(ref_t, dtype=np.int64))
    np.testing.assert_array_equal(log.imu.omega_b[:k], np.array(ref_w))
    assert log.truth.topic == "/ground_truth/orientation"
    assert log.custom_data["broad.movement_intervals_index"] == "[[7573, 41189]]"
    assert [c.topic for c in log.channels] == ["/imu/data", "/imu/mag", "/ground_truth/orientation"]


def test_vendor_wrapper_with_imu_field(tmp_path):
    # The Imu sits after a header, a string of varying length and a byte: its offset varies.
    t_ns, omega = _samples(30)
    p = tmp_path / "w.mcap"
    with open(p, "wb") as f:
        w = Ros2Writer(f)
        schema = w.register_msgdef("acme_msgs/msg/ImuPacket", WRAPPER_DEF)
        for i, t in enumerate(t_ns):
            msg = {
                "header": {"stamp": _stamp(0), "frame_id": "base"},
                "device_name": "dev" * (i % 4),
                "status": 1,
                "imu": _imu_msg(int(t), omega[i], "imu" * (i % 3)),
                "temperature": 25.0,
            }
            w.write_message("/acme/imu", schema, msg, log_time=int(t), publish_time=int(t))
        w.finish()
    log = read_log(p)
    assert log.imu.topic == "/acme/imu" and log.imu.type == "acme_msgs/msg/ImuPacket"
    np.testing.assert_array_equal(log.imu.omega_b, omega)
    np.testing.assert_array_equal(log.imu.t_ns, t_ns)  # the Imu's own header stamp


def test_json_channel(tmp_path):
    t_ns, omega = _samples(20)
    p = tmp_path / "j.mcap"
    with open(p, "wb") as f:
        w = McapWriter(f)
        w.start("", "test")
        sid = w.register_schema("Imu", "jsonschema", b"{}")
        cid = w.register_channel("/phone/gyro", "json", sid)
        for i, t in enumerate(t_ns):
            msg = {
                "header": {"stamp": _stamp(int(t))},
                "angular_velocity": dict(zip("xyz", omega[i].tolist(), strict=False)),
            }
            w.add_message(
                cid, log_time=int(t) + 7, data=json.dumps(msg).encode(), publish_time=int(t)
            )
        w.finish()
    log = read_log(p)
    np.testing.assert_allclose(log.imu.omega_b, omega, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(log.imu.t_ns, t_ns)
    np.testing.assert_array_equal(log.imu.log_t_ns, t_ns + 7)


def _write_truth(w: Ros2Writer, topic: str, typ: str, definition: str, t_ns, q, make):
    schema = w.register_msgdef(typ, definition)
    for i, t in enumerate(t_ns):
        w.write_message(
            topic,
            schema,
            make(int(t), dict(zip("xyzw", q[i].tolist(), strict=False))),
            log_time=int(t),
            publish_time=int(t),
        )


def _rand_quats(n, seed=1):
    q = np.random.default_rng(seed).normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _h(t):
    return {"stamp": _stamp(t), "frame_id": "world"}


def _pose(q):
    return {"position": {"x": 1.0, "y": 2.0, "z": 3.0}, "orientation": q}


ZERO_COV = [0.0] * 36
TRUTH_CASES = {
    "geometry_msgs/msg/QuaternionStamped": (
        QSTAMPED_DEF,
        lambda t, q: {"header": _h(t), "quaternion": q},
    ),
    "geometry_msgs/msg/PoseStamped": (
        POSE_STAMPED_DEF,
        lambda t, q: {"header": _h(t), "pose": _pose(q)},
    ),
    "geometry_msgs/msg/PoseWithCovarianceStamped": (
        "std_msgs/Header header\ngeometry_msgs/PoseWithCovariance pose\n"
        + HEADER
        + "\n"
        + "=" * 80
        + "\nMSG: geometry_msgs/PoseWithCovariance\nPose pose\n"
        "float64[36] covariance\n" + POSE + POINT + QUAT,
        lambda t, q: {"header": _h(t), "pose": {"pose": _pose(q), "covariance": ZERO_COV}},
    ),
    "geometry_msgs/msg/TransformStamped": (
        TRANSFORM_DEF,
        lambda t, q: {
            "header": _h(t),
            "child_frame_id": "imu_link",
            "transform": {"translation": {"x": 0.0, "y": 0.0, "z": 0.0}, "rotation": q},
        },
    ),
    "nav_msgs/msg/Odometry": (
        ODOM_DEF,
        lambda t, q: {
            "header": _h(t),
            "child_frame_id": "base_link",
            "pose": {"pose": _pose(q), "covariance": ZERO_COV},
            "twist": {
                "twist": {
                    "linear": {"x": 0.0, "y": 0.0, "z": 0.0},
                    "angular": {"x": 0.0, "y": 0.0, "z": 0.0},
                },
                "covariance": ZERO_COV,
            },
        },
    ),
}


@pytest.mark.parametrize("typ", sorted(TRUTH_CASES))
def test_truth_types(tmp_path, typ):
    t_ns, omega = _samples(20)
    q = _rand_quats(20)
    definition, make = TRUTH_CASES[typ]
    p = write_imu_bag(
        tmp_path / "t.mcap",
        t_ns,
        omega,
        extra=lambda w: _write_truth(w, "/truth", typ, definition, t_ns, q, make),
    )
    log = read_log(p)
    assert log.truth.topic == "/truth" and log.truth.type == typ
    np.testing.assert_array_equal(log.truth.q_w_b, q)
    np.testing.assert_array_equal(log.truth.t_ns, t_ns)


def test_imu_orientation_as_truth_when_flagged(tmp_path):
    # covariance[0] = 0 (not -1): the Imu carries an orientation, used as the reference.
    t_ns, omega = _samples(10)
    q = _rand_quats(10)
    p = write_imu_bag(tmp_path / "o.mcap", t_ns, omega, quats=q, cov0=0.0)
    log = read_log(p)
    assert log.truth.topic == "/imu/data"
    np.testing.assert_allclose(log.truth.q_w_b, q, rtol=0, atol=1e-15)


def test_all_zero_quaternion_without_flag_is_not_truth(tmp_path):
    # Devices publish (0, 0, 0, 0) without the -1 flag (DESIGN §8): that is not an attitude.
    t_ns, omega = _samples(10)
    p = write_imu_bag(tmp_path / "z.mcap", t_ns, omega, quats=np.zeros((10, 4)), cov0=0.0)
    assert read_log(p).truth is None


def test_constant_default_orientation_behind_garbage_covariance_is_not_truth(tmp_path):
    # DESIGN §8: covariance arrays holding 4e-322 instead of -1, with the default quaternion.
    t_ns, omega = _samples(10)
    ident = np.tile([0.0, 0.0, 0.0, 1.0], (10, 1))
    p = write_imu_bag(tmp_path / "g.mcap", t_ns, omega, quats=ident, cov0=4e-322)
    assert read_log(p).truth is None
    asked = read_log(p, truth_topic="/imu/data").truth  # named explicitly: used as given
    np.testing.assert_array_equal(asked.q_w_b, ident)


def test_several_imu_channels_fail_listing_them_and_topic_chooses(tmp_path):
    t_ns, omega = _samples(10)

    def second(w):
        schema = w.register_msgdef("sensor_msgs/msg/Imu", IMU_DEF)
        for i, t in enumerate(t_ns):
            w.write_message("/imu2", schema, _imu_msg(int(t), -omega[i]), log_time=int(t))

    p = write_imu_bag(tmp_path / "two.mcap", t_ns, omega, extra=second)
    with raises_naming(LogError, 2, "/imu/data", "/imu2", "--imu-topic"):
        read_log(p)
    np.testing.assert_array_equal(read_log(p, imu_topic="/imu2").imu.omega_b, -omega)
    with pytest.raises(LogError, match="IMU topic '/nope'"):
        read_log(p, imu_topic="/nope")


def test_no_imu_channel_lists_channels(tmp_path):
    p = tmp_path / "mag.mcap"
    with open(p, "wb") as f:
        w = Ros2Writer(f)
        schema = w.register_msgdef("sensor_msgs/msg/MagneticField", MAG_DEF)
        w.write_message(
            "/imu/mag",
            schema,
            {
                "header": _h(T0_NS),
                "magnetic_field": {"x": 1e-5, "y": 0.0, "z": 0.0},
                "magnetic_field_covariance": [0.0] * 9,
            },
            log_time=T0_NS,
        )
        w.finish()
    with raises_naming(
        LogError, "sensor_msgs/msg/Imu", "/imu/mag", "sensor_msgs/msg/MagneticField"
    ):
        read_log(p)


def test_unknown_encoding(tmp_path):
    p = tmp_path / "pb.mcap"
    with open(p, "wb") as f:
        w = McapWriter(f)
        w.start("", "test")
        sid = w.register_schema("foxglove.Imu", "protobuf", b"\x00")
        cid = w.register_channel("/imu", "protobuf", sid)
        w.add_message(cid, log_time=1, data=b"\x08\x01", publish_time=1)
        w.finish()
    with raises_naming(LogError, "cdr", "json", "'protobuf'", "/imu"):
        read_log(p)


def test_empty_bag(tmp_path):
    p = tmp_path / "empty.mcap"
    with open(p, "wb") as f:
        w = Ros2Writer(f)
        w.register_msgdef("sensor_msgs/msg/Imu", IMU_DEF)
        w.finish()
    with pytest.raises(LogError, match="empty log"):
        read_log(p)


def test_not_mcap_empty_file_and_missing_path(tmp_path):
    (tmp_path / "garbage.mcap").write_bytes(b"this is not an mcap file at all" * 10)
    with raises_naming(LogError, "MCAP", str(tmp_path / "garbage.mcap")):
        read_log(tmp_path / "garbage.mcap")
    (tmp_path / "zero.mcap").write_bytes(b"")
    with pytest.raises(LogError, match="empty file"):
        read_log(tmp_path / "zero.mcap")
    with pytest.raises(LogError, match="no such file"):
        read_log(tmp_path / "missing")
    (tmp_path / "folder").mkdir()
    with raises_naming(LogError, ".mcap", str(tmp_path / "folder")):
        read_log(tmp_path / "folder")


@pytest.mark.parametrize("keep_fraction", [0.2, 0.55, 0.9])
def test_truncated_file_replays_readable_part(tmp_path, keep_fraction):
    # A copy of the shipped trial cut short: every sample read must equal the full read's
    # prefix, and a warning must say where reading stopped. The input is never modified.
    src = resolve_mcap_path(SHIPPED)
    before = src.stat().st_mtime_ns, src.stat().st_size
    data = src.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * keep_fraction)])
    with pytest.warns(ImuDcmWarning, match=r"truncated or corrupt: .* at byte \d+"):
        part = read_log(cut)
    full = read_log(SHIPPED)
    k = len(part.imu.t_ns)
    # chunks of ~1 MB hold ~1750 samples each: at least the complete chunks are read
    assert 0.5 * keep_fraction * len(full.imu.t_ns) < k < len(full.imu.t_ns)
    np.testing.assert_array_equal(part.imu.omega_b, full.imu.omega_b[:k])
    assert part.stopped_at is not None
    assert (src.stat().st_mtime_ns, src.stat().st_size) == before


def _chunk_messages(path: Path) -> list[list[tuple[str, int]]]:
    """(topic, log time) of the messages of every chunk, by the mcap library's stream reader."""
    from mcap.records import Channel, Chunk
    from mcap.stream_reader import StreamReader, breakup_chunk

    topics, chunks = {}, []
    with open(path, "rb") as f:
        for rec in StreamReader(f, emit_chunks=True).records:
            if isinstance(rec, Chunk):
                inner = breakup_chunk(rec)
                topics.update({r.id: r.topic for r in inner if isinstance(r, Channel)})
                chunks.append(
                    [
                        (topics[r.channel_id], r.log_time)
                        for r in inner
                        if hasattr(r, "channel_id") and hasattr(r, "log_time")
                    ]
                )
    return chunks


def test_corrupt_chunk_costs_only_itself(tmp_path):
    # Overwrite bytes inside the compressed data of the 16th chunk (of 30): that chunk's
    # messages are lost, every other chunk is read, and the warning names the chunk's file offset.
    src = resolve_mcap_path(SHIPPED)
    with open(src, "rb") as f:
        summary = make_reader(f).get_summary()
    chunk = summary.chunk_indexes[15]
    data = bytearray(src.read_bytes())
    mid = chunk.chunk_start_offset + chunk.chunk_length // 2
    data[mid : mid + 64] = bytes(range(64))
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    with pytest.warns(
        ImuDcmWarning,
        match=rf"truncated or corrupt: .*file offset "
        rf"{chunk.chunk_start_offset}\b",
    ):
        log = read_log(bad)
    full = read_log(SHIPPED)
    # Oracle: the mcap library's own chunk walker lists the messages of the 16th chunk.
    per_chunk = _chunk_messages(src)
    assert len(per_chunk) == 30
    lost = per_chunk[15]
    imu_lost = [m for m in lost if m[0] == "/imu/data"]
    n_before = sum(sum(m[0] == "/imu/data" for m in c) for c in per_chunk[:15])
    keep = np.ones(len(full.imu.t_ns), bool)
    keep[n_before : n_before + len(imu_lost)] = False
    assert 1500 < len(imu_lost) < 1900
    np.testing.assert_array_equal(log.imu.omega_b, full.imu.omega_b[keep])
    np.testing.assert_array_equal(log.imu.t_ns, full.imu.t_ns[keep])
    (d,) = log.damage
    assert d.offset == chunk.chunk_start_offset
    assert d.messages_lost == sum(m[0] != "/imu/mag" for m in lost)
    assert (d.t_start_ns, d.t_end_ns) == (chunk.message_start_time, chunk.message_end_time)


def test_bag_folder_and_file_give_the_same(tmp_path):
    t_ns, omega = _samples(10)
    folder = tmp_path / "bag"
    folder.mkdir()
    write_imu_bag(folder / "bag_0.mcap", t_ns, omega)
    a, b = read_log(folder), read_log(folder / "bag_0.mcap")
    np.testing.assert_array_equal(a.imu.omega_b, b.imu.omega_b)
    shutil.copy(folder / "bag_0.mcap", folder / "bag_1.mcap")
    with raises_naming(LogError, str(folder), "bag_0.mcap", "bag_1.mcap"):
        read_log(folder)


def test_layout_the_bulk_walker_cannot_follow_falls_back_to_the_decoder(tmp_path):
    # A sequence of strings before the Imu: per-message offsets need every string's length, so
    # the reader decodes these messages one by one with mcap_ros2 (same values, slower).
    t_ns, omega = _samples(12)
    definition = "string[] tags\nsensor_msgs/Imu imu\n" + IMU_SECTION + HEADER + QUAT + VEC3
    p = tmp_path / "tags.mcap"
    with open(p, "wb") as f:
        w = Ros2Writer(f)
        schema = w.register_msgdef("acme_msgs/msg/TaggedImu", definition)
        for i, t in enumerate(t_ns):
            msg = {"tags": ["a" * i, "bc"][: i % 3], "imu": _imu_msg(int(t), omega[i])}
            w.write_message("/tagged", schema, msg, log_time=int(t), publish_time=int(t))
        w.finish()
    log = read_log(p)
    np.testing.assert_array_equal(log.imu.omega_b, omega)
    np.testing.assert_array_equal(log.imu.t_ns, t_ns)


def test_short_message_is_dropped_and_counted(tmp_path):
    # Re-write a bag's raw payloads with one cut to 20 bytes (shorter than an Imu's layout).
    t_ns, omega = _samples(15)
    src = write_imu_bag(tmp_path / "ok.mcap", t_ns, omega)
    with open(src, "rb") as f:
        reader = make_reader(f)
        schema_rec = next(iter(reader.get_summary().schemas.values()))
        payloads = [(m.log_time, m.data) for _, _, m in reader.iter_messages()]
    p = tmp_path / "short.mcap"
    with open(p, "wb") as f:
        w = McapWriter(f)
        w.start("ros2", "test")
        sid = w.register_schema(schema_rec.name, schema_rec.encoding, schema_rec.data)
        cid = w.register_channel("/imu/data", "cdr", sid)
        for i, (lt, data) in enumerate(payloads):
            w.add_message(cid, log_time=lt, data=data[:20] if i == 7 else data, publish_time=lt)
        w.finish()
    with pytest.warns(ImuDcmWarning, match="/imu/data: dropped 1 messages that do not decode"):
        log = read_log(p)
    np.testing.assert_array_equal(log.imu.omega_b, np.delete(omega, 7, axis=0))


def test_live_batch_decode_matches_the_file_reader():
    # A live source hands raw payloads and the schema text: the batch decoder must give the
    # same samples as reading the file, and flag a cut payload.
    from imu_dcm.logio.ros.payload import classify_schema, decode_cdr_batch

    src = resolve_mcap_path(SHIPPED)
    by_topic: dict[str, list] = {}
    with open(src, "rb") as f:
        for schema, channel, m in make_reader(f).iter_messages():
            got = by_topic.setdefault(channel.topic, [schema, []])
            if len(got[1]) < 300:
                got[1].append(m.data)
            if all(len(v[1]) >= 300 for v in by_topic.values()) and len(by_topic) == 3:
                break
    full = read_log(SHIPPED)
    schema, payloads = by_topic["/imu/data"]
    kind = classify_schema(schema.name, schema.encoding, schema.data.decode())
    assert kind == ("imu", "")
    payloads[7] = payloads[7][:20]
    dec = decode_cdr_batch(
        kind, schema.name, schema.encoding, schema.data.decode(), payloads, "/imu/data"
    )
    assert not dec.good[7] and dec.good.sum() == 299
    np.testing.assert_array_equal(dec.values, np.delete(full.imu.omega_b[:300], 7, axis=0))
    np.testing.assert_array_equal(dec.t_ns, np.delete(full.imu.t_ns[:300], 7))
    schema, payloads = by_topic["/ground_truth/orientation"]
    kind = classify_schema(schema.name, schema.encoding, schema.data.decode())
    assert kind == ("truth", "quaternion")
    dec = decode_cdr_batch(
        kind, schema.name, schema.encoding, schema.data.decode(), payloads, "/truth"
    )
    np.testing.assert_array_equal(dec.values, full.truth.q_w_b[:300])
    schema, _ = by_topic["/imu/mag"]
    assert classify_schema(schema.name, schema.encoding, schema.data.decode()) is None


def test_vector3stamped_is_the_gyro_only_when_its_name_says_so_or_it_is_named(tmp_path):
    t_ns, omega = _samples(8)
    vec_def = "std_msgs/Header header\ngeometry_msgs/Vector3 vector\n" + HEADER + VEC3
    for topic, auto in (("/wind", False), ("/sensors/gyro", True), ("/imu/angular_velocity", True)):
        p = tmp_path / f"{topic.strip('/').replace('/', '_')}.mcap"
        with open(p, "wb") as f:
            w = Ros2Writer(f)
            schema = w.register_msgdef("geometry_msgs/msg/Vector3Stamped", vec_def)
            for i, t in enumerate(t_ns):
                w.write_message(
                    topic,
                    schema,
                    {
                        "header": _h(int(t)),
                        "vector": dict(zip("xyz", omega[i].tolist(), strict=False)),
                    },
                    log_time=int(t),
                )
            w.finish()
        if auto:
            np.testing.assert_array_equal(read_log(p).imu.omega_b, omega)
        else:
            with pytest.raises(LogError, match="named with --imu-topic"):
                read_log(p)
        np.testing.assert_array_equal(read_log(p, imu_topic=topic).imu.omega_b, omega)

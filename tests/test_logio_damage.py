"""Damaged, lying and hostile inputs: one damaged chunk costs only itself, nothing explodes.

Files are a slice of the shipped BROAD trial written with small chunks; then one chunk is
damaged on purpose. The oracle for which messages each chunk holds is the mcap library's own
stream reader on the undamaged file.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
import zstandard
from conftest import raises_naming
from mcap.reader import make_reader
from mcap.writer import CompressionType
from test_logio_formats import IMU, SHIPPED, SLICE_NS, write_mcap

from imu_dcm.errors import ImuDcmWarning, LogError
from imu_dcm.logio import read_log

K = 5  # the damaged chunk (0-based)


@pytest.fixture(scope="module")
def msgs():
    out = []
    with open(next(SHIPPED.glob("*.mcap")), "rb") as f:
        reader = make_reader(f)
        start = reader.get_summary().statistics.message_start_time
        for schema, channel, m in reader.iter_messages(ending_before=start + SLICE_NS // 2):
            out.append(
                (channel.topic, schema.name, schema.data, m.log_time, m.publish_time, m.data)
            )
    return out


def chunk_messages(path: Path) -> list[list[str]]:
    """Topics of the messages of every chunk, by the mcap library's stream reader."""
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
                        topics[r.channel_id]
                        for r in inner
                        if hasattr(r, "channel_id") and hasattr(r, "log_time")
                    ]
                )
    return chunks


def chunk_index(path: Path):
    with open(path, "rb") as f:
        return make_reader(f).get_summary().chunk_indexes


def make(tmp_path, msgs, name="ok.mcap", **kw):
    p = write_mcap(tmp_path / name, msgs, chunk_size=16 * 1024, **kw)
    base = read_log(p)
    per_chunk = chunk_messages(p)
    assert len(per_chunk) > K + 3
    return p, base, per_chunk


def expect_chunk_lost(log, base, per_chunk, k: int, offset: int) -> None:
    n_before = sum(c.count(IMU) for c in per_chunk[:k])
    n_lost = per_chunk[k].count(IMU)
    assert n_lost > 20
    keep = np.ones(len(base.imu.t_ns), bool)
    keep[n_before : n_before + n_lost] = False
    np.testing.assert_array_equal(log.imu.omega_b, base.imu.omega_b[keep])
    np.testing.assert_array_equal(log.imu.t_ns, base.imu.t_ns[keep])
    (d,) = log.damage
    assert d.offset == offset
    if d.messages_lost is not None:
        assert d.messages_lost == sum(t != "/imu/mag" for t in per_chunk[k])


def patched(src: Path, dst: Path, offset: int, data: bytes) -> Path:
    raw = bytearray(src.read_bytes())
    raw[offset : offset + len(data)] = data
    dst.write_bytes(bytes(raw))
    return dst


def read_warned(p: Path, offset: int):
    with pytest.warns(ImuDcmWarning, match=rf"file offset {offset}\b"):
        return read_log(p)


# ------------------------------------------------------------------------ damaged chunks
def test_flipped_byte_in_chunk_k_with_crc_costs_only_that_chunk(tmp_path, msgs):
    # Uncompressed chunks with a CRC: the CRC catches one flipped byte in a payload.
    p, base, per_chunk = make(tmp_path, msgs, crc=True, compression=CompressionType.NONE)
    ci = chunk_index(p)[K]
    raw = p.read_bytes()
    at = ci.chunk_start_offset + ci.chunk_length // 2
    bad = patched(p, tmp_path / "bad.mcap", at, bytes([raw[at] ^ 0x10]))
    log = read_warned(bad, ci.chunk_start_offset)
    expect_chunk_lost(log, base, per_chunk, K, ci.chunk_start_offset)


@pytest.mark.parametrize("field", ["length", "channel"])
def test_flipped_byte_in_a_message_record_costs_only_that_message(tmp_path, msgs, field):
    # No CRC (rosbag2's default), uncompressed: a flipped byte in a message record's length or
    # channel id (the first IMU message of chunk K). The message indexes locate every other record:
    # only that message is lost, and the warning names the chunk's file offset.
    p, base, per_chunk = make(tmp_path, msgs, crc=False, compression=CompressionType.NONE)
    ci = chunk_index(p)[K]
    raw = p.read_bytes()
    first = ci.chunk_start_offset + 49  # chunk header of an uncompressed chunk: 40 bytes
    for _ in range(per_chunk[K].index(IMU)):  # to the chunk's first IMU message record
        first += 9 + struct.unpack_from("<Q", raw, first + 1)[0]
    assert raw[first] == 5
    at = first + 8 if field == "length" else first + 9
    bad = patched(p, tmp_path / "bad.mcap", at, bytes([raw[at] ^ 0x40]))
    log = read_warned(bad, ci.chunk_start_offset)
    n_before = sum(c.count(IMU) for c in per_chunk[:K])
    np.testing.assert_array_equal(log.imu.omega_b, np.delete(base.imu.omega_b, n_before, axis=0))
    (d,) = log.damage
    assert d.offset == ci.chunk_start_offset and d.messages_lost == 1


@pytest.mark.parametrize("usize", [2**63 + 5, 2**64 - 1, 2_200_000_000, "minus1"])
def test_lying_uncompressed_size_costs_only_that_chunk(tmp_path, msgs, usize):
    p, base, per_chunk = make(tmp_path, msgs)
    ci = chunk_index(p)[K]
    value = ci.uncompressed_size - 1 if usize == "minus1" else usize
    bad = patched(p, tmp_path / "bad.mcap", ci.chunk_start_offset + 25, struct.pack("<Q", value))
    log = read_warned(bad, ci.chunk_start_offset)
    expect_chunk_lost(log, base, per_chunk, K, ci.chunk_start_offset)


def test_lying_sizes_in_a_file_without_summary_resync_on_the_next_chunk(tmp_path, msgs):
    # No summary (the data section, then a data-end record and nothing more): the file is
    # walked forward. Chunk K's record length is a lie; the walk resumes at the next chunk.
    p, base, per_chunk = make(tmp_path, msgs)
    index = chunk_index(p)
    ci = index[K]
    last = index[-1]
    cut = last.chunk_start_offset + last.chunk_length + last.message_index_length
    raw = bytearray(p.read_bytes()[:cut] + struct.pack("<BQI", 0x0F, 4, 0))
    raw[ci.chunk_start_offset + 1 : ci.chunk_start_offset + 9] = struct.pack("<Q", 10**12)
    bad = tmp_path / "nosummary.mcap"
    bad.write_bytes(bytes(raw))
    log = read_warned(bad, ci.chunk_start_offset)
    expect_chunk_lost(log, base, per_chunk, K, ci.chunk_start_offset)


def test_truncated_file_keeps_every_complete_chunk(tmp_path, msgs):
    p, base, per_chunk = make(tmp_path, msgs)
    ci = chunk_index(p)[K]
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(p.read_bytes()[: ci.chunk_start_offset + ci.chunk_length // 2])
    with pytest.warns(
        ImuDcmWarning, match=rf"ends inside a record at byte {ci.chunk_start_offset}"
    ):
        log = read_log(cut)
    n = sum(c.count(IMU) for c in per_chunk[:K])
    np.testing.assert_array_equal(log.imu.omega_b, base.imu.omega_b[:n])


# ---------------------------------------------------------------------- memory bombs
def _bomb_file(tmp_path: Path, compression: str, declared: int, payload: bytes) -> Path:
    """An MCAP whose only chunk holds ``payload`` (compressed) and declares ``declared``."""
    from mcap.writer import Writer

    p = tmp_path / "bomb.mcap"
    with open(p, "wb") as f:
        w = Writer(f, compression=CompressionType.NONE, chunk_size=1 << 30)
        w.start("ros2", "test")
        w.finish()
    raw = p.read_bytes()
    magic, rest = raw[:8], raw[8:]
    header_len = 9 + struct.unpack_from("<Q", rest, 1)[0]
    comp = compression.encode()
    body = struct.pack("<QQQI", 0, 0, declared, 0) + struct.pack("<I", len(comp)) + comp
    body += struct.pack("<Q", len(payload)) + payload
    chunk = struct.pack("<BQ", 6, len(body)) + body
    p.write_bytes(magic + rest[:header_len] + chunk)  # no summary: the forward walk meets it
    return p


def _zeros_zstd(n: int) -> bytes:
    c = zstandard.ZstdCompressor().compressobj()
    block = bytes(1 << 20)
    out = [c.compress(block) for _ in range(n >> 20)]
    return b"".join(out) + c.flush()


def test_a_chunk_declaring_gigabytes_from_a_small_file_is_refused(tmp_path):
    # ~2.2 GB of zeros truthfully declared, from a few kB: refused before decompressing.
    data = _zeros_zstd(2_200 << 20)
    assert len(data) < 200_000
    p = _bomb_file(tmp_path, "zstd", 2_200 << 20, data)
    with pytest.raises(
        LogError,
        match=r"got none readable .*declares 2306867200 bytes "
        r"uncompressed from \d+ \(refused",
    ):
        read_log(p)


def test_lz4_chunk_never_decompresses_past_its_declared_size(tmp_path):
    import lz4.frame

    data = lz4.frame.compress(bytes(50 << 20))  # 50 MB of zeros, declared as 1000 bytes
    p = _bomb_file(tmp_path, "lz4", 1000, data)
    with pytest.raises(LogError, match=r"decompresses to 1001\+ bytes, not its declared 1000"):
        read_log(p)


def test_zstd_frame_larger_than_the_chunk_declares_is_refused(tmp_path):
    data = zstandard.ZstdCompressor().compress(bytes(10 << 20))  # content size in the frame
    p = _bomb_file(tmp_path, "zstd", 1000, data)
    with pytest.raises(LogError, match="its zstd frame declares 10485760 bytes"):
        read_log(p)


# ------------------------------------------------------------ hostile schemas, JSON, YAML
def _one_channel(
    tmp_path: Path, name: str, enc: str, text: bytes, payloads: list[bytes], msg_enc: str = "cdr"
) -> Path:
    from mcap.writer import Writer

    p = tmp_path / "h.mcap"
    with open(p, "wb") as f:
        w = Writer(f)
        w.start("ros2", "test")
        sid = w.register_schema(name, enc, text)
        cid = w.register_channel("/imu/data", msg_enc, sid)
        for i, data in enumerate(payloads):
            w.add_message(cid, log_time=i + 1, data=data, publish_time=i + 1)
        w.finish()
    return p


@pytest.mark.parametrize(
    "text",
    [
        b"\xff\xfe not utf-8 \x80",
        b"float64 x y z\n!!! ???",
        b"std_msgs/Header header\nfloat64[9 orientation_covariance",
    ],
)
def test_corrupt_imu_schema_is_one_line_error(tmp_path, text):
    p = _one_channel(tmp_path, "sensor_msgs/msg/Imu", "ros2msg", text, [b"\x00\x01\x00\x00"])
    with raises_naming(LogError, "/imu/data", "ros2msg", "sensor_msgs/msg/Imu"):
        read_log(p)


def test_self_containing_and_very_deep_types_are_refused(tmp_path):
    from test_logio import HEADER, IMU_SECTION, QUAT, VEC3

    sep = "\n" + "=" * 80 + "\n"
    rec = "acme_msgs/Rec rec\nsensor_msgs/Imu imu\n" + IMU_SECTION + HEADER + QUAT + VEC3
    rec += sep + "MSG: acme_msgs/Rec\nacme_msgs/Rec rec\n"
    p = _one_channel(tmp_path, "acme_msgs/msg/Rec", "ros2msg", rec.encode(), [b"\x00\x01\0\0"])
    with pytest.raises(LogError):
        read_log(p)
    deep = (
        "acme_msgs/T1 t\n"
        + "".join(f"{sep}MSG: acme_msgs/T{i}\nacme_msgs/T{i + 1} t\n" for i in range(1, 3000))
        + f"{sep}MSG: acme_msgs/T3000\nint8 x\n"
    )
    p = _one_channel(tmp_path, "sensor_msgs/msg/Imu", "ros2msg", deep.encode(), [b"\0\1\0\0"])
    with pytest.raises(LogError):
        read_log(p)


def test_empty_covariance_sequence_keeps_the_gyro(tmp_path):
    # A vendor Imu whose orientation_covariance is float64[] and empty: the per-message decoder
    # reads the gyro and leaves the orientation flag unknown (no StopIteration).
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore
    from test_logio import HEADER, QUAT, VEC3

    fields = (
        "std_msgs/Header header\ngeometry_msgs/Quaternion orientation\n"
        "float64[] orientation_covariance\ngeometry_msgs/Vector3 angular_velocity\n"
    )
    text = fields + HEADER + QUAT + VEC3
    store = get_typestore(Stores.EMPTY)
    types = get_types_from_msg(text, "sensor_msgs/msg/Imu")
    types["builtin_interfaces/msg/Time"] = get_typestore(Stores.ROS2_HUMBLE).fielddefs[
        "builtin_interfaces/msg/Time"
    ]
    store.register(types)
    T = store.types
    omega = np.random.default_rng(3).normal(size=(5, 3))
    payloads = []
    for i, w in enumerate(omega):
        hdr = T["std_msgs/msg/Header"](T["builtin_interfaces/msg/Time"](1, i), "imu")
        m = T["sensor_msgs/msg/Imu"](
            hdr,
            T["geometry_msgs/msg/Quaternion"](0.0, 0.0, 0.0, 1.0),
            np.zeros(0),
            T["geometry_msgs/msg/Vector3"](*w),
        )
        payloads.append(bytes(store.serialize_cdr(m, "sensor_msgs/msg/Imu")))
    p = _one_channel(tmp_path, "sensor_msgs/msg/Imu", "ros2msg", text.encode(), payloads)
    log = read_log(p, imu_topic="/imu/data")
    np.testing.assert_array_equal(log.imu.omega_b, omega)


@pytest.mark.parametrize("stamp", ["1e300", str(2**70), "Infinity", "NaN"])
def test_json_stamps_beyond_int64_drop_that_message(tmp_path, stamp):
    good = [
        b'{"header": {"stamp": {"sec": %d, "nanosec": 0}}, "angular_velocity": '
        b'{"x": 1.0, "y": 2.0, "z": 3.0}}' % i
        for i in range(1, 4)
    ]
    bad = (
        '{"header": {"stamp": {"sec": ' + stamp + ', "nanosec": 0}}, "angular_velocity": '
        '{"x": 1.0, "y": 2.0, "z": 3.0}}'
    ).encode()
    p = _one_channel(tmp_path, "Imu", "jsonschema", b"{}", good + [bad], msg_enc="json")
    with pytest.warns(ImuDcmWarning, match="dropped 1 messages"):
        log = read_log(p)
    np.testing.assert_array_equal(log.imu.t_ns, [1_000_000_000, 2_000_000_000, 3_000_000_000])


def test_json_nested_100000_deep_is_dropped(tmp_path):
    good = b'{"angular_velocity": {"x": 1.0, "y": 2.0, "z": 3.0}}'
    deep = (
        b'{"angular_velocity": {"x": 1.0, "y": 2.0, "z": 3.0}, "a": '
        + b"[" * 100_000
        + b"]" * 100_000
        + b"}"
    )
    p = _one_channel(tmp_path, "Imu", "jsonschema", b"{}", [good, deep, good], msg_enc="json")
    with pytest.warns(ImuDcmWarning, match="dropped 1 messages"):
        assert len(read_log(p).imu.t_ns) == 2


@pytest.mark.parametrize(
    "text, facts",
    [
        (b"- just\n- a list\n", ("rosbag2_bagfile_information", "list")),
        (b"rosbag2_bagfile_information: \xff\xfe\n", ("UTF-8", 29)),  # the byte's offset
        (b"rosbag2_bagfile_information: [unclosed\n", ("YAML", "syntax")),
        (
            (
                b"a: &a [x, x, x, x, x, x, x, x, x]\nb: &b [*a, *a, *a, *a, *a, *a, *a, *a, *a]\n"
                b"c: &c [*b, *b, *b, *b, *b, *b, *b, *b, *b]\n"
                b"rosbag2_bagfile_information: [*c, *c, *c]\n"
            ),
            ("YAML aliases",),
        ),
        (
            b"rosbag2_bagfile_information:\n  storage_identifier: mcap\n  relative_file_paths: 3\n",
            ("relative_file_paths", 3),
        ),
    ],
)
def test_bad_metadata_yaml_is_one_line_error(tmp_path, text, facts):
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "metadata.yaml").write_bytes(text)
    with raises_naming(LogError, str(bag / "metadata.yaml"), *facts):
        read_log(bag)


# ------------------------------------------------------------------------- ROS 1 chunks
def _ros1_bag(tmp_path: Path, msgs, compression: str) -> Path:
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ros2, ros1 = get_typestore(Stores.ROS2_HUMBLE), get_typestore(Stores.ROS1_NOETIC)
    path = tmp_path / f"{compression}.bag"
    w = Writer(path)
    w.set_compression(Writer.CompressionFormat[compression.upper()])
    w.chunk_threshold = 16 * 1024
    with w:
        conns = {}
        for topic, sname, _sd, lt, _pt, data in msgs:
            if topic not in conns:
                conns[topic] = w.add_connection(topic, sname, typestore=ros1)
            w.write(conns[topic], lt, ros2.cdr_to_ros1(data, sname))
    return path


def _ros1_chunks(path: Path) -> list[tuple[int, int]]:
    """(file offset, IMU messages) of every chunk, from rosbags' index."""
    from rosbags.rosbag1 import Reader

    with Reader(path) as r:
        imu = next(c.id for c in r.connections if c.topic == IMU)
        return [
            (ci.pos, ci.connection_counts.get(imu, 0))
            for ci in sorted(r.chunk_infos, key=lambda c: c.pos)
        ]


@pytest.mark.parametrize("compression, lie", [("bz2", "flip"), ("lz4", "size")])
def test_ros1_damaged_chunk_costs_only_itself(tmp_path, msgs, compression, lie):
    p = _ros1_bag(tmp_path, msgs, compression)
    base = read_log(p)
    chunks = _ros1_chunks(p)
    assert len(chunks) > K + 3
    pos, n_lost = chunks[K]
    raw = bytearray(p.read_bytes())
    if lie == "flip":  # a byte in the middle of the compressed data
        end = chunks[K + 1][0]
        mid = (pos + end) // 2
        raw[mid : mid + 16] = bytes(16)
    else:  # the chunk header's uncompressed size, 1000 bytes less than the truth
        at = raw.index(b"size=", pos) + 5
        size = struct.unpack_from("<I", raw, at)[0]
        raw[at : at + 4] = struct.pack("<I", size - 1000)
    bad = tmp_path / "bad.bag"
    bad.write_bytes(bytes(raw))
    log = read_warned(bad, pos)
    n_before = sum(n for _, n in chunks[:K])
    keep = np.ones(len(base.imu.t_ns), bool)
    keep[n_before : n_before + n_lost] = False
    np.testing.assert_array_equal(log.imu.omega_b, base.imu.omega_b[keep])
    (d,) = log.damage
    assert d.offset == pos and d.messages_lost >= n_lost

"""Every container a ROS user has gives the same samples: variants of the shipped BROAD trial.

Each variant is written here, in a temporary folder, with independent writers (rosbags for
sqlite3, ROS 1 and message-compressed bags; mcap for split, ros1-profile, ros2idl and
two-channel files; rosbags' serialisers for ROS 1, Vector3Stamped and TFMessage payloads) from
a slice of the shipped trial. The oracle is the slice written as a plain MCAP and read back,
itself checked against the mcap_ros2 decoder in tests/test_logio.py: every variant must give
bit-identical gyro samples, stamps and truth.
"""

from __future__ import annotations

import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
import yaml
import zstandard
from conftest import raises_naming
from mcap.reader import make_reader
from mcap.writer import Writer as McapWriter

from imu_dcm.logio import read_log
from imu_dcm.replay import replay

SHIPPED = Path(__file__).resolve().parents[1] / "replay" / "broad_07_undisturbed_fast_rotation_B"
SLICE_NS = 8_000_000_000  # the first 8 s (~2300 IMU samples, ~6800 messages)
IMU, MAG, TRUTH = "/imu/data", "/imu/mag", "/ground_truth/orientation"


def _shipped_mcap() -> Path:
    return next(SHIPPED.glob("*.mcap"))


@pytest.fixture(scope="module")
def msgs():
    """(topic, schema name, schema text, log time, publish time, CDR payload) of the slice."""
    out = []
    with open(_shipped_mcap(), "rb") as f:
        reader = make_reader(f)
        start = reader.get_summary().statistics.message_start_time
        for schema, channel, m in reader.iter_messages(ending_before=start + SLICE_NS):
            out.append(
                (channel.topic, schema.name, schema.data, m.log_time, m.publish_time, m.data)
            )
    return out


def write_mcap(
    path: Path,
    msgs,
    *,
    schema_of=None,
    chunk_size: int = 64 * 1024,
    channel_of=None,
    profile: str = "ros2",
    encoding: str = "cdr",
    compression=None,
    crc: bool = False,
) -> Path:
    """Raw copy of ``msgs`` into an MCAP; ``schema_of(name, text) -> (name, enc, data)``."""
    from mcap.writer import CompressionType

    kw = {"chunk_size": chunk_size, "enable_crcs": crc}
    if compression is not None:
        kw["compression"] = compression
    with open(path, "wb") as f:
        w = McapWriter(f, **kw)
        w.start(profile, "test")
        schemas, channels = {}, {}
        for i, (topic, sname, sdata, lt, pt, data) in enumerate(msgs):
            if sname not in schemas:
                name, enc, text = (
                    schema_of(sname, sdata) if schema_of else (sname, "ros2msg", sdata)
                )
                schemas[sname] = w.register_schema(name, enc, text)
            key = channel_of(topic, i) if channel_of else topic
            if key not in channels:
                channels[key] = w.register_channel(topic, encoding, schemas[sname])
            w.add_message(channels[key], log_time=lt, data=data, publish_time=pt)
        w.finish()
    del CompressionType
    return path


def write_metadata(folder: Path, files: list[str], storage: str = "mcap", mode: str = "") -> None:
    info = {
        "version": 5,
        "storage_identifier": storage,
        "relative_file_paths": files,
        "compression_format": "zstd" if mode else "",
        "compression_mode": mode,
        "custom_data": {"made.by": "test_logio_formats"},
    }
    (folder / "metadata.yaml").write_text(yaml.safe_dump({"rosbag2_bagfile_information": info}))


@pytest.fixture(scope="module")
def base(msgs, tmp_path_factory):
    """The oracle: the slice as a plain MCAP, read."""
    p = write_mcap(tmp_path_factory.mktemp("base") / "base.mcap", msgs)
    log = read_log(p)
    assert 2000 < len(log.imu.t_ns) < 2600 and len(log.truth.t_ns) > 1000
    return log


def _rms_deg(path, **options) -> float:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the slice's own oddities are not this test's business
        return replay(path, bias="none", **options).summary.rms_error_deg


def assert_same(log, base, truth: bool = True, **replay_options) -> None:
    """Identical samples and truth, and (with truth) the same replay error to 1e-6°."""
    if truth:
        want = _rms_deg(base.path)
        assert abs(_rms_deg(log.path, **replay_options) - want) <= 1e-6, log.container
    np.testing.assert_array_equal(log.imu.omega_b, base.imu.omega_b)
    np.testing.assert_array_equal(log.imu.t_ns, base.imu.t_ns)
    np.testing.assert_array_equal(log.imu.log_t_ns, base.imu.log_t_ns)
    if truth:
        np.testing.assert_array_equal(log.truth.q_w_b, base.truth.q_w_b)
        np.testing.assert_array_equal(log.truth.t_ns, base.truth.t_ns)
    assert log.damage == ()


def _typestore(ros1: bool = False):
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)


def write_rosbag2(folder: Path, msgs, storage: str, mode: str = "") -> Path:
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer

    plugin = StoragePlugin.SQLITE3 if storage == "sqlite3" else StoragePlugin.MCAP
    store = _typestore()
    w = Writer(folder, version=9, storage_plugin=plugin)
    if mode:
        w.set_compression(CompressionMode[mode.upper()], CompressionFormat.ZSTD)
    with w:
        conns = {}
        for topic, sname, _sd, lt, _pt, data in msgs:
            if topic not in conns:
                conns[topic] = w.add_connection(topic, sname, typestore=store)
            w.write(conns[topic], lt, data)
    return folder


# ------------------------------------------------------------------------- containers
@pytest.mark.parametrize("mode", ["", "message"])
def test_sqlite3_bag(msgs, base, tmp_path, mode):
    bag = write_rosbag2(tmp_path / "bag", msgs, "sqlite3", mode)
    log = read_log(bag)
    assert log.container.startswith("ros2 sqlite3")
    assert_same(log, base)


def test_sqlite3_without_definitions_uses_the_type_store(msgs, base, tmp_path):
    # Humble's sqlite3 bags store no message definitions: rosbags' type store supplies them.
    import sqlite3

    bag = write_rosbag2(tmp_path / "bag", msgs, "sqlite3")
    (db,) = bag.glob("*.db3")
    with sqlite3.connect(db) as con:
        con.execute("DELETE FROM message_definitions")
    assert_same(read_log(bag), base)
    assert_same(read_log(db), base)  # the .db3 file alone


def test_message_compressed_mcap_bag(msgs, base, tmp_path):
    log = read_log(write_rosbag2(tmp_path / "bag", msgs, "mcap", "message"))
    assert "message-compressed" in log.container
    assert_same(log, base)


@pytest.mark.parametrize("compression", ["none", "bz2", "lz4"])
def test_ros1_bag(msgs, base, tmp_path, compression):
    from rosbags.rosbag1 import Writer

    ros2, ros1 = _typestore(), _typestore(ros1=True)
    path = tmp_path / "x.bag"
    w = Writer(path)
    if compression != "none":
        w.set_compression(Writer.CompressionFormat[compression.upper()])
    with w:
        conns = {}
        for topic, sname, _sd, lt, _pt, data in msgs:
            if topic not in conns:
                conns[topic] = w.add_connection(topic, sname, typestore=ros1)
            w.write(conns[topic], lt, ros2.cdr_to_ros1(data, sname))
    log = read_log(path)
    assert log.container == "ros1 bag"
    assert log.imu.frame_id == base.imu.frame_id
    assert_same(log, base)


def test_ros1_profile_mcap(msgs, base, tmp_path):
    # What `mcap convert x.bag` makes: profile ros1, ros1msg schemas, ROS 1 payloads.
    ros2, ros1 = _typestore(), _typestore(ros1=True)
    ros1_msgs = [(t, s, sd, lt, pt, bytes(ros2.cdr_to_ros1(d, s))) for t, s, sd, lt, pt, d in msgs]

    def schema(name, _text):
        short = name.replace("/msg/", "/")
        return short, "ros1msg", ros1.generate_msgdef(name)[0].encode()

    p = write_mcap(
        tmp_path / "r1.mcap", ros1_msgs, schema_of=schema, profile="ros1", encoding="ros1"
    )
    log = read_log(p)
    assert log.container == "ros1 mcap"
    assert_same(log, base)


def test_split_bag_and_file_compression(msgs, base, tmp_path):
    half = len(msgs) // 2
    split = tmp_path / "split"
    split.mkdir()
    write_mcap(split / "s_0.mcap", msgs[:half])
    write_mcap(split / "s_1.mcap", msgs[half:])
    write_metadata(split, ["s_0.mcap", "s_1.mcap"])
    log = read_log(split)
    assert "split in 2 files" in log.container
    assert log.custom_data == {"made.by": "test_logio_formats"}
    assert_same(log, base)
    packed = tmp_path / "packed"
    packed.mkdir()
    for name in ("s_0.mcap", "s_1.mcap"):
        data = zstandard.ZstdCompressor().compress((split / name).read_bytes())
        (packed / f"{name}.zstd").write_bytes(data)
    write_metadata(packed, ["s_0.mcap.zstd", "s_1.mcap.zstd"], mode="file")
    log = read_log(packed)
    assert "file-compressed" in log.container
    assert_same(log, base)
    # a single .mcap.zstd file
    one = tmp_path / "one.mcap.zstd"
    with open(one, "wb") as f, zstandard.ZstdCompressor().stream_writer(f) as z:
        z.write(write_mcap(tmp_path / "one.mcap", msgs).read_bytes())
    assert_same(read_log(one), base)


def test_lz4_and_uncompressed_chunks(msgs, base, tmp_path):
    from mcap.writer import CompressionType

    for comp in (CompressionType.LZ4, CompressionType.NONE):
        p = write_mcap(tmp_path / f"{comp.name}.mcap", msgs, compression=comp, crc=True)
        assert_same(read_log(p), base)


# --------------------------------------------------------------------------- schemas
IDL = {
    "builtin_interfaces/msg/Time": """module builtin_interfaces { module msg {
  struct Time { int32 sec; uint32 nanosec; }; }; };""",
    "std_msgs/msg/Header": """module std_msgs { module msg {
  struct Header { builtin_interfaces::msg::Time stamp; string frame_id; }; }; };""",
    "geometry_msgs/msg/Quaternion": """module geometry_msgs { module msg {
  struct Quaternion { double x; double y; double z; double w; }; }; };""",
    "geometry_msgs/msg/Vector3": """module geometry_msgs { module msg {
  struct Vector3 { double x; double y; double z; }; }; };""",
    "sensor_msgs/msg/Imu": """module sensor_msgs { module msg {
  struct Imu { std_msgs::msg::Header header; geometry_msgs::msg::Quaternion orientation;
    double orientation_covariance[9]; geometry_msgs::msg::Vector3 angular_velocity;
    double angular_velocity_covariance[9]; geometry_msgs::msg::Vector3 linear_acceleration;
    double linear_acceleration_covariance[9]; }; }; };""",
    "sensor_msgs/msg/MagneticField": """module sensor_msgs { module msg {
  struct MagneticField { std_msgs::msg::Header header;
    geometry_msgs::msg::Vector3 magnetic_field; double magnetic_field_covariance[9]; }; }; };""",
    "geometry_msgs/msg/QuaternionStamped": """module geometry_msgs { module msg {
  struct QuaternionStamped { std_msgs::msg::Header header;
    geometry_msgs::msg::Quaternion quaternion; }; }; };""",
}
DEPS = {
    "sensor_msgs/msg/Imu": [
        "std_msgs/msg/Header",
        "geometry_msgs/msg/Quaternion",
        "geometry_msgs/msg/Vector3",
    ],
    "sensor_msgs/msg/MagneticField": ["std_msgs/msg/Header", "geometry_msgs/msg/Vector3"],
    "geometry_msgs/msg/QuaternionStamped": ["std_msgs/msg/Header", "geometry_msgs/msg/Quaternion"],
}


def test_ros2idl_schemas(msgs, base, tmp_path):
    def schema(name, _text):
        names = [name, "builtin_interfaces/msg/Time", *DEPS[name]]
        parts = [IDL[n] for n in names]  # the root first, as rosbag2 writes it
        sep = "=" * 80 + "\n"
        return (
            name,
            "ros2idl",
            "".join(f"{sep}IDL: {n}\n{t}\n" for n, t in zip(names, parts, strict=False)).encode(),
        )

    assert_same(read_log(write_mcap(tmp_path / "idl.mcap", msgs, schema_of=schema)), base)


# -------------------------------------------------------------------------- messages
def _restamp(msgs, topic_from, topic_to, typ, make):
    """Replace the messages of ``topic_from`` by ``make(decoded)`` of type ``typ``."""
    store = _typestore()
    text = store.generate_msgdef(typ, ros_version=2)[0].encode()
    out = []
    for topic, sname, sd, lt, pt, data in msgs:
        if topic == topic_from:
            new = make(store, store.deserialize_cdr(data, sname))
            out.append((topic_to, typ, text, lt, pt, bytes(store.serialize_cdr(new, typ))))
        else:
            out.append((topic, sname, sd, lt, pt, data))
    return out


def test_vector3stamped_gyro(msgs, base, tmp_path):
    def gyro(store, m):
        return store.types["geometry_msgs/msg/Vector3Stamped"](m.header, m.angular_velocity)

    got = _restamp(msgs, IMU, "/gyro", "geometry_msgs/msg/Vector3Stamped", gyro)
    log = read_log(write_mcap(tmp_path / "v.mcap", got))
    assert log.imu.topic == "/gyro" and log.imu.orientation_xyzw is None
    assert log.imu.frame_id == base.imu.frame_id
    assert_same(log, base)


def test_tf_truth_and_truth_frame(msgs, base, tmp_path):
    store = _typestore()
    types = store.types
    still = types["geometry_msgs/msg/Quaternion"](0.0, 0.0, 0.0, 1.0)
    zero = types["geometry_msgs/msg/Vector3"](0.0, 0.0, 0.0)

    def tf(store, m):
        moving = types["geometry_msgs/msg/TransformStamped"](
            m.header, "imu", types["geometry_msgs/msg/Transform"](zero, m.quaternion)
        )
        return types["tf2_msgs/msg/TFMessage"]([moving])

    got = _restamp(msgs, TRUTH, "/tf", "tf2_msgs/msg/TFMessage", tf)
    # a static transform world -> map on /tf_static, and a second moving child on /tf
    hdr = types["std_msgs/msg/Header"](types["builtin_interfaces/msg/Time"](0, 0), "world")
    static = types["tf2_msgs/msg/TFMessage"](
        [
            types["geometry_msgs/msg/TransformStamped"](
                hdr, "map", types["geometry_msgs/msg/Transform"](zero, still)
            )
        ]
    )
    text = store.generate_msgdef("tf2_msgs/msg/TFMessage", ros_version=2)[0].encode()
    raw = bytes(store.serialize_cdr(static, "tf2_msgs/msg/TFMessage"))
    got.insert(0, ("/tf_static", "tf2_msgs/msg/TFMessage", text, got[0][3], got[0][3], raw))
    log = read_log(write_mcap(tmp_path / "tf.mcap", got))
    assert (log.truth.topic, log.truth.child_frame_id, log.truth.auto) == (
        "/tf//tf_static",
        "imu",
        True,
    )
    assert log.truth.frame_id == "world"
    assert_same(log, base)
    asked = read_log(tmp_path / "tf.mcap", truth_frame="map").truth
    np.testing.assert_array_equal(asked.q_w_b, [[0.0, 0.0, 0.0, 1.0]])


def test_two_channels_on_one_topic_are_merged(msgs, base, tmp_path):
    # /imu/data on two channel ids, alternating: every sample, in file order.
    p = write_mcap(
        tmp_path / "two.mcap",
        msgs,
        channel_of=lambda topic, i: (topic, i % 2 if topic == IMU else 0),
    )
    log = read_log(p)
    assert [c.topic for c in log.channels].count(IMU) == 2
    assert_same(log, base)


# ------------------------------------------------------------------- what cannot be read
def test_special_files_are_refused(tmp_path):
    import os

    from imu_dcm.errors import LogError

    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    with raises_naming(LogError, "FIFO", str(fifo)):
        read_log(fifo)
    with pytest.raises(LogError, match="got a character device"):
        read_log("/dev/zero")


def test_unreadable_formats_name_the_fix(tmp_path):
    from imu_dcm.errors import LogError

    old = tmp_path / "old.bag"
    old.write_bytes(b"#ROSBAG V1.2\n" + b"\0" * 64)
    with pytest.raises(LogError, match=r"version 1\.2 .*`rosbag fix old\.bag out\.bag`"):
        read_log(old)
    csv = tmp_path / "gyro.csv"
    csv.write_text("t,x,y,z\n0,1,2,3\n")
    with pytest.raises(LogError, match="convert-csv gyro.csv"):
        read_log(csv)
    bag = tmp_path / "bag"
    bag.mkdir()
    write_metadata(bag, ["x.db"], storage="rocksdb")
    (bag / "x.db").write_bytes(b"\0")
    with raises_naming(LogError, "'rocksdb'", "mcap", "sqlite3", str(bag / "metadata.yaml")):
        read_log(bag)


def test_copy_of_shipped_bag_reads_the_same(tmp_path):
    # The folder path, the file path and a copied folder give the same samples.
    dst = tmp_path / "copy"
    shutil.copytree(SHIPPED, dst)
    a, b = read_log(dst), read_log(next(dst.glob("*.mcap")))
    np.testing.assert_array_equal(a.imu.omega_b, b.imu.omega_b)
    assert a.container == "ros2 mcap" and a.custom_data == b.custom_data != {}


# ---------------------------------------------------------------------------- memory
# VmHWM, not ru_maxrss: Linux keeps ru_maxrss across exec, so a child forked from a big
# pytest process would report the parent's peak.
_PEAK = """
import sys, warnings
warnings.simplefilter("ignore")
from imu_dcm.logio import read_log
log = read_log(sys.argv[1])
hwm = [ln for ln in open("/proc/self/status") if ln.startswith("VmHWM:")][0].split()[1]
print(len(log.imu.t_ns), hwm)
"""


def _peak_kib(path: Path) -> tuple[int, int]:
    import os
    import subprocess
    import sys

    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    out = subprocess.run(
        [sys.executable, "-c", _PEAK, str(path)],
        capture_output=True,
        text=True,
        env=env,
        check=True,
    ).stdout.split()
    return int(out[0]), int(out[1])


@pytest.mark.skipif(not Path("/proc/self/status").is_file(), reason="needs Linux /proc")
def test_a_camera_topic_does_not_raise_peak_memory(tmp_path):
    # The whole trial plus a 10 Hz camera of 48 kB incompressible frames (~88 MB, mixed into
    # the same 768 KiB chunks as the IMU, as rosbag2 records): peak RSS (VmHWM) rises <= 20 %.
    with open(_shipped_mcap(), "rb") as f:
        reader = make_reader(f)
        msgs = [
            (c.topic, s.name, s.data, m.log_time, m.publish_time, m.data)
            for s, c, m in reader.iter_messages()
        ]
    plain = write_mcap(tmp_path / "plain.mcap", msgs, chunk_size=768 * 1024)
    rng = np.random.default_rng(0)
    t0, t1 = msgs[0][3], msgs[-1][3]
    cam = [
        (
            "/camera/image_raw",
            "sensor_msgs/msg/Image",
            b"uint8[] data\n",
            int(t),
            int(t),
            b"\x00\x01\x00\x00" + rng.bytes(48_000),
        )
        for t in range(t0, t1, 100_000_000)
    ]
    mixed = sorted(msgs + cam, key=lambda m: m[3])
    with_cam = write_mcap(tmp_path / "cam.mcap", mixed, chunk_size=768 * 1024)
    del msgs, mixed, cam
    assert with_cam.stat().st_size > plain.stat().st_size + 80e6
    n0, peak0 = _peak_kib(plain)
    n1, peak1 = _peak_kib(with_cam)
    assert n0 == n1 == 52518
    assert peak1 <= 1.2 * peak0, f"peak RSS {peak0} KiB without the camera, {peak1} KiB with"


def test_file_order_and_both_time_bases_are_kept(msgs, base, tmp_path):
    # 1 % of the IMU messages swapped with their neighbour in the file, and every header stamp
    # zero in a second file: the reader returns file order and both time bases untouched
    # (sorting and the choice of time base are the replay's job).
    imu_idx = [i for i, m in enumerate(msgs) if m[0] == IMU]
    swapped = list(msgs)
    for k in range(0, len(imu_idx) - 1, 100):
        a, b = imu_idx[k], imu_idx[k + 1]
        swapped[a], swapped[b] = swapped[b], swapped[a]
    log = read_log(write_mcap(tmp_path / "swapped.mcap", swapped))
    perm = np.arange(len(base.imu.t_ns))
    for k in range(0, len(perm) - 1, 100):
        perm[k], perm[k + 1] = perm[k + 1], perm[k]
    np.testing.assert_array_equal(log.imu.t_ns, base.imu.t_ns[perm])
    np.testing.assert_array_equal(log.imu.log_t_ns, base.imu.log_t_ns[perm])
    np.testing.assert_array_equal(log.imu.omega_b, base.imu.omega_b[perm])
    zeroed = [
        (t, s, sd, lt, pt, d[:4] + bytes(8) + d[12:])
        if t in (IMU, TRUTH)
        else (t, s, sd, lt, pt, d)
        for t, s, sd, lt, pt, d in msgs
    ]
    log = read_log(write_mcap(tmp_path / "zero.mcap", zeroed))
    assert not log.imu.t_ns.any() and not log.truth.t_ns.any()
    np.testing.assert_array_equal(log.imu.log_t_ns, base.imu.log_t_ns)
    np.testing.assert_array_equal(log.imu.omega_b, base.imu.omega_b)

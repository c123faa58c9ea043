"""The ROS 2 bag writer: round trips through two independent readers (mcap + mcap_ros2, and
rosbags), metadata in the layout of the real BROAD bags, atomic output, errors."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Reader as Rosbag2Reader
from rosbags.typesys import Stores, get_typestore
from ruamel.yaml import YAML  # a dependency of rosbags: an independent YAML parser

from imu_dcm.errors import InputError, LogError
from imu_dcm.logio.writers import MSG_DEFINITIONS, TYPE_HASHES, StampedSeries, write_bag

EPOCH_NS = 1_700_000_000_000_000_000
TYPESTORE = get_typestore(Stores.ROS2_HUMBLE)


def _sample(n: int = 500, seed: int = 3):
    """Stamps with an uneven step and a sub-second start, random rates and unit quaternions; the
    first quaternion is 90° about z, [0, 0, √½, √½], the boundary case a wrong order would break."""
    rng = np.random.default_rng(seed)
    t_ns = EPOCH_NS + 123_456_789 + np.cumsum(rng.integers(400_000, 600_000, n)).astype(np.int64)
    w = rng.normal(scale=3.0, size=(n, 3))
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[0] = [0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)]
    v = rng.normal(size=(n, 3))
    return t_ns, w, q, v


def _load_meta(folder: Path) -> dict:
    return YAML(typ="safe").load((folder / "metadata.yaml").read_text())[
        "rosbag2_bagfile_information"
    ]


def _write(tmp_path: Path, **kw) -> Path:
    t_ns, w, q, v = _sample()
    return write_bag(
        tmp_path / "bag",
        imu=StampedSeries(t_ns, w, "imu"),
        quaternions={"/ground_truth/orientation": StampedSeries(t_ns, q, "world")},
        vectors={"/ground_truth/angular_velocity": StampedSeries(t_ns[::2], v[::2], "imu")},
        custom_data={"data_synth.scene": "heavy-top", "data_synth.note": 'it\'s "quoted"'},
        **kw,
    )


def test_round_trip_mcap_ros2_bit_identical(tmp_path):
    t_ns, w, q, v = _sample()
    out = _write(tmp_path)
    assert sorted(p.name for p in out.iterdir()) == ["bag.mcap", "metadata.yaml"]
    got: dict[str, list] = {}
    with open(out / "bag.mcap", "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        assert {s.name: s.encoding for s in summary.schemas.values()} == dict.fromkeys(
            MSG_DEFINITIONS, "ros2msg"
        )
        for _schema, channel, message, decoded in reader.iter_decoded_messages():
            assert channel.message_encoding == "cdr"
            stamp = decoded.header.stamp.sec * 1_000_000_000 + decoded.header.stamp.nanosec
            # log time = publish time = header stamp (like the BROAD bags)
            assert message.log_time == message.publish_time == stamp
            got.setdefault(channel.topic, []).append((stamp, decoded))
    imu = got["/imu/data"]
    assert np.array_equal([s for s, _ in imu], t_ns)
    rates = np.array(
        [[m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z] for _, m in imu]
    )
    assert np.array_equal(rates, w)  # bit-identical, not approximately equal
    m0 = imu[0][1]
    assert m0.header.frame_id == "imu"
    assert m0.orientation_covariance[0] == -1.0 and m0.linear_acceleration_covariance[0] == -1.0
    quats = np.array(
        [
            [m.quaternion.x, m.quaternion.y, m.quaternion.z, m.quaternion.w]
            for _, m in got["/ground_truth/orientation"]
        ]
    )
    assert np.array_equal(quats, q)
    assert got["/ground_truth/orientation"][0][1].header.frame_id == "world"
    vec = got["/ground_truth/angular_velocity"]
    assert np.array_equal([s for s, _ in vec], t_ns[::2])
    assert np.array_equal([[m.vector.x, m.vector.y, m.vector.z] for _, m in vec], v[::2])


def test_multi_chunk_file_indexes_and_crcs(tmp_path):
    """A bag larger than one 1 MiB chunk: CRCs valid, chunk and message indexes point at the
    right records (checked record by record with the mcap library's stream reader)."""
    import zstandard
    from mcap.records import Chunk, ChunkIndex, MessageIndex
    from mcap.stream_reader import StreamReader

    n = 12_000
    t_ns = EPOCH_NS + np.arange(n, dtype=np.int64) * 1_000_000
    rng = np.random.default_rng(9)
    w, v = rng.normal(size=(n, 3)), rng.normal(size=(n // 3, 3))
    out = write_bag(
        tmp_path / "big",
        imu=StampedSeries(t_ns, w, "imu"),
        vectors={"/v": StampedSeries(t_ns[::3], v, "imu")},
    )
    mcap_file = out / "big.mcap"
    with open(mcap_file, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        summary = reader.get_summary()
        assert len(summary.chunk_indexes) > 1
        assert summary.statistics.message_count == n + n // 3
        assert summary.statistics.channel_message_counts == {1: n, 2: n // 3}
        got = [(c.topic, m.log_time) for _, c, m in reader.iter_messages()]
    assert len(got) == n + n // 3 and [t for _, t in got] == sorted(t for _, t in got)

    data = mcap_file.read_bytes()
    with open(mcap_file, "rb") as f:
        records = list(
            StreamReader(f, skip_magic=False, emit_chunks=True, validate_crcs=True).records
        )
    chunks = [r for r in records if isinstance(r, Chunk)]
    assert len(chunks) == len(summary.chunk_indexes)
    checked = 0
    current = None
    for r in records:
        if isinstance(r, Chunk):
            current = zstandard.ZstdDecompressor().decompress(
                r.data, max_output_size=r.uncompressed_size
            )
        elif isinstance(r, MessageIndex):
            for log_time, offset in r.records:
                assert current[offset] == 0x05  # a Message record starts there
                assert int.from_bytes(current[offset + 9 : offset + 11], "little") == r.channel_id
                assert int.from_bytes(current[offset + 15 : offset + 23], "little") == log_time
                checked += 1
    assert checked == n + n // 3
    for ci in summary.chunk_indexes:
        assert isinstance(ci, ChunkIndex) and data[ci.chunk_start_offset] == 0x06
        for offset in ci.message_index_offsets.values():
            assert data[offset] == 0x07
    with AnyReader([out], default_typestore=TYPESTORE) as reader:
        rates = np.array(
            [
                [m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z]
                for m in (
                    reader.deserialize(raw, c.msgtype)
                    for c, _, raw in reader.messages()
                    if c.topic == "/imu/data"
                )
            ]
        )
    assert np.array_equal(rates, w)


def test_round_trip_rosbags_bit_identical(tmp_path):
    t_ns, w, q, _v = _sample()
    out = _write(tmp_path)
    rates, quats, stamps = [], [], []
    with AnyReader([out], default_typestore=TYPESTORE) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        assert types == {
            "/imu/data": "sensor_msgs/msg/Imu",
            "/ground_truth/orientation": "geometry_msgs/msg/QuaternionStamped",
            "/ground_truth/angular_velocity": "geometry_msgs/msg/Vector3Stamped",
        }
        log_times = []
        for con, t, raw in reader.messages():
            log_times.append(t)
            msg = reader.deserialize(raw, con.msgtype)
            if con.topic == "/imu/data":
                stamps.append(msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)
                av = msg.angular_velocity
                rates.append([av.x, av.y, av.z])
            elif con.topic == "/ground_truth/orientation":
                qq = msg.quaternion
                quats.append([qq.x, qq.y, qq.z, qq.w])
    assert np.array_equal(stamps, t_ns)
    assert np.array_equal(rates, w) and np.array_equal(quats, q)
    # Messages are written in stamp order across topics.
    assert np.all(np.diff(log_times) >= 0)


def test_metadata_yaml_matches_rosbag2_v9(tmp_path):
    t_ns, _, _, _ = _sample()
    out = _write(tmp_path)
    with Rosbag2Reader(out) as reader:  # rosbags accepts the folder
        assert reader.message_count == 1250
    meta = _load_meta(out)
    assert meta["version"] == 9 and meta["storage_identifier"] == "mcap"
    assert meta["relative_file_paths"] == ["bag.mcap"]
    assert meta["message_count"] == 500 + 500 + 250
    assert meta["starting_time"]["nanoseconds_since_epoch"] == int(t_ns[0])
    assert meta["duration"]["nanoseconds"] == int(t_ns[-1] - t_ns[0])
    assert meta["custom_data"] == {
        "data_synth.scene": "heavy-top",
        "data_synth.note": 'it\'s "quoted"',
    }
    topics = {t["topic_metadata"]["name"]: t for t in meta["topics_with_message_count"]}
    assert topics["/imu/data"]["message_count"] == 500
    assert topics["/ground_truth/angular_velocity"]["message_count"] == 250
    for t in topics.values():
        md = t["topic_metadata"]
        assert md["serialization_format"] == "cdr"
        assert md["type_description_hash"] == TYPE_HASHES[md["type"]]


def test_metadata_has_the_keys_of_the_broad_bags(tmp_path, broad_dir):
    ref = _load_meta(broad_dir / "02_undisturbed_slow_rotation_B")
    ours = _load_meta(_write(tmp_path))
    assert set(ours) == set(ref)
    assert set(ours["topics_with_message_count"][0]["topic_metadata"]) == set(
        ref["topics_with_message_count"][0]["topic_metadata"]
    )
    assert ours["files"][0].keys() == ref["files"][0].keys()
    assert (
        ours["topics_with_message_count"][0]["topic_metadata"]["offered_qos_profiles"]
        == ref["topics_with_message_count"][0]["topic_metadata"]["offered_qos_profiles"]
    )


def test_definitions_and_hashes_agree_with_rosbags_typestore():
    # An independent source of the ROS 2 message definitions and their REP 2011 hashes.
    for msgtype, text in MSG_DEFINITIONS.items():
        assert TYPESTORE.generate_msgdef(msgtype, ros_version=2)[0] == text
        assert TYPESTORE.hash_rihs01(msgtype) == TYPE_HASHES[msgtype]


def test_acceleration_and_gyro_covariance(tmp_path):
    t_ns, w, _, v = _sample(20)
    cov = np.diag([1e-6, 2e-6, 3e-6])
    out = write_bag(
        tmp_path / "acc",
        imu=StampedSeries(t_ns, w, "imu"),
        imu_linear_acceleration=v,
        imu_angular_velocity_covariance=cov,
    )
    with AnyReader([out], default_typestore=TYPESTORE) as reader:
        msgs = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages()]
    acc = np.array(
        [[m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z] for m in msgs]
    )
    assert np.array_equal(acc, v)
    assert msgs[0].linear_acceleration_covariance[0] == 0.0  # measured: not flagged
    assert np.array_equal(msgs[3].angular_velocity_covariance, cov.ravel())


def test_refuses_existing_output_and_force_replaces(tmp_path):
    out = _write(tmp_path)
    before = (out / "bag.mcap").read_bytes()
    with pytest.raises(LogError, match="bag"):
        _write(tmp_path)
    assert (out / "bag.mcap").read_bytes() == before
    t_ns, w, _, _ = _sample(10)
    write_bag(out, imu=StampedSeries(t_ns, w, "imu"), force=True)
    with Rosbag2Reader(out) as reader:
        assert reader.message_count == 10
    assert [p.name for p in tmp_path.iterdir()] == ["bag"]  # no temporary siblings left


def test_output_is_whole_or_absent(tmp_path, monkeypatch):
    import imu_dcm.logio.writers.bag as bw

    def boom(*a, **k):
        raise RuntimeError("disk full")

    monkeypatch.setattr(bw, "metadata_body", boom)
    with pytest.raises(RuntimeError):
        _write(tmp_path)
    assert list(tmp_path.iterdir()) == []


def test_same_input_same_bytes(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    a, b = _write(tmp_path / "a"), _write(tmp_path / "b")
    assert (a / "bag.mcap").read_bytes() == (b / "bag.mcap").read_bytes()


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({}, "at least one"),
        ({"imu": StampedSeries(np.array([0, 1]), np.zeros((2, 4)), "imu")}, r"\(N, 3\)"),
        ({"imu": StampedSeries(np.array([-5, 1]), np.zeros((2, 3)), "imu")}, r"t_ns\[0\] = -5"),
        (
            {
                "quaternions": {
                    "/q": StampedSeries(
                        np.array([1, 2]), np.array([[0, 0, 0, 1], [np.nan, 0, 0, 1.0]]), "w"
                    )
                }
            },
            "row 1",
        ),
        ({"vectors": {"v": StampedSeries(np.array([1]), np.zeros((1, 3)), "w")}}, "'/'"),
        (
            {"imu": StampedSeries(np.array([1]), np.zeros((1, 3)), "imu"), "custom_data": {"k": 3}},
            "custom_data",
        ),
    ],
)
def test_bad_input_raises_input_error(tmp_path, kwargs, match):
    with pytest.raises(InputError, match=match):
        write_bag(tmp_path / "x", **kwargs)
    assert not (tmp_path / "x").exists()


def test_series_rejects_float_stamps_and_nul_frames():
    with pytest.raises(InputError, match="int64"):
        StampedSeries(np.array([0.5, 1.5]), np.zeros((2, 3)), "imu")
    with pytest.raises(InputError, match="frame_id"):
        StampedSeries(np.array([1]), np.zeros((1, 3)), "im\0u")
    with pytest.raises(InputError, match="UTF-8"):  # a lone surrogate (a str, not text)
        StampedSeries(np.array([1]), np.zeros((1, 3)), "imu\ud800")


@settings(
    max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    frame=st.text(
        st.characters(blacklist_characters="\0", blacklist_categories=("Cs",)),
        min_size=0,
        max_size=12,
    ),
    rows=st.lists(
        st.tuples(*[st.floats(allow_nan=False, allow_infinity=False)] * 4), min_size=1, max_size=6
    ),
    t0=st.integers(min_value=0, max_value=2**31 * 10**9 - 10**6),
)
def test_any_frame_id_and_values_round_trip(tmp_path_factory, frame, rows, t0):
    """Frame ids of every length shift the CDR alignment padding; any finite float (±0,
    subnormals, ±1e308) and any stamp in range must come back bit-identical."""
    vals = np.array(rows, dtype=float)
    t_ns = t0 + np.arange(len(rows), dtype=np.int64)
    out = write_bag(
        tmp_path_factory.mktemp("h") / "bag",
        imu=StampedSeries(t_ns, vals[:, :3], frame),
        quaternions={"/q": StampedSeries(t_ns, vals, frame)},
    )
    seen = {"/imu/data": [], "/q": []}
    with open(out / "bag.mcap", "rb") as f:
        for _, ch, _, m in make_reader(
            f, decoder_factories=[DecoderFactory()]
        ).iter_decoded_messages():
            assert m.header.frame_id == frame
            assert m.header.stamp.sec * 10**9 + m.header.stamp.nanosec in t_ns
            if ch.topic == "/imu/data":
                seen["/imu/data"].append(
                    [m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z]
                )
            else:
                seen["/q"].append([m.quaternion.x, m.quaternion.y, m.quaternion.z, m.quaternion.w])
    assert np.array_equal(np.array(seen["/imu/data"]).view(np.int64), vals[:, :3].view(np.int64))
    assert np.array_equal(np.array(seen["/q"]).view(np.int64), vals.view(np.int64))


def test_chunk_by_chunk_encoding_equals_one_shot(tmp_path):
    """The file's bytes do not depend on how its payloads are built: encoded chunk by chunk
    (4 KiB chunks, the rows of one chunk at a time) equals every payload built up front."""
    import io

    from imu_dcm.logio.writers import bag as writer

    t_ns, w, q, v = _sample(n=900)
    log_t = t_ns + np.random.default_rng(4).integers(0, 3_000_000, t_ns.size)  # out of order
    series = [
        ("/imu", "sensor_msgs/msg/Imu", StampedSeries(t_ns, w, "imu", log_t)),
        ("/q", "geometry_msgs/msg/QuaternionStamped", StampedSeries(t_ns[::2], q[::2], "world")),
        ("/v", "geometry_msgs/msg/Vector3Stamped", StampedSeries(t_ns[1::3], v[1::3], "i")),
    ]
    asked: list[int] = []

    def doubles(s: StampedSeries, imu: bool):
        def rows(r):
            asked.append(len(r))
            return writer.imu_doubles(s.values[r], None, None) if imu else s.values[r]

        return rows

    chunked = [writer._encoded(n, t, s, doubles(s, n == "/imu")) for n, t, s in series]
    whole = []
    for n, t, s in series:
        d = writer.imu_doubles(s.values, None, None) if n == "/imu" else s.values
        rows = writer.cdr_messages(s.t_ns, s.frame_id, d)
        whole.append(writer.Encoded(n, t, s.file_t_ns, rows.shape[1], rows.__getitem__))
    files = []
    for topics in (chunked, whole):
        f = io.BytesIO()
        writer.write_mcap(f, [topics], lambda w: {"k": "v"}, chunk_size=4096)
        files.append(f.getvalue())
    assert files[0] == files[1]
    n_chunks = len(make_reader(io.BytesIO(files[0])).get_summary().chunk_indexes)
    assert n_chunks > 20
    # a chunk of 4 KiB holds at most 4096 / 31 records: no call built more rows than that
    assert max(asked[1:]) <= 4096 // 31 + 1

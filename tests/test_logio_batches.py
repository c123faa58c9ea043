"""MCAP chunks read in batches (several chunks decompressed into one buffer and located at once)
give exactly the samples written, whatever the batch size, and a damaged chunk inside a batch
costs only its own messages."""

from __future__ import annotations

import io
import warnings

import numpy as np
import pytest

from imu_dcm.errors import ImuDcmWarning
from imu_dcm.logio import read_log
from imu_dcm.logio.containers import chunks
from imu_dcm.logio.workers import WORKERS
from imu_dcm.logio.writers import StampedSeries
from imu_dcm.logio.writers import bag as writer

EPOCH_NS = 1_700_000_000_000_000_000


def _log(tmp_path, n: int = 3000):
    """A .mcap of 4 KiB chunks (about 70 of them) with an Imu and a quaternion topic whose
    stamps interleave unevenly; returns its path and the series written."""
    rng = np.random.default_rng(11)
    t = EPOCH_NS + np.cumsum(rng.integers(900_000, 1_100_000, n)).astype(np.int64)
    w = rng.normal(size=(n, 3))
    q = rng.normal(size=(n // 3, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[0] = [0.0, 0.0, np.sqrt(0.5), np.sqrt(0.5)]  # 90° about z: a wrong order would show
    imu = StampedSeries(t, w, "imu")
    truth = StampedSeries(t[::3] + 250_000, q, "world")
    topics = [
        writer._encoded(
            "/imu/data",
            "sensor_msgs/msg/Imu",
            imu,
            writer._imu_topic(imu, "/imu/data", None, None)[3],
        ),
        writer._encoded(
            "/ground_truth/orientation",
            "geometry_msgs/msg/QuaternionStamped",
            truth,
            truth.values.__getitem__,
        ),
    ]
    f = io.BytesIO()
    writer.write_mcap(f, [topics], lambda w: {"k": "v"}, chunk_size=4096)
    path = tmp_path / "log.mcap"
    path.write_bytes(f.getvalue())
    return path, imu, truth


@pytest.mark.parametrize("batch_bytes", [1, 5 * 4096, 1 << 30])
def test_any_batch_size_reads_exactly_what_was_written(tmp_path, monkeypatch, batch_bytes):
    path, imu, truth = _log(tmp_path)
    monkeypatch.setattr(chunks, "BATCH_BYTES", batch_bytes)
    log = read_log(path)
    assert np.array_equal(log.imu.t_ns, imu.t_ns)
    assert np.array_equal(log.imu.omega_b, imu.values)  # bit for bit: no arithmetic on the way
    assert np.array_equal(log.truth.t_ns, truth.t_ns)
    assert np.array_equal(log.truth.q_w_b, truth.values)
    assert log.damage == ()


def test_a_damaged_chunk_inside_a_batch_costs_only_itself(tmp_path, monkeypatch):
    """A byte flipped in the compressed data of a chunk in the middle of a batch: that chunk
    fails (zstd or its CRC), every message of the other chunks of the batch is kept."""
    from mcap.reader import make_reader

    path, imu, _ = _log(tmp_path)
    buf = bytearray(path.read_bytes())
    idx = make_reader(io.BytesIO(bytes(buf))).get_summary().chunk_indexes
    bad = idx[len(idx) // 2]
    buf[bad.chunk_start_offset + bad.chunk_length - bad.compressed_size // 2] ^= 0x41
    path.write_bytes(bytes(buf))
    monkeypatch.setattr(chunks, "BATCH_BYTES", 8 * 4096)  # the damaged chunk among others
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ImuDcmWarning)
        log = read_log(path)
    (damage,) = log.damage
    lost = (imu.t_ns >= bad.message_start_time) & (imu.t_ns <= bad.message_end_time)
    assert lost.sum() > 0 and damage.offset == bad.chunk_start_offset
    assert np.array_equal(log.imu.t_ns, imu.t_ns[~lost])
    assert np.array_equal(log.imu.omega_b, imu.values[~lost])


def _batches(rng, sizes, missing_in=None):
    """Decoded batches of one channel: file-order keys that go back once, two fields."""
    from imu_dcm.logio.ros.collect import Columns

    out, key = [], 0
    for k, n in enumerate(sizes):
        order = key + np.arange(n, dtype=np.int64)
        key += n
        if k == 1:
            order = order - 5  # a batch whose first keys come before the last batch's
        fields = {"t_ns": rng.integers(0, 10**9, n), "omega": rng.normal(size=(n, 3))}
        if k == missing_in:
            del fields["omega"]
        out.append(Columns(order, order * 10, fields, {"frame_id": f"f{k}"}, None, k))
    return out


@pytest.mark.parametrize(
    ("count", "missing_in"),
    [(60, None), (40, None), (None, None), (0, None), (60, 2), (10**15, None)],
    ids=["exact", "count-too-small", "no-count", "zero-count", "field-missing", "count-absurd"],
)
def test_batches_written_into_the_channels_arrays_equal_their_join(count, missing_in):
    # written into arrays of the channel's count as they come, or kept and joined where the
    # count is absent, too small or absurd, or the batches are unlike: the join's result
    from imu_dcm.logio.ros.collect import ColumnsBuilder, join_columns

    make = lambda: _batches(np.random.default_rng(4), [10, 20, 15, 15], missing_in)  # noqa: E731
    built = ColumnsBuilder(count)
    for p in make():
        built.add(p)
    got, want = built.result(), join_columns(make())
    assert np.all(np.diff(got.order) >= 0)  # file order
    for name in ("order", "log_time"):
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name))
    assert got.fields.keys() == want.fields.keys()
    for k, v in want.fields.items():
        assert got.fields[k].dtype == v.dtype
        np.testing.assert_array_equal(got.fields[k], v)
    assert (got.frames, got.dropped) == (want.frames, want.dropped) == ({"frame_id": "f0"}, 6)
    assert ColumnsBuilder(count).result() is None


def test_the_read_heap_thresholds_are_not_set_over_the_environments():
    # glibc's mmap and trim thresholds, set before the first read of a process (a batch's
    # temporaries then come from reused heap, not fresh pages), are never set over a value the
    # environment gives (glibc reads those at start-up).
    from imu_dcm.memory import heap_settings

    assert heap_settings({}) == [(-3, 4 << 20), (-1, 16 << 20)]  # malloc.h's parameter numbers
    assert heap_settings({"GLIBC_TUNABLES": "glibc.pthread.rseq=0"}) == heap_settings({})
    for env in (
        {"MALLOC_MMAP_THRESHOLD_": "131072"},
        {"MALLOC_TRIM_THRESHOLD_": "131072"},
        {"GLIBC_TUNABLES": "glibc.malloc.mmap_threshold=131072"},
    ):
        assert heap_settings(env) == [], env


def test_the_read_threads_are_daemons_that_end_with_the_read(tmp_path, monkeypatch):
    # A signal that raises in the main thread while it starts a thread or waits on a future can
    # leave one of their locks held: the read's threads must then not keep the process from
    # exiting (daemons), and a read that finishes leaves none behind (a fork stays safe).
    import threading

    path, _imu, _truth = _log(tmp_path)
    monkeypatch.setattr(chunks, "BATCH_BYTES", 1 << 14)  # several batches, one report each
    seen: list = []

    def during(_frac: float) -> None:
        seen.append(
            [t.daemon for t in threading.enumerate() if t.name.startswith("imu_dcm-worker")]
        )

    read_log(path, progress=during)
    assert len(seen) > 3 and all(len(s) == WORKERS and all(s) for s in seen[1:-1])
    assert not [t for t in threading.enumerate() if t.name.startswith("imu_dcm-worker")]


@pytest.mark.parametrize("offset", [(1 << 63) - 10, (1 << 64) - 1, 1 << 40])
@pytest.mark.parametrize("batch_bytes", [8 * 4096, 1])
def test_an_index_offset_far_past_its_chunk_costs_nothing(
    tmp_path, monkeypatch, offset, batch_bytes
):
    # A message index entry damaged to point far out of its chunk (near 2^63, where an added
    # header size wraps an int64 negative; 2^64 - 1, read as -1): the batch is read chunk by
    # chunk, the record is found by walking the chunk, and every message is kept.
    from mcap.reader import make_reader

    path, imu, truth = _log(tmp_path)
    buf = bytearray(path.read_bytes())
    chunk = make_reader(io.BytesIO(bytes(buf))).get_summary().chunk_indexes[3]
    at = min(chunk.message_index_offsets.values())  # a message index record of that chunk
    buf[at + 15 + 16 + 8 : at + 15 + 16 + 16] = offset.to_bytes(8, "little")  # entry 1's offset
    path.write_bytes(bytes(buf))
    monkeypatch.setattr(chunks, "BATCH_BYTES", batch_bytes)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ImuDcmWarning)
        log = read_log(path)
    assert np.array_equal(log.imu.t_ns, imu.t_ns)
    assert np.array_equal(log.truth.t_ns, truth.t_ns)


def _imu_payloads(store, rng, n: int):
    """``n`` Imu messages serialised by rosbags (CDR), frame ids of varying length."""
    from imu_dcm.logio.ros.collect import Payloads

    t = store.types
    raw, omega = [], rng.normal(size=(n, 3))
    for i in range(n):
        msg = t["sensor_msgs/msg/Imu"](
            header=t["std_msgs/msg/Header"](
                stamp=t["builtin_interfaces/msg/Time"](sec=1000 + i, nanosec=i),
                frame_id="imu" + "x" * (i % 5),
            ),
            orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=np.full(9, -1.0),
            angular_velocity=t["geometry_msgs/msg/Vector3"](*omega[i]),
            angular_velocity_covariance=np.zeros(9),
            linear_acceleration=t["geometry_msgs/msg/Vector3"](0.0, 0.0, 9.8),
            linear_acceleration_covariance=np.zeros(9),
        )
        raw.append(bytes(store.serialize_cdr(msg, "sensor_msgs/msg/Imu")))
    start = np.cumsum([0] + [len(r) for r in raw[:-1]]).astype(np.int64)
    length = np.array([len(r) for r in raw], np.int64)
    buf = np.frombuffer(b"".join(raw), np.uint8)
    keys = np.arange(n, dtype=np.int64)
    return Payloads(buf, start, length, keys, keys), omega


@pytest.mark.parametrize("count", [None, 35], ids=["kept-as-batches", "written-into-arrays"])
def test_lent_vectors_outlive_the_decoders_next_batch(count):
    # a decoder that lends its words (the vectors are views of them, no second copy) and the
    # next batch decoded into the same words: the channel's columns still hold what rosbags
    # wrote, whether the builder copied the first batch into its arrays or kept it as it came
    from rosbags.typesys import Stores, get_typestore

    from imu_dcm.logio.ros.channels import ChannelDecoder
    from imu_dcm.logio.ros.collect import ColumnsBuilder, Conn

    store = get_typestore(Stores.ROS2_HUMBLE)
    rng = np.random.default_rng(5)
    (a, wa), (b, wb) = _imu_payloads(store, rng, 20), _imu_payloads(store, rng, 15)  # words reused
    b.order = b.order + 20
    conn = Conn(1, "/imu/data", "sensor_msgs/msg/Imu", "cdr")
    lender, owner = ChannelDecoder(conn, "imu", lend=True), ChannelDecoder(conn, "imu")
    first = lender(a)
    assert np.shares_memory(first.fields["omega"], lender.scratch._local.buf)  # a view indeed
    assert not np.shares_memory(owner(a).fields["omega"], owner.scratch._local.buf)
    built = ColumnsBuilder(count)
    built.add(first)
    built.add(lender(b))
    got = built.result()
    np.testing.assert_array_equal(got.fields["omega"], np.concatenate([wa, wb]))
    want = 10**9 * (1000 + np.r_[0:20, 0:15]) + np.r_[0:20, 0:15]
    np.testing.assert_array_equal(got.fields["t_ns"], want)


def test_the_chunk_checksum_is_zlibs_crc32():
    # the fast CRC-32 that checks every chunk is the standard library's, on any length, running
    # value and buffer kind (a chunk's slice of a batch is a memoryview of a numpy array)
    import zlib

    from imu_dcm.logio.checksum import crc32

    rng = np.random.default_rng(8)
    for n in (0, 1, 7, 64, 4099, 1 << 20):
        data = rng.integers(0, 256, n, dtype=np.uint8)
        seed = int(rng.integers(0, 2**32))
        assert crc32(memoryview(data)) == zlib.crc32(data.tobytes())
        assert crc32(data.tobytes(), seed) == zlib.crc32(data.tobytes(), seed)


def _huge_kb(addr: int) -> int:
    """AnonHugePages (kB) of the mapping of this process that holds ``addr``."""
    inside = False
    with open("/proc/self/smaps") as f:
        for line in f:
            head = line.split()[0]
            if "-" in head and not head.endswith(":"):
                lo, hi = (int(x, 16) for x in head.split("-"))
                inside = lo <= addr < hi
            elif inside and head == "AnonHugePages:":
                return int(line.split()[1])
    raise AssertionError("no mapping holds the array")


def test_a_channels_columns_are_written_into_small_pages():
    # written once in order, the columns are asked for ordinary pages before their first touch
    # (no wait for the kernel to compact memory into huge ones); their values are untouched
    import sys
    from pathlib import Path

    from imu_dcm.memory import small_pages

    thp = Path("/sys/kernel/mm/transparent_hugepage/enabled")
    if not sys.platform.startswith("linux") or not thp.exists() or "[never]" in thp.read_text():
        pytest.skip("no transparent huge pages on this system: nothing to ask for")
    a = np.arange(8 << 20, dtype=np.float64)  # 64 MB, touched: its pages are there
    small_pages(a)
    np.testing.assert_array_equal(a, np.arange(8 << 20, dtype=np.float64))
    b = np.empty(8 << 20)
    small_pages(b)
    b[:] = 1.0
    assert _huge_kb(b.__array_interface__["data"][0] + (32 << 20)) == 0


def test_message_indexes_read_whole_in_part_or_alone_give_the_same_entries(tmp_path):
    # a chunk's message indexes are read at once from the region its chunk index gives; a
    # length that understates it (a record whose entries run past it, one outside it) or none
    # at all reads the rest from the file: the same entries, whose log times are those of
    # mcap's own reader, channel by channel
    from mcap.reader import make_reader

    from imu_dcm.logio.containers.mcap.indexed import IndexedReader, read_summary

    path, _imu, _truth = _log(tmp_path)
    size = path.stat().st_size
    times: dict[int, list] = {}
    for _schema, channel, message in make_reader(io.BytesIO(path.read_bytes())).iter_messages():
        times.setdefault(channel.id, []).append(message.log_time)
    with open(path, "rb") as f:
        summary = read_summary(f, size)
        reader = IndexedReader(summary, path, size, None)
        got_times: dict[int, list] = {}
        for k, chunk in enumerate(summary.chunks):
            offsets, ilen = chunk[4], chunk[5]
            whole = reader._message_index(f, offsets, ilen)
            assert sorted(whole) == sorted(offsets)
            for cid, (_offs, t) in whole.items():
                got_times.setdefault(cid, []).extend(t.tolist())
            if k not in (0, 5, len(summary.chunks) - 1):
                continue
            for part in (ilen - 20, 20, 0):  # entries past the region; a header past it; none
                got = reader._message_index(f, offsets, part)
                assert sorted(got) == sorted(whole), part
                for cid, (offs, t) in whole.items():
                    assert np.array_equal(got[cid][0], offs) and np.array_equal(got[cid][1], t)
    assert {c: sorted(v) for c, v in got_times.items()} == {c: sorted(v) for c, v in times.items()}

"""Write ROS 2 bags (MCAP storage) of IMU rates, quaternions and vectors, fast and atomically.

The output is a rosbag2 folder in the layout of recorded ROS 2 logs: ``metadata.yaml``
(rosbag2 format version 9) and one ``<folder name>.mcap`` file with profile ``ros2``, CDR
messages, their ``ros2msg`` definitions embedded as schemas, zstd chunks, and the rosbag2
metadata record. Readable by the project's reader, by ``mcap`` + ``mcap-ros2-support`` and by
``rosbags``. ``metadata.yaml`` is written by :mod:`imu_dcm.logio.meta` (the one module that reads
and writes it).

Message types and conventions:

* IMU rates: ``sensor_msgs/msg/Imu``, ``angular_velocity`` = ``omega_b`` (rad/s, body axes);
  ``orientation = (0, 0, 0, 1)`` with ``orientation_covariance[0] = -1`` (no orientation);
  ``linear_acceleration_covariance[0] = -1`` unless an acceleration is given.
* Quaternions: ``geometry_msgs/msg/QuaternionStamped``, ``[x, y, z, w]`` as given (``q_w_b``).
* Vectors: ``geometry_msgs/msg/Vector3Stamped``.

Header stamps come from ``t_ns`` (int64 ns since the Unix epoch); MCAP ``log_time`` and
``publish_time`` equal the header stamp unless a series gives its own ``log_t_ns`` (to build
logs whose receive times differ from their stamps). Messages are written in log-time order
across topics.

Output safety (:mod:`imu_dcm.outputs`): the bag never replaces an input, a folder holding one,
or a special file; ``force`` replaces only a bag this module wrote (its MCAP header names the
library ``imu_dcm.bag_writer``, the module's name before it moved into :mod:`imu_dcm.logio`:
bags written then stay replaceable).

Speed: the fixed-layout CDR payloads and the MCAP message records and message indexes are built
in bulk with numpy (one byte array per topic and chunk), each chunk is built, compressed and
written before the next (memory holds the input series and one chunk, never every payload),
and only the few summary records go through ``mcap.records``. Measured here: 150 000 messages
(50 000 each of Imu, QuaternionStamped, Vector3Stamped) in ~0.3 s, against ~1.5 s through
``mcap.writer.Writer`` with the same payloads and 44 µs per Imu message through
``mcap_ros2.writer``.
"""

from __future__ import annotations

import os
import shutil
import struct
import uuid
import zlib
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from itertools import pairwise
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imu_dcm.errors import InputError
from imu_dcm.logio.meta import QOS_YAML, TYPE_HASHES, metadata_body, metadata_document
from imu_dcm.outputs import OutputError, check_output_dir, ensure_parent

__all__ = [
    "MSG_DEFINITIONS",
    "OWN_LIBRARY",
    "TYPE_HASHES",
    "StampedSeries",
    "cdr_messages",
    "imu_doubles",
    "write_bag",
]

#: The library named in the MCAP header of the bags written here (see the module doc).
OWN_LIBRARY = "imu_dcm.bag_writer"

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

_MAX_T_NS = (2**31) * 10**9  # header.stamp.sec is an int32


@dataclass(frozen=True)
class StampedSeries:
    """Stamped samples for one topic.

    Attributes
    ----------
    t_ns : ndarray of int64, shape (N,)
        Header stamps, ns since the Unix epoch (>= 0); also the MCAP log and publish times.
    values : ndarray of float64, shape (N, k)
        Samples: ``k = 3`` for rates (rad/s, body axes) and vectors, ``k = 4`` for quaternions
        ``[x, y, z, w]``.
    frame_id : str
        ``header.frame_id`` (e.g. ``"imu"``, ``"world"``).
    log_t_ns : ndarray of int64, shape (N,), optional
        MCAP log (receive) times when they differ from the header stamps (default: equal).
        Messages are written in log-time order, so header stamps may then be out of file order.
    """

    t_ns: NDArray[np.int64]
    values: NDArray[np.float64]
    frame_id: str
    log_t_ns: NDArray[np.int64] | None = None

    def __post_init__(self) -> None:
        t = np.asarray(self.t_ns)
        if t.ndim != 1 or not np.issubdtype(t.dtype, np.integer):
            raise InputError(
                f"Expected `t_ns` an int64 array of shape (N,), got {t.dtype} of shape {t.shape}"
            )
        v = np.asarray(self.values, dtype=np.float64)
        if v.ndim != 2 or v.shape[0] != t.shape[0]:
            raise InputError(f"Expected `values` of shape (N={t.shape[0]}, k), got {v.shape}")
        if not isinstance(self.frame_id, str) or "\0" in self.frame_id:
            raise InputError(f"Expected `frame_id` a str without NUL, got {self.frame_id!r}")
        object.__setattr__(self, "t_ns", t.astype(np.int64, copy=False))
        object.__setattr__(self, "values", v)
        if self.log_t_ns is not None:
            lt = np.asarray(self.log_t_ns)
            if lt.shape != t.shape or not np.issubdtype(lt.dtype, np.integer):
                raise InputError(
                    f"Expected `log_t_ns` an int64 array of shape {t.shape}, got "
                    f"{lt.dtype} of shape {lt.shape}"
                )
            object.__setattr__(self, "log_t_ns", lt.astype(np.int64, copy=False))

    @property
    def file_t_ns(self) -> NDArray[np.int64]:
        """The MCAP log times: ``log_t_ns`` when given, else the header stamps."""
        return self.t_ns if self.log_t_ns is None else self.log_t_ns


def _check_series(name: str, s: StampedSeries, k: int) -> None:
    if not isinstance(s, StampedSeries):
        raise InputError(f"Expected {name} a StampedSeries, got {type(s).__name__}")
    if s.values.shape[1] != k:
        raise InputError(f"Expected {name} values of shape (N, {k}), got {s.values.shape}")
    if s.t_ns.size == 0:
        raise InputError(f"Expected {name} to hold at least one sample, got none")
    for label, t in (("t_ns", s.t_ns), ("log_t_ns", s.file_t_ns)):
        bad = np.flatnonzero((t < 0) | (t >= _MAX_T_NS))
        if bad.size:
            raise InputError(
                f"Expected {name} stamps in [0, 2^31 s) ns, got {label}[{bad[0]}] "
                f"= {int(t[bad[0]])}"
            )
    finite = np.isfinite(s.values).all(axis=1)
    if not finite.all():
        i = int(np.argmin(finite))
        raise InputError(f"Expected {name} finite values, got row {i} = {s.values[i].tolist()}")


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


def _u8le(values: NDArray, width: int) -> NDArray[np.uint8]:
    """Little-endian bytes of unsigned integers, shape (n, width)."""
    dt = {2: "<u2", 4: "<u4", 8: "<u8"}[width]
    return np.ascontiguousarray(values, dtype=dt).view(np.uint8).reshape(-1, width)


# ------------------------------------------------------------------------------- MCAP file
_MAGIC = b"\x89MCAP0\r\n"


class Encoded:
    """One channel to write: its messages' MCAP log times and how to build their CDR payloads.

    ``payloads(rows)`` returns the (len(rows), ``size``) CDR payload bytes of the messages
    ``rows`` (indices into ``t_ns``), so a file is encoded one chunk at a time and never holds
    every payload at once.
    """

    __slots__ = ("topic", "msgtype", "t_ns", "size", "payloads")

    def __init__(self, topic: str, msgtype: str, t_ns: NDArray[np.int64], size: int, payloads):
        self.topic, self.msgtype, self.t_ns, self.size = topic, msgtype, t_ns, size
        self.payloads = payloads


@dataclass(frozen=True)
class _Messages:
    """Where every message record of the file goes, in (log time, topic) order.

    ``stamps`` (log times), ``chan`` (0-based topic index), ``row`` (the message's index in its
    topic) and ``ends`` (byte offset after its record, counted from the first record) have one
    entry per message, in file order; ``sizes`` is the record size of each topic.
    """

    stamps: NDArray[np.int64]
    chan: NDArray[np.uint16]
    row: NDArray[np.int64]
    ends: NDArray[np.int64]
    sizes: NDArray[np.int64]

    def starts(self, a: int, b: int) -> NDArray[np.int64]:
        return self.ends[a:b] - self.sizes[self.chan[a:b]]


def _schemas_and_channels(topics: list[Encoded]) -> tuple[dict, list]:
    """mcap Schema records (one per type, ``ros2msg``) and Channel records (ids from 1)."""
    from mcap.records import Channel, Schema

    schemas: dict[str, Schema] = {}
    channels: list[Channel] = []
    for cid, t in enumerate(topics, start=1):
        name, msgtype = t.topic, t.msgtype
        if msgtype not in schemas:
            schemas[msgtype] = Schema(
                id=len(schemas) + 1,
                name=msgtype,
                encoding="ros2msg",
                data=MSG_DEFINITIONS[msgtype].encode(),
            )
        channels.append(
            Channel(
                id=cid,
                topic=name,
                message_encoding="cdr",
                schema_id=schemas[msgtype].id,
                metadata={"offered_qos_profiles": QOS_YAML},
            )
        )
    return schemas, channels


def _message_order(topics: list[Encoded]) -> _Messages:
    """The file order of all messages (merged by log time, stable across topics)."""
    stamps = np.concatenate([t.t_ns for t in topics])
    order = np.argsort(stamps, kind="stable")
    stamps = stamps[order]
    first = np.cumsum([0] + [t.t_ns.size for t in topics])
    chan = (np.searchsorted(first, order, side="right") - 1).astype(np.uint16)
    row = order - first[chan]
    del order
    sizes = np.array([31 + t.size for t in topics], dtype=np.int64)
    return _Messages(stamps, chan, row, np.cumsum(sizes[chan]), sizes)


def _records(topic: Encoded, cid: int, rows: NDArray[np.int64]) -> NDArray[np.uint8]:
    """Message records (opcode 0x05) of ``rows`` of one topic, one row of bytes each."""
    payload = topic.payloads(rows)
    n, size = payload.shape
    rec = np.empty((n, 31 + size), dtype=np.uint8)
    rec[:, 0] = 0x05  # opcode Message
    rec[:, 1:9] = _u8le(np.full(n, 22 + size), 8)  # record length
    rec[:, 9:11] = _u8le(np.full(n, cid), 2)  # channel id
    rec[:, 11:15] = 0  # sequence
    rec[:, 15:23] = _u8le(topic.t_ns[rows], 8)  # log time
    rec[:, 23:31] = rec[:, 15:23]  # publish time
    rec[:, 31:] = payload
    return rec


def _chunk_body(topics: list[Encoded], m: _Messages, a: int, b: int) -> bytes:
    """The records of messages ``[a, b)`` in file order, built in bulk per topic."""
    starts = m.starts(a, b)
    lo = int(starts[0])
    body = np.empty(int(m.ends[b - 1]) - lo, dtype=np.uint8)
    chan = m.chan[a:b]
    for i in np.unique(chan).tolist():
        sel = np.flatnonzero(chan == i)
        rec = _records(topics[i], i + 1, m.row[a:b][sel])
        # rows of record bytes placed at their offsets: one copy per record
        places = np.lib.stride_tricks.as_strided(
            body, (len(body) - rec.shape[1] + 1, rec.shape[1]), (1, 1), writeable=True
        )
        places[starts[sel] - lo] = rec
    return body.tobytes()


def _chunk_bounds(m: _Messages, chunk_size: int) -> list[int]:
    """Message indices where chunks start (and the end): a chunk closes at ``chunk_size``."""
    bounds = [0]
    while bounds[-1] < m.stamps.size:
        a = bounds[-1]
        start = int(m.ends[a]) - int(m.sizes[m.chan[a]])
        j = int(np.searchsorted(m.ends, start + chunk_size, side="left")) + 1
        bounds.append(min(max(j, a + 1), m.stamps.size))
    return bounds


def _message_indexes(m: _Messages, a: int, b: int, lo: int, pos: int, index) -> bytes:
    """The message index records (0x07) following the chunk of messages ``[a, b)``."""
    parts: list[bytes] = []
    sub_chan = m.chan[a:b]
    starts = m.starts(a, b)
    for i in np.unique(sub_chan).tolist():
        sel = np.flatnonzero(sub_chan == i)
        pairs = np.empty((sel.size, 16), dtype=np.uint8)
        pairs[:, :8] = _u8le(m.stamps[a:b][sel], 8)
        pairs[:, 8:] = _u8le(starts[sel] - lo, 8)
        head = struct.pack("<BQHI", 0x07, 2 + 4 + 16 * sel.size, i + 1, 16 * sel.size)
        index.message_index_offsets[i + 1] = pos + sum(len(p) for p in parts)
        parts.append(head + pairs.tobytes())
    return b"".join(parts)


def _write_chunks(f, out, topics: list[Encoded], m: _Messages, chunk_size: int) -> list:
    """Write the zstd chunks, each followed by its message indexes; returns the chunk indexes.

    Each chunk's records are built, compressed and written before the next one's: memory
    holds one chunk, not the file.
    """
    import zstandard
    from mcap.records import Chunk, ChunkIndex

    pos = f.tell()
    compressor = zstandard.ZstdCompressor()
    chunk_indexes: list[ChunkIndex] = []
    for a, b in pairwise(_chunk_bounds(m, chunk_size)):
        lo = int(m.ends[a]) - int(m.sizes[m.chan[a]])
        raw = _chunk_body(topics, m, a, b)
        data = compressor.compress(raw)
        t0, t1 = int(m.stamps[a:b].min()), int(m.stamps[a:b].max())
        Chunk(
            compression="zstd",
            data=data,
            message_start_time=t0,
            message_end_time=t1,
            uncompressed_crc=zlib.crc32(raw),
            uncompressed_size=len(raw),
        ).write(out)
        chunk_bytes = out.end()
        index = ChunkIndex(
            message_start_time=t0,
            message_end_time=t1,
            chunk_start_offset=pos,
            chunk_length=len(chunk_bytes),
            message_index_offsets={},
            message_index_length=0,
            compression="zstd",
            compressed_size=len(data),
            uncompressed_size=len(raw),
        )
        f.write(chunk_bytes)
        pos += len(chunk_bytes)
        idx = _message_indexes(m, a, b, lo, pos, index)
        index.message_index_length = len(idx)
        f.write(idx)
        pos += len(idx)
        chunk_indexes.append(index)
    return chunk_indexes


def _write_summary(f, out, summary_groups: list[tuple[int, list]]) -> None:
    """The summary section (record groups, then their summary offsets) and the footer."""
    from mcap.data_stream import RecordBuilder
    from mcap.records import Footer, SummaryOffset

    summary_start = f.tell()
    summary = RecordBuilder()
    groups = []
    for opcode, records in summary_groups:
        start = summary.count
        for r in records:
            r.write(summary)
        groups.append(
            SummaryOffset(
                group_opcode=opcode,
                group_start=summary_start + start,
                group_length=summary.count - start,
            )
        )
    summary_offset_start = summary_start + summary.count
    for g in groups:
        g.write(summary)
    summary_bytes = summary.end()
    crc = zlib.crc32(summary_bytes)
    crc = zlib.crc32(struct.pack("<BQQQ", 0x02, 20, summary_start, summary_offset_start), crc)
    f.write(summary_bytes)
    Footer(
        summary_start=summary_start, summary_offset_start=summary_offset_start, summary_crc=crc
    ).write(out)
    f.write(out.end() + _MAGIC)


def write_mcap(
    f, topics: list[Encoded], metadata: dict[str, str], chunk_size: int = 1 << 20
) -> None:
    """Write an indexed MCAP file (profile ros2, zstd chunks) with all records built in bulk.

    ``topics`` holds one :class:`Encoded` per channel; each chunk's payloads are built when it
    is written (the bytes do not depend on how the payloads are produced). Schemas and channels
    are written in the data section and repeated in the summary; every chunk is followed by
    its message indexes; the summary has statistics, chunk and metadata indexes and summary
    offsets (the layout of the mcap library's own writer).
    """
    from mcap.data_stream import RecordBuilder
    from mcap.records import DataEnd, Header, Metadata, MetadataIndex, Statistics

    schemas, channels = _schemas_and_channels(topics)
    m = _message_order(topics)
    out = RecordBuilder()
    Header(profile="ros2", library=OWN_LIBRARY).write(out)
    for record in (*schemas.values(), *channels):
        record.write(out)
    f.write(_MAGIC + out.end())
    chunk_indexes = _write_chunks(f, out, topics, m, chunk_size)
    Metadata(name="rosbag2", metadata=metadata).write(out)
    meta_bytes = out.end()
    meta_index = MetadataIndex(offset=f.tell(), length=len(meta_bytes), name="rosbag2")
    f.write(meta_bytes)
    DataEnd(data_section_crc=0).write(out)
    f.write(out.end())
    stats = Statistics(
        message_count=int(m.stamps.size),
        schema_count=len(schemas),
        channel_count=len(channels),
        attachment_count=0,
        metadata_count=1,
        chunk_count=len(chunk_indexes),
        message_start_time=int(m.stamps[0]),
        message_end_time=int(m.stamps[-1]),
        channel_message_counts={i + 1: int(t.t_ns.size) for i, t in enumerate(topics)},
    )
    groups = [
        (0x03, list(schemas.values())),
        (0x04, channels),
        (0x0B, [stats]),
        (0x08, chunk_indexes),
        (0x0D, [meta_index]),
    ]
    _write_summary(f, out, groups)


# ------------------------------------------------------------------------------- the bag
#: (topic, msgtype, series, rows -> the float64 after each of those messages' headers)
_Topic = tuple[str, str, StampedSeries, Callable[[NDArray[np.int64]], NDArray[np.float64]]]


def _imu_topic(
    imu: StampedSeries, imu_topic: str, accel: ArrayLike | None, cov: ArrayLike | None
) -> _Topic:
    """The IMU topic's row, its acceleration and gyro covariance checked."""
    _check_series(f"imu ({imu_topic})", imu, 3)
    a = None
    if accel is not None:
        a = np.asarray(accel, dtype=float)
        if a.shape != imu.values.shape or not np.all(np.isfinite(a)):
            raise InputError(
                f"Expected finite imu_linear_acceleration of shape "
                f"{imu.values.shape}, got {a.shape}"
            )
    c = None
    if cov is not None:
        c = np.asarray(cov, dtype=float)
        if c.shape != (3, 3):
            raise InputError(
                f"Expected imu_angular_velocity_covariance of shape (3, 3), got {c.shape}"
            )

    def doubles(rows: NDArray[np.int64]) -> NDArray[np.float64]:
        return imu_doubles(imu.values[rows], None if a is None else a[rows], c)

    return (imu_topic, "sensor_msgs/msg/Imu", imu, doubles)


def _check_topic_names(topics: list[_Topic]) -> None:
    if not topics:
        raise InputError("Expected at least one of imu, quaternions, vectors, got none")
    names = [t[0] for t in topics]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise InputError(f"Expected distinct topic names, got {dup} more than once")
    for name in names:
        if not name.startswith("/"):
            raise InputError(f"Expected topic names starting with '/', got {name!r}")


def _encoded(topic: str, msgtype: str, s: StampedSeries, doubles) -> Encoded:
    """A topic's channel, its CDR payloads built for the rows each chunk asks for."""
    width = doubles(np.zeros(1, np.int64)).shape[1]
    size = cdr_messages(np.zeros(1, np.int64), s.frame_id, np.zeros((1, width))).shape[1]

    def payloads(rows: NDArray[np.int64]) -> NDArray[np.uint8]:
        return cdr_messages(s.t_ns[rows], s.frame_id, doubles(rows))

    return Encoded(topic, msgtype, s.file_t_ns, size, payloads)


def _write_into(folder: Path, name: str, topics: list[_Topic], custom: dict[str, str]) -> None:
    """``<name>.mcap`` and ``metadata.yaml`` of the bag, written into ``folder``."""
    mcap_name = f"{name}.mcap"
    stamps = np.concatenate([t[2].file_t_ns for t in topics])
    counts = [(t[0], t[1], int(t[2].t_ns.size)) for t in topics]
    body = metadata_body(mcap_name, counts, int(stamps.min()), int(stamps.max()), custom)
    encoded = [_encoded(*t) for t in topics]
    with open(folder / mcap_name, "wb") as f:
        write_mcap(f, encoded, {"serialized_metadata": body})
    (folder / "metadata.yaml").write_text(metadata_document(body), encoding="utf-8")


def _swap_in(tmp: Path, out: Path) -> None:
    """Rename the finished ``tmp`` to ``out``; an existing ``out`` (our own bag) is replaced."""
    if out.exists():  # force, and it is our own bag: swap in, then remove the old one
        old = out.parent / f".{out.name}.old-{os.getpid()}-{uuid.uuid4().hex[:8]}"
        os.rename(out, old)
        os.rename(tmp, out)
        shutil.rmtree(old)
    else:
        os.rename(tmp, out)


def _write_atomic(out: Path, topics: list[_Topic], custom: dict, inputs: tuple, force: bool):
    """Write the bag under a temporary sibling name, then swap it in (whole or not at all)."""
    tmp = out.parent / f".{out.name}.tmp-{os.getpid()}-{uuid.uuid4().hex[:8]}"
    try:
        ensure_parent(out, "output bag")  # e.g. --out out/top in a fresh checkout
        tmp.mkdir()
    except OSError as exc:
        raise OutputError(
            f"Expected to create the output bag {str(out)!r}, got "
            f"{type(exc).__name__}: {exc.strerror}"
        ) from None
    try:
        _write_into(tmp, out.name, topics, custom)
        check_output_dir(out, inputs, force=force, what="output bag")  # unchanged meanwhile
        _swap_in(tmp, out)
    except OSError as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        raise OutputError(
            f"Expected to write the output bag {str(out)!r}, got "
            f"{type(exc).__name__}: {exc.strerror or exc}"
        ) from None
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def write_bag(
    out_dir: str | os.PathLike,
    *,
    imu: StampedSeries | None = None,
    quaternions: Mapping[str, StampedSeries] | None = None,
    vectors: Mapping[str, StampedSeries] | None = None,
    imu_topic: str = "/imu/data",
    imu_linear_acceleration: ArrayLike | None = None,
    imu_angular_velocity_covariance: ArrayLike | None = None,
    custom_data: Mapping[str, str] | None = None,
    force: bool = False,
    inputs: Iterable[str | os.PathLike] = (),
) -> Path:
    """Write a rosbag2 folder (MCAP storage) atomically.

    Parameters
    ----------
    out_dir : path
        Bag folder to create; it appears whole or not at all (written under a temporary sibling
        name, renamed at the end).
    imu : StampedSeries, optional
        Gyro rates ``omega_b`` (N, 3), rad/s, body axes, on ``imu_topic`` as
        ``sensor_msgs/msg/Imu``.
    quaternions : dict of topic -> StampedSeries, optional
        ``geometry_msgs/msg/QuaternionStamped`` topics, values (N, 4) ``[x, y, z, w]``.
    vectors : dict of topic -> StampedSeries, optional
        ``geometry_msgs/msg/Vector3Stamped`` topics, values (N, 3).
    imu_topic : str
        Topic of the IMU messages.
    imu_linear_acceleration : array_like, shape (N, 3), optional
        Specific force, m/s², body axes, aligned with ``imu``; ``None``: not measured
        (``linear_acceleration_covariance[0] = -1``).
    imu_angular_velocity_covariance : array_like, shape (3, 3), optional
        ``angular_velocity_covariance``, (rad/s)²; ``None``: zeros (unknown).
    custom_data : dict of str -> str, optional
        Recorded in ``metadata.yaml`` ``custom_data`` (and in the MCAP's rosbag2 record).
    force : bool
        Replace an existing ``out_dir``, only if it is a bag this function wrote
        (:func:`imu_dcm.outputs.is_own_bag`).
    inputs : iterable of path
        Paths that must survive: ``out_dir`` may not be, hold or lie inside any of them.

    Returns
    -------
    Path
        ``out_dir``.

    Raises
    ------
    LogError
        (:class:`imu_dcm.outputs.OutputError`) If ``out_dir`` exists and ``force`` is false,
        exists and is not a bag written here, is or holds an input, is a special file, its
        parent folder is missing or read-only, or writing fails.
    InputError
        For a malformed series (shape, non-finite value, stamp out of range), no topics at all,
        a duplicated topic, or a non-string ``custom_data`` entry.
    """
    inputs = tuple(inputs)
    out = check_output_dir(out_dir, inputs, force=force, what="output bag")
    custom = dict(custom_data or {})
    for k, v in custom.items():
        if not isinstance(k, str) or not isinstance(v, str):
            raise InputError(f"Expected custom_data str -> str, got {k!r}: {type(v).__name__}")
    topics: list[_Topic] = []
    if imu is not None:
        topics.append(
            _imu_topic(imu, imu_topic, imu_linear_acceleration, imu_angular_velocity_covariance)
        )
    for name, s in dict(quaternions or {}).items():
        _check_series(f"quaternions[{name!r}]", s, 4)
        topics.append((name, "geometry_msgs/msg/QuaternionStamped", s, s.values.__getitem__))
    for name, s in dict(vectors or {}).items():
        _check_series(f"vectors[{name!r}]", s, 3)
        topics.append((name, "geometry_msgs/msg/Vector3Stamped", s, s.values.__getitem__))
    _check_topic_names(topics)
    _write_atomic(out, topics, custom, inputs, force)
    return out

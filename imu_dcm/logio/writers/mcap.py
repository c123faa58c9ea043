"""An indexed MCAP file (profile ``ros2``, zstd chunks) with every record built in bulk.

The MCAP message records and message indexes are built with numpy (one byte array per topic
and chunk); each chunk is built, then compressed on a worker thread while the next ones are
built, and written in order (memory holds the input series and a few chunks, never every
payload), and only the few summary records go through
``mcap.records``. The layout is the mcap library's own writer's: schemas and channels in the
data section and again in the summary, message indexes after every chunk, the rosbag2 metadata
record, statistics, chunk and metadata indexes, summary offsets. A file can be written a block
of messages at a time (each block's chunks written before the next block is made), so a long
log never needs to be in memory whole. Measured here: 150 000 messages
(50 000 each of Imu, QuaternionStamped, Vector3Stamped) in ~0.3 s, against ~1.5 s through
``mcap.writer.Writer`` with the same payloads and 44 µs per Imu message through
``mcap_ros2.writer``.
"""

from __future__ import annotations

import struct
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from itertools import pairwise

import numpy as np
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.records import (
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)
from numpy.typing import NDArray

from imu_dcm.errors import InputError
from imu_dcm.logio.checksum import crc32
from imu_dcm.logio.meta import QOS_YAML
from imu_dcm.logio.paths import MCAP_MAGIC as MAGIC
from imu_dcm.logio.workers import WORKERS, Workers
from imu_dcm.logio.writers.messages import MSG_DEFINITIONS

__all__ = ["OWN_LIBRARY", "Encoded", "Written", "write_mcap"]

#: The library named in the MCAP header of the bags written here (see :mod:`.bag`: a bag
#: naming it is one ``force`` may replace).
OWN_LIBRARY = "imu_dcm.bag_writer"


def _u8le(values: NDArray, width: int) -> NDArray[np.uint8]:
    """Little-endian bytes of unsigned integers, shape (n, width)."""
    dt = {2: "<u2", 4: "<u4", 8: "<u8"}[width]
    return np.ascontiguousarray(values, dtype=dt).view(np.uint8).reshape(-1, width)


@dataclass(slots=True, frozen=True)
class Encoded:
    """One channel to write: its messages' MCAP log times and how to build their CDR payloads.

    ``payloads(rows)`` returns the (len(rows), ``size``) CDR payload bytes of the messages
    ``rows`` (indices into ``t_ns``), so a file is encoded one chunk at a time and never holds
    every payload at once.
    """

    topic: str
    msgtype: str
    t_ns: NDArray[np.int64]
    size: int
    payloads: Callable[[NDArray[np.int64]], NDArray[np.uint8]]


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


def _compressed(raw: bytes) -> tuple[bytes, int]:
    """A chunk's records zstd-compressed (level 3, zstd's default) and their CRC-32 (both
    release the GIL: run on a worker thread)."""
    return zstandard.ZstdCompressor().compress(raw), crc32(raw)


def _write_chunks(f, out, topics: list[Encoded], m: _Messages, chunk_size: int) -> list:
    """Write the zstd chunks of one block's messages, each followed by its message indexes;
    returns the chunk indexes.

    Each chunk's records are built on this thread, compressed on a worker
    (:class:`imu_dcm.logio.workers.Workers`) while the next ones are built, and written in
    order: memory holds a few chunks, not the file.
    """
    pos = f.tell()
    chunk_indexes: list[ChunkIndex] = []
    pending: deque = deque()  # (a, b, raw, future) of the chunks built, in order

    def write_next() -> None:
        nonlocal pos
        a, b, raw, fut = pending.popleft()
        data, crc = fut.result()
        lo = int(m.ends[a]) - int(m.sizes[m.chan[a]])
        t0, t1 = int(m.stamps[a:b].min()), int(m.stamps[a:b].max())
        Chunk(
            compression="zstd",
            data=data,
            message_start_time=t0,
            message_end_time=t1,
            uncompressed_crc=crc,
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

    pool, finished = Workers(), False
    try:
        for a, b in pairwise(_chunk_bounds(m, chunk_size)):
            raw = _chunk_body(topics, m, a, b)
            pending.append((a, b, raw, pool.submit(_compressed, raw)))
            if len(pending) > WORKERS:  # the workers busy: write the oldest
                write_next()
        while pending:
            write_next()
        finished = True
    finally:
        for *_, fut in pending:
            fut.cancel()
        pool.stop(wait=finished)
    return chunk_indexes


@dataclass
class Written:
    """What :func:`write_mcap` wrote: messages per channel (in the order of the topics), and
    the first and last log time, ns."""

    counts: list[int]
    t_min_ns: int
    t_max_ns: int


def _same_channels(first: list[Encoded], block: list[Encoded], k: int) -> None:
    got = [(t.topic, t.msgtype) for t in block]
    want = [(t.topic, t.msgtype) for t in first]
    if got != want:
        raise InputError(f"Expected block {k} to hold the channels {want} of block 0, got {got}")


def _write_summary(f, out, summary_groups: list[tuple[int, list]]) -> None:
    """The summary section (record groups, then their summary offsets) and the footer."""
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
    crc = crc32(summary_bytes)
    crc = crc32(struct.pack("<BQQQ", 0x02, 20, summary_start, summary_offset_start), crc)
    f.write(summary_bytes)
    Footer(
        summary_start=summary_start, summary_offset_start=summary_offset_start, summary_crc=crc
    ).write(out)
    f.write(out.end() + MAGIC)


def write_mcap(
    f,
    blocks: Iterable[list[Encoded]],
    metadata: Callable[[Written], dict[str, str]],
    chunk_size: int = 1 << 20,
) -> Written:
    """Write an indexed MCAP file (profile ros2, zstd chunks) with all records built in bulk.

    ``blocks`` yields the messages a block at a time, each block one :class:`Encoded` per
    channel (the same channels, in the same order, in every block), each block's log times at
    or after the block before's; a block's chunks are built and written before the next block
    is asked for, so memory holds one block, not the file. ``metadata(written)`` gives the
    rosbag2 metadata record once every message is written. Schemas and channels are written in
    the data section and repeated in the summary; every chunk is followed by its message
    indexes; the summary has statistics, chunk and metadata indexes and summary offsets (the
    layout of the mcap library's own writer). Raises :class:`InputError` for a block out of
    log-time order or with other channels, and when there is no message at all.
    """
    out = RecordBuilder()
    chunk_indexes: list[ChunkIndex] = []
    first: list[Encoded] | None = None
    written = Written([], 0, 0)
    for k, block in enumerate(blocks):
        if first is None:
            first = block
            schemas, channels = _schemas_and_channels(block)
            Header(profile="ros2", library=OWN_LIBRARY).write(out)
            for record in (*schemas.values(), *channels):
                record.write(out)
            f.write(MAGIC + out.end())
            written.counts = [0] * len(block)
        else:
            _same_channels(first, block, k)
        m = _message_order(block)
        if m.stamps.size == 0:
            continue
        if any(written.counts) and int(m.stamps[0]) < written.t_max_ns:
            raise InputError(
                f"Expected block {k} to start at or after the last log time before it "
                f"({written.t_max_ns} ns), got {int(m.stamps[0])} ns"
            )
        if not any(written.counts):
            written.t_min_ns = int(m.stamps[0])
        written.t_max_ns = int(m.stamps[-1])
        written.counts = [c + int(t.t_ns.size) for c, t in zip(written.counts, block, strict=True)]
        chunk_indexes += _write_chunks(f, out, block, m, chunk_size)
        del m
    if first is None or not any(written.counts):
        raise InputError("Expected at least one message to write, got none")
    Metadata(name="rosbag2", metadata=metadata(written)).write(out)
    meta_bytes = out.end()
    meta_index = MetadataIndex(offset=f.tell(), length=len(meta_bytes), name="rosbag2")
    f.write(meta_bytes)
    DataEnd(data_section_crc=0).write(out)
    f.write(out.end())
    stats = Statistics(
        message_count=sum(written.counts),
        schema_count=len(schemas),
        channel_count=len(channels),
        attachment_count=0,
        metadata_count=1,
        chunk_count=len(chunk_indexes),
        message_start_time=written.t_min_ns,
        message_end_time=written.t_max_ns,
        channel_message_counts={i + 1: c for i, c in enumerate(written.counts)},
    )
    groups = [
        (0x03, list(schemas.values())),
        (0x04, channels),
        (0x0B, [stats]),
        (0x08, chunk_indexes),
        (0x0D, [meta_index]),
    ]
    _write_summary(f, out, groups)
    return written

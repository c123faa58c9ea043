"""The indexed MCAP reader: the summary says where every chunk is and which channels it holds.

Chunks of other channels (a camera) are never read; the others are read in batches
(:mod:`imu_dcm.logio.containers.chunks`: decompressed on worker threads into one buffer) and
the messages of a whole batch located and checked at once from their message indexes. A
damaged chunk costs only itself (from the index, the next chunk is known).
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from imu_dcm._kernels import locate_batch
from imu_dcm.logio.checksum import crc32
from imu_dcm.logio.containers.chunks import Decompressor, Job, batches
from imu_dcm.logio.containers.mcap.reader import McapReader
from imu_dcm.logio.containers.mcap.records import (
    MAGIC,
    MAX_META_RECORD,
    OP_CHANNEL,
    OP_CHUNK,
    OP_CHUNK_INDEX,
    OP_FOOTER,
    OP_METADATA,
    OP_METADATA_INDEX,
    OP_MSG_INDEX,
    OP_SCHEMA,
    OP_STATISTICS,
    REC,
    BadRecord,
    chunk_head,
    decompress_into,
    parse_channel,
    parse_schema,
    read_string,
)
from imu_dcm.logio.types import Damage

__all__ = ["IndexedReader", "Summary", "read_summary"]


@dataclass(slots=True, frozen=True)
class Summary:
    """The summary section of an MCAP file, as far as the reader uses it.

    ``chunks`` holds one ``(start, length, t0, t1, {channel: message index offset},
    message index length, compression, compressed size, uncompressed size)`` per chunk, by
    file offset; ``counts`` the message count per channel (statistics); ``metadata`` the
    ``(offset, length)`` of each metadata record.
    """

    schemas: dict[int, tuple[str, str, bytes]]
    channels: dict[int, tuple[int, str, str]]
    chunks: list[tuple]
    counts: dict[int, int]
    metadata: list[tuple[int, int]]


def _summary_section(f, size: int) -> bytes | None:
    """The summary section's bytes, CRC checked, or None when the file has none to trust."""
    if size < 8 + 9 + 20 + 8:
        return None
    f.seek(size - 8 - 29)
    tail = f.read(29 + 8)
    if tail[-8:] != MAGIC or tail[0] != OP_FOOTER:
        return None
    summary_start, _, summary_crc = struct.unpack_from("<QQI", tail, 9)
    end = size - 8 - 29
    if summary_start == 0 or not 8 <= summary_start <= end or end - summary_start > MAX_META_RECORD:
        return None
    f.seek(summary_start)
    buf = f.read(end - summary_start)
    if summary_crc != 0 and crc32(tail[:25], crc32(buf)) != summary_crc:
        return None  # a damaged summary: the data section is walked instead
    return buf


def _parse_summary(buf: bytes) -> Summary | None:
    """The records of a summary section (None when one runs past it or is damaged)."""
    schemas, channels, chunks, counts, metas = {}, {}, [], {}, []
    pos = 0
    try:
        while pos + 9 <= len(buf):
            op, length = REC.unpack_from(buf, pos)
            p, rec_end = pos + 9, pos + 9 + length
            if rec_end > len(buf):
                return None
            if op == OP_SCHEMA:
                parse_schema(buf, p, schemas)
            elif op == OP_CHANNEL:
                parse_channel(buf, p, channels)
            elif op == OP_CHUNK_INDEX:
                t0, t1, start, clen, nmap = struct.unpack_from("<QQQQI", buf, p)
                q = p + 36
                offsets = {}
                for _ in range(nmap // 10):
                    cid, off = struct.unpack_from("<HQ", buf, q)
                    offsets[cid] = off
                    q += 10
                (ilen,) = struct.unpack_from("<Q", buf, q)
                comp, q = read_string(buf, q + 8)
                csize, usize = struct.unpack_from("<QQ", buf, q)
                chunks.append((start, clen, t0, t1, offsets, ilen, comp, csize, usize))
            elif op == OP_STATISTICS:
                (nmap,) = struct.unpack_from("<I", buf, p + 42)
                q = p + 46
                for _ in range(nmap // 10):
                    cid, n = struct.unpack_from("<HQ", buf, q)
                    counts[cid] = n
                    q += 10
            elif op == OP_METADATA_INDEX:
                metas.append(struct.unpack_from("<QQ", buf, p))
            pos = rec_end
    except (struct.error, BadRecord):
        return None
    return Summary(schemas, channels, sorted(chunks), counts, metas)


def read_summary(f, size: int) -> Summary | None:
    """The summary of the MCAP file ``f`` of ``size`` bytes, or None when it is absent or
    unusable (no chunk index, a damaged record, an index that does not point at a chunk):
    the file is then walked by the streaming reader."""
    buf = _summary_section(f, size)
    summary = None if buf is None else _parse_summary(buf)
    if summary is None or not summary.chunks:
        return None  # no chunk index (or messages outside chunks): walk the file
    for start, clen, *_ in summary.chunks:  # an index that lies about where a chunk is: walk
        if start + clen > size or clen < 9:
            return None
        f.seek(start)
        op, length = REC.unpack(f.read(9))
        if op != OP_CHUNK or 9 + length != clen:
            return None
    return summary


class IndexedReader(McapReader):
    """Reads an MCAP file through its :class:`Summary` (see the module doc)."""

    def __init__(self, summary: Summary, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.summary = summary

    def _apply_summary(self, f) -> list[tuple]:
        """The summary's schemas, channels, counts and metadata taken; its chunk indexes."""
        s = self.summary
        self.schemas.update(s.schemas)
        self.channels.update(s.channels)
        self.counts.update(s.counts)
        for off, length in s.metadata:
            if 9 < length <= MAX_META_RECORD and off + length <= self.size:
                f.seek(off)
                if f.read(1)[0] == OP_METADATA:
                    f.seek(8, 1)
                    self.metadata(f.read(length - 9), off)
        return s.chunks

    def read(self, f) -> None:
        """Read the chunks holding kept channels, in batches decompressed on worker threads;
        each chunk's place and message indexes are read as its batch comes (the batch before
        is decompressed meanwhile), so only the batches at hand hold theirs."""
        index = self._apply_summary(f)
        wanted = {c for c in self.channels if self.is_kept(c)}
        chunks = [k for k, c in enumerate(index) if not c[4] or wanted & c[4].keys()]
        first_damage, done = len(self.damage), 0
        jobs = self._jobs(f, index, chunks, wanted)
        for buf, group in Decompressor(f.fileno(), decompress_into).run(batches(jobs)):
            if self.progress is not None:
                self.progress(done / max(len(chunks), 1))
            done += len(group)
            good = []
            for j in group:
                k, start, t0, t1, entries = j.key
                if j.out is None:
                    self._lost_chunk(k, len(index), start, t0, t1, entries, wanted, j.why)
                else:
                    good.append(j)
            self._take_batch(buf, good)
            del buf, good  # the batch's buffer can then be reused for the next batch
        # a chunk the index misplaces is found when its batch is made, before the batch ahead
        # is checked: the damage in file order
        self.damage[first_damage:] = sorted(self.damage[first_damage:], key=lambda d: d.offset)

    def _jobs(self, f, index: list, chunks: list[int], wanted: set) -> Iterator[Job]:
        """The :class:`Job` of each chunk ``k`` in ``chunks`` (positions in ``index``), with its
        message index entries; a chunk whose index entry does not point at a chunk record is
        noted as damaged instead."""
        for k in chunks:
            start, clen, t0, t1, offsets, ilen, *_ = index[k]
            entries = self._message_index(f, offsets, ilen)
            try:
                if start + clen > self.size or clen < 9:
                    raise BadRecord(
                        f"its index points past the end of the file ({self.size} bytes)"
                    )
                f.seek(start)
                op, length = REC.unpack(f.read(9))
                if op != OP_CHUNK or 9 + length != clen:
                    raise BadRecord("its index does not point at a chunk record")
                at, n, usize, comp, crc = chunk_head(f, start, length, self.size)
            except BadRecord as exc:
                self._lost_chunk(k, len(index), start, t0, t1, entries, wanted, str(exc))
                continue
            yield Job((k, start, t0, t1, entries), at, n, usize, comp, crc)

    def _lost_chunk(self, k, n_chunks, start, t0, t1, entries, wanted, why: str) -> None:
        """The chunk ``k`` of ``n_chunks`` is damaged: noted, with the kept messages it held."""
        lost = sum(len(e[0]) for c, e in entries.items() if c in wanted) if entries else None
        self.damage.append(
            Damage(start, f"chunk {k + 1} of {n_chunks} is damaged: {why}", t0, t1, lost)
        )

    def _message_index(self, f, offsets: dict[int, int], ilen: int) -> dict:
        """Message index entries (record offsets, log times) of every channel of one chunk.

        A chunk's message indexes stand together after it, ``ilen`` bytes from the first (the
        chunk index says so): read at once, then each channel's record checked in them (opcode,
        channel, length); a record outside them is read alone."""
        out = {}
        first = min(offsets.values(), default=0)
        ilen = ilen if 0 < ilen <= MAX_META_RECORD and first + ilen <= self.size else 0
        region = b""
        if ilen:
            f.seek(first)
            region = f.read(ilen)
        for cid in sorted(offsets):
            off = offsets[cid]
            at = off - first
            inside = at >= 0 and at + 15 <= len(region)  # its header read with the region
            if inside:
                buf, p = region, at
            elif off + 15 <= self.size:
                f.seek(off)
                buf, p = f.read(15), 0
            else:
                continue
            op, length, c, nbytes = struct.unpack_from("<BQHI", buf, p)
            if (
                op != OP_MSG_INDEX
                or c != cid
                or nbytes != length - 6
                or nbytes % 16
                or (off + 9 + length > self.size)
            ):
                continue
            if inside and p + 15 + nbytes <= len(region):
                pairs = np.frombuffer(region, "<i8", nbytes // 8, p + 15)
            else:  # its entries run past the region (or it was read alone): read from the file
                f.seek(off + 15)
                data = f.read(nbytes)
                if len(data) != nbytes:
                    continue
                pairs = np.frombuffer(data, "<i8")
            # (log time, offset) pairs; a log time or offset past 2**63 reads negative and the
            # record location refuses it
            pairs = pairs.reshape(-1, 2)
            out[cid] = (pairs[:, 1], pairs[:, 0])
        return out

    def _take_batch(self, buf: np.ndarray, group: list[Job]) -> None:
        """Keep the messages of a batch of decompressed chunks (``buf``, one slice each):
        located all at once where every chunk's message indexes check out, else chunk by
        chunk (:meth:`_take`: damaged records cost only themselves)."""
        if group and all(j.key[4] for j in group) and self._take_located(buf, group):
            return
        for j in group:
            k, start, t0, t1, entries = j.key
            self.take_chunk(j.out, start, k, entries, (t0, t1))

    def _take_located(self, buf: np.ndarray, group: list[Job]) -> bool:
        """The batch's messages from their indexes, located, checked (opcode, length, channel,
        no overlap, inside their chunk) and grouped by channel in one compiled pass; False,
        with nothing kept, when any record does not check out."""
        cids = sorted({c for j in group for c in j.key[4]})
        if not all(c in self.channels for c in cids):
            return False
        slot = {c: i for i, c in enumerate(cids)}
        offs, seg, seg_chunk, seg_slot = [], [0], [], []
        for k, j in enumerate(group):
            for c, e in j.key[4].items():
                offs.append(e[0])
                seg.append(seg[-1] + len(e[0]))
                seg_chunk.append(k)
                seg_slot.append(slot[c])
        bases = np.array([j.start for j in group], np.int64)  # damaged chunks leave holes
        sizes = np.array([j.usize for j in group], np.int64)
        seqs = np.array([j.key[0] for j in group], np.int64)
        start, length, lt, order, bounds, gaps, bad = locate_batch(
            buf, np.concatenate(offs), seg, seg_chunk, seg_slot, bases, sizes, seqs, cids
        )
        if bad >= 0:
            return False
        self.n_kept = 0
        # schema and channel records between the indexed messages: walked chunk by chunk
        for a, b in gaps.reshape(-1, 2).tolist():
            g = int(np.searchsorted(bases, a, side="right")) - 1
            seq, pos, t0, t1, _ = group[g].key
            base = int(bases[g])
            self.walk(group[g].out, a - base, b - base, pos, seq, span=(t0, t1))
        spans = [
            (c, start[a:b], length[a:b], lt[a:b], order[a:b])
            for c, a, b in zip(cids, bounds[:-1].tolist(), bounds[1:].tolist(), strict=True)
        ]
        self.hand_on(buf, spans)
        return True

"""MCAP, read our own way: only the chunks that hold kept channels, each bounded and checked.

With a summary (the normal case) the chunk indexes say which channels every chunk holds, so
chunks of other channels (a camera) are never read; the others are read in batches
(:mod:`imu_dcm.logio.containers.chunks`: decompressed on worker threads into one buffer) and
the messages of a whole batch located and checked at once from their message indexes. Without one (a
truncated file) the file is walked forward record by record, one chunk in memory at a time; a
chunk is skipped unread when the message indexes behind it show no kept channel. Each chunk is
refused when its declared size is beyond :func:`size_bound`, and never decompresses past its
declared size. A damaged chunk costs only itself: it becomes a :class:`Damage` (file offset,
time range, messages lost) and reading goes on with the next chunk (from the index, or a scan
for the next valid chunk).
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np

from imu_dcm.errors import LogError
from imu_dcm.logio.containers.chunks import Decompressor, Job, batches
from imu_dcm.logio.ros.cdr import gather
from imu_dcm.logio.ros.read import RosSource
from imu_dcm.logio.source import ProgressCallback
from imu_dcm.logio.types import Collected, Conn, Damage, Payloads, Sink

MAGIC = b"\x89MCAP0\r\n"
_SCHEMA, _CHANNEL, _MESSAGE, _CHUNK, _MSG_INDEX, _CHUNK_INDEX, _STATS = 3, 4, 5, 6, 7, 8, 11
_FOOTER, _DATA_END, _METADATA, _METADATA_INDEX = 2, 15, 12, 13
_REC = struct.Struct("<BQ")
_MSG = struct.Struct("<BQHIQQ")  # opcode, length, channel_id, sequence, log_time, publish_time
_MSG_HEADER = _MSG.size  # 31 bytes before the payload of a message record
_CHUNK_HEAD = struct.Struct("<QQQI")  # start time, end time, uncompressed size, uncompressed crc
#: Hard limit on one decompressed chunk (bytes); rosbag2 writes 768 KiB chunks, mcap 1 MiB.
MAX_CHUNK_BYTES = 256 << 20
#: Largest schema / channel / summary record read whole (bytes).
MAX_META_RECORD = 64 << 20


def size_bound(compressed: int) -> int:
    """Largest uncompressed size accepted for a chunk of ``compressed`` bytes.

    128x the compressed size (zstd reaches 5-14x on real IMU chunks, ~31x on all-zero
    messages), at least 1 MiB, at most :data:`MAX_CHUNK_BYTES`: a small file cannot make the
    reader allocate gigabytes.
    """
    return min(MAX_CHUNK_BYTES, max(1 << 20, 128 * compressed))


def compact(d: np.ndarray, start: np.ndarray, length: np.ndarray) -> tuple:
    """Copy the byte ranges ``d[start:start+length]`` into one buffer, in order; returns
    (buffer, new starts, lengths)."""
    out_start = np.concatenate([[0], np.cumsum(length)[:-1]]).astype(np.int64)
    if len(length) and length.min() == length.max() > 0:  # one layout: one run per message
        buf = gather(d, start, "u1", int(length[0])).reshape(-1)
        return buf, out_start, length.astype(np.int64)
    mv = memoryview(d)
    buf = b"".join([mv[s : s + n] for s, n in zip(start.tolist(), length.tolist(), strict=False)])
    return np.frombuffer(buf, np.uint8), out_start, length.astype(np.int64)


class _Bad(Exception):
    """A damaged record: ``why`` is one line."""


def _str(buf, pos: int) -> tuple[str, int]:
    (n,) = struct.unpack_from("<I", buf, pos)
    end = pos + 4 + n
    if end > len(buf):
        raise _Bad("a string runs past its record")
    return bytes(buf[pos + 4 : end]).decode("utf-8", errors="replace"), end


def decompress(compression: str, data: bytes, size: int) -> bytes:
    """Decompress a chunk to exactly ``size`` bytes, never more; raises _Bad otherwise."""
    if compression == "":
        out = data
    elif compression == "zstd":
        import zstandard

        declared = zstandard.frame_content_size(data) if len(data) >= 4 else -2
        if declared not in (-1, size):
            raise _Bad(f"its zstd frame declares {declared} bytes, the chunk {size}")
        try:
            out = zstandard.ZstdDecompressor().decompress(data, max_output_size=max(size, 1))
        except zstandard.ZstdError as exc:
            raise _Bad(f"it does not decompress ({str(exc)[:60]})") from None
    elif compression == "lz4":
        import lz4.frame

        try:
            out = lz4.frame.LZ4FrameDecompressor().decompress(data, max_length=size + 1)
        except RuntimeError as exc:
            raise _Bad(f"it does not decompress ({str(exc)[:60]})") from None
    else:
        raise LogError(f"Expected chunk compression zstd, lz4 or none, got {compression!r}")
    if len(out) != size:
        raise _Bad(
            f"it decompresses to {len(out)}{'+' if len(out) > size else ''} bytes, "
            f"not its declared {size}"
        )
    return out


def decompress_into(compression: str, data: bytes, out: memoryview) -> str | None:
    """Decompress a chunk into ``out``, filling it exactly; returns why not (one line) or None."""
    size = len(out)
    try:
        if compression == "zstd":
            import zstandard

            declared = zstandard.frame_content_size(data) if len(data) >= 4 else -2
            if declared not in (-1, size):
                return f"its zstd frame declares {declared} bytes, the chunk {size}"
            try:
                with zstandard.ZstdDecompressor().stream_reader(data) as r:
                    n = 0
                    while n < size:
                        k = r.readinto(out[n:])
                        if not k:
                            break
                        n += k
                    more = n == size and bool(r.read(1))
            except zstandard.ZstdError as exc:
                return f"it does not decompress ({str(exc)[:60]})"
            if n != size or more:
                return f"it decompresses to {n}{'+' if more else ''} bytes, not its declared {size}"
            return None
        got = decompress(compression, data, size)
    except _Bad as exc:
        return str(exc)
    out[:] = got
    return None


def _schema(buf, pos: int, out: dict) -> None:
    (sid,) = struct.unpack_from("<H", buf, pos)
    name, p = _str(buf, pos + 2)
    enc, p = _str(buf, p)
    (n,) = struct.unpack_from("<I", buf, p)
    out[sid] = (name, enc, bytes(buf[p + 4 : p + 4 + n]))


def _channel(buf, pos: int, out: dict) -> None:
    cid, sid = struct.unpack_from("<HH", buf, pos)
    topic, p = _str(buf, pos + 4)
    enc, p = _str(buf, p)
    out[cid] = (sid, topic, enc)


def _rosbag2_custom_data(buf: bytes, where: Path) -> dict[str, str]:
    """``custom_data`` of a Metadata record body named ``rosbag2`` (empty for any other name).

    rosbag2 stores its bag information (the ``metadata.yaml`` body) in such a record's
    ``serialized_metadata``, so a single ``.mcap`` carries it without the folder's file.
    """
    from imu_dcm.logio.meta import custom_data, load_yaml

    name, p = _str(buf, 0)
    if name != "rosbag2":
        return {}
    (n,) = struct.unpack_from("<I", buf, p)
    p, end, entries = p + 4, p + 4 + n, {}
    while p < min(end, len(buf)):
        key, p = _str(buf, p)
        entries[key], p = _str(buf, p)
    doc = load_yaml(entries.get("serialized_metadata", ""), where, "rosbag2 metadata record")
    if isinstance(doc, dict) and isinstance(doc.get("rosbag2_bagfile_information"), dict):
        doc = doc["rosbag2_bagfile_information"]
    return custom_data(doc) if isinstance(doc, dict) else {}


class McapSource(RosSource):
    """One MCAP file. ``collect(sink)`` returns every channel and the data of kept ones."""

    kind = "mcap"

    def __init__(self, path: Path, progress: ProgressCallback | None = None):
        self.path = path
        self.progress = progress
        self.schemas: dict[int, tuple[str, str, bytes]] = {}
        self.channels: dict[int, tuple[int, str, str]] = {}
        self.counts: dict[int, int] = {}
        self.counts_seen: dict[int, int] = {}
        self.unknown: dict[int, int] = {}  # chunk offset -> messages naming no defined channel
        self._n_kept = 0
        self.damage: list[Damage] = []
        self.profile = ""
        self.sink = Sink(lambda c: None)
        self._kept: dict[int, bool] = {}

    # ------------------------------------------------------------------ channels
    def conn(self, cid: int) -> Conn:
        sid, topic, enc = self.channels[cid]
        name, senc, data = self.schemas.get(sid, ("", "", b""))
        try:
            text = data.decode("utf-8")
        except UnicodeDecodeError:
            text = "\x00"  # corrupt schema: fails to parse later, naming the topic
        if enc == "ros1":
            senc = senc or "ros1msg"
        return Conn(
            cid, topic, name, enc, senc, text, self.counts.get(cid, self.counts_seen.get(cid, 0))
        )

    def _is_kept(self, cid: int) -> bool:
        k = self._kept.get(cid)
        if k is None:
            k = self._kept[cid] = cid in self.channels and self.sink.wants(self.conn(cid))
        return k

    # ------------------------------------------------------------------ reading
    def collect(self, sink: Sink) -> Collected:
        self.sink = sink
        try:
            f = open(self.path, "rb")  # noqa: SIM115
        except OSError as exc:
            raise LogError(
                f"Expected a readable MCAP file, got {self.path} ({exc.strerror})"
            ) from None
        with f:
            self.size = f.seek(0, 2)
            f.seek(0)
            head = f.read(len(MAGIC))
            if not head:
                raise LogError(f"Expected an MCAP file, got an empty file: {self.path}")
            if head != MAGIC:
                raise LogError(
                    f"Expected an MCAP file (magic \\x89MCAP0), got {head!r} in {self.path}"
                )
            self.profile = self._header_profile(f)
            index = self._summary(f)
            if index is not None:
                self._read_indexed(f, index)
            else:
                self._scan(f)
        for pos, n in sorted(self.unknown.items()):
            self.damage.append(
                Damage(
                    pos,
                    f"{n} messages in the chunk at byte {pos} name a "
                    f"channel id that is not defined; they are lost",
                    None,
                    None,
                    n,
                )
            )
        if self.kind == "mcap" and self.profile in ("ros1", "ros2"):
            self.kind = f"{self.profile} mcap"
        conns = [self.conn(c) for c in sorted(self.channels)]
        payloads = self.sink.finish()
        return Collected(self.kind, conns, payloads, self.damage)

    def _header_profile(self, f) -> str:
        try:
            op, length = _REC.unpack(f.read(9))
            if op == 1 and length < 1 << 16:
                return _str(f.read(length), 0)[0]
        except (struct.error, _Bad):
            pass
        return ""

    def _summary(self, f) -> list[tuple] | None:
        """Chunk indexes from the summary, or None when absent/unusable (then scan)."""
        if self.size < 8 + 9 + 20 + 8:
            return None
        f.seek(self.size - 8 - 29)
        tail = f.read(29 + 8)
        if tail[-8:] != MAGIC or tail[0] != _FOOTER:
            return None
        summary_start, _, summary_crc = struct.unpack_from("<QQI", tail, 9)
        end = self.size - 8 - 29
        if (
            summary_start == 0
            or not 8 <= summary_start <= end
            or end - summary_start > (MAX_META_RECORD)
        ):
            return None
        f.seek(summary_start)
        buf = f.read(end - summary_start)
        if summary_crc != 0 and zlib.crc32(tail[:25], zlib.crc32(buf)) != summary_crc:
            return None  # a damaged summary: the data section is walked instead
        schemas, channels, chunks, counts, metas = {}, {}, [], {}, []
        pos = 0
        try:
            while pos + 9 <= len(buf):
                op, length = _REC.unpack_from(buf, pos)
                p, rec_end = pos + 9, pos + 9 + length
                if rec_end > len(buf):
                    return None
                if op == _SCHEMA:
                    _schema(buf, p, schemas)
                elif op == _CHANNEL:
                    _channel(buf, p, channels)
                elif op == _CHUNK_INDEX:
                    t0, t1, start, clen, nmap = struct.unpack_from("<QQQQI", buf, p)
                    q = p + 36
                    offsets = {}
                    for _ in range(nmap // 10):
                        cid, off = struct.unpack_from("<HQ", buf, q)
                        offsets[cid] = off
                        q += 10
                    (ilen,) = struct.unpack_from("<Q", buf, q)
                    comp, q = _str(buf, q + 8)
                    csize, usize = struct.unpack_from("<QQ", buf, q)
                    chunks.append((start, clen, t0, t1, offsets, ilen, comp, csize, usize))
                elif op == _STATS:
                    (nmap,) = struct.unpack_from("<I", buf, p + 42)
                    q = p + 46
                    for _ in range(nmap // 10):
                        cid, n = struct.unpack_from("<HQ", buf, q)
                        counts[cid] = n
                        q += 10
                elif op == _METADATA_INDEX:
                    metas.append(struct.unpack_from("<QQ", buf, p))
                pos = rec_end
        except (struct.error, _Bad):
            return None
        if not chunks:
            return None  # no chunk index (or messages outside chunks): walk the file
        for start, clen, *_ in chunks:  # an index that lies about where a chunk is: walk
            if start + clen > self.size or clen < 9:
                return None
            f.seek(start)
            op, length = _REC.unpack(f.read(9))
            if op != _CHUNK or 9 + length != clen:
                return None
        self.schemas.update(schemas)
        self.channels.update(channels)
        self.counts.update(counts)
        for off, length in metas:
            if 9 < length <= MAX_META_RECORD and off + length <= self.size:
                f.seek(off)
                if f.read(1)[0] == _METADATA:
                    f.seek(8, 1)
                    self._metadata(f.read(length - 9), off)
        return sorted(chunks)

    def _metadata(self, buf: bytes, pos: int) -> None:
        """The bag's ``custom_data`` from a rosbag2 Metadata record (at byte ``pos``), unless
        the bag folder's ``metadata.yaml`` gave it; a damaged record costs only itself."""
        if self.custom_data:
            return
        try:
            self.custom_data = _rosbag2_custom_data(buf, self.path)
        except (struct.error, _Bad, LogError) as exc:
            why = str(exc) if isinstance(exc, LogError) else "a field runs past the record"
            self.damage.append(
                Damage(
                    pos,
                    f"the metadata record at byte {pos} is damaged ({why}); its "
                    "custom_data (declared intervals, whose estimate the truth is) is lost",
                )
            )

    def _read_indexed(self, f, index: list[tuple]) -> None:
        """Read the chunks holding kept channels, in batches decompressed on worker threads."""
        wanted = {c for c in self.channels if self._is_kept(c)}
        jobs = []
        for k, (start, clen, t0, t1, offsets, _ilen, _c, _cs, _us) in enumerate(index):
            if offsets and not (wanted & offsets.keys()):
                continue
            entries = self._message_index(f, offsets, set(offsets))
            try:
                if start + clen > self.size or clen < 9:
                    raise _Bad(f"its index points past the end of the file ({self.size} bytes)")
                f.seek(start)
                op, length = _REC.unpack(f.read(9))
                if op != _CHUNK or 9 + length != clen:
                    raise _Bad("its index does not point at a chunk record")
                at, n, usize, comp, crc = self._chunk_head(f, start, length)
            except _Bad as exc:
                self._lost_chunk(k, len(index), start, t0, t1, entries, wanted, str(exc))
                continue
            jobs.append(Job((k, start, t0, t1, entries), at, n, usize, comp, crc))
        done = 0
        for buf, group in Decompressor(f.fileno(), decompress_into).run(batches(jobs)):
            if self.progress is not None:
                self.progress(done / max(len(jobs), 1))
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

    def _lost_chunk(self, k, n_chunks, start, t0, t1, entries, wanted, why: str) -> None:
        lost = sum(len(e[0]) for c, e in entries.items() if c in wanted) if entries else None
        self.damage.append(
            Damage(start, f"chunk {k + 1} of {n_chunks} is damaged: {why}", t0, t1, lost)
        )

    def _chunk_head(self, f, pos: int, length: int) -> tuple[int, int, int, str, int]:
        """The chunk record at ``pos`` (file positioned after its opcode and length), checked:
        (file offset of its records, their compressed size, uncompressed size, compression,
        CRC). Raises _Bad."""
        if length < 40 or pos + 9 + length > self.size:
            raise _Bad(f"its record of {length} bytes runs past the end of the file")
        head = f.read(min(length, 4096))
        _t0, _t1, usize, crc = _CHUNK_HEAD.unpack_from(head, 0)
        comp, p = _str(head, 28)
        (n,) = struct.unpack_from("<Q", head, p)
        if p + 8 + n != length:
            raise _Bad(f"its records size {n} does not match its record length {length}")
        if usize > size_bound(n):
            raise _Bad(
                f"it declares {usize} bytes uncompressed from {n} (refused, beyond {size_bound(n)})"
            )
        if comp == "" and usize != n:
            raise _Bad(f"it is uncompressed but declares {usize} bytes for {n}")
        if comp not in ("", "zstd", "lz4"):
            raise LogError(f"Expected chunk compression zstd, lz4 or none, got {comp!r}")
        return pos + 9 + p + 8, n, usize, comp, crc

    def _message_index(self, f, offsets: dict[int, int], wanted: set[int]) -> dict:
        """Message index entries (log times, offsets) of the kept channels of one chunk."""
        out = {}
        for cid in sorted(wanted & offsets.keys()):
            off = offsets[cid]
            if off + 15 > self.size:
                continue
            f.seek(off)
            head = f.read(15)
            op, length, c, nbytes = struct.unpack("<BQHI", head)
            if (
                op != _MSG_INDEX
                or c != cid
                or nbytes != length - 6
                or nbytes % 16
                or (off + 9 + length > self.size)
            ):
                continue
            pairs = np.frombuffer(f.read(nbytes), "<u8").reshape(-1, 2).astype(np.int64)
            out[cid] = (pairs[:, 1], pairs[:, 0])
        return out

    def _chunk(self, f, pos: int, length: int, seq: int, entries: dict | None) -> None:
        """Read, check and decompress the chunk record at file offset ``pos``; keep payloads."""
        at, n, usize, comp, crc = self._chunk_head(f, pos, length)
        f.seek(pos + 9)
        _t0, _t1 = struct.unpack("<QQ", f.read(16))
        f.seek(at)
        data = decompress(comp, f.read(n), usize)
        if crc != 0 and zlib.crc32(data) != crc:
            raise _Bad("it fails its CRC check")
        self._take(data, pos, seq, entries, (_t0, _t1))

    def _take_batch(self, buf: np.ndarray, group: list[Job]) -> None:
        """Keep the messages of a batch of decompressed chunks (``buf``, one slice each):
        located all at once where every chunk's message indexes check out, else chunk by
        chunk (:meth:`_take`: damaged records cost only themselves)."""
        if group and all(j.key[4] for j in group) and self._take_located(buf, group):
            return
        for j in group:
            k, start, t0, t1, entries = j.key
            self._take(j.out, start, k, entries, (t0, t1))

    def _take_located(self, buf: np.ndarray, group: list[Job]) -> bool:
        """The batch's messages from their indexes, checked together (opcode, length, channel,
        no overlap, inside their chunk) with one numpy pass per field; False, with nothing
        kept, when any record does not check out."""
        sizes = np.array([j.usize for j in group], np.int64)
        bases = np.array([j.start for j in group], np.int64)  # damaged chunks leave holes
        offs, icid = [], []
        for j, base in zip(group, bases.tolist(), strict=True):
            for c, e in j.key[4].items():
                offs.append(e[0] + base)
                icid.append(np.full(len(e[0]), c, np.int64))
        offs, icid = np.concatenate(offs), np.concatenate(icid)
        k = np.argsort(offs, kind="stable")
        offs, icid = offs[k], icid[k]
        chunk = np.searchsorted(bases, offs, side="right") - 1
        start, end = bases[chunk], bases[chunk] + sizes[chunk]
        if not ((offs >= start) & (offs + _MSG_HEADER <= end)).all():
            return False
        # opcode, length, channel id, sequence, log time: one run of bytes per record
        head = gather(buf, offs, "u1", 23).reshape(len(offs), 23)
        length_u = head[:, 1:9].view("<u8")[:, 0]
        room = (end - offs - 9).astype(np.uint64)
        ok = (head[:, 0] == _MESSAGE) & (length_u >= 22) & (length_u <= room)
        if not ok.all():
            return False
        length = length_u.astype(np.int64)
        ends = offs + 9 + length
        ok = ends <= np.minimum(np.concatenate([offs[1:], [end[-1]]]), end)
        ok &= head[:, 9:11].view("<u2")[:, 0] == icid
        if not ok.all() or not all(c in self.channels for j in group for c in j.key[4]):
            return False
        lt = head[:, 15:23].view("<u8")[:, 0].astype(np.int64)
        del head
        self._n_kept = 0
        # schema and channel records between the indexed messages: walked chunk by chunk
        gap_a = np.sort(np.concatenate([ends, bases]))
        gap_b = np.sort(np.concatenate([offs, bases + sizes]))
        for a, b in zip(gap_a[gap_b > gap_a].tolist(), gap_b[gap_b > gap_a].tolist(), strict=True):
            g = int(np.searchsorted(bases, a, side="right")) - 1
            seq, pos, t0, t1, _ = group[g].key
            base = int(bases[g])
            self._walk(group[g].out, a - base, b - base, pos, seq, span=(t0, t1))
        seqs = np.array([j.key[0] for j in group], np.int64)
        order = (seqs[chunk] << 32) + (offs - start)
        self._keep_spans(buf, offs, length, icid, lt, order, int(group[0].key[1]))
        return True

    def _take(
        self,
        data: bytes,
        pos: int,
        seq: int,
        entries: dict | None,
        span: tuple[int, int] = (None, None),
    ) -> None:
        """Locate the messages in a decompressed chunk; keep payloads of kept channels.

        With message indexes, every indexed record is checked (opcode, length, channel, no
        overlap): a damaged message record costs only itself. Without, the chunk is walked
        record by record, and a damaged record costs the rest of the chunk.
        """
        d = np.frombuffer(data, np.uint8)
        size = len(data)
        if entries:
            offs = np.concatenate([e[0] for e in entries.values()])
            icid = np.concatenate([np.full(len(e[0]), c) for c, e in entries.items()])
            k = np.argsort(offs, kind="stable")
            offs, icid = offs[k], icid[k]
            inside = (offs >= 0) & (offs + _MSG_HEADER <= size)
            o = np.where(inside, offs, 0)
            length_u = gather(d, o + 1, "u8")
            valid = inside & (d[o] == _MESSAGE) & (length_u >= 22) & (length_u <= size)
            length = np.where(valid, length_u, 22).astype(np.int64)
            ends = o + 9 + length
            nxt = np.concatenate([offs[1:], [size]])
            valid &= (ends <= nxt) & (ends <= size)
            cid = gather(d, o + 9, "u2").astype(np.int64)
            valid &= cid == icid
            lt = gather(d, o + 15, "u8").astype(np.int64)
            all_valid = bool(valid.all())
            # Schema/channel records sit between indexed messages: walk only those gaps. Where
            # index entries do not match the data (a damaged or stale index), the walk of the
            # gaps finds the messages they should have located.
            self._n_kept = 0
            gs = np.concatenate([[0], ends[valid]])
            ge = np.concatenate([offs[valid], [size]])
            for a, b in zip(gs[ge > gs].tolist(), ge[ge > gs].tolist(), strict=False):
                self._walk(data, a, b, pos, seq, span=span, quiet=not all_valid)
            if not all_valid:
                bad = ~valid
                expected = int(sum(self._is_kept(int(c)) for c in icid[bad]))
                lost = max(expected - self._n_kept, 0)
                if lost:
                    first = int(offs[bad][0])
                    self.damage.append(
                        Damage(
                            pos,
                            f"{int(bad.sum())} message records in the "
                            f"chunk at byte {pos} are damaged or misindexed "
                            f"(the first at byte {first} of its {size} "
                            f"decompressed bytes)",
                            span[0],
                            span[1],
                            lost,
                        )
                    )
            o = offs[valid]
            self._keep_spans(d, o, length[valid], cid[valid], lt[valid], (seq << 32) + o, pos)
            return
        self._n_kept = 0
        self._walk(data, 0, size, pos, seq, span=span, expected=None)

    def _keep_spans(
        self, d, offs, length, cid, log_time, order, pos: int = -1, note_unknown: bool = True
    ) -> None:
        """Hand the kept channels' payloads (message records at ``offs`` of ``d``) to the sink;
        ``order`` is each message's file-order key."""
        kept = []
        for c in np.flatnonzero(np.bincount(cid)).tolist():  # the ids present, ascending
            m = cid == c
            if c not in self.channels:
                if note_unknown:
                    self.unknown[pos] = self.unknown.get(pos, 0) + int(m.sum())
                continue
            self.counts_seen[c] = self.counts_seen.get(c, 0) + int(m.sum())
            if self._is_kept(c):
                kept.append((c, m, offs[m] + _MSG_HEADER, length[m] - 22))
        # Kept channels that together fill most of the chunk keep the chunk as is, shared (no
        # copy: IMU and truth interleaved); small ones (IMU beside a camera) copy out their
        # payloads, so the chunk can go.
        share = 2 * sum(int(n.sum()) for *_, n in kept) >= len(d)
        for c, m, s, n in kept:
            self._n_kept += len(s)
            buf = (d, s, n) if share else compact(d, s, n)
            self.sink.add(c, Payloads(*buf, log_time[m], order[m]))

    def _walk(
        self,
        data: bytes,
        a: int,
        b: int,
        pos: int,
        seq: int,
        span=(None, None),
        expected: int | None = None,
        quiet: bool = False,
    ) -> None:
        """Walk the records in ``data[a:b]`` of one chunk (chunk at file offset ``pos``)."""
        offs, lens, cids, times = [], [], [], []
        p = a
        while p + 9 <= b:
            op, length = _REC.unpack_from(data, p)
            end = p + 9 + length
            if end > b:
                break
            try:
                if op == _MESSAGE and length >= 22:
                    _, _, cid, _, lt, _ = _MSG.unpack_from(data, p)
                    offs.append(p)
                    lens.append(length)
                    cids.append(cid)
                    times.append(lt)
                elif op == _SCHEMA:
                    _schema(data, p + 9, self.schemas)
                elif op == _CHANNEL:
                    _channel(data, p + 9, self.channels)
            except (struct.error, _Bad):
                break
            p = end
        if offs:
            o = np.asarray(offs, np.int64)
            self._keep_spans(
                np.frombuffer(data, np.uint8),
                o,
                np.asarray(lens, np.int64),
                np.asarray(cids, np.int64),
                np.asarray(times, np.int64),
                (seq << 32) + o,
                pos,
                note_unknown=not quiet,
            )
        if p < b and not quiet:  # (a gap around damaged indexed records is reported once)
            lost = None if expected is None else max(expected - self._n_kept, 0)
            self.damage.append(
                Damage(
                    pos,
                    f"a record inside the chunk at byte {pos} is damaged "
                    f"(at byte {p} of its {len(data)} decompressed bytes); "
                    f"the rest of that chunk is lost",
                    span[0],
                    span[1],
                    lost,
                )
            )

    # ------------------------------------------------------------------ forward scan
    def _scan(self, f) -> None:
        """Walk the file record by record (no summary to trust), from the magic to data end."""
        pos, seq = len(MAGIC), 0
        f.seek(pos)
        while pos + 9 <= self.size:
            if self.progress is not None:
                self.progress(pos / self.size)
            f.seek(pos)
            op, length = _REC.unpack(f.read(9))
            end = pos + 9 + length
            if op in (_DATA_END, _FOOTER):
                return
            if end > self.size or op == 0 or op > 0x0F:
                nxt = self._skip_damaged(f, pos, end)
                if nxt is None:
                    return
                pos = nxt
                continue
            if op == _CHUNK:
                pos = self._scan_chunk(f, pos, length, end, seq)
                seq += 1
                continue
            if op in (_SCHEMA, _CHANNEL) and length <= MAX_META_RECORD:
                self._scan_definition(f, op, pos, length)
            elif op == _METADATA and length <= MAX_META_RECORD:
                self._metadata(f.read(length), pos)
            elif op == _MESSAGE and length >= 22:
                self._scan_message(f, length, seq)
                seq += 1
            pos = end
        # no data-end record: the file was cut (at a record boundary or inside a header)
        where = "inside a record " if pos < self.size else ""
        self.damage.append(
            Damage(
                pos,
                f"the file ends {where}at byte {pos} of {self.size} "
                f"without its data-end record; anything after it is lost",
            )
        )

    def _skip_damaged(self, f, pos: int, end: int) -> int | None:
        """A damaged record at ``pos``: noted; the next plausible chunk's offset, or None."""
        nxt = self._resync(f, pos + 1)
        what = (
            "the file ends inside a record"
            if nxt is None and end > self.size
            else "a record is damaged"
        )
        self.damage.append(
            Damage(
                pos,
                f"{what} at byte {pos} of {self.size}"
                + ("" if nxt is None else f"; resumed at byte {nxt}"),
            )
        )
        return nxt

    def _scan_chunk(self, f, pos: int, length: int, end: int, seq: int) -> int:
        """Read (or skip, when its index shows no kept channel) the chunk at ``pos``; returns
        the offset after it and its message indexes."""
        entries, after, complete = self._following_index(f, end)
        if not complete:
            entries = None
        t0 = t1 = None
        try:
            f.seek(pos + 9)
            t0, t1 = struct.unpack("<QQ", f.read(16))
            known = entries is not None and all(c in self.channels for c in entries)
            if known and not any(self._is_kept(c) for c in entries):
                for c, e in entries.items():
                    self.counts_seen[c] = self.counts_seen.get(c, 0) + len(e[0])
            else:
                f.seek(pos + 9)
                self._chunk(f, pos, length, seq, entries)
        except _Bad as exc:
            lost = None
            if entries is not None:
                lost = sum(
                    len(e[0])
                    for c, e in entries.items()
                    if c not in self.channels or self._is_kept(c)
                )
            self.damage.append(
                Damage(pos, f"the chunk at byte {pos} is damaged: {exc}", t0, t1, lost)
            )
        return after

    def _scan_definition(self, f, op: int, pos: int, length: int) -> None:
        """A schema or channel record outside chunks (the file is positioned at its body)."""
        buf = f.read(length)
        try:
            (_schema if op == _SCHEMA else _channel)(
                buf, 0, self.schemas if op == _SCHEMA else self.channels
            )
        except (struct.error, _Bad):
            self.damage.append(Damage(pos, f"a schema or channel record at byte {pos} is damaged"))

    def _scan_message(self, f, length: int, seq: int) -> None:
        """A message record outside chunks (the file is positioned at its body)."""
        head = f.read(22)
        cid, _, lt, _ = struct.unpack_from("<HIQQ", head)
        self.counts_seen[cid] = self.counts_seen.get(cid, 0) + 1
        if self._is_kept(cid):
            payload = np.frombuffer(f.read(length - 22), np.uint8)
            self.sink.add(
                cid,
                Payloads(
                    payload,
                    np.array([0], np.int64),
                    np.array([len(payload)], np.int64),
                    np.array([lt], np.int64),
                    np.array([(seq << 32) + 0], np.int64),
                ),
            )

    def _following_index(self, f, pos: int) -> tuple[dict | None, int, bool]:
        """Message index records right after a chunk: ({channel: (offsets, log times)}, the
        offset after them, whether they are complete). Incomplete (cut or damaged) indexes
        are not trusted: the chunk is then read and walked whole."""
        entries: dict = {}
        while pos < self.size:
            f.seek(pos)
            head = f.read(15)
            if head[0] != _MSG_INDEX:
                return (entries or None), pos, True  # the next record: the index is complete
            if len(head) < 15:
                return (entries or None), pos, False
            _, length, cid, nbytes = struct.unpack("<BQHI", head)
            if (
                pos + 9 + length > self.size
                or nbytes != length - 6
                or nbytes % 16
                or nbytes > MAX_META_RECORD
            ):
                return (entries or None), pos, False
            pairs = np.frombuffer(f.read(nbytes), "<u8").reshape(-1, 2).astype(np.int64)
            entries[cid] = (pairs[:, 1], pairs[:, 0])
            pos += 9 + length
        return (entries or None), pos, False  # the file ends here: cut, maybe mid-index

    def _resync(self, f, pos: int) -> int | None:
        """File offset of the next plausible chunk record at or after ``pos`` (None if none)."""
        block = 1 << 20
        while pos < self.size:
            f.seek(pos)
            buf = f.read(block + 64)
            i = buf.find(b"\x06")
            while i != -1 and i + 50 <= len(buf):
                try:
                    _, length = _REC.unpack_from(buf, i)
                    comp, p = _str(buf, i + 9 + 28)
                    (n,) = struct.unpack_from("<Q", buf, p)
                    if (
                        comp in ("", "zstd", "lz4")
                        and p - i - 9 + 8 + n == length
                        and (pos + i + 9 + length <= self.size)
                    ):
                        return pos + i
                except (struct.error, _Bad):
                    pass
                i = buf.find(b"\x06", i + 1)
            pos += block
        return None

"""ROS 1 bags (v2.0; uncompressed, bz2 or lz4 chunks): rosbags reads the index, we the chunks.

:class:`rosbags.rosbag1.Reader` parses the connection records and the per-chunk index. The
chunks that hold kept connections are then read here, each decompressed to at most its declared
``size`` (a chunk that claims 1000 bytes cannot inflate to gigabytes), and the message records
located from the index offsets with numpy. ROS 1 payloads are little endian, packed without
alignment; :mod:`imu_dcm.logio.ros.cdr` decodes them in bulk. A damaged chunk is skipped and
reported with its file offset, time range and the kept messages it held.
"""

from __future__ import annotations

import bz2
import struct
from collections import defaultdict
from pathlib import Path

import numpy as np

from imu_dcm.errors import LogError
from imu_dcm.logio.containers.mcap import compact, size_bound
from imu_dcm.logio.paths import read_head
from imu_dcm.logio.ros.cdr import gather
from imu_dcm.logio.ros.collect import Collected, Conn, Payloads, Sink
from imu_dcm.logio.ros.read import RosSource
from imu_dcm.logio.source import ProgressCallback
from imu_dcm.logio.types import Damage

__all__ = ["MAGIC", "Ros1Source", "open_bag"]


MAGIC = b"#ROSBAG V"


class _Bad(Exception):
    pass


def _decompress(compression: str, data: bytes, size: int) -> bytes:
    if size > size_bound(len(data)):
        raise _Bad(f"it declares {size} bytes uncompressed from {len(data)} (refused)")
    try:
        if compression == "none":
            out = data
        elif compression == "bz2":
            out = bz2.BZ2Decompressor().decompress(data, max_length=size + 1)
        elif compression == "lz4":
            import lz4.frame  # lazy: only an lz4 chunk needs it

            out = lz4.frame.LZ4FrameDecompressor().decompress(data, max_length=size + 1)
        else:
            raise LogError(
                f"Expected ROS 1 chunk compression none, bz2 or lz4, got "
                f"{compression!r}; `rosbag decompress x.bag` rewrites it"
            )
    except (OSError, RuntimeError, ValueError, EOFError) as exc:
        raise _Bad(f"it does not decompress ({str(exc)[:60]})") from None
    if len(out) != size:
        raise _Bad(
            f"it decompresses to {len(out)}{'+' if len(out) > size else ''} bytes, "
            f"not its declared {size}"
        )
    return out


def _op(d: np.ndarray, off: int, hl: int) -> int | None:
    """The ``op`` field of the record header at ``off`` (header length ``hl``)."""
    head = d[off + 4 : off + 4 + hl].tobytes()
    p = 0
    while p + 4 <= len(head):
        (n,) = struct.unpack_from("<I", head, p)
        name, _, value = head[p + 4 : p + 4 + n].partition(b"=")
        if name == b"op" and len(value) == 1:
            return value[0]
        p += 4 + n
    return None


def _walk_records(d: np.ndarray, offs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Payload (start, length) of the message record at or after each offset, skipping
    connection records (one record at a time)."""
    starts, lens = [], []
    for off in offs.tolist():
        while True:
            if off + 4 > len(d):
                raise _Bad("a message record runs past the chunk")
            (hl,) = struct.unpack_from("<I", d, off)
            if off + 8 + hl > len(d):
                raise _Bad("a message record header is damaged")
            (dl,) = struct.unpack_from("<I", d, off + 4 + hl)
            op = _op(d, off, hl)
            if op == 2:
                break
            if op != 7:
                raise _Bad(f"expected a message record, got op {op}")
            off += 8 + hl + dl
        if off + 8 + hl + dl > len(d):
            raise _Bad("a message runs past the chunk")
        starts.append(off + 8 + hl)
        lens.append(dl)
    return np.asarray(starts, np.int64), np.asarray(lens, np.int64)


class Ros1Source(RosSource):
    """A ROS 1 bag file."""

    kind = "ros1 bag"

    def __init__(self, path: Path, progress: ProgressCallback | None = None):
        self.path = path
        self.progress = progress

    def collect(self, sink: Sink) -> Collected:
        from rosbags.rosbag1 import Reader, ReaderError  # lazy: heavy, a .bag read only

        reader = Reader(self.path)
        try:
            reader.open()
        except ReaderError as exc:
            msg = str(exc.args[0] if exc.args else exc)
            fix = ""
            if "not indexed" in msg or "index looks damaged" in msg:
                fix = f"; `rosbag reindex {self.path.name}` rebuilds its index"
            elif "version" in msg:
                fix = (
                    f"; `rosbag fix {self.path.name} out.bag` rewrites it as v2.0, then "
                    f"read out.bag"
                )
            raise LogError(
                f"Expected a readable ROS 1 bag (v2.0), got {msg.rstrip('.')} in {self.path}{fix}"
            ) from None
        except (OSError, ValueError, KeyError, AssertionError, IndexError) as exc:
            raise LogError(
                f"Expected a readable ROS 1 bag, got a damaged index in {self.path} "
                f"({type(exc).__name__}); `rosbag reindex {self.path.name}` rebuilds "
                f"it"
            ) from None
        try:
            return self._read(reader, sink)
        finally:
            reader.close()

    def _read(self, reader, sink: Sink) -> Collected:
        from rosbags.rosbag1.reader import Header, RecordType  # lazy, as in collect

        conns = []
        for c in reader.connections:
            conns.append(
                Conn(c.id, c.topic, c.msgtype, "ros1", "ros1msg", c.msgdef.data, c.msgcount)
            )
        kept = {c.id for c in conns if sink.wants(c)}
        # index entries of kept connections, grouped by chunk: (offsets, times)
        by_chunk: dict[int, dict[int, tuple[list, list]]] = defaultdict(dict)
        for cid in kept:
            for e in reader.indexes.get(cid, []):
                offs, times = by_chunk[e.chunk_pos].setdefault(cid, ([], []))
                offs.append(e.offset)
                times.append(e.time)
        damage = []
        bio = reader.bio
        infos = sorted(reader.chunk_infos, key=lambda ci: ci.pos)
        for k, info in enumerate(infos):
            if self.progress is not None:
                self.progress(k / max(len(infos), 1))
            entries = by_chunk.get(info.pos)
            if not entries:
                continue
            try:
                bio.seek(info.pos)
                try:
                    head = Header.read(bio, RecordType.CHUNK)
                    compression = head.get_string("compression")
                    size = head.get_uint32("size")
                except Exception as exc:
                    raise _Bad(f"its header is damaged ({type(exc).__name__})") from None
                chunk = reader.chunks[info.pos]
                bio.seek(chunk.datapos)
                data = _decompress(compression, bio.read(chunk.datasize), size)
                self._take(np.frombuffer(data, np.uint8), entries, k, sink)
            except _Bad as exc:
                lost = sum(len(e[0]) for e in entries.values())
                damage.append(
                    Damage(
                        info.pos,
                        f"ROS 1 chunk {k + 1} of {len(infos)} at byte {info.pos} is damaged: {exc}",
                        info.start_time,
                        info.end_time,
                        lost,
                    )
                )
        payloads = sink.finish()
        return Collected(self.kind, conns, payloads, damage)

    @staticmethod
    def _take(d: np.ndarray, entries: dict, seq: int, sink: Sink) -> None:
        for cid, (offs, times) in entries.items():
            off = np.asarray(offs, np.int64)
            t = np.asarray(times, np.int64)
            if len(off) == 0:
                continue
            if off.min() < 0 or off.max() + 8 > len(d):
                raise _Bad("its index points outside the chunk")
            hl = gather(d, off, "u4").astype(np.int64)
            if np.any(hl > 4096) or np.any(off + 8 + hl > len(d)):
                raise _Bad("a message record header is damaged")
            dl = gather(d, off + 4 + hl, "u4").astype(np.int64)
            start = off + 8 + hl
            if np.any(start + dl > len(d)):
                raise _Bad("a message runs past the chunk")
            if not all(_op(d, int(off[i]), int(hl[i])) == 2 for i in {0, len(off) - 1}):
                # an index entry points at a connection record before its message: walk
                start, dl = _walk_records(d, off)
            k = np.argsort(start, kind="stable")
            buf, out_start, n = compact(d, start[k], dl[k])
            sink.add(cid, Payloads(buf, out_start, n, t[k], (seq << 32) + off[k]))


def open_bag(path: Path, progress: ProgressCallback | None = None) -> Ros1Source:
    """The source of a ROS 1 bag; LogError naming the fix for a version other than 2.0."""
    head = read_head(path)
    if not head.startswith(b"#ROSBAG V2.0"):
        version = head[9:12].decode("ascii", "replace")
        raise LogError(
            f"Expected a ROS 1 bag of version 2.0, got version {version} in {path}; "
            f"`rosbag fix {path.name} out.bag` rewrites it as 2.0"
        )
    return Ros1Source(path, progress)

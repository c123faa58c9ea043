"""The MCAP records as this reader parses them: opcodes, layouts, bounds and decompression.

Everything here is a function of bytes; the readers (:mod:`.indexed`, :mod:`.streaming`) walk
the file and keep state. A damaged record raises :class:`BadRecord` (one line), which a reader
turns into a :class:`~imu_dcm.logio.types.Damage`.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from imu_dcm.errors import LogError
from imu_dcm.logio.meta import custom_data, load_yaml
from imu_dcm.logio.paths import MCAP_MAGIC as MAGIC
from imu_dcm.logio.ros.cdr import gather

__all__ = [
    "CHUNK_HEAD",
    "MAGIC",
    "MAX_CHUNK_BYTES",
    "MAX_META_RECORD",
    "MSG",
    "MSG_HEADER",
    "OP_CHANNEL",
    "OP_CHUNK",
    "OP_CHUNK_INDEX",
    "OP_DATA_END",
    "OP_FOOTER",
    "OP_MESSAGE",
    "OP_METADATA",
    "OP_METADATA_INDEX",
    "OP_MSG_INDEX",
    "OP_SCHEMA",
    "OP_STATISTICS",
    "REC",
    "BadRecord",
    "chunk_head",
    "compact",
    "decompress",
    "decompress_into",
    "header_profile",
    "parse_channel",
    "parse_schema",
    "read_string",
    "rosbag2_custom_data",
    "size_bound",
]

OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK, OP_MSG_INDEX = 2, 3, 4, 5, 6, 7
OP_CHUNK_INDEX, OP_STATISTICS, OP_METADATA, OP_METADATA_INDEX, OP_DATA_END = 8, 11, 12, 13, 15
REC = struct.Struct("<BQ")
MSG = struct.Struct("<BQHIQQ")  # opcode, length, channel_id, sequence, log_time, publish_time
MSG_HEADER = MSG.size  # 31 bytes before the payload of a message record
CHUNK_HEAD = struct.Struct("<QQQI")  # start time, end time, uncompressed size, uncompressed crc
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


class BadRecord(Exception):
    """A damaged record: ``why`` is one line."""


def read_string(buf, pos: int) -> tuple[str, int]:
    (n,) = struct.unpack_from("<I", buf, pos)
    end = pos + 4 + n
    if end > len(buf):
        raise BadRecord("a string runs past its record")
    return bytes(buf[pos + 4 : end]).decode("utf-8", errors="replace"), end


def decompress(compression: str, data: bytes, size: int) -> bytes:
    """Decompress a chunk to exactly ``size`` bytes, never more; raises BadRecord otherwise."""
    if compression == "":
        out = data
    elif compression == "zstd":
        import zstandard  # lazy: with lz4, ~6 ms of CPU at import (a ULog replay needs neither)

        declared = zstandard.frame_content_size(data) if len(data) >= 4 else -2
        if declared not in (-1, size):
            raise BadRecord(f"its zstd frame declares {declared} bytes, the chunk {size}")
        try:
            out = zstandard.ZstdDecompressor().decompress(data, max_output_size=max(size, 1))
        except zstandard.ZstdError as exc:
            raise BadRecord(f"it does not decompress ({str(exc)[:60]})") from None
    elif compression == "lz4":
        import lz4.frame  # lazy: only an lz4 chunk needs it

        try:
            out = lz4.frame.LZ4FrameDecompressor().decompress(data, max_length=size + 1)
        except RuntimeError as exc:
            raise BadRecord(f"it does not decompress ({str(exc)[:60]})") from None
    else:
        raise LogError(f"Expected chunk compression zstd, lz4 or none, got {compression!r}")
    if len(out) != size:
        raise BadRecord(
            f"it decompresses to {len(out)}{'+' if len(out) > size else ''} bytes, "
            f"not its declared {size}"
        )
    return out


def decompress_into(compression: str, data: bytes, out: memoryview) -> str | None:
    """Decompress a chunk into ``out``, filling it exactly; returns why not (one line) or None."""
    size = len(out)
    try:
        if compression == "zstd":
            import zstandard  # lazy, as in decompress

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
    except BadRecord as exc:
        return str(exc)
    out[:] = got
    return None


def parse_schema(buf, pos: int, out: dict) -> None:
    (sid,) = struct.unpack_from("<H", buf, pos)
    name, p = read_string(buf, pos + 2)
    enc, p = read_string(buf, p)
    (n,) = struct.unpack_from("<I", buf, p)
    out[sid] = (name, enc, bytes(buf[p + 4 : p + 4 + n]))


def parse_channel(buf, pos: int, out: dict) -> None:
    cid, sid = struct.unpack_from("<HH", buf, pos)
    topic, p = read_string(buf, pos + 4)
    enc, p = read_string(buf, p)
    out[cid] = (sid, topic, enc)


def rosbag2_custom_data(buf: bytes, where: Path) -> dict[str, str]:
    """``custom_data`` of a Metadata record body named ``rosbag2`` (empty for any other name).

    rosbag2 stores its bag information (the ``metadata.yaml`` body) in such a record's
    ``serialized_metadata``, so a single ``.mcap`` carries it without the folder's file.
    """
    name, p = read_string(buf, 0)
    if name != "rosbag2":
        return {}
    (n,) = struct.unpack_from("<I", buf, p)
    p, end, entries = p + 4, p + 4 + n, {}
    while p < min(end, len(buf)):
        key, p = read_string(buf, p)
        entries[key], p = read_string(buf, p)
    doc = load_yaml(entries.get("serialized_metadata", ""), where, "rosbag2 metadata record")
    if isinstance(doc, dict) and isinstance(doc.get("rosbag2_bagfile_information"), dict):
        doc = doc["rosbag2_bagfile_information"]
    return custom_data(doc) if isinstance(doc, dict) else {}


def chunk_head(f, pos: int, length: int, size: int) -> tuple[int, int, int, str, int]:
    """The chunk record at ``pos`` of a file of ``size`` bytes (``f`` positioned after its
    opcode and length), checked:
    (file offset of its records, their compressed size, uncompressed size, compression,
    CRC). Raises BadRecord."""
    if length < 40 or pos + 9 + length > size:
        raise BadRecord(f"its record of {length} bytes runs past the end of the file")
    head = f.read(min(length, 4096))
    _t0, _t1, usize, crc = CHUNK_HEAD.unpack_from(head, 0)
    comp, p = read_string(head, 28)
    (n,) = struct.unpack_from("<Q", head, p)
    if p + 8 + n != length:
        raise BadRecord(f"its records size {n} does not match its record length {length}")
    if usize > size_bound(n):
        raise BadRecord(
            f"it declares {usize} bytes uncompressed from {n} (refused, beyond {size_bound(n)})"
        )
    if comp == "" and usize != n:
        raise BadRecord(f"it is uncompressed but declares {usize} bytes for {n}")
    if comp not in ("", "zstd", "lz4"):
        raise LogError(f"Expected chunk compression zstd, lz4 or none, got {comp!r}")
    return pos + 9 + p + 8, n, usize, comp, crc


def header_profile(f) -> str:
    """The profile named by the header record at the file's position ("" when unreadable)."""
    try:
        op, length = REC.unpack(f.read(9))
        if op == 1 and length < 1 << 16:
            return read_string(f.read(length), 0)[0]
    except (struct.error, BadRecord):
        pass
    return ""

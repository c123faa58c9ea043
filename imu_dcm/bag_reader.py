"""Read gyro logs (ROS 2 bags with MCAP storage, or single ``.mcap`` files) fast, in bulk.

The reader walks the MCAP records itself: it decompresses each chunk once, notes where every
message of every channel sits, and then decodes the ROS 2 CDR payloads of one channel *all at
once* with numpy. The byte layout comes from the ``ros2msg`` definition embedded in the file: a
vectorised walker follows the fields in order, keeping one offset per message (strings and
sequences make offsets differ between messages, e.g. a ``frame_id`` of varying length), aligning
each primitive to its size relative to the payload after the 4-byte CDR encapsulation header, and
gathers the wanted leaves (``header.stamp``, ``angular_velocity`` ...) with one fancy index each.
This is what makes a replay ~10x faster than decoding one Python object per message. Layouts the
walker cannot follow (sequences of strings or of messages before a wanted field) fall back to the
``mcap_ros2`` decoder, message by message. JSON channels are parsed with :mod:`json`.

Conventions: stamps are int64 nanoseconds (``t_ns``); rates ``omega_b`` are the body angular
velocity in body (sensor) axes as the log stores them (normally rad/s); quaternions are
``[x, y, z, w]`` (ROS order, Hamilton) and, for truth, ``q_w_b`` maps body to world.

A truncated or corrupt file is read up to the last complete record (an :class:`ImuDcmWarning`
says where it stopped). A missing path, a file that is not MCAP, an empty log, a log without an
IMU channel or with an unknown message encoding raise :class:`imu_dcm.errors.LogError`.
"""

from __future__ import annotations

import json
import re
import struct
import warnings
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from imu_dcm.errors import ImuDcmWarning, LogError

__all__ = [
    "TRUTH_TYPES",
    "ChannelInfo",
    "ImuSeries",
    "LogData",
    "TruthSeries",
    "read_custom_data",
    "read_log",
    "resolve_mcap_path",
]

MCAP_MAGIC = b"\x89MCAP0\r\n"
IMU_TYPE = "sensor_msgs/msg/Imu"
#: Truth message types and the field path of the quaternion ``q_w_b`` inside each.
TRUTH_TYPES = {
    "geometry_msgs/msg/QuaternionStamped": "quaternion",
    "geometry_msgs/msg/PoseStamped": "pose.orientation",
    "geometry_msgs/msg/PoseWithCovarianceStamped": "pose.pose.orientation",
    "geometry_msgs/msg/TransformStamped": "transform.rotation",
    "nav_msgs/msg/Odometry": "pose.pose.orientation",
}
KNOWN_ENCODINGS = ("cdr", "json")

_OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK = 0x03, 0x04, 0x05, 0x06
_OP_DATA_END, _OP_FOOTER, _OP_MESSAGE_INDEX = 0x0F, 0x02, 0x07
_REC = struct.Struct("<BQ")
_MSG = struct.Struct("<BQHIQQ")  # opcode, length, channel_id, sequence, log_time, publish_time
_MSG_HEADER = _MSG.size  # 31 bytes before the payload of a message record


# ----------------------------------------------------------------------------------- results
@dataclass(frozen=True)
class ChannelInfo:
    """One channel of the log: ``topic``, message ``type`` (schema name), ``encoding``, count."""

    topic: str
    type: str
    encoding: str
    count: int


@dataclass(frozen=True)
class ImuSeries:
    """Gyro samples of the IMU channel, in file order (not yet sorted or cleaned).

    Attributes
    ----------
    t_ns : int64 (N,) — sample stamps, ns (``header.stamp``; the log time for JSON without one).
    log_t_ns : int64 (N,) — the container's log (receive) time of each sample, ns.
    omega_b : float64 (N, 3) — angular velocity, body (sensor) axes, in the log's unit (rad/s
        for ROS). Not cleaned: may hold NaN/Inf.
    orientation_xyzw : float64 (N, 4) or None — the message's own orientation ``q_w_b``
        ``[x, y, z, w]``; NaN rows where ``orientation_covariance[0] == -1`` (none given).
    topic, type, frame_id : where the samples came from.
    """

    t_ns: NDArray[np.int64]
    log_t_ns: NDArray[np.int64]
    omega_b: NDArray[np.float64]
    orientation_xyzw: NDArray[np.float64] | None
    topic: str
    type: str
    frame_id: str


@dataclass(frozen=True)
class TruthSeries:
    """Reference attitude samples ``q_w_b`` (``[x, y, z, w]``, body to world) with stamps.

    ``t_ns`` header stamps and ``log_t_ns`` log times, int64 (M,); ``auto`` is true when the
    channel was picked automatically (not named by the caller).
    """

    t_ns: NDArray[np.int64]
    log_t_ns: NDArray[np.int64]
    q_w_b: NDArray[np.float64]
    topic: str
    type: str
    frame_id: str = ""
    child_frame_id: str = ""
    auto: bool = False


@dataclass(frozen=True)
class LogData:
    """What :func:`read_log` found: the IMU series, the truth (or None) and the channel list."""

    path: Path
    imu: ImuSeries
    truth: TruthSeries | None
    channels: tuple[ChannelInfo, ...]
    custom_data: dict[str, str] = field(default_factory=dict)
    stopped_at: str | None = None  # where a truncated/corrupt file stopped being readable


# ------------------------------------------------------------------------------ file walking
@dataclass
class _Schema:
    name: str
    encoding: str
    data: bytes


@dataclass
class _Channel:
    id: int
    schema_id: int
    topic: str
    encoding: str


@dataclass
class _Scan:
    """Raw result of walking an MCAP file: segments of bytes and per-channel message spans."""

    schemas: dict[int, _Schema] = field(default_factory=dict)
    channels: dict[int, _Channel] = field(default_factory=dict)
    segments: list[bytes] = field(default_factory=list)
    # per channel: lists of (segment index, payload start, payload length, log_time) arrays
    spans: dict[int, list[tuple[int, NDArray, NDArray, NDArray]]] = field(default_factory=dict)
    stopped_at: str | None = None
    joined: tuple | None = None  # (segments used, concatenated bytes, shift per segment)
    progress: Callable[[float], None] | None = None  # called with the fraction of bytes read


def _read_str(buf: bytes | memoryview, pos: int) -> tuple[str, int]:
    (n,) = struct.unpack_from("<I", buf, pos)
    end = pos + 4 + n
    if end > len(buf):
        raise struct.error("string runs past the record")
    return bytes(buf[pos + 4 : end]).decode("utf-8", errors="replace"), end


def _parse_schema(buf, pos: int) -> tuple[int, _Schema]:
    (sid,) = struct.unpack_from("<H", buf, pos)
    name, p = _read_str(buf, pos + 2)
    enc, p = _read_str(buf, p)
    (n,) = struct.unpack_from("<I", buf, p)
    return sid, _Schema(name, enc, bytes(buf[p + 4 : p + 4 + n]))


def _parse_channel(buf, pos: int) -> _Channel:
    cid, sid = struct.unpack_from("<HH", buf, pos)
    topic, p = _read_str(buf, pos + 4)
    enc, p = _read_str(buf, p)
    return _Channel(cid, sid, topic, enc)


def _decompress(compression: str, data: bytes, size: int) -> bytes:
    if compression == "":
        return data
    if compression == "zstd":
        import zstandard

        return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
    if compression == "lz4":
        import lz4.frame

        return lz4.frame.decompress(data)
    raise LogError(f"Expected chunk compression zstd, lz4 or none, got {compression!r}")


def _walk_records(buf, start: int, end: int, scan: _Scan, seg: int, in_chunk: bool) -> int:
    """Walk records in ``buf[start:end]``; note messages of segment ``seg``. Returns stop pos.

    Messages are collected per channel into (payload start, payload length, log time) lists.
    Returns -1 when a data-end or footer record closed the walk. Raises ``struct.error`` /
    ``_Corrupt`` on a record that runs past ``end``.
    """
    unpack_rec = _REC.unpack_from
    unpack_msg = _MSG.unpack_from
    starts: dict[int, list[int]] = {}
    lens: dict[int, list[int]] = {}
    times: dict[int, list[int]] = {}
    pos = start
    pending = None  # (segment, data, [message offsets]) of a chunk awaiting its indices
    try:
        while pos + 9 <= end:
            op, length = unpack_rec(buf, pos)
            rec_end = pos + 9 + length
            if rec_end > end:
                raise _Corrupt(pos)
            if op == _OP_MESSAGE:
                _, _, cid, _, log_time, _ = unpack_msg(buf, pos)
                s = starts.get(cid)
                if s is None:
                    s = starts[cid] = []
                    lens[cid] = []
                    times[cid] = []
                s.append(pos + _MSG_HEADER)
                lens[cid].append(length - 22)
                times[cid].append(log_time)
            elif op == _OP_SCHEMA:
                sid, sch = _parse_schema(buf, pos + 9)
                scan.schemas[sid] = sch
            elif op == _OP_CHANNEL:
                ch = _parse_channel(buf, pos + 9)
                scan.channels[ch.id] = ch
            elif not in_chunk:
                if op == _OP_MESSAGE_INDEX and pending is not None:
                    cid, nbytes = struct.unpack_from("<HI", buf, pos + 9)
                    if pos + 15 + nbytes <= rec_end:
                        pairs = np.frombuffer(buf, "<u8", nbytes // 8, pos + 15)
                        pending[2].append(pairs[1::2].astype(np.int64))
                    pos = rec_end
                    continue
                if pending is not None:
                    _finish_chunk(*pending, scan)
                    pending = None
                if op == _OP_CHUNK:
                    pending = _read_chunk(buf, pos + 9, rec_end, scan)
                    if scan.progress is not None:
                        scan.progress(rec_end / end)
                elif op in (_OP_DATA_END, _OP_FOOTER):
                    return -1  # the data section ended properly
            pos = rec_end
        if pos < end and not in_chunk:
            raise _Corrupt(pos)
    finally:
        if pending is not None:  # a chunk that decompressed is good even if what follows is not
            _finish_chunk(*pending, scan)
        for cid, s in starts.items():
            scan.spans.setdefault(cid, []).append(
                (
                    seg,
                    np.asarray(s, dtype=np.int64),
                    np.asarray(lens[cid], dtype=np.int64),
                    np.asarray(times[cid], dtype=np.int64),
                )
            )
    return pos


class _Corrupt(Exception):
    def __init__(self, pos: int, why: str = "a record runs past the end of the file"):
        super().__init__(pos, why)
        self.pos = pos
        self.why = why


def _read_chunk(buf, pos: int, end: int, scan: _Scan) -> tuple[int, bytes, list]:
    """Decompress and check one chunk; returns (segment index, data, empty index list)."""
    _, _, size, crc = struct.unpack_from("<QQQI", buf, pos)
    compression, p = _read_str(buf, pos + 28)
    (n,) = struct.unpack_from("<Q", buf, p)
    if p + 8 + n > end:
        raise _Corrupt(pos, "a chunk runs past its record")
    import zstandard

    try:
        data = _decompress(compression, bytes(buf[p + 8 : p + 8 + n]), size)
    except LogError:
        raise
    except (zstandard.ZstdError, RuntimeError, ValueError, MemoryError) as exc:
        raise _Corrupt(pos, f"a chunk does not decompress ({type(exc).__name__})") from None
    if len(data) != size or (crc != 0 and zlib.crc32(data) != crc):
        raise _Corrupt(pos, "a chunk fails its size or CRC check")
    scan.segments.append(data)
    return len(scan.segments) - 1, data, []


def _finish_chunk(seg: int, data: bytes, index: list[NDArray[np.int64]], scan: _Scan) -> None:
    """Note the messages of a decompressed chunk, from its message indices when it has them.

    The indices give every message record's offset, so records are located without a Python
    loop; whatever lies between the indexed records (schemas, channels, unindexed messages) is
    walked record by record. Without indices, or when they disagree with the data, the whole
    chunk is walked.
    """
    size = len(data)
    if index:
        offs = np.sort(np.concatenate(index))  # channels never share an offset
        d = np.frombuffer(data, np.uint8)
        if len(offs) and offs[0] >= 0 and offs[-1] + _MSG_HEADER <= size and np.all(
            d[offs] == _OP_MESSAGE
        ):
            length = _gather(d, offs + 1, "u8").astype(np.int64)
            ends = offs + 9 + length
            if np.all(ends[:-1] <= offs[1:]) and ends[-1] <= size:
                gap_starts = np.concatenate([[0], ends])
                gap_ends = np.concatenate([offs, [size]])
                view = memoryview(data)
                has_gap = gap_ends > gap_starts
                for a, b in zip(gap_starts[has_gap].tolist(), gap_ends[has_gap].tolist()):
                    _walk_records(view, a, b, scan, seg, in_chunk=True)
                cid = _gather(d, offs + 9, "u2").astype(np.int64)
                log_time = _gather(d, offs + 15, "u8").astype(np.int64)
                for c in np.unique(cid).tolist():
                    m = cid == c
                    scan.spans.setdefault(c, []).append(
                        (seg, offs[m] + _MSG_HEADER, length[m] - 22, log_time[m])
                    )
                return
    _walk_records(memoryview(data), 0, size, scan, seg, in_chunk=True)


def _scan_file(path: Path, progress: Callable[[float], None] | None = None) -> _Scan:
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise LogError(f"Expected a readable MCAP file, got {path} ({exc.strerror})") from None
    if len(data) == 0:
        raise LogError(f"Expected an MCAP file, got an empty file: {path}")
    if not data.startswith(MCAP_MAGIC):
        raise LogError(f"Expected an MCAP file (magic \\x89MCAP0), got {data[:8]!r} in {path}")
    scan = _Scan(progress=progress)
    scan.segments.append(data)
    try:
        stop = _walk_records(memoryview(data), len(MCAP_MAGIC), len(data), scan, 0, False)
        if stop != -1:
            scan.stopped_at = f"the file ends without its data-end record at byte {stop}"
    except _Corrupt as exc:
        scan.stopped_at = f"{exc.why} at byte {exc.pos} of {len(data)}"
    except struct.error:
        scan.stopped_at = f"a record is malformed (file of {len(data)} bytes)"
    return scan


# ------------------------------------------------------------------ ros2msg definition graph
_PRIM = {
    "bool": "u1", "byte": "u1", "char": "u1", "octet": "u1", "int8": "i1", "uint8": "u1",
    "int16": "i2", "uint16": "u2", "int32": "i4", "uint32": "u4", "int64": "i8",
    "uint64": "u8", "float32": "f4", "float64": "f8", "float": "f4", "double": "f8",
}  # fmt: skip
_FIELD_RE = re.compile(r"^\s*([A-Za-z0-9_/]+(?:<=\d+)?)(\[(<=)?(\d*)\])?\s+([A-Za-z0-9_]+)")


@dataclass(frozen=True)
class _Field:
    name: str
    base: str  # primitive name, "string", or full type "pkg/msg/Name"
    array: str | None  # None, "fixed", "seq"
    count: int


def _norm_type(t: str, pkg: str) -> str:
    t = t.strip()
    if t in _PRIM or t.startswith(("string", "wstring")):
        return "string" if t.startswith(("string", "wstring")) else t
    if t == "Header":
        return "std_msgs/msg/Header"
    parts = t.split("/")
    if len(parts) == 1:
        return f"{pkg}/msg/{t}"
    return f"{parts[0]}/msg/{parts[-1]}"


def _parse_definitions(root: str, text: str) -> dict[str, list[_Field]]:
    """All message definitions in a ros2msg schema text, by full type name."""
    defs: dict[str, list[_Field]] = {}
    name = _norm_type(root, root.split("/")[0])
    for block in re.split(r"^=+\s*$", text, flags=re.MULTILINE):
        lines = block.strip("\n").splitlines()
        if lines and lines[0].startswith("MSG:"):
            name = _norm_type(lines[0][4:].strip(), "")
            lines = lines[1:]
        pkg = name.split("/")[0]
        fields = []
        for line in lines:
            line = line.split("#", 1)[0]
            m = _FIELD_RE.match(line)
            if not m or "=" in line:
                continue  # blank, comment or constant (NAME=value)
            base, arr, _, n, fname = m.groups()
            array = None if arr is None else ("fixed" if n and not _ else "seq")
            fields.append(_Field(fname, _norm_type(base, pkg), array, int(n) if n else 0))
        defs[name] = fields
    return defs


def _find_imu_path(defs: dict[str, list[_Field]], root: str, depth: int = 0) -> str | None:
    """Field path of an Imu inside type ``root`` ("" if root is the Imu), else None."""
    if root == IMU_TYPE:
        return ""
    if depth > 4 or root not in defs:
        return None
    for f in defs[root]:
        if f.array is None and f.base in defs:
            sub = _find_imu_path(defs, f.base, depth + 1)
            if sub is not None:
                return f.name if sub == "" else f"{f.name}.{sub}"
    return None


class _Unsupported(Exception):
    """The vectorised walker cannot follow this layout; use the per-message decoder."""


def _gather(buf: NDArray[np.uint8], pos: NDArray[np.int64], dtype: str, n: int = 1) -> NDArray:
    """Read ``n`` consecutive little-endian ``dtype`` values at each byte position ``pos``.

    A view of the byte buffer with a stride of one byte and the item size of ``dtype`` puts a
    (possibly unaligned) value at every byte position, so one fancy index reads them all.
    """
    dt = np.dtype("<" + dtype)
    count = len(buf) - dt.itemsize + 1
    if count <= 0:
        return np.zeros((len(pos), n) if n > 1 else len(pos), dtype=dt)
    view = np.ndarray((count,), dtype=dt, buffer=buf, strides=(1,))
    if n == 1:
        return view[pos]
    return view[pos[:, None] + dt.itemsize * np.arange(n)]


def _walk_layout(
    defs: dict[str, list[_Field]],
    type_name: str,
    buf: NDArray[np.uint8],
    base: NDArray[np.int64],
    off: NDArray[np.int64],
    end: NDArray[np.int64],
    want: dict[str, tuple[str, int]],
    out: dict[str, NDArray],
    prefix: str = "",
) -> NDArray[np.int64]:
    """Advance per-message offsets ``off`` through ``type_name``; gather wanted leaves.

    ``base`` is each payload's byte position after the 4-byte encapsulation header (CDR aligns
    relative to it); ``end`` the payload end, for bounds checks. ``want`` maps a field path to
    (dtype, count). Returns the offsets after the type. Stops early once all wanted are found.
    """
    if type_name not in defs:
        raise _Unsupported(f"no definition of {type_name}")
    for f in defs[type_name]:
        if len(out) == len(want):
            return off
        path = prefix + f.name
        inside = [k for k in want if k == path or k.startswith(path + ".")]
        if f.base in _PRIM:
            size = np.dtype(_PRIM[f.base]).itemsize
            if f.array == "seq":
                off = (off + 3) & ~3
                cnt = _gather(buf, np.minimum(base + off, end - 4), "u4").astype(np.int64)
                off = off + 4
                n = cnt
            else:
                n = f.count if f.array == "fixed" else 1
            if size > 1:
                off = (off + size - 1) & ~(size - 1)
            if path in want:
                if f.array == "seq":
                    raise _Unsupported("a wanted field is a sequence")
                dtype, count = want[path]
                if np.any(base + off + size * count > end):
                    raise _Corrupt(0, "a message is shorter than its layout")
                out[path] = _gather(buf, base + off, _PRIM[f.base], count).astype(dtype)
            off = off + size * n
        elif f.base == "string":
            if f.array is not None or inside:
                raise _Unsupported("string arrays or wanted strings")
            off = (off + 3) & ~3
            if np.any(base + off + 4 > end):
                raise _Corrupt(0, "a message is shorter than its layout")
            off = off + 4 + _gather(buf, base + off, "u4").astype(np.int64)
        else:
            if f.array is not None:
                if inside:
                    raise _Unsupported("a wanted field inside an array of messages")
                raise _Unsupported("an array of messages before the wanted fields")
            off = _walk_layout(defs, f.base, buf, base, off, end, want, out, path + ".")
    return off


def _frame_id(seg: bytes, start: int) -> str:
    """frame_id of an Imu whose payload starts at ``start`` (its header comes first)."""
    try:
        (n,) = struct.unpack_from("<I", seg, start + 12)
        return bytes(seg[start + 16 : start + 15 + n]).decode("utf-8", errors="replace")
    except struct.error:
        return ""


# ------------------------------------------------------------------------- channel decoding
@dataclass
class _Raw:
    """Concatenated payloads of one channel: ``buf[start[i] : start[i] + length[i]]``."""

    buf: NDArray[np.uint8]
    start: NDArray[np.int64]
    length: NDArray[np.int64]
    log_time: NDArray[np.int64]
    segments: list[bytes]
    seg_idx: NDArray[np.int64]
    seg_start: NDArray[np.int64]


def _collect(scan: _Scan, cid: int) -> _Raw:
    spans = scan.spans.get(cid, [])
    # Concatenate the decompressed chunks (and the file itself only when it holds messages
    # outside chunks) once per scan; payload positions shift by each segment's place.
    used = tuple(sorted({s[0] for s in spans} | set(range(1, len(scan.segments)))))
    if scan.joined is None or scan.joined[0] != used:
        shift, total = {}, 0
        for seg in used:
            shift[seg] = total
            total += len(scan.segments[seg])
        pieces = b"".join(scan.segments[seg] for seg in used)
        scan.joined = (used, np.frombuffer(pieces, dtype=np.uint8), shift)
    _, buf, shift = scan.joined
    if spans:
        start = np.concatenate([s[1] + shift[s[0]] for s in spans])
        length = np.concatenate([s[2] for s in spans])
        log_time = np.concatenate([s[3] for s in spans])
        seg_idx = np.concatenate([np.full(len(s[1]), s[0]) for s in spans])
        seg_start = np.concatenate([s[1] for s in spans])
    else:
        start = length = log_time = seg_idx = seg_start = np.zeros(0, np.int64)
    return _Raw(buf, start, length, log_time, scan.segments, seg_idx, seg_start)


def _decode_cdr(
    raw: _Raw, schema: _Schema, want: dict[str, tuple[str, int]], topic: str
) -> tuple[dict[str, NDArray], NDArray[np.bool_]]:
    """Decode wanted leaves of every CDR message; returns arrays and a mask of good messages."""
    n = len(raw.start)
    good = raw.length >= 4
    if n == 0:
        return {k: np.zeros((0, c) if c > 1 else 0, dtype=d) for k, (d, c) in want.items()}, good
    enc = np.where(good, raw.buf[np.minimum(raw.start + 1, len(raw.buf) - 1)], 1)
    if np.any(enc[good] != 1):
        if np.all(enc[good] == 0):
            return _decode_slow(raw, schema, want, topic)
        good &= enc == 1  # mixed endianness: keep the little-endian ones
    defs = _parse_definitions(schema.name, schema.data.decode("utf-8", errors="replace"))
    idx = np.flatnonzero(good)
    base = raw.start[idx] + 4
    end = raw.start[idx] + raw.length[idx]
    try:
        out: dict[str, NDArray] = {}
        _walk_layout(defs, _norm_type(schema.name, ""), raw.buf, base, np.zeros_like(base), end,
                     want, out)  # fmt: skip
        if len(out) != len(want):
            raise _Unsupported(f"fields {sorted(set(want) - set(out))} not found")
    except _Unsupported:
        return _decode_slow(raw, schema, want, topic)
    except _Corrupt:
        # Some messages are shorter than the layout: decode the others one by one.
        return _decode_slow(raw, schema, want, topic)
    full = {}
    for k, v in out.items():
        arr = np.full((n,) + v.shape[1:], np.nan if v.dtype.kind == "f" else 0, dtype=v.dtype)
        arr[idx] = v
        full[k] = arr
    return full, good


def _decode_slow(
    raw: _Raw, schema: _Schema, want: dict[str, tuple[str, int]], topic: str
) -> tuple[dict[str, NDArray], NDArray[np.bool_]]:
    """Per-message fallback with the ``mcap_ros2`` decoder (for layouts the walker can't do)."""
    from mcap.records import Schema as McapSchema
    from mcap_ros2.decoder import DecoderFactory

    mcap_schema = McapSchema(id=0, name=schema.name, encoding=schema.encoding, data=schema.data)
    decoder = DecoderFactory().decoder_for("cdr", mcap_schema)
    if decoder is None:
        raise LogError(f"Expected a ros2msg schema for {topic}, got {schema.encoding!r}")
    n = len(raw.start)
    out = {k: np.full((n, c) if c > 1 else n, np.nan if np.dtype(d).kind == "f" else 0, dtype=d)
           for k, (d, c) in want.items()}  # fmt: skip
    good = np.zeros(n, dtype=bool)
    for i in range(n):
        seg = raw.segments[raw.seg_idx[i]]
        s = int(raw.seg_start[i])
        try:
            msg = decoder(bytes(seg[s : s + int(raw.length[i])]))
            vals = {}
            for k, (_, c) in want.items():
                v = msg
                for part in k.split("."):
                    v = getattr(v, part)
                vals[k] = v
        except (ValueError, IndexError, AttributeError, TypeError, struct.error):
            continue  # a corrupt payload: counted as dropped by the caller
        for k, (_, c) in want.items():
            v = vals[k]
            if isinstance(v, (list, tuple, np.ndarray)):
                v = next(iter(v)) if c == 1 else list(v)[:c]
            out[k][i] = v
        good[i] = True
    return out, good


def _imu_want(prefix: str) -> dict[str, tuple[str, int]]:
    p = prefix + "." if prefix else ""
    return {
        p + "header.stamp.sec": ("i8", 1),
        p + "header.stamp.nanosec": ("i8", 1),
        p + "orientation.x": ("f8", 1),
        p + "orientation.y": ("f8", 1),
        p + "orientation.z": ("f8", 1),
        p + "orientation.w": ("f8", 1),
        p + "orientation_covariance": ("f8", 1),  # first element only
        p + "angular_velocity.x": ("f8", 1),
        p + "angular_velocity.y": ("f8", 1),
        p + "angular_velocity.z": ("f8", 1),
    }


def _header_prefix(defs: dict[str, list[_Field]], type_name: str) -> str | None:
    for f in defs.get(type_name, []):
        if f.base == "std_msgs/msg/Header" and f.array is None:
            return f.name
    return None


def _stamps(out: dict[str, NDArray], prefix: str) -> NDArray[np.int64]:
    p = prefix + "." if prefix else ""
    sec = out[p + "header.stamp.sec"].astype(np.int64)
    nsec = out[p + "header.stamp.nanosec"].astype(np.int64)
    return sec * 1_000_000_000 + nsec


# ------------------------------------------------------------------------------ public API
def resolve_mcap_path(path: str | Path) -> Path:
    """The ``.mcap`` file of a bag folder (metadata.yaml + .mcap) or a file path itself.

    Raises
    ------
    LogError
        When the path does not exist or a folder holds no ``.mcap`` file.
    """
    p = Path(path)
    if not p.exists():
        raise LogError(f"Expected an existing log path, got {str(path)!r} (no such file or folder)")
    if p.is_dir():
        files = sorted(p.glob("*.mcap"))
        if not files:
            names = ", ".join(sorted(x.name for x in p.iterdir())[:8]) or "nothing"
            raise LogError(f"Expected a bag folder with a .mcap file, got {p} holding {names}")
        if len(files) > 1:
            raise LogError(f"Expected one .mcap file in {p}, got {len(files)}: "
                           + ", ".join(f.name for f in files))  # fmt: skip
        return files[0]
    return p


def _load_yaml(text: str):
    """Parse YAML with PyYAML (C loader when built) or, failing that, ruamel.yaml (a rosbags
    dependency). Returns None when neither is installed or the text is not YAML."""
    try:
        import yaml
    except ImportError:
        try:
            from ruamel.yaml import YAML, YAMLError
        except ImportError:
            return None
        try:
            return YAML(typ="safe", pure=True).load(text)
        except YAMLError:
            return None
    try:
        return yaml.load(text, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))  # safe
    except yaml.YAMLError:
        return None


def read_custom_data(path: str | Path) -> dict[str, str]:
    """``custom_data`` of a rosbag2 folder's ``metadata.yaml`` (empty dict when absent)."""
    p = Path(path)
    meta = (p if p.is_dir() else p.parent) / "metadata.yaml"
    try:
        doc = _load_yaml(meta.read_text()) if meta.is_file() else None
    except OSError:
        doc = None
    info = (doc if isinstance(doc, dict) else {}).get("rosbag2_bagfile_information", {}) or {}
    return {str(k): str(v) for k, v in (info.get("custom_data") or {}).items()}


def _channel_list(scan: _Scan) -> tuple[ChannelInfo, ...]:
    out = []
    for cid, ch in sorted(scan.channels.items()):
        sch = scan.schemas.get(ch.schema_id)
        count = sum(len(s[1]) for s in scan.spans.get(cid, []))
        out.append(ChannelInfo(ch.topic, sch.name if sch else "", ch.encoding, count))
    return tuple(out)


def _describe(channels: tuple[ChannelInfo, ...]) -> str:
    if not channels:
        return "no channels"
    return ", ".join(f"{c.topic} ({c.type or 'no schema'}, {c.encoding}, {c.count})"
                     for c in channels)  # fmt: skip


def _json_messages(raw: _Raw) -> list[dict | None]:
    msgs: list[dict | None] = []
    for i in range(len(raw.start)):
        s = int(raw.start[i])
        try:
            m = json.loads(raw.buf[s : s + int(raw.length[i])].tobytes())
            msgs.append(m if isinstance(m, dict) else None)
        except ValueError:
            msgs.append(None)
    return msgs


def _collect_first(scan: _Scan, cid: int) -> dict | None:
    spans = scan.spans.get(cid, [])
    if not spans or not len(spans[0][1]):
        return None
    seg, s, n = spans[0][0], int(spans[0][1][0]), int(spans[0][2][0])
    try:
        m = json.loads(bytes(scan.segments[seg][s : s + n]))
    except ValueError:
        return None
    return m if isinstance(m, dict) else None


def _is_json_imu(m: dict | None) -> bool:
    av = (m or {}).get("angular_velocity")
    return isinstance(av, dict) and all(k in av for k in "xyz")


def _imu_candidates(scan: _Scan) -> tuple[dict[int, str], list[_Channel]]:
    """IMU channels (channel id -> Imu field path) and channels of unknown encodings."""
    found: dict[int, str] = {}
    unknown = []
    for cid, ch in scan.channels.items():
        sch = scan.schemas.get(ch.schema_id)
        if ch.encoding == "cdr" and sch is not None:
            if sch.name == IMU_TYPE or sch.name == "sensor_msgs/Imu":
                found[cid] = ""
                continue
            if sch.encoding == "ros2msg" and b"Imu" in sch.data:
                defs = _parse_definitions(sch.name, sch.data.decode("utf-8", errors="replace"))
                path = _find_imu_path(defs, _norm_type(sch.name, ""))
                if path is not None:
                    found[cid] = path
        elif ch.encoding == "json":
            if _is_json_imu(_collect_first(scan, cid)):
                found[cid] = "json"
        elif ch.encoding not in KNOWN_ENCODINGS:
            unknown.append(ch)
    return found, unknown


def _pick(scan: _Scan, topic: str | None, candidates: dict[int, str], what: str, flag: str) -> int:
    channels = _channel_list(scan)
    if topic is not None:
        ids = [cid for cid, ch in scan.channels.items() if ch.topic == topic]
        if not ids:
            raise LogError(f"Expected {what} topic {topic!r} in the log, got {_describe(channels)}")
        cid = ids[0]
        ch = scan.channels[cid]
        if ch.encoding not in KNOWN_ENCODINGS:
            raise LogError(f"Expected message encoding cdr or json on {topic}, "
                           f"got {ch.encoding!r}")  # fmt: skip
        if cid not in candidates:
            sch = scan.schemas.get(ch.schema_id)
            raise LogError(f"Expected {what} messages on {topic}, got "
                           f"{sch.name if sch else 'no schema'} ({ch.encoding})")  # fmt: skip
        return cid
    if len(candidates) > 1:
        names = ", ".join(sorted(scan.channels[c].topic for c in candidates))
        raise LogError(f"Expected one {what} channel, got {len(candidates)}: {names} "
                       f"(choose with {flag})")  # fmt: skip
    return next(iter(candidates))


def _read_imu(scan: _Scan, cid: int, path: str) -> tuple[ImuSeries, int]:
    ch = scan.channels[cid]
    sch = scan.schemas.get(ch.schema_id)
    raw = _collect(scan, cid)
    n = len(raw.start)
    if path == "json":
        msgs = _json_messages(raw)
        omega = np.full((n, 3), np.nan)
        t_ns = raw.log_time.copy()
        good = np.zeros(n, dtype=bool)
        for i, m in enumerate(msgs):
            if not _is_json_imu(m):
                continue
            av = m["angular_velocity"]
            try:
                omega[i] = [float(av["x"]), float(av["y"]), float(av["z"])]
                st = (m.get("header") or {}).get("stamp") or m.get("stamp")
                if st is not None:
                    t_ns[i] = int(st.get("sec", 0)) * 1_000_000_000 + int(
                        st.get("nanosec", st.get("nsec", 0))
                    )
            except (TypeError, ValueError, AttributeError):
                continue
            good[i] = True
        series = ImuSeries(t_ns[good], raw.log_time[good], omega[good], None, ch.topic, "json",
                           "")
        return series, int(n - good.sum())
    out, good = _decode_cdr(raw, sch, _imu_want(path), ch.topic)
    p = path + "." if path else ""
    t_ns = _stamps(out, path)
    omega = np.stack([out[p + "angular_velocity." + a] for a in "xyz"], axis=1)
    quat = np.stack([out[p + "orientation." + a] for a in "xyzw"], axis=1)
    cov0 = out[p + "orientation_covariance"]
    quat[cov0 == -1.0] = np.nan
    frame = ""
    if n and good.any():
        i = int(np.flatnonzero(good)[0])
        # only a bare Imu has its header's frame_id at a fixed place
        frame = "" if path else _frame_id(raw.segments[raw.seg_idx[i]], int(raw.seg_start[i]))
    q = quat[good] if np.isfinite(quat[good]).any() else None
    series = ImuSeries(t_ns[good], raw.log_time[good], omega[good], q, ch.topic, sch.name, frame)
    return series, int(n - good.sum())


def _truth_candidates(scan: _Scan) -> dict[int, str]:
    found = {}
    for cid, ch in scan.channels.items():
        sch = scan.schemas.get(ch.schema_id)
        if ch.encoding == "cdr" and sch is not None and _norm_type(sch.name, "") in TRUTH_TYPES:
            found[cid] = TRUTH_TYPES[_norm_type(sch.name, "")]
    return found


def _read_truth(scan: _Scan, cid: int, auto: bool) -> TruthSeries:
    ch = scan.channels[cid]
    sch = scan.schemas[ch.schema_id]
    qpath = TRUTH_TYPES[_norm_type(sch.name, "")]
    defs = _parse_definitions(sch.name, sch.data.decode("utf-8", errors="replace"))
    hdr = _header_prefix(defs, _norm_type(sch.name, "")) or "header"
    want = {f"{qpath}.{a}": ("f8", 1) for a in "xyzw"}
    want[hdr + ".stamp.sec"] = ("i8", 1)
    want[hdr + ".stamp.nanosec"] = ("i8", 1)
    raw = _collect(scan, cid)
    out, good = _decode_cdr(raw, sch, want, ch.topic)
    t_ns = out[hdr + ".stamp.sec"] * 1_000_000_000 + out[hdr + ".stamp.nanosec"]
    q = np.stack([out[f"{qpath}.{a}"] for a in "xyzw"], axis=1)
    return TruthSeries(t_ns[good].astype(np.int64), np.asarray(raw.log_time)[good].astype(np.int64),
                       q[good], ch.topic, sch.name, auto=auto)


def read_log(
    path: str | Path,
    imu_topic: str | None = None,
    truth_topic: str | None = None,
    truth_frame: str | None = None,
    progress: Callable[[float], None] | None = None,
) -> LogData:
    """Read the gyro samples and the reference attitude of a ROS 2 bag or an MCAP file.

    Parameters
    ----------
    path : str or Path
        A rosbag2 folder (``metadata.yaml`` + one ``.mcap``) or a single ``.mcap`` file. Never
        modified.
    imu_topic : str, optional
        The IMU channel. By default the one channel whose schema is ``sensor_msgs/msg/Imu``, a
        type containing an ``Imu`` field (vendor wrappers), or a JSON channel with
        ``angular_velocity {x, y, z}``.
    truth_topic : str, optional
        The reference attitude ``q_w_b``: ``geometry_msgs`` QuaternionStamped, PoseStamped,
        PoseWithCovarianceStamped, TransformStamped or ``nav_msgs`` Odometry; or the IMU topic
        itself for its own orientation. By default the one such channel not under
        ``/estimate``; else the Imu's orientation where ``orientation_covariance[0] != -1``
        (unit norm, and not one constant value: devices leave the default ``0,0,0,1`` behind
        a garbage covariance). ``"none"`` disables truth.
    truth_frame : str, optional
        Child frame of a transform truth (accepted for the ``/tf`` reader; unused here).
    progress : callable(fraction), optional
        Called after each chunk with the fraction of the file read (for a progress bar).

    Returns
    -------
    LogData
        IMU samples in file order (not cleaned), truth or None, the channel list.

    Raises
    ------
    LogError
        Missing path, not MCAP, empty log, no (or several) IMU channels, unknown encoding, a
        truth topic of the wrong type.

    Warns
    -----
    ImuDcmWarning
        A truncated or corrupt file: the readable part is returned and the warning says where
        reading stopped.
    """
    mcap_path = resolve_mcap_path(path)
    scan = _scan_file(mcap_path, progress)
    channels = _channel_list(scan)
    if scan.stopped_at:
        total = sum(c.count for c in channels)
        warnings.warn(
            f"{mcap_path.name} is truncated or corrupt: {scan.stopped_at}; "
            f"replaying the {total} messages before it",
            ImuDcmWarning,
            stacklevel=2,
        )
    if not channels or sum(c.count for c in channels) == 0:
        raise LogError(f"Expected messages in the log, got an empty log ({_describe(channels)}): "
                       f"{mcap_path}")  # fmt: skip
    candidates, unknown = _imu_candidates(scan)
    if imu_topic is None and not candidates:
        if unknown:
            ch = unknown[0]
            raise LogError(f"Expected message encoding cdr or json, got {ch.encoding!r} "
                           f"on {ch.topic}")  # fmt: skip
        raise LogError(f"Expected an IMU channel (sensor_msgs/msg/Imu or a type with an Imu "
                       f"field), got {_describe(channels)}")  # fmt: skip
    imu_cid = _pick(scan, imu_topic, candidates, "IMU", "--imu-topic")
    imu, undecodable = _read_imu(scan, imu_cid, candidates[imu_cid])
    if undecodable:
        warnings.warn(f"{imu.topic}: dropped {undecodable} messages that do not decode",
                      ImuDcmWarning, stacklevel=2)  # fmt: skip
    if len(imu.t_ns) == 0:
        raise LogError(f"Expected IMU samples on {imu.topic}, got none that decode")
    truth = None
    if truth_topic != "none":
        truth_c = _truth_candidates(scan)
        if truth_topic is not None and truth_topic == imu.topic:
            truth = _imu_truth(imu, required=True, auto=False)
        elif truth_topic is not None:
            tcid = _pick(scan, truth_topic, truth_c, "truth", "--truth-topic")
            truth = _read_truth(scan, tcid, auto=False)
        else:
            auto = {c: p for c, p in truth_c.items()
                    if not scan.channels[c].topic.startswith("/estimate")}  # fmt: skip
            if auto:
                truth = _read_truth(scan, _pick(scan, None, auto, "truth", "--truth-topic"),
                                    auto=True)
            else:
                truth = _imu_truth(imu, required=False, auto=True)
    return LogData(mcap_path, imu, truth, channels, read_custom_data(path), scan.stopped_at)


def _imu_truth(imu: ImuSeries, required: bool, auto: bool) -> TruthSeries | None:
    """The Imu's own orientation as truth where it is given (covariance[0] != -1, unit norm)."""
    q = imu.orientation_xyzw
    if q is None:
        if required:
            raise LogError(f"Expected an orientation on {imu.topic} (orientation_covariance[0] "
                           f"!= -1), got none")  # fmt: skip
        return None
    norm = np.linalg.norm(q, axis=1)
    ok = np.isfinite(norm) & (np.abs(norm - 1.0) < 1e-3)  # all-zero quaternions are not truth
    if not ok.any():
        if required:
            raise LogError(f"Expected unit orientation quaternions on {imu.topic}, got none")
        return None
    if not required and ok.sum() > 1 and np.all(q[ok] == q[ok][0]):
        # A constant quaternion (typically the default 0,0,0,1 behind a garbage covariance
        # instead of the -1 flag) is no estimate; it is used only when asked for by topic.
        return None
    return TruthSeries(imu.t_ns[ok], imu.log_t_ns[ok], q[ok] / norm[ok, None], imu.topic,
                       imu.type, imu.frame_id, auto=auto)

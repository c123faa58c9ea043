"""The scan of a ULog's message chain: the records of the wanted topics, gathered with numpy.

The ULog data section is a chain of ``[uint16 size][uint8 type][payload]`` messages (the
format PX4 documents). :func:`scan` walks that chain in blocks and gathers the records of the
wanted topics through the layouts the log's own format messages declare. A damaged message
costs only itself, and the one before it when its size may be what was damaged: the walk
resumes at the next sound messages (:mod:`imu_dcm.logio.containers.ulog_resync`) and each
damaged part is listed with its byte offset. Appended data and incompatible flags hand the
file to ``pyulog`` (PX4's own parser). A log cut short costs its last message.
"""

from __future__ import annotations

import contextlib
import io
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from imu_dcm import _kernels as kernel
from imu_dcm.errors import LogError
from imu_dcm.logio.containers.ulog_resync import KNOWN_TYPES, MAX_MESSAGE, Resync
from imu_dcm.logio.paths import ULOG_MAGIC as MAGIC
from imu_dcm.logio.source import ProgressCallback
from imu_dcm.logio.types import Damage

__all__ = ["BLOCK_BYTES", "Irregular", "Scanned", "Topic", "scan"]

BLOCK_BYTES = 8 << 20
_BASIC = {
    "int8_t": "i1",
    "uint8_t": "u1",
    "int16_t": "<i2",
    "uint16_t": "<u2",
    "int32_t": "<i4",
    "uint32_t": "<u4",
    "int64_t": "<i8",
    "uint64_t": "<u8",
    "float": "<f4",
    "double": "<f8",
    "bool": "u1",
    "char": "u1",
}
# Message types of the ULog format: F(ormat), I(nfo), M(ulti info), P(aram), Q (param default),
# A(dd subscription), R(emove), D(ata), L(og), C (tagged log), S(ync), O (dropout), B (flags).
_KNOWN = frozenset(KNOWN_TYPES)


class Irregular(Exception):
    """The fast scan met something only pyulog's recovery handles; ``skipped_at`` is the byte
    offset of a message pyulog skips (a type the format does not define), else -1."""

    def __init__(self, why: str, skipped_at: int = -1):
        super().__init__(why)
        self.skipped_at = skipped_at


def _check_flags(payload: bytes) -> None:
    """The flag-bits message: 8 compat bytes, 8 incompat bytes, 3 appended offsets."""
    if len(payload) < 16 or payload[8] & ~1 or any(payload[9:16]):
        raise Irregular("incompatible flag bits")
    if payload[8] & 1:
        raise Irregular("data appended after the log was written")


# ---------------------------------------------------------------------------- formats
def _parse_format(payload: bytes) -> tuple[str, list[tuple[str, int, str]]]:
    """``name:type field;type[n] field;...`` -> (name, [(type, n or 0, field)])."""
    text = payload.decode("utf-8", errors="replace")
    name, _, body = text.partition(":")
    fields = []
    for item in body.split(";"):
        item = item.strip()
        if not item:
            continue
        typ, _, fname = item.rpartition(" ")
        m = re.fullmatch(r"(.+)\[(\d+)\]", typ)
        fields.append((m.group(1), int(m.group(2)), fname) if m else (typ, 0, fname))
    return name, fields


def _dtype(name: str, formats: dict[str, bytes], depth: int = 0) -> np.dtype:
    """The packed numpy layout of format ``name`` (nested formats resolved)."""
    if depth > 16 or name not in formats:
        raise Irregular(f"format {name!r} undefined or nested too deep")
    parts = []
    for typ, n, fname in _parse_format(formats[name])[1]:
        base = np.dtype(_BASIC[typ]) if typ in _BASIC else _dtype(typ, formats, depth + 1)
        parts.append((fname, base, (n,)) if n else (fname, base))
    try:
        return np.dtype(parts)
    except (ValueError, TypeError) as exc:  # a field named twice, an empty or bad name
        raise Irregular(f"format {name!r} has no numpy layout ({exc})") from None


def _layout(name: str, formats: dict) -> tuple[np.dtype, int]:
    """(layout without the trailing padding, the padding's size): PX4 leaves the padding at
    the end of a record out of the log, so a record holds between the two sizes."""
    full = _dtype(name, formats)
    names = list(full.names or ())
    while names and names[-1].startswith("_padding"):
        names.pop()
    if not names:
        raise Irregular(f"format {name!r} has no fields")
    last = full.fields[names[-1]]
    size = last[1] + last[0].itemsize
    kept = np.dtype(
        {
            "names": names,
            "formats": [full.fields[n][0] for n in names],
            "offsets": [full.fields[n][1] for n in names],
            "itemsize": size,
        }
    )
    return kept, full.itemsize - size


def _flat(rec: NDArray) -> dict[str, NDArray]:
    """Fields of a structured array in pyulog's flat naming (``gyro_rad[0]``, ``x``)."""
    out: dict[str, NDArray] = {}
    for fname in rec.dtype.names or ():
        col = rec[fname]
        if col.dtype.names:  # a nested message: not needed by this reader
            continue
        if col.ndim == 2:
            for i in range(col.shape[1]):
                out[f"{fname}[{i}]"] = col[:, i]
        else:
            out[fname] = col
    return out


# ------------------------------------------------------------------------------- scan
@dataclass
class Topic:
    """One (topic, instance) as read: pyulog-style flat fields, file positions of its records."""

    name: str
    multi_id: int
    fields: dict[str, NDArray]
    positions: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, np.int64))

    def __len__(self) -> int:
        return len(self.fields.get("timestamp", ()))


@dataclass
class Scanned:
    """What the scan of one ULog found (internal)."""

    topics: list[Topic]
    counts: dict[tuple[str, int, str], int]  # (topic, instance, format) -> messages
    dropouts: list[tuple[int, int]]  # (file position or timestamp µs, duration ms)
    info: dict[str, str]
    start_us: int  # the log's start (its header), µs
    damage: list[Damage] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    dropout_times_us: list[int] = field(default_factory=list)


class _Scanner(Resync):
    """Walks the message chain of a ULog in blocks, keeping the records of ``wanted`` topics
    (and resuming after a damaged message: :class:`imu_dcm.logio.containers.ulog_resync.Resync`)."""

    def __init__(self, wanted: frozenset[str]):
        self.wanted = wanted
        self.formats: dict[str, bytes] = {}  # name -> its format message
        self.subs: dict[int, tuple[str, int, str]] = {}  # msg_id -> (name, instance, format)
        self.layouts: dict[int, tuple[np.dtype, int]] = {}
        self.blocks: dict[int, list[NDArray[np.uint8]]] = {}
        self.positions: dict[int, list[NDArray[np.int64]]] = {}
        self.counts: dict[int, int] = {}
        self.short: dict[int, int] = {}
        self.dropouts: list[tuple[int, int]] = []
        self.info: dict[str, str] = {}
        self.damage: list[Damage] = []

    def _special(self, typ: int, payload: bytes, at: int) -> None:
        if typ == 65:  # A: u8 instance, u16 msg_id, name
            if len(payload) < 4:
                raise Irregular(f"short subscription at byte {at}")
            inst, msg_id = payload[0], int.from_bytes(payload[1:3], "little")
            fmt = payload[3:].decode("utf-8", errors="replace")
            self.subs[msg_id] = (fmt, inst, fmt)
            if fmt in self.wanted:
                self.layouts[msg_id] = _layout(fmt, self.formats)
        elif typ == 70:  # F: parsed when a wanted topic needs it
            self.formats[payload.partition(b":")[0].decode("utf-8", "replace")] = payload
        elif typ == 79 and len(payload) >= 2:  # O: u16 ms
            self.dropouts.append((at, int.from_bytes(payload[:2], "little")))
        elif typ == 73 and payload:  # I: u8 key length, "type key", value
            n = payload[0]
            typ_key = payload[1 : 1 + n].decode("utf-8", errors="replace")
            if typ_key.startswith("char["):
                key = typ_key.partition(" ")[2]
                self.info[key] = payload[1 + n :].decode("utf-8", errors="replace")

    def walk(self, buf: bytes, base: int, final: bool = True) -> int:
        """Walk ``buf`` (file offset ``base``); gather data records; return bytes consumed.
        After a damaged message the walk resumes at the next sound ones (said in
        ``self.damage``); with none in ``buf`` and more to come, it stops before the damage."""
        b = np.frombuffer(buf, np.uint8)
        pos, typ, used = kernel.record_chain(b, 0)
        bad, ids = self._first_unsound(b, pos, typ)
        ahead = len(pos) if bad is None else bad  # formats and subscriptions first: the
        new = np.flatnonzero((typ[:ahead] == 65) | (typ[:ahead] == 70)).tolist()  # layouts
        for i in new:  # that judge the data messages' sizes
            at = int(pos[i])
            size = int(b[at]) | int(b[at + 1]) << 8
            self._special(int(typ[i]), buf[at + 3 : at + 3 + size], base + at)
        if new:
            bad, ids = self._first_unsound(b, pos, typ)
        found = None
        if bad is not None:
            found = self._resync(b, pos, bad, ids, final)
        elif final and len(b) - used > 3:  # a size past the end of the file, or cut short
            resume = self._resume_after(b, int(used), ids, final)
            found = (len(pos), int(used), resume) if resume < len(b) else None
        if found is not None:
            keep, start, resume = found
            pos, typ = pos[:keep], typ[:keep]
            if resume < 0 and start > 0:  # no sound message after it yet: retry with more
                used = start
            elif resume < 0:  # damage from the start of the buffer on: skip what cannot
                used = max(len(buf) - MAX_MESSAGE, 1)  # hold the start of a sound message
                self.damage.append(
                    Damage(base, f"ULog damaged bytes at byte {base}: {used} bytes skipped")
                )
            else:
                self.damage.append(
                    Damage(
                        base + start,
                        f"ULog damaged message at byte {base + start}: {resume - start} bytes "
                        "skipped to the next whole messages",
                    )
                )
                used = resume
        for i in np.flatnonzero(typ != 68).tolist():
            at, t = int(pos[i]), int(typ[i])
            size = int(b[at]) | int(b[at + 1]) << 8
            payload = buf[at + 3 : at + 3 + size]
            if t not in _KNOWN or size == 0:
                why = f"message type {t} of {size} bytes at byte {base + at}"
                raise Irregular(why, base + at if size else -1)
            if t in (73, 79):  # A and F: taken above
                self._special(t, payload, base + at)
            elif t == 66:
                _check_flags(payload)
        data = pos[typ == 68]
        if len(data):
            self._gather(b, data, base)
        return int(used)

    def _gather(self, b: NDArray[np.uint8], dpos: NDArray[np.int64], base: int) -> None:
        size = b[dpos].astype(np.int64) | (b[dpos + 1].astype(np.int64) << 8)
        ids = b[dpos + 3].astype(np.int64) | (b[dpos + 4].astype(np.int64) << 8)
        cnt = np.bincount(ids)
        for k in np.flatnonzero(cnt).tolist():
            if k not in self.subs:
                raise Irregular(f"data for unknown subscription {k}")
            self.counts[k] = self.counts.get(k, 0) + int(cnt[k])
        for k, (layout, pad) in self.layouts.items():
            if k >= len(cnt) or not cnt[k]:
                continue
            sel = np.flatnonzero(ids == k)
            n = size[sel] - 2
            ok = (n >= layout.itemsize) & (n <= layout.itemsize + pad)
            self.short[k] = self.short.get(k, 0) + int(len(sel) - np.count_nonzero(ok))
            if not ok.any():
                continue
            start = dpos[sel[ok]] + 5
            rows = np.lib.stride_tricks.sliding_window_view(b, layout.itemsize)[start]
            self.blocks.setdefault(k, []).append(rows)
            self.positions.setdefault(k, []).append(start + base)

    def topics(self) -> list[Topic]:
        out = []
        for k, parts in self.blocks.items():
            name, inst, _fmt = self.subs[k]
            rec = np.ascontiguousarray(np.concatenate(parts)).view(self.layouts[k][0])[:, 0]
            out.append(Topic(name, inst, _flat(rec), np.concatenate(self.positions[k])))
        return out


def _scan_fast(path: Path, wanted: frozenset[str], progress: ProgressCallback | None) -> Scanned:
    sc = _Scanner(wanted)
    total = max(path.stat().st_size, 1)
    damage: list[Damage] = []
    with open(path, "rb") as f:
        head = f.read(16)
        if len(head) < 16 or not head.startswith(MAGIC):
            raise LogError(f"Expected a ULog file (magic ULog\\x01\\x12\\x35), got {head[:8]!r}")
        carry, base = b"", 16
        while True:
            chunk = f.read(BLOCK_BYTES)
            buf = carry + chunk if carry else chunk
            used = sc.walk(buf, base, final=not chunk)
            carry, base = buf[used:], base + used
            if progress is not None:
                progress(min(base / total, 0.99))
            if not chunk and not (used and carry):
                break
    damage += sc.damage
    if carry:
        damage.append(
            Damage(base, f"ULog cut short: the last message at byte {base} is incomplete")
        )
    topics = sc.topics()
    counts: dict[tuple[str, int, str], int] = {}
    for k, v in sc.subs.items():
        if sc.counts.get(k):
            counts[v] = counts.get(v, 0) + sc.counts[k]
    for k, n in sc.short.items():
        if n:
            name, inst, _ = sc.subs[k]
            damage.append(Damage(-1, f"{name}[{inst}]: {n} records shorter than their format"))
    start_us = int.from_bytes(head[8:16], "little")
    return Scanned(topics, counts, sc.dropouts, sc.info, start_us, damage)


def _scan_pyulog(path: Path, wanted: frozenset[str], why: str) -> Scanned:
    """The same through pyulog's parser (for what the fast scan leaves to it)."""
    ulog_cls = _pyulog()
    with contextlib.redirect_stdout(io.StringIO()):  # pyulog prints what it recovers from
        log = ulog_cls(str(path), sorted(wanted))
    topics = [Topic(d.name, d.multi_id, dict(d.data)) for d in log.data_list]
    counts = {(t.name, t.multi_id, t.name): len(t) for t in topics}
    info = {k: v for k, v in log.msg_info_dict.items() if isinstance(v, str)}
    scanned = Scanned(topics, counts, [], info, int(log.start_timestamp))
    scanned.dropout_times_us = [int(d.timestamp) for d in log.dropouts]
    scanned.dropouts = [(-1, int(d.duration)) for d in log.dropouts]
    scanned.notes.append(f"read through pyulog's parser ({why})")
    if log.file_corruption:
        scanned.damage.append(Damage(-1, "ULog corrupt: pyulog skipped to its sync markers"))
    return scanned


def _pyulog():
    try:
        from pyulog import ULog  # lazy: only for the logs the fast scan hands over
    except ImportError:  # pragma: no cover - pyulog is a dependency
        raise LogError(
            "Expected pyulog to read this ULog, got no pyulog; `pip install pyulog`"
        ) from None
    return ULog


def scan(path: Path, wanted: frozenset[str], progress: ProgressCallback | None = None) -> Scanned:
    """Read the ``wanted`` topics of a ULog (fast scan; pyulog where the scan cannot)."""
    try:
        scanned = _scan_fast(path, wanted, progress)
    except Irregular as exc:
        try:
            scanned = _scan_pyulog(path, wanted, str(exc))
            if exc.skipped_at >= 0 and not scanned.damage:  # pyulog skips it: said as damage
                what = f"ULog message of a type the format does not define ({exc}) skipped"
                scanned.damage.append(Damage(exc.skipped_at, what))
        except LogError:
            raise
        except Exception as err:  # pyulog's own failure on a file the fast scan refused
            raise LogError(
                f"Expected a readable ULog, got {exc} (and pyulog: {type(err).__name__}: "
                f"{err}) in {path}"
            ) from None
    if not scanned.dropout_times_us:
        scanned.dropout_times_us = _dropout_times(scanned)
    return scanned


def _dropout_times(s: Scanned) -> list[int]:
    """Each dropout's time: the last kept record (µs) before it in the file."""
    timed = [t for t in s.topics if "timestamp" in t.fields]
    pos = np.concatenate([t.positions for t in timed] + [np.zeros(0, np.int64)])
    ts = np.concatenate(
        [t.fields["timestamp"].astype(np.int64) for t in timed] + [np.zeros(0, np.int64)]
    )
    order = np.argsort(pos, kind="stable")
    pos, ts = pos[order], ts[order]
    out = []
    for at, _ms in s.dropouts:
        i = int(np.searchsorted(pos, at)) - 1
        out.append(int(ts[i]) if i >= 0 else 0)
    return out

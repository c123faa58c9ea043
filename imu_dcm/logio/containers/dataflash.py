"""The records of a binary DataFlash log, indexed with resynchronisation after damage.

A DataFlash log is a run of records ``A3 95 <type> <payload>``; the length of each type comes
from the ``FMT`` records (type 0x80, 89 bytes) that declare it. The container has no checksum,
so a damaged byte shows only where the chain of records breaks: a record whose type no FMT
declares, or whose declared length does not end where another record begins.

How the index is built (numpy, one pass over the candidates, no per-record objects):

1. Every ``A3 95`` pair is a candidate record start.
2. The FMT records are taken from the candidates of type 0x80 whose content is a well-formed
   format (a name of letters and digits, format characters known to ArduPilot's reader, a
   length that matches them, one column per character). A record retagged as FMT fails this
   and is skipped, not obeyed.
3. The chain is followed from offset 0: a record is confirmed when its end is the end of the
   file or another candidate. At a break, the reader resynchronises at the next candidate that
   starts two confirmed records, and counts the bytes between as one damaged part (its byte
   offset, its cause). A record whose end lands on one record with damaged sync bytes is kept
   (only that next record is lost).

Zero or 0xFF padding after the last record (block logs end in up to a page of it) is not
damage; a last record cut short by the end of the file is counted by the decoder.
"""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from imu_dcm.logio.types import Damage

__all__ = ["Format", "Index", "index_log"]

HEAD = (0xA3, 0x95)
FMT_TYPE, FMT_LEN = 0x80, 89
_NAME = re.compile(r"[A-Za-z0-9_]{1,4}")
_COLUMN = re.compile(r"[A-Za-z0-9_\[\].]{1,64}")


@dataclass(frozen=True, slots=True)
class Format:
    """One message type as its FMT record declares it.

    Attributes
    ----------
    type : int — the type byte of its records.
    name : str — e.g. ``IMU``.
    length : int — bytes per record, header (3) included.
    format : str — one DataFlash format character per column (pymavlink's ``FORMAT_TO_STRUCT``).
    columns : tuple of str — the column names.
    mults : tuple of float or None — the multiplier of each column's format character.
    """

    type: int
    name: str
    length: int
    format: str
    columns: tuple[str, ...]
    mults: tuple[float | None, ...]


@dataclass(frozen=True, slots=True)
class Index:
    """Where every record of a DataFlash log is.

    Attributes
    ----------
    data : uint8 (n,) — the file's bytes (a read-only memory map).
    formats : dict int -> Format — by type byte.
    name_to_id : dict str -> int — type byte by message name.
    offsets : dict int -> int64 (k,) — byte offsets of the records of each type, file order
        (a last record cut short by the end of the file included).
    damage : tuple of Damage — the damaged parts skipped, file order.
    cut_at : int or None — byte offset of a last record cut short by the end of the file.
    """

    data: NDArray[np.uint8]
    formats: dict[int, Format]
    name_to_id: dict[str, int]
    offsets: dict[int, NDArray[np.int64]]
    damage: tuple[Damage, ...]
    cut_at: int | None = None


def _cstr(raw: bytes) -> str | None:
    text = raw.split(b"\0", 1)[0]
    try:
        return text.decode("ascii")
    except UnicodeDecodeError:
        return None


def parse_fmt(body: bytes, struct_codes: dict) -> Format | None:
    """The format an FMT record's 86-byte payload declares, or None when it is not well formed.
    Its length is the one its format characters give (the declared one may differ: see
    :func:`_formats`)."""
    ftype, flen = body[0], body[1]
    name, chars, cols = _cstr(body[2:6]), _cstr(body[6:22]), _cstr(body[22:86])
    if name is None or chars is None or cols is None or not _NAME.fullmatch(name):
        return None
    if any(c not in struct_codes for c in chars):
        return None
    columns = tuple(cols.split(",")) if cols else ()
    if len(columns) != len(chars) or not all(_COLUMN.fullmatch(c) for c in columns):
        return None
    if (ftype == FMT_TYPE) != (name == "FMT") or flen < 3:
        return None
    size = struct.calcsize("<" + "".join(struct_codes[c][0] for c in chars))
    mults = tuple(struct_codes[c][1] for c in chars)
    return Format(ftype, name, size + 3, chars, columns, mults)


def _formats(
    b: NDArray[np.uint8], starts: NDArray[np.int64], struct_codes: dict
) -> tuple[dict[int, Format], list[Damage]]:
    formats = {FMT_TYPE: Format(FMT_TYPE, "FMT", FMT_LEN, "BBnNZ", (), ())}
    damage = []
    n = len(b)
    for ofs in starts[(b[np.minimum(starts + 2, n - 1)] == FMT_TYPE)].tolist():
        if ofs + FMT_LEN > n:
            continue
        fmt = parse_fmt(bytes(b[ofs + 3 : ofs + FMT_LEN]), struct_codes)
        if fmt is None or fmt.type == FMT_TYPE:
            continue
        old = formats.get(fmt.type)
        if old is None:
            formats[fmt.type] = fmt
            if fmt.length != b[ofs + 4]:
                damage.append(
                    Damage(
                        ofs,
                        f"DataFlash FMT of {fmt.name} declaring {b[ofs + 4]} bytes a record, "
                        f"its format {fmt.format!r} {fmt.length}: read as {fmt.length}",
                        messages_lost=0,
                    )
                )
        elif old != fmt:
            damage.append(
                Damage(
                    ofs,
                    f"DataFlash FMT redefining type {fmt.type} ({old.name}) ignored",
                    messages_lost=0,
                )
            )
    return formats, damage


def _links(b, starts, lengths):
    """Per candidate: its end, and the index of the candidate there (-1: none, len: the end)."""
    n, m = len(b), len(starts)
    ends = starts + lengths[b[starts + 2]]
    k = np.searchsorted(starts, ends)
    hit = (k < m) & (starts[np.minimum(k, m - 1)] == ends)
    nxt = np.where(hit, k, -1)
    nxt[ends == n] = m
    nxt[lengths[b[starts + 2]] == 0] = -1
    return ends, nxt


def _walk(b, starts, ends, nxt, formats) -> tuple[NDArray[np.int64], list[Damage], int | None]:
    """Follow the chain of records from offset 0, resynchronising after each break: the
    indices of the records kept, the damaged parts skipped, and the offset of a last record
    cut short by the end of the file (None if none). A run of records each followed by the
    next candidate is taken whole, so the loop turns once per irregular record only."""
    n, m = len(b), len(starts)
    ok = nxt >= 0
    ok_next = np.zeros(m, bool)
    ok_next[ok] = np.append(ok, True)[nxt[ok]]
    strong = np.flatnonzero(ok & ok_next)  # starts two confirmed records (or the last one)
    strong_at = starts[strong]
    odd = np.flatnonzero(nxt != np.arange(1, m + 1))  # not followed by the next candidate
    keep: list[NDArray[np.int64]] = []
    damage: list[Damage] = []
    cut_at = None

    def resync(after: int) -> int:
        k = int(np.searchsorted(strong_at, after, side="left"))
        return int(strong[k]) if k < len(strong) else m

    i = 0 if m and starts[0] == 0 else -1
    if i < 0:
        i = resync(0)
        damage.append(_gap(b, 0, int(starts[i]) if i < m else n, formats))
    while i < m:
        k = int(np.searchsorted(odd, i))
        r = int(odd[k]) if k < len(odd) else m
        if r > i:  # records i .. r-1 each followed by the next: r is reached too
            keep.append(np.arange(i, r))
            i = r
            continue
        j = int(nxt[i])
        if j >= 0:
            keep.append(np.array([i]))
            i = j
            continue
        start, end = int(starts[i]), int(ends[i])
        j = resync(start + 1)
        stop = int(starts[j]) if j < m else n
        if end == start:  # a type no FMT declares
            damage.append(_gap(b, start, stop, formats))
        elif j == m and end > n:  # the last record, cut short (its type decides what is lost)
            keep.append(np.array([i]))
            cut_at = start
            break
        elif end <= stop and _one_record(b, end, stop, formats):
            keep.append(np.array([i]))
            if not _padding(b, end, stop):  # kept; only what follows it is lost
                damage.append(_gap(b, end, stop, formats))
        else:
            damage.append(_gap(b, start, stop, formats))
        i = j
    return np.concatenate([*keep, np.zeros(0, np.int64)]).astype(np.int64), damage, cut_at


def _one_record(b, start: int, stop: int, formats) -> bool:
    """True when [start, stop) is end-of-file padding or one record whose sync bytes are
    damaged (its type byte is declared and its length is the span)."""
    if _padding(b, start, stop) or stop - start < 3:
        return _padding(b, start, stop) or stop == len(b)  # or a header cut short
    f = formats.get(int(b[start + 2]))
    return f is not None and f.length == stop - start


def _padding(b, start: int, stop: int) -> bool:
    """True when bytes [start, stop) are empty, or end-of-file padding (all 0x00 or all 0xFF)."""
    if start >= stop:
        return True
    if stop != len(b):
        return False
    tail = b[start:stop]
    return bool(np.all(tail == 0) or np.all(tail == 0xFF))


def _gap(b, start: int, stop: int, formats) -> Damage:
    size = stop - start
    if b[start] == HEAD[0] and start + 2 < len(b) and b[start + 1] == HEAD[1]:
        t = int(b[start + 2])
        name = formats[t].name if t in formats else None
        cause = (
            f"a record of type {name} not followed by a record"
            if name
            else f"a record of unknown type 0x{t:02x}"
        )
    else:
        cause = "bytes with no record header"
    fits = sorted({f.name for f in formats.values() if f.length == size})
    one = f", the length of one {' or '.join(fits[:3])} record" if 0 < len(fits) <= 3 else ""
    return Damage(start, f"DataFlash {cause}: {size} bytes skipped{one}")


def index_log(path: Path, struct_codes: dict) -> Index:
    """Index a binary DataFlash log (see the module doc). ``struct_codes`` is pymavlink's
    ``FORMAT_TO_STRUCT``: format character -> (struct code, multiplier, type)."""
    b = np.memmap(path, np.uint8, mode="r") if Path(path).stat().st_size else np.zeros(0, np.uint8)
    n = len(b)
    head = np.flatnonzero(b[: max(n - 2, 0)] == HEAD[0])
    starts = head[b[head + 1] == HEAD[1]].astype(np.int64)
    formats, damage = _formats(b, starts, struct_codes)
    lengths = np.zeros(256, np.int64)
    for f in formats.values():
        lengths[f.type] = f.length
    ends, nxt = _links(b, starts, lengths)
    keep, walked, cut_at = _walk(b, starts, ends, nxt, formats)
    kept = starts[np.asarray(keep, np.int64)]
    types = b[kept + 2]
    offsets = {t: kept[types == t] for t in np.unique(types).tolist()}
    name_to_id = {f.name: t for t, f in formats.items()}
    damage = sorted(damage + walked, key=lambda d: d.offset)
    return Index(b, formats, name_to_id, offsets, tuple(damage), cut_at)

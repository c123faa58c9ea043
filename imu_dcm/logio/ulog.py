"""PX4 ULog (``.ulg``) logs: gyro, accelerometer and attitude, in the toolkit's frames.

What is read
------------
* Gyro: ``sensor_combined.gyro_rad`` (the autopilot's selected IMU) by default, or the
  highest-rate ``sensor_gyro`` instance where it is more than 10 % faster. ``imu_topic``
  names one: ``sensor_combined``, ``sensor_gyro``, ``sensor_gyro_1`` or ``sensor_gyro[1]``.
  What each gyro topic held (samples, rate) is said in :attr:`LogData.notes`.
* Accelerometer: ``sensor_combined.accelerometer_m_s2`` (m/s²), on the gyro's rows
  (interpolated in time onto a ``sensor_gyro`` series); NaN where PX4 marks it invalid.
* Truth: ``vehicle_attitude_groundtruth`` where present (simulation), else
  ``vehicle_attitude``, which is PX4's own estimate and named as such
  (:attr:`TruthSeries.estimate_of`). ``truth_topic`` names either; ``"none"`` reads none.
* Vehicle state: ``vehicle_land_detected.landed`` and ``actuator_armed.armed`` where the log
  has them, as :attr:`LogData.vehicle_state` (evidence for the rest rule).
* Stamps: ULog stamps are µs since boot; ``t_ns`` is the sample time (``timestamp_sample``
  where the topic has it, else ``timestamp``), ``log_t_ns`` the publication time
  (``timestamp``), both int64 ns.
* The logger's dropouts, multi-instance sensors and estimator resets are listed in the notes.

Frames
------
PX4 states body vectors in FRD, the world in NED and ``q`` as ``[w, x, y, z]`` (FRD to NED).
The reader converts the gyro, the accelerometer and the truth into body FLU, world ENU and
``[x, y, z, w]`` (:mod:`imu_dcm.logio.ned`): a vehicle facing north is 90° about z in ENU.

How it is read
--------------
The ULog data section is a chain of ``[uint16 size][uint8 type][payload]`` messages (the
format PX4 documents). The reader walks that chain itself, in blocks, and gathers the records of
the wanted topics with numpy through the layouts the log's own format messages declare. Any
damaged message (a type the format does not define, a data message of an unknown subscription
or of another size than its format, a size past the end) costs only itself, and the one before
it when its size may be what was damaged: the walk resumes at the next sound messages
(:mod:`imu_dcm.logio.ulog_resync`) and each damaged part is listed in
:attr:`LogData.damage` with its byte offset. Appended data and incompatible flags hand the
file to ``pyulog`` (PX4's own parser); the notes say so. A log cut short costs its last
message and is listed too.
"""

from __future__ import annotations

import contextlib
import io
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from imu_dcm import kernel
from imu_dcm.errors import LogError
from imu_dcm.logio.damage import warn_damage
from imu_dcm.logio.ned import FLU_FROM_FRD, q_enu_flu
from imu_dcm.logio.paths import ULOG_MAGIC as MAGIC
from imu_dcm.logio.paths import is_ulog as probe  # noqa: F401 (the reader's probe, here too)
from imu_dcm.logio.source import Progress, ReadRequest
from imu_dcm.logio.types import (
    ChannelInfo,
    Damage,
    ImuSeries,
    LogData,
    TruthSeries,
    VehicleState,
)
from imu_dcm.logio.ulog_resync import KNOWN_TYPES, MAX_MESSAGE, Resync

KIND = "px4 ulog"
GYRO_TOPICS = ("sensor_combined", "sensor_gyro")
TRUTH_TOPICS = ("vehicle_attitude_groundtruth", "vehicle_attitude")
STATE_TOPICS = ("vehicle_land_detected", "actuator_armed")
PX4_ESTIMATE = "PX4's own estimate"
BLOCK_BYTES = 8 << 20
#: PX4's RELATIVE_TIMESTAMP_INVALID in ``sensor_combined.accelerometer_timestamp_relative``.
_ACCEL_INVALID = 0x7FFFFFFF
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


class _Irregular(Exception):
    """The fast scan met something only pyulog's recovery handles; ``skipped_at`` is the byte
    offset of a message pyulog skips (a type the format does not define), else -1."""

    def __init__(self, why: str, skipped_at: int = -1):
        super().__init__(why)
        self.skipped_at = skipped_at


def _check_flags(payload: bytes) -> None:
    """The flag-bits message: 8 compat bytes, 8 incompat bytes, 3 appended offsets."""
    if len(payload) < 16 or payload[8] & ~1 or any(payload[9:16]):
        raise _Irregular("incompatible flag bits")
    if payload[8] & 1:
        raise _Irregular("data appended after the log was written")


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
        raise _Irregular(f"format {name!r} undefined or nested too deep")
    parts = []
    for typ, n, fname in _parse_format(formats[name])[1]:
        base = np.dtype(_BASIC[typ]) if typ in _BASIC else _dtype(typ, formats, depth + 1)
        parts.append((fname, base, (n,)) if n else (fname, base))
    try:
        return np.dtype(parts)
    except (ValueError, TypeError) as exc:  # a field named twice, an empty or bad name
        raise _Irregular(f"format {name!r} has no numpy layout ({exc})") from None


def _layout(name: str, formats: dict) -> tuple[np.dtype, int]:
    """(layout without the trailing padding, the padding's size): PX4 leaves the padding at
    the end of a record out of the log, so a record holds between the two sizes."""
    full = _dtype(name, formats)
    names = list(full.names or ())
    while names and names[-1].startswith("_padding"):
        names.pop()
    if not names:
        raise _Irregular(f"format {name!r} has no fields")
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
    (and resuming after a damaged message: :class:`imu_dcm.logio.ulog_resync.Resync`)."""

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
                raise _Irregular(f"short subscription at byte {at}")
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
                raise _Irregular(why, base + at if size else -1)
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
                raise _Irregular(f"data for unknown subscription {k}")
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


def _scan_fast(path: Path, wanted: frozenset[str], progress: Progress | None) -> Scanned:
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
        from pyulog import ULog
    except ImportError:  # pragma: no cover - pyulog is a dependency
        raise LogError(
            "Expected pyulog to read this ULog, got no pyulog; `pip install pyulog`"
        ) from None
    return ULog


def scan(path: Path, wanted: frozenset[str], progress: Progress | None = None) -> Scanned:
    """Read the ``wanted`` topics of a ULog (fast scan; pyulog where the scan cannot)."""
    try:
        scanned = _scan_fast(path, wanted, progress)
    except _Irregular as exc:
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


# ------------------------------------------------------------------------ the series
def _split_name(text: str) -> tuple[str, int | None]:
    """``sensor_gyro_1`` / ``sensor_gyro[1]`` -> ("sensor_gyro", 1); a bare name -> (name, None)."""
    m = re.fullmatch(r"(.+?)(?:_(\d+)|\[(\d+)\])", text)
    if m:
        return m.group(1), int(m.group(2) or m.group(3))
    return text, None


def _labeller(counts: dict[tuple[str, int, str], int]):
    """Labels as said to the user: ``name`` for a single instance, ``name_k`` for several."""
    multi = {n for n, i, _ in counts if i > 0}
    return lambda name, inst: f"{name}_{inst}" if name in multi else name


def _rate_hz(t_us: NDArray) -> float:
    """The median rate of the steps forward, Hz."""
    d = np.diff(np.asarray(t_us, dtype=np.int64))
    d = d[d > 0]
    return 1e6 / float(np.median(d)) if len(d) else 0.0


def _vec(t: Topic, names: tuple[str, ...]) -> NDArray[np.float64]:
    return np.stack([np.asarray(t.fields[n], dtype=np.float64) for n in names], axis=1)


def _sample_us(t: Topic) -> NDArray[np.int64]:
    """``timestamp_sample`` where the topic has it (and it is set), else ``timestamp``."""
    ts = t.fields["timestamp"].astype(np.int64)
    s = t.fields.get("timestamp_sample")
    if s is None:
        return ts
    s = s.astype(np.int64)
    return np.where(s > 0, s, ts)


def _omega_frd(t: Topic) -> NDArray[np.float64] | None:
    if t.name == "sensor_combined" and "gyro_rad[2]" in t.fields:
        return _vec(t, ("gyro_rad[0]", "gyro_rad[1]", "gyro_rad[2]"))
    if t.name == "sensor_gyro" and "z" in t.fields:
        return _vec(t, ("x", "y", "z"))
    return None


def _pick_gyro(topics: list[Topic], label, imu_topic: str | None) -> tuple[Topic, str]:
    """The gyro topic (see the module doc) and a note listing every gyro topic found."""
    gyros = [t for t in topics if t.name in GYRO_TOPICS and len(t) and _omega_frd(t) is not None]
    gyros.sort(key=lambda t: (t.name != "sensor_combined", t.multi_id))
    if not gyros:
        raise LogError(
            "Expected a gyro topic (sensor_combined or sensor_gyro) in the ULog, got none"
        )
    rates = {id(t): _rate_hz(_sample_us(t)) for t in gyros}
    if imu_topic is not None:
        name, inst = _split_name(imu_topic)
        found = [t for t in gyros if t.name == name and t.multi_id == (inst or 0)]
        if not found:
            have = ", ".join(label(t.name, t.multi_id) for t in gyros)
            raise LogError(f"Expected gyro topic {imu_topic!r} in the ULog, got {have}")
        chosen = found[0]
    else:
        chosen = gyros[0]
        fastest = max(gyros, key=lambda t: rates[id(t)])
        if fastest.name == "sensor_gyro" and rates[id(fastest)] > 1.1 * rates[id(chosen)]:
            chosen = fastest
    listed = "; ".join(
        f"{label(t.name, t.multi_id)}: {len(t)} samples at {rates[id(t)]:.3g} Hz" for t in gyros
    )
    used = f"used {label(chosen.name, chosen.multi_id)} at {rates[id(chosen)]:.3g} Hz"
    return chosen, f"{listed}; {used}" if len(gyros) > 1 else used


def _accel(gyro: Topic, topics: list[Topic], t_ns: NDArray[np.int64]) -> NDArray | None:
    """sensor_combined's accelerometer (m/s², FLU) on the gyro's rows, NaN where invalid."""
    comb = next((t for t in topics if t.name == "sensor_combined" and len(t)), None)
    if comb is None or "accelerometer_m_s2[2]" not in comb.fields:
        return None
    a = _vec(comb, tuple(f"accelerometer_m_s2[{i}]" for i in range(3))) * FLU_FROM_FRD
    rel = comb.fields.get("accelerometer_timestamp_relative")
    if rel is not None:
        a[rel.astype(np.int64) == _ACCEL_INVALID] = np.nan
    if gyro is comb:
        return a
    # PX4 stamps the accelerometer at timestamp + accelerometer_timestamp_relative (µs)
    t_us = comb.fields["timestamp"].astype(np.int64)
    if rel is not None:
        t_us = t_us + np.where(rel.astype(np.int64) == _ACCEL_INVALID, 0, rel.astype(np.int64))
    good = np.all(np.isfinite(a), axis=1)
    t_acc, a = t_us[good] * 1000, a[good]
    out = np.full((len(t_ns), 3), np.nan)
    if len(t_acc) < 2:
        return out
    order = np.argsort(t_acc, kind="stable")
    t_acc, a = t_acc[order], a[order]
    inside = (t_ns >= t_acc[0]) & (t_ns <= t_acc[-1])
    for i in range(3):
        out[inside, i] = np.interp(t_ns[inside], t_acc, a[:, i])
    return out


def _vehicle_state(topics: list[Topic]) -> VehicleState | None:
    """``vehicle_land_detected.landed`` and ``actuator_armed.armed`` (instance 0), or None."""

    def steps(name: str, field_name: str):
        t = next((t for t in topics if t.name == name and t.multi_id == 0 and len(t)), None)
        if t is None or field_name not in t.fields:
            return None
        return t.fields["timestamp"].astype(np.int64) * 1000, t.fields[field_name]

    landed, armed = steps(*STATE_TOPICS[:1], "landed"), steps(STATE_TOPICS[1], "armed")
    used = [n for n, x in zip(STATE_TOPICS, (landed, armed), strict=True) if x is not None]
    return VehicleState.of(", ".join(used), landed, armed)


def imu_series(gyro: Topic, topics: list[Topic], label) -> ImuSeries:
    """The gyro (rad/s) and accelerometer in body FLU, stamps in ns."""
    t_ns = _sample_us(gyro) * 1000
    omega_flu = _omega_frd(gyro) * FLU_FROM_FRD
    return ImuSeries(
        t_ns=t_ns,
        log_t_ns=gyro.fields["timestamp"].astype(np.int64) * 1000,
        omega_b=omega_flu,
        orientation_xyzw=None,
        topic=label(gyro.name, gyro.multi_id),
        type=gyro.name,
        frame_id="body",
        accel_b=_accel(gyro, topics, t_ns),
        log_axes="FRD",
    )


def truth_series(t: Topic, label, auto: bool) -> TruthSeries:
    estimate_of = "" if t.name == "vehicle_attitude_groundtruth" else PX4_ESTIMATE
    return TruthSeries(
        t_ns=_sample_us(t) * 1000,
        log_t_ns=t.fields["timestamp"].astype(np.int64) * 1000,
        q_w_b=q_enu_flu(_vec(t, tuple(f"q[{i}]" for i in range(4)))),
        topic=label(t.name, t.multi_id),
        type=t.name,
        frame_id="world",
        child_frame_id="body",
        auto=auto,
        estimate_of=estimate_of,
    )


def _pick_truth(topics: list[Topic], label, truth_topic: str | None) -> tuple[list[Topic], str]:
    """Attitude topics, the chosen one first (empty when none or ``"none"``), and a note."""
    att = [t for t in topics if t.name in TRUTH_TOPICS and len(t) and "q[3]" in t.fields]
    att.sort(key=lambda t: (TRUTH_TOPICS.index(t.name), t.multi_id))
    if truth_topic == "none":
        return [], ""
    if truth_topic is not None:
        name, inst = _split_name(truth_topic)
        found = [t for t in att if t.name == name and t.multi_id == (inst or 0)]
        if not found:
            have = ", ".join(label(t.name, t.multi_id) for t in att) or "no attitude topic"
            raise LogError(f"Expected truth topic {truth_topic!r} in the ULog, got {have}")
        att.remove(found[0])
        att.insert(0, found[0])
    if not att:
        return [], "no attitude in the log (vehicle_attitude_groundtruth, vehicle_attitude)"
    first = att[0]
    if first.name == "vehicle_attitude_groundtruth":
        return att, f"truth: {label(first.name, first.multi_id)} (the simulator's attitude)"
    why = "" if truth_topic else " (no vehicle_attitude_groundtruth in the log)"
    return att, f"truth: {label(first.name, first.multi_id)}, {PX4_ESTIMATE}{why}"


# --------------------------------------------------------------------------- notes
def _multi_note(counts: dict[tuple[str, int, str], int]) -> str | None:
    inst: dict[str, set[int]] = {}
    for name, i, _ in counts:
        if name.startswith("sensor_"):
            inst.setdefault(name, set()).add(i)
    multi = [f"{n} x{len(s)}" for n, s in sorted(inst.items()) if len(s) > 1]
    return f"multi-instance sensors: {', '.join(multi)}" if multi else None


def _dropout_note(s: Scanned) -> str | None:
    if not s.dropouts:
        return None
    ms = [d for _, d in s.dropouts]
    k = int(np.argmax(ms))
    at = (s.dropout_times_us[k] - s.start_us) * 1e-6 if k < len(s.dropout_times_us) else np.nan
    return (
        f"the logger dropped data {len(ms)} time{'s' if len(ms) > 1 else ''}: {sum(ms)} ms in "
        f"all, the longest {ms[k]} ms at {at:.3f} s into the log"
    )


def _reset_note(t: Topic, label, start_us: int) -> str | None:
    c = t.fields.get("quat_reset_counter")
    if c is None or len(c) < 2:
        return None
    steps = np.flatnonzero(np.diff(c.astype(np.int64)) != 0) + 1
    if not len(steps):
        return None
    at = ", ".join(f"{(x - start_us) * 1e-6:.3f}" for x in _sample_us(t)[steps[:5]])
    more = " ..." if len(steps) > 5 else ""
    return (
        f"{label(t.name, t.multi_id)}: the estimator reset its attitude {len(steps)} "
        f"time{'s' if len(steps) > 1 else ''} (quat_reset_counter) at {at}{more} s into the log"
    )


def _timed(topics: list[Topic], label) -> tuple[list[Topic], str | None]:
    """The topics whose format has a ``timestamp`` field, and a note naming the gyro and
    attitude topics without one (skipped). Refused in one line when no gyro topic is left."""
    bad = [t for t in topics if "timestamp" not in t.fields and len(t.positions)]
    if not bad:
        return topics, None
    good = [t for t in topics if "timestamp" in t.fields]
    names = ", ".join(label(t.name, t.multi_id) for t in bad)
    if not any(t.name in GYRO_TOPICS and _omega_frd(t) is not None for t in good):
        gyro = [label(t.name, t.multi_id) for t in bad if t.name in GYRO_TOPICS]
        if gyro:
            raise LogError(
                f"Expected a timestamp field in the format of {', '.join(gyro)} in the ULog, "
                "got none"
            )
    return good, f"skipped (their format has no timestamp field): {names}"


# --------------------------------------------------------------------------- source
class UlogSource:
    """One PX4 ULog file (see the module doc for what is read and how frames convert)."""

    kind = KIND

    def __init__(self, path: Path, progress: Progress | None = None):
        self.path = Path(path)
        self.progress = progress

    def read(self, request: ReadRequest) -> LogData:
        wanted = set(GYRO_TOPICS + TRUTH_TOPICS + STATE_TOPICS)
        for named in (request.imu_topic, request.truth_topic):
            if named and named != "none":
                wanted.add(_split_name(named)[0])
        progress = request.progress or self.progress
        s = scan(self.path, frozenset(wanted), progress)
        label = _labeller(s.counts)
        topics, untimed = _timed(s.topics, label)
        gyro, gyro_note = _pick_gyro(topics, label, request.imu_topic)
        imu = imu_series(gyro, topics, label)
        att, truth_note = _pick_truth(topics, label, request.truth_topic)
        auto = request.truth_topic is None
        series = [truth_series(t, label, auto) for t in att]
        notes = [untimed, gyro_note, truth_note, _multi_note(s.counts), _dropout_note(s)]
        notes += [_reset_note(t, label, s.start_us) for t in att] + s.notes
        channels = tuple(
            ChannelInfo(label(n, i), fmt, "ulog", c) for (n, i, fmt), c in sorted(s.counts.items())
        )
        # once the log is known to be usable
        stopped_at = warn_damage(self.path, s.damage, diagnostics=request.diagnostics)
        if progress is not None:
            progress(1.0)
        return LogData(
            path=self.path,
            imu=imu,
            truth=series[0] if series else None,
            channels=channels,
            custom_data={k: v for k, v in s.info.items() if len(v) < 200},
            container=KIND,
            damage=tuple(s.damage),
            stopped_at=stopped_at,
            truth_candidates=tuple(series[1:]),
            notes=tuple(n for n in notes if n),
            vehicle_state=_vehicle_state(topics),
        )


def open_ulog(path: Path, progress: Progress | None = None) -> UlogSource:
    return UlogSource(path, progress)

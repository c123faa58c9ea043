"""The raw form every ROS container hands to the decoders, and how it is collected.

A container describes each channel as a :class:`Conn`; a :class:`Sink` says which channels to
keep and decodes their :class:`Payloads` batch by batch into :class:`Columns`; the container
returns everything as a :class:`Collected`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from imu_dcm.logio.types import Damage
from imu_dcm.memory import small_pages

__all__ = [
    "Collected",
    "Columns",
    "ColumnsBuilder",
    "Conn",
    "Payloads",
    "Sink",
    "join_any",
    "join_columns",
    "join_payloads",
]


@dataclass(slots=True, eq=False)
class Conn:
    """A channel as a container describes it (internal).

    ``encoding`` is the payload serialisation: "cdr" (ROS 2), "ros1" (ROS 1, packed little
    endian), "json" or whatever else the file says. ``schema_encoding`` is "ros2msg", "ros2idl",
    "ros1msg" or "" (the definition then comes from rosbags' type store for ``msgtype``).
    ``count`` is the channel's message count (a split bag adds its files' counts up).

    The records here are mutable (a split bag renumbers its channels' file-order keys) and
    compared by identity (``eq=False``: they hold arrays).
    """

    id: int
    topic: str
    msgtype: str
    encoding: str
    schema_encoding: str = ""
    schema_text: str = ""
    count: int | None = None


@dataclass(slots=True, eq=False)
class Payloads:
    """Raw payloads of one channel: ``buf[start[i] : start[i] + length[i]]`` (internal).

    ``order`` is a file-order key (increasing within a file and across split files), used to
    merge several channels of one topic in file order.
    """

    buf: NDArray[np.uint8]
    start: NDArray[np.int64]
    length: NDArray[np.int64]
    log_time: NDArray[np.int64]
    order: NDArray[np.int64]

    @staticmethod
    def empty() -> Payloads:
        z = np.zeros(0, np.int64)
        return Payloads(np.zeros(0, np.uint8), z, z, z, z)

    def __len__(self) -> int:
        return len(self.start)

    def payload(self, i: int) -> bytes:
        s = int(self.start[i])
        return self.buf[s : s + int(self.length[i])].tobytes()


def join_payloads(parts: list[Payloads]) -> Payloads:
    """One Payloads from several (one buffer), ordered by their file-order keys (stable)."""
    parts = [p for p in parts if len(p)]
    if not parts:
        return Payloads.empty()
    if len(parts) == 1:
        return parts[0]
    shift = np.cumsum([0] + [len(p.buf) for p in parts[:-1]])
    buf = np.concatenate([p.buf for p in parts])
    start = np.concatenate([p.start + s for p, s in zip(parts, shift, strict=False)])
    length = np.concatenate([p.length for p in parts])
    log_time = np.concatenate([p.log_time for p in parts])
    order = np.concatenate([p.order for p in parts])
    idx = np.argsort(order, kind="stable")
    return Payloads(buf, start[idx], length[idx], log_time[idx], order[idx])


@dataclass(slots=True, eq=False)
class Columns:
    """Decoded fields of one channel (internal): one row per message that decoded, file order.

    ``fields`` maps a name ("t_ns", "omega", "quat", "q") to an array (N,) or (N, k);
    ``dropped`` counts messages that did not decode; ``frames`` holds the first message's
    "frame_id" / "child_frame_id" and the "type"; ``error`` is the schema error when the
    channel's definition could not be read (then every message is dropped).
    """

    order: NDArray[np.int64]
    log_time: NDArray[np.int64]
    fields: dict[str, NDArray]
    frames: dict[str, str] = field(default_factory=dict)
    error: Exception | None = None
    dropped: int = 0

    def __len__(self) -> int:
        return len(self.order)


def join_columns(parts: list[Columns]) -> Columns:
    """One Columns from several, ordered by their file-order keys (stable).

    Fields are joined one at a time and each part's copy released as it goes, so the join
    needs one field's worth of extra memory, not a second copy of everything.
    """
    if len(parts) == 1:
        return parts[0]
    order = np.concatenate([p.order for p in parts])
    idx = None if np.all(order[1:] >= order[:-1]) else np.argsort(order, kind="stable")

    def joined(arrays: list[NDArray]) -> NDArray:
        a = np.concatenate(arrays)
        return a if idx is None else a[idx]

    frames: dict[str, str] = {}
    for p in parts:
        for k, v in p.frames.items():
            if v and k not in frames:
                frames[k] = v
    fields = {}
    for k in sorted({k for p in parts for k in p.fields}):
        proto = next(p.fields[k] for p in parts if k in p.fields)
        fields[k] = joined(
            [
                p.fields.pop(k) if k in p.fields else np.full((len(p),) + proto.shape[1:], np.nan)
                for p in parts
            ]
        )
    return Columns(
        order if idx is None else order[idx],
        joined([p.log_time for p in parts]),
        fields,
        frames,
        next((p.error for p in parts if p.error is not None), None),
        sum(p.dropped for p in parts),
    )


def join_any(parts: list) -> Payloads | Columns:
    if parts and isinstance(parts[0], Columns):
        return join_columns(parts)
    return join_payloads(parts)


class ColumnsBuilder:
    """One channel's decoded batches written into arrays of its message count as they come
    (internal): the whole channel's columns without its batches held beside them and joined
    at the end (a second copy, and heap that the batches leave behind).

    Without a count, or when the batches are not alike (a field in some only, another dtype)
    or outnumber the count (a file that says less than it holds), the rest are kept as
    batches and joined as :func:`join_columns` does; the result is the same either way.
    """

    def __init__(self, count: int | None) -> None:
        self.capacity = count if count is not None and count > 0 else 0
        self.n = 0
        self.arrays: dict[str, NDArray] | None = None  # "order", "log_time" and the fields
        self.layout: dict[str, tuple] = {}  # each field's dtype and row shape, from the first
        self.frames: dict[str, str] = {}
        self.error: Exception | None = None
        self.dropped = 0
        self.rest: list[Columns] = []  # batches past the count, or unlike the first

    def add(self, p: Columns) -> None:
        self.dropped += p.dropped  # counted here once, whichever way the batch goes
        p.dropped = 0
        if not self.rest and self._fits(p):
            self._write(p)
        else:  # kept as it is: its own copy of any field lent by its decoder
            p.fields = {k: v if v.base is None else v.copy() for k, v in p.fields.items()}
            self.rest.append(p)

    def _fits(self, p: Columns) -> bool:
        if self.n + len(p) > self.capacity:
            return False
        if self.arrays is None:
            return self._allocate(p)
        return {k: (v.dtype, v.shape[1:]) for k, v in p.fields.items()} == self.layout

    def _allocate(self, p: Columns) -> bool:
        cap = self.capacity
        try:  # pages are taken as rows are written: a count too large costs address space
            self.arrays = {
                "order": np.empty(cap, p.order.dtype),
                "log_time": np.empty(cap, p.log_time.dtype),
                **{k: np.empty((cap,) + v.shape[1:], v.dtype) for k, v in p.fields.items()},
            }
        except (MemoryError, ValueError):
            self.capacity = 0
            return False
        for a in self.arrays.values():
            small_pages(a)  # written once in order: no wait for huge pages (imu_dcm.memory)
        self.layout = {k: (v.dtype, v.shape[1:]) for k, v in p.fields.items()}
        return True

    def _write(self, p: Columns) -> None:
        a, b = self.n, self.n + len(p)
        arrays = self.arrays
        arrays["order"][a:b] = p.order
        arrays["log_time"][a:b] = p.log_time
        for k, v in p.fields.items():
            arrays[k][a:b] = v
        for k, v in p.frames.items():
            if v and k not in self.frames:
                self.frames[k] = v
        if self.error is None:
            self.error = p.error
        self.n = b

    def result(self) -> Columns | None:
        """The channel's columns (None when no batch came)."""
        parts = list(self.rest)
        if self.arrays is not None:
            n, arrays = self.n, self.arrays
            fields = {k: v[:n] for k, v in arrays.items() if k not in ("order", "log_time")}
            built = Columns(
                arrays["order"][:n], arrays["log_time"][:n], fields, self.frames, self.error
            )
            parts.insert(0, built)
        if not parts:
            return None
        out = join_columns(parts) if len(parts) > 1 else _in_order(parts[0])
        out.dropped = self.dropped
        return out


def _in_order(c: Columns) -> Columns:
    """``c`` in file order (stable), as :func:`join_columns` leaves several batches."""
    if np.all(c.order[1:] >= c.order[:-1]):
        return c
    idx = np.argsort(c.order, kind="stable")
    return Columns(
        c.order[idx], c.log_time[idx], {k: v[idx] for k, v in c.fields.items()}, c.frames,
        c.error, c.dropped,
    )  # fmt: skip


class Sink:
    """Where a container puts the payloads of kept channels (internal).

    ``plan(conn)`` says what to do with a channel: None (skip it), or a callable turning a
    batch of :class:`Payloads` into :class:`Columns` (decoded now, so raw bytes never pile
    up; its fields may be views valid until its next batch, copied into the channel's arrays
    at once) or returning the Payloads themselves (kept raw: JSON, /tf). ``transform(p)`` runs on
    each batch first (message decompression). Payloads are decoded every :data:`BATCH_BYTES`.
    """

    BATCH_BYTES = 2 << 20
    #: Payloads are decoded in groups of at least this many bytes (see ``_flush``).
    GROUP_BYTES = 256 << 10

    def __init__(self, plan, transform=None):
        self.plan = plan
        self.transform = transform
        self._plans: dict[int, object] = {}
        self._pending: dict[int, list[Payloads]] = {}
        self._bytes: dict[int, int] = {}
        self._done: dict[int, list] = {}
        self._counts: dict[int, int | None] = {}
        self._built: dict[int, ColumnsBuilder] = {}

    def wants(self, conn: Conn) -> bool:
        if conn.id not in self._plans:
            self._plans[conn.id] = self.plan(conn)
            self._counts[conn.id] = conn.count
        return self._plans[conn.id] is not None

    def add(self, cid: int, p: Payloads) -> None:
        self._pending.setdefault(cid, []).append(p)
        self._bytes[cid] = self._bytes.get(cid, 0) + len(p.buf)
        if self._bytes[cid] >= self.BATCH_BYTES:
            self._flush(cid)

    def _flush(self, cid: int) -> None:
        parts = self._pending.pop(cid, [])
        self._bytes[cid] = 0
        # Decoded in groups of at least GROUP_BYTES: a part that holds a whole chunk (shared by
        # the channels that fill it) alone, small parts (a channel's payloads copied out of its
        # chunks) joined. Joining whole chunks would copy each once per channel.
        group: list[Payloads] = []
        size = 0
        for k, p in enumerate(parts):
            group.append(p)
            size += len(p.buf)
            if size >= self.GROUP_BYTES or k == len(parts) - 1:
                batch = join_payloads(group)
                if self.transform is not None:
                    batch = self.transform(batch)
                got = self._plans[cid](batch)
                if isinstance(got, Columns):  # into the channel's arrays as it comes
                    if cid not in self._built:
                        self._built[cid] = ColumnsBuilder(self._counts.get(cid))
                    self._built[cid].add(got)
                else:
                    self._done.setdefault(cid, []).append(got)
                group, size = [], 0

    def finish(self) -> dict[int, Payloads | Columns]:
        for cid in list(self._pending):
            self._flush(cid)
        out = {cid: join_any(parts) for cid, parts in self._done.items()}
        for cid, built in self._built.items():
            got = built.result()
            if got is not None:
                out[cid] = got
        return out


@dataclass(slots=True, eq=False)
class Collected:
    """What a container read (internal): all channels, the kept ones' data, damage."""

    kind: str
    conns: list[Conn]
    payloads: dict[int, Payloads | Columns]
    damage: list[Damage] = field(default_factory=list)

"""What both MCAP readers share: the file's channels, and the messages of one chunk located.

:class:`McapReader` holds what a read finds (schemas, channels, message counts, damage) and
hands the kept channels' payloads to the sink. :meth:`~McapReader.take_chunk` locates the
messages of one decompressed chunk, from its message indexes where they check out, else by
walking its records; the indexed reader (:mod:`.indexed`) and the streaming one
(:mod:`.streaming`) differ only in how they find the chunks.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from imu_dcm.errors import LogError
from imu_dcm.logio.containers.mcap.records import (
    MSG,
    MSG_HEADER,
    OP_CHANNEL,
    OP_MESSAGE,
    OP_SCHEMA,
    REC,
    BadRecord,
    compact,
    parse_channel,
    parse_schema,
    rosbag2_custom_data,
)
from imu_dcm.logio.ros.cdr import gather
from imu_dcm.logio.ros.collect import Conn, Payloads, Sink
from imu_dcm.logio.source import ProgressCallback
from imu_dcm.logio.types import Damage

__all__ = ["McapReader"]


class McapReader:
    """Base of the indexed and the streaming reader of one MCAP file (``size`` bytes).

    ``read(f)`` is theirs; the state it fills and the per-chunk message location are shared.
    ``custom_data`` starts as the bag folder's (its ``metadata.yaml``) and is else taken from
    the file's rosbag2 Metadata record.
    """

    def __init__(
        self,
        path: Path,
        size: int,
        sink: Sink,
        progress: ProgressCallback | None = None,
        custom_data: dict[str, str] | None = None,
    ):
        self.path, self.size, self.sink, self.progress = path, size, sink, progress
        self.custom_data = dict(custom_data or {})
        self.schemas: dict[int, tuple[str, str, bytes]] = {}
        self.channels: dict[int, tuple[int, str, str]] = {}
        self.counts: dict[int, int] = {}
        self.counts_seen: dict[int, int] = {}
        self.unknown: dict[int, int] = {}  # chunk offset -> messages naming no defined channel
        self.n_kept = 0
        self.damage: list[Damage] = []
        self._kept: dict[int, bool] = {}

    def read(self, f) -> None:
        """Read the open file ``f``: every channel, the kept ones' payloads into the sink."""
        raise NotImplementedError

    def unknown_channel_damage(self) -> list[Damage]:
        """One :class:`Damage` per chunk holding messages of a channel id never defined."""
        return [
            Damage(
                pos,
                f"{n} messages in the chunk at byte {pos} name a "
                f"channel id that is not defined; they are lost",
                None,
                None,
                n,
            )
            for pos, n in sorted(self.unknown.items())
        ]

    def conn(self, cid: int) -> Conn:
        """The channel ``cid`` as the decoders see it (its schema text, its message count)."""
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

    def is_kept(self, cid: int) -> bool:
        """The sink wants channel ``cid`` (asked once per channel)."""
        k = self._kept.get(cid)
        if k is None:
            k = self._kept[cid] = cid in self.channels and self.sink.wants(self.conn(cid))
        return k

    def metadata(self, buf: bytes, pos: int) -> None:
        """The bag's ``custom_data`` from a rosbag2 Metadata record (at byte ``pos``), unless
        the bag folder's ``metadata.yaml`` gave it; a damaged record costs only itself."""
        if self.custom_data:
            return
        try:
            self.custom_data = rosbag2_custom_data(buf, self.path)
        except (struct.error, BadRecord, LogError) as exc:
            why = str(exc) if isinstance(exc, LogError) else "a field runs past the record"
            self.damage.append(
                Damage(
                    pos,
                    f"the metadata record at byte {pos} is damaged ({why}); its "
                    "custom_data (declared intervals, whose estimate the truth is) is lost",
                )
            )

    def take_chunk(
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
            inside = (offs >= 0) & (offs <= size - MSG_HEADER)  # an offset near 2^63 cannot wrap
            o = np.where(inside, offs, 0)
            length_u = gather(d, o + 1, "u8")
            valid = inside & (d[o] == OP_MESSAGE) & (length_u >= 22) & (length_u <= size)
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
            self.n_kept = 0
            gs = np.concatenate([[0], ends[valid]])
            ge = np.concatenate([offs[valid], [size]])
            for a, b in zip(gs[ge > gs].tolist(), ge[ge > gs].tolist(), strict=False):
                self.walk(data, a, b, pos, seq, span=span, quiet=not all_valid)
            if not all_valid:
                bad = ~valid
                expected = int(sum(self.is_kept(int(c)) for c in icid[bad]))
                lost = max(expected - self.n_kept, 0)
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
            self.keep_spans(d, o, length[valid], cid[valid], lt[valid], (seq << 32) + o, pos)
            return
        self.n_kept = 0
        self.walk(data, 0, size, pos, seq, span=span, expected=None)

    def keep_spans(
        self, d, offs, length, cid, log_time, order, pos: int = -1, note_unknown: bool = True
    ) -> None:
        """Hand the kept channels' payloads (message records at ``offs`` of ``d``) to the sink;
        ``order`` is each message's file-order key."""
        spans = []
        for c in np.flatnonzero(np.bincount(cid)).tolist():  # the ids present, ascending
            m = cid == c
            if c not in self.channels:
                if note_unknown:
                    self.unknown[pos] = self.unknown.get(pos, 0) + int(m.sum())
                continue
            spans.append((c, offs[m] + MSG_HEADER, length[m] - 22, log_time[m], order[m]))
        self.hand_on(d, spans)

    def hand_on(self, d, spans: list) -> None:
        """Count each channel's messages of ``d`` and hand the kept ones' payloads to the sink:
        ``spans`` holds ``(channel, payload starts, lengths, log times, file-order keys)``
        of defined channels."""
        kept = []
        for c, s, n, lt, order in spans:
            if not len(s):
                continue
            self.counts_seen[c] = self.counts_seen.get(c, 0) + len(s)
            if self.is_kept(c):
                kept.append((c, s, n, lt, order))
        # Kept channels that together fill most of the chunk keep the chunk as is, shared (no
        # copy: IMU and truth interleaved); small ones (IMU beside a camera) copy out their
        # payloads, so the chunk can go.
        share = 2 * sum(int(n.sum()) for _, _, n, _, _ in kept) >= len(d)
        for c, s, n, lt, order in kept:
            self.n_kept += len(s)
            buf = (d, s, n) if share else compact(d, s, n)
            self.sink.add(c, Payloads(*buf, lt, order))

    def walk(
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
            op, length = REC.unpack_from(data, p)
            end = p + 9 + length
            if end > b:
                break
            try:
                if op == OP_MESSAGE and length >= 22:
                    _, _, cid, _, lt, _ = MSG.unpack_from(data, p)
                    offs.append(p)
                    lens.append(length)
                    cids.append(cid)
                    times.append(lt)
                elif op == OP_SCHEMA:
                    parse_schema(data, p + 9, self.schemas)
                elif op == OP_CHANNEL:
                    parse_channel(data, p + 9, self.channels)
            except (struct.error, BadRecord):
                break
            p = end
        if offs:
            o = np.asarray(offs, np.int64)
            self.keep_spans(
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
            lost = None if expected is None else max(expected - self.n_kept, 0)
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

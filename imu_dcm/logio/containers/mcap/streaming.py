"""The streaming MCAP reader: the file walked forward record by record, as it was written.

For a file without a usable summary (a recording cut short, a damaged summary). One chunk is
in memory at a time; a chunk is skipped unread when the message indexes behind it show no kept
channel. A damaged record is noted with its file offset and the walk resumes at the next
plausible chunk; a file that ends without its data-end record is noted too.
"""

from __future__ import annotations

import struct

import numpy as np

from imu_dcm.logio.checksum import crc32
from imu_dcm.logio.containers.mcap.reader import McapReader
from imu_dcm.logio.containers.mcap.records import (
    MAGIC,
    MAX_META_RECORD,
    OP_CHANNEL,
    OP_CHUNK,
    OP_DATA_END,
    OP_FOOTER,
    OP_MESSAGE,
    OP_METADATA,
    OP_MSG_INDEX,
    OP_SCHEMA,
    REC,
    BadRecord,
    chunk_head,
    decompress,
    parse_channel,
    parse_schema,
    read_string,
)
from imu_dcm.logio.ros.collect import Payloads
from imu_dcm.logio.types import Damage

__all__ = ["StreamingReader"]


class StreamingReader(McapReader):
    """Reads an MCAP file from its magic to its data end (see the module doc)."""

    def read(self, f) -> None:
        """Walk the file record by record (no summary to trust), from the magic to data end."""
        pos, seq = len(MAGIC), 0
        f.seek(pos)
        while pos + 9 <= self.size:
            if self.progress is not None:
                self.progress(pos / self.size)
            f.seek(pos)
            op, length = REC.unpack(f.read(9))
            end = pos + 9 + length
            if op in (OP_DATA_END, OP_FOOTER):
                return
            if end > self.size or op == 0 or op > 0x0F:
                nxt = self._skip_damaged(f, pos, end)
                if nxt is None:
                    return
                pos = nxt
                continue
            if op == OP_CHUNK:
                pos = self._scan_chunk(f, pos, length, end, seq)
                seq += 1
                continue
            if op in (OP_SCHEMA, OP_CHANNEL) and length <= MAX_META_RECORD:
                self._scan_definition(f, op, pos, length)
            elif op == OP_METADATA and length <= MAX_META_RECORD:
                self.metadata(f.read(length), pos)
            elif op == OP_MESSAGE and length >= 22:
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
            if known and not any(self.is_kept(c) for c in entries):
                for c, e in entries.items():
                    self.counts_seen[c] = self.counts_seen.get(c, 0) + len(e[0])
            else:
                f.seek(pos + 9)
                self._chunk(f, pos, length, seq, entries)
        except BadRecord as exc:
            lost = None
            if entries is not None:
                lost = sum(
                    len(e[0])
                    for c, e in entries.items()
                    if c not in self.channels or self.is_kept(c)
                )
            self.damage.append(
                Damage(pos, f"the chunk at byte {pos} is damaged: {exc}", t0, t1, lost)
            )
        return after

    def _chunk(self, f, pos: int, length: int, seq: int, entries: dict | None) -> None:
        """Read, check and decompress the chunk record at file offset ``pos``; keep payloads."""
        at, n, usize, comp, crc = chunk_head(f, pos, length, self.size)
        f.seek(pos + 9)
        _t0, _t1 = struct.unpack("<QQ", f.read(16))
        f.seek(at)
        data = decompress(comp, f.read(n), usize)
        if crc != 0 and crc32(data) != crc:
            raise BadRecord("it fails its CRC check")
        self.take_chunk(data, pos, seq, entries, (_t0, _t1))

    def _scan_definition(self, f, op: int, pos: int, length: int) -> None:
        """A schema or channel record outside chunks (the file is positioned at its body)."""
        buf = f.read(length)
        try:
            (parse_schema if op == OP_SCHEMA else parse_channel)(
                buf, 0, self.schemas if op == OP_SCHEMA else self.channels
            )
        except (struct.error, BadRecord):
            self.damage.append(Damage(pos, f"a schema or channel record at byte {pos} is damaged"))

    def _scan_message(self, f, length: int, seq: int) -> None:
        """A message record outside chunks (the file is positioned at its body)."""
        head = f.read(22)
        cid, _, lt, _ = struct.unpack_from("<HIQQ", head)
        self.counts_seen[cid] = self.counts_seen.get(cid, 0) + 1
        if self.is_kept(cid):
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
            if head[0] != OP_MSG_INDEX:
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
                    _, length = REC.unpack_from(buf, i)
                    comp, p = read_string(buf, i + 9 + 28)
                    (n,) = struct.unpack_from("<Q", buf, p)
                    if (
                        comp in ("", "zstd", "lz4")
                        and p - i - 9 + 8 + n == length
                        and (pos + i + 9 + length <= self.size)
                    ):
                        return pos + i
                except (struct.error, BadRecord):
                    pass
                i = buf.find(b"\x06", i + 1)
            pos += block
        return None

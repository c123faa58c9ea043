"""Resuming a ULog scan after a damaged message (the message chain has no checksum).

A message is *sound* when its type is one the ULog format defines, its size fits what is
read, and a data message names a known subscription (and, for a topic whose layout is known,
has its size). After the first unsound message, the scan resumes at the first offset that
starts four sound messages in a row (or sound messages up to the end of the file). A message
whose type alone is wrong (its size leads to sound messages) costs only itself; otherwise the
message before it is dropped too, as its size may be what was damaged.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["KNOWN_TYPES", "MAX_MESSAGE", "Resync"]

#: The message types of the ULog format (F, I, M, P, Q, A, R, D, L, C, S, O, B).
KNOWN_TYPES = b"FIMPQARDLCSOB"
_KNOWN_U8 = np.frombuffer(bytes(sorted(KNOWN_TYPES)), np.uint8)
#: The longest ULog message: a uint16 size and its 3-byte header.
MAX_MESSAGE = 65535 + 3
_DATA, _SUBSCRIPTION = 68, 65


class Resync:
    """The soundness checks and the resume search of the ULog scanner; the scanner holds
    ``subs`` (msg_id -> subscription) and ``layouts`` (msg_id -> (dtype, padding bytes))."""

    subs: dict
    layouts: dict

    def _sound(self, b: NDArray[np.uint8], at: int, ids: set[int]) -> bool:
        """Whether the message at ``at`` of ``b`` can be one: a defined type, a size that fits,
        and for data a known subscription (and its layout's size, for a topic read)."""
        if at + 3 > len(b):
            return False
        size, t = int(b[at]) | int(b[at + 1]) << 8, int(b[at + 2])
        if t not in KNOWN_TYPES or size == 0 or at + 3 + size > len(b):
            return False
        if t != _DATA:
            return True
        k = int(b[at + 3]) | int(b[at + 4]) << 8 if size >= 2 else -1
        if k not in ids:
            return False
        if k in self.layouts:
            layout, pad = self.layouts[k]
            return layout.itemsize <= size - 2 <= layout.itemsize + pad
        return True

    def _first_unsound(self, b, pos, typ) -> tuple[int | None, set[int]]:
        ids = set(self.subs)
        for i in np.flatnonzero(typ == _SUBSCRIPTION).tolist():  # subscriptions here
            at = int(pos[i])
            if int(b[at]) | int(b[at + 1]) << 8 >= 3:
                ids.add(int(b[at + 4]) | int(b[at + 5]) << 8)
        size = b[pos].astype(np.int64) | (b[pos + 1].astype(np.int64) << 8)
        odd = np.flatnonzero(~np.isin(typ, _KNOWN_U8) | (size == 0))
        data = np.flatnonzero(typ == _DATA)
        if len(data):
            mid = b[pos[data] + 3].astype(np.int64) | (b[pos[data] + 4].astype(np.int64) << 8)
            odd = np.union1d(odd, data[~np.isin(mid, list(ids))])
            for k, (layout, pad) in self.layouts.items():
                sel = data[mid == k]
                n = size[sel] - 2
                odd = np.union1d(odd, sel[(n < layout.itemsize) | (n > layout.itemsize + pad)])
        return (int(odd[0]) if len(odd) else None), ids

    def _chain_ok(self, b, at: int, ids: set[int], final: bool) -> bool:
        """Four sound messages from ``at`` (or fewer up to the end of the file)."""
        for _ in range(4):
            if final and at == len(b):
                return True
            if not self._sound(b, at, ids):
                return False
            at += 3 + (int(b[at]) | int(b[at + 1]) << 8)
        return True

    def _resume_after(self, b, start: int, ids: set[int], final: bool) -> int:
        """The first offset after ``start`` where sound messages resume; the end of ``b``
        when none does and it is the file's end, else -1 (read on)."""
        cand = np.flatnonzero(np.isin(b[start + 3 :], _KNOWN_U8)) + start + 1
        for q in cand.tolist():
            if self._chain_ok(b, q, ids, final):
                return q
        return len(b) if final else -1

    def _resync(self, b, pos, bad: int, ids: set[int], final: bool) -> tuple[int, int, int]:
        """After the unsound message ``bad``: (messages kept before it, where the damage
        starts, where whole messages resume). A message whose type alone is wrong (its size
        leads to sound messages) costs itself; otherwise the one before it goes too (its size
        may be what was damaged) and the scan resumes at the first of 4 sound messages."""
        at = int(pos[bad])
        size = int(b[at]) | int(b[at + 1]) << 8
        if size and at + 3 + size <= len(b) and self._chain_ok(b, at + 3 + size, ids, final):
            return bad, at, at + 3 + size
        keep = max(bad - 1, 0)
        start = int(pos[keep])
        return keep, start, self._resume_after(b, start, ids, final)

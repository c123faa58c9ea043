"""The MCAP message records of a batch of chunks, written for numba: located from the chunks'
message indexes, checked and grouped by channel in one pass
(:mod:`imu_dcm.logio.containers.mcap.indexed` hands their payloads on), and its entry point
(:data:`ENTRIES`).

Imported only to compile, like :mod:`imu_dcm._kernels.integrator`.
"""

from __future__ import annotations

import numpy as np

from imu_dcm._kernels.jit import inline

__all__ = ["ENTRIES", "SIGNATURE", "locate_batch"]

SIGNATURE = (
    "Tuple((int64[::1], int64[::1], int64[::1], int64[::1], int64[::1], int64[::1], int64))"
    "(uint8[::1], int64[::1], int64[::1], int64[::1], int64[::1], int64[::1], int64[::1],"
    " int64[::1], int64[::1])"
)
_OP_MESSAGE = 0x05
_HEADER = 31  # opcode, record length, channel id, sequence, log time, publish time
_MERGE_MAX = 8  # a chunk of more indexed channels than this is sorted, not merged


@inline
def _u64(b, at: int) -> int:
    """The little-endian 64-bit integer at ``b[at]``, ``at >= 0`` (as int64: a top bit set is
    negative). Indexed unsigned: with no negative index to wrap around, the compiler reads
    the eight bytes as one load."""
    p = np.uint64(at)
    v = np.uint64(0)
    for k in range(8):
        v |= np.uint64(b[p + np.uint64(k)]) << np.uint64(8 * k)
    return np.int64(v)


@inline
def _file_order(offs, seg, s0: int, s1: int, idx) -> int:
    """The entries of segments ``s0 .. s1 - 1`` (one chunk's channels, each in its index's
    order) in file order into ``idx`` (positions in ``offs``): merged when there are few
    segments and each is in order, else sorted (stable). Returns their count."""
    first, m = seg[s0], seg[s1] - seg[s0]
    k = s1 - s0
    merged = k <= _MERGE_MAX
    if merged:
        head = seg[s0:s1].copy()
        for r in range(m):
            best = -1
            for j in range(k):
                if head[j] < seg[s0 + j + 1] and (best < 0 or offs[head[j]] < offs[head[best]]):
                    best = j
            idx[r] = head[best]
            head[best] += 1
            if r and offs[idx[r]] < offs[idx[r - 1]]:
                merged = False  # a segment out of order: sorted instead
                break
    if not merged:
        order = np.argsort(offs[first : first + m], kind="mergesort")
        for r in range(m):
            idx[r] = first + order[r]
    return m


def locate_batch(buf, offs, seg, seg_chunk, seg_slot, bases, sizes, seqs, slot_cid):
    """Locate, check and group the message records a batch's message indexes point at.

    ``offs`` holds the index entries (record offsets inside their chunk) segment by
    segment: segment ``s`` is ``offs[seg[s]:seg[s + 1]]``, the index of channel
    ``slot_cid[seg_slot[s]]`` in chunk ``seg_chunk[s]`` (non-decreasing); chunk ``c`` is
    ``buf[bases[c]:bases[c] + sizes[c]]``, sequence number ``seqs[c]``.

    Each record must lie inside its chunk after the one before it (no overlap), with the
    message opcode, a length of at least the 22 header bytes, and its index's channel.
    Returns ``(start, length, log_time, order, bounds, gaps, bad)``: each payload's start in
    ``buf``, its length, the log time and a file-order key (``seq << 32`` plus the offset in
    the chunk), grouped by slot (slot ``i`` is rows ``bounds[i]:bounds[i + 1]``, in file
    order); ``gaps`` the byte ranges ``[a, b)`` of ``buf`` no indexed record covers, as
    ``a0, b0, a1, b1, ...`` in file order; ``bad`` -1, or the position in ``offs`` of a
    record that does not check out (then nothing else is meaningful).
    """
    n = len(offs)
    n_seg = len(seg) - 1
    n_slots = len(slot_cid)
    bounds = np.zeros(n_slots + 1, np.int64)
    for s in range(n_seg):
        bounds[seg_slot[s] + 1] += seg[s + 1] - seg[s]
    for i in range(n_slots):
        bounds[i + 1] += bounds[i]
    cursor = bounds[:n_slots].copy()
    start = np.empty(n, np.int64)
    length = np.empty(n, np.int64)
    log_time = np.empty(n, np.int64)
    order = np.empty(n, np.int64)
    gaps = np.empty(2 * (n + len(bases)), np.int64)
    idx = np.empty(n, np.int64)  # one chunk's entries in file order
    seg_at = np.empty(n, np.int64)  # each entry's segment
    for s in range(n_seg):
        seg_at[seg[s] : seg[s + 1]] = s
    g = 0
    s = 0
    for c in range(len(bases)):
        s0 = s
        while s < n_seg and seg_chunk[s] == c:
            s += 1
        m = _file_order(offs, seg, s0, s, idx)
        base, end = bases[c], bases[c] + sizes[c]
        done = base  # the end of the record before
        for r in range(m):
            i = idx[r]
            if offs[i] < 0 or offs[i] > sizes[c] - _HEADER:  # no sum that can overflow
                return start, length, log_time, order, bounds, gaps[:g], np.int64(i)
            o = base + offs[i]
            if o < done or buf[o] != _OP_MESSAGE:
                return start, length, log_time, order, bounds, gaps[:g], np.int64(i)
            size = _u64(buf, o + 1)
            cid = np.int64(buf[o + 9]) | (np.int64(buf[o + 10]) << np.int64(8))
            slot = seg_slot[seg_at[i]]
            if size < 22 or size > end - o - 9 or cid != slot_cid[slot]:
                return start, length, log_time, order, bounds, gaps[:g], np.int64(i)
            if o > done:
                gaps[g] = done
                gaps[g + 1] = o
                g += 2
            done = o + 9 + size
            w = cursor[slot]
            cursor[slot] += 1
            start[w] = o + _HEADER
            length[w] = size - 22
            log_time[w] = _u64(buf, o + 15)
            order[w] = (seqs[c] << np.int64(32)) + (o - base)
        if end > done:
            gaps[g] = done
            gaps[g + 1] = end
            g += 2
    return start, length, log_time, order, bounds, gaps[:g], np.int64(-1)


#: ``name -> (function, signature)`` of this kernel's entry point.
ENTRIES = {"locate_batch": (locate_batch, SIGNATURE)}

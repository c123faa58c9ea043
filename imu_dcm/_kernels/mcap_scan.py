"""The MCAP message-record check, written for numba: the records a batch's message indexes
point at, checked and read in one pass (:mod:`imu_dcm.logio.containers.mcap.indexed` keeps
their payloads), and its entry point (:data:`ENTRIES`).

Imported only to compile, like :mod:`imu_dcm._kernels.integrator`.
"""

from __future__ import annotations

import numpy as np

from imu_dcm._kernels.jit import inline

__all__ = ["ENTRIES", "SIGNATURE", "located_records"]

SIGNATURE = (
    "Tuple((int64[::1], int64[::1], int64))"
    "(uint8[::1], int64[::1], int64[::1], int64[::1], int64[::1])"
)
_OP_MESSAGE = 0x05
_HEADER = 31  # opcode, record length, channel id, sequence, log time, publish time


@inline
def _u64(b, at: int) -> int:
    """The little-endian 64-bit integer at ``b[at]`` (as int64: a top bit set is negative)."""
    v = np.int64(0)
    for k in range(8):
        v |= np.int64(b[at + k]) << np.int64(8 * k)
    return v


def located_records(buf, offs, start, end, channel):
    """Check the message records at ``offs`` of ``buf`` (increasing; ``start[i]`` and
    ``end[i]`` the bounds of record ``i``'s chunk, ``channel[i]`` the channel its index names)
    and read them: ``(length, log_time, bad)``, each record's length and log time, and the
    first record that does not check out (-1 when all do): its header inside its chunk, the
    message opcode, a length of at least the header's 22 bytes that ends inside its chunk and
    before the next record, and the channel of its index."""
    n = len(offs)
    length = np.empty(n, np.int64)
    log_time = np.empty(n, np.int64)
    for i in range(n):
        o, e = offs[i], end[i]
        if o < start[i] or o + _HEADER > e or buf[o] != _OP_MESSAGE:
            return length, log_time, np.int64(i)
        size = _u64(buf, o + 1)
        if size < 22 or size > e - o - 9:
            return length, log_time, np.int64(i)
        stop = e if i + 1 == n else min(e, offs[i + 1])
        cid = np.int64(buf[o + 9]) | (np.int64(buf[o + 10]) << np.int64(8))
        if o + 9 + size > stop or cid != channel[i]:
            return length, log_time, np.int64(i)
        length[i] = size
        log_time[i] = _u64(buf, o + 15)
    return length, log_time, np.int64(-1)


#: ``name -> (function, signature)`` of this kernel's entry point.
ENTRIES = {"located_records": (located_records, SIGNATURE)}

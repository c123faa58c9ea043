"""The wanted fields of a batch of ROS messages (ROS 2 CDR or ROS 1), written for numba: one
walk through every message's layout, in one pass, and its entry point (:data:`ENTRIES`).

:mod:`imu_dcm.logio.ros.cdr` flattens a message definition into steps and hands them here. The
walk keeps each message's own byte offset, so strings and sequences of any length (a
``frame_id``) cost nothing extra, and copies each wanted value into a row of 64-bit words.

Imported only to compile, like :mod:`imu_dcm._kernels.integrator`.
"""

from __future__ import annotations

import numpy as np

from imu_dcm._kernels.field_steps import COL, COUNT, KIND, KIND_PRIM, KIND_STRING, SIGNED, SIZE, N
from imu_dcm._kernels.jit import inline

__all__ = ["ENTRIES", "SIGNATURE", "walk_fields"]

SIGNATURE = (
    "int64(uint8[::1], int64[::1], int64[::1], boolean, int64[:, ::1], uint64[:, ::1],"
    " boolean[::1])"
)


@inline
def _bytes(b, at: int, size: int):
    """The little-endian unsigned integer of ``size`` bytes (a constant after inlining) at
    ``b[at]``, ``at >= 0``. Indexed unsigned: with no negative index to wrap around, the
    compiler reads the bytes as one load."""
    p = np.uint64(at)
    v = np.uint64(0)
    for k in range(size):
        v |= np.uint64(b[p + np.uint64(k)]) << np.uint64(8 * k)
    return v


@inline
def _value(b, at: int, size: int, signed: bool):
    """The value of ``size`` bytes (1, 2, 4 or 8) at ``b[at]`` as 64 bits: sign-extended when
    ``signed``. One branch per size, so that each read is of a constant width."""
    if size == 8:
        return _bytes(b, at, 8)
    if size == 4:
        v = _bytes(b, at, 4)
    elif size == 2:
        v = _bytes(b, at, 2)
    else:
        v = _bytes(b, at, 1)
    if signed:
        shift = np.uint64(64 - 8 * size)
        v = np.uint64(np.int64(v << shift) >> np.int64(shift))
    return v


@inline
def _copy(b, at: int, size: int, count: int, signed: bool, out, row: int, col: int) -> None:
    """``count`` values of ``size`` bytes from ``b[at]`` into ``out[row, col:col + count]``
    (indexed unsigned, like the reads: no wraparound test per value)."""
    r = np.uint64(row)
    c = np.uint64(col)
    if size == 8:
        for k in range(count):
            out[r, c + np.uint64(k)] = _bytes(b, at + 8 * k, 8)
    else:
        for k in range(count):
            out[r, c + np.uint64(k)] = _value(b, at + size * k, size, signed)


def walk_fields(buf, start, length, cdr, steps, out, good) -> int:
    """Walk the layout ``steps`` (k, 6), in the columns of :mod:`imu_dcm._kernels.field_steps`,
    through every message ``buf[start[i] : start[i] + length[i]]``, and copy its wanted values
    into ``out[i]`` (n, W), one 64-bit word each: a float's bits, an integer zero- or
    sign-extended.

    With ``cdr``, each message opens with CDR's 4-byte encapsulation header, whose second byte
    must say little endian (1), and each value starts at a multiple of its size from the end
    of that header, a count or length at a multiple of 4; ROS 1 (not ``cdr``) packs them with
    no header. ``good[i]`` says whether message ``i`` lies inside ``buf`` and holds every
    wanted value; where it does not, its row of ``out`` holds no meaning. Returns how many do
    not."""
    bad = 0
    head = 4 if cdr else 0
    size_buf = buf.shape[0]
    for i in range(start.shape[0]):
        base = start[i] + head
        room = length[i] - head
        ok = room >= 0 and start[i] >= 0 and length[i] <= size_buf - start[i]
        if ok and cdr:
            ok = buf[np.uint64(start[i] + 1)] == 1
        off = 0
        for s in range(steps.shape[0]):
            if not ok:
                break
            su = np.uint64(s)
            kind, size, n = steps[su, KIND], steps[su, SIZE], steps[su, N]
            if kind != KIND_PRIM:
                if cdr:
                    off = (off + 3) & -4
                if off + 4 > room:
                    ok = False
                    break
                count = np.int64(_bytes(buf, base + off, 4))
                off += 4
                if kind == KIND_STRING:
                    off += count
                    continue
                n = count
            if cdr and size > 1:
                off = (off + size - 1) & -size
            col = steps[su, COL]
            if col >= 0:
                want = steps[su, COUNT]
                if off + size * want > room:
                    ok = False
                    break
                _copy(buf, base + off, size, want, steps[su, SIGNED] != 0, out, i, col)
            off += size * n
        good[i] = ok
        if not ok:
            bad += 1
    return bad


#: The entry point and its signature, as built ahead of time.
ENTRIES = {"walk_fields": (walk_fields, SIGNATURE)}

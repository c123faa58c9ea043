"""Bulk decoding of ROS 2 CDR and ROS 1 payloads: the wanted fields of every message at once.

A message definition is flattened once into steps (:func:`_compile`): primitives, string
lengths and sequence counts, in field order up to the last wanted leaf (``header.stamp``,
``angular_velocity`` ...). One compiled pass (:func:`imu_dcm._kernels.calls.walk_fields`)
follows them through every message with its own byte offset (strings and sequences make offsets
differ between messages, e.g. a ``frame_id`` of varying length) and copies each wanted value
into a row of 64-bit words, which are then seen as the leaves' types. ROS 2 CDR aligns each
primitive to its size relative to the payload after the 4-byte encapsulation header; ROS 1
packs fields little endian without alignment or header. Layouts the walk cannot follow
(sequences of strings or of messages before a wanted field, big-endian CDR), and any message
too short for it, are decoded by rosbags' deserialiser, message by message.
"""

from __future__ import annotations

import threading

import numpy as np
from numpy.typing import NDArray

from imu_dcm._kernels.calls import walk_fields
from imu_dcm._kernels.field_steps import KIND_PRIM, KIND_SEQ, KIND_STRING
from imu_dcm.logio.ros.collect import Conn, Payloads
from imu_dcm.logio.ros.schema import PRIM, Defs, typestore_for

__all__ = ["Scratch", "Unsupported", "Want", "decode", "decode_slow", "gather"]


Want = dict[str, tuple[str, int]]  # field path -> (output dtype, element count)


class Unsupported(Exception):
    """The vectorised walker cannot follow this layout; use the per-message decoder."""


def gather(buf: NDArray[np.uint8], pos: NDArray[np.int64], dtype: str, n: int = 1) -> NDArray:
    """Read ``n`` consecutive little-endian ``dtype`` values at each byte position ``pos``.

    A view of the byte buffer with a stride of one byte and items of ``n`` values' bytes puts
    a (possibly unaligned) run at every byte position, so one fancy index copies each run
    whole (one copy per message, ~30 ns for 250 bytes, where a gather of unaligned values one
    by one costs ~20 ns each) into a fresh, aligned array, then seen as ``dtype``.
    """
    dt = np.dtype("<" + dtype)
    pos = np.asarray(pos)
    width = dt.itemsize * n
    count = len(buf) - width + 1
    if count <= 0:
        return np.zeros(pos.shape + ((n,) if n > 1 else ()), dtype=dt)
    runs = np.ndarray((count,), dtype=np.dtype((np.void, width)), buffer=buf, strides=(1,))
    got = runs[pos].view(dt)
    return got.reshape(pos.shape + (n,)) if n > 1 else got.reshape(pos.shape)


# One step of a compiled walk (see :func:`_compile`): ``kind`` "prim" (``n`` values of ``size``
# bytes, gathered as ``path`` when ``dtype`` is set), "seq" (a u4 count, then values of
# ``size`` bytes) or "string" (a u4 length, then the bytes).
_Step = tuple[str, int, int, str, str, int, str]  # kind, size, n, path, prim, count, dtype


def _compile(defs: Defs, type_name: str, want: Want, found: set, steps: list, path0: str, depth):
    """Flatten the walk through ``type_name`` into ``steps``, in field order, up to the last
    wanted leaf. Raises :class:`Unsupported` for what the walker cannot follow."""
    if type_name not in defs or depth > 64:
        raise Unsupported(f"no definition of {type_name}")
    for f in defs[type_name]:
        if len(found) == len(want):
            return
        path = path0 + f.name
        inside = any(k == path or k.startswith(path + ".") for k in want)
        if f.base in PRIM:
            size = np.dtype(PRIM[f.base]).itemsize
            if path in want and f.array == "seq":
                raise Unsupported("a wanted field is a sequence")
            dtype, count = want.get(path, ("", 0))
            if dtype:
                found.add(path)
            if f.array == "seq":
                steps.append(("seq", size, 0, "", "", 0, ""))
            else:
                n = f.count if f.array == "fixed" else 1
                steps.append(("prim", size, n, path, PRIM[f.base], count, dtype))
        elif f.base == "string":
            if f.array is not None or inside:
                raise Unsupported("string arrays or wanted strings")
            steps.append(("string", 4, 0, "", "", 0, ""))
        else:
            if f.array is not None:
                raise Unsupported("an array of messages before the wanted fields")
            _compile(defs, f.base, want, found, steps, path + ".", depth + 1)


_KINDS = {"prim": KIND_PRIM, "seq": KIND_SEQ, "string": KIND_STRING}


class _Walk:
    """A compiled walk as the kernel reads it: ``steps`` (k, 6) int64 (the columns of
    :mod:`imu_dcm._kernels.field_steps`), ``width`` words a message, and each wanted leaf's
    ``(path, first word, count, primitive, output dtype)``."""

    __slots__ = ("leaves", "steps", "width")

    def __init__(self, steps: list[_Step]) -> None:
        rows, leaves, width = [], [], 0
        for kind, size, n, path, prim, count, dtype in steps:
            col = -1
            if dtype:
                col, width = width, width + count
                leaves.append((path, col, count, prim, dtype))
            row = [_KINDS[kind], size, n, int(prim[:1] == "i"), col, count if dtype else 0]
            last = rows[-1] if rows else None
            # the next values of a run (x, y, z of a vector), all wanted or none: one step
            if (
                last is not None and row[0] == last[0] == KIND_PRIM
                and (row[1], row[3]) == (last[1], last[3])
                and (
                    (col >= 0 and row[5] == n and last[5] == last[2] and col == last[4] + last[5])
                    or col == last[4] == -1
                )
            ):  # fmt: skip
                last[2] += n
                last[5] += row[5]
            else:
                rows.append(row)
        self.steps = np.array(rows, np.int64).reshape(-1, 6)
        self.width = width
        self.leaves = tuple(leaves)


_PLANS: dict = {}


def _plan(defs: Defs, root: str, want: Want) -> _Walk | Unsupported:
    """The compiled walk of ``root`` for ``want``, computed once per layout and reused (a live
    source decodes a batch every few ms). Holds ``defs`` so that its ``id`` stays its own."""
    key = (id(defs), root, tuple(want.items()))
    hit = _PLANS.get(key)
    if hit is not None and hit[0] is defs:
        return hit[1]
    steps: list = []
    found: set = set()
    try:
        _compile(defs, root, want, found, steps, "", 0)
        if len(found) != len(want):
            raise Unsupported(f"fields {sorted(set(want) - found)} not found")
        plan: _Walk | Unsupported = _Walk(steps)
    except Unsupported as exc:
        plan = exc
    if len(_PLANS) >= 64:
        _PLANS.clear()
    _PLANS[key] = (defs, plan)
    return plan


class Scratch:
    """The walk's words, reused from batch to batch by one decoder: fresh memory costs more
    to touch than the walk that fills it. The leaves :func:`decode` returns are views of it,
    valid until its next use in the same thread (each thread has its own)."""

    __slots__ = ("_local",)

    def __init__(self) -> None:
        self._local = threading.local()

    def words(self, n: int, width: int) -> NDArray[np.uint64]:
        buf = getattr(self._local, "buf", None)
        if buf is None or len(buf) < n * width:
            buf = self._local.buf = np.empty(n * width + (n * width >> 2), np.uint64)
        return buf[: n * width].reshape(n, width)


def _words_as(words: NDArray[np.uint64], col: int, count: int, prim: str, dtype: str) -> NDArray:
    """The leaf at ``words[:, col : col + count]`` as ``dtype``: a view where the types allow
    (a float64, an integer into int64), else converted."""
    block = words[:, col] if count == 1 else words[:, col : col + count]
    if prim == "f4":
        values = block.astype(np.uint32).view(np.float32)
    elif prim in ("f8", "u8"):
        values = block.view("<" + prim)
    else:  # an integer of 1-4 bytes, or int64: extended to 64 bits by the walk
        values = block.view(np.int64)
    return values.astype(dtype, copy=False)


def _walk(
    conn: Conn, plan: _Walk, raw: Payloads, want: Want, scratch: Scratch | None
) -> tuple[dict[str, NDArray], NDArray[np.bool_]]:
    """The wanted leaves of every message of ``raw`` by the compiled walk; a message it cannot
    follow to the end (too short, big-endian) is given to rosbags' deserialiser. Returns the
    leaves (views of the words: of ``scratch`` when given) and which messages decoded."""
    n, width = len(raw), plan.width
    words = np.empty((n, width), np.uint64) if scratch is None else scratch.words(n, width)
    ok = np.empty(n, bool)
    cdr = conn.encoding != "ros1"
    bad = walk_fields(raw.buf, raw.start, raw.length, cdr, plan.steps, words, ok)
    out = {path: _words_as(words, *rest) for path, *rest in plan.leaves}
    if bad:  # whatever rosbags makes of them (those inside the buffer)
        rows = np.flatnonzero(~ok)
        rows = rows[(raw.start[rows] >= 0) & (raw.start[rows] + raw.length[rows] <= len(raw.buf))]
        sub = Payloads(raw.buf, raw.start[rows], raw.length[rows], raw.log_time[rows], rows)
        slow, ok[rows] = decode_slow(conn, sub, want)
        for k, v in out.items():
            v[rows] = slow[k]
    return out, ok


def decode(
    conn: Conn, defs: Defs, root: str, raw: Payloads, want: Want, scratch: Scratch | None = None
) -> tuple[dict[str, NDArray], NDArray[np.bool_]]:
    """Decode the wanted leaves of every message of ``raw``; with ``scratch``, the leaves may
    be views of it (valid until its next use).

    Returns
    -------
    out : dict field path -> array (N,) or (N, count); rows of undecodable messages are NaN / 0.
    good : bool (N,) — messages that decoded.
    """
    plan = _plan(defs, root, want)
    if isinstance(plan, Unsupported):
        return decode_slow(conn, raw, want)
    out, good = _walk(conn, plan, raw, want, scratch)
    if not good.all():
        for v in out.values():
            v[~good] = np.nan if v.dtype.kind == "f" else 0
    return out, good


def _leaf(msg, path: str):
    v = msg
    for part in path.split("."):
        v = getattr(v, part)
    return v


def decode_slow(
    conn: Conn, raw: Payloads, want: Want
) -> tuple[dict[str, NDArray], NDArray[np.bool_]]:
    """Per-message fallback with rosbags' deserialiser (layouts the walker cannot follow)."""
    try:
        store, root = typestore_for(conn)
        store.get_msgdef(root)
    except Exception:
        store = None
    n = len(raw)
    out = {
        k: np.full((n, c) if c > 1 else n, np.nan if np.dtype(d).kind == "f" else 0, dtype=d)
        for k, (d, c) in want.items()
    }
    good = np.zeros(n, dtype=bool)
    if store is None:
        return out, good
    deser = store.deserialize_ros1 if conn.encoding == "ros1" else store.deserialize_cdr
    for i in range(n):
        try:
            msg = deser(raw.payload(i), root)
            vals = {k: _leaf(msg, k) for k in want}
        except Exception:
            continue
        for k, (_, c) in want.items():
            v = vals[k]
            if isinstance(v, (list, tuple, np.ndarray)):
                v = np.asarray(v).ravel()
                if len(v) < c:
                    continue  # an empty sequence holds no value: the row keeps NaN / 0
                v = v[0] if c == 1 else v[:c]
            out[k][i] = v
        good[i] = True
    return out, good

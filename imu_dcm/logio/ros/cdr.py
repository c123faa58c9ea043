"""Bulk numpy decoding of ROS 2 CDR and ROS 1 payloads: one pass per field, all messages at once.

A vectorised walker follows the fields of a message definition in order, keeping one byte
offset per message (strings and sequences make offsets differ between messages, e.g. a
``frame_id`` of varying length) and gathers the wanted leaves (``header.stamp``,
``angular_velocity`` ...) with one fancy index each. ROS 2 CDR aligns each primitive to its
size relative to the payload after the 4-byte encapsulation header; ROS 1 packs fields little
endian without alignment or header. Layouts the walker cannot follow (sequences of strings or
of messages before a wanted field, big-endian CDR) fall back to rosbags' deserialiser, message
by message.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from imu_dcm.logio.ros.collect import Conn, Payloads
from imu_dcm.logio.ros.schema import PRIM, Defs, typestore_for

__all__ = ["BLOCK", "Unsupported", "Want", "decode", "decode_slow", "gather"]


Want = dict[str, tuple[str, int]]  # field path -> (output dtype, element count)


class Unsupported(Exception):
    """The vectorised walker cannot follow this layout; use the per-message decoder."""


class _Short(Exception):
    """Some message is shorter than the layout."""


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


_PLANS: dict = {}


def _plan(defs: Defs, root: str, want: Want) -> tuple[_Step, ...] | Unsupported:
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
        plan: tuple | Unsupported = tuple(steps)
    except Unsupported as exc:
        plan = exc
    if len(_PLANS) >= 64:
        _PLANS.clear()
    _PLANS[key] = (defs, plan)
    return plan


def _skip(buf, base, off, room, room_min, align: bool):
    """Offsets after a u4 count or length at ``off``, and the count (int if all equal)."""
    if align:
        off = (off + 3) & ~3
    if (off + 4 > room_min) if isinstance(off, int) else np.any(off + 4 > room):
        raise _Short
    n = gather(buf, base + off, "u4").astype(np.int64)
    lo, hi = n.min(), n.max()
    return off + 4, (int(lo) if lo == hi else n)


def _run(plan, buf, base, end, out: dict, align: bool) -> None:
    """Follow a compiled walk over every message at once; gather the wanted leaves into ``out``.

    The offset stays a Python int while it is the same in every message (the usual case: one
    ``frame_id`` per channel), an array once strings or sequences make messages differ. Leaves
    at an int offset are gathered together, one fancy index per primitive type.
    """
    room = end - base
    room_min = int(room.min())
    off: int | NDArray[np.int64] = 0
    fixed: dict[str, list] = {}  # primitive -> [(path, offset, count, dtype)]
    for kind, size, n, path, prim, count, dtype in plan:
        if kind == "string":
            off, length = _skip(buf, base, off, room, room_min, align)
            off = off + length
            continue
        if kind == "seq":
            off, n = _skip(buf, base, off, room, room_min, align)
        if align and size > 1:
            off = (off + size - 1) & ~(size - 1)
        if dtype:
            need = off + size * count
            if (need > room_min) if isinstance(need, int) else np.any(need > room):
                raise _Short
            if isinstance(off, int):
                fixed.setdefault(prim, []).append((path, off, count, dtype))
            else:
                out[path] = gather(buf, base + off, prim, count).astype(dtype)
        off = off + size * n
    if fixed:
        _gather_fixed(buf, base, fixed, out)


#: Messages whose runs are copied at once (~1 MiB of runs: they stay in cache, and the same
#: allocation is reused from block to block instead of touching fresh memory, which costs
#: more here than the copy).
BLOCK = 4096


def _gather_fixed(buf, base, fixed: dict[str, list], out: dict) -> None:
    """Leaves at the same offset in every message: the bytes from the first to the last copied
    once per message (one run, :data:`BLOCK` messages at a time), each leaf then seen in it at
    its offset and copied into its output."""
    spans = [(o, o + np.dtype(p).itemsize * c) for p, ls in fixed.items() for _, o, c, _ in ls]
    lo = min(a for a, _ in spans) & ~7  # CDR aligns each value to its size: the run keeps that
    width = max(b for _, b in spans) - lo  # inside every message (checked by the walk)
    n = len(base)
    if n and int(base.max()) + lo + (-width % 8) + width <= len(buf):
        width += -width % 8  # a whole number of float64: the leaves stay aligned in the run
    runs = np.ndarray((len(buf) - width + 1,), np.dtype((np.void, width)), buf, strides=(1,))
    views = []
    for prim, leaves in fixed.items():
        size = np.dtype(prim).itemsize
        for path, off, count, dtype in leaves:
            dst = out[path] = np.empty((n, count) if count > 1 else n, dtype)
            views.append((dst, off - lo, size * count, "<" + prim, count))
    for a in range(0, n, BLOCK):
        b = min(n, a + BLOCK)
        rows = runs[base[a:b] + lo].view(np.uint8).reshape(b - a, width)
        for dst, at, nbytes, prim, count in views:
            v = rows[:, at : at + nbytes].view(prim)
            dst[a:b] = v[:, 0] if count == 1 else v


def decode(
    conn: Conn, defs: Defs, root: str, raw: Payloads, want: Want
) -> tuple[dict[str, NDArray], NDArray[np.bool_]]:
    """Decode the wanted leaves of every message of ``raw``.

    Returns
    -------
    out : dict field path -> array (N,) or (N, count); rows of undecodable messages are NaN / 0.
    good : bool (N,) — messages that decoded.
    """
    n = len(raw)
    if n == 0:
        return {
            k: np.zeros((0, c) if c > 1 else 0, dtype=d) for k, (d, c) in want.items()
        }, np.zeros(0, bool)
    ros1 = conn.encoding == "ros1"
    if ros1:
        good = np.ones(n, bool)
        base_all = raw.start
    else:
        good = raw.length >= 4
        enc = np.where(good, raw.buf[np.minimum(raw.start + 1, max(len(raw.buf) - 1, 0))], 1)
        if np.any(enc[good] != 1):
            if np.all(enc[good] == 0):
                return decode_slow(conn, raw, want)  # big-endian CDR
            good &= enc == 1  # mixed endianness: keep the little-endian ones
        base_all = raw.start + 4
    every = bool(good.all())  # the usual batch: its offsets as they are, no gathered copy
    idx = None if every else np.flatnonzero(good)
    base = base_all if every else base_all[idx]
    end = raw.start + raw.length if every else raw.start[idx] + raw.length[idx]
    plan = _plan(defs, root, want)
    if isinstance(plan, Unsupported):
        return decode_slow(conn, raw, want)
    out: dict[str, NDArray] = {}
    if not len(base):
        out = {k: np.zeros((0, c) if c > 1 else 0, dtype=d) for k, (d, c) in want.items()}
    else:
        try:
            _run(plan, raw.buf, base, end, out, align=not ros1)
        except _Short:
            return decode_slow(conn, raw, want)
    if every:
        return out, good  # every message decoded: no row to fill
    full = {}
    for k, v in out.items():
        arr = np.full((n,) + v.shape[1:], np.nan if v.dtype.kind == "f" else 0, dtype=v.dtype)
        arr[idx] = v
        full[k] = arr
    return full, good


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

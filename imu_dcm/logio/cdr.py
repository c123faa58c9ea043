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

from imu_dcm.logio.schema import PRIM, Defs, typestore_for
from imu_dcm.logio.types import Conn, Payloads

Want = dict[str, tuple[str, int]]  # field path -> (output dtype, element count)


class Unsupported(Exception):
    """The vectorised walker cannot follow this layout; use the per-message decoder."""


class _Short(Exception):
    """Some message is shorter than the layout."""


def gather(buf: NDArray[np.uint8], pos: NDArray[np.int64], dtype: str, n: int = 1) -> NDArray:
    """Read ``n`` consecutive little-endian ``dtype`` values at each byte position ``pos``.

    A view of the byte buffer with a stride of one byte and the item size of ``dtype`` puts a
    (possibly unaligned) value at every byte position, so one fancy index reads them all.
    """
    dt = np.dtype("<" + dtype)
    count = len(buf) - dt.itemsize + 1
    if count <= 0:
        return np.zeros((len(pos), n) if n > 1 else len(pos), dtype=dt)
    view = np.ndarray((count,), dtype=dt, buffer=buf, strides=(1,))
    if n == 1:
        return view[pos]
    return view[pos[:, None] + dt.itemsize * np.arange(n)]


def _walk(
    defs: Defs,
    type_name: str,
    buf,
    base,
    off,
    end,
    want: Want,
    out: dict,
    align: bool,
    prefix: str = "",
    depth: int = 0,
):
    """Advance per-message offsets ``off`` through ``type_name``; gather wanted leaves.

    ``base`` is each payload body's byte position (CDR aligns relative to it); ``end`` the
    payload end, for bounds checks. Returns the offsets after the type; stops early once all
    wanted fields are found.
    """
    if type_name not in defs or depth > 64:
        raise Unsupported(f"no definition of {type_name}")
    for f in defs[type_name]:
        if len(out) == len(want):
            return off
        path = prefix + f.name
        inside = any(k == path or k.startswith(path + ".") for k in want)
        if f.base in PRIM:
            size = np.dtype(PRIM[f.base]).itemsize
            if f.array == "seq":
                if align:
                    off = (off + 3) & ~3
                if np.any(base + off + 4 > end):
                    raise _Short
                n = gather(buf, base + off, "u4").astype(np.int64)
                off = off + 4
            else:
                n = f.count if f.array == "fixed" else 1
            if align and size > 1:
                off = (off + size - 1) & ~(size - 1)
            if path in want:
                dtype, count = want[path]
                if f.array == "seq":
                    raise Unsupported("a wanted field is a sequence")
                if np.any(base + off + size * count > end):
                    raise _Short
                out[path] = gather(buf, base + off, PRIM[f.base], count).astype(dtype)
            off = off + size * n
        elif f.base == "string":
            if f.array is not None or inside:
                raise Unsupported("string arrays or wanted strings")
            if align:
                off = (off + 3) & ~3
            if np.any(base + off + 4 > end):
                raise _Short
            off = off + 4 + gather(buf, base + off, "u4").astype(np.int64)
        else:
            if f.array is not None:
                raise Unsupported("an array of messages before the wanted fields")
            off = _walk(defs, f.base, buf, base, off, end, want, out, align, path + ".", depth + 1)
    return off


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
    idx = np.flatnonzero(good)
    base = base_all[idx]
    end = raw.start[idx] + raw.length[idx]
    out: dict[str, NDArray] = {}
    try:
        _walk(defs, root, raw.buf, base, np.zeros_like(base), end, want, out, align=not ros1)
        if len(out) != len(want):
            raise Unsupported(f"fields {sorted(set(want) - set(out))} not found")
    except (Unsupported, _Short):
        return decode_slow(conn, raw, want)
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

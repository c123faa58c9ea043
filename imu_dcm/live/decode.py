"""The one place live touches the project's log reader: ros2msg schemas and bulk CDR decoding.

Live sources deliver raw CDR payloads with the ``ros2msg`` schema text their server advertised.
Decoding goes through the reader's own schema parser and vectorised CDR walker (one numpy pass
over a batch of payloads), never a decoder of our own, so a live sample decodes exactly as the
same message read from a recorded bag. :func:`classify_schema` tells whether a schema is an IMU
(``sensor_msgs/msg/Imu`` or a type holding one) or a truth type, the same rule the reader uses to
pick channels; :func:`decode_cdr_batch` decodes a batch.

Conventions: stamps int64 ns (``header.stamp``); ``omega_b`` (N, 3) body rate as the message
stores it (rad/s in ROS); truth ``q_w_b`` (M, 4) ``[x, y, z, w]``, body to world.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

# The reader's internals live here only (the lead repoints this import when the reader moves).
from imu_dcm import bag_reader as _reader

__all__ = ["IMU_TYPE", "TRUTH_TYPES", "Decoded", "classify_schema", "decode_cdr_batch"]

IMU_TYPE = _reader.IMU_TYPE
TRUTH_TYPES = _reader.TRUTH_TYPES


@dataclass(frozen=True)
class Decoded:
    """A decoded batch: ``t_ns`` int64 (n,), ``values`` float64 (n, 3) rates or (n, 4)
    quaternions, ``good`` bool (len(payloads),) — which payloads decoded (the others are
    counted as malformed by the caller)."""

    t_ns: NDArray[np.int64]
    values: NDArray[np.float64]
    good: NDArray[np.bool_]


def classify_schema(name: str, encoding: str, text: str) -> tuple[str, str] | None:
    """What a channel carries: ``("imu", field path)``, ``("truth", quaternion path)`` or None.

    Parameters
    ----------
    name : str
        Schema name, e.g. ``sensor_msgs/msg/Imu``.
    encoding : str
        Schema encoding; only ``ros2msg`` (with CDR messages) is decoded.
    text : str
        The ``ros2msg`` definition text.
    """
    if encoding != "ros2msg":
        return None
    full = _reader._norm_type(name, "")
    if full == IMU_TYPE or name == "sensor_msgs/Imu":
        return "imu", ""
    if full in TRUTH_TYPES:
        return "truth", TRUTH_TYPES[full]
    if "Imu" in text:
        defs = _reader._parse_definitions(name, text)
        path = _reader._find_imu_path(defs, full)
        if path is not None:
            return "imu", path
    return None


def decode_cdr_batch(kind: tuple[str, str], name: str, encoding: str, text: str,
                     payloads: list[bytes], topic: str) -> Decoded:
    """Decode CDR payloads of one channel in bulk with the reader's walker.

    Parameters
    ----------
    kind : tuple
        From :func:`classify_schema`.
    name, encoding, text : str
        The channel's schema.
    payloads : list of bytes
        Raw CDR messages (with their 4-byte encapsulation header).
    topic : str
        For messages.

    Returns
    -------
    Decoded
        IMU: ``values`` = ``angular_velocity`` (n, 3); truth: the quaternion (n, 4) ``[x, y, z,
        w]``. Only the payloads that decode (``good``) are in ``t_ns`` / ``values``.
    """
    lengths = np.fromiter((len(p) for p in payloads), np.int64, len(payloads))
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64)
    joined = b"".join(payloads)
    raw = _reader._Raw(np.frombuffer(joined, np.uint8), starts, lengths,
                       np.zeros(len(payloads), np.int64), [joined],
                       np.zeros(len(payloads), np.int64), starts)  # fmt: skip
    schema = _reader._Schema(name, encoding, text.encode("utf-8"))
    what, path = kind
    if what == "imu":
        out, good = _reader._decode_cdr(raw, schema, _reader._imu_want(path), topic)
        p = path + "." if path else ""
        t_ns = _reader._stamps(out, path)
        values = np.stack([out[p + "angular_velocity." + a] for a in "xyz"], axis=1)
    else:
        full = _reader._norm_type(name, "")
        defs = _reader._parse_definitions(name, text)
        hdr = _reader._header_prefix(defs, full) or "header"
        want = {f"{path}.{a}": ("f8", 1) for a in "xyzw"}
        want[hdr + ".stamp.sec"] = ("i8", 1)
        want[hdr + ".stamp.nanosec"] = ("i8", 1)
        out, good = _reader._decode_cdr(raw, schema, want, topic)
        t_ns = out[hdr + ".stamp.sec"] * 1_000_000_000 + out[hdr + ".stamp.nanosec"]
        values = np.stack([out[f"{path}.{a}"] for a in "xyzw"], axis=1)
    good = np.asarray(good, dtype=bool)
    return Decoded(np.asarray(t_ns, np.int64)[good], values[good], good)

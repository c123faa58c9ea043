"""Decode a batch of raw payloads that did not come from a file (live sources), as a file would.

A live source (a Foxglove WebSocket, a ROS bridge) delivers raw CDR payloads with the schema its
server advertised. :func:`classify_schema` tells whether a channel is an IMU (``sensor_msgs/Imu``,
a type holding one, or a ``geometry_msgs/Vector3Stamped`` gyro) or a truth type, by the same rule
:func:`imu_dcm.logio.read_log` picks channels; :func:`decode_cdr_batch` decodes a batch with the
same bulk decoder, so a live sample decodes exactly as the same message read from a bag.

Conventions: stamps int64 ns (``header.stamp``); ``omega_b`` (N, 3) body rate as the message
stores it (rad/s in ROS); ``accel_b`` (N, 3) its ``linear_acceleration`` (m/s², NaN rows where
the message flags none: covariance[0] = -1); truth ``q_w_b`` (M, 4) ``[x, y, z, w]``, body to world.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from imu_dcm.logio.ros.channels import IMU_TYPE, TRUTH_TYPES, ChannelDecoder, imu_path
from imu_dcm.logio.ros.collect import Conn, Payloads
from imu_dcm.logio.ros.schema import norm_type

__all__ = ["IMU_TYPE", "TRUTH_TYPES", "Decoded", "classify_schema", "decode_cdr_batch"]


@dataclass(slots=True, frozen=True)
class Decoded:
    """A decoded batch: ``t_ns`` int64 (n,), ``values`` float64 (n, 3) rates or (n, 4)
    quaternions ``[x, y, z, w]``, ``good`` bool (len(payloads),) — which payloads decoded (only
    those are in ``t_ns`` / ``values``), ``accel`` float64 (n, 3) an IMU's linear acceleration,
    m/s², or None (a type without one, or every message of the batch flags none)."""

    t_ns: NDArray[np.int64]
    values: NDArray[np.float64]
    good: NDArray[np.bool_]
    accel: NDArray[np.float64] | None = None


def classify_schema(name: str, encoding: str, text: str) -> tuple[str, str] | None:
    """What a CDR channel carries: ``("imu", field path)``, ``("truth", quaternion path)`` or None.

    Parameters
    ----------
    name : str
        Schema name, e.g. ``sensor_msgs/msg/Imu``.
    encoding : str
        Schema encoding: ``ros2msg`` or ``ros2idl`` (anything else gives None).
    text : str
        The schema text.
    """
    if encoding not in ("ros2msg", "ros2idl"):
        return None
    path = imu_path(Conn(0, "", name, "cdr", encoding, text))
    if path is not None:
        return "imu", path
    full = norm_type(name)
    if full in TRUTH_TYPES:
        return "truth", TRUTH_TYPES[full]
    return None


@functools.lru_cache(maxsize=64)
def _decoder(
    kind: tuple[str, str], name: str, encoding: str, text: str, topic: str
) -> ChannelDecoder:
    """One decoder per channel (its schema parsed once, not per batch: a live source decodes
    a batch every few ms)."""
    what, path = kind
    conn = Conn(0, topic, name, "cdr", encoding, text)
    return ChannelDecoder(conn, "imu", path) if what == "imu" else ChannelDecoder(conn, "truth")


def decode_cdr_batch(
    kind: tuple[str, str], name: str, encoding: str, text: str, payloads: list[bytes], topic: str
) -> Decoded:
    """Decode CDR payloads of one channel in bulk.

    Parameters
    ----------
    kind : tuple
        From :func:`classify_schema`.
    name, encoding, text : str
        The channel's schema.
    payloads : list of bytes
        Raw CDR messages (with their 4-byte encapsulation header).
    topic : str
        Named in error messages.

    Returns
    -------
    Decoded
        IMU: ``values`` = the angular velocity (n, 3), ``accel`` its linear acceleration
        (decoded in bulk with it); truth: the quaternion (n, 4).

    Raises
    ------
    LogError
        The schema cannot be read.
    """
    n = len(payloads)
    lengths = np.fromiter(map(len, payloads), np.int64, n)
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]]).astype(np.int64)
    raw = Payloads(
        np.frombuffer(b"".join(payloads), np.uint8),
        starts,
        lengths,
        np.zeros(n, np.int64),
        np.arange(n, dtype=np.int64),
    )
    what = kind[0]
    cols = _decoder(kind, name, encoding, text, topic)(raw)
    if cols.error is not None:
        raise cols.error
    good = np.zeros(n, bool)
    good[cols.order] = True
    values = cols.fields.get("omega" if what == "imu" else "q")
    if values is None:
        values = np.zeros((0, 3 if what == "imu" else 4))
    t_ns = cols.fields.get("t_ns", np.zeros(0, np.int64))
    accel = cols.fields.get("accel") if what == "imu" else None
    if accel is not None:
        accel = np.asarray(accel, np.float64)
    return Decoded(np.asarray(t_ns, np.int64), np.asarray(values, np.float64), good, accel)

"""What the log readers return (the raw form a ROS container hands to the decoders is in
:mod:`imu_dcm.logio.ros.collect`).

Conventions: stamps are int64 nanoseconds (``t_ns`` from the messages' header stamps,
``log_t_ns`` from the container's receive/log time); rates ``omega_b`` are the body angular
velocity in body (sensor) axes as stored (normally rad/s); quaternions are ``[x, y, z, w]``
(Hamilton) and, for truth, ``q_w_b`` maps body to world.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "ChannelInfo",
    "Damage",
    "ImuSeries",
    "LogData",
    "StaticTransform",
    "TruthSeries",
    "VehicleState",
]


@dataclass(frozen=True)
class ChannelInfo:
    """One channel of the log: ``topic``, message ``type`` (schema name), ``encoding``, count."""

    topic: str
    type: str
    encoding: str
    count: int


@dataclass(frozen=True)
class Damage:
    """A damaged part of a log that was skipped.

    Attributes
    ----------
    offset : int — byte offset of the damaged record in its file (never chunk-relative);
        -1 where the container has no byte offsets (a message of a sqlite3 bag).
    what : str — what was wrong, one line (names the file when a bag has several).
    t_start_ns, t_end_ns : int or None — log-time range the damaged part covered, when known.
    messages_lost : int or None — messages of the selected channels it held, when known.
    """

    offset: int
    what: str
    t_start_ns: int | None = None
    t_end_ns: int | None = None
    messages_lost: int | None = None


@dataclass(frozen=True)
class ImuSeries:
    """Gyro samples of the IMU topic, in file order (not yet sorted or cleaned).

    Attributes
    ----------
    t_ns : int64 (N,) — header stamps, ns.
    log_t_ns : int64 (N,) — the container's log (receive) times, ns.
    omega_b : float64 (N, 3) — angular velocity, body (sensor) axes, in the log's unit (rad/s
        for ROS). Not cleaned: may hold NaN/Inf.
    orientation_xyzw : float64 (N, 4) or None — the message's own orientation ``q_w_b``
        ``[x, y, z, w]``; NaN rows where ``orientation_covariance[0] == -1`` (none given).
    topic, type, frame_id : where the samples came from.
    accel_b : float64 (N, 3) or None — specific force (accelerometer), body (sensor) axes,
        m/s², on the same rows as ``omega_b``; None where the log has none. Used to judge rest.
    gyro_absent : bool — the messages mark the angular velocity as absent (ROS
        ``angular_velocity_covariance[0] == -1`` on every message).
    log_axes : str — "" when ``omega_b`` is in the log's own axes; otherwise the log's axes
        that the reader converted from (``"FRD"``: PX4 and ArduPilot, ``omega_b = (x, -y, -z)``
        of the log's; :data:`imu_dcm.logio.ned.LOG_AXES`).
    """

    t_ns: NDArray[np.int64]
    log_t_ns: NDArray[np.int64]
    omega_b: NDArray[np.float64]
    orientation_xyzw: NDArray[np.float64] | None
    topic: str
    type: str
    frame_id: str
    accel_b: NDArray[np.float64] | None = None
    gyro_absent: bool = False
    log_axes: str = ""


@dataclass(frozen=True)
class TruthSeries:
    """Reference attitude samples ``q_w_b`` (``[x, y, z, w]``, body to world) with stamps.

    Attributes
    ----------
    t_ns, log_t_ns : int64 (M,) — header stamps and log times, ns.
    q_w_b : float64 (M, 4) — body-to-world quaternion, ``[x, y, z, w]``.
    topic, type, frame_id : where the samples came from (``frame_id`` is the parent frame).
    child_frame_id : the body frame of a transform or odometry, "" otherwise.
    auto : True when the truth was picked automatically (not named by the caller).
    estimate_of : "" for an independent reference (motion capture, simulation); otherwise who
        estimated it, said to the user ("PX4's own estimate", "ArduPilot's own estimate",
        "wheel odometry", "the IMU's own orientation").
    p_w : float64 (M, 3) or None — the body's position in the parent frame, m, where the
        message carries one (a pose, a transform, odometry).
    omega_b : float64 (M, 3) or None — the body's angular rate in its own frame, rad/s, where
        the message carries one (odometry's ``twist.twist.angular``).
    """

    t_ns: NDArray[np.int64]
    log_t_ns: NDArray[np.int64]
    q_w_b: NDArray[np.float64]
    topic: str
    type: str
    frame_id: str = ""
    child_frame_id: str = ""
    auto: bool = False
    estimate_of: str = ""
    p_w: NDArray[np.float64] | None = None
    omega_b: NDArray[np.float64] | None = None


@dataclass(frozen=True)
class StaticTransform:
    """A static transform of the log's ``/tf_static`` (rotation only).

    Attributes
    ----------
    parent, child : frame ids as the message gives them (``header.frame_id``,
        ``child_frame_id``; a leading '/' is kept here and ignored where frames are compared).
    q_xyzw : ``q_parent_child`` ``[x, y, z, w]``, unit: maps child-frame coordinates into the
        parent frame (``v_parent = R(q_parent_child) v_child``), as tf defines a transform.
    """

    parent: str
    child: str
    q_xyzw: tuple[float, float, float, float]


@dataclass(frozen=True)
class VehicleState:
    """The vehicle's landed and armed state as the autopilot logged it (a step series).

    Each value holds from its stamp until the next one (the autopilot publishes on change and
    at a low rate); before the first stamp the state is unknown. ``landed`` and ``armed`` are
    int8 (M,): 1 true, 0 false, -1 not logged at that stamp (the other one changed).
    ``t_ns`` (M,) int64 ns, increasing, on the IMU's clock (``ImuSeries.t_ns``). ``source``
    names where it came from ("vehicle_land_detected, actuator_armed"; "EV (arm, land)").
    """

    t_ns: NDArray[np.int64]
    landed: NDArray[np.int8]
    armed: NDArray[np.int8]
    source: str

    @classmethod
    def of(cls, source: str, landed=None, armed=None) -> VehicleState | None:
        """Merge ``(t_ns, values)`` step series of each (either may be None); None if both are.

        Values are truthy or not (PX4's uint8 flags); at equal stamps the landed row comes first.
        """
        given = ((k, tv) for k, tv in enumerate((landed, armed)) if tv is not None)
        parts = [(np.asarray(tv[0], np.int64), np.asarray(tv[1]) != 0, k) for k, tv in given]
        parts = [p for p in parts if len(p[0])]
        if not parts:
            return None
        t = np.concatenate([p[0] for p in parts])
        cols = np.full((2, len(t)), -1, np.int8)
        at = 0
        for stamps, values, k in parts:
            cols[k, at : at + len(stamps)] = values
            at += len(stamps)
        order = np.argsort(t, kind="stable")
        return cls(t[order], cols[0, order], cols[1, order], source)

    def at(self, t_ns: NDArray[np.int64]) -> tuple[NDArray[np.int8], NDArray[np.int8]]:
        """``(landed, armed)`` held at each stamp of ``t_ns`` (-1 where not known)."""
        k = np.searchsorted(self.t_ns, np.asarray(t_ns, dtype=np.int64), side="right") - 1
        held = [np.where(k >= 0, _hold(x)[np.maximum(k, 0)], -1).astype(np.int8)
                for x in (self.landed, self.armed)]  # fmt: skip
        return held[0], held[1]


def _hold(x: NDArray[np.int8]) -> NDArray[np.int8]:
    """Each -1 (not logged) replaced by the last logged value before it (-1 before any)."""
    x = np.asarray(x, dtype=np.int8)
    idx = np.where(x >= 0, np.arange(len(x)), -1)
    last = np.maximum.accumulate(idx) if len(x) else idx
    return np.where(last >= 0, x[np.maximum(last, 0)], -1).astype(np.int8)


@dataclass(frozen=True)
class LogData:
    """What :func:`imu_dcm.logio.read_log` found: IMU series, truth (or None), channels.

    ``container`` names what was read ("ros2 mcap", "ros2 sqlite3", "ros1 bag", "px4 ulog",
    ...); ``damage`` lists the damaged parts skipped; ``stopped_at`` summarises them (None if
    none). ``truth_candidates`` holds every other attitude series the log offered (the picked
    one is ``truth``), for the replay to judge which follows the gyro; ``notes`` are one-line
    findings of the reader for the user ("sensor_gyro_0: 6 samples at 1 Hz; used
    sensor_combined at 250 Hz"). ``static_transforms`` holds the log's ``/tf_static`` transforms
    (one per child frame, the last one sent; empty where the log has none), from which the
    replay composes the mounting between the IMU's frame and the truth's body frame.
    """

    path: Path
    imu: ImuSeries
    truth: TruthSeries | None
    channels: tuple[ChannelInfo, ...]
    custom_data: dict[str, str] = field(default_factory=dict)
    container: str = ""
    damage: tuple[Damage, ...] = ()
    stopped_at: str | None = None
    truth_candidates: tuple[TruthSeries, ...] = ()
    notes: tuple[str, ...] = ()
    static_transforms: tuple[StaticTransform, ...] = ()
    vehicle_state: VehicleState | None = None

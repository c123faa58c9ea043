"""Read gyro logs of every container a ROS user has, through one interface: :func:`read_log`.

Containers (see :mod:`imu_dcm.logio.containers`): ROS 2 bags with MCAP or sqlite3 storage
(split, ``file``- or ``message``-compressed), single ``.mcap`` files (``ros2`` or ``ros1``
profile; ``ros2msg``, ``ros2idl`` or ``ros1msg`` schemas; CDR, ROS 1 or JSON messages),
single ``.db3`` files and ROS 1 ``.bag`` files (v2.0; uncompressed, bz2 or lz4 chunks).
Only the channels that can be the IMU or the truth are read (a camera topic is never
decompressed); their payloads are decoded in bulk with numpy (:mod:`imu_dcm.logio.cdr`).

A damaged part costs only itself: it is skipped, listed in :attr:`LogData.damage` with its
file offset, and one :class:`~imu_dcm.errors.ImuDcmWarning` summarises the damage.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from pathlib import Path

from imu_dcm.errors import ImuDcmWarning, LogError
from imu_dcm.logio.channels import TRUTH_TYPES, describe, pick_imu_judged, plan, read_imu
from imu_dcm.logio.channels import read_truths as _read_truths
from imu_dcm.logio.containers import open_source, resolve_mcap_path
from imu_dcm.logio.meta import read_custom_data
from imu_dcm.logio.types import ChannelInfo, Damage, ImuSeries, LogData, Sink, TruthSeries

__all__ = [
    "TRUTH_TYPES",
    "ChannelInfo",
    "Damage",
    "ImuSeries",
    "LogData",
    "TruthSeries",
    "read_custom_data",
    "read_log",
    "resolve_mcap_path",
]


def _damage_summary(name: str, damage: list[Damage]) -> str:
    lost = [d.messages_lost for d in damage]
    n_lost = "an unknown number of" if None in lost else str(sum(lost))
    first = damage[0]
    more = f" (and {len(damage) - 1} more)" if len(damage) > 1 else ""
    when = ""
    if first.t_start_ns is not None and first.t_end_ns is not None:
        when = f", log time {first.t_start_ns}..{first.t_end_ns} ns"
    return (
        f"{first.what} (file offset {first.offset}{when}){more}; {n_lost} messages of the "
        f"read channels lost in {len(damage)} damaged part{'s' if len(damage) > 1 else ''}"
    )


def read_log(
    path: str | Path,
    imu_topic: str | None = None,
    truth_topic: str | None = None,
    truth_frame: str | None = None,
    progress: Callable[[float], None] | None = None,
) -> LogData:
    """Read the gyro samples and the reference attitude of a log, whatever its container.

    Parameters
    ----------
    path : str or Path
        A rosbag2 folder (``metadata.yaml`` + ``.mcap`` / ``.db3`` files), a ``.mcap``,
        ``.mcap.zstd`` or ``.db3`` file, or a ROS 1 ``.bag``. Regular files and folders only.
        Never modified.
    imu_topic : str, optional
        The IMU topic. By default the one topic of ``sensor_msgs/Imu``, of a type containing an
        ``Imu`` field (vendor wrappers), or JSON with ``angular_velocity {x, y, z}``; failing
        those, the one ``geometry_msgs/Vector3Stamped`` topic whose name says gyro ("gyr",
        "angular_vel" or "imu"; not under ``/estimate`` or ``/ground_truth``); any
        Vector3Stamped topic when named here.
    truth_topic : str, optional
        The reference attitude ``q_w_b``: ``geometry_msgs`` QuaternionStamped, PoseStamped,
        PoseWithCovarianceStamped, TransformStamped, ``nav_msgs`` Odometry, ``/tf`` (TFMessage),
        or the IMU topic itself for its own orientation. By default the one such topic not under
        ``/estimate``; else the moving transform of ``/tf`` + ``/tf_static``; else the Imu's
        orientation where ``orientation_covariance[0] != -1`` (unit norm, not constant).
        ``"none"`` disables truth.
    truth_frame : str, optional
        The child frame of the ``/tf`` transform to use as truth (where several move).
    progress : callable(fraction), optional
        Called as the file is read with the fraction done (for a progress bar).

    Returns
    -------
    LogData
        IMU samples (header stamps and log times) in file order, not cleaned; truth or None;
        every channel; the container name; the damaged parts skipped.

    Raises
    ------
    LogError
        Missing path, not a regular file or folder, an unreadable format (the message names
        the command that converts it), an empty log, no (or several) IMU topics, a truth topic
        of the wrong type, a corrupt schema.

    Warns
    -----
    ImuDcmWarning
        Damaged parts were skipped (one warning naming the first file offset and the messages
        lost), or messages did not decode.
    """
    source, shown, custom = open_source(path, progress)
    got = source.read(Sink(plan(imu_topic, truth_topic)))
    channels = tuple(
        ChannelInfo(c.topic, c.msgtype, c.encoding, int(c.count or 0)) for c in got.conns
    )
    stopped_at = _damage_summary(shown.name, got.damage) if got.damage else None
    if not channels or sum(c.count for c in channels) == 0 and not got.payloads:
        if stopped_at:  # one line: the damage is why nothing was read
            raise LogError(
                f"Expected messages in the log, got none readable in {shown}: {stopped_at}"
            )
        raise LogError(
            f"Expected messages in the log, got an empty log ({describe(got.conns)}): {shown}"
        )
    topic, conns, notes = pick_imu_judged(got, imu_topic)
    imu, undecodable = read_imu(got, topic, conns)
    if len(imu.t_ns) == 0:
        raise LogError(
            f"Expected IMU samples on {imu.topic}, got none that decode ({undecodable} messages)"
        )
    truth, candidates = _read_truths(got, imu, truth_topic, truth_frame)
    # Warnings only once the log is known to be usable: an error is then the only line.
    if stopped_at:
        warnings.warn(
            f"{shown.name} is truncated or corrupt: {stopped_at}", ImuDcmWarning, stacklevel=2
        )
    if undecodable:
        warnings.warn(
            f"{imu.topic}: dropped {undecodable} messages that do not decode",
            ImuDcmWarning,
            stacklevel=2,
        )
    if progress is not None:
        progress(1.0)
    return LogData(
        shown,
        imu,
        truth,
        channels,
        custom,
        got.kind or source.kind,
        tuple(got.damage),
        stopped_at,
        truth_candidates=candidates,
        notes=notes,
    )

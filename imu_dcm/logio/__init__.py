"""Read gyro logs of every container a ROS user has, through one interface: :func:`read_log`.

Containers (the table :data:`imu_dcm.logio.registry.READERS`): ROS 2 bags with MCAP or sqlite3
storage (split, ``file``- or ``message``-compressed), single ``.mcap`` files (``ros2`` or ``ros1``
profile; ``ros2msg``, ``ros2idl`` or ``ros1msg`` schemas; CDR, ROS 1 or JSON messages),
single ``.db3`` files, ROS 1 ``.bag`` files (v2.0; uncompressed, bz2 or lz4 chunks), PX4 ULog,
ArduPilot DataFlash and EuRoC/ASL dataset folders (CSVs): one reader a container in
:mod:`imu_dcm.logio.containers`, the ROS message decoding they share in :mod:`imu_dcm.logio.ros`,
the bag writer in :mod:`imu_dcm.logio.writers`.
Only the channels that can be the IMU or the truth are read (a camera topic is never
decompressed); their payloads are decoded in bulk with numpy (:mod:`imu_dcm.logio.ros.cdr`).

A damaged part costs only itself: it is skipped, listed in :attr:`LogData.damage` with its
file offset, and one :class:`~imu_dcm.errors.ImuDcmWarning` summarises the damage.
"""

from __future__ import annotations

from pathlib import Path

from imu_dcm.errors import Diagnostics
from imu_dcm.logio.meta import read_custom_data
from imu_dcm.logio.registry import READERS, find_logs, open_log, resolve_mcap_path
from imu_dcm.logio.ros.channels import TRUTH_TYPES
from imu_dcm.logio.source import LogSource, ProgressCallback, ReadRequest, SourceEntry
from imu_dcm.logio.types import (
    ChannelInfo,
    Damage,
    ImuSeries,
    LogData,
    StaticTransform,
    TruthSeries,
)
from imu_dcm.memory import release_freed_memory, reuse_freed_heap

__all__ = [
    "READERS",
    "TRUTH_TYPES",
    "ChannelInfo",
    "Damage",
    "ImuSeries",
    "LogData",
    "LogSource",
    "ProgressCallback",
    "ReadRequest",
    "SourceEntry",
    "StaticTransform",
    "TruthSeries",
    "find_logs",
    "open_log",
    "read_custom_data",
    "read_log",
    "resolve_mcap_path",
]


def read_log(
    path: str | Path,
    imu_topic: str | None = None,
    truth_topic: str | None = None,
    truth_frame: str | None = None,
    progress: ProgressCallback | None = None,
    diagnostics: Diagnostics | None = None,
) -> LogData:
    """Read the gyro samples and the reference attitude of a log, whatever its container.

    Parameters
    ----------
    path : str or Path
        A rosbag2 folder (``metadata.yaml`` + ``.mcap`` / ``.db3`` files), a ``.mcap``,
        ``.mcap.zstd`` or ``.db3`` file, a ROS 1 ``.bag``, a EuRoC/ASL dataset folder (or its
        ``mav0``; :mod:`imu_dcm.logio.containers.euroc`), or any other container of
        :data:`imu_dcm.logio.registry.READERS`. Regular files and folders only. Never modified.
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
    diagnostics : Diagnostics, optional
        Where the warnings below go instead of being warned (the caller's result carries them).

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
    reuse_freed_heap()  # the batches' temporaries from the heap (glibc; once per process)
    source = open_log(path, progress)
    log = source.read(ReadRequest(imu_topic, truth_topic, truth_frame, progress, diagnostics))
    release_freed_memory()  # the decoding's freed batches: ~400 MB after a 1 h log
    return log

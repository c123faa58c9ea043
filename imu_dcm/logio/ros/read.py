"""What every ROS container shares: from the raw channels a container collected to :class:`LogData`.

A ROS container (MCAP, rosbag2 sqlite3, split or compressed rosbag2 folders, ROS 1 bags) only
collects: ``collect(sink)`` walks its file and hands the payloads of the channels the
:class:`~imu_dcm.logio.ros.collect.Sink` wants to the decoders, batch by batch, and returns a
:class:`~imu_dcm.logio.ros.collect.Collected`. :func:`read_ros` then picks the IMU and the
truth channels (:mod:`imu_dcm.logio.ros.imu`, :mod:`imu_dcm.logio.ros.truth`) and builds the
:class:`LogData`; :class:`RosSource` makes that the container's
:meth:`~imu_dcm.logio.source.LogSource.read`.
"""

from __future__ import annotations

from pathlib import Path

from imu_dcm.errors import ImuDcmWarning, LogError, say
from imu_dcm.logio.damage import damage_summary, warn_damage
from imu_dcm.logio.ros.channels import describe, plan
from imu_dcm.logio.ros.collect import Collected, Sink
from imu_dcm.logio.ros.imu import pick_imu, read_imu
from imu_dcm.logio.ros.tf import static_transforms
from imu_dcm.logio.ros.truth import declared_estimates, read_truths
from imu_dcm.logio.source import ProgressCallback, ReadRequest
from imu_dcm.logio.types import ChannelInfo, LogData

__all__ = ["RosSource", "read_ros"]


class RosSource:
    """Base of the ROS containers: ``collect(sink)`` is theirs, ``read(request)`` is shared.

    Attributes
    ----------
    kind : str — the container, as said to the user ("ros2 mcap", "ros1 bag", ...).
    path : Path — the file or folder read; it is :attr:`LogData.path` too.
    progress : callable(fraction) or None — called as the log is read.
    custom_data : dict — the rosbag2 ``custom_data`` of the bag the file belongs to.
    """

    kind = "ros"
    path: Path
    progress: ProgressCallback | None = None
    custom_data: dict[str, str] = {}  # replaced per instance, never mutated

    def collect(self, sink: Sink) -> Collected:
        """Every channel, the kept channels' data (decoded in batches), the damage skipped."""
        raise NotImplementedError

    def read(self, request: ReadRequest) -> LogData:
        return read_ros(self, request)


def _check_not_empty(got: Collected, channels: tuple[ChannelInfo, ...], shown: Path, stopped_at):
    if channels and (sum(c.count for c in channels) or got.payloads):
        return
    if stopped_at:  # one line: the damage is why nothing was read
        raise LogError(f"Expected messages in the log, got none readable in {shown}: {stopped_at}")
    raise LogError(
        f"Expected messages in the log, got an empty log ({describe(got.conns)}): {shown}"
    )


def read_ros(source: RosSource, request: ReadRequest) -> LogData:
    """The IMU series, the truth and every channel of a ROS container (see ``read_log``).

    Warnings (damage skipped, messages that do not decode) are given only once the log is
    known to be usable: an error is then the only line the user sees.
    """
    if request.progress is not None:
        source.progress = request.progress
    got = source.collect(Sink(plan(request.imu_topic, request.truth_topic)))
    shown = source.path
    channels = tuple(
        ChannelInfo(c.topic, c.msgtype, c.encoding, int(c.count or 0)) for c in got.conns
    )
    stopped_at = damage_summary(got.damage) if got.damage else None
    _check_not_empty(got, channels, shown, stopped_at)
    topic, conns, notes = pick_imu(got, request.imu_topic)
    imu, undecodable = read_imu(got, topic, conns)
    if len(imu.t_ns) == 0:
        raise LogError(
            f"Expected IMU samples on {imu.topic}, got none that decode ({undecodable} messages)"
        )
    truth, candidates = read_truths(got, imu, request.truth_topic, request.truth_frame)
    truth, *more = declared_estimates((truth, *candidates), source.custom_data)
    candidates = tuple(more)
    warn_damage(shown, got.damage, stacklevel=4, diagnostics=request.diagnostics)
    if undecodable:
        say(
            request.diagnostics,
            f"{imu.topic}: dropped {undecodable} messages that do not decode",
            ImuDcmWarning,
            stacklevel=4,
        )
    if source.progress is not None:
        source.progress(1.0)
    return LogData(
        shown,
        imu,
        truth,
        channels,
        dict(source.custom_data),
        got.kind or source.kind,
        tuple(got.damage),
        stopped_at,
        truth_candidates=candidates,
        notes=notes,
        static_transforms=static_transforms(got),
    )

"""The reader interface: what every log container implements, and how one is chosen.

A container is one module of :mod:`imu_dcm.logio.containers` holding a class that satisfies
:class:`LogSource`, plus one row in :data:`imu_dcm.logio.registry.READERS` (a
:class:`SourceEntry`) that recognises it by a file's first bytes or a folder's layout.
:func:`imu_dcm.logio.read_log` opens the first entry whose ``probe`` accepts the path and calls
its ``read``; replay, batch and live never know which container they got.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol, runtime_checkable

from imu_dcm.errors import Diagnostics
from imu_dcm.logio.types import LogData

__all__ = ["LogSource", "ProgressCallback", "ReadRequest", "SourceEntry"]


ProgressCallback = Callable[[float], None]


@dataclass(slots=True, frozen=True)
class ReadRequest:
    """What the caller wants from a log.

    Attributes
    ----------
    imu_topic : str or None — the gyro channel by name (a ROS topic, a ULog topic such as
        ``sensor_combined``, an ArduPilot message such as ``IMU[1]``); None picks it.
    truth_topic : str or None — the reference attitude channel; None picks it; ``"none"``
        reads no truth.
    truth_frame : str or None — the child frame of a ``/tf`` transform to use as truth.
    progress : callable(fraction) or None — called as the log is read.
    diagnostics : Diagnostics or None — where the reader's warnings go (damage skipped,
        messages that do not decode); None warns them.
    """

    imu_topic: str | None = None
    truth_topic: str | None = None
    truth_frame: str | None = None
    progress: ProgressCallback | None = None
    diagnostics: Diagnostics | None = None


@runtime_checkable
class LogSource(Protocol):
    """One opened log of one container.

    ``kind`` names the container for the user ("ros2 mcap", "px4 ulog", "euroc folder").
    ``read`` returns the gyro series (rad/s, body axes, int64 ns stamps), the truth (``q_w_b``,
    ``[x, y, z, w]``) or None, every channel, and the damaged parts skipped; it raises
    :class:`~imu_dcm.errors.LogError` (one line naming what and where) when the log cannot
    give a gyro series. Conversions into the toolkit's conventions happen inside ``read``.
    """

    kind: str

    def read(self, request: ReadRequest) -> LogData: ...


@dataclass(slots=True, frozen=True)
class SourceEntry:
    """One row of the container table.

    Attributes
    ----------
    name : str — the container, as said to the user.
    probe : callable(path, head) -> bool — True when ``path`` is this container. ``head`` holds
        the first 64 bytes of a regular file, or ``b""`` for a folder.
    open : callable(path, progress) -> LogSource — opens it (reads no samples yet). A row
        that recognises a format only to refuse it raises :class:`~imu_dcm.errors.LogError`
        here, saying how to convert it.
    search : bool — :func:`imu_dcm.logio.find_logs` lists what this row accepts (False for
        refusals and for the catch-all "folder holding one log").
    """

    name: str
    probe: Callable[[Path, bytes], bool]
    open: Callable[[Path, ProgressCallback | None], LogSource]
    search: bool = True

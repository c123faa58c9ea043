"""Live sources: a Foxglove WebSocket server, UDP lines, stdin lines and MAVLink, one a file.

A source puts :mod:`imu_dcm.live.events` on a queue for the session's loop, in arrival order,
read by its own thread or by the loop (:mod:`imu_dcm.live.sources.base`).

=================  ==========================================================================
SOURCE             module
=================  ==========================================================================
``ws://HOST:PORT``  :mod:`~imu_dcm.live.sources.foxglove` (its client:
                   :mod:`~imu_dcm.live.sources.websocket`)
``udp://HOST:PORT`` :mod:`~imu_dcm.live.sources.udp` (line format: :mod:`imu_dcm.live.lines`)
``-``              :mod:`~imu_dcm.live.sources.stdin` (the same lines)
``mavlink:...``    :mod:`~imu_dcm.live.sources.mavlink` (pymavlink, the ``mavlink`` extra)
=================  ==========================================================================

Beside them: :mod:`~imu_dcm.live.sources.spec` (what a source is opened with),
:mod:`~imu_dcm.live.sources.schemes` (the table, parsing a SOURCE, opening it),
:mod:`~imu_dcm.live.sources.line_source` (the line sources' bulk parse) and
:mod:`~imu_dcm.live.sources.sockets` (what the system tells about a socket or a pipe).

**A new source** is one file here (a :class:`Source` subclass) and one row in :data:`SCHEMES`
(the URL scheme and ``"module:Class"``, imported when a SOURCE of that scheme is opened).
"""

from __future__ import annotations

from imu_dcm.live.sources.base import Source
from imu_dcm.live.sources.schemes import SCHEMES, open_source, parse_source
from imu_dcm.live.sources.spec import BATCH_S, SourceOptions, SourceSpec

__all__ = [
    "BATCH_S",
    "SCHEMES",
    "Source",
    "SourceOptions",
    "SourceSpec",
    "open_source",
    "parse_source",
]

"""The SOURCE argument: the table of URL schemes, parsing a SOURCE, opening its source.

:data:`SCHEMES` maps each URL scheme to the :class:`~imu_dcm.live.sources.Source` class that
reads it, as ``"module:Class"``, imported when a SOURCE of that scheme is opened (a source's
dependencies load only when it is used). ``-`` is stdin.
"""

from __future__ import annotations

import importlib
from urllib.parse import urlsplit

from imu_dcm.errors import InputError
from imu_dcm.live.sources.base import Source
from imu_dcm.live.sources.spec import BATCH_S, SourceOptions, SourceSpec

__all__ = ["SCHEMES", "open_source", "parse_source"]

#: SOURCE URL scheme -> the Source class that reads it, as ``"module:Class"`` (imported on
#: open). ``-`` is stdin. A new source: one file of this package and one row here.
SCHEMES: dict[str, str] = {
    "ws": "imu_dcm.live.sources.foxglove:WsSource",
    "udp": "imu_dcm.live.sources.udp:UdpSource",
    "-": "imu_dcm.live.sources.stdin:StdinSource",
    "mavlink": "imu_dcm.live.sources.mavlink:MavlinkSource",
}


def parse_source(text: str) -> SourceSpec:
    """``SCHEME://HOST:PORT`` for a scheme of :data:`SCHEMES`, or ``-`` (stdin); raises
    InputError otherwise."""
    if text == "-":
        return SourceSpec("stdin")
    if text.startswith("mavlink:"):  # a pymavlink-style connection: .mavlink
        return SourceSpec("mavlink", url=text)
    parts = urlsplit(text)
    try:
        port = parts.port
    except ValueError:
        port = None
    if parts.scheme not in SCHEMES or parts.scheme == "-" or not parts.hostname or port is None:
        forms = ", ".join(
            "mavlink:udpin:HOST:PORT" if k == "mavlink" else f"{k}://HOST:PORT"
            for k in SCHEMES
            if k != "-"
        )
        raise InputError(f"Expected SOURCE {forms} or -, got {text!r}")
    return SourceSpec(parts.scheme, parts.hostname, port, text)


def open_source(
    spec: SourceSpec,
    *,
    imu_topic: str | None = None,
    truth_topic: str | None = None,
    gyro_units: str = "rad/s",
    time_units: str = "s",
    give_up_s: float | None = 30.0,
    stdin_fd: int | None = None,
    batch_s: float = BATCH_S,
) -> Source:
    """Create (not start) the source for ``spec``: the :data:`SCHEMES` class of its scheme."""
    options = SourceOptions(
        imu_topic, truth_topic, gyro_units, time_units, give_up_s, stdin_fd, batch_s
    )
    module, _, name = SCHEMES["-" if spec.kind == "stdin" else spec.kind].partition(":")
    cls = getattr(importlib.import_module(module), name)
    return cls.open(spec, options)

"""What a source is opened with: the parsed SOURCE argument and the options a source reads."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["BATCH_S", "SourceOptions", "SourceSpec"]

#: A batch collects what arrives within this long after its first sample, s (default): per-batch
#: costs (one bulk parse or decode, one queue event) are shared by the samples of a few ms.
BATCH_S = 0.005


@dataclass(slots=True, frozen=True)
class SourceSpec:
    """A parsed SOURCE argument: ``kind`` (the scheme of
    :data:`~imu_dcm.live.sources.SCHEMES`; ``stdin`` for ``-``), ``host``, ``port``, ``url``."""

    kind: str
    host: str = ""
    port: int = 0
    url: str = "-"


@dataclass(slots=True, frozen=True)
class SourceOptions:
    """What a source may need besides its URL (each source reads the fields it uses).

    Attributes
    ----------
    imu_topic, truth_topic : str or None — channel choices (``truth_topic="none"``: no truth).
    gyro_units : "rad/s" or "deg/s" — unit of the rates the source delivers.
    time_units : "s", "ms", "us" or "ns" — unit of line stamps.
    give_up_s : float or None — stop after this long without a connection, s.
    stdin_fd : int or None — file descriptor of ``-`` (default 0).
    batch_s : float — a wake-up collects what arrives within this long, s.
    """

    imu_topic: str | None = None
    truth_topic: str | None = None
    gyro_units: str = "rad/s"
    time_units: str = "s"
    give_up_s: float | None = 30.0
    stdin_fd: int | None = None
    batch_s: float = BATCH_S

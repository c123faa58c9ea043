"""Replay recorded gyro logs (ROS bags / MCAP) through the integrator against their truth.

``python -m imu_dcm.replay LOG`` or :func:`replay` (returns a :class:`ReplayResult` whose
``summary`` is a :class:`ReplaySummary`). The names load lazily, so the command line's
``--help`` does not pay for the numerical stack.
"""

from __future__ import annotations

__all__ = ["ReplayResult", "ReplaySummary", "replay", "replay_many"]


def __getattr__(name: str):
    if name == "replay":
        from imu_dcm.replay.core import replay

        return replay
    if name == "replay_many":
        from imu_dcm.replay.batch import replay_many

        return replay_many
    if name in ("ReplayResult", "ReplaySummary"):
        from imu_dcm.replay import summary

        return getattr(summary, name)
    raise AttributeError(f"module 'imu_dcm.replay' has no attribute {name!r}")

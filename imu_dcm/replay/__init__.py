"""Replay recorded gyro logs (ROS 2 bags / MCAP) through the integrator against their truth.

``python -m imu_dcm.replay LOG`` or :func:`replay` (returns a :class:`ReplayResult`).
"""

from imu_dcm.replay.batch import replay_many
from imu_dcm.replay.core import ReplayResult, replay

__all__ = ["ReplayResult", "replay", "replay_many"]

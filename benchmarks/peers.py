"""The peer integrators, for the benchmarks: they live in :mod:`imu_dcm.peers`."""

from imu_dcm.peers import *  # noqa: F403
from imu_dcm.peers import __all__  # noqa: F401

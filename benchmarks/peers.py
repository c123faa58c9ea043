"""The peer integrators, for the benchmarks: they live in :mod:`imu_dcm.integrator.peers`."""

from imu_dcm.integrator.peers import *  # noqa: F403
from imu_dcm.integrator.peers import __all__  # noqa: F401

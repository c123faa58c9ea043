"""Writing ROS 2 bags (MCAP storage): :func:`write_bag` and the CDR messages it lays out."""

# the public face is bag's __all__, listed once, there
from imu_dcm.logio.writers.bag import *  # noqa: F403
from imu_dcm.logio.writers.bag import __all__  # noqa: F401

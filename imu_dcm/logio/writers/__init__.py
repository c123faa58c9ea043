"""Writing ROS 2 bags (MCAP storage): :func:`write_bag` and the CDR messages it lays out."""

from imu_dcm.logio.writers.bag import (
    MSG_DEFINITIONS,
    OWN_LIBRARY,
    TYPE_HASHES,
    StampedSeries,
    cdr_messages,
    imu_doubles,
    write_bag,
)

__all__ = [
    "MSG_DEFINITIONS",
    "OWN_LIBRARY",
    "TYPE_HASHES",
    "StampedSeries",
    "cdr_messages",
    "imu_doubles",
    "write_bag",
]

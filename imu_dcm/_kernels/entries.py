"""Every entry point of the compiled kernels, by name: the table the build exports and numba
compiles from.

The kernels are :mod:`~imu_dcm._kernels.integrator` (the attitude update),
:mod:`~imu_dcm._kernels.ulog_scan` (the ULog record chain), :mod:`~imu_dcm._kernels.mcap_scan`
(the MCAP message records of a batch), :mod:`~imu_dcm._kernels.csv_scan` (the live CSV
lines), :mod:`~imu_dcm._kernels.series` (passes over whole attitude and rate series) and
:mod:`~imu_dcm._kernels.ros_fields` (the wanted fields of a batch of ROS messages); each lists
its own entry points. A new kernel is one module with its ``ENTRIES``, one line here, and its
file in :data:`imu_dcm._kernels.loader.KERNEL_SOURCES`.
"""

from __future__ import annotations

from imu_dcm._kernels import csv_scan, integrator, mcap_scan, ros_fields, series, ulog_scan
from imu_dcm._kernels.jit import compile_entry

__all__ = ["ENTRIES", "compiled"]

#: ``name -> (function, signature)`` of every entry point, as built ahead of time.
ENTRIES: dict[str, tuple[object, str]] = {
    **integrator.ENTRIES,
    **ulog_scan.ENTRIES,
    **mcap_scan.ENTRIES,
    **csv_scan.ENTRIES,
    **series.ENTRIES,
    **ros_fields.ENTRIES,
}


def compiled(name: str, why: str = ""):
    """Entry point ``name`` compiled by numba for its signature, or loaded from numba's cache
    (saying so once, with ``why``, when it compiles)."""
    fn, signature = ENTRIES[name]
    return compile_entry(fn, signature, why)

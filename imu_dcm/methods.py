"""The integrator's method names, numpy-free so that a command's ``--help`` can list them.

:mod:`imu_dcm.integrate` and the kernel index their codes by position in these tuples.
"""

from __future__ import annotations

__all__ = ["DELTA_METHODS", "METHODS"]

#: Rate-input methods, in order of increasing accuracy (``rotvec_sum`` last: a counter-example).
METHODS = ("start", "end", "trapezoid", "coning", "magnus4", "rotvec_sum")
#: Delta-angle methods of :func:`imu_dcm.integrate.integrate_delta`.
DELTA_METHODS = ("plain", "one_plus_previous", "two_sample", "three_sample")

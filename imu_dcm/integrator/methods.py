"""The integrator's method codes and the gap rule's factor: one definition below the kernel and
:mod:`imu_dcm.integrator.batch`, which both import it (no numpy, no numba).

A method's name is its member's name in lower case (``Method.MAGNUS4`` is ``"magnus4"``) and its
code is the member's value, which the compiled kernel branches on. Adding a method is one member
here and one branch in :func:`imu_dcm._kernels.integrator.increment`.
"""

from __future__ import annotations

import enum

__all__ = ["DELTA_METHODS", "GAP_FACTOR", "METHODS", "DeltaMethod", "Method"]


class Method(enum.IntEnum):
    """Rate-input increment rules, in order of increasing accuracy (``rotvec_sum`` last: a
    counter-example). See :mod:`imu_dcm.integrator.batch` for the formulas."""

    START = 0
    END = 1
    TRAPEZOID = 2
    CONING = 3
    MAGNUS4 = 4
    ROTVEC_SUM = 5

    @property
    def label(self) -> str:
        """The name users type (``"magnus4"``)."""
        return self.name.lower()


class DeltaMethod(enum.IntEnum):
    """Delta-angle rules of :func:`imu_dcm.integrate_delta`."""

    PLAIN = 0
    ONE_PLUS_PREVIOUS = 1
    TWO_SAMPLE = 2
    THREE_SAMPLE = 3

    @property
    def label(self) -> str:
        """The name users type (``"one_plus_previous"``)."""
        return self.name.lower()


#: Rate-input method names, in code order.
METHODS = tuple(m.label for m in Method)
#: Delta-angle method names, in code order.
DELTA_METHODS = tuple(m.label for m in DeltaMethod)
#: A step longer than this many median steps is a gap (:func:`imu_dcm.integrator.batch.find_gaps`,
#: GapWarning; the streaming kernel flags candidates with it).
GAP_FACTOR = 5.0

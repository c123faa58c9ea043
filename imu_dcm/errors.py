"""The project's exception and warning hierarchy.

Every error raised at a public boundary derives from :class:`ImuDcmError` and from a builtin
(usually ``ValueError``), so callers may catch either. Messages read "Expected X, got Y" and name
the array, index and value at fault.
"""

from __future__ import annotations


class ImuDcmError(Exception):
    """Base class of every error this project raises on purpose."""


class InputError(ImuDcmError, ValueError):
    """An argument has the wrong shape, dtype, unit or value (also a ``ValueError``)."""


class LogError(ImuDcmError, ValueError):
    """A log file is missing, foreign, truncated, empty or lacks a needed channel."""


class ImuDcmWarning(UserWarning):
    """Base class of the project's warnings (recoverable oddities in the input)."""


class GapWarning(ImuDcmWarning):
    """A time step longer than 5x the median step was found in the input."""

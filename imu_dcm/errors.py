"""The project's exception and warning hierarchy.

Every error raised at a public boundary derives from :class:`ImuDcmError` and from a builtin
(usually ``ValueError``), so callers may catch either. Messages read "Expected X, got Y" and name
the array, index and value at fault. Recoverable oddities are warnings
(:class:`ImuDcmWarning`), gathered on the way as :class:`Diagnostics` where a result carries them.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field


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


@dataclass(slots=True)
class Diagnostics:
    """The one-line diagnostics said on the way to a result, in the order said, each with its
    warning category (None: kept with the result, never warned).

    A function that takes ``diagnostics`` adds to it instead of warning, so a diagnostic
    travels with its result and never through the process-wide warnings state (replays in
    threads keep theirs apart); the public function the user called warns them once, at its
    edge (:meth:`warn`). Without ``diagnostics`` such a function warns as it goes.
    """

    said: list[tuple[str, type[Warning] | None]] = field(default_factory=list)

    def add(self, message: str, category: type[Warning] | None = ImuDcmWarning) -> None:
        """Keep ``message`` (one line), warned as ``category`` at the edge (None: never)."""
        self.said.append((message, category))

    def lines(self, start: int = 0) -> tuple[str, ...]:
        """The messages from the ``start``-th on, in the order said."""
        return tuple(m for m, _ in self.said[start:])

    def warned(self) -> tuple[str, ...]:
        """The messages to warn (those with a category), in the order said."""
        return tuple(m for m, c in self.said if c is not None)

    def warn(self, stacklevel: int = 2) -> None:
        """Warn every message, in order (``stacklevel`` counted from the caller of this)."""
        for message, category in self.said:
            if category is not None:
                warnings.warn(message, category, stacklevel=stacklevel + 1)


def say(
    diagnostics: Diagnostics | None,
    message: str,
    category: type[Warning] = ImuDcmWarning,
    stacklevel: int = 2,
) -> None:
    """Add ``message`` to ``diagnostics``, or without them warn it now (``stacklevel`` counted
    from the caller of this, as for :func:`warnings.warn`)."""
    if diagnostics is None:
        warnings.warn(message, category, stacklevel=stacklevel + 1)
    else:
        diagnostics.add(message, category)

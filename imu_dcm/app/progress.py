"""A terminal progress line (standard library only, so ``--help`` stays fast)."""

from __future__ import annotations

import sys
import time

__all__ = ["Progress"]


class Progress:
    """A plain-text progress line on stderr, drawn only when stderr is a terminal and only once
    the work has run for ``delay_s`` (short runs print nothing).

    Call it as ``progress(stage, fraction)`` (the signature the replay takes as ``progress``);
    :meth:`close` clears the line.
    """

    def __init__(self, stream=None, min_interval_s: float = 0.1, delay_s: float = 0.5):
        self.stream = stream or sys.stderr
        self.enabled = bool(getattr(self.stream, "isatty", lambda: False)())
        self.min_interval_s = min_interval_s
        self._start = time.monotonic()
        self.delay_s = delay_s
        self._last = 0.0
        self._drawn = False

    def __call__(self, stage: str, fraction: float) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if now - self._start < self.delay_s:
            return
        if fraction < 1.0 and now - self._last < self.min_interval_s:
            return
        self._last = now
        width = 30
        filled = round(width * min(max(fraction, 0.0), 1.0))
        self.stream.write(
            f"\r{stage:<10} [{'#' * filled}{'.' * (width - filled)}] {100 * fraction:5.1f}%"
        )
        self.stream.flush()
        self._drawn = True

    def close(self) -> None:
        if self._drawn:
            self.stream.write("\r" + " " * 60 + "\r")
            self.stream.flush()

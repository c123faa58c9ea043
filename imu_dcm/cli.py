"""Command-line plumbing shared by the project's commands: a one-line argument parser, the
parsing of ``"a,b,c"`` option values and a terminal progress line (standard library only, so
``--help`` stays fast)."""

from __future__ import annotations

import argparse
import sys
import time
from typing import NoReturn


class OneLineArgumentParser(argparse.ArgumentParser):
    """argparse that reports a bad option in one line (no usage dump) and exits with status 2.

    Sub-command parsers made by ``add_subparsers`` inherit the class.
    """

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message}\n")


class Progress:
    """A plain-text progress line on stderr, drawn only when stderr is a terminal and only once
    the replay has run for ``delay_s`` (short replays print nothing)."""

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


def parse_numbers(text: str, n: int, name: str) -> list[float]:
    """``"a,b,c"`` -> n finite floats; raises InputError "Expected {name} as n ... numbers"."""
    from imu_dcm.errors import InputError

    try:
        values = [float(x) for x in text.split(",")]
    except ValueError:
        raise InputError(f"Expected {name} as {n} comma-separated numbers, got {text!r}") from None
    if len(values) != n or not all(abs(v) < float("inf") for v in values):
        raise InputError(f"Expected {name} as {n} finite numbers, got {text!r}")
    return values

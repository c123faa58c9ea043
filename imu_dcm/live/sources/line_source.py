"""The base of the line sources (UDP, stdin): sample lines read in batches, parsed in bulk.

The line format is :mod:`imu_dcm.live.lines`: plain CSV lines in one pass over a wake-up's blob
(:func:`~imu_dcm.live.lines.parse_csv_blob`), else line by line
(:func:`~imu_dcm.live.lines.parse_lines`: a header, JSON lines, truth quaternions).
"""

from __future__ import annotations

import numpy as np

from imu_dcm.live.events import Event, Malformed, Received
from imu_dcm.live.lines import parse_csv_blob, parse_lines
from imu_dcm.live.sources.base import Source
from imu_dcm.live.sources.spec import BATCH_S

__all__ = ["LineSource"]


class LineSource(Source):
    """The base of the line sources: batches of sample lines decoded in one pass."""

    converts_gyro_units = True
    #: The session's loop may watch it for its first bytes (:meth:`ready`).
    watchable = True

    def ready(self, timeout_s: float) -> bool:
        """Whether there is something to read within ``timeout_s``."""
        return self._ready(timeout_s)

    def __init__(self, gyro_units: str, time_units: str, batch_s: float = BATCH_S) -> None:
        super().__init__()
        self.gyro_units = gyro_units
        self.time_units = time_units
        self.batch_s = batch_s
        self._first = True

    pollable = True

    def _run(self) -> None:
        self.begin()
        try:
            while not self._stop.is_set():
                got = self._await(self._ready, self.batch_s)
                if got is not None and not self._read(*got):
                    return
        finally:
            self._close()

    def decode(self, key, items: list) -> list[Event]:
        """Items ``(blob, arrival_ns, wall_ns)``, ``blob`` whole lines: plain CSV lines in one
        pass over each blob (:func:`parse_csv_blob`), else line by line (:func:`parse_lines`)."""
        out: list[Event] = []
        for blob, arrival_ns, wall_ns in items:
            bulk = None
            if not self._first:
                bulk = parse_csv_blob(blob, gyro_units=self.gyro_units, time_units=self.time_units)
            if bulk is None:
                lines = [ln for ln in blob.split(b"\n") if ln.strip()]
                out.extend(self._each(lines, arrival_ns, wall_ns))
                continue
            t, w, bad = bulk
            if bad:
                out.append(Malformed(bad))
            if len(t):
                n = len(t)
                arrival, wall = np.full(n, arrival_ns, np.int64), np.full(n, wall_ns, np.int64)
                out.append(Received("imu", t, w, arrival, wall))
        return out

    def _each(self, lines: list[bytes], arrival_ns: int, wall_ns: int) -> list[Event]:
        t, w, tt, q, bad = parse_lines(
            lines, gyro_units=self.gyro_units, time_units=self.time_units, first=self._first
        )
        self._first = self._first and not lines
        out: list[Event] = [Malformed(bad)] if bad else []
        for kind, stamps, values in (("truth", tt, q), ("imu", t, w)):
            if len(stamps):
                n = len(stamps)
                arrival = np.full(n, arrival_ns, np.int64)
                wall = np.full(n, wall_ns, np.int64)
                out.append(Received(kind, stamps, values, arrival, wall))
        return out

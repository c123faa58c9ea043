"""``-``: sample lines from a file descriptor (stdin by default) until end of input."""

from __future__ import annotations

import os

from imu_dcm.live.events import Channel, End, Raw
from imu_dcm.live.sources.line_source import LineSource
from imu_dcm.live.sources.sockets import pipe_size, readable
from imu_dcm.live.sources.spec import BATCH_S, SourceOptions, SourceSpec

__all__ = ["MAX_LINE_BYTES", "StdinSource"]

#: A stdin line longer than this (bytes, no line end) is dropped as malformed, not kept whole.
MAX_LINE_BYTES = 1 << 16


class StdinSource(LineSource):
    """Sample lines from a file descriptor (stdin by default) until end of input."""

    @classmethod
    def open(cls, spec: SourceSpec, options: SourceOptions) -> StdinSource:
        return cls(options.gyro_units, options.time_units, options.stdin_fd, options.batch_s)

    def __init__(
        self, gyro_units: str, time_units: str, fd: int | None = None, batch_s: float = BATCH_S
    ) -> None:
        super().__init__(gyro_units, time_units, batch_s)
        self.fd = 0 if fd is None else fd
        self._rest = b""  # a line not yet ended
        self._skipping = False  # the rest of a line too long to keep
        self._room = pipe_size(self.fd)  # bytes a pipe holds (None: not a pipe)

    def begin(self) -> None:
        self.events.put(Channel("imu", "stdin", "", "", "", "lines"))

    def _ready(self, timeout_s: float) -> bool:
        return readable(self.fd, timeout_s)

    def _read(self, arrival_ns: int, wall_ns: int) -> bool:
        data = os.read(self.fd, 1 << 20)
        # a pipe half full or more: its writer would soon block (a datagram socket, which
        # loses rather than blocks, asks for a reader sooner, at a quarter)
        self.fill = None if self._room is None else min(1.0, len(data) / self._room)
        self.flowing |= bool(data)
        self.crowded = self._room is not None and len(data) >= self._room // 2
        if not data:
            if self._rest:
                self.events.put(Raw("lines", [(self._rest, arrival_ns, wall_ns)]))
                self._rest = b""
            self.events.put(End("end of input"))
            return False
        buf = self._rest + data
        if self._skipping:  # the rest of a line dropped as too long, up to its end
            _, end, buf = buf.partition(b"\n")
            self._skipping = not end
        whole, newline, self._rest = buf.rpartition(b"\n")
        if newline:  # parsed by the session's loop (decode), with the other items
            self.events.put(Raw("lines", [(whole, arrival_ns, wall_ns)]))
        if len(self._rest) > MAX_LINE_BYTES:  # no line end in sight: memory stays bounded
            self._rest, self._skipping = b"", True
            self.drop("long-line", f"a line longer than {MAX_LINE_BYTES} bytes")
        return True

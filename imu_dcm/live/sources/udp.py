"""``udp://HOST:PORT``: datagrams of one or more sample lines, on an address bound on open.

Each read takes every datagram the socket holds; the system's count of the datagrams it dropped
(its buffer full) is told with each datagram (``SO_RXQ_OVFL``) and read again at the end
(``/proc/net/udp``), each rise said once (:mod:`imu_dcm.live.sources.sockets`).
"""

from __future__ import annotations

import os
import socket
import sys
import time

from imu_dcm.errors import InputError
from imu_dcm.live.events import Channel, Info, Raw
from imu_dcm.live.sources.line_source import LineSource
from imu_dcm.live.sources.sockets import (
    OVFL_SPACE,
    SO_RXQ_OVFL,
    enable_drop_count,
    proc_udp_drops,
    proc_udp_queue,
    proc_udp_row,
    readable,
)
from imu_dcm.live.sources.spec import BATCH_S, SourceOptions, SourceSpec

__all__ = ["DRAIN_MAX", "UDP_RCVBUF", "UdpSource"]

#: Datagrams one read takes at most (besides what the receive buffer can hold).
DRAIN_MAX = 4000
#: The receive buffer a UDP source asks for, bytes (the system caps it at ``net.core.rmem_max``).
UDP_RCVBUF = 4 << 20


class UdpSource(LineSource):
    """Datagrams of sample lines on ``host:port`` (bound on open)."""

    @classmethod
    def open(cls, spec: SourceSpec, options: SourceOptions) -> UdpSource:
        return cls(spec.host, spec.port, options.gyro_units, options.time_units, options.batch_s)

    def __init__(
        self, host: str, port: int, gyro_units: str, time_units: str, batch_s: float = BATCH_S
    ) -> None:
        super().__init__(gyro_units, time_units, batch_s)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, UDP_RCVBUF)
        try:
            self.sock.bind((host, port))
        except OSError as exc:
            self.sock.close()
            raise InputError(f"Expected to bind udp://{host}:{port}, got {exc}") from None
        self.address = self.sock.getsockname()
        self._room = 4  # datagrams the receive buffer holds at least (set by begin)
        self._got = 0  # datagrams the last read took
        self._rcvbuf, self._inode = 1 << 20, 0  # set by begin
        self._measure = False  # read inline: measure the buffer's use at each read
        self._ovfl = enable_drop_count(self.sock)

    def _close(self) -> None:
        """At the end: read what the socket still holds, take the system's final count of the
        datagrams it dropped (those after the last one read tell nobody else), then close."""
        try:
            self.sock.setblocking(False)
            at = self._read_at or (time.perf_counter_ns(), time.time_ns())
            while self._read(*at) and self._got >= DRAIN_MAX:
                pass
            self._count_final_drops()
        except OSError:
            pass
        finally:
            self.sock.close()

    def _count_final_drops(self) -> None:
        """The socket's drop count from ``/proc/net/udp`` (Linux: the ``drops`` column of the
        row of this socket's inode), said as a rise is said."""
        drops = proc_udp_drops(os.fstat(self.sock.fileno()).st_ino)
        if drops is not None and drops > self.lost:
            self._say_lost(drops)

    def begin(self) -> None:
        where = f"udp://{self.address[0]}:{self.address[1]}"
        self.events.put(Channel("imu", where, "", "", "", "lines"))
        self.events.put(Info(f"listening on {where}"))
        self.sock.setblocking(False)
        # a small datagram takes ~0.8 KB of the buffer (the system's bookkeeping with it)
        self._rcvbuf = self.sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
        self._room = max(4, self._rcvbuf // 1024)
        ino = os.fstat(self.sock.fileno()).st_ino
        self._inode = ino if proc_udp_row(ino) is not None else 0

    def _ready(self, timeout_s: float) -> bool:
        return readable(self.sock, timeout_s)

    def poll(self) -> None:
        """Inline (see :meth:`Source.poll`): each read also measures the buffer's use (the
        loop's cadence follows it; a thread's read, 2.5 ms after the first bytes, needs none)."""
        self._measure = True
        super().poll()

    def _read(self, arrival_ns: int, wall_ns: int) -> bool:
        queued = proc_udp_queue(self._inode) if self._inode and self._measure else None
        chunks: list[bytes] = []
        last = None  # the last datagram's ancillary data: the system's drop count then
        most = max(DRAIN_MAX, 2 * self._room)  # all the buffer can hold, and what came since
        try:
            while len(chunks) < most:
                if self._ovfl:
                    data, anc, _, _ = self.sock.recvmsg(65536, OVFL_SPACE)
                    last = anc or last
                else:
                    data = self.sock.recv(65536)
                chunks.append(data)
        except (BlockingIOError, InterruptedError):
            pass
        if chunks:  # parsed by the session's loop (decode), with the other items
            self.events.put(Raw("lines", [(b"\n".join(chunks), arrival_ns, wall_ns)]))
        self._got = len(chunks)
        self.flowing |= bool(chunks)
        # the buffer's use before the read (the system's own count, /proc/net/udp), or from
        # the datagrams read at a conservative ~1 KB each
        self.fill = queued / self._rcvbuf if queued is not None else len(chunks) / self._room
        self.crowded = self.fill >= 0.25
        if last:
            self._count_drops(last)
        return True

    def _count_drops(self, anc: list) -> None:
        """The system's count of datagrams dropped on this socket (``SO_RXQ_OVFL``): say each
        rise, once."""
        for level, kind, data in anc:
            if level == socket.SOL_SOCKET and kind == SO_RXQ_OVFL and len(data) >= 4:
                lost = int.from_bytes(data[:4], sys.byteorder)
                if lost > self.lost:
                    self.crowded = True
                    self._say_lost(lost)

    def _say_lost(self, lost: int) -> None:
        why = (
            f"udp: the system dropped {lost - self.lost} datagram(s) (its receive "
            f"buffer was full; {lost} in all): samples were lost"
        )
        self.events.put(Info(why))
        self.lost = lost

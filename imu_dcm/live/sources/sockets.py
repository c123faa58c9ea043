"""What the system tells about a socket or a pipe: drop counts, buffer use, pipe size, readiness.

Linux tells the most (``SO_RXQ_OVFL``, ``/proc/net/udp``, ``F_GETPIPE_SZ``); elsewhere each
function says it cannot (False, None, or a default).
"""

from __future__ import annotations

import os
import select
import socket
import stat
import sys

try:
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None

__all__ = [
    "OVFL_SPACE",
    "SO_RXQ_OVFL",
    "enable_drop_count",
    "pipe_size",
    "proc_udp_drops",
    "proc_udp_queue",
    "proc_udp_row",
    "readable",
]

#: ``SO_RXQ_OVFL`` (Linux): each datagram read carries the socket's count of dropped datagrams.
SO_RXQ_OVFL = getattr(socket, "SO_RXQ_OVFL", 40)
OVFL_SPACE = socket.CMSG_SPACE(4) if hasattr(socket, "CMSG_SPACE") else 0


def enable_drop_count(sock: socket.socket) -> bool:
    """Ask the system to tell the socket's drop count with each datagram (Linux); False where
    it cannot."""
    if not OVFL_SPACE or not sys.platform.startswith("linux"):
        return False
    try:
        sock.setsockopt(socket.SOL_SOCKET, SO_RXQ_OVFL, 1)
    except OSError:
        return False
    return True


def proc_udp_row(inode: int) -> list[str] | None:
    """The row of the UDP socket with ``inode`` in ``/proc/net/udp`` (or ``udp6``), as cells, or
    None where there is no such file or row (not Linux)."""
    key = f" {inode} "
    for name in ("/proc/net/udp", "/proc/net/udp6"):
        try:
            with open(name) as f:
                text = f.read()
        except OSError:
            continue
        at = text.find(key)
        while at >= 0:  # the inode's column (the 10th), not a number elsewhere in a row
            row = text[text.rfind("\n", 0, at) + 1 : text.find("\n", at)].split()
            if len(row) >= 13 and row[9] == str(inode):
                return row
            at = text.find(key, at + 1)
    return None


def proc_udp_drops(inode: int) -> int | None:
    """The ``drops`` count of the UDP socket with ``inode`` (``/proc/net/udp``), or None."""
    row = proc_udp_row(inode)
    return None if row is None else int(row[12])


def proc_udp_queue(inode: int) -> int | None:
    """The bytes queued on the UDP socket with ``inode`` (``rx_queue``, the buffer's use as the
    system counts it against ``SO_RCVBUF``), or None."""
    row = proc_udp_row(inode)
    return None if row is None else int(row[4].partition(":")[2], 16)


def pipe_size(fd: int) -> int | None:
    """The bytes the pipe ``fd`` holds (Linux ``F_GETPIPE_SZ``; 64 KiB elsewhere), or None when
    ``fd`` is not a pipe."""
    try:
        if not stat.S_ISFIFO(os.fstat(fd).st_mode):
            return None
    except OSError:
        return None
    if fcntl is None:
        return 65536
    try:
        return int(fcntl.fcntl(fd, getattr(fcntl, "F_GETPIPE_SZ", 1032)))
    except OSError:
        return 65536


def readable(fd, timeout_s: float) -> bool:
    """Whether ``fd`` (a socket or a file descriptor) has something to read within
    ``timeout_s``."""
    return bool(select.select([fd], [], [], timeout_s)[0])

"""UDP ports on 127.0.0.1 for tests that start ``imu_dcm.live`` on a UDP source.

Two races made a child's bind fail with "Address already in use" when tests ran side by
side: a port taken from the kernel's ephemeral range (``bind(("127.0.0.1", 0))``) can be
handed straight to another test's sending socket, and probing "is it bound yet?" by binding
the port ourselves holds it for a moment the child may choose to bind in. So a port here
comes from below the ephemeral range (no socket is ever given one there implicitly), and
the probe reads the kernel's socket table (``/proc/net/udp``) instead of binding, where
Linux offers it.
"""

from __future__ import annotations

import random
import socket
import subprocess
import time
from pathlib import Path

_PROC_UDP = Path("/proc/net/udp")


def _ephemeral_low() -> int:
    try:
        return int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return 32768  # Linux's default low end; other systems start higher


def free_udp_port() -> int:
    """A UDP port on 127.0.0.1 that is free now and outside the ephemeral range."""
    low = max(_ephemeral_low(), 12000)
    for _ in range(200):
        port = random.randrange(10000, low)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
        return port
    raise RuntimeError("no free UDP port below the ephemeral range")


def _bound_by_table(port: int) -> bool | None:
    try:
        rows = _PROC_UDP.read_text().splitlines()[1:]
    except OSError:
        return None
    want = {f"0100007F:{port:04X}", f"00000000:{port:04X}"}
    return any(len(f := r.split()) > 1 and f[1] in want for r in rows)


def _bound_by_bind(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return True
    return False


def udp_bound(port: int) -> bool:
    """Whether some socket holds UDP ``port`` on 127.0.0.1 (without binding it where we can)."""
    by_table = _bound_by_table(port)
    return _bound_by_bind(port) if by_table is None else by_table


def wait_bound(port: int, proc: subprocess.Popen, timeout_s: float = 20.0) -> bool:
    """Wait until ``proc`` is running and UDP ``port`` is bound; False if it exits or times out."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end and proc.poll() is None:
        if udp_bound(port):
            return True
        time.sleep(0.02)
    return False

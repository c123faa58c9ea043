"""What a log path may be: a regular file or a folder, never a FIFO, device or socket."""

from __future__ import annotations

import stat
from pathlib import Path

from imu_dcm.errors import LogError

__all__ = [
    "DATAFLASH_MAGIC",
    "HEAD_BYTES",
    "MCAP_MAGIC",
    "ULOG_MAGIC",
    "check_regular",
    "is_dataflash",
    "is_euroc",
    "is_ulog",
    "mav_folder",
    "read_head",
]


#: Bytes of a file's start handed to the container table's probes.
HEAD_BYTES = 64

#: First bytes of an MCAP file (read by :mod:`imu_dcm.logio.containers.mcap`, written by
#: :mod:`imu_dcm.logio.writers`).
MCAP_MAGIC = b"\x89MCAP0\r\n"
#: First bytes of a PX4 ULog and of a binary ArduPilot DataFlash log (its first FMT record).
ULOG_MAGIC = b"ULog\x01\x12\x35"
DATAFLASH_MAGIC = b"\xa3\x95\x80\x80"


def check_regular(p: Path) -> bool:
    """True for a folder, False for a regular file; LogError for anything else or missing."""
    try:
        st = p.stat()
    except FileNotFoundError:
        raise LogError(
            f"Expected an existing log path, got {str(p)!r} (no such file or folder)"
        ) from None
    except OSError as exc:
        raise LogError(f"Expected a readable log path, got {p} ({exc.strerror})") from None
    if stat.S_ISDIR(st.st_mode):
        return True
    if not stat.S_ISREG(st.st_mode):
        # lazy: outputs is kept off the replay's import path (tests/test_replay_imports.py)
        from imu_dcm.outputs import file_kind

        raise LogError(
            f"Expected a regular file or a folder, got a {file_kind(st.st_mode)} (a special "
            f"file): {p}"
        )
    return False


def read_head(p: Path) -> bytes:
    """The first :data:`HEAD_BYTES` bytes of the regular file ``p``."""
    try:
        with open(p, "rb") as f:
            return f.read(HEAD_BYTES)
    except OSError as exc:
        raise LogError(f"Expected a readable log file, got {p} ({exc.strerror})") from None


# Probes of the readers imported only when they open a log (:mod:`imu_dcm.logio.registry`).
def is_ulog(path: Path, head: bytes) -> bool:
    """True for a ULog file (its 7-byte magic)."""
    return head.startswith(ULOG_MAGIC)


def is_dataflash(path: Path, head: bytes) -> bool:
    """True for a binary DataFlash log (its first FMT record)."""
    return head.startswith(DATAFLASH_MAGIC)


def mav_folder(path: Path) -> Path | None:
    """The ``mav0`` folder of a EuRoC dataset given as itself or its parent (None if neither):
    a ``mav0`` folder, or a folder holding ``imu0`` (whose ``data.csv`` the reader checks, so
    that a missing one is named as such)."""
    if (path / "mav0").is_dir():
        return path / "mav0"
    if (path / "imu0").is_dir() or (path / "imu0" / "data.csv").is_file():
        return path
    return None


def is_euroc(path: Path, head: bytes) -> bool:
    """A EuRoC/ASL dataset folder or its ``mav0`` (``mav0`` or ``imu0`` inside)."""
    return not head and path.is_dir() and mav_folder(path) is not None

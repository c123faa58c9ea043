"""What a log path may be: a regular file or a folder, never a FIFO, device or socket."""

from __future__ import annotations

import stat
from pathlib import Path

from imu_dcm.errors import LogError

#: Bytes of a file's start handed to the container table's probes.
HEAD_BYTES = 64


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
        from imu_dcm.outputs import file_kind  # (tempfile, shutil: not for every read)

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

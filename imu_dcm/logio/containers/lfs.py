"""Git LFS pointers: the small text file a repository holds in place of a large log until
``git lfs pull`` fetches it. A row of the container table refuses them with that command."""

from __future__ import annotations

import re
from pathlib import Path

from imu_dcm.errors import LogError

__all__ = ["LFS_PREFIX", "is_lfs_pointer", "refuse_lfs_pointer"]

#: How every Git LFS pointer file begins (its spec's first line).
LFS_PREFIX = b"version https://git-lfs"


def is_lfs_pointer(_path: Path, head: bytes) -> bool:
    """True when the file's first bytes are a Git LFS pointer's."""
    return head.startswith(LFS_PREFIX)


def refuse_lfs_pointer(path: Path, _progress=None):
    """Raise the one-line refusal, with the size of the real log from the pointer."""
    try:
        with open(path, "rb") as f:
            text = f.read(1024)
    except OSError:
        text = b""
    size = re.search(rb"^size (\d+)", text, re.MULTILINE)
    of = f" to a {int(size.group(1)) / 1e6:.1f} MB file" if size else ""
    raise LogError(
        f"Expected a ROS bag or an MCAP file, got a Git LFS pointer{of} in its place: {path}; "
        f"`git lfs pull` fetches the log"
    )

"""Git LFS pointers: the small text file a repository holds in place of a large log until
``git lfs pull`` fetches it. Named in the reader's refusal, with that command."""

from __future__ import annotations

import re
from pathlib import Path

__all__ = ["lfs_pointer"]

#: How every Git LFS pointer file begins (its spec's first line).
LFS_PREFIX = b"version https://git-lfs"


def lfs_pointer(path: Path, head: bytes) -> str | None:
    """The refusal's line for a Git LFS pointer at ``path`` (``head``: its first bytes), or None.

    The pointer's ``size`` line says how large the real log is.
    """
    if not LFS_PREFIX.startswith(head[: len(LFS_PREFIX)]) or len(head) < 8:
        return None
    try:
        with open(path, "rb") as f:
            text = f.read(1024)
    except OSError:
        return None
    if not text.startswith(LFS_PREFIX):
        return None
    size = re.search(rb"^size (\d+)", text, re.MULTILINE)
    of = f" to a {int(size.group(1)) / 1e6:.1f} MB file" if size else ""
    return (
        f"Expected a ROS bag or an MCAP file, got a Git LFS pointer{of} in its place: {path}; "
        f"`git lfs pull` fetches the log"
    )

"""The commands' memory: their arrays in ordinary pages, and the memory they free kept for the
next (standard library only, so that a command's start stays free of numpy until its work
needs it).

numpy asks the kernel for transparent huge pages on every array of 4 MB or more, and with
Linux's default ``defrag`` setting (``madvise``) a first touch of such a page waits while the
kernel compacts memory into a free 2 MB page: on a machine whose memory has been in use for a
while, more than the work on the array. A replay's whole-log arrays are each used in order, a
pass at a time, and gain nothing from huge pages, so the commands that make them (``replay``,
``batch``, ``data_synth``) ask numpy not to request them for the process: the replay of a
1 h log at 1 kHz took 5.9-6.2 s against 6.5-6.9 s, four rounds each, interleaved, on the
2-core machine (docs/benchmarks.md "Long logs"). A library call (``replay()`` from a script)
leaves numpy's setting alone: there the reader still writes a log's columns into ordinary pages
(:func:`imu_dcm.memory.small_pages`).

The same commands keep the memory they free for their next arrays
(:func:`imu_dcm.memory.keep_freed_memory`, glibc's allocator: see there).
"""

from __future__ import annotations

import os
import sys

from imu_dcm.memory import keep_freed_memory

__all__ = ["command_memory", "numpy_small_pages"]


def command_memory() -> None:
    """A command's memory settings, before its work: :func:`numpy_small_pages` and
    :func:`imu_dcm.memory.keep_freed_memory`."""
    numpy_small_pages()
    keep_freed_memory()


def numpy_small_pages() -> None:
    """For a command's process: numpy's arrays in ordinary pages (the module docstring), unless
    ``NUMPY_MADVISE_HUGEPAGE`` says otherwise. Before numpy is imported, by that variable (which
    numpy reads when imported, and the command's worker processes inherit); after, by numpy's
    own switch. Where numpy has no such switch, nothing."""
    if "NUMPY_MADVISE_HUGEPAGE" in os.environ:
        return
    np = sys.modules.get("numpy")
    if np is None:
        os.environ["NUMPY_MADVISE_HUGEPAGE"] = "0"
        return
    core = getattr(np, "_core", None) or np.core  # numpy 2, numpy 1
    setter = getattr(core.multiarray, "_set_madvise_hugepage", None)
    if setter is not None:
        setter(False)

"""The commands' arrays in ordinary pages (standard library only, so that a command's start
stays free of numpy until its work needs it).

numpy asks the kernel for transparent huge pages on every array of 4 MB or more, and with
Linux's default ``defrag`` setting (``madvise``) a first touch of such a page waits while the
kernel compacts memory into a free 2 MB page: on a machine whose memory has been in use for a
while, more than the work on the array. A replay's whole-log arrays are each used in order, a
pass at a time, and gain nothing from huge pages, so the commands that make them (``replay``,
``batch``, ``data_synth``) ask numpy not to request them for the process: the replay of a
1 h log at 1 kHz took 5.9-6.2 s against 6.5-6.9 s, four rounds each, interleaved, on the
2-core machine (docs/benchmarks.md "Long logs"). A library call (``replay()`` from a script)
leaves numpy's setting alone: there the reader still writes a log's columns into ordinary pages
(:func:`imu_dcm.logio.heap.small_pages`).

The same commands keep the memory they free for their next arrays (:func:`reuse_freed_memory`).
glibc's ``malloc`` gives every block above 32 MB (a whole-log column of 4 M samples) its own
fresh mapping and returns it to the kernel when freed, so each such array pays for its first
touch again (the kernel zeroes every page: ~1 µs a 4 KiB page here). A replay makes and frees
dozens of them, one pass after the other; from the heap, freed and kept, the next one reuses
pages already touched: the replay of a 1 h log at 1 kHz took 4.7-4.8 s against 5.8-6.3 s,
three rounds each, interleaved, for 781 MB at its peak against 731 MB (docs/benchmarks.md "Long
logs"). ``MALLOC_MMAP_MAX_`` or ``MALLOC_TRIM_THRESHOLD_`` in the environment (glibc's own
settings) leave it alone.
"""

from __future__ import annotations

import ctypes
import os
import sys

__all__ = ["command_memory", "numpy_small_pages", "reuse_freed_memory"]

#: glibc's ``mallopt`` parameters: the most blocks given their own mapping (0: none), and how
#: much free memory at the heap's top is kept before it is returned to the kernel (bytes).
M_MMAP_MAX, M_TRIM_THRESHOLD = -4, -1
#: The free memory a command keeps (the most ``mallopt`` takes: a C int).
KEEP_FREED_BYTES = 2**31 - 1


def command_memory() -> None:
    """A command's memory settings, before its work: :func:`numpy_small_pages` and
    :func:`reuse_freed_memory`."""
    numpy_small_pages()
    reuse_freed_memory()


def reuse_freed_memory() -> bool:
    """For a command's process on glibc: every block from the heap and freed memory kept there
    for the next (the module docstring). The process's own setting, not its environment's: a
    program it starts (the viewer) keeps its own; a batch's worker processes ask for it
    themselves. Returns whether it applied (False: not glibc, or the environment says
    otherwise)."""
    if "MALLOC_MMAP_MAX_" in os.environ or "MALLOC_TRIM_THRESHOLD_" in os.environ:
        return False
    if not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):  # no C library of glibc's kind
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return bool(mallopt(M_MMAP_MAX, 0) and mallopt(M_TRIM_THRESHOLD, KEEP_FREED_BYTES))


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

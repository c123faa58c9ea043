"""How the allocator serves long logs (standard library only): a read reuses freed heap blocks
and gives them back after, a command keeps every freed block for its next arrays (glibc), and a
log's columns go into small pages (Linux; elsewhere nothing is done).

Reading a long log decodes it batch by batch: every batch makes and frees temporaries of a few
hundred KB to a few MB (the records' offsets, lengths, log times, decoded fields). glibc hands
blocks that size out as fresh pages from the system (mmap) until its threshold has grown past
them, and gives freed heap back above a trim threshold, so each batch paid a first touch of
every page of its temporaries again (~1 µs a 4 KiB page on this machine: more than the work on
them). :func:`reuse_freed_heap` sets both thresholds once per process, before the first read:
blocks under 4 MiB come from the heap and up to 16 MiB of freed heap is kept for reuse
(``read_log`` of a 1 h log at 1 kHz 5.2 -> 3.3 s, the whole replay ~10 % faster, its peak
+11 MB; measured side by side under the same load). A setting of glibc's allocator in the
environment (``MALLOC_MMAP_THRESHOLD_``, ``MALLOC_TRIM_THRESHOLD_``, ``MALLOC_MMAP_MAX_``,
``MALLOC_ARENA_MAX``, ``GLIBC_TUNABLES``) is left as set.

After the read, glibc keeps the freed mid-sized blocks, and the large arrays that follow never
reuse them: after reading a 1 h log the process held ~410 MB beyond its 317 MB of arrays,
until ``malloc_trim(0)`` returned them (:func:`release_freed_memory`; measured: 757 -> 347 MB
resident, in 33 ms).

A channel's columns (hundreds of MB an hour) are written once, in order, batch by batch. numpy
asks the kernel for transparent huge pages on every array of 4 MB or more
(``madvise(MADV_HUGEPAGE)``), and with Linux's default ``defrag`` setting (``madvise``) a first
touch of such a page then waits while the kernel compacts memory into a free 2 MB page, which
on a machine whose memory has been used for a while can cost more than the whole read's work.
Written in order, the columns gain nothing from huge pages, so :func:`small_pages` asks for
ordinary pages on them (``MADV_NOHUGEPAGE``) before they are touched: ``read_log`` of a 1 h log
at 1 kHz took 2.0-2.7 s against 3.2-3.9 s, five fresh processes each, interleaved, on the
2-core machine after an hour of benchmarks (docs/benchmarks.md "Reading logs").

The commands go further, for all their arrays (:func:`keep_freed_memory`, called by
:func:`imu_dcm.app.pages.command_memory`): every block from the heap, freed memory kept there
for the next. glibc gives every block above 32 MB (the most its threshold takes: a whole-log
column of 4 M samples) its own fresh mapping and returns it to the kernel when freed, so each
such array pays for its first touch again (the kernel zeroes every page); a replay makes and
frees dozens of them, one pass after the other. From the heap, freed and kept, the next array
reuses pages already touched: the replay of a 10 h log at 1 kHz took 48 s against 67 s with
glibc's defaults (one round each, interleaved, on the 2-core machine), for a peak of 7.5 GB
against 7.1 GB; of a 1 h log 4.9-5.2 s against 5.5-6.1 s (three rounds each), for a peak of
790-819 MB against 766-776 MB (bytes, as docs/benchmarks.md "Long logs" counts them). That is
the price: the 1 h peak at the 0.8 GB it is held to, and above it in one run of three. The
read then keeps its freed batches too (no trim after it): the judgement's arrays take their
pages. One arena serves every thread (the decompression's workers, a pass beside another), so
what a worker frees is there for the main thread's next array: for the 1 h log 790-819 MB
against 823 MB with an arena a thread, as fast (three rounds each); for the 10 h log 7.6-7.7
GB against 7.5 GB, 52-62 s against 54 s. glibc's own variables in the environment
(``MALLOC_MMAP_MAX_``, ``MALLOC_ARENA_MAX``, ...) turn it off: the allocator is then theirs.
"""

from __future__ import annotations

import ctypes
import os
import sys

__all__ = [
    "heap_settings",
    "keep_freed_memory",
    "release_freed_memory",
    "reuse_freed_heap",
    "small_pages",
]

#: Blocks under this many bytes come from the heap while reading (glibc's ``M_MMAP_THRESHOLD``).
MMAP_THRESHOLD = 4 << 20
#: Freed heap up to this many bytes is kept for reuse (glibc's ``M_TRIM_THRESHOLD``).
TRIM_THRESHOLD = 16 << 20
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD, _M_MMAP_MAX, _M_ARENA_MAX = -1, -3, -4, -8  # malloc.h
#: Free heap a command keeps before returning any to the kernel (the most mallopt takes).
KEEP_FREED_BYTES = 2**31 - 1
_OWN = ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_", "MALLOC_MMAP_MAX_", "MALLOC_ARENA_MAX")

_MADV_NOHUGEPAGE = 15  # madvise's advice number (linux/mman.h)
_PAGE = 4096

_TRIM = _MALLOPT = _MADVISE = None
if sys.platform.startswith("linux"):
    try:
        _libc = ctypes.CDLL(None)  # the running process's C library
        _MADVISE = _libc.madvise
        _MADVISE.argtypes, _MADVISE.restype = (
            [ctypes.c_void_p, ctypes.c_size_t, ctypes.c_int],
            ctypes.c_int,
        )
        _TRIM, _MALLOPT = _libc.malloc_trim, _libc.mallopt  # glibc's
        _TRIM.argtypes, _TRIM.restype = [ctypes.c_size_t], ctypes.c_int
        _MALLOPT.argtypes, _MALLOPT.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    except (OSError, AttributeError):  # musl and others have no malloc_trim
        _TRIM = _MALLOPT = None
_set: list[bool] = []  # reuse_freed_heap's settings made
_kept: list[bool] = []  # keep_freed_memory's made


def heap_settings(environ) -> list[tuple[int, int]]:
    """The ``mallopt`` calls :func:`reuse_freed_heap` makes, ``(parameter, value)``: none when
    ``environ`` sets either threshold itself (glibc reads those at start-up)."""
    if _environment_sets(environ):
        return []
    return [(_M_MMAP_THRESHOLD, MMAP_THRESHOLD), (_M_TRIM_THRESHOLD, TRIM_THRESHOLD)]


def _environment_sets(environ) -> bool:
    """Whether ``environ`` sets glibc's allocator itself (glibc reads it at start-up)."""
    return any(k in environ for k in _OWN) or "malloc" in environ.get("GLIBC_TUNABLES", "")


def keep_freed_memory() -> bool:
    """For a command's process: every block from the heap, and freed memory kept there for the
    next (the module docstring); a read after it keeps its settings and its freed batches.
    Returns whether it applied (False: not glibc, or the environment sets the allocator)."""
    if _MALLOPT is None or _environment_sets(os.environ):
        return False
    settings = ((_M_MMAP_MAX, 0), (_M_TRIM_THRESHOLD, KEEP_FREED_BYTES), (_M_ARENA_MAX, 1))
    made = [_MALLOPT(what, value) for what, value in settings]  # every one, then the check
    if not all(made):
        return False
    _set.append(True)
    _kept.append(True)
    return True


def reuse_freed_heap() -> None:
    """Keep a read's temporaries in the heap and reuse them (the module docstring): set glibc's
    mmap and trim thresholds (:func:`heap_settings`), once per process."""
    if _set or _MALLOPT is None:
        return
    _set.append(True)
    for what, value in heap_settings(os.environ):
        _MALLOPT(what, value)


def release_freed_memory() -> None:
    """Return the allocator's free heap memory to the system, where the C library can, unless
    the process keeps it (:func:`keep_freed_memory`)."""
    if _TRIM is not None and not _kept:
        _TRIM(0)


def small_pages(a) -> None:
    """Ask for ordinary pages on the whole pages inside ``a``'s buffer (the module docstring),
    before it is first written. Advice only: its values are untouched, and where the system
    has no such advice (not Linux, a kernel without huge pages) nothing changes."""
    if _MADVISE is None or a.nbytes < 4 << 20:  # numpy asks for huge pages from 4 MB
        return
    start = a.__array_interface__["data"][0]
    lo, hi = -(-start // _PAGE) * _PAGE, (start + a.nbytes) // _PAGE * _PAGE
    if hi > lo:
        _MADVISE(lo, hi - lo, _MADV_NOHUGEPAGE)

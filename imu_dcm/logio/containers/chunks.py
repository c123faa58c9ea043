"""Chunks decompressed in batches: several chunks into one buffer, on worker threads.

A long log is thousands of 768 KiB - 1 MiB chunks; the numpy work that locates and decodes
their messages costs about the same per call whatever the size, so it runs once per batch of
chunks (:data:`BATCH_BYTES` decompressed), not once per chunk. The chunks of a batch are
decompressed side by side into one buffer, each into its own slice, by a small thread pool
(zstd, lz4 and CRC-32 release the GIL), while the caller decodes the batch before.

The pool is :class:`imu_dcm.logio.workers.Workers` (daemon threads, one set per read).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass

import numpy as np

from imu_dcm.logio.checksum import crc32
from imu_dcm.logio.workers import Workers

__all__ = ["BATCH_BYTES", "Decompressor", "Job", "batches"]


#: Decompressed bytes per batch: ~10 chunks of rosbag2's 768 KiB, few enough calls per message,
#: a small multiple of a chunk held at once. The batch decoded and the one decompressed beside it
#: then stay in the caches: ``read_log`` of a 1 h log at 1 kHz took 1.9 s with 6-8 MiB batches,
#: 2.2 s with 12 and 2.5 s with 16 (fresh processes, interleaved, 2-core machine); below 4 MiB
#: the calls per batch cost more than that saves (3.5 s with 1-2 MiB).
BATCH_BYTES = 8 << 20


@dataclass(slots=True, eq=False)
class Job:
    """One chunk to read: ``n`` compressed bytes at file offset ``at``, ``usize`` bytes out.

    ``key`` is the caller's (what it needs to place the chunk's messages); ``comp`` the
    compression, ``crc`` the uncompressed CRC-32 (0: none). ``why`` is set to a one-line reason
    when the chunk is damaged; ``out`` is its slice of the batch buffer once decompressed,
    ``start`` where that slice begins.
    """

    key: object
    at: int
    n: int
    usize: int
    comp: str
    crc: int
    why: str | None = None
    out: memoryview | None = None
    start: int = 0


def batches(jobs: Iterable[Job], limit: int | None = None) -> Iterator[list[Job]]:
    """Consecutive jobs grouped into batches of at most ``limit`` (:data:`BATCH_BYTES`)
    decompressed bytes (a chunk larger than that is a batch of its own)."""
    limit = BATCH_BYTES if limit is None else limit
    group: list[Job] = []
    size = 0
    for j in jobs:
        if group and size + j.usize > limit:
            yield group
            group, size = [], 0
        group.append(j)
        size += j.usize
    if group:
        yield group


def _decompress_into(fd: int, job: Job, out: memoryview, decompress: Callable) -> None:
    data = os.pread(fd, job.n, job.at)
    if len(data) != job.n:
        job.why = f"the file ends inside it ({len(data)} of {job.n} bytes)"
        return
    why = decompress(job.comp, data, out)
    if why is None and job.crc != 0 and crc32(out) != job.crc:
        why = "it fails its CRC check"
    job.why = why
    if why is None:
        job.out = out


class Decompressor:
    """Decompresses batches of :class:`Job` into one buffer each, on worker threads, one batch
    ahead of the caller. ``decompress(comp, data, out)`` fills ``out`` exactly or returns why
    it could not.

    Buffers are reused: a batch's buffer goes back to the pool when nothing else holds it
    (the caller kept no payload in it), so a long log touches fresh memory for a few batches
    only (a first touch costs ~1 µs a 4 KiB page here: 0.5 s for 1.8 GB of chunks).
    """

    def __init__(self, fd: int, decompress: Callable):
        self.fd, self.decompress = fd, decompress
        self._free: list[np.ndarray] = []

    def _buffer(self, size: int) -> np.ndarray:
        for k, b in enumerate(self._free):
            if len(b) >= size:
                return self._free.pop(k)
        return np.empty(max(size, BATCH_BYTES), np.uint8)

    def _start(self, pool: Workers, group: list[Job]):
        size = sum(j.usize for j in group)
        whole = self._buffer(size)
        mv = memoryview(whole)
        futures, pos = [], 0
        for j in group:
            out, j.start = mv[pos : pos + j.usize], pos
            futures.append(pool.submit(_decompress_into, self.fd, j, out, self.decompress))
            pos += j.usize
        return [whole, size, group, futures]  # a list: emptied when handed over

    def run(self, groups: Iterator[list[Job]]) -> Iterator[tuple[np.ndarray, list[Job]]]:
        """(buffer, jobs) per batch, in order; each job's ``out`` is its slice of the buffer
        (None when damaged), valid until the next batch is asked for. A read given up (an
        error, a signal) cancels the batch started ahead that no worker has begun."""
        pool, finished = Workers(), False
        ahead = started = None
        try:
            for group in groups:
                started = self._start(pool, group)
                if ahead is not None:
                    yield from self._hand_over(ahead)
                ahead = started
            if ahead is not None:
                yield from self._hand_over(ahead)
            finished = True
        finally:  # a batch handed over is emptied: only those still ahead have futures
            for batch in (ahead, started):
                for fut in batch[3] if batch else ():
                    fut.cancel()
            pool.stop(wait=finished)

    def _hand_over(self, started) -> Iterator[tuple[np.ndarray, list[Job]]]:
        whole, size, group, futures = started
        started.clear()
        for fut in futures:
            fut.result()
        yield whole[:size], group
        for j in group:
            j.out = None
        del futures
        if sys.getrefcount(whole) <= 2:  # this frame and the call: nobody kept a view
            self._free.append(whole)

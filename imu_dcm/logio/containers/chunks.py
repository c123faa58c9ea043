"""Chunks decompressed in batches: several chunks into one buffer, on worker threads.

A long log is thousands of 768 KiB - 1 MiB chunks; the numpy work that locates and decodes
their messages costs about the same per call whatever the size, so it runs once per batch of
chunks (:data:`BATCH_BYTES` decompressed), not once per chunk. The chunks of a batch are
decompressed side by side into one buffer, each into its own slice, by a small thread pool
(zstd, lz4 and CRC-32 release the GIL), while the caller decodes the batch before.

The pool's threads are daemons, one set per read: a signal handler that raises in the main
thread (SIGTERM's :class:`~imu_dcm.app.run.Terminated`, Ctrl-C) can do so inside
``Thread.start`` or a future's wait and leave one of their locks held, and the threads of an
executor would then keep the process from exiting (it waits for them). A read that finishes
waits for its threads to end, so none outlives it.
"""

from __future__ import annotations

import os
import queue
import sys
import threading
import zlib
from collections.abc import Callable, Iterator
from concurrent.futures import Future
from dataclasses import dataclass

import numpy as np

__all__ = ["BATCH_BYTES", "WORKERS", "Decompressor", "Job", "batches"]


#: Decompressed bytes per batch: ~16 chunks of rosbag2's 768 KiB, few enough numpy calls per
#: message, a small multiple of a chunk held at once.
BATCH_BYTES = 16 << 20
#: Worker threads (decompression and CRC release the GIL); batches decompressed ahead.
WORKERS = min(2, os.cpu_count() or 1)


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


def batches(jobs: list[Job], limit: int | None = None) -> Iterator[list[Job]]:
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
    if why is None and job.crc != 0 and zlib.crc32(out) != job.crc:
        why = "it fails its CRC check"
    job.why = why
    if why is None:
        job.out = out


class _Workers:
    """:data:`WORKERS` daemon threads running submitted calls, each call's :class:`Future`
    given back, for one read (see the module doc). :meth:`stop` ends them once their calls
    are done: waited for after a read that finished, not after one given up."""

    def __init__(self) -> None:
        self._jobs: queue.SimpleQueue = queue.SimpleQueue()
        self._threads = [
            threading.Thread(target=self._work, args=(self._jobs,), name=f"imu_dcm-read-{k}")
            for k in range(WORKERS)
        ]
        for t in self._threads:
            t.daemon = True
            t.start()

    def submit(self, fn: Callable, *args) -> Future:
        fut: Future = Future()
        self._jobs.put((fut, fn, args))
        return fut

    def stop(self, wait: bool) -> None:
        for _ in self._threads:
            self._jobs.put(None)
        if wait:
            for t in self._threads:
                t.join()

    @staticmethod
    def _work(jobs: queue.SimpleQueue) -> None:
        while (job := jobs.get()) is not None:
            fut, fn, args = job
            if not fut.set_running_or_notify_cancel():
                continue  # cancelled: its read was given up
            try:
                fut.set_result(fn(*args))
            except BaseException as exc:  # handed to the caller, as an executor does
                fut.set_exception(exc)


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

    def _start(self, pool: _Workers, group: list[Job]):
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
        pool, finished = _Workers(), False
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

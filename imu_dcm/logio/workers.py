"""The worker threads of a read or a write: decompression, compression and CRC-32 release the
GIL, so chunks are (de)compressed beside the main thread's work.

They are daemons, one set per read or write: a signal handler that raises in the main thread
(SIGTERM's :class:`~imu_dcm.app.run.Terminated`, Ctrl-C) can do so inside ``Thread.start`` or
a future's wait and leave one of their locks held, and the threads of an executor would then
keep the process from exiting (it waits for them). Work that finishes waits for its threads
to end, so none outlives it (a later fork stays safe).
"""

from __future__ import annotations

import os
import queue
import threading
from collections.abc import Callable
from concurrent.futures import Future

__all__ = ["WORKERS", "Workers"]

#: Worker threads of one read or write.
WORKERS = min(2, os.cpu_count() or 1)


class Workers:
    """:data:`WORKERS` daemon threads running submitted calls, each call's :class:`Future`
    given back, for one read or write. :meth:`stop` ends them once their calls are done:
    waited for after work that finished, not after work given up (an error, a signal)."""

    def __init__(self) -> None:
        self._jobs: queue.SimpleQueue = queue.SimpleQueue()
        self._threads = [
            threading.Thread(target=self._work, args=(self._jobs,), name=f"imu_dcm-worker-{k}")
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

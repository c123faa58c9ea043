"""Timing helpers for the benchmarks: one BLAS thread, warm-up, medians of interleaved rounds.

How a figure is measured here (the project's rule: speed is measured in benchmarks, never
asserted in tests; ratios against a reference measured in the same run):

* **One BLAS/OpenMP thread.** Call :func:`limit_threads_env` *before* numpy is imported (it sets
  the usual environment variables), then run the measurement inside :func:`single_thread` (a
  ``threadpoolctl`` limit, which also works when numpy was imported first).
* **Warm-up, then interleaved rounds.** Every case runs once untimed, then each round runs every
  case once in turn; a case's figure is the median over rounds. Interleaving spreads slow phases
  of a shared machine over all cases, so *ratios* between cases measured in the same run are
  fairer than the absolute figures.

Example
-------
>>> from benchmarks.timing import limit_threads_env
>>> limit_threads_env()                          # before importing numpy
>>> import numpy as np
>>> from benchmarks.timing import interleaved_medians, single_thread
>>> with single_thread():
...     res = interleaved_medians({"sum": (lambda: np.ones(1000).sum(), 1000)}, rounds=5)
>>> res["sum"].ns_per_item > 0
True
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass

__all__ = [
    "THREAD_ENV_VARS",
    "Timing",
    "interleaved_medians",
    "limit_threads_env",
    "single_thread",
    "time_once",
]

#: Environment variables read by the BLAS / OpenMP runtimes at load time.
THREAD_ENV_VARS = (
    "OMP_NUM_THREADS",
    "OPENBLAS_NUM_THREADS",
    "MKL_NUM_THREADS",
    "BLIS_NUM_THREADS",
    "VECLIB_MAXIMUM_THREADS",
    "NUMEXPR_NUM_THREADS",
)


def limit_threads_env(n_threads: int = 1) -> None:
    """Set the thread-count environment variables to ``n_threads`` (call before importing numpy).

    Variables already set by the user are overwritten, so every benchmark run is alike.
    """
    for name in THREAD_ENV_VARS:
        os.environ[name] = str(int(n_threads))


@contextmanager
def single_thread() -> Iterator[None]:
    """Context in which BLAS and OpenMP pools use one thread (``threadpoolctl``)."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1):
        yield


@dataclass(frozen=True)
class Timing:
    """Result of timing one case.

    Attributes
    ----------
    name : str
        Case name.
    n_items : int
        Items (e.g. samples) processed by one call of the case.
    times_s : tuple of float
        Wall time of each timed round, seconds.
    """

    name: str
    n_items: int
    times_s: tuple[float, ...]

    @property
    def median_s(self) -> float:
        """Median wall time of one call, seconds."""
        t = sorted(self.times_s)
        m = len(t) // 2
        return t[m] if len(t) % 2 else 0.5 * (t[m - 1] + t[m])

    @property
    def ns_per_item(self) -> float:
        """Median cost per item, nanoseconds."""
        return 1e9 * self.median_s / self.n_items

    @property
    def items_per_s(self) -> float:
        """Median throughput, items per second."""
        return self.n_items / self.median_s


def time_once(fn: Callable[[], object], clock: Callable[[], float] = time.perf_counter) -> float:
    """Time of one call of ``fn`` on ``clock`` (default wall time, ``time.perf_counter``), s."""
    t0 = clock()
    fn()
    return clock() - t0


def interleaved_medians(
    cases: Mapping[str, tuple[Callable[[], object], int]],
    rounds: int = 5,
    warmup: int = 1,
    clock: Callable[[], float] = time.perf_counter,
) -> dict[str, Timing]:
    """Time several cases in interleaved rounds after a warm-up.

    Parameters
    ----------
    cases : mapping name -> (callable, n_items)
        Each callable does the whole work of one measurement and takes no argument; ``n_items``
        is how many items (samples) it processes, used for per-item figures.
    rounds : int
        Timed rounds (>= 1); each runs every case once, in the mapping's order.
    warmup : int
        Untimed calls of every case before the first round.
    clock : callable
        ``time.perf_counter`` (wall time, default) or ``time.process_time`` (CPU time of this
        process: on a shared, loaded machine it leaves out the time other processes hold the
        CPU; for single-threaded cases it equals wall time on an idle machine).

    Returns
    -------
    dict name -> :class:`Timing`
    """
    if rounds < 1:
        raise ValueError(f"Expected rounds >= 1, got {rounds}")
    for _ in range(warmup):
        for fn, _n in cases.values():
            fn()
    times: dict[str, list[float]] = {name: [] for name in cases}
    for _ in range(rounds):
        for name, (fn, _n) in cases.items():
            times[name].append(time_once(fn, clock))
    return {name: Timing(name, int(n), tuple(times[name])) for name, (_fn, n) in cases.items()}

"""Where the logs of a batch run: in this process, in a process pool, or on a Dask cluster.

Each runner calls ``fn(path, options) -> (row, curve)`` once per log (``fn`` must not raise and
must be importable by name, e.g. :func:`imu_dcm.replay.batch_log.replay_one`) and yields the results
as they finish, in completion order. Workers get one BLAS/OpenMP thread each.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import signal
import sys
import threading
import warnings
from collections.abc import Callable, Iterator, Mapping
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Any

from imu_dcm.app.run import one_line
from imu_dcm.errors import ImuDcmWarning, InputError
from imu_dcm.memory import keep_freed_memory
from imu_dcm.replay.table import Curve, LogRow

__all__ = ["DASK_HINT", "LOST", "run_dask", "run_local"]

#: In the error of a row whose worker died (not the log's fault: ``resume`` retries it).
LOST = "worker lost"
DASK_HINT = "pip install 'imu_dcm[dask]' (or pip install 'dask[distributed]')"
_BLAS_ENV = (
    "OMP_NUM_THREADS",
    "OPENBLAS_NUM_THREADS",
    "MKL_NUM_THREADS",
    "VECLIB_MAXIMUM_THREADS",
    "NUMEXPR_NUM_THREADS",
)

Outcome = tuple[LogRow, "Curve | None"]
PerLog = Callable[[str, Mapping[str, Any]], Outcome]


def pin_threads() -> None:
    """One BLAS/OpenMP thread in this process: threadpoolctl for libraries already loaded
    (when installed), and the env vars for those loaded later."""
    for name in _BLAS_ENV:
        os.environ[name] = "1"
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        return
    threadpool_limits(1)


def _worker_init() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles Ctrl-C
    signal.signal(signal.SIGTERM, signal.SIG_DFL)  # die when the parent terminates us
    pin_threads()
    keep_freed_memory()  # as the command's own process (imu_dcm.memory)


def _pool_context() -> multiprocessing.context.BaseContext:
    """fork (workers start in milliseconds, modules already imported) on Linux when this
    process runs a single thread and threadpoolctl can pin BLAS after the fork; else spawn,
    with the BLAS env vars set before the workers import numpy."""
    try:
        import threadpoolctl  # noqa: F401
    except ImportError:
        return multiprocessing.get_context("spawn")
    if sys.platform.startswith("linux") and threading.active_count() == 1:
        return multiprocessing.get_context("fork")
    return multiprocessing.get_context("spawn")


@contextlib.contextmanager
def _env(values: Mapping[str, str]):
    old = {k: os.environ.get(k) for k in values}
    os.environ.update(values)
    try:
        yield
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _lost(path: str, exc: BaseException) -> Outcome:
    return LogRow(path, error=f"{type(exc).__name__}: {LOST}: {one_line(str(exc))}"), None


def run_local(
    fn: PerLog, paths: list[str], options: Mapping[str, Any], jobs: int
) -> Iterator[Outcome]:
    """Yield ``fn(path, options)`` per log as each finishes: in this process for one job (with
    one BLAS thread, the workers' arithmetic), else in a pool of ``jobs`` worker processes."""
    if jobs == 1 or len(paths) == 1:
        with contextlib.ExitStack() as stack:
            try:
                from threadpoolctl import threadpool_limits

                stack.enter_context(threadpool_limits(1))
            except ImportError:
                pass
            for p in paths:
                yield fn(p, options)
        return
    pool = ProcessPoolExecutor(
        min(jobs, len(paths)), mp_context=_pool_context(), initializer=_worker_init
    )
    finished = False
    try:
        with _env(dict.fromkeys(_BLAS_ENV, "1")):  # spawned workers start as tasks are submitted
            futures = {pool.submit(fn, p, options): p for p in paths}
        for fut in as_completed(futures):
            path = futures.pop(fut)
            exc = fut.exception()
            yield fut.result() if exc is None else _lost(path, exc)
        finished = True
    finally:
        if finished:  # every worker is idle: let them exit, so no pool thread outlives the batch
            pool.shutdown(wait=True)
        else:  # stopped early: do not leave workers replaying
            procs = list((getattr(pool, "_processes", None) or {}).values())
            pool.shutdown(wait=False, cancel_futures=True)
            for proc in procs:
                if proc.is_alive():
                    proc.terminate()


def run_dask(fn: PerLog, paths: list[str], options: Mapping[str, Any], dask) -> Iterator[Outcome]:
    """Yield ``fn(path, options)`` per log as each finishes on a Dask cluster.

    ``dask`` is a ``distributed.Client`` (left open) or a scheduler address such as
    ``"tcp://host:8786"`` (a client is opened and closed here).
    """
    try:
        from distributed import Client
        from distributed import as_completed as dask_completed
    except ImportError:
        raise InputError(
            f"Expected dask.distributed for --dask, got it not installed: {DASK_HINT}"
        ) from None
    own = isinstance(dask, str)
    try:
        client = Client(dask) if own else dask
    except OSError as exc:  # refused, timed out
        raise InputError(f"Expected a Dask scheduler at {dask}, got {one_line(str(exc))}") from None
    futures: dict = {}
    try:
        workers = client.scheduler_info().get("workers", {}).values()
        threaded = sum(w.get("nthreads", 1) > 1 for w in workers)
        if threaded:
            warnings.warn(
                f"{threaded} Dask workers run several threads, whose replays share one Python "
                f"interpreter: start workers with --nthreads 1 --nworkers N",
                ImuDcmWarning,
                stacklevel=3,
            )
        client.run(pin_threads)
        futures = {client.submit(fn, p, dict(options), pure=False): p for p in paths}
        for fut in dask_completed(list(futures)):
            path = futures.pop(fut)
            yield fut.result() if fut.status == "finished" else _lost(path, fut.exception())
            fut.release()
    finally:
        if futures:
            client.cancel(list(futures))
        if own:
            client.close()

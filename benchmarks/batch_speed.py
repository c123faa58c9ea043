"""Batch replay speed: a process pool and a Dask cluster against one process, and the per-log
cost of the batch machinery against a bare replay.

``python -m benchmarks.batch_speed [--rounds N] [--broad DIR] [--small N] [--only-small]``

Logs: the six BROAD bags (``../shared/data/broad`` beside the repository, or ``--broad``) and the
shipped BROAD trial under ``replay/``. Medians of interleaved rounds after a warm-up, one BLAS
thread per process (see :mod:`benchmarks.timing`). Three measurements:

1. Per-log cost of the batch machinery, all in this process: ``bare`` (a loop of
   :func:`imu_dcm.replay.replay` calls), ``jobs 1`` (:func:`imu_dcm.replay.replay_many`, rows in
   memory) and ``jobs 1 + table`` (writing the CSV with an fsync per row, the curves and the
   markdown; no chart), in CPU time of this process (exact on a loaded machine) and wall time.
2. Parallel speed-up, wall time, no Dask client alive (so the pool forks its workers):
   ``jobs 2`` (a pool of two workers started inside the timed call) against ``jobs 1``. Target:
   <= 0.6 on two cores. In the same rounds, two units of pure-Python CPU work in this process
   or split over a fresh pool of two: on a shared machine this ratio says how much parallelism
   the machine gave during the run (0.5 on two idle cores, 1.0 when others take a whole core).
3. Dask: a ``LocalCluster`` of two single-thread worker processes on 127.0.0.1 (started before
   the rounds, warmed up by one batch), against ``jobs 1`` timed in the same rounds.

4. Many small logs (``--small N``, default 64): N synthetic coning logs written by data_synth
   (400 Hz, 20-40 s, 8 000-16 000 samples each) into a temporary folder, replayed by the
   command a user types, ``python -m imu_dcm.replay batch DIR --table T.csv --force
   --no-chart --jobs J``, each call a fresh process (so the workers start as they do for a
   user: the parent has imported nothing of the replay), ``--jobs 2`` against ``--jobs 1`` in
   interleaved rounds, beside the pure-CPU reference. Target: 1.7x or more (ratio <= 0.59).

Every mode must give the same rows, bit for bit except the wall time; the script checks it.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.timing import limit_threads_env

REPO = Path(__file__).resolve().parents[1]
DEFAULT_BROAD = REPO.parent / "shared" / "data" / "broad"
SHIPPED = REPO / "replay" / "broad_07_undisturbed_fast_rotation_B"
TARGET_RATIO = 0.6


SPIN = 10_000_000  # loop iterations of one unit of pure CPU work (~0.5 s on an idle core)


def _spin(n: int) -> int:
    s = 0
    for i in range(n):
        s += i
    return s


def _spin_units(jobs: int) -> None:
    """Two units of CPU work: in this process (jobs 1) or in a fresh pool of two workers, as the
    batch runs them. The ratio of the two says what parallelism the machine gives right now."""
    if jobs == 1:
        _spin(SPIN), _spin(SPIN)
        return
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("fork")) as ex:
        list(ex.map(_spin, [SPIN, SPIN]))


def _same(a, b) -> bool:
    def strip(rows):
        return [dataclasses.replace(r, elapsed_s=None) for r in rows]

    return strip(a) == strip(b)


class _Batches:
    """The logs, the timed calls on them, and what each call gave (rows, CPU time)."""

    def __init__(self, logs: list[str]):
        from imu_dcm.replay import replay, replay_many

        self._replay, self._replay_many = replay, replay_many
        self.logs = logs
        self.n = len(logs)
        self.rows: dict[str, tuple] = {}
        self.cpu_s: dict[str, list[float]] = {}  # this process plus its reaped workers, per call

    def batch(self, name: str, **kw):
        """A call of ``replay_many`` over the logs, keeping its rows and CPU time under ``name``."""

        def fn():
            before = os.times()
            self.rows[name] = self._replay_many(self.logs, chart=None, **kw).rows
            after = os.times()
            # user, sys, children's user and sys
            used = sum(a - b for a, b in zip(after[:4], before[:4], strict=False))
            self.cpu_s.setdefault(name, []).append(used)

        return fn

    def bare(self) -> None:
        for path in self.logs:
            self._replay(path)

    def show(self, timings) -> None:
        for name, t in timings.items():
            print(
                f"  {name:<16} median {t.median_s:6.3f} s  "
                f"({1e3 * t.median_s / self.n:6.1f} ms/log; "
                f"rounds {', '.join(f'{x:.2f}' for x in t.times_s)})"
            )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m benchmarks.batch_speed",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--broad", type=Path, default=DEFAULT_BROAD, help="folder of BROAD bags")
    p.add_argument("--rounds", type=int, default=5, help="timed rounds (default 5)")
    p.add_argument("--small", type=int, default=64, help="small logs of measurement 4 (64)")
    p.add_argument("--only-small", action="store_true", help="measurement 4 only")
    p.add_argument(
        "--baseline",
        type=Path,
        help="another checkout of the project (an earlier commit): measurement 4 also times "
        "its batch command, in the same rounds",
    )
    args = p.parse_args(argv)

    limit_threads_env()
    if args.only_small:
        print(f"load average before: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
        ok = _small_logs(args.small, args.rounds, args.baseline)
        print(f"load average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
        return 0 if ok else 1
    from imu_dcm.replay.batch import find_logs

    logs = find_logs([args.broad, SHIPPED])
    if len(logs) != 7:
        print(
            f"expected the six BROAD bags under {args.broad} and the shipped trial, "
            f"found {len(logs)} logs",
            file=sys.stderr,
        )
        return 2
    b = _Batches(logs)
    print(
        f"{b.n} logs; {os.cpu_count()} cores; load average before: "
        f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}"
    )
    _machinery_and_pool(b, args.rounds)
    modes = ["jobs 2", "table"]
    if _dask(b, args.rounds):
        modes.append("dask")
    same = all(_same(b.rows[k], b.rows["jobs 1"]) for k in modes)
    same = _small_logs(args.small, args.rounds, args.baseline) and same
    print(f"same rows in every mode (bit for bit, wall time aside): {'yes' if same else 'NO'}")
    print(f"load average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    return 0 if same else 1


def _machinery_and_pool(b: _Batches, rounds: int) -> None:
    """Measurements 1 and 2: the per-log cost of the machinery (CPU and wall time), and the
    speed-up of a pool of two against one process, beside the parallelism the machine gave."""
    from benchmarks.timing import interleaved_medians, single_thread

    n, tmp = b.n, Path(tempfile.mkdtemp(prefix="batch_speed_"))
    with single_thread():
        # Per-log cost of the machinery: all in this process, so CPU time is exact even on a
        # loaded machine; wall time adds the fsync of each row.
        costs = {
            "bare": (b.bare, n),
            "jobs 1": (b.batch("jobs 1", jobs=1), n),
            "jobs 1 + table": (b.batch("table", table=tmp / "t.csv", jobs=1, overwrite=True), n),
        }
        cpu = interleaved_medians(costs, rounds=rounds, clock=time.process_time)
        wall = interleaved_medians(costs, rounds=rounds)
        # Parallel speed-up: wall time, the pool started inside the timed call.
        par = interleaved_medians(
            {
                "jobs 1": (b.batch("jobs 1", jobs=1), n),
                "jobs 2": (b.batch("jobs 2", jobs=2), n),
                "spin 1 process": (lambda: _spin_units(1), 2),
                "spin 2 processes": (lambda: _spin_units(2), 2),
            },
            rounds=rounds,
        )
    print("CPU time of this process:")
    b.show(cpu)
    print("wall time:")
    b.show(wall)
    for label, t in (("CPU", cpu), ("wall", wall)):
        bare_s = t["bare"].median_s
        print(
            f"per-log overhead vs a bare replay ({label}): jobs 1 "
            f"{1e3 * (t['jobs 1'].median_s - bare_s) / n:+.1f} ms/log, with the table files "
            f"{1e3 * (t['jobs 1 + table'].median_s - bare_s) / n:+.1f} ms/log "
            f"(bare {1e3 * bare_s / n:.0f} ms/log)"
        )
    print("parallel, wall time:")
    b.show({k: v for k, v in par.items() if not k.startswith("spin")})
    ratio = par["jobs 2"].median_s / par["jobs 1"].median_s
    spin = par["spin 2 processes"].median_s / par["spin 1 process"].median_s
    print(
        f"jobs 2 / jobs 1 wall ratio: {ratio:.2f} (target <= {TARGET_RATIO}); the same ratio "
        f"for pure CPU work split over 2 processes in the same rounds: {spin:.2f} (0.5 on two "
        f"idle cores)"
    )
    c1, c2 = statistics.median(b.cpu_s["jobs 1"]), statistics.median(b.cpu_s["jobs 2"])
    print(
        f"CPU time per batch (this process and its workers): jobs 1 {c1:.2f} s, jobs 2 "
        f"{c2:.2f} s ({c2 / c1:.2f}x): on two idle cores jobs 2 / jobs 1 would be about "
        f"{c2 / c1 / 2:.2f} plus the pool's start"
    )


def _dask(b: _Batches, rounds: int) -> bool:
    """Measurement 3: a local Dask cluster of two workers against one process; False when Dask
    is not installed (the phase is skipped)."""
    from benchmarks.timing import interleaved_medians, single_thread

    try:
        from distributed import LocalCluster
    except ImportError:
        print("dask: not installed (pip install 'imu_dcm[dask]'), phase skipped")
        return False
    with (
        LocalCluster(
            n_workers=2,
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            dashboard_address="127.0.0.1:0",  # any free port, loopback only
            silence_logs=logging.ERROR,
        ) as cluster,
        single_thread(),
    ):
        address = cluster.scheduler_address
        on_dask = interleaved_medians(
            {
                "jobs 1": (b.batch("jobs 1", jobs=1), b.n),
                "dask 2 workers": (b.batch("dask", dask=address), b.n),
            },
            rounds=rounds,
        )
    print("Dask, wall time:")
    b.show(on_dask)
    dratio = on_dask["dask 2 workers"].median_s / on_dask["jobs 1"].median_s
    print(f"dask (LocalCluster, 2 worker processes) / jobs 1 wall ratio: {dratio:.2f}")
    return True


def _write_small_logs(folder: Path, n: int) -> None:
    from data_synth.cli import main as synth

    for k in range(n):
        argv = ["coning", "--rate", "400", "--duration", str(20 + k % 21)]
        if synth([*argv, "--out", str(folder / f"coning_{k:03d}")]) != 0:
            raise RuntimeError(f"data_synth failed on {argv}")


def _small_logs(n: int, rounds: int, baseline: Path | None = None) -> bool:
    """Measurement 4: ``--jobs 2`` / ``--jobs 1`` of the batch command on ``n`` small logs,
    each call a fresh process (and the same with the ``baseline`` checkout's code); wall time
    and the CPU time of the command with its workers. True when the tables hold the same rows
    (wall time aside)."""
    import contextlib
    import io
    import resource
    import subprocess

    from benchmarks.timing import interleaved_medians, single_thread
    from imu_dcm.replay.table import read_table

    trees = {"": REPO} | ({"baseline ": baseline.resolve()} if baseline else {})
    cpu: dict[str, list[float]] = {}
    with tempfile.TemporaryDirectory(prefix="batch_small_") as tmp:
        folder = Path(tmp) / "logs"
        folder.mkdir()
        with contextlib.redirect_stdout(io.StringIO()):
            _write_small_logs(folder, n)

        def command(tree: str, jobs: int):
            name = f"{tree}jobs {jobs}"
            table = str(Path(tmp) / f"{name.replace(' ', '_')}.csv")
            argv = [sys.executable, "-m", "imu_dcm.replay", "batch", str(folder), "--table"]
            argv += [table, "--force", "--no-chart", "--quiet", "--jobs", str(jobs)]
            env = {**os.environ, "PYTHONPATH": str(trees[tree])}

            def run():
                before = resource.getrusage(resource.RUSAGE_CHILDREN)
                subprocess.run(argv, env=env, check=True, capture_output=True)
                after = resource.getrusage(resource.RUSAGE_CHILDREN)
                used = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
                cpu.setdefault(name, []).append(used)

            return name, (run, n)

        cases = dict(command(tree, j) for tree in trees for j in (1, 2))
        cases["spin 1 process"] = (lambda: _spin_units(1), 2)
        cases["spin 2 processes"] = (lambda: _spin_units(2), 2)
        with single_thread():
            t = interleaved_medians(cases, rounds=rounds)
        rows = {k: read_table(Path(tmp) / f"{k.replace(' ', '_')}.csv") for k in cpu}
    print(f"{n} small logs (400 Hz, 20-40 s), the batch command in a fresh process:")
    for name in cpu:
        x = t[name]
        print(
            f"  {name:<16} wall median {x.median_s:6.3f} s ({1e3 * x.median_s / n:5.1f} ms/log; "
            f"rounds {', '.join(f'{v:.2f}' for v in x.times_s)}); CPU with workers "
            f"{statistics.median(cpu[name]):.2f} s"
        )
    spin = t["spin 2 processes"].median_s / t["spin 1 process"].median_s
    for tree in trees:
        ratio = t[f"{tree}jobs 2"].median_s / t[f"{tree}jobs 1"].median_s
        c = statistics.median(cpu[f"{tree}jobs 2"]) / statistics.median(cpu[f"{tree}jobs 1"])
        print(
            f"small logs, {tree or 'this tree '}: jobs 2 / jobs 1 wall ratio {ratio:.2f} "
            f"(speed-up {1 / ratio:.2f}x, target >= 1.7x); CPU ratio {c:.2f}"
        )
    print(f"pure CPU work over 2 processes in the same rounds: {spin:.2f} ({1 / spin:.2f}x)")
    same = all(_same(rows[k], rows["jobs 1"]) for k in rows)
    print(f"small logs: same rows in every run (wall time aside): {'yes' if same else 'NO'}")
    return same


if __name__ == "__main__":
    sys.exit(main())

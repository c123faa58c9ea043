"""Long logs: where the time and the memory of a replay go, from 1 minute to hours at 1 kHz.

``python -m benchmarks.scale [--long] [--rounds N] [--minutes M ...] [--no-rosbags]``

Each log is a synthetic coning bag written by ``python -m data_synth coning --rate 1000`` into a
temporary folder (removed at the end): 1 min, 10 min and 1 h (``--long`` adds 4 h). For each:

* **Floors and references**, in interleaved rounds after a warm-up (medians,
  :mod:`benchmarks.timing`): ``cat`` of the ``.mcap`` (the page-cache floor), the zstd
  decompression of every chunk on one thread (what no MCAP reader can skip), ``read_log``, and
  rosbags' ``AnyReader`` + ``deserialize`` loop over the IMU and truth topics (the reference,
  skipped above 10 min: it takes minutes an hour). Ratios are to figures of the same run.
* **The replay**, in a fresh process set up as the command sets itself up (numpy's pages,
  :mod:`imu_dcm.app.pages`), ``replay()`` without a viewer, then the estimate written as a bag,
  as ``--out`` does: wall, CPU and peak RSS of that process (``os.wait4``'s rusage),
  and the time per sample of each phase, timed by wrapping the functions that do it: read
  (``read_log``), clean (``clean_imu``), truth check (``align_truth`` and the judgement around
  it, less its resampling), resample (``slerp_truth``), bias (``estimate_bias``), integrate
  (``integrate_quat``), score (``attitude_errors``), write (the estimate bag). ``arrays``
  is the bytes the replay must hold: its result's arrays, each buffer once.

The machine is shared: absolute figures move with the load, ratios within a run much less.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.timing import limit_threads_env

REPO = Path(__file__).resolve().parents[1]
RATE_HZ = 1000
PHASES = ("read", "clean", "truth check", "resample", "bias", "integrate", "score", "write")


# ------------------------------------------------------------------------------ logs
def make_log(folder: Path, minutes: float) -> Path:
    """A coning bag of ``minutes`` at 1 kHz written by data_synth (its own process)."""
    out = folder / f"coning_{minutes:g}min"
    cmd = [sys.executable, "-m", "data_synth", "coning", "--rate", str(RATE_HZ)]
    cmd += ["--duration", str(60 * minutes), "--out", str(out)]
    cmd += ["--max-memory-gib", "16", "--max-minutes", "120"]
    run = _measured(cmd)
    print(
        f"  wrote {out.name}: {_mb(_size(out))} on disk in {run['wall_s']:.1f} s, "
        f"data_synth peak {_mb(run['peak_bytes'])}",
        flush=True,
    )
    return out


def _size(bag: Path) -> int:
    return sum(p.stat().st_size for p in bag.iterdir())


def _mb(n: float) -> str:
    return f"{n / 1e6:.0f} MB" if n < 1e9 else f"{n / 1e9:.2f} GB"


def _measured(cmd: list[str]) -> dict:
    """Run ``cmd``; its wall and CPU time and peak RSS (``os.wait4``), and its stdout."""
    env = dict(os.environ, PYTHONPATH=str(REPO))
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, env=env, cwd=REPO)
    out = proc.stdout.read()
    _, status, ru = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode:
        raise SystemExit(f"Expected {' '.join(cmd[:4])} ... to succeed, got {proc.returncode}")
    return {
        "wall_s": wall,
        "cpu_s": ru.ru_utime + ru.ru_stime,
        "peak_bytes": ru.ru_maxrss * 1024,
        "stdout": out.decode(),
    }


# --------------------------------------------------------------------- floors, readers
def cat(path: Path) -> None:
    subprocess.run(["cat", str(path)], stdout=subprocess.DEVNULL, check=True)


def zstd_chunks(path: Path) -> int:
    """Decompress every chunk of an indexed MCAP on one thread; returns the bytes out."""
    import zstandard

    from imu_dcm.logio.containers.mcap.indexed import read_summary

    total = 0
    with open(path, "rb") as f:
        for start, clen, *_rest, _comp, csize, usize in read_summary(f, f.seek(0, 2)).chunks:
            f.seek(start + clen - csize)
            data = f.read(csize)
            total += len(zstandard.ZstdDecompressor().decompress(data, max_output_size=usize))
    return total


def rosbags_loop(bag: Path) -> int:
    """rosbags AnyReader: deserialize every IMU and truth message; returns the count."""
    from rosbags.highlevel import AnyReader

    n = 0
    with AnyReader([bag]) as reader:
        conns = [c for c in reader.connections if c.topic != "/ground_truth/angular_velocity"]
        for conn, _t, raw in reader.messages(connections=conns):
            reader.deserialize(raw, conn.msgtype)
            n += 1
    return n


def floors(bag: Path, rounds: int, rosbags: bool) -> dict:
    from benchmarks.timing import interleaved_medians, single_thread
    from imu_dcm.logio import read_log

    mcap = next(bag.glob("*.mcap"))
    n = len(read_log(bag).imu.t_ns)
    cases = {
        "cat": (lambda: cat(mcap), n),
        "zstd (1 thread)": (lambda: zstd_chunks(mcap), n),
        "read_log": (lambda: read_log(bag), n),
    }
    if rosbags:
        cases["rosbags loop"] = (lambda: rosbags_loop(bag), n)
    with single_thread():
        got = interleaved_medians(cases, rounds=rounds, warmup=1)
    return {k: v.median_s for k, v in got.items()}


# ------------------------------------------------------------------------------ replay
def _phase_child(bag: str) -> None:
    """In a fresh process: replay ``bag`` with every phase timed; print the figures as JSON.
    The process sets numpy's pages as the replay command does (:mod:`imu_dcm.app.pages`)."""
    from imu_dcm.app.pages import command_memory

    command_memory()
    import imu_dcm.replay.core as core
    import imu_dcm.replay.gyro as gyro
    import imu_dcm.replay.rate_check as rate_check
    import imu_dcm.replay.truth as truth

    spent = dict.fromkeys(PHASES, 0.0)
    stack: list[str] = []

    def timed(mod, name: str, phase: str) -> None:
        fn = getattr(mod, name)

        def wrapper(*a, **k):
            t0 = time.perf_counter()
            stack.append(phase)
            try:
                return fn(*a, **k)
            finally:
                stack.pop()
                dt = time.perf_counter() - t0
                spent[phase] += dt
                if stack:  # a phase inside another: counted once, in the inner one
                    spent[stack[-1]] -= dt

        setattr(mod, name, wrapper)

    timed(core, "read_log", "read")
    timed(gyro, "clean_imu", "clean")
    timed(core, "judge_truth", "truth check")
    timed(core, "pick_truth", "truth check")
    timed(truth, "slerp_truth", "resample")
    timed(rate_check, "slerp_truth", "resample")
    timed(core, "estimate_bias", "bias")
    timed(core, "integrate_quat", "integrate")
    timed(core, "attitude_errors", "score")  # the compiled rows (the numpy path on refusal)
    timed(core, "attitude_error_deg", "score")
    from imu_dcm.replay.__main__ import _write_out

    t0 = time.perf_counter()
    result = core.replay(bag)
    with tempfile.TemporaryDirectory() as tmp:
        t1 = time.perf_counter()
        _write_out(Path(tmp) / "estimate", result, force=False, inputs=(bag,))
        spent["write"] = time.perf_counter() - t1
    arrays = _held_bytes([*vars(result).values(), *vars(result.error).values()])
    n = len(result.t_ns)
    print(json.dumps({"n": n, "total_s": time.perf_counter() - t0, "arrays": arrays, **spent}))


def _held_bytes(values) -> int:
    """The bytes the result's arrays hold: each buffer once (the rates as read and as
    integrated are one array when no bias is removed), a view of one row repeated (one bias
    vector on every row) as nothing."""
    import numpy as np

    held: list = []
    for a in values:
        fresh = isinstance(a, np.ndarray) and 0 not in a.strides
        if fresh and not any(np.shares_memory(a, b) for b in held):
            held.append(a)
    return sum(a.nbytes for a in held)


def replay_figures(bag: Path) -> dict:
    run = _measured([sys.executable, "-m", "benchmarks.scale", "--phase-child", str(bag)])
    return {**run, **json.loads(run.pop("stdout").strip().splitlines()[-1])}


# ------------------------------------------------------------------------------ report
def report(rows: list[dict]) -> None:
    print("\n| log | samples | file | replay wall | CPU | peak RSS | arrays | peak / arrays |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        rp = r["replay"]
        print(
            f"| {r['minutes']:g} min | {rp['n'] / 1e6:.2f} M | {_mb(r['size'])} | "
            f"{rp['wall_s']:.2f} s | {rp['cpu_s']:.2f} s | {_mb(rp['peak_bytes'])} | "
            f"{_mb(rp['arrays'])} | {rp['peak_bytes'] / rp['arrays']:.1f}x |"
        )
    print("\nper-phase time per sample (ns):\n")
    print("| log | " + " | ".join(PHASES) + " |")
    print("|---|" + "---|" * len(PHASES))
    for r in rows:
        rp = r["replay"]
        cells = " | ".join(f"{1e9 * rp[p] / rp['n']:.0f}" for p in PHASES)
        print(f"| {r['minutes']:g} min | {cells} |")
    print("\nreading, medians of interleaved rounds (ratio to zstd decompression on one thread):\n")
    print("| log | cat | zstd (1 thread) | read_log | read_log / zstd | rosbags loop / read_log |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        f = r["floors"]
        rb = f.get("rosbags loop")
        ref = "-" if rb is None else f"{rb / f['read_log']:.1f}x"
        print(
            f"| {r['minutes']:g} min | {f['cat']:.3f} s | {f['zstd (1 thread)']:.3f} s | "
            f"{f['read_log']:.3f} s | {f['read_log'] / f['zstd (1 thread)']:.2f}x | "
            f"{ref} |"
        )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--long", action="store_true", help="add the 4 h log")
    ap.add_argument("--minutes", type=float, nargs="+", help="log lengths instead (minutes)")
    ap.add_argument("--rounds", type=int, default=3, help="timed rounds of the reading cases")
    ap.add_argument("--no-rosbags", action="store_true", help="skip rosbags' loop")
    ap.add_argument("--phase-child", metavar="BAG", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    limit_threads_env()
    if args.phase_child:
        _phase_child(args.phase_child)
        return 0
    minutes = args.minutes or [1, 10, 60] + ([240] if args.long else [])
    rows = []
    tmp = Path(tempfile.mkdtemp(prefix="imu_dcm_scale_"))
    try:
        for m in minutes:
            print(f"{m:g} min:", flush=True)
            bag = make_log(tmp, m)
            rows.append(
                {
                    "minutes": m,
                    "size": _size(bag),
                    "floors": floors(bag, args.rounds, not args.no_rosbags and m <= 10),
                    "replay": replay_figures(bag),
                }
            )
            shutil.rmtree(bag)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    report(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())

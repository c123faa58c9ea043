"""Regenerate every benchmark chart and table: ``python -m benchmarks [--quick] --out DIR``.

Steps (a progress line each): the speed-against-accuracy measurement of every imu_dcm method and
every peer (:mod:`benchmarks.pareto`) and its chart ``pareto.png``; the convergence chart
``convergence.png``; the eight stability scenes (:mod:`benchmarks.stability`,
``stability_*.png``); the noise study (``benchmarks.noise_study.run``) and the core speed study
(``benchmarks.core_speed.run``) when those modules offer a ``run``; then ``results.md`` with every
table. ``--quick`` measures fewer rates (100, 1000, 5000 Hz) in 3 rounds instead of 6 rates in
5 rounds, and shortens the long stability runs; CI runs it as a smoke step.

All timing runs on one BLAS thread (set before numpy is imported, and held by threadpoolctl).
"""

from __future__ import annotations

from benchmarks.timing import limit_threads_env

limit_threads_env()  # before numpy is imported anywhere below

import argparse
import dataclasses
import importlib
import inspect
import json
import sys
import time
from collections.abc import Callable
from datetime import datetime, timezone
from pathlib import Path

from benchmarks.timing import single_thread
from imu_dcm.outputs import OutputError, check_output_folder, write_text_atomic


def _progress_printer() -> Callable[[str], None]:
    t0 = time.perf_counter()

    def progress(msg: str) -> None:
        print(f"[{time.perf_counter() - t0:7.1f} s] {msg}", flush=True)

    return progress


def _optional_run(
    module: str, out_dir: Path, quick: bool, progress: Callable[[str], None]
) -> tuple[str, list[str]]:
    """Call ``benchmarks.<module>.run`` if it exists; return (status, markdown lines)."""
    try:
        mod = importlib.import_module(f"benchmarks.{module}")
    except ModuleNotFoundError as exc:
        if exc.name == f"benchmarks.{module}":
            return "absent", []
        raise
    run = getattr(mod, "run", None)
    if not callable(run):
        return f"no run(); a separate command (python -m benchmarks.{module})", []
    params = inspect.signature(run).parameters
    kwargs = {}
    if "quick" in params:
        kwargs["quick"] = quick
    if "progress" in params:
        kwargs["progress"] = progress
    first = next(iter(params), None)
    if first in ("out_dir", "out", "output_dir", "out_path"):
        result = run(out_dir, **kwargs)
    else:
        return "run() takes no output folder", []
    if isinstance(result, str):
        return "ran", result.splitlines()
    if isinstance(result, (list, tuple)) and all(isinstance(x, str) for x in result):
        return "ran", list(result)
    return "ran", []


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks",
        description="Regenerate the speed-vs-accuracy and stability charts and results.md.",
    )
    parser.add_argument("--out", required=True, type=Path, help="output folder (created)")
    parser.add_argument(
        "--quick",
        action="store_true",
        help="fewer rates and rounds, shorter long runs (CI smoke step)",
    )
    parser.add_argument(
        "--clock",
        choices=("wall", "cpu"),
        default="wall",
        help="timer: wall time (default) or this process's CPU time, which "
        "leaves out the time other processes hold the CPU on a shared "
        "machine",
    )
    return parser


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    out: Path = args.out
    try:
        check_output_folder(out)
        out.mkdir(parents=True, exist_ok=True)
    except (OutputError, OSError) as exc:
        text = getattr(exc, "strerror", None) or exc
        print(f"benchmarks: Expected a writable output folder, got {out} ({text})", file=sys.stderr)
        return 2

    import numpy as np  # noqa: F401  (after the thread limit)

    from benchmarks import stability

    progress = _progress_printer()
    t_start = time.perf_counter()
    rounds = 3 if args.quick else 5
    with single_thread():
        meas, cases, conv = _pareto(out, args.quick, rounds, args.clock, progress)
        stab_md = stability.run(out, quick=args.quick, progress=progress)
        extra, failed = _studies(out, args.quick, progress)
    elapsed = time.perf_counter() - t_start
    md = _results_markdown(args, rounds, elapsed, meas, cases, conv, stab_md + extra)
    write_text_atomic(out / "results.md", "\n".join(md) + "\n")
    write_text_atomic(
        out / "pareto.json", json.dumps([dataclasses.asdict(m) for m in meas], indent=0) + "\n"
    )
    progress(f"done: {out / 'results.md'} ({elapsed:.0f} s)")
    if failed:
        print(
            f"benchmarks: Expected every study to run, got failures in {', '.join(failed)}",
            file=sys.stderr,
        )
        return 1
    return 0


def _results_markdown(args, rounds, elapsed, meas, cases, conv, tail: list[str]) -> list[str]:
    """``results.md``: the command that made it, then each study's section."""
    from benchmarks import pareto

    command = (
        "python -m benchmarks"
        + (" --quick" if args.quick else "")
        + (f" --clock {args.clock}" if args.clock != "wall" else "")
        + " --out DIR"
    )
    md = [
        "# imu_dcm benchmarks: speed against accuracy, and stability",
        "",
        (
            f"Generated by `{command}` on {datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC in "
            f"{elapsed:.0f} s. Charts beside this file: `pareto.png` "
            "(`pareto_all.png`: every case), "
            "`convergence.png`, "
            "`stability_*.png`."
        ),
        "",
    ]
    md += pareto.summary_markdown(meas)
    md += pareto.results_markdown(meas, cases, rounds, command, clock=args.clock)
    md += pareto.convergence_markdown(conv)
    return md + tail


def _pareto(out: Path, quick: bool, rounds: int, clock: str, progress: Callable[[str], None]):
    """Measure every method on every scene, draw ``pareto.png`` and ``pareto_all.png``; the
    convergence runs and ``convergence.png``. Returns (measurements, cases, convergence)."""
    from benchmarks import pareto

    rates = pareto.QUICK_RATES_HZ if quick else pareto.FULL_RATES_HZ
    conv_rates = (50.0, 200.0, 1000.0, 5000.0, 20000.0) if quick else pareto.CONVERGENCE_RATES_HZ
    cases = pareto.method_cases()
    progress(
        f"pareto: {len(cases)} methods, {len(pareto.SCENES)} scenes, rates "
        f"{', '.join(f'{r:g}' for r in rates)} Hz, {rounds} rounds"
    )
    meas = pareto.measure(pareto.SCENES, rates, cases, rounds, progress, clock=clock)
    pareto.plot_pareto(meas, cases, out / "pareto.png", skip=pareto.MAIN_CHART_SKIP, clock=clock)
    pareto.plot_pareto(
        meas,
        cases,
        out / "pareto_all.png",
        clock=clock,
        title_note=" (every case, incl. all streaming methods)",
    )
    progress("pareto: wrote pareto.png, pareto_all.png")
    conv = pareto.convergence(pareto.SCENES, conv_rates, progress=progress)
    pareto.plot_convergence(conv, out / "convergence.png")
    progress("convergence: wrote convergence.png")
    return meas, cases, conv


def _studies(
    out: Path, quick: bool, progress: Callable[[str], None]
) -> tuple[list[str], list[str]]:
    """The noise and core speed studies, each when it offers a ``run``: their markdown (or a
    line saying why a study is not part of the run) and the studies that failed."""
    extra: list[str] = []
    failed = []
    for module in ("noise_study", "core_speed"):
        progress(f"{module}: running")
        try:
            status, lines = _optional_run(module, out, quick, progress)
        except Exception as exc:
            status, lines = f"FAILED ({type(exc).__name__}: {exc})", []
            failed.append(module)
        progress(f"{module}: {status}")
        if lines:
            extra += lines + [""]
        elif status != "ran":
            extra += [f"`benchmarks.{module}`: {status}; not part of this run.", ""]
    return extra, failed


if __name__ == "__main__":
    sys.exit(main())

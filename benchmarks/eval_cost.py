"""What the replay's statistics cost: a plain replay with and without them, interleaved.

``python -m benchmarks.eval_cost [LOG] [--rounds N]``

The same :func:`imu_dcm.replay.replay` call, once with the statistics, drift fits and bias
self-check of :func:`imu_dcm.replay.stats.evaluate` and once with that step skipped, in
interleaved rounds after a warm-up, one BLAS thread, CPU time of this process (exact on a
loaded machine). Prints both medians and their ratio (target: at most 1.05). Default log: the
shipped BROAD trial.
"""

from __future__ import annotations

import argparse
import statistics
import time
import warnings
from pathlib import Path

from benchmarks.timing import limit_threads_env

REPO = Path(__file__).resolve().parents[1]
TRIAL = REPO / "replay" / "broad_07_undisturbed_fast_rotation_B"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.eval_cost", description=__doc__)
    p.add_argument("log", nargs="?", default=str(TRIAL))
    p.add_argument("--rounds", type=int, default=31)
    args = p.parse_args(argv)
    limit_threads_env(1)
    import imu_dcm.replay.core as core
    from benchmarks.timing import interleaved_medians, single_thread

    real = core.evaluate

    def plain() -> None:
        core.evaluate = lambda *a, **k: None
        try:
            core.replay(args.log)
        finally:
            core.evaluate = real

    def with_stats() -> None:
        core.replay(args.log)

    cases = {"without statistics": (plain, 1), "with statistics": (with_stats, 1)}
    with warnings.catch_warnings(), single_thread():
        warnings.simplefilter("ignore")
        res = interleaved_medians(cases, rounds=args.rounds, warmup=1, clock=time.process_time)
    med = {k: statistics.median(v.times_s) for k, v in res.items()}
    for k, v in med.items():
        print(f"{k:20s} {v * 1e3:8.1f} ms CPU (median of {args.rounds})")
    print(f"ratio                {med['with statistics'] / med['without statistics']:.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

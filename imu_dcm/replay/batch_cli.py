"""Command line: ``python -m imu_dcm.replay batch PATH... --table OUT.csv [--jobs N | --dask A]``.

Replays every log with the same options (those of the single-log command), prints the failed
logs, the files written and the summary line. Exit code 0 when every log replayed, 1 when some
failed (their rows carry the error), 2 for bad input, 130 / 143 when interrupted (the rows
written so far stay in the table: rerun with ``--resume``). Bad input gives one line on stderr.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
import warnings

from imu_dcm.cli import OneLineArgumentParser, end_quietly_on_broken_pipe
from imu_dcm.errors import ImuDcmError, InputError
from imu_dcm.replay.batch import replay_many
from imu_dcm.replay.options import add_replay_options
from imu_dcm.replay.table import LogRow, one_line

PROG = "imu-dcm-replay batch"


def build_parser() -> argparse.ArgumentParser:
    """The parser of ``python -m imu_dcm.replay batch`` (options are checked before any I/O)."""
    p = OneLineArgumentParser(
        prog=PROG,
        description="Replay many gyro logs with the same options, on all cores or on a Dask "
        "cluster, and tabulate one row per log (CSV, markdown, chart). Exit code: 0 all logs "
        "replayed, 1 some failed (their rows say why), 2 bad input.",
    )
    p.add_argument(
        "paths",
        nargs="+",
        metavar="PATH",
        help="a log (bag folder or .mcap), a folder searched for logs, or a .txt "
        "file listing them, one a line",
    )
    p.add_argument(
        "--table",
        required=True,
        metavar="OUT.csv",
        help="CSV table, one row per log, appended as logs finish; OUT.md (markdown "
        "and summary), OUT.png (chart) and OUT.curves.jsonl are written beside it",
    )
    where = p.add_mutually_exclusive_group()
    where.add_argument(
        "--jobs", type=int, metavar="N", help="worker processes (default: the number of cores)"
    )
    where.add_argument(
        "--dask",
        metavar="ADDRESS",
        help="run on a Dask cluster, e.g. tcp://HOST:8786 (workers must see the "
        "logs at the same paths)",
    )
    p.add_argument(
        "--resume",
        action="store_true",
        help="skip logs that already have a row in OUT (failed ones too)",
    )
    p.add_argument(
        "--force",
        action="store_true",
        help="start OUT afresh if it exists (only a table this tool wrote)",
    )
    chart = p.add_mutually_exclusive_group()
    chart.add_argument(
        "--chart",
        metavar="PATH.png",
        help="where to draw the chart (default OUT.png; needs matplotlib)",
    )
    chart.add_argument("--no-chart", action="store_true", help="draw no chart")
    p.add_argument(
        "--compare",
        metavar="M1,M2,...",
        help="one row per log and method: each method or peer (magnus4, trapezoid, end, ..., "
        "vqf, imufusion, ahrs, reference, scipy) integrates the replay's rates from its start, "
        "as the single-log --compare; the rows gain the columns method and ns_per_sample",
    )
    p.add_argument("--quiet", action="store_true", help="print only the summary and errors")
    add_replay_options(p.add_argument_group("replay options (the same for every log)"))
    return p


class _Bar:
    """``logs [#####.....] 3/7, 1 failed, 0:12`` on stderr, only when stderr is a terminal."""

    def __init__(self, stream=None):
        self.stream = stream or sys.stderr
        self.enabled = bool(getattr(self.stream, "isatty", lambda: False)())
        self.t0 = time.monotonic()
        self.failed = 0

    def __call__(self, done: int, total: int, row: LogRow) -> None:
        self.failed += row.failed
        if not self.enabled:
            return
        width = 30
        fill = round(width * done / total)
        s = int(time.monotonic() - self.t0)
        self.stream.write(
            f"\rlogs [{'#' * fill}{'.' * (width - fill)}] {done}/{total}, "
            f"{self.failed} failed, {s // 60}:{s % 60:02d} "
        )
        self.stream.flush()

    def close(self) -> None:
        if self.enabled:
            self.stream.write("\r" + " " * 70 + "\r")
            self.stream.flush()


class _Terminated(BaseException):
    """SIGTERM, raised like KeyboardInterrupt (a per-log ``except Exception`` never eats it)."""


def _on_sigterm(signum, frame):
    raise _Terminated


def _compare(args) -> tuple[str, ...] | None:
    """``--compare``'s names, checked before any I/O (None without it)."""
    if args.compare is None:
        return None
    from imu_dcm.replay.compare import parse_compare

    return parse_compare(args.compare)


def main(argv: list[str] | None = None) -> int:
    """Run the batch command; returns the exit code (0 all replayed, 1 some failed, 2 bad
    input, 130/143 interrupted; rows appended before the interruption are kept)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    message, code = "", 2
    on_main = threading.current_thread() is threading.main_thread()
    old = signal.signal(signal.SIGTERM, _on_sigterm) if on_main else None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            args = build_parser().parse_args(argv)
            if not args.table.endswith(".csv"):
                raise InputError(f"Expected --table ending in .csv, got {args.table!r}")
            from imu_dcm.replay.options import replay_keywords

            options = replay_keywords(args)  # the outputs are claimed by replay_many first
            compare = _compare(args)
            bar = _Bar()
            t0 = time.perf_counter()
            try:
                result = replay_many(
                    args.paths,
                    args.table,
                    jobs=args.jobs,
                    dask=args.dask,
                    resume=args.resume,
                    overwrite=args.force,
                    chart=None if args.no_chart else (args.chart or "auto"),
                    progress=bar,
                    compare=compare,
                    **options,
                )
            finally:
                bar.close()
            code = 1 if result.failed else 0  # kept when the output pipe closes early
            if not args.quiet:
                for r in result.rows:
                    if r.failed and r.method in (None, result.rows[0].method):  # once a log
                        print(f"failed     {r.path}: {r.error}")
                files = [result.table, result.markdown, result.chart]
                print("wrote      " + ", ".join(str(f) for f in files if f is not None))
                if result.resumed and compare:
                    n = result.resumed
                    print(f"resumed    {n} logs ({n * len(compare)} rows) already in the table")
                elif result.resumed:
                    print(f"resumed    {result.resumed} rows already in the table")
                print(f"elapsed    {time.perf_counter() - t0:.2f} s")
            print(result.summary)
        except BrokenPipeError:  # ... | head: the reader had what it wanted
            end_quietly_on_broken_pipe()
        except (ImuDcmError, OSError) as exc:
            message = one_line(str(exc)) or type(exc).__name__
        except SystemExit as exc:  # argparse: --help (0) or a bad option (2), already printed
            code = exc.code if isinstance(exc.code, int) else 2
        except KeyboardInterrupt:
            code, message = 130, "interrupted; the rows written so far are kept (--resume)"
        except _Terminated:
            code, message = 143, "terminated; the rows written so far are kept (--resume)"
        finally:
            if on_main:
                signal.signal(signal.SIGTERM, old)
            for w in caught:
                print(f"{PROG}: warning: {one_line(str(w.message))}", file=sys.stderr)
    if message:
        print(f"{PROG}: error: {message}", file=sys.stderr)
    return code

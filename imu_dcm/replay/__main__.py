"""Command line: ``python -m imu_dcm.replay LOG [options]`` (console script ``imu-dcm-replay``).

Replays a ROS 2 bag / MCAP gyro log through the integrator, prints a summary of the estimate's
error against the log's truth, and optionally writes the estimate as a bag (``--out``), TUM
files for evo (``--export-tum``), the summary as JSON (``--summary-json``) and a rerun view
(``--rerun``). Every option is checked and every output claimed before the log is read
(:mod:`imu_dcm.outputs`: new or this tool's own file, never an input, no link to a file), so a
bad one leaves nothing behind. ``--summary-json -`` puts the JSON alone on stdout and the lines
for people on stderr.
``python -m imu_dcm.replay convert-csv ...`` turns a CSV log into a ROS 2 MCAP bag;
``python -m imu_dcm.replay info LOG`` says what a log holds (:mod:`imu_dcm.replay.info`).

Bad input gives one line on stderr and exit code 2; recoverable oddities are printed as
one-line warnings.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import os
import signal
import sys
import threading
import warnings
from pathlib import Path

from imu_dcm.app.options import OneLineArgumentParser
from imu_dcm.app.pages import command_memory
from imu_dcm.app.progress import Progress
from imu_dcm.app.rerun_mode import check_rerun_mode, rerun_save_path
from imu_dcm.app.run import run_main
from imu_dcm.errors import Diagnostics, ImuDcmError, InputError
from imu_dcm.replay.options import LOG_KINDS, add_replay_options, replay_keywords

# The modules imported inside functions load numpy and the rest of the numerical stack (each
# ~80 ms of CPU on top of --help's ~65 ms; the comparison ~330 ms), which --help and a bad
# option never pay for; or, like imu_dcm.outputs, only the options that write a file need them
# (a plain replay imports no writer: tests/test_replay_imports.py).

PROG = "imu-dcm-replay"


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the replay command (options are checked before any I/O).

    Only argparse is imported to build it: ``--help`` does not load the numerical stack.
    """
    kinds = "; ".join(LOG_KINDS)
    p = OneLineArgumentParser(
        prog=PROG,
        description=f"Replay a recorded gyro log ({kinds}) through the DCM integrator and "
        "compare the estimate with the log's truth. "
        f"Many logs at once: {PROG} batch PATH... --table OUT.csv (see {PROG} batch --help). "
        f"A CSV log: {PROG} convert-csv --help. What a log holds: {PROG} info LOG. "
        f"The gyro's noise parameters: {PROG} noise --help. "
        "Exit codes: 0 done, 2 bad input or options, 130/143 interrupted.",
    )
    p.add_argument("log", help=f"the log: {kinds}")
    add_replay_options(p)
    p.add_argument(
        "--summary-json",
        metavar="PATH",
        help="write the summary as JSON (- for stdout: the summary lines then go to stderr); "
        "an existing file is replaced only when this tool wrote it",
    )
    p.add_argument(
        "--out", metavar="DIR", help="write the estimate as a ROS 2 bag (/estimate/orientation)"
    )
    p.add_argument(
        "--export-tum",
        metavar="DIR",
        help="write DIR/estimate.tum and DIR/truth.tum (t x y z qx qy qz qw) for evo",
    )
    p.add_argument(
        "--compare",
        metavar="M1,M2,...",
        help="also integrate the same rates from the same start with each method or peer "
        "(magnus4, trapezoid, end, ..., vqf, imufusion, ahrs, reference, scipy): a table of "
        "their statistics and cost; with --plot, one figure of every method's error",
    )
    p.add_argument(
        "--noise-params",
        metavar="IMU.yaml",
        help="the gyro's noise (Kalibr keys, as `noise --yaml` writes): print the error "
        "budget, how much of the error the noise and the method explain",
    )
    p.add_argument(
        "--export-csv",
        metavar="FILE",
        help="write one row per estimate sample: stamp, q_w_b (xyzw), the truth where scored "
        "and the errors (deg), each column named with its unit",
    )
    p.add_argument(
        "--plot",
        metavar="FILE",
        help="draw the error over time, the gyro with its rests, the scored segments and the "
        "truth jumps and gaps to FILE.png or FILE.svg (matplotlib)",
    )
    p.add_argument(
        "--force",
        action="store_true",
        help="replace an existing --out bag (only one this tool wrote)",
    )
    p.add_argument(
        "--rerun",
        metavar="MODE",
        help="spawn | serve | save:PATH.rrd | off (default: spawn with a display, else no "
        "view and no file). serve: rerun's web viewer on 127.0.0.1 until Ctrl-C",
    )
    p.add_argument(
        "--keep-viewer",
        action="store_true",
        help="with --rerun serve: leave the web viewer running after the command exits",
    )
    p.add_argument(
        "--realtime", action="store_true", help="pace the rerun view at the recorded speed"
    )
    p.add_argument("--quiet", action="store_true", help="print only warnings and errors")
    return p


def _write_out(out: Path, result, force: bool, inputs: tuple) -> Path:
    """The estimate as a bag, a block of rows at a time (the file order of one block's
    messages in memory, not of the log's)."""
    from imu_dcm.arrays import BLOCK_ROWS
    from imu_dcm.logio.writers import BagBlock, StampedSeries, write_bag_blocks

    filtered = result.summary.prefilter is not None

    def blocks():
        for a in range(result.start_index, len(result.t_ns), BLOCK_ROWS):
            k = slice(a, a + BLOCK_ROWS)
            t = result.t_ns[k]
            vectors = {}
            if filtered:
                vectors["/estimate/angular_velocity"] = StampedSeries(t, result.omega_b[k], "imu")
            yield BagBlock(
                quaternions={"/estimate/orientation": StampedSeries(t, result.q_est[k], "world")},
                vectors=vectors,
            )

    custom = {
        "imu_dcm.source_log": str(result.summary.path),
        "imu_dcm.method": result.summary.method,
        "imu_dcm.bias_mode": result.summary.bias_mode,
        "imu_dcm.gyro.prefilter": result.summary.prefilter or "none",
    }
    return write_bag_blocks(out, blocks(), custom_data=custom, force=force, inputs=inputs)


def _show(result, mode: str | None, realtime: bool, keep: bool, claim=None) -> tuple[str, int]:
    """Hand the replay to the rerun view; returns the line to print and the exit code. ``serve``
    keeps the web viewer up until Ctrl-C (130) or SIGTERM (143), or, with ``keep``, leaves it
    running and says how to stop it. ``claim``: the checked ``save:`` file."""
    from imu_dcm.viz import ViewData, save_rrd, saved_line, serve_replay, show_replay

    view = ViewData(
        t_s=result.t_s,
        q_est=result.q_est,
        q_truth=result.q_truth,
        omega_b=result.omega_b,
        error_total_deg=result.error.total_deg,
        error_inclination_deg=result.error.inclination_deg,
        error_heading_deg=result.error.heading_deg,
        title=Path(str(result.summary.path).rstrip("/")).name,
        omega_raw_b=result.omega_raw_b,
    )
    if claim is not None:
        return saved_line(save_rrd(view, claim)), 0
    if mode != "serve" or keep:
        return show_replay(view, mode, realtime=realtime), 0
    served = serve_replay(view, realtime)
    try:
        signum = _serve_until_stopped(served)
    finally:
        served.stop()
    return "rerun: web viewer stopped", 128 + signum if signum else 0


def _serve_until_stopped(served) -> int:
    """Print the viewer's URL, then wait for Ctrl-C, SIGTERM or the server's own exit; returns
    the signal that ended the wait (0: the server exited), for the exit code 128 + signal."""
    stop = threading.Event()
    got = []
    signals = (signal.SIGINT, signal.SIGTERM)

    def on_signal(signum, frame):
        got.append(signum)
        stop.set()

    old = {sig: signal.signal(sig, on_signal) for sig in signals}
    try:
        print(f"{served.line}; Ctrl-C stops it", flush=True)
        while not stop.wait(0.2) and served.viewer.process.poll() is None:
            pass
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)
    return int(got[0]) if got else 0


def _check_rerun(mode: str | None, inputs: tuple):
    """What --rerun needs, checked before anything is read or written (the mode itself is
    checked by :func:`imu_dcm.app.rerun_mode.check_rerun_mode`): a display for ``spawn``; the
    claimed ``save:`` file (or None)."""
    if mode == "spawn":
        from imu_dcm.viz import has_display

        if not has_display():
            raise InputError(
                "Expected a display (DISPLAY or WAYLAND_DISPLAY) for --rerun spawn, "
                "got none; use --rerun save:PATH.rrd or serve"
            )
    target = rerun_save_path(mode)
    if target is None:
        return None
    from imu_dcm.outputs import claim_output

    return claim_output(target, "rrd", inputs, what="--rerun save:")


def _inputs(log: str) -> tuple[str, ...]:
    """What must survive: the log, and the bag folder around a log file named inside one."""
    parent = os.path.dirname(os.path.abspath(log))
    if os.path.isfile(log) and os.path.isfile(os.path.join(parent, "metadata.yaml")):
        return (log, parent)
    return (log,)


def _distinct_outputs(args) -> None:
    """No output is another output, and nothing is written inside the --out bag folder."""
    named = [("--out", args.out), ("--summary-json", args.summary_json), ("--plot", args.plot)]
    named.append(("--export-csv", args.export_csv))
    if args.export_tum:
        named += [
            ("--export-tum", os.path.join(args.export_tum, f))
            for f in ("estimate.tum", "truth.tum")
        ]
    named.append(("--rerun save:", rerun_save_path(args.rerun)))
    paths = [(flag, Path(os.path.abspath(os.path.realpath(p)))) for flag, p in named if p]
    for i, (fa, a) in enumerate(paths):
        for fb, b in paths[i + 1 :]:
            inside = (fa == "--out" and b.is_relative_to(a)) or (
                fb == "--out" and a.is_relative_to(b)
            )
            if a == b or inside:
                raise InputError(f"Expected {fa} and {fb} to be separate paths, got {a} and {b}")


def _not_a_folder_of_logs(log: str) -> None:
    """A folder that holds logs (not a log itself) is for ``batch``: say so."""
    if not os.path.isdir(log) or os.path.isfile(os.path.join(log, "metadata.yaml")):
        return
    from imu_dcm.replay.batch import find_logs

    found = find_logs([log], diagnostics=Diagnostics())  # what it skips is batch's to say
    if len(found) > 1:  # a folder holding one log file is that log (the reader opens it)
        n = len(found)
        raise InputError(
            f"Expected one log, got a folder of {n} log{'s' if n != 1 else ''} {log!r}; "
            f"replay them all with: {PROG} batch {log} --table OUT.csv"
        )


def _options(args) -> tuple[dict, dict]:
    """Every option parsed and checked, and every output claimed (:mod:`imu_dcm.outputs`),
    before any input is read or output written: the replay's keywords and the claims."""
    keywords = replay_keywords(args)
    args.rerun = check_rerun_mode(args.rerun)  # RERUN=off: no default view; a named one refused
    _not_a_folder_of_logs(args.log)
    inputs = _inputs(args.log)
    _distinct_outputs(args)
    claims = {}
    if args.out:
        from imu_dcm.outputs import check_output_dir

        check_output_dir(args.out, inputs, force=args.force, what="--out bag")
    if args.summary_json:
        from imu_dcm.outputs import claim_output

        claims["summary"] = claim_output(args.summary_json, "json", inputs, what="--summary-json")
    if args.export_tum:
        from imu_dcm.replay.export import claim_export

        claims["tum"] = claim_export(args.export_tum, inputs)
    claims["rrd"] = _check_rerun(args.rerun, inputs)
    _check_view_options(args)
    if args.plot:
        from imu_dcm.replay.plot import check_plot

        claims["plot"] = check_plot(args.plot, inputs)
    if args.export_csv:
        from imu_dcm.replay.export_csv import claim_csv

        claims["csv"] = claim_csv(args.export_csv, inputs)
    if args.noise_params:
        from imu_dcm.replay.budget import read_noise_params

        args.noise_params = read_noise_params(args.noise_params)
    if args.compare is not None:
        from imu_dcm.replay.compare import parse_compare

        args.compare = parse_compare(args.compare)
    return keywords, claims


def _check_view_options(args) -> None:
    """``--keep-viewer`` and ``--realtime`` act only on a view: refused where there is none."""
    mode = args.rerun or "the default (no view without a display)"
    if args.keep_viewer and args.rerun != "serve":
        raise InputError(f"Expected --rerun serve with --keep-viewer, got --rerun {mode}")
    if args.realtime and (args.rerun == "off" or rerun_save_path(args.rerun) is not None):
        raise InputError(
            f"Expected --rerun spawn or serve with --realtime (it paces a view), got --rerun {mode}"
        )


def _replay_main(argv: list[str]) -> int:
    args = build_parser().parse_args(argv)
    options, claims = _options(args)  # every option checked before the log is read
    from imu_dcm.replay.core import replay
    from imu_dcm.replay.summary import format_summary

    inputs = _inputs(args.log)
    progress = Progress()
    try:
        result = replay(args.log, progress=progress, **options)
    finally:
        progress.close()
    written: list[str] = []
    if args.out:
        out = _write_out(Path(args.out), result, args.force, inputs)
        written.append(f"{out} (bag: /estimate/orientation)")
    if args.export_tum:
        from imu_dcm.replay.export import export_tum

        k = slice(result.start_index, None)
        files = export_tum(
            claims["tum"],
            result.t_ns[k],
            result.q_est[k],
            result.q_truth[k] if result.summary.truth_topic else None,
        )
        written += [str(f) for f in files]
    summary_claim = claims.get("summary")
    if summary_claim is not None and summary_claim.stream != "stdout":
        written.append(str(args.summary_json))
    if rerun_save_path(args.rerun) is not None:
        written.append(rerun_save_path(args.rerun))
    lines: list[str] = []  # the evaluations' lines (budget, comparison), after the summary
    extra = _evaluations(result, args, claims, lines)
    written += [str(p) for p in (args.export_csv, args.plot) if p]
    summary = dataclasses.replace(result.summary, written=tuple(written))
    if summary_claim is not None:
        from imu_dcm.outputs import write_json

        write_json(summary_claim, summary.to_dict() | extra, writer="replay summary")
    # the JSON on stdout (--summary-json -): every line for people goes to stderr
    to_stderr = summary_claim is not None and summary_claim.stream == "stdout"
    stream = sys.stderr if to_stderr else sys.stdout
    if not args.quiet:
        print(format_summary(summary), file=stream)
        for line in lines:
            print(line, file=stream)
    if args.rerun == "off":
        return 0
    with contextlib.redirect_stdout(stream):
        line, code = _view(result, args, claims["rrd"])
    if line:
        print(line, file=stream)
    return code


def _view(result, args, claim) -> tuple[str, int]:
    """:func:`_show`, its failures one line: an error when the view was asked for, else a
    warning (the default view is a convenience)."""
    try:
        return _show(result, args.rerun, args.realtime, args.keep_viewer, claim)
    except Exception as exc:
        if isinstance(exc, (ImuDcmError, OSError)) and args.rerun is not None:
            raise  # asked for: a failure is an error (exit 2, one line)
        first = str(exc).splitlines()[0] if str(exc) else ""
        if args.rerun is not None:
            raise ImuDcmError(
                f"Expected the rerun view {args.rerun!r} to work, got {type(exc).__name__}: {first}"
            ) from None
        warnings.warn(f"rerun view skipped: {type(exc).__name__}: {first}", stacklevel=1)
        return "", 0


def _evaluations(result, args, claims: dict, lines: list[str]) -> dict:
    """``--compare``, ``--noise-params``, ``--export-csv`` and ``--plot`` (their outputs claimed
    in ``claims``): their lines go to ``lines``; returns what they add to the summary JSON."""
    from imu_dcm.app.summary import json_ready

    extra = {}
    rows = _compare(result, args, lines)
    if rows is not None:
        from imu_dcm.replay.compare import compare_json

        extra["compare"] = json_ready(compare_json(rows))
    if args.noise_params:
        from imu_dcm.replay.budget import budget, budget_line

        b = budget(result, args.noise_params)
        lines.insert(0, budget_line(b))
        if b is not None:
            extra["budget"] = json_ready(b)
    if args.export_csv:
        from imu_dcm.replay.export_csv import export_csv

        export_csv(claims["csv"], result)  # named on the summary's `written` line
    if args.plot and rows is not None:
        from imu_dcm.replay.plot import plot_compare

        errors = {r.name: r.error.total_deg for r in rows}
        plot_compare(result, errors, claims["plot"])
    elif args.plot:
        from imu_dcm.replay.plot import plot_replay

        plot_replay(result, claims["plot"])
    return extra


def _compare(result, args, lines: list[str]):
    """``--compare``: every named method on the replay's rates; its table goes to ``lines``."""
    if args.compare is None:
        return None
    from imu_dcm.replay.compare import compare_lines, compare_methods

    rows = compare_methods(result, args.compare)
    lines.extend(compare_lines(rows))
    return rows


def _dispatch(argv: list[str]) -> int:
    """The sub-command named first (noise, convert-csv, info), else a replay of one log."""
    if argv and argv[0] == "noise":
        from imu_dcm.replay.noise_cli import noise_main

        return noise_main(argv[1:])
    if argv and argv[0] == "convert-csv":
        from imu_dcm.replay.csv_import import convert_main

        return convert_main(argv[1:])
    if argv and argv[0] == "info":
        from imu_dcm.replay.info import info_main

        return info_main(argv[1:], PROG)
    return _replay_main(argv)


def main(argv: list[str] | None = None) -> int:
    """Run the command; returns the exit code (:mod:`imu_dcm.app.run`: 0 done, 2 bad input or
    options, 130 interrupted; ``batch`` adds 1 for failed logs)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    command_memory()  # ordinary pages, freed memory reused (imu_dcm.app.pages)
    if argv and argv[0] == "batch":
        from imu_dcm.replay import batch_cli

        return batch_cli.main(argv[1:])
    return run_main(PROG, _dispatch, argv)


if __name__ == "__main__":
    sys.exit(main())

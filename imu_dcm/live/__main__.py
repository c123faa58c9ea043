"""Command line: ``python -m imu_dcm.live SOURCE [options]`` (console script ``imu-dcm-live``).

Integrates a live gyro stream as it arrives (Foxglove WebSocket ``ws://HOST:PORT``, UDP lines
``udp://HOST:PORT`` or stdin lines ``-``), shows it in rerun, optionally records it as a ROS 2
bag, and prints a summary when it stops (Ctrl-C, SIGTERM, end of input, lost source).

Exit codes (:mod:`imu_dcm.app.run`): 0 done; 1 no sample received (never connected, or nothing
came); 2 bad input or options (one line on stderr); 130 / 143 stopped by Ctrl-C / SIGTERM (the
summary and the recording are still written).
"""

from __future__ import annotations

import argparse
import sys

from imu_dcm.app.options import OneLineArgumentParser, parse_bias, parse_init_q_w_b
from imu_dcm.app.rerun_mode import check_rerun_mode
from imu_dcm.app.run import EXIT_FAILED, EXIT_INTERRUPTED, EXIT_OK, EXIT_TERMINATED, run_main
from imu_dcm.integrator.methods import METHODS

PROG = "imu-dcm-live"


def build_parser() -> argparse.ArgumentParser:
    """The argument parser (options are checked before any I/O)."""
    p = OneLineArgumentParser(
        prog=PROG,
        description="Integrate a live gyro stream with the DCM integrator as it arrives, show it "
        "in rerun, record it, and print a summary on Ctrl-C / SIGTERM / end of input. Exit "
        "codes: 0 done, 1 no sample received, 2 bad input or options, 130/143 stopped by "
        "Ctrl-C/SIGTERM.",
    )
    p.add_argument(
        "source",
        help="ws://HOST:PORT (Foxglove WebSocket, e.g. foxglove_bridge), "
        "udp://HOST:PORT (lines), - (lines on stdin), or mavlink:CONNECTION "
        "(pymavlink's: mavlink:udpin:HOST:PORT, mavlink:tcp:HOST:PORT, ...; "
        "?raw_gyro_scale=RAD_S_PER_COUNT for RAW_IMU)",
    )
    _add_input_options(p)
    _add_output_options(p)
    _add_stop_options(p)
    return p


def _add_input_options(p) -> None:
    """What the stream is and how it is integrated."""
    p.add_argument("--imu-topic", help="IMU channel (default: the one Imu-typed channel)")
    p.add_argument(
        "--truth-topic", help="truth channel (default: by type, as replay; 'none' to ignore truth)"
    )
    p.add_argument(
        "--method",
        choices=METHODS,
        default="magnus4",
        help="integrator increment (default magnus4)",
    )
    p.add_argument(
        "--bias",
        default="auto",
        help="gyro bias: auto (from rest as it happens, default), none, or x,y,z rad/s "
        "(negative numbers as they are: --bias -0.01,0,0)",
    )
    p.add_argument(
        "--gyro-units",
        choices=("rad/s", "deg/s"),
        default="rad/s",
        help="unit of the incoming rates (default rad/s)",
    )
    p.add_argument(
        "--time-units",
        "--time-unit",
        dest="time_units",
        choices=("s", "ms", "us", "ns"),
        default="s",
        help="unit of CSV line stamps (default s; --time-unit is the same)",
    )
    p.add_argument(
        "--init-quat",
        dest="init_q_w_b",
        metavar="X,Y,Z,W",
        help="start attitude q_world_body (scalar last) instead of the truth",
    )
    p.add_argument(
        "--reorder-window",
        type=float,
        default=50.0,
        metavar="MS",
        help="reorder window in source time, ms (default 50); later samples are "
        "dropped and counted",
    )


def _add_output_options(p) -> None:
    """The view, the recording and the summary file."""
    p.add_argument(
        "--view-interval",
        type=float,
        metavar="MS",
        help="wake up and send the view and the recording in batches every MS ms (default 50 "
        "with a view, 250 without: each wake-up costs CPU)",
    )
    p.add_argument(
        "--rerun",
        metavar="MODE",
        help="spawn | serve | save:PATH.rrd | off (default: spawn with a display, else no "
        "view). serve: rerun's web viewer on 127.0.0.1, stopped at exit",
    )
    p.add_argument(
        "--keep-viewer",
        action="store_true",
        help="with --rerun serve: leave the web viewer running after the command exits",
    )
    p.add_argument("--record", metavar="DIR", help="record as a ROS 2 bag as it goes")
    p.add_argument(
        "--force",
        action="store_true",
        help="replace an existing --record bag (only one this tool wrote)",
    )
    p.add_argument(
        "--summary-json",
        metavar="PATH",
        help="write the summary as JSON at stop (- for stdout: the summary lines then go to "
        "stderr)",
    )


def _add_stop_options(p) -> None:
    """When the run ends, and what it prints."""
    p.add_argument(
        "--give-up",
        type=float,
        default=30.0,
        metavar="S",
        help="WebSocket: stop after S s without a connection (default 30)",
    )
    p.add_argument(
        "--idle-stop",
        type=float,
        metavar="S",
        help="stop after S s without a sample (default: never)",
    )
    p.add_argument("--no-status", action="store_true", help="no status line on stderr")
    p.add_argument("--quiet", action="store_true", help="print no summary")


def _fmt(x: float | None, unit: str = "°") -> str:
    if x is None:
        return "n/a"
    return f"{x:.2f}{unit}" if x == 0.0 or abs(x) >= 0.01 else f"{x:.2g}{unit}"


def format_summary(s: dict) -> str:
    """The summary for a person, one fact per line (the layout replay prints)."""
    rate = f"{s['rate_hz']:.1f} Hz" if s["rate_hz"] else "n/a"
    imu = s["imu_topic"] or "no IMU channel"
    if s["imu_type"]:
        imu += f" ({s['imu_type']})"
    lines = [
        f"source     {s['source']}",
        (
            f"imu        {imu}: {s['samples']} samples, "
            f"{s['duration_s']:.3f} s, {rate}, units {s['gyro_units']}"
        ),
    ]
    if s["truth_topic"]:
        kind = f" ({s['truth_type']})" if s["truth_type"] else ""
        lines.append(
            f"truth      {s['truth_topic']}{kind}: {s['truth_samples_used']} estimates compared"
        )
    else:
        lines.append("truth      none (no error can be measured)")
    gaps = s.get("gap_count", len(s["gaps"]))
    lines.append(
        f"dropped    {s['dropped_nonfinite']} NaN/Inf, {s['dropped_implausible']} implausible, "
        f"{s['dropped_duplicate']} duplicate, "
        f"{s['dropped_backward']} late/backward stamps, {s['malformed']} malformed; "
        f"{s['reordered']} put back in order; {gaps} gap{'s' if gaps != 1 else ''} over "
        f"5x the median step; {s['reconnects']} reconnects"
        + (f"; {s['lost_by_system']} datagrams lost by the system" if s["lost_by_system"] else "")
    )
    import numpy as np

    b = np.asarray(s["bias_rad_s"])
    bias = f"({b[0]:+.5f}, {b[1]:+.5f}, {b[2]:+.5f}) rad/s"
    if s["bias_mode"] == "auto" and not s["bias_segments"]:
        lines.append("bias       auto: no rest segment found, no bias removed")
    elif s["bias_mode"] == "auto":
        n = len(s["bias_segments"])
        unused = sum(1 for x in s["bias_segments"] if not x.get("used", True))
        bd = np.degrees(b)
        lines.append(
            f"bias       auto: {n} rest segment{'s' if n != 1 else ''}"
            + (f" ({unused} not used)" if unused else "")
            + f", mean applied {bias} = ({bd[0]:+.3f}, {bd[1]:+.3f}, {bd[2]:+.3f}) °/s"
        )
        agreement = s.get("rest_agreement")
        if agreement and agreement["line"]:
            lines.append("rests      " + agreement["line"])
    else:
        lines.append(f"bias       {s['bias_mode']}: {bias}")
    if s["start_time_s"] is None:
        lines.append(f"method     {s['method']}; no estimate (no sample was integrated)")
    else:
        lines.append(f"method     {s['method']}; estimate from t = {s['start_time_s']:.3f} s")
    if s["final_q_w_b"] is not None:
        q = ", ".join(f"{v:+.6f}" for v in s["final_q_w_b"])
        lines.append(f"final      q_w_b [x, y, z, w] = [{q}] at t = {s['final_t_s']:.3f} s")
    if s["rms_error_deg"] is not None:
        lines.append(
            f"error      total RMS {_fmt(s['rms_error_deg'])}, max "
            f"{_fmt(s['max_error_deg'])}; inclination RMS "
            f"{_fmt(s['rms_inclination_deg'])}, max {_fmt(s['max_inclination_deg'])}; "
            f"heading RMS {_fmt(s['rms_heading_deg'])}, max "
            f"{_fmt(s['max_heading_deg'])}"
        )
    if s["latency_p50_ms"] is not None:
        lines.append(
            f"latency    receive -> view: p50 {s['latency_p50_ms']:.1f} ms, "
            f"p99 {s['latency_p99_ms']:.1f} ms"
        )
    if s["record"]:
        lines.append(f"record     {s['record']}")
    lines.append(f"stopped    {s['stopped']}")
    lines.append(f"elapsed    {s['elapsed_s']:.3f} s")
    return "\n".join(lines)


def exit_code(summary: dict) -> int:
    """The exit code of a run that ended (module doc)."""
    if summary["stopped"] == "stopped by SIGINT":
        return EXIT_INTERRUPTED
    if summary["stopped"] == "stopped by SIGTERM":
        return EXIT_TERMINATED
    return EXIT_OK if summary["samples"] else EXIT_FAILED


def _main(argv: list[str]) -> int:
    args = build_parser().parse_args(argv)
    from imu_dcm.live.session import run
    from imu_dcm.live.sources import parse_source
    from imu_dcm.outputs import writes_to_stdout

    parse_source(args.source)
    rerun = check_rerun_mode(args.rerun)  # RERUN=off: no default view; a named one refused
    bias = parse_bias(args.bias)
    result = run(
        args.source,
        imu_topic=args.imu_topic,
        truth_topic=args.truth_topic,
        method=args.method,
        bias=bias,
        gyro_units=args.gyro_units,
        time_units=args.time_units,
        init_q_w_b=parse_init_q_w_b(args.init_q_w_b),
        reorder_window_s=args.reorder_window * 1e-3,
        view_interval_s=None if args.view_interval is None else args.view_interval * 1e-3,
        rerun=rerun,
        keep_viewer=args.keep_viewer,
        record=args.record,
        force=args.force,
        summary_json=args.summary_json,
        give_up_s=args.give_up,
        idle_stop_s=args.idle_stop,
        status=not args.no_status,
    )
    code = exit_code(result.summary)
    if not args.quiet:  # the JSON on stdout (--summary-json -): the lines for people on stderr
        out = sys.stderr if writes_to_stdout(args.summary_json) else sys.stdout
        print(format_summary(result.summary), file=out, flush=True)
    if code == EXIT_FAILED:
        print(f"{PROG}: no sample received ({result.summary['stopped']})", file=sys.stderr)
    return code


def main(argv: list[str] | None = None) -> int:
    """Run the command; returns the exit code (module doc)."""
    return run_main(PROG, _main, argv)


if __name__ == "__main__":
    sys.exit(main())

"""Command line: ``python -m imu_dcm.live SOURCE [options]`` (console script ``imu-dcm-live``).

Integrates a live gyro stream as it arrives (Foxglove WebSocket ``ws://HOST:PORT``, UDP lines
``udp://HOST:PORT`` or stdin lines ``-``), shows it in rerun, optionally records it as a ROS 2
bag, and prints a summary when it stops (Ctrl-C, SIGTERM, end of input, lost source).

Bad input gives one line on stderr and exit code 2.
"""

from __future__ import annotations

import argparse
import sys
import warnings

import numpy as np

from imu_dcm.cli import OneLineArgumentParser
from imu_dcm.errors import ImuDcmError
from imu_dcm.integrate import METHODS

PROG = "imu-dcm-live"


def build_parser() -> argparse.ArgumentParser:
    """The argument parser (options are checked before any I/O)."""
    p = OneLineArgumentParser(
        prog=PROG,
        description="Integrate a live gyro stream with the DCM integrator as it arrives, show it "
        "in rerun, record it, and print a summary on Ctrl-C / SIGTERM / end of input.",
    )
    p.add_argument(
        "source",
        help="ws://HOST:PORT (Foxglove WebSocket, e.g. foxglove_bridge), "
        "udp://HOST:PORT (lines) or - (lines on stdin)",
    )
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
        help="gyro bias: auto (from rest as it happens, default), none, or x,y,z rad/s",
    )
    p.add_argument(
        "--gyro-units",
        choices=("rad/s", "deg/s"),
        default="rad/s",
        help="unit of the incoming rates (default rad/s)",
    )
    p.add_argument(
        "--time-units",
        choices=("s", "ms", "us", "ns"),
        default="s",
        help="unit of CSV line stamps (default s)",
    )
    p.add_argument(
        "--init-quat",
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
    p.add_argument(
        "--view-interval",
        type=float,
        default=50.0,
        metavar="MS",
        help="send the view and the recording in batches every MS ms (default 50; "
        "each rerun send_columns call costs ~0.5 ms)",
    )
    p.add_argument(
        "--rerun",
        metavar="MODE",
        help="spawn | serve | save:PATH.rrd | off (default: spawn with a display, "
        "else serve the web viewer on 127.0.0.1)",
    )
    p.add_argument("--record", metavar="DIR", help="record as a ROS 2 bag as it goes")
    p.add_argument("--force", action="store_true", help="replace an existing --record bag")
    p.add_argument("--summary-json", metavar="PATH", help="write the summary as JSON at stop")
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
    return p


def _fmt(x: float | None, unit: str = "°") -> str:
    if x is None:
        return "n/a"
    return f"{x:.2f}{unit}" if x == 0.0 or abs(x) >= 0.01 else f"{x:.2g}{unit}"


def format_summary(s: dict) -> str:
    """The summary for a person, one fact per line (the layout replay prints)."""
    rate = f"{s['rate_hz']:.1f} Hz" if s["rate_hz"] else "n/a"
    lines = [
        f"source     {s['source']}",
        (
            f"imu        {s['imu_topic']} ({s['imu_type']}): {s['samples']} samples, "
            f"{s['duration_s']:.3f} s, {rate}, units {s['gyro_units']}"
        ),
    ]
    if s["truth_topic"]:
        lines.append(
            f"truth      {s['truth_topic']} ({s['truth_type']}): "
            f"{s['truth_samples_used']} estimates compared"
        )
    else:
        lines.append("truth      none (no error can be measured)")
    gaps = len(s["gaps"])
    lines.append(
        f"dropped    {s['dropped_nonfinite']} NaN/Inf, {s['dropped_duplicate']} duplicate, "
        f"{s['dropped_backward']} late/backward stamps, {s['malformed']} malformed; "
        f"{s['reordered']} put back in order; {gaps} gap{'s' if gaps != 1 else ''} over "
        f"5x the median step; {s['reconnects']} reconnects"
    )
    b = np.asarray(s["bias_rad_s"])
    bias = f"({b[0]:+.5f}, {b[1]:+.5f}, {b[2]:+.5f}) rad/s"
    if s["bias_mode"] == "auto" and not s["bias_segments"]:
        lines.append("bias       auto: no rest segment found, no bias removed")
    elif s["bias_mode"] == "auto":
        n = len(s["bias_segments"])
        bd = np.degrees(b)
        lines.append(
            f"bias       auto: {n} rest segment{'s' if n != 1 else ''}, mean applied "
            f"{bias} = ({bd[0]:+.3f}, {bd[1]:+.3f}, {bd[2]:+.3f}) °/s"
        )
    else:
        lines.append(f"bias       {s['bias_mode']}: {bias}")
    start = "never started" if s["start_time_s"] is None else f"t = {s['start_time_s']:.3f} s"
    lines.append(f"method     {s['method']}; estimate from {start}")
    if s["final_quat_xyzw"] is not None:
        q = ", ".join(f"{v:+.6f}" for v in s["final_quat_xyzw"])
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


def _main(argv: list[str]) -> int:
    args = build_parser().parse_args(argv)
    from imu_dcm.live.session import run
    from imu_dcm.live.sources import parse_source
    from imu_dcm.live.view import check_mode

    parse_source(args.source)
    check_mode(args.rerun)
    result = run(
        args.source,
        imu_topic=args.imu_topic,
        truth_topic=args.truth_topic,
        method=args.method,
        bias=args.bias,
        gyro_units=args.gyro_units,
        time_units=args.time_units,
        init_quat=args.init_quat,
        reorder_window_s=args.reorder_window * 1e-3,
        view_interval_s=args.view_interval * 1e-3,
        rerun=args.rerun,
        record=args.record,
        force=args.force,
        summary_json=args.summary_json,
        give_up_s=args.give_up,
        idle_stop_s=args.idle_stop,
        status=not args.no_status,
    )
    if not args.quiet:
        print(format_summary(result.summary), flush=True)
    return 0


def main(argv: list[str] | None = None) -> int:
    """Run the command; returns the exit code (0 fine, 2 bad input)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    message = ""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            code = _main(argv)
        except (ImuDcmError, FileExistsError) as exc:
            code = 2
            message = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else 2
        except KeyboardInterrupt:
            code, message = 130, "interrupted"
        finally:
            for w in caught:
                print(f"{PROG}: warning: {str(w.message).splitlines()[0]}", file=sys.stderr)
    if message:
        print(f"{PROG}: error: {message}", file=sys.stderr)
    return code


if __name__ == "__main__":
    sys.exit(main())

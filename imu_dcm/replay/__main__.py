"""Command line: ``python -m imu_dcm.replay LOG [options]`` (console script ``imu-dcm-replay``).

Replays a ROS 2 bag / MCAP gyro log through the integrator, prints a summary of the estimate's
error against the log's truth, and optionally writes the estimate as a bag (``--out``), TUM
files for evo (``--export-tum``), the summary as JSON (``--summary-json``) and a rerun view
(``--rerun``). Every option and output path is checked before the log is read, so a bad one
leaves nothing behind; no output may be, hold or lie inside the input.
``python -m imu_dcm.replay convert-csv ...`` turns a CSV log into a ROS 2 MCAP bag.

Bad input gives one line on stderr and exit code 2; recoverable oddities are printed as
one-line warnings.
"""

from __future__ import annotations

import argparse
import os
import sys
import warnings
from pathlib import Path

from imu_dcm.cli import OneLineArgumentParser, Progress, parse_numbers

PROG = "imu-dcm-replay"
TIME_BASES = ("auto", "header", "log")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the replay command (options are checked before any I/O).

    Only argparse is imported to build it: ``--help`` does not load the numerical stack.
    """
    p = OneLineArgumentParser(
        prog=PROG,
        description="Replay a recorded gyro log (ROS 2 bag folder or .mcap) through the DCM "
        "integrator and compare the estimate with the log's truth. "
        f"See also: {PROG} convert-csv --help",
    )
    p.add_argument("log", help="ROS 2 bag folder (metadata.yaml + .mcap) or a .mcap file")
    add_replay_options(p)
    p.add_argument("--summary-json", metavar="PATH", help="write the summary as JSON")
    p.add_argument(
        "--out", metavar="DIR", help="write the estimate as a ROS 2 bag (/estimate/orientation)"
    )
    p.add_argument(
        "--export-tum",
        metavar="DIR",
        help="write DIR/estimate.tum and DIR/truth.tum (t x y z qx qy qz qw) for evo",
    )
    p.add_argument(
        "--force",
        action="store_true",
        help="replace an existing --out bag (only one this tool wrote)",
    )
    p.add_argument(
        "--rerun",
        metavar="MODE",
        help="spawn | serve | save:PATH.rrd | off (default: spawn with a display, "
        "else save next to the output)",
    )
    p.add_argument(
        "--realtime", action="store_true", help="pace the rerun view at the recorded speed"
    )
    p.add_argument("--quiet", action="store_true", help="print only warnings and errors")
    return p


def add_replay_options(g) -> None:
    """The options that choose how one log is replayed (shared by ``replay`` and ``batch``)."""
    g.add_argument("--imu-topic", help="IMU channel (default: the one Imu-typed channel)")
    g.add_argument(
        "--truth-topic",
        help="truth channel (QuaternionStamped, PoseStamped, ...; the IMU topic for "
        "its own orientation; 'none' to ignore truth). Named here, it is scored even "
        "when its rate does not follow the gyro",
    )
    g.add_argument(
        "--truth-frame",
        metavar="CHILD",
        help="child frame of a /tf truth, where several frames move",
    )
    g.add_argument(
        "--truth-offset",
        default="0",
        metavar="auto|SECONDS",
        help="shift added to the truth stamps: seconds (default 0) or auto (the "
        "shift that best aligns the truth's rotation rate with the gyro's)",
    )
    g.add_argument(
        "--time",
        choices=TIME_BASES,
        default="auto",
        help="stamps: auto (default: header stamps unless they are all equal, not "
        "increasing or miss the truth while log times overlap it), header, or log",
    )
    g.add_argument(
        "--method",
        default="magnus4",
        metavar="METHOD",
        help="integrator increment (default magnus4; one of imu_dcm.METHODS)",
    )
    g.add_argument(
        "--bias",
        default="auto",
        help="gyro bias: auto (from rest segments, default), none, or x,y,z in rad/s",
    )
    g.add_argument(
        "--gyro-units",
        choices=("rad/s", "deg/s"),
        default="rad/s",
        help="unit of the log's angular velocity (default rad/s)",
    )
    g.add_argument(
        "--init-quat",
        metavar="X,Y,Z,W",
        help="initial q_world_body (scalar last) when the log has no truth",
    )
    g.add_argument(
        "--prefilter",
        choices=("none", "kalman", "rts"),
        default="none",
        help="gyro pre-filter: Kalman filter or RTS smoother (default none)",
    )
    g.add_argument(
        "--gyro-noise-density",
        type=float,
        metavar="RAD_S_SQRT_HZ",
        help="pre-filter: gyro white-noise density, rad/s/√Hz (default: from rest)",
    )
    g.add_argument(
        "--angular-accel",
        type=float,
        metavar="RAD_S2",
        help="pre-filter: angular-acceleration scale, rad/s² (default: fitted)",
    )


def _write_out(out: Path, result, force: bool, inputs: tuple) -> Path:
    from imu_dcm.logio.writer import StampedSeries, write_bag

    k = slice(result.start_index, None)
    quats = {"/estimate/orientation": StampedSeries(result.t_ns[k], result.q_est[k], "world")}
    vectors = {}
    if result.summary.prefilter is not None:
        vectors["/estimate/angular_velocity"] = StampedSeries(
            result.t_ns[k], result.omega_b[k], "imu"
        )
    custom = {
        "imu_dcm.source_log": str(result.summary.path),
        "imu_dcm.method": result.summary.method,
        "imu_dcm.bias_mode": result.summary.bias_mode,
        "imu_dcm.prefilter": result.summary.prefilter or "none",
    }
    return write_bag(
        out, quaternions=quats, vectors=vectors, custom_data=custom, force=force, inputs=inputs
    )


def _show(result, mode: str | None, realtime: bool, save_dir: Path) -> str:
    """Hand the replay to the rerun view."""
    from imu_dcm.viz import ViewData, show_replay

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
    return show_replay(view, mode, save_dir, realtime=realtime)


def _check_rerun(mode: str | None, inputs: tuple) -> None:
    """Validate --rerun before anything is read or written."""
    from imu_dcm.errors import InputError
    from imu_dcm.outputs import check_output_file

    if mode is None or mode in ("off", "serve"):
        return
    if mode == "spawn":
        from imu_dcm.viz import has_display

        if not has_display():
            raise InputError(
                "Expected a display (DISPLAY or WAYLAND_DISPLAY) for --rerun spawn, "
                "got none; use --rerun save:PATH.rrd or serve"
            )
        return
    if mode.startswith("save:"):
        target = mode[len("save:") :]
        if not target.endswith(".rrd") or len(target) <= len(".rrd"):
            raise InputError(f"Expected --rerun save:PATH.rrd, got {mode!r}")
        check_output_file(target, inputs, "--rerun save: file")
        return
    raise InputError(f"Expected --rerun spawn, serve, save:PATH.rrd or off, got {mode!r}")


def _inputs(log: str) -> tuple[str, ...]:
    """What must survive: the log, and the bag folder around a log file named inside one."""
    parent = os.path.dirname(os.path.abspath(log))
    if os.path.isfile(log) and os.path.isfile(os.path.join(parent, "metadata.yaml")):
        return (log, parent)
    return (log,)


def _distinct_outputs(args) -> None:
    """No output is another output, and nothing is written inside the --out bag folder."""
    from imu_dcm.errors import InputError

    named = [("--out", args.out), ("--summary-json", args.summary_json)]
    if args.export_tum:
        named += [
            ("--export-tum", os.path.join(args.export_tum, f))
            for f in ("estimate.tum", "truth.tum")
        ]
    if args.rerun and args.rerun.startswith("save:"):
        named.append(("--rerun save:", args.rerun[len("save:") :]))
    paths = [(flag, Path(os.path.abspath(os.path.realpath(p)))) for flag, p in named if p]
    for i, (fa, a) in enumerate(paths):
        for fb, b in paths[i + 1 :]:
            inside = (fa == "--out" and b.is_relative_to(a)) or (
                fb == "--out" and a.is_relative_to(b)
            )
            if a == b or inside:
                raise InputError(f"Expected {fa} and {fb} to be separate paths, got {a} and {b}")


def replay_keywords(args) -> dict:
    """The keywords of :func:`imu_dcm.replay.replay` from :func:`add_replay_options`' options,
    parsed and checked (string parsing lives here, not in the library)."""
    from imu_dcm.errors import InputError
    from imu_dcm.integrate import METHODS

    if args.method not in METHODS:
        build_parser().error(
            f"argument --method: invalid choice: {args.method!r} (choose from {', '.join(METHODS)})"
        )
    bias = args.bias
    if bias not in ("auto", "none"):
        bias = parse_numbers(bias, 3, "bias (rad/s)")
    init = None
    if args.init_quat is not None:
        init = parse_numbers(args.init_quat, 4, "init quaternion x,y,z,w")
        if sum(v * v for v in init) < 1e-12:
            raise InputError(f"Expected a non-zero init quaternion x,y,z,w, got {args.init_quat!r}")
    offset: float | str = args.truth_offset
    if offset != "auto":
        offset = parse_numbers(offset, 1, "--truth-offset (auto or seconds)")[0]
    config = None
    if args.prefilter != "none":
        from imu_dcm.prefilter import PrefilterConfig

        config = PrefilterConfig(
            noise_density_rad_s_sqrt_hz=args.gyro_noise_density,
            angular_accel_rad_s2=args.angular_accel,
        )
    elif args.gyro_noise_density is not None or args.angular_accel is not None:
        raise InputError(
            "Expected --prefilter kalman or rts with --gyro-noise-density / "
            "--angular-accel, got --prefilter none"
        )
    return {
        "imu_topic": args.imu_topic,
        "truth_topic": args.truth_topic,
        "truth_frame": args.truth_frame,
        "time": args.time,
        "method": args.method,
        "bias": bias,
        "gyro_units": args.gyro_units,
        "init_q_w_b": init,
        "prefilter": None if args.prefilter == "none" else args.prefilter,
        "prefilter_config": config,
        "truth_offset_s": offset,
    }


def _options(args) -> dict:
    """Every option parsed and checked, before any input is read or output written."""
    from imu_dcm.outputs import check_output_dir, check_output_file

    keywords = replay_keywords(args)
    inputs = _inputs(args.log)
    _distinct_outputs(args)
    if args.out:
        check_output_dir(args.out, inputs, force=args.force, what="--out bag")
    if args.summary_json:
        check_output_file(args.summary_json, inputs, "--summary-json file")
    if args.export_tum:
        from imu_dcm.replay.export import check_export_dir

        check_export_dir(args.export_tum, inputs)
    _check_rerun(args.rerun, inputs)
    return keywords


def _replay_main(argv: list[str]) -> int:
    args = build_parser().parse_args(argv)
    options = _options(args)  # every option checked before the log is read
    import json

    from imu_dcm.errors import ImuDcmError
    from imu_dcm.outputs import write_text_atomic
    from imu_dcm.replay.core import replay
    from imu_dcm.replay.summary import format_summary

    inputs = _inputs(args.log)
    progress = Progress()
    try:
        result = replay(args.log, progress=progress, **options)
    finally:
        progress.close()
    lines = []
    if args.out:
        out = _write_out(Path(args.out), result, args.force, inputs)
        lines.append(f"out        {out} (/estimate/orientation)")
    if args.export_tum:
        from imu_dcm.replay.export import export_tum

        k = slice(result.start_index, None)
        files = export_tum(
            args.export_tum,
            result.t_ns[k],
            result.q_est[k],
            result.q_truth[k] if result.summary.truth_topic else None,
            inputs,
        )
        lines.append(f"tum        {', '.join(str(f) for f in files)}")
    if args.summary_json:
        text = json.dumps(result.summary.to_dict(), indent=2, allow_nan=False) + "\n"
        write_text_atomic(args.summary_json, text, inputs)
    if not args.quiet:
        print(format_summary(result.summary))
        for line in lines:
            print(line)
    if args.rerun != "off":
        save_dir = Path(args.out).resolve().parent if args.out else Path.cwd()
        try:
            line = _show(result, args.rerun, args.realtime, save_dir)
        except Exception as exc:
            if isinstance(exc, (ImuDcmError, OSError)) and args.rerun is not None:
                raise  # asked for: a failure is an error (exit 2, one line)
            first = str(exc).splitlines()[0] if str(exc) else ""
            if args.rerun is not None:
                raise ImuDcmError(
                    f"Expected the rerun view {args.rerun!r} to work, got "
                    f"{type(exc).__name__}: {first}"
                ) from None
            warnings.warn(f"rerun view skipped: {type(exc).__name__}: {first}", stacklevel=1)
            line = ""
        if line:
            print(line)
    return 0


def _message(exc: BaseException) -> str:
    text = str(exc).splitlines()[0] if str(exc) else ""
    if isinstance(exc, OSError):
        where = f" {exc.filename!r}" if exc.filename else ""
        return (
            f"Expected a readable input and writable outputs, got {type(exc).__name__}: "
            f"{exc.strerror or text}{where}"
        )
    return text or type(exc).__name__


def main(argv: list[str] | None = None) -> int:
    """Run the command; returns the exit code (0 fine, 2 bad input)."""
    from imu_dcm.errors import ImuDcmError

    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == "batch":
        from imu_dcm.replay import batch_cli

        return batch_cli.main(argv[1:])
    message = ""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            if argv and argv[0] == "convert-csv":
                from imu_dcm.replay.csv_import import convert_main

                code = convert_main(argv[1:])
            else:
                code = _replay_main(argv)
        except (ImuDcmError, OSError) as exc:
            code, message = 2, _message(exc)
        except SystemExit as exc:  # argparse: --help (0) or a bad option (2), already printed
            code = exc.code if isinstance(exc.code, int) else 2
        except KeyboardInterrupt:
            code, message = 130, "interrupted"
        finally:
            for w in caught:
                text = str(w.message).splitlines()[0]
                print(f"{PROG}: warning: {text}", file=sys.stderr)
    if message:
        print(f"{PROG}: error: {message}", file=sys.stderr)
    return code


if __name__ == "__main__":
    sys.exit(main())

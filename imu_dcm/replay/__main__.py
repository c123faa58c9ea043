"""Command line: ``python -m imu_dcm.replay LOG [options]`` (console script ``imu-dcm-replay``).

Replays a ROS 2 bag / MCAP gyro log through the integrator, prints a summary of the estimate's
error against the log's truth, and optionally writes the estimate as a bag (``--out``), the
summary as JSON (``--summary-json``) and a rerun view (``--rerun``).
``python -m imu_dcm.replay convert-csv ...`` turns a CSV log into a ROS 2 MCAP bag.

Bad input gives one line on stderr and exit code 2; recoverable oddities are printed as
one-line warnings.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

from imu_dcm.cli import OneLineArgumentParser
from imu_dcm.errors import ImuDcmError
from imu_dcm.integrate import METHODS

PROG = "imu-dcm-replay"


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the replay command (options are checked before any I/O)."""
    p = OneLineArgumentParser(
        prog=PROG,
        description="Replay a recorded gyro log (ROS 2 bag folder or .mcap) through the DCM "
        "integrator and compare the estimate with the log's truth. "
        f"See also: {PROG} convert-csv --help",
    )
    p.add_argument("log", help="ROS 2 bag folder (metadata.yaml + .mcap) or a .mcap file")
    p.add_argument("--imu-topic", help="IMU channel (default: the one Imu-typed channel)")
    p.add_argument("--truth-topic",
                   help="truth channel (QuaternionStamped, PoseStamped, ...; the IMU topic for "
                   "its own orientation; 'none' to ignore truth)")  # fmt: skip
    p.add_argument("--time", choices=("header", "log"), default="header",
                   help="stamps from header.stamp (default) or MCAP log time")  # fmt: skip
    p.add_argument("--method", choices=METHODS, default="magnus4",
                   help="integrator increment (default magnus4)")  # fmt: skip
    p.add_argument("--bias", default="auto",
                   help="gyro bias: auto (from rest segments, default), none, or x,y,z in rad/s")
    p.add_argument("--gyro-units", choices=("rad/s", "deg/s"), default="rad/s",
                   help="unit of the log's angular velocity (default rad/s)")  # fmt: skip
    p.add_argument("--init-quat", metavar="X,Y,Z,W",
                   help="initial q_world_body (scalar last) when the log has no truth")
    p.add_argument("--prefilter", choices=("none", "kalman", "rts"), default="none",
                   help="gyro pre-filter: Kalman filter or RTS smoother (default none)")
    p.add_argument("--gyro-noise-density", type=float, metavar="RAD_S_SQRT_HZ",
                   help="pre-filter: gyro white-noise density, rad/s/√Hz (default: from rest)")
    p.add_argument("--angular-accel", type=float, metavar="RAD_S2",
                   help="pre-filter: angular-acceleration scale, rad/s² (default: fitted)")
    p.add_argument("--summary-json", metavar="PATH", help="write the summary as JSON")
    p.add_argument("--out", metavar="DIR",
                   help="write the estimate as a ROS 2 bag (/estimate/orientation)")
    p.add_argument("--force", action="store_true", help="replace an existing --out bag")
    p.add_argument("--rerun", metavar="MODE",
                   help="spawn | serve | save:PATH.rrd | off (default: spawn with a display, "
                   "else save next to the output)")  # fmt: skip
    p.add_argument("--realtime", action="store_true",
                   help="pace the rerun view at the recorded speed")
    p.add_argument("--quiet", action="store_true", help="print only warnings and errors")
    return p


class Progress:
    """A plain-text progress line on stderr, drawn only when stderr is a terminal and only once
    the replay has run for ``delay_s`` (short replays print nothing)."""

    def __init__(self, stream=None, min_interval_s: float = 0.1, delay_s: float = 0.5):
        self.stream = stream or sys.stderr
        self.enabled = bool(getattr(self.stream, "isatty", lambda: False)())
        self.min_interval_s = min_interval_s
        self._start = time.monotonic()
        self.delay_s = delay_s
        self._last = 0.0
        self._drawn = False

    def __call__(self, stage: str, fraction: float) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if now - self._start < self.delay_s:
            return
        if fraction < 1.0 and now - self._last < self.min_interval_s:
            return
        self._last = now
        width = 30
        filled = round(width * min(max(fraction, 0.0), 1.0))
        self.stream.write(f"\r{stage:<10} [{'#' * filled}{'.' * (width - filled)}] "
                          f"{100 * fraction:5.1f}%")  # fmt: skip
        self.stream.flush()
        self._drawn = True

    def close(self) -> None:
        if self._drawn:
            self.stream.write("\r" + " " * 60 + "\r")
            self.stream.flush()


def _fmt(x: float | None, unit: str = "°") -> str:
    """Two decimals, or two significant digits below 0.01 (so 1.2e-05° does not read as 0.00°)."""
    if x is None:
        return "n/a"
    return f"{x:.2f}{unit}" if x == 0.0 or abs(x) >= 0.01 else f"{x:.2g}{unit}"


def format_summary(s: dict) -> str:
    """The summary for a person, one fact per line."""
    rate = f"{s['rate_hz']:.1f} Hz"
    lines = [
        f"log        {s['log']}",
        (f"imu        {s['imu_topic']} ({s['imu_type']}): {s['samples']} samples, "
        f"{s['duration_s']:.3f} s, {rate}, units {s['gyro_units']}"),
    ]
    if s["truth_topic"]:
        lines.append(f"truth      {s['truth_topic']} ({s['truth_type']}): "
                     f"{s['truth_samples_used']} gyro samples inside its coverage")  # fmt: skip
    else:
        lines.append("truth      none (no error can be measured)")
    gaps = len(s["gaps"])
    lines.append(f"dropped    {s['dropped_nonfinite']} NaN/Inf, {s['dropped_nonincreasing']} "
                 f"duplicate/backward stamps; {gaps} gap{'s' if gaps != 1 else ''} over "
                 f"5x the median step")  # fmt: skip
    b = np.asarray(s["bias_rad_s"])
    bias = f"({b[0]:+.5f}, {b[1]:+.5f}, {b[2]:+.5f}) rad/s"
    bdeg = np.degrees(b)
    if s["bias_mode"] == "auto" and not s["bias_segments"]:
        lines.append("bias       auto: no rest segment found, no bias removed")
    elif s["bias_mode"] == "auto":
        nseg = len(s["bias_segments"])
        lines.append(f"bias       auto: {nseg} rest segment{'s' if nseg != 1 else ''}, mean "
                     f"{bias} = ({bdeg[0]:+.3f}, {bdeg[1]:+.3f}, {bdeg[2]:+.3f}) °/s")  # fmt: skip
    else:
        lines.append(f"bias       {s['bias_mode']}: {bias}")
    pf = "" if s["prefilter"] == "none" else f", pre-filter {s['prefilter']}"
    lines.append(f"method     {s['method']}{pf}; estimate from t = {s['start_time_s']:.3f} s")
    if s["rms_error_deg"] is not None:
        lines.append(f"error      total RMS {_fmt(s['rms_error_deg'])}, max "
                     f"{_fmt(s['max_error_deg'])}; inclination RMS "
                     f"{_fmt(s['rms_inclination_deg'])}, max {_fmt(s['max_inclination_deg'])}; "
                     f"heading RMS {_fmt(s['rms_heading_deg'])}, max "
                     f"{_fmt(s['max_heading_deg'])}")  # fmt: skip
    if s.get("stopped_at"):
        lines.append(f"stopped    {s['stopped_at']}")
    lines.append(f"elapsed    {s['elapsed_s']:.3f} s")
    return "\n".join(lines)


def _json_default(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer, np.bool_)):
        return o.item()
    if isinstance(o, Path):
        return str(o)
    return repr(o)


def _write_json_atomic(path: Path, data: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w") as f:
            json.dump(data, f, indent=2, default=_json_default)
            f.write("\n")
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _write_out(out: Path, result, force: bool) -> Path:
    from imu_dcm.bag_writer import StampedSeries, write_bag

    k = slice(result.start_index, None)
    quats = {"/estimate/orientation": StampedSeries(result.t_ns[k], result.q_est[k], "world")}
    vectors = {}
    if result.summary["prefilter"] != "none":
        vectors["/estimate/angular_velocity"] = StampedSeries(result.t_ns[k], result.omega_b[k],
                                                              "imu")  # fmt: skip
    custom = {
        "imu_dcm.source_log": str(result.summary["log"]),
        "imu_dcm.method": result.summary["method"],
        "imu_dcm.bias_mode": result.summary["bias_mode"],
        "imu_dcm.prefilter": result.summary["prefilter"],
    }
    return write_bag(out, quaternions=quats, vectors=vectors, custom_data=custom, force=force)


def _show(result, args, save_dir: Path) -> str:
    """Hand the replay to the rerun view; a broken viewer never breaks the replay."""
    try:
        from imu_dcm.viz import ViewData, show_replay
    except ImportError as exc:
        return f"rerun view skipped: imu_dcm.viz is not available ({exc})"
    view = ViewData(
        t_s=result.t_s,
        q_est=result.q_est,
        q_truth=result.q_truth,
        omega_b=result.omega_b,
        error_total_deg=result.error.total_deg,
        error_inclination_deg=result.error.inclination_deg,
        error_heading_deg=result.error.heading_deg,
        title=Path(str(result.summary["log"]).rstrip("/")).name,
        omega_raw_b=result.omega_raw_b,
    )
    return show_replay(view, args.rerun, save_dir, realtime=args.realtime)


def _replay_main(argv: list[str]) -> int:
    args = build_parser().parse_args(argv)
    from imu_dcm.replay.core import replay

    log = Path(args.log)
    if args.out and log.exists() and Path(args.out).resolve() == log.resolve():
        raise ImuDcmError(f"Expected --out different from the input log, got {args.out}")
    if args.summary_json and log.exists() and Path(args.summary_json).resolve() == log.resolve():
        raise ImuDcmError(f"Expected --summary-json different from the input, got {log}")
    if args.rerun is not None and not (args.rerun in ("spawn", "serve", "off")
                                       or args.rerun.startswith("save:")):  # fmt: skip
        raise ImuDcmError(f"Expected --rerun spawn, serve, save:PATH.rrd or off, "
                          f"got {args.rerun!r}")  # fmt: skip
    config = None
    if args.prefilter != "none":
        from imu_dcm.prefilter import PrefilterConfig

        config = PrefilterConfig(noise_density_rad_s_sqrt_hz=args.gyro_noise_density,
                                 angular_accel_rad_s2=args.angular_accel)  # fmt: skip
    elif args.gyro_noise_density is not None or args.angular_accel is not None:
        raise ImuDcmError("Expected --prefilter kalman or rts with --gyro-noise-density / "
                          "--angular-accel, got --prefilter none")  # fmt: skip
    progress = Progress()
    try:
        result = replay(
            args.log,
            imu_topic=args.imu_topic,
            truth_topic=args.truth_topic,
            time=args.time,
            method=args.method,
            bias=args.bias,
            gyro_units=args.gyro_units,
            init_quat=args.init_quat,
            prefilter=args.prefilter,
            prefilter_config=config,
            progress=progress,
        )
    finally:
        progress.close()
    if args.out:
        out = _write_out(Path(args.out), result, args.force)
        result.summary["out"] = str(out)
    if not args.quiet:
        print(format_summary(result.summary))
        if args.out:
            print(f"out        {args.out} (/estimate/orientation)")
    if args.summary_json:
        _write_json_atomic(Path(args.summary_json), result.summary)
    if args.rerun != "off":
        save_dir = Path(args.out).resolve().parent if args.out else Path.cwd()
        try:
            line = _show(result, args, save_dir)
        except ImuDcmError:
            raise
        except Exception as exc:  # noqa: BLE001 - the view is optional: never lose the replay
            line = f"rerun view failed: {type(exc).__name__}: {exc}"
        if line:
            print(line)
    return 0


def main(argv: list[str] | None = None) -> int:
    """Run the command; returns the exit code (0 fine, 2 bad input)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == "batch":
        from imu_dcm.replay import batch

        return batch.main(argv[1:])
    message = ""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            if argv and argv[0] == "convert-csv":
                from imu_dcm.replay.csv_import import convert_main

                code = convert_main(argv[1:])
            else:
                code = _replay_main(argv)
        except (ImuDcmError, FileExistsError) as exc:
            code = 2
            message = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
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

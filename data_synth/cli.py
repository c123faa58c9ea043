"""Command line: simulate a scene, sample it with a synthetic gyro, write a ROS 2 bag (MCAP).

``python -m data_synth SCENE [options] --rate HZ --duration S --out DIR``

SCENE is ``heavy-top``, ``free-body`` or ``coning`` (see :mod:`data_synth.scenes`). The bag holds

* ``/imu/data`` ``sensor_msgs/msg/Imu``: the gyro output as ``angular_velocity`` (rad/s, body
  axes, frame ``imu``); for ``--gyro-output delta-angle`` the mean rate ``Δθ_k / Δt_k`` over
  ``(t_{k−1}, t_k]``, stamped ``t_k``; ``orientation_covariance[0] = −1`` and
  ``linear_acceleration_covariance[0] = −1`` (not measured);
* ``/ground_truth/orientation`` ``geometry_msgs/msg/QuaternionStamped``: true ``q_w_b``
  ``[x, y, z, w]`` (frame ``world``), at every sample instant (for delta angles also at ``t_0``);
* ``/ground_truth/angular_velocity`` ``geometry_msgs/msg/Vector3Stamped``: true ``omega_b``,
  rad/s (frame ``imu``), at the same instants.

Stamps are ``--epoch-ns + round(t_s · 1e9)``. The scene, every parameter, the gyro model and the
command line are recorded in ``metadata.yaml`` ``custom_data`` under keys ``data_synth.*``. A bad
option or value prints one line and exits with status 2; the output folder appears whole or not
at all and is not overwritten without ``--force``.
"""

from __future__ import annotations

import argparse
import json
import math
import shlex
import sys
from pathlib import Path

import numpy as np

from data_synth.gyro import DEFAULT_EPOCH_NS, OUTPUTS, GyroModel, synthetic_gyro
from data_synth.scenes import BRANCHES, FREE_BODY_CASES, MOTIONS, simulate
from imu_dcm.bag_writer import StampedSeries, write_bag
from imu_dcm.cli import OneLineArgumentParser
from imu_dcm.errors import ImuDcmError, InputError, LogError

__all__ = ["build_parser", "main", "make_log"]

PROG = "python -m data_synth"


def _number(bound: str):
    """argparse type: a finite float, with ``bound`` one of ``"> 0"``, ``">= 0"`` or ``""``."""
    def parse(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        ok = math.isfinite(v) and {"> 0": v > 0, ">= 0": v >= 0}.get(bound, True)
        if not ok:
            raise argparse.ArgumentTypeError(
                f"expected a finite number{' ' + bound if bound else ''}, got {text!r}")
        return v

    return parse


_positive, _non_negative, _finite = _number("> 0"), _number(">= 0"), _number("")


def _vector3(text: str) -> tuple[float, float, float]:
    parts = text.split(",")
    try:
        v = tuple(float(x) for x in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected x,y,z numbers, got {text!r}") from None
    if len(v) != 3 or not all(math.isfinite(x) for x in v):
        raise argparse.ArgumentTypeError(f"expected three finite numbers x,y,z, got {text!r}")
    return v  # type: ignore[return-value]


def _add_common(p: argparse.ArgumentParser, scheme: bool) -> None:
    g = p.add_argument_group("sampling and output")
    g.add_argument("--rate", type=_positive, required=True, metavar="HZ",
                   help="gyro sample rate, Hz")
    g.add_argument("--duration", type=_positive, required=True, metavar="S",
                   help="length of the log, s")
    g.add_argument("--out", type=Path, required=True, metavar="DIR",
                   help="bag folder to create (rosbag2, MCAP storage)")
    g.add_argument("--force", action="store_true", help="replace an existing DIR")
    g.add_argument("--epoch-ns", type=int, default=DEFAULT_EPOCH_NS, metavar="NS",
                   help=f"stamp of t = 0, ns since the Unix epoch (default {DEFAULT_EPOCH_NS})")
    if scheme:
        g.add_argument("--scheme", choices=("exact", "reference"), default="exact",
                       help="truth: exact (DOP853 1e-12, default) or the reference document's "
                            "coupled RK4 + DCM scheme stepped at --rate")
    m = p.add_argument_group("gyro model (each term off unless given)")
    m.add_argument("--gyro-output", choices=OUTPUTS, default="rate",
                   help="rate: omega_b(t_k) (default); delta-angle: exact integral over each "
                        "interval, written as its mean rate")
    m.add_argument("--gyro-noise-density", type=_non_negative, metavar="RAD_S_SQRT_HZ",
                   help="white rate noise density, rad/s/sqrt(Hz)")
    m.add_argument("--gyro-bias", type=_vector3, metavar="X,Y,Z",
                   help="constant bias, rad/s (write --gyro-bias=-x,y,z when x < 0)")
    m.add_argument("--gyro-bias-walk", type=_non_negative, metavar="RAD_S2_SQRT_HZ",
                   help="bias random walk density, rad/s^2/sqrt(Hz)")
    m.add_argument("--gyro-quantization", type=_positive, metavar="RAD_S",
                   help="output step, rad/s")
    m.add_argument("--gyro-range", type=_positive, metavar="RAD_S",
                   help="full-scale range, rad/s (saturates)")
    m.add_argument("--stamp-jitter", type=_non_negative, metavar="S",
                   help="standard deviation of the sample instants about the grid, s")
    m.add_argument("--seed", type=int, default=0, help="seed of the random terms (default 0)")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser (sub-commands ``heavy-top``, ``free-body``, ``coning``)."""
    ap = OneLineArgumentParser(prog=PROG, description="Simulate a rigid body, sample it with a "
                        "synthetic gyro and write a ROS 2 bag (MCAP) with its ground truth.")
    sub = ap.add_subparsers(dest="scene", required=True, metavar="SCENE",
                            parser_class=OneLineArgumentParser)
    top = sub.add_parser("heavy-top", help="the reference document's heavy symmetric top")
    top.add_argument("--motion", choices=MOTIONS, default="cusp",
                     help="initial precession rate: cusp (0), wavy (+1/2 slow steady), looping "
                          "(-1/2 slow steady), steady, sleeping (tilt 0)")
    top.add_argument("--branch", choices=BRANCHES, default="slow",
                     help="steady precession root (default slow)")
    top.add_argument("--tilt-deg", type=_non_negative, metavar="DEG",
                     help="initial tilt from the vertical, deg (default 54.57)")
    top.add_argument("--spin-hz", type=_positive, metavar="HZ",
                     help="spin omega_3 / 2 pi, Hz (default 20)")
    _add_common(top, scheme=True)
    fb = sub.add_parser("free-body", help="the second reference document's torque-free box")
    fb.add_argument("--case", choices=FREE_BODY_CASES, default="diagonal",
                    help="omega_b(0) = (1,1,1)/sqrt(3) rad/s (diagonal) or (0.05, 3, 0.05) "
                         "(intermediate: flips)")
    fb.add_argument("--omega", type=_vector3, metavar="X,Y,Z",
                    help="initial body rate, rad/s (overrides --case; --omega=-x,y,z when x < 0)")
    _add_common(fb, scheme=False)
    co = sub.add_parser("coning", help="pure coning, closed form")
    co.add_argument("--half-angle-deg", type=_non_negative, default=10.0, metavar="DEG",
                    help="cone half-angle, deg (default 10)")
    co.add_argument("--freq-hz", type=_finite, default=5.0, metavar="HZ",
                    help="coning frequency, Hz (default 5)")
    _add_common(co, scheme=False)
    return ap


def _scene_params(args: argparse.Namespace) -> dict:
    if args.scene == "heavy-top":
        kw = {"motion": args.motion, "branch": args.branch}
        if args.tilt_deg is not None:
            kw["tilt_deg"] = args.tilt_deg
        if args.spin_hz is not None:
            kw["spin_hz"] = args.spin_hz
        return kw
    if args.scene == "free-body":
        kw = {"case": args.case}
        if args.omega is not None:
            kw["omega0_b"] = args.omega
        return kw
    return {"half_angle_deg": args.half_angle_deg, "freq_hz": args.freq_hz}


def make_log(args: argparse.Namespace, argv: list[str]) -> Path:
    """Simulate, sample and write the bag described by parsed ``args``; return its folder."""
    out = Path(args.out)
    if out.exists() and not args.force:  # fail before simulating
        raise LogError(f"Expected output {str(out)!r} not to exist (use --force), got an "
                          f"existing {'folder' if out.is_dir() else 'file'}")
    model = GyroModel(
        noise_density_rad_s_sqrt_hz=args.gyro_noise_density,
        bias_rad_s=args.gyro_bias,
        bias_walk_rad_s2_sqrt_hz=args.gyro_bias_walk,
        quantization_rad_s=args.gyro_quantization,
        range_rad_s=args.gyro_range,
        stamp_jitter_s=args.stamp_jitter,
    )
    params = _scene_params(args)
    scheme = getattr(args, "scheme", "exact")
    if scheme == "reference":
        from data_synth.reference_scheme import SampledTrajectory, reference_top

        if args.gyro_output != "rate" or args.stamp_jitter:
            raise InputError("Expected --gyro-output rate and no --stamp-jitter with --scheme "
                              "reference (it exists only on its own time grid), got "
                              f"--gyro-output {args.gyro_output}, --stamp-jitter "
                              f"{args.stamp_jitter}")
        run = reference_top(args.duration, args.rate, **params)
        traj = SampledTrajectory(run, args.rate)
    else:
        traj = simulate(args.scene, args.duration, **params)
    rec = synthetic_gyro(traj, args.rate, args.duration, model, output=args.gyro_output,
                         seed=args.seed, epoch_ns=args.epoch_ns)
    if args.gyro_output == "rate":
        t_truth_s, t_truth_ns = rec.t_s, rec.t_ns
        rates = rec.values
    else:
        t_truth_s = np.concatenate([[0.0], rec.t_s])
        t_truth_ns = np.concatenate([[args.epoch_ns], rec.t_ns])
        rates = rec.rate_rad_s(0.0)
    q_true, w_true = traj.at(t_truth_s)
    custom = {
        "data_synth.scene": traj.scene,
        "data_synth.scheme": scheme,
        "data_synth.params": json.dumps(traj.params, sort_keys=True),
        "data_synth.gyro.output": args.gyro_output,
        "data_synth.gyro.rate_hz": repr(float(args.rate)),
        "data_synth.gyro.model": json.dumps(model.as_dict(), sort_keys=True),
        "data_synth.gyro.seed": str(args.seed),
        "data_synth.duration_s": repr(float(args.duration)),
        "data_synth.epoch_ns": str(args.epoch_ns),
        "data_synth.frames": "q_w_b [x,y,z,w] body to world (world ENU, z up); omega_b rad/s "
                             "body axes; /imu/data frame 'imu' = body",
        "data_synth.command": "python -m data_synth " + shlex.join(argv),
    }
    if args.gyro_output == "delta-angle":
        custom["data_synth.gyro.note"] = ("angular_velocity = delta angle / interval: mean "
                                          "rate over (t_k-1, t_k], stamped t_k")
    out.parent.mkdir(parents=True, exist_ok=True)  # e.g. --out out/top in a fresh checkout
    return write_bag(
        out,
        imu=StampedSeries(rec.t_ns, rates, "imu"),
        quaternions={"/ground_truth/orientation": StampedSeries(t_truth_ns, q_true, "world")},
        vectors={"/ground_truth/angular_velocity": StampedSeries(t_truth_ns, w_true, "imu")},
        custom_data=custom,
        force=args.force,
    )


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit status (0 ok, 2 bad option, value or existing output)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    try:
        out = make_log(args, argv)
    except ImuDcmError as exc:  # bad value or existing output: one line, status 2
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        print(f"{PROG}: error: {msg}", file=sys.stderr)
        return 2
    except OSError as exc:  # the file system refused: one line, status 1
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return 1
    print(out)
    return 0

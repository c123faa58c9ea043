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
at all and is not overwritten without ``--force`` (which replaces only a bag data_synth wrote).
A job estimated to need more than ``--max-memory-gib`` (2) or ``--max-minutes`` (30) is refused
before it starts, with the estimate (:mod:`data_synth.budget`).
"""

from __future__ import annotations

import argparse
import json
import math
import shlex
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from data_synth import budget
from data_synth.gyro import (
    DEFAULT_EPOCH_NS,
    MAX_STAMP_NS,
    OUTPUTS,
    GyroModel,
    sample_count,
    synthetic_gyro_blocks,
)
from data_synth.scenes import BRANCHES, FREE_BODY_CASES, MOTIONS, simulate
from imu_dcm.app.options import OneLineArgumentParser, prog_name
from imu_dcm.app.pages import command_memory
from imu_dcm.app.run import run_main
from imu_dcm.arrays import BLOCK_ROWS
from imu_dcm.errors import InputError
from imu_dcm.logio.writers import BagBlock, StampedSeries, write_bag_blocks
from imu_dcm.outputs import check_output_dir

__all__ = ["build_parser", "main", "make_log"]

PROG = prog_name("data-synth", "python -m data_synth")
#: A long job says how far it is on stderr at most this often, s.
PROGRESS_EVERY_S = 5.0


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
                f"expected a finite number{' ' + bound if bound else ''}, got {text!r}"
            )
        return v

    return parse


_positive, _non_negative, _finite = _number("> 0"), _number(">= 0"), _number("")


def _integer(lo: int, hi: int | None = None):
    """argparse type: an integer in ``[lo, hi)`` (``hi`` None: no upper bound)."""

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if v < lo or (hi is not None and v >= hi):
            span = f">= {lo}" if hi is None else f"in [{lo}, {hi})"
            raise argparse.ArgumentTypeError(f"expected an integer {span}, got {text!r}")
        return v

    return parse


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
    """The options every scene shares: sampling, output, budget, and the gyro model."""
    g = p.add_argument_group("sampling and output")
    g.add_argument(
        "--rate", type=_positive, required=True, metavar="HZ", help="gyro sample rate, Hz"
    )
    g.add_argument(
        "--duration", type=_positive, required=True, metavar="S", help="length of the log, s"
    )
    g.add_argument(
        "--out",
        type=Path,
        required=True,
        metavar="DIR",
        help="bag folder to create (rosbag2, MCAP storage)",
    )
    g.add_argument("--force", action="store_true", help="replace an existing DIR")
    g.add_argument(
        "--epoch-ns",
        type=_integer(0, MAX_STAMP_NS),
        default=DEFAULT_EPOCH_NS,
        metavar="NS",
        help=f"stamp of t = 0, ns since the Unix epoch (default "
        f"{DEFAULT_EPOCH_NS}; stamps must stay below 2^31 s: header.stamp.sec is int32)",
    )
    g.add_argument(
        "--max-memory-gib",
        type=_positive,
        default=2.0,
        metavar="GIB",
        help="refuse a job estimated to need more memory, GiB (default 2)",
    )
    g.add_argument(
        "--max-minutes",
        type=_positive,
        default=30.0,
        metavar="MIN",
        help="refuse a job estimated to run longer, minutes (default 30)",
    )
    if scheme:
        g.add_argument(
            "--scheme",
            choices=("exact", "reference"),
            default="exact",
            help="truth: exact (DOP853 1e-12, default) or the coupled RK4 + DCM "
            "scheme of Xiaoliang (2014) stepped at --rate",
        )
    _add_gyro_model(p.add_argument_group("gyro model (each term off unless given)"))


def _add_gyro_model(m) -> None:
    """The synthetic gyro's error terms (:class:`data_synth.gyro.GyroModel`)."""
    m.add_argument(
        "--gyro-output",
        choices=OUTPUTS,
        default="rate",
        help="rate: omega_b(t_k) (default); delta-angle: exact integral over each "
        "interval, written as its mean rate",
    )
    m.add_argument(
        "--gyro-noise-density",
        type=_non_negative,
        metavar="RAD_S_SQRT_HZ",
        help="white rate noise density, rad/s/sqrt(Hz)",
    )
    m.add_argument(
        "--gyro-bias",
        type=_vector3,
        metavar="X,Y,Z",
        help="constant bias, rad/s (negative numbers as they are: --gyro-bias -0.01,0,0)",
    )
    m.add_argument(
        "--gyro-bias-walk",
        type=_non_negative,
        metavar="RAD_S2_SQRT_HZ",
        help="bias random walk density, rad/s^2/sqrt(Hz)",
    )
    m.add_argument(
        "--gyro-quantization", type=_positive, metavar="RAD_S", help="output step, rad/s"
    )
    m.add_argument(
        "--gyro-range", type=_positive, metavar="RAD_S", help="full-scale range, rad/s (saturates)"
    )
    m.add_argument(
        "--stamp-jitter",
        type=_non_negative,
        metavar="S",
        help="standard deviation of the sample instants about the grid, s",
    )
    m.add_argument(
        "--seed",
        type=_integer(0),
        default=0,
        help="seed of the random terms, an integer >= 0 (default 0)",
    )


def build_parser() -> argparse.ArgumentParser:
    """The argument parser (sub-commands ``heavy-top``, ``free-body``, ``coning``)."""
    ap = OneLineArgumentParser(
        prog=PROG,
        description="Simulate a rigid body, sample it with a "
        "synthetic gyro and write a ROS 2 bag (MCAP) with its ground truth.",
    )
    sub = ap.add_subparsers(
        dest="scene", required=True, metavar="SCENE", parser_class=OneLineArgumentParser
    )
    top = sub.add_parser("heavy-top", help="the heavy symmetric top of Xiaoliang (2014)")
    top.add_argument(
        "--motion",
        choices=MOTIONS,
        default="cusp",
        help="initial precession rate: cusp (0), wavy (+1/2 slow steady), looping "
        "(-1/2 slow steady), steady, sleeping (tilt 0)",
    )
    top.add_argument(
        "--branch", choices=BRANCHES, default="slow", help="steady precession root (default slow)"
    )
    top.add_argument(
        "--tilt-deg",
        type=_non_negative,
        metavar="DEG",
        help="initial tilt from the vertical, deg (default 54.57)",
    )
    top.add_argument(
        "--spin-hz", type=_positive, metavar="HZ", help="spin omega_3 / 2 pi, Hz (default 20)"
    )
    _add_common(top, scheme=True)
    fb = sub.add_parser("free-body", help="the torque-free box of Shuijing (n.d.)")
    fb.add_argument(
        "--case",
        choices=FREE_BODY_CASES,
        default="diagonal",
        help="omega_b(0) = (1,1,1)/sqrt(3) rad/s (diagonal) or (0.05, 3, 0.05) "
        "(intermediate: flips)",
    )
    fb.add_argument(
        "--omega",
        type=_vector3,
        metavar="X,Y,Z",
        help="initial body rate, rad/s (overrides --case)",
    )
    _add_common(fb, scheme=False)
    co = sub.add_parser("coning", help="pure coning, closed form")
    co.add_argument(
        "--half-angle-deg",
        type=_non_negative,
        default=10.0,
        metavar="DEG",
        help="cone half-angle, deg (default 10)",
    )
    co.add_argument(
        "--freq-hz",
        type=_finite,
        default=5.0,
        metavar="HZ",
        help="coning frequency, Hz (default 5)",
    )
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


def _refuse(args: argparse.Namespace, est: budget.JobEstimate, what: str) -> budget.JobTooLarge:
    return budget.JobTooLarge(
        f"Expected a job within {args.max_memory_gib:g} GiB and {args.max_minutes:g} min "
        f"(--max-memory-gib, --max-minutes), got an estimated "
        f"{budget.format_bytes(est.memory_bytes)} and {budget.format_seconds(est.seconds)} for "
        f"{what}"
    )


def _budget_steps(args: argparse.Namespace, est: budget.JobEstimate, per_step_s: float) -> float:
    """ODE steps left in the budget after the samples."""
    mem = (args.max_memory_gib * 2.0**30 - est.memory_bytes) / budget.BYTES_PER_STEP
    return max(0.0, min(mem, (args.max_minutes * 60.0 - est.seconds) / per_step_s))


def _sample_cost(args: argparse.Namespace) -> budget.JobEstimate:
    """Cost of the samples alone (refused before anything is simulated): one block's memory,
    time and disk space that grow with the samples (the reference scheme also keeps its run)."""
    n = sample_count(args.rate, args.duration)
    memory = min(n, BLOCK_ROWS) * budget.BYTES_PER_BLOCK_ROW
    est = budget.JobEstimate(n, 0.0, memory, n * budget.SECONDS_PER_SAMPLE)
    if getattr(args, "scheme", "exact") == "reference":  # a Python RK4 step per sample
        est = budget.JobEstimate(
            n,
            n,
            est.memory_bytes + n * budget.BYTES_PER_REFERENCE_STEP,
            est.seconds + n * budget.SECONDS_PER_REFERENCE_STEP,
        )
    if est.memory_bytes > args.max_memory_gib * 2.0**30 or est.seconds > args.max_minutes * 60:
        raise _refuse(
            args, est, f"{n:.3g} samples (--rate {args.rate:g} Hz x --duration {args.duration:g} s)"
        )
    disk = n * budget.DISK_BYTES_PER_SAMPLE
    free = budget.free_bytes(Path(args.out))
    if free is not None and disk > free:
        raise budget.JobTooLarge(
            f"Expected room for the bag on disk, got an estimated {budget.format_bytes(disk)} "
            f"for {n:.3g} samples and {budget.format_bytes(free)} free where --out "
            f"{str(args.out)!r} goes"
        )
    return est


def _check_values(args: argparse.Namespace) -> None:
    """Checks that need two options together (each option alone is checked by argparse)."""
    last_s = args.epoch_ns * 1e-9 + args.duration
    if (
        last_s >= MAX_STAMP_NS * 1e-9
        or args.epoch_ns + math.ceil(args.duration * 1e9) >= MAX_STAMP_NS
    ):
        raise InputError(
            f"Expected --epoch-ns + --duration below 2^31 s (header.stamp.sec is an "
            f"int32), got stamps up to {last_s:.10g} s"
        )


def _trajectory(args: argparse.Namespace, est: budget.JobEstimate, params: dict, scheme: str):
    """The scene's motion: the reference scheme, coning's closed form, or the ODE within the
    budget left after the samples."""
    if scheme == "reference":
        from data_synth.reference_scheme import SampledTrajectory, reference_top

        if args.gyro_output != "rate" or args.stamp_jitter:
            raise InputError(
                "Expected --gyro-output rate and no --stamp-jitter with --scheme "
                "reference (it exists only on its own time grid), got "
                f"--gyro-output {args.gyro_output}, --stamp-jitter "
                f"{args.stamp_jitter}"
            )
        run = reference_top(args.duration, args.rate, **params)
        traj = SampledTrajectory(run, args.rate)
    elif args.scene == "coning":  # closed form: the samples are the whole cost
        traj = simulate(args.scene, args.duration, **params)
    else:
        max_steps = _budget_steps(args, est, budget.SECONDS_PER_STEP)
        try:
            traj = simulate(args.scene, args.duration, max_steps=max_steps, **params)
        except budget.JobTooLarge as exc:
            steps = getattr(exc, "steps", math.inf)
            total = budget.JobEstimate(
                est.samples,
                steps,
                est.memory_bytes + steps * budget.BYTES_PER_STEP,
                est.seconds + steps * budget.SECONDS_PER_STEP,
            )
            raise _refuse(
                args,
                total,
                f"{steps:.3g} ODE steps (the motion over --duration "
                f"{args.duration:g} s) and {est.samples:.3g} "
                f"samples",
            ) from None
    return traj


def _custom_data(args: argparse.Namespace, argv: list[str], traj, model, scheme: str) -> dict:
    """``metadata.yaml`` ``custom_data``: the scene, its parameters, the gyro model, the command."""
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
        custom["data_synth.gyro.note"] = (
            "angular_velocity = delta angle / interval: mean rate over (t_k-1, t_k], stamped t_k"
        )
    return custom


def make_log(args: argparse.Namespace, argv: list[str]) -> Path:
    """Simulate, sample and write the bag described by parsed ``args``; return its folder.

    Every check runs before the simulation (options, output, estimated memory and time). The
    bag is written a block of samples at a time under a temporary name and appears when it is
    complete (:func:`imu_dcm.logio.writers.write_bag_blocks`): memory holds one block and the
    motion's solution, not the log.
    """
    out = Path(args.out)
    _check_values(args)
    check_output_dir(out, (), force=args.force, what="--out bag", writer=PROG)  # before simulating
    est = _sample_cost(args)
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
    traj = _trajectory(args, est, params, scheme)
    custom = _custom_data(args, argv, traj, model, scheme)
    return write_bag_blocks(out, _blocks(args, traj, model), custom_data=custom, force=args.force)


def _blocks(args: argparse.Namespace, traj, model: GyroModel) -> Iterator[BagBlock]:
    """The bag a block of samples at a time (:func:`data_synth.gyro.synthetic_gyro_blocks`):
    the gyro, and the truth sampled at the same instants (for delta angles also at ``t_0``)."""
    blocks = synthetic_gyro_blocks(
        traj,
        args.rate,
        args.duration,
        model,
        output=args.gyro_output,
        seed=args.seed,
        epoch_ns=args.epoch_ns,
    )
    n = sample_count(args.rate, args.duration)
    done, shown = 0, time.monotonic()
    for k, rec in enumerate(blocks):
        t_truth_s, t_truth_ns = rec.t_s, rec.t_ns
        if args.gyro_output == "delta-angle" and k == 0:  # the first interval's start
            t_truth_s = np.concatenate([[0.0], rec.t_s])
            t_truth_ns = np.concatenate([[args.epoch_ns], rec.t_ns])
        q_true, w_true = traj.at(t_truth_s)
        yield BagBlock(
            imu=StampedSeries(rec.t_ns, rec.rate_rad_s(), "imu"),
            quaternions={"/ground_truth/orientation": StampedSeries(t_truth_ns, q_true, "world")},
            vectors={"/ground_truth/angular_velocity": StampedSeries(t_truth_ns, w_true, "imu")},
        )
        done += len(rec.t_s)
        if time.monotonic() - shown > PROGRESS_EVERY_S and done < n:
            shown = time.monotonic()
            print(f"{PROG}: {done / n:.0%} of {n} samples written", file=sys.stderr, flush=True)


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit status (:mod:`imu_dcm.app.run`: 0 ok; 2 bad option or value,
    a job too large, an existing output or a file-system error; 130 interrupted). A bad option
    ends in ``SystemExit`` (argparse's, status 2), before the work starts."""
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    command_memory()  # ordinary pages, freed memory reused (imu_dcm.app.pages)

    def work(_: list[str]) -> int:
        print(make_log(args, argv))
        return 0

    return run_main(PROG, work, argv)

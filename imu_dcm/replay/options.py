"""The options of :func:`imu_dcm.replay.replay`: the command-line options shared by ``replay``
and ``replay batch`` (:func:`add_replay_options`, parsed once by :func:`replay_keywords`), and the
library's check of typed values (:func:`check_options`).

Text such as ``"x,y,z"`` is parsed by the command line only (:mod:`imu_dcm.app.options`); the
library takes numbers, and checks the bias and the start attitude as live does
(:mod:`imu_dcm.app.checks`). Only argparse and the numpy-free :mod:`imu_dcm.integrator.methods` are
imported at module level, so ``--help`` stays fast.
"""

from __future__ import annotations

import math

from imu_dcm.app.options import parse_bias, parse_init_q_w_b, parse_mounting, parse_numbers
from imu_dcm.errors import InputError
from imu_dcm.integrator.methods import METHODS

__all__ = [
    "GYRO_UNITS",
    "LOG_KINDS",
    "PREFILTERS",
    "TIME_BASES",
    "add_replay_options",
    "check_options",
    "replay_keywords",
]

#: What the replay reads, in words for --help (static: --help does not import the readers). One
#: entry per row of the reader table (imu_dcm.logio.registry.READERS): add one with a new reader
#: (tests/test_first_run.py checks that every row is named here).
LOG_KINDS = [
    "a ROS 2 bag folder (metadata.yaml with .mcap or .db3 storage)",
    "a .mcap file",
    "a ROS 2 .db3 (sqlite3) file",
    "a zstd-compressed storage file (.mcap.zstd, .db3.zstd)",
    "a ROS 1 .bag file",
    "a PX4 ULog (.ulg)",
    "an ArduPilot DataFlash log (.bin; pip install imu_dcm[mavlink])",
    "a EuRoC / ASL dataset folder (mav0/imu0/data.csv)",
]

TIME_BASES = ("auto", "header", "log")
GYRO_UNITS = ("rad/s", "deg/s")
PREFILTERS = ("kalman", "rts")


def check_options(
    path, time, method, bias, gyro_units, init_q_w_b, prefilter, truth_offset_s
) -> tuple:
    """Validate every option of :func:`imu_dcm.replay.replay` once, before the log is read.

    Returns
    -------
    (bias, init_q_w_b, truth_offset_s)
        ``bias`` "auto", "none" or a float64 (3,) array, rad/s; ``init_q_w_b`` a unit
        ``[x, y, z, w]`` or None (:mod:`imu_dcm.app.checks`); the offset as given (seconds or
        "auto").

    Raises
    ------
    InputError
        A value out of its set or not finite. (A special file as the log is refused by the
        reader, from its ``stat``, before a byte is read.)
    """
    from imu_dcm.app.checks import check_bias, check_init_q_w_b  # numpy: not for --help

    if time not in TIME_BASES:
        raise InputError(f"Expected time in {TIME_BASES}, got {time!r}")
    if method not in METHODS:
        raise InputError(f"Expected method in {METHODS}, got {method!r}")
    if gyro_units is not None and gyro_units not in GYRO_UNITS:
        raise InputError(f"Expected gyro units 'rad/s', 'deg/s' or None, got {gyro_units!r}")
    if prefilter is not None and prefilter not in PREFILTERS:
        raise InputError(f"Expected prefilter None, 'kalman' or 'rts', got {prefilter!r}")
    bias = check_bias(bias)
    init_q_w_b = check_init_q_w_b(init_q_w_b)
    if isinstance(truth_offset_s, str):
        if truth_offset_s != "auto":
            raise InputError(f"Expected truth offset 'auto' or seconds, got {truth_offset_s!r}")
    elif (
        not isinstance(truth_offset_s, (int, float))
        or not math.isfinite(truth_offset_s)
        or abs(truth_offset_s) > 1e6
    ):
        raise InputError(
            f"Expected a finite truth offset in s (|x| <= 1e6), got {truth_offset_s!r}"
        )
    return bias, init_q_w_b, truth_offset_s


def _add_scoring_options(g) -> None:
    """``--truth-offset`` and ``--score-window``: how the estimate meets the truth."""
    g.add_argument(
        "--truth-offset",
        default="0",
        metavar="auto|SECONDS",
        help="shift added to the truth stamps: seconds (default 0) or auto (the "
        "shift that best aligns the truth's rotation rate with the gyro's)",
    )
    g.add_argument(
        "--score-window",
        default="all",
        metavar="all|declared|T0:T1",
        help="samples the error is scored on: all (default), declared (the intervals the log's "
        "metadata declares, such as BROAD's movement phases), or T0:T1 in seconds from the "
        "log's start",
    )


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
    _add_scoring_options(g)
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
        choices=METHODS,
        help="integrator increment (default magnus4)",
    )
    g.add_argument(
        "--bias",
        default="auto",
        help="gyro bias: auto (from rest segments, default), none, or x,y,z in rad/s "
        "(negative numbers as they are: --bias -0.01,0,0)",
    )
    g.add_argument(
        "--mounting",
        default="auto",
        metavar="auto|none|X,Y,Z,W",
        help="rotation from the gyro's frame into the truth's body frame: auto (estimated from "
        "the rates, applied when determined and above 3°; default), none (reported only), or "
        "x,y,z,w",
    )
    _add_truth_convention(g)
    g.add_argument(
        "--gyro-units",
        choices=GYRO_UNITS,
        default="rad/s",
        help="unit of the log's angular velocity (default rad/s)",
    )
    g.add_argument(
        "--init-quat",
        dest="init_q_w_b",
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
        help="pre-filter: gyro white-noise density, rad/s/√Hz (default: --noise-params' "
        "gyroscope_noise_density when given, else from rest)",
    )
    g.add_argument(
        "--angular-accel",
        type=float,
        metavar="RAD_S2",
        help="pre-filter: angular-acceleration scale, rad/s² (default: fitted)",
    )


def _add_truth_convention(g) -> None:
    g.add_argument(
        "--truth-convention",
        choices=("auto", "as-is", "conjugate", "w-first", "w-last", "ned"),
        default="auto",
        help="how the truth's quaternions are to be read: auto (as read, unless its body rates "
        "fit the gyro clearly only in another convention, or the accelerometer's gravity says "
        "its world is NED; default), as-is, conjugate (world to body), w-first ([w,x,y,z] read "
        "as [x,y,z,w]), w-last (the reverse), ned (body to a NED world, not ENU)",
    )


def replay_keywords(args) -> dict:
    """The keywords of :func:`imu_dcm.replay.replay` from :func:`add_replay_options`' options,
    parsed and checked (string parsing lives here, not in the library)."""
    from imu_dcm.replay.window import parse_score_window

    bias = parse_bias(args.bias)
    init = parse_init_q_w_b(args.init_q_w_b)
    mounting = parse_mounting(args.mounting)
    offset: float | str = args.truth_offset
    if offset != "auto":
        offset = parse_numbers(offset, 1, "--truth-offset (auto or seconds)")[0]
    config = None
    density = args.gyro_noise_density
    params = getattr(args, "noise_params", None)  # replay's --noise-params IMU.yaml
    if args.prefilter != "none" and density is None and isinstance(params, str):
        from imu_dcm.replay.budget import read_noise_params

        density = read_noise_params(params).N  # its gyroscope_noise_density, rad/s/√Hz
    if args.prefilter != "none":
        from imu_dcm.gyro.prefilter import PrefilterConfig

        config = PrefilterConfig(
            noise_density_rad_s_sqrt_hz=density,
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
        "mounting": mounting,
        "score_window": parse_score_window(args.score_window),
        "truth_convention": args.truth_convention,
    }

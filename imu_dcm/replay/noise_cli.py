"""``imu-dcm-replay noise LOG``: the gyro's noise parameters from a static stretch of a log.

The stretch is the whole log when it is all rest (the longest rest covers 95 % of it or more),
else its longest rest (:func:`imu_dcm.replay.bias.estimate_bias`). Over it, per axis, the
overlapping Allan deviation at octave cluster times 1, 2, 4, ... samples
(:func:`imu_dcm.gyro.allan.allan_deviation`) and the three standard terms
(:func:`imu_dcm.gyro.allan.fit_noise`):
angle random walk N, bias instability B and rate random walk K, each with the τ it was read at
and its relative uncertainty from the number of clusters there.

``--yaml FILE`` writes Kalibr's ``imu.yaml`` gyroscope keys, continuous time, the largest axis
(Kalibr takes one value per sensor); ``--plot FILE.png|.svg`` the Allan plot with the fitted
lines. Units: N rad/s/√Hz (= rad/√s) and °/√h (× 180/π × 60); B rad/s and °/h; K rad/s²/√Hz
(= rad/s/√s) and °/h/√h (× 180/π × 3600 × 60).
"""

from __future__ import annotations

import argparse
import os
from dataclasses import dataclass

import numpy as np

from imu_dcm.app.options import OneLineArgumentParser
from imu_dcm.errors import InputError, LogError

__all__ = ["NoiseReport", "build_parser", "convert_units", "measure_noise", "noise_main"]

PROG = "imu-dcm-replay noise"
#: The longest rest stands for the whole log from this share of its samples on.
WHOLE_LOG_SHARE = 0.95
_DEG = 180.0 / np.pi


def build_parser() -> argparse.ArgumentParser:
    p = OneLineArgumentParser(
        prog=PROG,
        description="The gyro's noise parameters (angle random walk N, bias instability B, "
        "rate random walk K) from the Allan deviation of a static log or of its longest rest.",
    )
    p.add_argument("log", help="the log (any container the replay reads)")
    p.add_argument("--imu-topic", help="IMU channel (default: the one Imu-typed channel)")
    p.add_argument("--gyro-units", choices=("rad/s", "deg/s"), default="rad/s")
    p.add_argument("--yaml", metavar="FILE", help="write Kalibr's imu.yaml gyroscope keys")
    p.add_argument("--plot", metavar="FILE", help="draw the Allan plot to FILE.png or .svg")
    return p


@dataclass(slots=True, frozen=True)
class NoiseReport:
    """What ``noise`` found: the stretch used, its rate and one :class:`AllanFit` per axis.

    ``topic`` the IMU channel; ``rate_hz`` its rate over the stretch; ``start_s``, ``end_s``
    the stretch (s since the first sample); ``samples`` its length; ``whole`` True when the
    stretch is the whole log (all rest); ``fits`` one ``AllanFit`` per axis (x, y, z).
    """

    topic: str
    rate_hz: float
    start_s: float
    end_s: float
    samples: int
    whole: bool
    fits: tuple

    def largest(self, term: str):
        """The axis term with the largest value (Kalibr takes one per sensor)."""
        return max((getattr(f, term) for f in self.fits), key=lambda x: x.value)


def measure_noise(path: str, imu_topic: str | None = None, gyro_units: str = "rad/s"):
    """Read a log, find its static stretch and fit the Allan deviation of each axis.

    Raises
    ------
    LogError
        No rest in the log, or a rest too short for an Allan deviation.
    """
    from imu_dcm.gyro.allan import allan_deviation, fit_noise, octave_clusters

    # lazy: the readers ~20 ms of CPU, the Allan fit, bias and cleaning ~11 ms, which
    # `noise --help` and a bad option never need
    from imu_dcm.logio import read_log
    from imu_dcm.replay.bias import estimate_bias
    from imu_dcm.replay.clean import clean_imu

    log = read_log(path, imu_topic=imu_topic, truth_topic="none")
    imu = log.imu
    scale = np.pi / 180.0 if gyro_units == "deg/s" else 1.0
    clean = clean_imu(imu.t_ns, np.asarray(imu.omega_b, dtype=float) * scale, imu.topic)
    t_s = (clean.t_ns - clean.t_ns[0]) * 1e-9
    accel = None if imu.accel_b is None else np.asarray(imu.accel_b, dtype=float)[clean.index]
    if accel is not None and not np.all(np.isfinite(accel)):
        accel = None
    est = estimate_bias(clean.omega_b, t_s, "auto", None, accel)
    if not est.segments:
        raise LogError(f"Expected a rest on {imu.topic} for the noise, got none: {est.no_rest}")
    seg = max(est.segments, key=lambda x: x.stop - x.start)
    n_all = len(t_s)
    whole = (seg.stop - seg.start) >= WHOLE_LOG_SHARE * n_all
    lo, hi = (0, n_all) if whole else (seg.start, seg.stop)
    if hi - lo < 18:
        raise LogError(f"Expected a rest of at least 18 samples, got {hi - lo} on {imu.topic}")
    rate = 1.0 / float(np.median(np.diff(t_s[lo:hi])))
    w = clean.omega_b[lo:hi]
    tau, adev = allan_deviation(w, rate, m=octave_clusters(hi - lo))
    fits = tuple(fit_noise(tau, adev[:, a], hi - lo) for a in range(3))
    return NoiseReport(imu.topic, rate, float(t_s[lo]), float(t_s[hi - 1]), hi - lo, whole, fits)


def convert_units(term: str, value: float) -> tuple[float, str]:
    """The second unit of a term: N in °/√h, B in °/h, K in °/h/√h."""
    return {
        "N": (value * _DEG * 60.0, "°/√h"),
        "B": (value * _DEG * 3600.0, "°/h"),
        "K": (value * _DEG * 3600.0 * 60.0, "°/h/√h"),
    }[term]


def _term_line(r: NoiseReport, term: str, label: str, unit: str) -> str:
    """``label  x, y, z unit = x, y, z other-unit; τ ...; ±...`` and the axes only bounded."""
    terms = [getattr(f, term) for f in r.fits]
    alt_unit = convert_units(term, 1.0)[1]

    def join(values, fmt: str) -> str:
        return ", ".join(format(v, fmt) for v in values)

    bounded = [a for a, t in zip("xyz", terms, strict=True) if not t.reached]
    note = f"; {', '.join(bounded)}: upper bound (slope not reached)" if bounded else ""
    return (
        f"{label:10s} {join((t.value for t in terms), '.3g')} {unit} (x, y, z) = "
        f"{join((convert_units(term, t.value)[0] for t in terms), '.3g')} {alt_unit}; "
        f"at τ {join((t.tau_s for t in terms), '.3g')} s; "
        f"± {join((100 * t.rel_uncertainty for t in terms), '.2g')} %{note}"
    )


def report_lines(r: NoiseReport) -> list[str]:
    """One line for the stretch, one per term."""
    where = (
        "the whole log (static)"
        if r.whole
        else f"its longest rest, {r.start_s:.2f}..{r.end_s:.2f} s"
    )
    head = (
        f"noise      {r.topic} at {r.rate_hz:.1f} Hz: {where}, {r.samples} samples "
        f"({r.samples / r.rate_hz:.1f} s)"
    )
    return [
        head,
        _term_line(r, "N", "ARW N", "rad/s/√Hz"),
        _term_line(r, "B", "bias B", "rad/s"),
        _term_line(r, "K", "RRW K", "rad/s²/√Hz"),
    ]


def kalibr_yaml(r: NoiseReport) -> str:
    """Kalibr's ``imu.yaml`` gyroscope keys (continuous time; the largest axis)."""
    n, k, b = r.largest("N"), r.largest("K"), r.largest("B")
    bound = "" if k.reached else " (an upper bound: the +1/2 slope is not reached)"
    from imu_dcm.outputs.signatures import comment_line

    return (
        comment_line("noise yaml")
        + f"# Gyroscope noise from imu-dcm-replay noise: the Allan deviation of {r.samples}\n"
        f"# samples ({r.samples / r.rate_hz:.1f} s); the largest of the three axes; continuous\n"
        f"# time.\n"
        f"rostopic: {r.topic}\n"
        f"update_rate: {r.rate_hz:.6g}  # Hz\n"
        f"gyroscope_noise_density: {n.value:.6g}  # rad/s/sqrt(Hz): angle random walk N, "
        f"sigma(tau) = N/sqrt(tau); discrete per-sample std = N*sqrt(update_rate)\n"
        f"gyroscope_random_walk: {k.value:.6g}  # rad/s^2/sqrt(Hz): rate random walk K, "
        f"sigma(tau) = K*sqrt(tau/3){bound}\n"
        f"gyroscope_bias_instability: {b.value:.6g}  # rad/s: bias instability B, the Allan "
        f"floor over 0.664{'' if b.reached else ' (an upper bound: no floor reached)'}; not a "
        f"Kalibr key (for imu-dcm-replay --noise-params)\n"
    )


def _outputs(args) -> dict:
    """The outputs claimed before the log is read (:func:`imu_dcm.outputs.claim_output`: new,
    or a file of this tool's of the same kind, never the log)."""
    from imu_dcm.outputs import claim_output

    inputs = (args.log,)
    if args.yaml and args.plot and os.path.realpath(args.yaml) == os.path.realpath(args.plot):
        raise InputError(f"Expected --yaml and --plot to be separate paths, got {args.yaml}")
    claims = {}
    if args.yaml:
        claims["yaml"] = claim_output(args.yaml, "yaml", inputs, what="--yaml file")
    if args.plot:
        from imu_dcm.replay.plot import check_plot

        claims["plot"] = check_plot(args.plot, inputs)
    return claims


def noise_main(argv: list[str]) -> int:
    """Run ``noise``: print the terms, write the YAML and the plot when asked."""
    args = build_parser().parse_args(argv)
    claims = _outputs(args)  # checked before the log is read
    r = measure_noise(args.log, args.imu_topic, args.gyro_units)
    lines = report_lines(r)
    if args.yaml:
        from imu_dcm.outputs import write_atomic

        lines.append(f"yaml       {write_atomic(claims['yaml'], kalibr_yaml(r))}")
    if args.plot:
        from imu_dcm.replay.noise_plot import plot_allan

        lines.append(f"plot       {plot_allan(r, claims['plot'], os.path.basename(args.log))}")
    print("\n".join(lines))
    return 0

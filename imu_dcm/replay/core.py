"""Replay a recorded gyro log through the integrator and compare the estimate with the truth.

Pipeline (:func:`replay`): read the log (:mod:`imu_dcm.bag_reader`), clean the gyro samples
(drop NaN/Inf, drop duplicate or backward stamps, warn about gaps over 5x the median step),
convert deg/s when asked (and warn with the evidence when the rates look like deg/s), slerp the
truth at the gyro stamps inside its coverage, remove the gyro bias (:mod:`imu_dcm.replay.bias`),
optionally pre-filter, integrate from the truth at the first gyro sample inside its coverage, and
measure the attitude error (total, inclination, heading).

Conventions: ``q_w_b`` Hamilton ``[x, y, z, w]``, body to world; ``omega_b`` body rate in body
axes, rad/s; ``t_ns`` int64 stamps, ``t_s`` float64 seconds since the first gyro sample; errors
in degrees.
"""

from __future__ import annotations

import time as _time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imu_dcm.bag_reader import LogData, TruthSeries, read_log
from imu_dcm.errors import GapWarning, ImuDcmWarning, InputError, LogError
from imu_dcm.integrate import GAP_FACTOR, METHODS, integrate
from imu_dcm.metrics import AttitudeError, attitude_error_deg, rms
from imu_dcm.replay.bias import BiasEstimate, RestConfig, estimate_bias
from imu_dcm.so3 import as_quat_xyzw, exp_quat, log_quat, quat_conjugate, quat_multiply

__all__ = ["CleanedImu", "ReplayResult", "clean_imu", "replay", "slerp_truth"]

DEG = np.pi / 180.0
#: Gaps between truth samples longer than this many median truth steps are not bridged.
TRUTH_BRIDGE_STEPS = 2.0
#: Full scale of common MEMS gyros (±2000 °/s): rates above it suggest a deg/s log.
FULL_SCALE_RAD_S = 2000.0 * DEG


@dataclass(frozen=True)
class CleanedImu:
    """Gyro samples after cleaning, with the counts of what was dropped.

    ``t_ns`` int64 (N,) strictly increasing; ``omega_b`` float64 (N, 3) finite, in the log's
    unit; ``keep`` bool mask over the input samples; gaps as (time s, length s) pairs.
    """

    t_ns: NDArray[np.int64]
    omega_b: NDArray[np.float64]
    keep: NDArray[np.bool_]
    dropped_nonfinite: int
    dropped_nonincreasing: int
    gaps: tuple[tuple[float, float], ...]


@dataclass(frozen=True)
class ReplayResult:
    """Everything a replay produced. Arrays cover the N cleaned gyro samples.

    Attributes
    ----------
    t_ns : int64 (N,) — gyro stamps, ns.
    t_s : float64 (N,) — seconds since the first gyro sample.
    omega_raw_b : float64 (N, 3) — gyro rates as read (after unit conversion), body, rad/s.
    omega_b : float64 (N, 3) — rates as integrated (bias removed, pre-filtered), body, rad/s.
    bias_b : float64 (N, 3) — bias removed at each sample, body, rad/s.
    q_est : float64 (N, 4) — estimate ``q_w_b`` ``[x, y, z, w]``; NaN before ``start_index``.
    q_truth : float64 (N, 4) — truth slerped at the gyro stamps; NaN outside its coverage.
    error : AttitudeError — per-sample errors, deg; NaN where there is no truth or estimate.
    start_index : int — first estimated sample (the first inside truth coverage, or 0).
    bias : BiasEstimate — rest segments and mode.
    summary : dict — JSON-ready summary (see :func:`replay`).
    """

    t_ns: NDArray[np.int64]
    t_s: NDArray[np.float64]
    omega_raw_b: NDArray[np.float64]
    omega_b: NDArray[np.float64]
    bias_b: NDArray[np.float64]
    q_est: NDArray[np.float64]
    q_truth: NDArray[np.float64]
    error: AttitudeError
    start_index: int
    bias: BiasEstimate
    summary: dict


def clean_imu(t_ns: ArrayLike, omega_b: ArrayLike, topic: str = "IMU") -> CleanedImu:
    """Drop non-finite samples and duplicate/backward stamps; find gaps over 5x the median step.

    A sample is kept when its rate is finite and its stamp is later than every stamp kept
    before it. Warns (:class:`ImuDcmWarning`) with the counts, and (:class:`GapWarning`) with
    the times of gaps, in seconds since the first kept sample.
    """
    t = np.asarray(t_ns, dtype=np.int64)
    w = np.asarray(omega_b, dtype=float)
    finite = np.all(np.isfinite(w), axis=1)
    n_bad = int((~finite).sum())
    tf = np.where(finite, t, np.iinfo(np.int64).min)
    prev_max = np.maximum.accumulate(np.concatenate([[np.iinfo(np.int64).min], tf[:-1]]))
    increasing = t > prev_max
    keep = finite & increasing
    n_back = int((finite & ~increasing).sum())
    if n_bad:
        warnings.warn(f"{topic}: dropped {n_bad} samples with NaN/Inf rates", ImuDcmWarning,
                      stacklevel=3)  # fmt: skip
    if n_back:
        first = int(np.flatnonzero(finite & ~increasing)[0])
        warnings.warn(
            f"{topic}: dropped {n_back} samples with duplicate or backward stamps "
            f"(first at sample {first}, t = {(t[first] - t[keep][0]) * 1e-9:.6f} s)",
            ImuDcmWarning,
            stacklevel=3,
        )
    tk = t[keep]
    gaps: list[tuple[float, float]] = []
    if len(tk) > 2:
        dt = np.diff(tk)
        big = np.flatnonzero(dt > GAP_FACTOR * np.median(dt))
        gaps = [(float((tk[i] - tk[0]) * 1e-9), float(dt[i] * 1e-9)) for i in big]
        if gaps:
            listed = ", ".join(f"{a:.3f} s (+{d:.3f} s)" for a, d in gaps[:5])
            more = f" and {len(gaps) - 5} more" if len(gaps) > 5 else ""
            warnings.warn(
                f"{topic}: {len(gaps)} gaps over 5x the median step "
                f"({np.median(dt) * 1e-9 * 1e3:.3f} ms) at {listed}{more}",
                GapWarning,
                stacklevel=3,
            )
    return CleanedImu(tk, w[keep], keep, n_bad, n_back, tuple(gaps))


def slerp_truth(truth_t_ns: ArrayLike, q_w_b: ArrayLike, t_ns: ArrayLike) -> NDArray[np.float64]:
    """Truth attitudes at times ``t_ns`` by slerp, NaN outside coverage and across long gaps.

    Parameters
    ----------
    truth_t_ns : array_like, int64 (M,)
        Truth stamps (any order; sorted here, duplicates dropped).
    q_w_b : array_like, shape (M, 4)
        Truth ``[x, y, z, w]`` (body to world); need not be sign-continuous.
    t_ns : array_like, int64 (N,)
        Query stamps.

    Returns
    -------
    ndarray, shape (N, 4)
        Unit quaternions; NaN rows before the first / after the last truth sample and inside
        gaps longer than ``TRUTH_BRIDGE_STEPS`` median truth steps (never bridged).
    """
    tt = np.asarray(truth_t_ns, dtype=np.int64)
    q = np.asarray(q_w_b, dtype=float)
    t = np.asarray(t_ns, dtype=np.int64)
    norm = np.linalg.norm(q, axis=1)
    ok = np.isfinite(norm) & (norm > 0.5)
    tt, q = tt[ok], q[ok] / norm[ok, None]
    order = np.argsort(tt, kind="stable")
    tt, q = tt[order], q[order]
    uniq = np.concatenate([[True], np.diff(tt) > 0]) if len(tt) else np.zeros(0, bool)
    tt, q = tt[uniq], q[uniq]
    out = np.full((len(t), 4), np.nan)
    if len(tt) == 0:
        return out
    j = np.searchsorted(tt, t, side="right") - 1  # tt[j] <= t < tt[j+1]
    exact = (j >= 0) & (tt[np.clip(j, 0, None)] == t)
    out[exact] = q[j[exact]]
    if len(tt) < 2:
        return out
    max_step = TRUTH_BRIDGE_STEPS * float(np.median(np.diff(tt)))
    inner = ~exact & (j >= 0) & (j < len(tt) - 1)
    jj = j[inner]
    step = (tt[jj + 1] - tt[jj]).astype(float)
    bridge = step <= max_step * (1 + 1e-6)
    idx = np.flatnonzero(inner)[bridge]
    jj = jj[bridge]
    u = (t[idx] - tt[jj]).astype(float) / (tt[jj + 1] - tt[jj]).astype(float)
    q0, q1 = q[jj], q[jj + 1]
    rel = quat_multiply(quat_conjugate(q0), q1)
    rel = np.where(rel[:, 3:4] < 0, -rel, rel)  # shortest arc
    out[idx] = quat_multiply(q0, exp_quat(u[:, None] * log_quat(rel)))
    return out


def _deg_evidence(omega_b: NDArray, t_s: NDArray, q_truth: NDArray) -> str | None:
    """Evidence that rates are in deg/s, or None. Compares with the truth's rate if possible."""
    ok = np.all(np.isfinite(q_truth), axis=1)
    pair = ok[:-1] & ok[1:]
    if pair.sum() > 10:
        i = np.flatnonzero(pair)
        rel = quat_multiply(quat_conjugate(q_truth[i]), q_truth[i + 1])
        ang = 2 * np.arctan2(np.linalg.norm(rel[:, :3], axis=1), np.abs(rel[:, 3]))
        truth_rate = ang / np.diff(t_s)[i]
        gyro_rate = np.linalg.norm(0.5 * (omega_b[i] + omega_b[i + 1]), axis=1)
        moving = truth_rate > 0.2  # rad/s: motion well above noise
        if moving.sum() > 10:
            ratio = float(np.median(gyro_rate[moving] / truth_rate[moving]))
            if abs(ratio / (180 / np.pi) - 1) < 0.2:
                return (f"the gyro rate is {ratio:.1f}x the truth's rotation rate "
                        f"(180/π = 57.3 for deg/s)")  # fmt: skip
            return None
    p99 = float(np.percentile(np.linalg.norm(omega_b, axis=1), 99)) if len(omega_b) else 0.0
    if p99 > FULL_SCALE_RAD_S:
        return (f"99 % of |omega| are below {p99:.0f}, above the ±2000 °/s = "
                f"{FULL_SCALE_RAD_S:.1f} rad/s full scale of common gyros")  # fmt: skip
    return None


def _parse_vec(value, n: int, name: str) -> NDArray[np.float64]:
    if isinstance(value, str):
        try:
            value = [float(x) for x in value.split(",")]
        except ValueError:
            raise InputError(f"Expected {name} as {n} comma-separated numbers, got {value!r}")
    arr = np.asarray(value, dtype=float)
    if arr.shape != (n,) or not np.all(np.isfinite(arr)):
        raise InputError(f"Expected {name} as {n} finite numbers, got {value!r}")
    return arr


def replay(
    path: str | Path,
    *,
    imu_topic: str | None = None,
    truth_topic: str | None = None,
    time: str = "header",
    method: str = "magnus4",
    bias: str | ArrayLike = "auto",
    gyro_units: str = "rad/s",
    init_quat: ArrayLike | None = None,
    prefilter: str = "none",
    prefilter_config=None,
    rest_config: RestConfig | None = None,
    progress: Callable[[str, float], None] | None = None,
) -> ReplayResult:
    """Replay a gyro log: integrate its rates and compare the attitude with its truth.

    Parameters
    ----------
    path : str or Path
        ROS 2 bag folder or ``.mcap`` file (never modified).
    imu_topic, truth_topic : str, optional
        Channel choices (see :func:`imu_dcm.bag_reader.read_log`); ``truth_topic="none"``
        ignores any truth.
    time : {"header", "log"}
        Stamps from ``header.stamp`` (default) or the MCAP log time.
    method : str
        Integrator method, one of :data:`imu_dcm.integrate.METHODS` (default ``"magnus4"``).
    bias : "auto", "none", "x,y,z" or array_like (3,)
        Gyro bias handling, rad/s (see :func:`imu_dcm.replay.bias.estimate_bias`).
    gyro_units : {"rad/s", "deg/s"}
        Unit of the log's rates; deg/s are converted to rad/s.
    init_quat : array_like (4,) or "x,y,z,w", optional
        Initial ``q_w_b`` ``[x, y, z, w]`` when the log has no truth (default identity).
    prefilter : {"none", "kalman", "rts"}
        Gyro pre-filter (:mod:`imu_dcm.prefilter`), applied after bias removal.
    prefilter_config : PrefilterConfig, optional
    rest_config : RestConfig, optional
    progress : callable(stage, fraction), optional
        Called as work advances (for a progress bar).

    Returns
    -------
    ReplayResult
        Arrays and a summary dict with keys ``log, imu_topic, truth_topic, samples,
        duration_s, rate_hz, dropped_nonfinite, dropped_nonincreasing, gaps, gyro_units,
        bias_mode, bias_rad_s, bias_segments, method, prefilter, start_time_s,
        truth_samples_used, rms_error_deg, max_error_deg, rms_inclination_deg,
        max_inclination_deg, rms_heading_deg, max_heading_deg, stopped_at, elapsed_s``.

    Raises
    ------
    LogError
        Unreadable log, no IMU channel, a truth that never overlaps the gyro, too few samples.
    InputError
        A bad option value.
    """
    t0 = _time.perf_counter()
    if method not in METHODS:
        raise InputError(f"Expected method in {METHODS}, got {method!r}")
    if gyro_units not in ("rad/s", "deg/s"):
        raise InputError(f"Expected gyro units 'rad/s' or 'deg/s', got {gyro_units!r}")
    if prefilter not in ("none", "kalman", "rts"):
        raise InputError(f"Expected prefilter 'none', 'kalman' or 'rts', got {prefilter!r}")
    if isinstance(bias, str) and bias not in ("auto", "none"):
        bias = _parse_vec(bias, 3, "bias (rad/s)")
    q_init = None
    if init_quat is not None:
        q_init = as_quat_xyzw(_parse_vec(init_quat, 4, "init quaternion x,y,z,w"), "init_quat")
    report = progress or (lambda stage, frac: None)

    report("read", 0.0)
    log: LogData = read_log(path, imu_topic=imu_topic, truth_topic=truth_topic, time=time,
                            progress=lambda frac: report("read", frac))  # fmt: skip
    report("read", 1.0)
    imu = log.imu
    clean = clean_imu(imu.t_ns, imu.omega_b, imu.topic)
    n = len(clean.t_ns)
    if n < 2:
        raise LogError(f"Expected at least 2 valid gyro samples on {imu.topic}, got {n}")
    t_ns = clean.t_ns
    t_s = (t_ns - t_ns[0]).astype(np.float64) * 1e-9
    omega_raw = clean.omega_b * (DEG if gyro_units == "deg/s" else 1.0)

    truth: TruthSeries | None = log.truth
    q_truth = np.full((n, 4), np.nan)
    if truth is not None:
        q_truth = slerp_truth(truth.t_ns, truth.q_w_b, t_ns)
        if not np.isfinite(q_truth[:, 3]).any():
            span = (f"{(truth.t_ns.min() - t_ns[0]) * 1e-9:.3f}..{(truth.t_ns.max() - t_ns[0]) * 1e-9:.3f} s"
                    if len(truth.t_ns) else "no samples")  # fmt: skip
            raise LogError(
                f"Expected the truth {truth.topic} to overlap the gyro (0..{t_s[-1]:.3f} s), "
                f"got {span}"
            )
    if gyro_units == "rad/s":
        evidence = _deg_evidence(omega_raw, t_s, q_truth)
        if evidence:
            warnings.warn(f"{imu.topic}: the rates look like deg/s: {evidence}; pass "
                          f"--gyro-units deg/s to convert", ImuDcmWarning, stacklevel=2)  # fmt: skip

    has_truth = np.all(np.isfinite(q_truth), axis=1)
    start = int(np.flatnonzero(has_truth)[0]) if has_truth.any() else 0
    if has_truth.any():
        q0 = q_truth[start]
    else:
        q0 = q_init if q_init is not None else np.array([0.0, 0.0, 0.0, 1.0])

    report("bias", 0.0)
    bias_est = estimate_bias(omega_raw, t_s, bias, rest_config)
    omega = omega_raw - bias_est.bias_b
    pf_summary = None
    if prefilter != "none":
        try:
            from imu_dcm.prefilter import prefilter as run_prefilter
        except ImportError as exc:
            raise InputError(f"Expected the pre-filter module imu_dcm.prefilter, got {exc}")
        with warnings.catch_warnings():  # gaps were reported once, by clean_imu
            warnings.simplefilter("ignore", GapWarning)
            pf = run_prefilter(omega, t_s, prefilter, prefilter_config)
        omega = np.asarray(pf.omega_b, dtype=float)
        pf_summary = pf.summary

    report("integrate", 0.0)
    q_est = np.full((n, 4), np.nan)
    if n - start >= 2:
        with warnings.catch_warnings():  # gaps were reported once, by clean_imu
            warnings.simplefilter("ignore", GapWarning)
            q_est[start:] = integrate(omega[start:], t_s[start:], q0, method).as_quat()
    else:
        q_est[start:] = q0
    report("integrate", 1.0)

    both = has_truth & np.all(np.isfinite(q_est), axis=1)
    err_full = attitude_error_deg(np.where(both[:, None], q_est, [0, 0, 0, 1.0]),
                                  np.where(both[:, None], q_truth, [0, 0, 0, 1.0]))  # fmt: skip
    nanify = lambda a: np.where(both, a, np.nan)
    error = AttitudeError(nanify(err_full.total_deg), nanify(err_full.inclination_deg),
                          nanify(err_full.heading_deg))  # fmt: skip

    def stat(a: NDArray, f) -> float | None:
        return float(f(a[both])) if both.any() else None

    dt = np.diff(t_s)
    used = slice(start, n)
    summary = {
        "log": str(path),
        "imu_topic": imu.topic,
        "imu_type": imu.type,
        "truth_topic": truth.topic if truth is not None else None,
        "truth_type": truth.type if truth is not None else None,
        "samples": int(n),
        "samples_estimated": int(n - start),
        "duration_s": float(t_s[-1]),
        "rate_hz": float(1.0 / np.median(dt)),
        "dropped_nonfinite": clean.dropped_nonfinite,
        "dropped_nonincreasing": clean.dropped_nonincreasing,
        "gaps": [{"t_s": a, "length_s": d} for a, d in clean.gaps],
        "gyro_units": gyro_units,
        "time": time,
        "bias_mode": bias_est.mode,
        "bias_rad_s": bias_est.bias_b[used].mean(axis=0).tolist(),
        "bias_segments": [
            {"start_s": s.start_s, "end_s": s.end_s, "bias_rad_s": list(s.bias_rad_s)}
            for s in bias_est.segments
        ],
        "method": method,
        "prefilter": prefilter,
        "prefilter_summary": pf_summary,
        "start_time_s": float(t_s[start]),
        "initial_quat_xyzw": [float(x) for x in q0],
        "truth_samples_used": int(both.sum()),
        "rms_error_deg": stat(error.total_deg, rms),
        "max_error_deg": stat(error.total_deg, np.max),
        "rms_inclination_deg": stat(error.inclination_deg, rms),
        "max_inclination_deg": stat(error.inclination_deg, np.max),
        "rms_heading_deg": stat(error.heading_deg, rms),
        "max_heading_deg": stat(error.heading_deg, np.max),
        "stopped_at": log.stopped_at,
        "channels": [c.__dict__ for c in log.channels],
    }
    summary["elapsed_s"] = _time.perf_counter() - t0
    return ReplayResult(t_ns, t_s, omega_raw, omega, bias_est.bias_b, q_est, q_truth, error,
                        start, bias_est, summary)  # fmt: skip

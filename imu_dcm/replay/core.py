"""Replay a recorded gyro log through the integrator and compare the estimate with the truth.

Pipeline (:func:`replay`): read the log, choose the time base (:mod:`imu_dcm.replay.truth`),
clean the gyro samples (:mod:`imu_dcm.replay.clean`: NaN/Inf, implausible rates, wild stamps,
file order, duplicates, gaps), convert deg/s when asked (and warn with the evidence when the
rates look like deg/s), check that the truth's rotation rate follows the gyro, slerp the truth
at the gyro stamps inside its coverage, remove the gyro bias (:mod:`imu_dcm.replay.bias`),
optionally pre-filter, integrate from the truth at the first gyro sample inside its coverage,
and measure the attitude error (total, inclination, heading).

Conventions: ``q_w_b`` Hamilton ``[x, y, z, w]``, body to world; ``omega_b`` body rate in body
axes, rad/s; ``t_ns`` int64 stamps, ``t_s`` float64 seconds since the first gyro sample; errors
in degrees.
"""

from __future__ import annotations

import dataclasses
import time as _time
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imu_dcm.errors import GapWarning, ImuDcmWarning, LogError
from imu_dcm.integrate import integrate_quat
from imu_dcm.logio import read_log
from imu_dcm.metrics import AttitudeError, attitude_error_deg, rms
from imu_dcm.replay.bias import RestConfig, estimate_bias
from imu_dcm.replay.clean import CleanedImu, _deg_evidence, clean_imu
from imu_dcm.replay.options import check_options
from imu_dcm.replay.summary import ReplayResult, ReplaySummary
from imu_dcm.replay.truth import align_truth, choose_time
from imu_dcm.resample import slerp_truth

__all__ = ["CleanedImu", "ReplayResult", "ReplaySummary", "clean_imu", "replay", "slerp_truth"]

DEG = np.pi / 180.0


def replay(
    path: str | Path,
    *,
    imu_topic: str | None = None,
    truth_topic: str | None = None,
    truth_frame: str | None = None,
    time: str = "auto",
    method: str = "magnus4",
    bias: str | ArrayLike = "auto",
    gyro_units: str | None = "rad/s",
    init_q_w_b: ArrayLike | None = None,
    prefilter: str | None = None,
    prefilter_config=None,
    truth_offset_s: float | str = 0.0,
    rest_config: RestConfig | None = None,
    progress: Callable[[str, float], None] | None = None,
) -> ReplayResult:
    """Replay a gyro log: integrate its rates and compare the attitude with its truth.

    Parameters
    ----------
    path : str or Path
        ROS 2 bag folder or log file (never modified).
    imu_topic, truth_topic : str, optional
        Channel choices (see the log reader); ``truth_topic="none"`` ignores any truth. A truth
        named here is scored even when its rate does not follow the gyro (the summary says so);
        an automatically picked one that does not follow is dropped with a warning.
    truth_frame : str, optional
        Child frame of a transform truth (``/tf``), passed to the reader.
    time : {"auto", "header", "log"}
        Stamp source; ``"auto"`` (default) prefers the header stamps (see
        :func:`imu_dcm.replay.truth.choose_time`).
    method : str
        Integrator method, one of :data:`imu_dcm.integrate.METHODS` (default ``"magnus4"``).
    bias : "auto", "none" or array_like (3,)
        Gyro bias handling, rad/s (see :func:`imu_dcm.replay.bias.estimate_bias`).
    gyro_units : {"rad/s", "deg/s"} or None
        Unit of the log's rates; deg/s are converted. None: rad/s (the ROS convention), with a
        warning when the rates look like deg/s.
    init_q_w_b : array_like (4,), optional
        Initial ``q_w_b`` ``[x, y, z, w]`` when the log has no truth (default identity).
    prefilter : {None, "kalman", "rts"}
        Gyro pre-filter (:mod:`imu_dcm.prefilter`), applied after bias removal.
    prefilter_config : PrefilterConfig, optional
    truth_offset_s : float or "auto"
        Added to the truth stamps, s (default 0); ``"auto"``: the shift that best aligns the
        truth's rate with the gyro's. The best shift is reported either way.
    rest_config : RestConfig, optional
    progress : callable(stage, fraction), optional
        Called as work advances (for a progress bar).

    Returns
    -------
    ReplayResult
        Arrays and a :class:`ReplaySummary`.

    Raises
    ------
    LogError
        Unreadable log, no IMU channel, a truth that never overlaps the gyro, too few valid
        samples, an estimate that is not finite.
    InputError
        A bad option value.
    """
    t0 = _time.perf_counter()
    bias, q_init, offset = check_options(
        path, time, method, bias, gyro_units, init_q_w_b, prefilter, truth_offset_s
    )
    notes: list[str] = []  # this replay's warnings, for the summary (no global state)
    result = _replay(
        path,
        imu_topic,
        truth_topic,
        truth_frame,
        time,
        method,
        bias,
        gyro_units or "rad/s",
        q_init,
        prefilter,
        prefilter_config,
        offset,
        rest_config,
        progress or (lambda stage, frac: None),
        notes,
    )
    summary = dataclasses.replace(
        result.summary, warnings=tuple(notes), elapsed_s=_time.perf_counter() - t0
    )
    return dataclasses.replace(result, summary=summary)


def _record(obj) -> dict:
    """A reader record (dataclass or plain object) as a dict for the summary."""
    if dataclasses.is_dataclass(obj):
        return dataclasses.asdict(obj)
    return dict(vars(obj))


def _warn(notes: list[str], msg: str) -> None:
    notes.append(msg)
    warnings.warn(msg, ImuDcmWarning, stacklevel=3)


def _replay(
    path,
    imu_topic,
    truth_topic,
    truth_frame,
    time,
    method,
    bias,
    gyro_units,
    q_init,
    prefilter,
    prefilter_config,
    offset,
    rest_config,
    report,
    notes: list[str],
) -> ReplayResult:
    report("read", 0.0)
    log = read_log(
        path,
        imu_topic=imu_topic,
        truth_topic=truth_topic,
        truth_frame=truth_frame,
        progress=lambda frac: report("read", frac),
    )
    report("read", 1.0)
    imu, truth = log.imu, log.truth
    base, why = choose_time(
        time,
        imu.t_ns,
        imu.log_t_ns,
        truth.t_ns if truth is not None else None,
        truth.log_t_ns if truth is not None else None,
    )
    if why:
        _warn(notes, f"time: using log time, not header stamps: {why}")
    imu_t = imu.t_ns if base == "header" else imu.log_t_ns
    scale = DEG if gyro_units == "deg/s" else 1.0
    clean = clean_imu(imu_t, np.asarray(imu.omega_b, dtype=float) * scale, imu.topic)
    notes.extend(clean.messages)
    n = len(clean.t_ns)
    if n < 2:
        hint = ""
        if base == "header" and len(np.unique(imu.log_t_ns[:1000])) > 1:
            hint = "; the log times differ: try --time log"
        raise LogError(f"Expected at least 2 valid gyro samples on {imu.topic}, got {n}{hint}")
    t_ns = clean.t_ns
    t_s = (t_ns - t_ns[0]).astype(np.float64) * 1e-9
    omega_raw = clean.omega_b

    aligned = align_truth(
        truth, base, t_ns, omega_raw, offset, imu.log_t_ns, lambda msg: _warn(notes, msg)
    )
    q_truth, truth = aligned.q_truth, aligned.truth
    if gyro_units == "rad/s":
        evidence = _deg_evidence(omega_raw, t_s, q_truth)
        if evidence:
            _warn(
                notes,
                f"{imu.topic}: the rates look like deg/s: {evidence}; pass "
                f"--gyro-units deg/s to convert",
            )

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
    if prefilter is not None:
        from imu_dcm.prefilter import prefilter as run_prefilter

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
            q_est[start:] = integrate_quat(omega[start:], t_s[start:], q0, method)
    else:
        q_est[start:] = q0
    report("integrate", 1.0)
    finite = np.all(np.isfinite(q_est[start:]), axis=1)
    if not finite.all():
        k = start + int(np.flatnonzero(~finite)[0])
        raise LogError(
            f"Expected a finite attitude estimate, got NaN/Inf from sample {k} "
            f"(t = {t_s[k]:.3f} s) on {imu.topic}"
        )

    both = has_truth & np.all(np.isfinite(q_est), axis=1)
    unit = np.array([0, 0, 0, 1.0])
    err_full = attitude_error_deg(
        np.where(both[:, None], q_est, unit), np.where(both[:, None], q_truth, unit)
    )
    error = AttitudeError(
        *(
            np.where(both, a, np.nan)
            for a in (err_full.total_deg, err_full.inclination_deg, err_full.heading_deg)
        )
    )

    def stat_(a: NDArray, f) -> float | None:
        return float(f(a[both])) if both.any() else None

    summary = ReplaySummary(
        path=str(path),
        container=getattr(log, "container", "ros2 mcap"),
        samples=int(n),
        samples_estimated=int(n - start),
        duration_s=float(t_s[-1]),
        rate_hz=float(1.0 / np.median(np.diff(t_s))),
        imu_topic=imu.topic,
        imu_type=imu.type,
        truth_topic=truth.topic if truth is not None else None,
        truth_type=truth.type if truth is not None else None,
        time=base,
        method=method,
        gyro_units=gyro_units,
        bias_mode=bias_est.mode,
        bias_rad_s=tuple(float(x) for x in bias_est.bias_b[start:].mean(axis=0)),
        bias_segments=tuple(
            {"start_s": s.start_s, "end_s": s.end_s, "bias_rad_s": [float(x) for x in s.bias_rad_s]}
            for s in bias_est.segments
        ),
        prefilter=prefilter,
        prefilter_summary=pf_summary,
        start_time_s=float(t_s[start]),
        initial_q_w_b=tuple(float(x) for x in q0),
        truth_samples_used=int(both.sum()),
        truth_offset_s=aligned.offset_s,
        truth_check=dataclasses.asdict(aligned.check) if aligned.check is not None else None,
        rms_error_deg=stat_(error.total_deg, rms),
        max_error_deg=stat_(error.total_deg, np.max),
        rms_inclination_deg=stat_(error.inclination_deg, rms),
        max_inclination_deg=stat_(error.inclination_deg, np.max),
        rms_heading_deg=stat_(error.heading_deg, rms),
        max_heading_deg=stat_(error.heading_deg, np.max),
        dropped_nonfinite=clean.dropped_nonfinite,
        dropped_implausible=clean.dropped_implausible,
        implausible_t_s=clean.implausible_t_s,
        dropped_duplicate=clean.dropped_duplicate,
        dropped_backward=clean.dropped_wild_stamp + clean.dropped_stamp_conflict,
        sorted_out_of_order=clean.sorted_out_of_order,
        gaps=clean.gaps,
        stopped_at=log.stopped_at,
        damage=tuple(_record(d) for d in getattr(log, "damage", ())),
        channels=tuple(_record(c) for c in log.channels),
        truth_rejected=aligned.rejected,
    )
    return ReplayResult(
        t_ns,
        t_s,
        omega_raw,
        omega,
        bias_est.bias_b,
        q_est,
        q_truth,
        error,
        start,
        bias_est,
        summary,
    )

"""Replay a recorded gyro log through the integrator and compare the estimate with the truth.

Pipeline (:func:`replay`): read the log; prepare the gyro (:mod:`imu_dcm.replay.gyro`: time
base from :mod:`imu_dcm.replay.truth`, cleaning by :mod:`imu_dcm.replay.clean` of NaN/Inf,
implausible rates, wild stamps, file order, duplicates and gaps, deg/s converted when asked);
remove the gyro bias (:mod:`imu_dcm.replay.bias`); judge the truth against the gyro
(:mod:`imu_dcm.replay.judge`: which candidate, its convention, its offset and rate check, rates
that look like the wrong unit, its jumps, the mounting between the gyro's frame and the truth's
body frame, gaps the gyro did not see) and remove the bias again with the truth's motion judging
rest; optionally pre-filter; integrate from the truth at the first gyro sample inside its
coverage (and again after each truth jump and unseen gap); measure the attitude error (total,
inclination, heading) over the segments between them and summarise
(:mod:`imu_dcm.replay.summarise`).

Conventions: ``q_w_b`` Hamilton ``[x, y, z, w]``, body to world; ``omega_b`` body rate in body
axes, rad/s; ``t_ns`` int64 stamps, ``t_s`` float64 seconds since the first gyro sample; errors
in degrees.
"""

from __future__ import annotations

import dataclasses
import time as _time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imu_dcm._kernels.calls import attitude_errors
from imu_dcm.app.beside import Beside
from imu_dcm.arrays import BLOCK_ROWS, row_finite
from imu_dcm.errors import Diagnostics, GapWarning, LogError
from imu_dcm.gyro.rest import GyroWindows
from imu_dcm.gyro.rest_evidence import Motion, position_noise_m, truth_noise_rad, twist_noise_rad_s
from imu_dcm.integrator.batch import integrate_quat
from imu_dcm.logio import LogData, read_log
from imu_dcm.metrics import AttitudeError, attitude_error_deg, rms
from imu_dcm.replay.bias import BiasEstimate, RestConfig, estimate_bias
from imu_dcm.replay.convention import check_convention
from imu_dcm.replay.gyro import Gyro, prepare_gyro
from imu_dcm.replay.judge import (
    Judged,
    apply_convention,
    judge_truth,
    pick_truth,
    plain_convention,
    scored_truth,
)
from imu_dcm.replay.offset_hint import auto_offset_rms_deg
from imu_dcm.replay.options import check_options
from imu_dcm.replay.outcome import outcome
from imu_dcm.replay.sampling import sampling_error_deg
from imu_dcm.replay.settings import ReplaySettings, check_mounting
from imu_dcm.replay.stats import evaluate
from imu_dcm.replay.summarise import heading_only, summarise
from imu_dcm.replay.summary import ReplayResult
from imu_dcm.replay.window import check_score_window, window_mask
from imu_dcm.so3 import product_planes, quat_as_matrix

__all__ = ["replay"]


def replay(
    path: str | Path | LogData,
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
    mounting: str | ArrayLike = "auto",
    progress: Callable[[str, float], None] | None = None,
    score_window: str | tuple[float, float] = "all",
    truth_convention: str = "auto",
    diagnostics: Diagnostics | None = None,
) -> ReplayResult:
    """Replay a gyro log: integrate its rates and compare the attitude with its truth.

    Parameters
    ----------
    path : str, Path or LogData
        ROS 2 bag folder or log file (never modified), or a log already read (then the topic
        and frame choices are those it was read with).
    imu_topic, truth_topic, truth_frame, time, method, bias, gyro_units, init_q_w_b, prefilter,
    prefilter_config, truth_offset_s, rest_config, mounting, score_window, truth_convention
        How to replay: each is a field of :class:`imu_dcm.replay.settings.ReplaySettings`,
        documented there.
    progress : callable(stage, fraction), optional
        Called as work advances (for a progress bar).
    diagnostics : Diagnostics, optional
        Where the warnings go, the reader's too (no process-wide state: replays may run in
        threads); without it they are warned when the replay ends or fails, in order.

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
    shown = path.path if isinstance(path, LogData) else path
    bias, init_q_w_b, offset = check_options(
        shown, time, method, bias, gyro_units, init_q_w_b, prefilter, truth_offset_s
    )
    settings = ReplaySettings(
        imu_topic, truth_topic, truth_frame, time, method, bias, gyro_units or "rad/s", init_q_w_b,
        prefilter, prefilter_config, offset, rest_config, check_mounting(mounting),
        check_score_window(score_window), check_convention(truth_convention),
    )  # fmt: skip
    notes = Diagnostics() if diagnostics is None else diagnostics
    try:
        result = _replay(path, settings, progress or (lambda stage, frac: None), notes)
    finally:
        if diagnostics is None:  # the user's call: warned here, once, at the edge
            notes.warn(stacklevel=2)
    summary = dataclasses.replace(result.summary, elapsed_s=_time.perf_counter() - t0)
    return dataclasses.replace(result, summary=summary)


def _rest_conflict(log: LogData, notes: Diagnostics, msg: str) -> LogData:
    """Evidence on rest that conflicts: a warning against an independent truth; against the
    vehicle's own estimate (which integrates this gyro, so it turns with its bias) one of the
    log's notes, since the conflict is then expected and says nothing about the log's health."""
    who = log.truth.estimate_of if log.truth is not None else ""
    if who:
        return dataclasses.replace(
            log, notes=(*log.notes, f"{msg} (the truth is {who}'s own estimate)")
        )
    notes.add(msg)
    return log


def _read(path, s: ReplaySettings, report, notes: Diagnostics) -> LogData:
    report("read", 0.0)
    log = read_log(
        path,
        imu_topic=s.imu_topic,
        truth_topic=s.truth_topic,
        truth_frame=s.truth_frame,
        progress=lambda frac: report("read", frac),
        diagnostics=notes,
    )
    report("read", 1.0)
    return log


def _remove_bias(
    s: ReplaySettings, g: Gyro, judged: Judged | None = None, windows: GyroWindows | None = None
) -> tuple[BiasEstimate, NDArray]:
    """The bias from rest (judged by the truth's motion too, when ``judged`` has a truth; its
    jumps, the truth's own, judge nothing); ``windows`` keeps the gyro's rest windows from one
    estimate to the next."""
    q, noise, r_t_g, motion = None, 0.0, None, None
    if judged is not None and judged.mounting.applied is not None:
        r_t_g = quat_as_matrix(judged.mounting.applied.q_t_g)
    if judged is not None and judged.aligned.truth is not None:
        q = scored_truth(judged.aligned.q_truth, g.t_s, judged.jumps)[0]
        tt = (judged.truth_t_ns - g.t_ns[0]) * 1e-9
        step_ok = np.ones(len(tt) - 1, dtype=bool)
        for j in judged.jumps:
            step_ok &= (tt[1:] < j.t0_s) | (tt[:-1] > j.t1_s)
        noise = truth_noise_rad(judged.aligned.truth.q_w_b, step_ok)
        motion = _motion(judged.aligned.truth, tt, g.t_s, q)
    bias_est = estimate_bias(
        g.omega, g.t_s, s.bias, s.rest_config, g.accel, truth_q_w_b=q, truth_noise=noise,
        r_t_g=r_t_g, vehicle=g.vehicle, motion=motion, windows=windows,
    )  # fmt: skip
    if bias_est.mode == "none" or (bias_est.mode == "auto" and not bias_est.segments):
        return bias_est, g.omega  # no bias: the rates themselves (x - 0 is x), no copy
    return bias_est, g.omega - bias_est.bias_b


def _motion(truth, tt: NDArray, t_s: NDArray, q: NDArray) -> Motion | None:
    """The truth's position and twist (where it has them) on the gyro rows, NaN where the
    scored truth has none (outside it, across its jumps)."""
    p_w, w_b = getattr(truth, "p_w", None), getattr(truth, "omega_b", None)
    if (p_w is None and w_b is None) or len(tt) < 3:
        return None
    none = ~row_finite(q)

    def on_rows(x):
        if x is None:
            return None
        out = np.stack([np.interp(t_s, tt, x[:, k]) for k in range(3)], axis=1)
        out[none] = np.nan
        return out

    rate = (len(tt) - 1) / (tt[-1] - tt[0]) if tt[-1] > tt[0] else 0.0
    return Motion(
        on_rows(p_w),
        position_noise_m(p_w) if p_w is not None else 0.0,
        on_rows(w_b),
        twist_noise_rad_s(w_b) if w_b is not None else 0.0,
        rate,
    )


def _prefilter(s: ReplaySettings, omega: NDArray, t_s: NDArray):
    if s.prefilter is None:
        return omega, None
    from imu_dcm.gyro.prefilter import prefilter as run_prefilter  # lazy: ~170 ms of CPU (filterpy)

    said = Diagnostics()  # its only warning, the gaps, was said once, by clean_imu
    pf = run_prefilter(omega, t_s, s.prefilter, s.prefilter_config, diagnostics=said)
    return np.asarray(pf.omega_b, dtype=float), pf.summary


def _integrate(s: ReplaySettings, omega, t_s, q_truth, anchors, topic, notes=None) -> NDArray:
    """Integrate each segment from its anchor (the truth there, or the initial attitude); the
    integrator's warnings go to ``notes`` once each, but gaps (said once, by clean_imu)."""
    said = Diagnostics()
    n = len(t_s)
    ends = [*anchors[1:], n]
    whole = anchors[0] == 0 and len(anchors) == 1 and n >= 2  # the integrator's array is it
    q_est = None if whole else np.full((n, 4), np.nan)
    for a, b in zip(anchors, ends, strict=True):
        q0 = q_truth[a] if np.all(np.isfinite(q_truth[a])) else s.init_q_w_b
        if q0 is None:
            q0 = np.array([0.0, 0.0, 0.0, 1.0])
        if whole:
            q_est = integrate_quat(omega, t_s, q0, s.method, diagnostics=said)
        elif b - a >= 2:
            q_est[a:b] = integrate_quat(omega[a:b], t_s[a:b], q0, s.method, diagnostics=said)
        else:
            q_est[a:b] = q0
    for line, category in dict.fromkeys(said.said):
        if notes is not None and category is not GapWarning:
            notes.add(line, category)
    finite = row_finite(q_est[anchors[0] :])
    if not finite.all():
        k = anchors[0] + int(np.flatnonzero(~finite)[0])
        raise LogError(
            f"Expected a finite attitude estimate, got NaN/Inf from sample {k} "
            f"(t = {t_s[k]:.3f} s) on {topic}"
        )
    return q_est


def _row_errors(q_est: NDArray, q_truth: NDArray) -> AttitudeError:
    """:func:`~imu_dcm.metrics.attitude_error_deg` of rows against rows, in one compiled pass
    (the same formulas: :func:`imu_dcm._kernels.calls.attitude_errors`); a quaternion it
    refuses is named by the numpy one."""
    out = np.empty((3, len(q_est)))
    if attitude_errors(np.ascontiguousarray(q_est), np.ascontiguousarray(q_truth), out) >= 0:
        return attitude_error_deg(q_est, q_truth)
    return AttitudeError(out[0], out[1], out[2])


def _score(q_est: NDArray, q_truth: NDArray) -> tuple[AttitudeError, NDArray]:
    both = row_finite(q_truth) & row_finite(q_est)
    unit = np.array([0, 0, 0, 1.0])
    out = [np.full(len(both), np.nan) for _ in range(3)]
    for a in range(0, len(both), BLOCK_ROWS):
        k = slice(a, a + BLOCK_ROWS)
        ok = both[k]
        every = bool(ok.all())  # the usual block: scored as it is, no masked copies
        err = _row_errors(
            q_est[k] if every else np.where(ok[:, None], q_est[k], unit),
            q_truth[k] if every else np.where(ok[:, None], q_truth[k], unit),
        )
        for dst, got in zip(
            out, (err.total_deg, err.inclination_deg, err.heading_deg), strict=True
        ):
            if every:
                dst[k] = got
            else:
                dst[k][ok] = got[ok]
    return AttitudeError(*out), both


def _replay(path, s: ReplaySettings, report, notes: Diagnostics) -> ReplayResult:
    log = path if isinstance(path, LogData) else _read(path, s, report, notes)
    own = len(notes.said)  # the summary's warnings: the replay's own, after the reader's
    g = prepare_gyro(log, s, notes)
    report("bias", 0.0)
    windows = GyroWindows()  # the gyro's rest windows, for both estimates
    bias_est, omega = _remove_bias(s, g, windows=windows)
    log, candidates = pick_truth(log, g, omega)
    log, convention = apply_convention(log, s, g, omega, notes)
    judged = judge_truth(log, s, g, omega, notes)
    if judged.aligned.truth is not None and isinstance(s.bias, str):  # its motion judges rest
        bias_est = omega = None  # the first estimate's arrays go before the second's come
        bias_est, omega = _remove_bias(s, g, judged, windows)
    del windows
    if bias_est.conflict:
        log = _rest_conflict(log, notes, bias_est.conflict)
    if judged.mounting.applied is not None:  # omega_T = R(q_t_g) omega_G, row by row
        omega = omega @ quat_as_matrix(judged.mounting.applied.q_t_g).T
    omega, pf_summary = _prefilter(s, omega, g.t_s)
    breaks = tuple(sorted((*judged.jumps, *judged.gaps), key=lambda j: j.t0_s))
    q_truth, anchors = scored_truth(judged.aligned.q_truth, g.t_s, breaks)
    report("integrate", 0.0)
    q_est = _integrate(s, omega, g.t_s, q_truth, anchors, log.imu.topic, notes)
    report("integrate", 1.0)
    if s.init_q_w_b is not None and np.isfinite(q_truth[anchors[0]]).all():
        notes.add(
            "--init-quat not used: the estimate starts from the truth's attitude "
            f"({judged.aligned.truth.topic}); --truth-topic none starts it from --init-quat",
        )
    inside, scored_on = window_mask(s.score_window, g.t_ns, log.custom_data, str(log.path))
    # what needs the estimate but not its score, on a thread of its own meanwhile (pure passes)
    side = Beside(
        _unscored, s, g, bias_est, judged, q_truth, anchors, omega, q_est, inside, log.imu.topic
    )
    (sampling, unbiased, ends), (error, both, summary) = side.then(
        _scored, log, s, g, bias_est, judged, pf_summary, anchors, q_est, q_truth, inside
    )
    summary = dataclasses.replace(
        summary,
        sampling_error_deg=sampling,
        truth_candidates=candidates,
        rms_error_no_bias_deg=unbiased,
        truth_convention=plain_convention(convention) if log.truth is not None else None,
        score_window=scored_on,
        notes=tuple(log.notes),  # the reader's findings (a refused channel, a better one used)
        warnings=notes.lines(own),
        **ends,
    )
    start = anchors[0]
    return ReplayResult(
        g.t_ns, g.t_s, g.omega, omega, bias_est.bias_b, q_est, q_truth, error, start,
        bias_est, summary,
    )  # fmt: skip


def _scored(log, s, g: Gyro, bias_est, judged: Judged, pf_summary, anchors, q_est, q_truth, inside):
    """The score and the summary of it: the errors, the rows scored (``both``, inside the
    score window), the automatic offset's RMS and the evaluation."""
    error, both = _score(q_est, q_truth)
    both = both if inside is None else both & inside
    auto_rms = auto_offset_rms_deg(judged.aligned, g.base, g.t_ns, q_est, anchors, both)
    summary = summarise(log, s, g, bias_est, judged, pf_summary, anchors, error, both)
    evaluation = evaluate(g.t_s, q_est, q_truth, both, anchors, error, summary.bias_rad_s)
    summary = dataclasses.replace(summary, evaluation=evaluation, offset_auto_rms_deg=auto_rms)
    return error, both, summary


def _unscored(s, g: Gyro, bias_est, judged: Judged, q_truth, anchors, omega, q_est, inside, topic):
    """What the estimate gives without its score: the sampling check (first segment), the
    RMS with no bias removed, and the outcome (final attitude, rotation, angle turned)."""
    a0 = anchors[0]
    end = anchors[1] if len(anchors) > 1 else len(g.t_s)
    sampling = sampling_error_deg(omega[a0:end], g.t_s[a0:end], q_est[a0:end], s.method)
    unbiased = _score_without_bias(s, g, bias_est, judged, q_truth, anchors, topic, inside)
    return sampling, unbiased, outcome(g.t_s, omega, q_est, a0)


def _score_without_bias(s, g: Gyro, bias_est, judged: Judged, q_truth, anchors, topic, inside):
    """The total RMS error with no bias removed, when a bias from rest was (None otherwise, or
    with a pre-filter, whose cost a second run would double), over the same scored window
    (``inside``: its mask, or None for all)."""
    if not bias_est.segments or s.prefilter is not None or not row_finite(q_truth).any():
        return None
    omega = g.omega
    if judged.mounting.applied is not None:
        omega = omega @ quat_as_matrix(judged.mounting.applied.q_t_g).T
    q_est = _integrate(s, omega, g.t_s, q_truth, anchors, topic)
    both = row_finite(q_truth) & row_finite(q_est)
    both = both if inside is None else both & inside
    return _rms_angle_deg(q_est, q_truth, both, heading_only(q_truth)) if both.any() else None


def _rms_angle_deg(q_est: NDArray, q_truth: NDArray, mask: NDArray, heading: bool) -> float:
    """The RMS over ``mask`` of the total (or the heading) error alone, deg: the arithmetic of
    :func:`imu_dcm.metrics.attitude_error_deg` for that one angle, so the same number as its
    ``total_deg`` (``heading_deg``) gives, without the other two angles; in blocks."""
    rows = np.flatnonzero(mask)
    out = np.empty(len(rows))
    for a in range(0, len(rows), BLOCK_ROWS):
        k = rows[a : a + BLOCK_ROWS]
        ex, ey, ez, ew = np.abs(product_planes(q_est[k], q_truth[k], conj_q=True))
        if heading:
            half = np.arctan2(ez, ew)
        else:
            half = np.arctan2(np.sqrt(ex * ex + ey * ey + ez * ez), ew)
        out[a : a + len(k)] = np.degrees(2.0 * half)
    return float(rms(out))

"""Replay a recorded gyro log through the integrator and compare the estimate with the truth.

Pipeline (:func:`replay`): read the log, choose the time base (:mod:`imu_dcm.replay.truth`),
clean the gyro samples (:mod:`imu_dcm.replay.clean`: NaN/Inf, implausible rates, wild stamps,
file order, duplicates, gaps), convert deg/s when asked (and warn with the evidence when the
rates look like deg/s), check that the truth's rotation rate follows the gyro, slerp the truth
at the gyro stamps inside its coverage, remove the gyro bias (:mod:`imu_dcm.replay.bias`),
estimate the mounting between the gyro's frame and the truth's body frame
(:mod:`imu_dcm.replay.mounting`) and compare it with the one ``/tf_static`` declares
(:mod:`imu_dcm.replay.mounting_tf`), find truth jumps the gyro does not show, optionally
pre-filter, integrate from the truth at the first gyro sample inside its coverage (and again
after each truth jump), and measure the attitude error (total, inclination, heading) over the
segments between jumps.

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

from imu_dcm.errors import Diagnostics, GapWarning, LogError
from imu_dcm.integrate import integrate_quat
from imu_dcm.logio import LogData, read_log
from imu_dcm.logio.ned import in_log_axes
from imu_dcm.metrics import AttitudeError, attitude_error_deg, rms
from imu_dcm.replay.bias import BIAS_RULE, BiasEstimate, RestConfig, estimate_bias
from imu_dcm.replay.clean import CleanedImu, _deg_evidence, clean_imu, truth_rate_ratio
from imu_dcm.replay.convention import ConventionChoice, check_convention, choose_convention, convert
from imu_dcm.replay.mounting import Mounting, estimate_mounting, from_rotation
from imu_dcm.replay.mounting_tf import MountingChoice, choose_mounting, tf_mounting
from imu_dcm.replay.offset_hint import auto_offset_rms_deg
from imu_dcm.replay.options import check_options
from imu_dcm.replay.outcome import outcome
from imu_dcm.replay.sampling import sampling_error_deg
from imu_dcm.replay.settings import ReplaySettings, check_mounting
from imu_dcm.replay.stats import evaluate
from imu_dcm.replay.summary import ReplayResult, ReplaySummary
from imu_dcm.replay.truth import (
    JUMP_DEG,
    AlignedTruth,
    TruthJump,
    align_truth,
    check_truth,
    choose_time,
    find_jumps,
)
from imu_dcm.replay.window import check_score_window, window_mask
from imu_dcm.resample import slerp_truth
from imu_dcm.rest import Motion, position_noise_m, truth_noise_rad, twist_noise_rad_s
from imu_dcm.so3 import median, quat_angle_rad, quat_as_matrix, row_finite, row_norm
from imu_dcm.stamps import NS_PER_UNIT, timing_doubt

__all__ = ["CleanedImu", "ReplayResult", "ReplaySummary", "clean_imu", "replay", "slerp_truth"]

DEG = np.pi / 180.0


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
        How to replay: each is a field of :class:`imu_dcm.replay.settings.ReplaySettings`
        (``init_q_w_b`` is its ``q_init``), documented there.
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
    bias, q_init, offset = check_options(
        shown, time, method, bias, gyro_units, init_q_w_b, prefilter, truth_offset_s
    )
    settings = ReplaySettings(
        imu_topic, truth_topic, truth_frame, time, method, bias, gyro_units or "rad/s", q_init,
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


def _record(obj) -> dict:
    """A reader record (dataclass or plain object) as a dict for the summary."""
    if dataclasses.is_dataclass(obj):
        return dataclasses.asdict(obj)
    return dict(vars(obj))


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


class _Gyro:
    """The cleaned gyro of a replay: time base, stamps, rates (rad/s), accelerometer, and the
    autopilot's (landed, armed) state on its rows (or None)."""

    __slots__ = ("base", "clean", "t_ns", "t_s", "omega", "accel", "vehicle")

    def __init__(
        self,
        base: str,
        clean: CleanedImu,
        t_ns: NDArray[np.int64],
        t_s: NDArray[np.float64],
        omega: NDArray[np.float64],
        accel: NDArray[np.float64] | None,
    ) -> None:
        self.base, self.clean, self.t_ns, self.t_s = base, clean, t_ns, t_s
        self.omega, self.accel = omega, accel
        self.vehicle: tuple[NDArray, NDArray] | None = None


class _Judged:
    """What the truth side found: truth at the gyro stamps, jumps, mounting.

    ``truth_t_ns``: the stamps of the truth used, at the applied offset (or None).
    """

    __slots__ = ("aligned", "truth_t_ns", "jumps", "mounting", "gaps")

    def __init__(
        self,
        aligned: AlignedTruth,
        truth_t_ns: NDArray[np.int64] | None,
        jumps: tuple,
        mounting: MountingChoice,
        gaps: tuple = (),
    ) -> None:
        self.aligned, self.truth_t_ns, self.jumps, self.mounting = (
            aligned,
            truth_t_ns,
            jumps,
            mounting,
        )
        self.gaps = gaps  # gyro gaps re-anchored (TruthJump records over each gap)


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


def _gyro(log: LogData, s: ReplaySettings, notes: Diagnostics) -> _Gyro:
    """Time base, cleaning and units of the gyro samples."""
    imu, truth = log.imu, log.truth
    base, why = choose_time(
        s.time,
        imu.t_ns,
        imu.log_t_ns,
        truth.t_ns if truth is not None else None,
        truth.log_t_ns if truth is not None else None,
    )
    if why:
        notes.add(f"time: using log time, not header stamps: {why}")
    imu_t = imu.t_ns if base == "header" else imu.log_t_ns
    scale = DEG if s.gyro_units == "deg/s" else 1.0
    omega = np.asarray(imu.omega_b, dtype=float)
    w = omega * scale if scale != 1.0 else omega  # no copy
    clean = clean_imu(imu_t, w, imu.topic, diagnostics=notes)
    n = len(clean.t_ns)
    if n < 2:
        hint = ""
        if base == "header" and len(np.unique(imu.log_t_ns[:1000])) > 1:
            hint = "; the log times differ: try --time log"
        raise LogError(f"Expected at least 2 valid gyro samples on {imu.topic}, got {n}{hint}")
    doubt = timing_doubt(clean.t_ns, omega_b=clean.omega_b)
    if doubt is not None:
        clause, fix = doubt
        factor = NS_PER_UNIT["s"] // NS_PER_UNIT[fix] if fix else 0
        # a log's stamps have no declared unit: say the factor, not a unit read as seconds
        clause = clause.replace(f"; as {fix}:", f"; with steps {factor}x shorter:")
        hint = (
            f"; was it converted with a time unit {factor}x too large (for a CSV declared in "
            f"s: convert-csv --time-units {fix})?"
        )
        notes.add(f"{imu.topic}: stamps no IMU produces: {clause}{hint if fix else ''}")
    t_s = (clean.t_ns - clean.t_ns[0]).astype(np.float64) * 1e-9
    g = _Gyro(base, clean, clean.t_ns, t_s, clean.omega_b, _accel(imu, clean, notes))
    if log.vehicle_state is not None:
        g.vehicle = log.vehicle_state.at(clean.t_ns)
    return g


def _accel(imu, clean: CleanedImu, notes: Diagnostics) -> NDArray | None:
    """The accelerometer on the cleaned gyro rows, m/s², or None (absent or incomplete)."""
    if imu.accel_b is None:
        return None
    acc = np.asarray(imu.accel_b, dtype=float)[clean.index]
    if not np.all(np.isfinite(acc)):
        bad = int(np.count_nonzero(~row_finite(acc)))
        notes.add(
            f"{imu.topic}: accelerometer missing on {bad} of {len(acc)} samples; rest judged "
            f"from the gyro alone",
            None,  # in the summary, not warned
        )
        return None
    return acc


def _judge_truth(
    log: LogData, s: ReplaySettings, g: _Gyro, omega: NDArray, notes: Diagnostics
) -> _Judged:
    """Offset, rate check, jumps and mounting of the truth against the (bias-free) gyro."""
    imu = log.imu
    aligned = align_truth(
        log.truth, g.base, g.t_ns, g.omega, s.truth_offset_s, imu.log_t_ns,
        notes.add,
    )  # fmt: skip
    if s.gyro_units == "rad/s":
        evidence = _deg_evidence(g.omega, g.t_s, aligned.q_truth)
        if evidence:
            notes.add(
                f"{imu.topic}: the rates look like deg/s: {evidence}; pass "
                f"--gyro-units deg/s to convert",
            )
    else:  # declared deg/s: a rad/s log converted reads 57.3x slower than its truth turns
        ratio = truth_rate_ratio(g.omega, g.t_s, aligned.q_truth)
        if ratio is not None and abs(ratio * (180 / np.pi) - 1) < 0.2:
            notes.add(
                f"{imu.topic}: the rates look like rad/s: converted from deg/s, the gyro rate "
                f"is 1/{1 / ratio:.1f} of the truth's rotation rate (1/57.3 for rad/s read as "
                f"deg/s); drop --gyro-units deg/s",
            )
    truth = aligned.truth
    if truth is None:
        given = None if isinstance(s.mounting, str) else _given(s.mounting)
        return _Judged(
            aligned, None, (), MountingChoice(given, given, "given" if given else "", None, "")
        )
    tt = (truth.t_ns if g.base == "header" else truth.log_t_ns) + np.int64(
        round(aligned.offset_s * 1e9)
    )
    residual = 0.0  # the measured truth lag, not applied to the scoring with a fixed offset
    if s.truth_offset_s != "auto" and aligned.check and aligned.check.shift_s is not None:
        residual = aligned.check.shift_s
    shift = np.int64(round(residual * 1e9))
    # jumps are judged with the truth aligned to the gyro (a lagging truth would turn after the
    # gyro and look like a jump), then said and scored on the truth's own stamps
    on_gyro = find_jumps(g.t_ns, omega, tt + shift, truth.q_w_b)
    t00 = int(g.t_ns[0])
    skip = tuple((t00 + round(j.t0_s * 1e9), t00 + round(j.t1_s * 1e9)) for j in on_gyro)
    jumps = tuple(
        dataclasses.replace(j, t0_s=j.t0_s - residual, t1_s=j.t1_s - residual) for j in on_gyro
    )
    if jumps:
        shown = "; ".join(j.describe() for j in jumps[:5])
        more = f" and {len(jumps) - 5} more" if len(jumps) > 5 else ""
        notes.add(
            f"truth {truth.topic} jumps where the gyro does not: {shown}{more}; the estimate "
            f"re-anchors to the truth after each jump and the "
            f"{len(_scored_truth(aligned.q_truth, g.t_s, jumps)[1])} segments between jumps are "
            f"scored",
        )
    est = estimate_mounting(g.t_ns, omega, tt + shift, truth.q_w_b, skip)
    declared = tf_mounting(log.static_transforms, imu.topic, imu.frame_id, truth)
    frames = f"{imu.frame_id or 'the gyro frame'} -> {truth.child_frame_id or truth.topic}"
    given = None if isinstance(s.mounting, str) else _given(s.mounting)
    choice = choose_mounting(s.mounting, est, declared, given, frames)
    if choice.line:
        notes.add(choice.line)
    gaps = _unseen_gaps(g, omega, aligned.q_truth, notes)
    return _Judged(aligned, tt, jumps, choice, gaps)


def _unseen_gaps(g: _Gyro, omega: NDArray, q_truth: NDArray, notes: Diagnostics) -> tuple:
    """The gyro's gaps whose rotation it did not see: where the truth turns across the gap, or
    the integrator's bridge of it (the mean of the rates at its ends times its length) would,
    more than a truth jump's :data:`JUMP_DEG`. The estimate re-anchors after each."""
    out = []
    speed = row_norm(omega)
    for t_gap, length in g.clean.gaps:
        k = int(np.searchsorted(g.t_s, t_gap))
        if k + 1 >= len(g.t_s) or not (row_finite(q_truth[k : k + 2]).all()):
            continue
        truth_deg = float(np.degrees(quat_angle_rad(q_truth[k], q_truth[k + 1])))
        bridge_deg = float(np.degrees(0.5 * (speed[k] + speed[k + 1]) * length))
        if max(truth_deg, bridge_deg) > JUMP_DEG:
            out.append(TruthJump(float(g.t_s[k]), float(g.t_s[k + 1]), truth_deg, bridge_deg))
    if out:
        shown = "; ".join(
            f"{j.t1_s - j.t0_s:.3f} s at {j.t0_s:.3f} s (the truth turns {j.truth_deg:.1f}°, "
            f"the integrator would bridge {j.gyro_deg:.1f}°)"
            for j in out[:5]
        )
        more = f" and {len(out) - 5} more" if len(out) > 5 else ""
        notes.add(
            f"{len(out)} gap{'s' if len(out) > 1 else ''} the gyro did not see: {shown}{more}; "
            f"the estimate re-anchors to the truth after each and the segments are scored",
        )
    return tuple(out)


def _given(q) -> Mounting:
    return from_rotation(q, "given", determined=0, fit=float("nan"))


def _pick_truth(log: LogData, g: _Gyro, omega: NDArray) -> tuple[LogData, tuple[dict, ...]]:
    """Among an automatically picked truth and the log's other attitude candidates, the one
    whose rate follows the gyro best: independent references before estimates (odometry, the
    IMU's own orientation, an autopilot's), then the higher rate-norm correlation."""
    if log.truth is None or not log.truth.auto or not log.truth_candidates:
        return log, ()
    rows = []
    for cand in (log.truth, *log.truth_candidates):
        tt = cand.t_ns if g.base == "header" else cand.log_t_ns
        chk = check_truth(g.t_ns, omega, tt, cand.q_w_b)
        corr = chk.correlation if chk.correlation is not None else -1.0
        rows.append(((chk.checked and chk.follows, not cand.estimate_of, corr), cand, chk))
    best = max(range(len(rows)), key=lambda i: rows[i][0])
    described = tuple(
        {
            "topic": cand.topic,
            "type": cand.type,
            "child_frame_id": cand.child_frame_id,
            "estimate_of": cand.estimate_of,
            "follows": bool(chk.checked and chk.follows),
            "correlation": chk.correlation,
            "residual_rad_s": chk.residual_rad_s,
            "picked": i == best,
        }
        for i, (_key, cand, chk) in enumerate(rows)
    )
    return dataclasses.replace(log, truth=rows[best][1]), described


def _convention(log: LogData, s: ReplaySettings, g: _Gyro, omega, notes):
    """The truth read in the convention stated, or the one its body rates fit clearly."""
    truth = log.truth
    if truth is None:
        return log, ConventionChoice()
    tt = truth.t_ns if g.base == "header" else truth.log_t_ns
    choice = choose_convention(g.t_ns, omega, tt, truth.q_w_b, s.truth_convention, truth.topic)
    if choice.line:
        notes.add(choice.line)
    if choice.used == "as-is":
        return log, choice
    q = convert(truth.q_w_b, choice.used)
    return dataclasses.replace(log, truth=dataclasses.replace(truth, q_w_b=q)), choice


def _plain_convention(c: ConventionChoice) -> dict:
    return {"used": c.used, "how": c.how, "fits": [list(f) for f in c.fits], "line": c.line}


def _remove_bias(
    s: ReplaySettings, g: _Gyro, judged: _Judged | None = None
) -> tuple[BiasEstimate, NDArray]:
    """The bias from rest (judged by the truth's motion too, when ``judged`` has a truth; its
    jumps, the truth's own, judge nothing)."""
    q, noise, r_t_g, motion = None, 0.0, None, None
    if judged is not None and judged.mounting.applied is not None:
        r_t_g = quat_as_matrix(judged.mounting.applied.q_t_g)
    if judged is not None and judged.aligned.truth is not None:
        q = _scored_truth(judged.aligned.q_truth, g.t_s, judged.jumps)[0]
        tt = (judged.truth_t_ns - g.t_ns[0]) * 1e-9
        step_ok = np.ones(len(tt) - 1, dtype=bool)
        for j in judged.jumps:
            step_ok &= (tt[1:] < j.t0_s) | (tt[:-1] > j.t1_s)
        noise = truth_noise_rad(judged.aligned.truth.q_w_b, step_ok)
        motion = _motion(judged.aligned.truth, tt, g.t_s, q)
    bias_est = estimate_bias(
        g.omega, g.t_s, s.bias, s.rest_config, g.accel, truth_q_w_b=q, truth_noise=noise,
        r_t_g=r_t_g, vehicle=g.vehicle, motion=motion,
    )  # fmt: skip
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
    from imu_dcm.prefilter import prefilter as run_prefilter

    said = Diagnostics()  # its only warning, the gaps, was said once, by clean_imu
    pf = run_prefilter(omega, t_s, s.prefilter, s.prefilter_config, diagnostics=said)
    return np.asarray(pf.omega_b, dtype=float), pf.summary


def _scored_truth(q_truth: NDArray, t_s: NDArray, jumps) -> tuple[NDArray, list[int]]:
    """Truth usable for scoring (NaN across each jump) and the anchor samples of the segments."""
    q = q_truth.copy() if jumps else q_truth  # a copy only where jumps are blanked out
    has = row_finite(q)
    anchors = [int(np.flatnonzero(has)[0])] if has.any() else [0]
    for j in jumps:
        q[(t_s > j.t0_s) & (t_s < j.t1_s)] = np.nan
        after = np.flatnonzero(has & (t_s >= j.t1_s) & (np.arange(len(t_s)) > anchors[-1]))
        if len(after):
            anchors.append(int(after[0]))
    return q, anchors


def _integrate(s: ReplaySettings, omega, t_s, q_truth, anchors, topic, notes=None) -> NDArray:
    """Integrate each segment from its anchor (the truth there, or the initial attitude); the
    integrator's warnings go to ``notes`` once each, but gaps (said once, by clean_imu)."""
    said = Diagnostics()
    n = len(t_s)
    q_est = np.full((n, 4), np.nan)
    ends = [*anchors[1:], n]
    for a, b in zip(anchors, ends, strict=True):
        q0 = q_truth[a] if np.all(np.isfinite(q_truth[a])) else s.q_init
        if q0 is None:
            q0 = np.array([0.0, 0.0, 0.0, 1.0])
        if b - a >= 2:
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


#: Samples scored at a time: each error depends on its own sample, so blocks give the
#: whole-log result exactly, without whole-log temporaries (~170 B a sample).
SCORE_BLOCK = 1 << 17


def _score(q_est: NDArray, q_truth: NDArray) -> tuple[AttitudeError, NDArray]:
    both = row_finite(q_truth) & row_finite(q_est)
    unit = np.array([0, 0, 0, 1.0])
    out = [np.full(len(both), np.nan) for _ in range(3)]
    for a in range(0, len(both), SCORE_BLOCK):
        k = slice(a, a + SCORE_BLOCK)
        ok = both[k]
        err = attitude_error_deg(
            np.where(ok[:, None], q_est[k], unit), np.where(ok[:, None], q_truth[k], unit)
        )
        for dst, got in zip(
            out, (err.total_deg, err.inclination_deg, err.heading_deg), strict=True
        ):
            dst[k][ok] = got[ok]
    return AttitudeError(*out), both


def _replay(path, s: ReplaySettings, report, notes: Diagnostics) -> ReplayResult:
    log = path if isinstance(path, LogData) else _read(path, s, report, notes)
    own = len(notes.said)  # the summary's warnings: the replay's own, after the reader's
    g = _gyro(log, s, notes)
    report("bias", 0.0)
    bias_est, omega = _remove_bias(s, g)
    log, candidates = _pick_truth(log, g, omega)
    log, convention = _convention(log, s, g, omega, notes)
    judged = _judge_truth(log, s, g, omega, notes)
    if judged.aligned.truth is not None and isinstance(s.bias, str):  # its motion judges rest
        bias_est, omega = _remove_bias(s, g, judged)
    if bias_est.conflict:
        log = _rest_conflict(log, notes, bias_est.conflict)
    if judged.mounting.applied is not None:  # omega_T = R(q_t_g) omega_G, row by row
        omega = omega @ quat_as_matrix(judged.mounting.applied.q_t_g).T
    omega, pf_summary = _prefilter(s, omega, g.t_s)
    breaks = tuple(sorted((*judged.jumps, *judged.gaps), key=lambda j: j.t0_s))
    q_truth, anchors = _scored_truth(judged.aligned.q_truth, g.t_s, breaks)
    report("integrate", 0.0)
    q_est = _integrate(s, omega, g.t_s, q_truth, anchors, log.imu.topic, notes)
    report("integrate", 1.0)
    error, both = _score(q_est, q_truth)
    if s.q_init is not None and np.isfinite(q_truth[anchors[0]]).all():
        notes.add(
            "--init-quat not used: the estimate starts from the truth's attitude "
            f"({judged.aligned.truth.topic}); --truth-topic none starts it from --init-quat",
        )
    inside, scored_on = window_mask(s.score_window, g.t_ns, log.custom_data, str(log.path))
    both = both if inside is None else both & inside
    auto_rms = auto_offset_rms_deg(judged.aligned, g.base, g.t_ns, q_est, anchors, both)
    summary = _summary(log, s, g, bias_est, judged, pf_summary, anchors, error, both)
    unbiased = _score_without_bias(s, g, bias_est, judged, q_truth, anchors, log.imu.topic, inside)
    end = anchors[1] if len(anchors) > 1 else len(g.t_s)
    a0 = anchors[0]
    sampling = sampling_error_deg(omega[a0:end], g.t_s[a0:end], q_est[a0:end], s.method)
    summary = dataclasses.replace(
        summary,
        sampling_error_deg=sampling,
        truth_candidates=candidates,
        rms_error_no_bias_deg=unbiased,
        truth_convention=_plain_convention(convention) if log.truth is not None else None,
    )
    evaluation = evaluate(g.t_s, q_est, q_truth, both, anchors, error, summary.bias_rad_s)
    summary = dataclasses.replace(summary, evaluation=evaluation)
    start = anchors[0]
    summary = dataclasses.replace(
        summary,
        truth_candidates=candidates,
        score_window=scored_on,
        notes=tuple(log.notes),  # the reader's findings (a refused channel, a better one used)
        warnings=notes.lines(own),
        offset_auto_rms_deg=auto_rms,
        **outcome(g.t_s, omega, q_est, start),
    )
    return ReplayResult(
        g.t_ns, g.t_s, g.omega, omega, bias_est.bias_b, q_est, q_truth, error, start,
        bias_est, summary,
    )  # fmt: skip


def _score_without_bias(s, g: _Gyro, bias_est, judged: _Judged, q_truth, anchors, topic, inside):
    """The total RMS error with no bias removed, when a bias from rest was (None otherwise, or
    with a pre-filter, whose cost a second run would double), over the same scored window
    (``inside``: its mask, or None for all)."""
    if not bias_est.segments or s.prefilter is not None or not row_finite(q_truth).any():
        return None
    omega = g.omega
    if judged.mounting.applied is not None:
        omega = omega @ quat_as_matrix(judged.mounting.applied.q_t_g).T
    q_est = _integrate(s, omega, g.t_s, q_truth, anchors, topic)
    error, both = _score(q_est, q_truth)
    both = both if inside is None else both & inside
    scored = error.heading_deg if _heading_only(q_truth) else error.total_deg
    return float(rms(scored[both])) if both.any() else None


#: A truth component this small is zero by construction (float32 rounding of a unit
#: quaternion's components is ~6e-8).
PLANAR_TOL = 1e-9


def _heading_only(q_truth: NDArray) -> bool:
    """The truth turns (its heading spans more than a truth jump's :data:`JUMP_DEG`) yet every
    sample turns about the world's vertical only (x and y components zero): planar by
    construction. A still, level truth is not: it is scored whole."""
    q = q_truth[row_finite(q_truth)]
    if not len(q) or float(np.max(np.abs(q[:, :2]))) > PLANAR_TOL:
        return False
    heading = np.unwrap(2.0 * np.arctan2(q[:, 2], q[:, 3]))
    return float(np.degrees(np.ptp(heading))) > JUMP_DEG


def _segments(t_s: NDArray, anchors: list[int], scored: NDArray, both) -> tuple:
    """Each segment's times and RMS of ``scored`` (the total error, or the heading's)."""
    out = []
    for a, b in zip(anchors, [*anchors[1:], len(t_s)], strict=True):
        e = scored[a:b][both[a:b]]
        out.append(
            {
                "start_s": float(t_s[a]),
                "end_s": float(t_s[b - 1]),
                "samples": int(len(e)),
                "rms_error_deg": float(rms(e)) if len(e) else None,
            }
        )
    return tuple(out)


def _summary(log, s, g: _Gyro, bias_est, judged: _Judged, pf_summary, anchors, error, both):
    """The :class:`ReplaySummary` of a replay."""
    imu, aligned, truth = log.imu, judged.aligned, judged.aligned.truth
    start, n, t_s = anchors[0], len(g.t_s), g.t_s
    clean = g.clean
    q0 = np.asarray(judged.aligned.q_truth[start]) if both.any() else s.q_init
    q0 = np.array([0.0, 0.0, 0.0, 1.0]) if q0 is None or not np.all(np.isfinite(q0)) else q0

    def stat_(a: NDArray, f) -> float | None:
        return float(f(a[both])) if both.any() else None

    # a truth that carries only heading (2D odometry, a planar pose) is scored on heading only
    planar = _heading_only(judged.aligned.q_truth)
    total = error.heading_deg if planar else error.total_deg

    mount = judged.mounting
    return ReplaySummary(
        path=str(log.path),
        container=getattr(log, "container", "ros2 mcap"),
        samples=int(n),
        samples_estimated=int(n - start),
        duration_s=float(t_s[-1]),
        rate_hz=1.0 / median(np.diff(t_s)),
        imu_topic=imu.topic,
        imu_type=imu.type,
        truth_topic=truth.topic if truth is not None else None,
        truth_type=truth.type if truth is not None else None,
        time=g.base,
        method=s.method,
        gyro_units=s.gyro_units,
        bias_mode=bias_est.mode,
        bias_rad_s=tuple(float(x) for x in bias_est.bias_b[start:].mean(axis=0)),
        log_axes=getattr(imu, "log_axes", ""),
        bias_log_rad_s=in_log_axes(
            bias_est.bias_b[start:].mean(axis=0), getattr(imu, "log_axes", "")
        ),
        bias_segments=tuple(x.as_dict() for x in bias_est.segments),
        prefilter=s.prefilter,
        prefilter_summary=pf_summary,
        start_time_s=float(t_s[start]),
        initial_q_w_b=tuple(float(x) for x in q0),
        truth_samples_used=int(both.sum()),
        truth_offset_s=aligned.offset_s,
        truth_check=dataclasses.asdict(aligned.check) if aligned.check is not None else None,
        rms_error_deg=stat_(total, rms),
        max_error_deg=stat_(total, np.max),
        rms_inclination_deg=None if planar else stat_(error.inclination_deg, rms),
        max_inclination_deg=None if planar else stat_(error.inclination_deg, np.max),
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
        bias_rule=BIAS_RULE if bias_est.mode == "auto" else "",
        rest_confirmed=bias_est.confirmed,
        no_rest=bias_est.no_rest,
        rest_conflict=bias_est.conflict,
        mounting=dataclasses.asdict(mount.reported) if mount.reported is not None else None,
        mounting_applied=mount.applied is not None,
        mounting_used=mount.used,
        mounting_tf=mount.tf,
        truth_jumps=tuple(dataclasses.asdict(j) for j in judged.jumps),
        scored_segments=_segments(t_s, anchors, total, both) if judged.jumps or judged.gaps else (),
        gap_reanchors=tuple(dataclasses.asdict(j) for j in judged.gaps),
        scored_on="heading" if planar else "attitude",
        truth_estimate_of=getattr(truth, "estimate_of", "") if truth is not None else "",
    )

"""What a replay returns: :class:`ReplayResult` (arrays) and :class:`ReplaySummary` (figures),
both frozen, and the summary as text for a person (:func:`format_summary`)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from imu_dcm.app.summary import RunFigures
from imu_dcm.metrics import AttitudeError
from imu_dcm.replay.bias import BiasEstimate
from imu_dcm.replay.mounting import APPLY_DEG, Mounting
from imu_dcm.replay.offset_hint import shift_ms
from imu_dcm.replay.outcome import outcome_lines
from imu_dcm.replay.sampling import TOO_SLOW_SHARE
from imu_dcm.replay.stats import evaluation_lines

__all__ = ["ReplayResult", "ReplaySummary", "format_summary"]


@dataclass(frozen=True)
class ReplaySummary(RunFigures):
    """The figures of one replay (angles in degrees, rates rad/s, times s since the first sample):
    those every run reports (:class:`imu_dcm.app.summary.RunFigures`, each documented there;
    :meth:`~imu_dcm.app.summary.RunFigures.to_dict` makes the JSON) and the replay's own.

    Error fields are None when nothing was scored (no truth, or truth rejected: then
    ``truth_rejected`` names the topic that did not follow the gyro). ``gaps`` holds
    (t_s, length_s) pairs. ``warnings`` holds the one-line warnings of the cleaning and the
    truth checks, kept per replay so that replays in threads do not mix (the reader's own are
    summed up in ``stopped_at`` / ``damage``). ``truth_check`` is the rate comparison of truth
    and gyro (:class:`imu_dcm.replay.rate_check.TruthCheck`) as a dict, or None without truth.
    ``mounting`` is the motion's estimate of the mounting (or the quaternion given);
    ``final_q_w_b``, ``rotation_deg``, ``turned_deg`` are the result with or without truth
    (:mod:`imu_dcm.replay.outcome`); ``written`` lists the files and folders the command wrote
    (empty from Python). ``score_window`` says which samples were scored
    (:mod:`imu_dcm.replay.window`; ``truth_samples_used`` counts them); ``offset_auto_rms_deg``
    is the RMS ``--truth-offset auto`` would give (:mod:`imu_dcm.replay.offset_hint`; None when
    it was applied or the shift is under half a step). ``mounting_used`` says
    which rotation was applied to the rates
    ("estimated", "given", "tf" for the one ``/tf_static`` declares, "" for none);
    ``mounting_tf`` is the declared one with its frames and its distance to the estimate
    (:mod:`imu_dcm.replay.mounting_tf`), or None.
    ``evaluation`` holds the error statistics, per-axis errors, drift rates and the bias
    self-check (:func:`imu_dcm.replay.stats.evaluate`), or None when nothing was scored.
    """

    path: str
    container: str
    time: str
    prefilter: str | None
    prefilter_summary: dict | None
    truth_offset_s: float
    truth_check: dict | None
    implausible_t_s: tuple[float, ...]
    sorted_out_of_order: int
    stopped_at: str | None
    channels: tuple[dict, ...]
    damage: tuple[dict, ...] = ()
    truth_rejected: str | None = None
    warnings: tuple[str, ...] = ()
    bias_rule: str = ""
    rest_confirmed: bool = False
    no_rest: str = ""
    rest_conflict: str = ""
    rest_agreement: dict | None = None
    rms_error_no_bias_deg: float | None = None
    truth_convention: dict | None = None
    gap_reanchors: tuple[dict, ...] = ()
    sampling_error_deg: float | None = None
    scored_on: str = "attitude"
    mounting: dict | None = None
    mounting_applied: bool = False
    mounting_used: str = ""
    mounting_tf: dict | None = None
    truth_jumps: tuple[dict, ...] = ()
    scored_segments: tuple[dict, ...] = ()
    truth_estimate_of: str = ""
    truth_candidates: tuple[dict, ...] = ()
    rotation_deg: float | None = None
    turned_deg: float | None = None
    written: tuple[str, ...] = ()
    score_window: str = "all"
    offset_auto_rms_deg: float | None = None
    notes: tuple[str, ...] = ()
    log_axes: str = ""
    bias_log_rad_s: tuple[float, float, float] | None = None
    evaluation: dict | None = None


def _rest_evidence(s: ReplaySummary) -> str:
    """Which signals judged the rests, e.g. "by gyro floor, accelerometer, truth (part)"."""
    seen: list[str] = []
    for seg in s.bias_segments:
        for e in seg.get("evidence", ()):
            if e not in seen:
                seen.append(e)
    if s.rest_confirmed:
        return "still by " + ", ".join(seen)
    return "unconfirmed: gyro floor alone, mean rate under 2 °/s"


def _sampling_line(s: ReplaySummary) -> list[str]:
    """The method's own error when it is half the score or more: the rate is too low."""
    e, r = s.sampling_error_deg, s.rms_error_deg
    if e is None or r is None or not r > 0 or e < TOO_SLOW_SHARE * r:
        return []
    line = (
        f"sampling   {s.rate_hz:.4g} Hz is too slow for this motion: the method's own error "
        f"is about {_fmt(e)} RMS (Richardson, from the rates at half the rate), "
        f"{100 * e / r:.0f} % of the score"
    )
    return [line]


def _bias_choice_line(s: ReplaySummary) -> list[str]:
    """The score without the bias, when removing it changes the score by more than 2x."""
    a, b = s.rms_error_deg, s.rms_error_no_bias_deg
    if a is None or b is None or not (a > 0 and b > 0) or max(a / b, b / a) <= 2.0:
        return []
    line = (
        f"error      without the bias from rest: total RMS {_fmt(b)} (the bias choice changes "
        f"the score {max(a / b, b / a):.1f}x: --bias none scores without it)"
    )
    return [line]


def _bias_axes(s: ReplaySummary) -> str:
    """For a log whose axes were converted (FRD): the frame of the bias printed, and the bias
    in the log's own axes."""
    if s.bias_log_rad_s is None:
        return ""
    b = np.degrees(s.bias_log_rad_s)
    return (
        f" in FLU, the replay's axes; ({b[0]:+.3f}, {b[1]:+.3f}, {b[2]:+.3f}) °/s in "
        f"{s.log_axes}, the log's axes"
    )


@dataclass(frozen=True)
class ReplayResult:
    """Everything a replay produced. Arrays cover the N cleaned gyro samples.

    Attributes
    ----------
    t_ns : int64 (N,) — gyro stamps, ns (on the chosen time base).
    t_s : float64 (N,) — seconds since the first gyro sample.
    omega_raw_b : float64 (N, 3) — gyro rates as read (after unit conversion), body, rad/s.
    omega_b : float64 (N, 3) — rates as integrated (bias removed, turned into the truth's body
        frame when a mounting was applied, pre-filtered), rad/s.
    bias_b : float64 (N, 3) — bias removed at each sample, gyro axes, rad/s.
    q_est : float64 (N, 4) — estimate ``q_w_b`` ``[x, y, z, w]``; NaN before ``start_index``.
    q_truth : float64 (N, 4) — truth slerped at the gyro stamps; NaN outside its coverage or
        when the truth was rejected.
    error : AttitudeError — per-sample errors, deg; NaN where there is no truth or estimate.
    start_index : int — first estimated sample (the first inside truth coverage, or 0).
    bias : BiasEstimate — rest segments and mode.
    summary : ReplaySummary
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
    summary: ReplaySummary


def _fmt(x: float | None, unit: str = "°") -> str:
    """Two decimals, or two significant digits below 0.01 (so 1.2e-05° does not read as 0.00°)."""
    if x is None:
        return "n/a"
    return f"{x:.2f}{unit}" if x == 0.0 or abs(x) >= 0.01 else f"{x:.2g}{unit}"


def _candidates_line(cands: tuple[dict, ...]) -> str:
    def one(c: dict) -> str:
        name = c["topic"] + (f" [{c['child_frame_id']}]" if c.get("child_frame_id") else "")
        corr = "n/a" if c["correlation"] is None else f"{c['correlation']:.2f}"
        who = f", {c['estimate_of']}" if c["estimate_of"] else ""
        follows = "" if c["follows"] else ", does not follow"
        return f"{name} (correlation {corr}{who}{follows})"

    picked = next(c for c in cands if c["picked"])
    others = "; ".join(one(c) for c in cands if not c["picked"])
    return (
        f"truth pick {one(picked)} of {len(cands)} attitude candidates, by how its rate follows "
        f"the gyro (independent references first); others: {others}"
    )


def _mounting_lines(s: ReplaySummary) -> list[str]:
    """The estimated (or given) mounting and the declared one, one line each."""
    fields = {f.name for f in dataclasses.fields(Mounting)}
    lines = []
    if s.mounting:
        mount = Mounting(**{k: v for k, v in s.mounting.items() if k in fields})
        own = s.mounting_used in ("estimated", "given")
        if own or (mount.determined and mount.angle_deg > APPLY_DEG):
            verdict = "applied" if own else "NOT applied"
            if s.mounting_used == "tf":
                verdict = "not applied (the declared one below is)"
            lines.append(f"mounting   {mount.describe()}: {verdict}")
    tf = s.mounting_tf
    if tf:
        declared = Mounting(**{k: v for k, v in tf.items() if k in fields})
        diff = tf["angle_to_estimate_deg"]
        where = " on the determined axis" if tf["compared_on"] == "axis" else ""
        word = "agree" if tf["agrees"] else "DISAGREE"
        compare = (
            "not checked by the motion"
            if diff is None
            else f"{diff:.1f}° from the estimate{where} ({word})"
        )
        verdict = "applied" if s.mounting_used == "tf" else "NOT applied"
        lines.append(
            f"mounting   /tf_static {' -> '.join(tf['chain'])}: {declared.describe()}, "
            f"{compare}: {verdict}"
        )
    return lines


def _judgement_lines(s: ReplaySummary) -> list[str]:
    """The mounting, the truth's own nature and its jumps, one line each."""
    lines = []
    if s.truth_candidates:
        lines.append(_candidates_line(s.truth_candidates))
    if s.truth_topic and s.truth_estimate_of:
        lines.append(
            f"truth is   {s.truth_estimate_of}, not an independent reference: the error is the "
            f"difference between two estimates"
        )
    lines += _mounting_lines(s)
    if s.truth_jumps:
        seg = ", ".join(
            f"{x['start_s']:.1f}..{x['end_s']:.1f} s {_fmt(x['rms_error_deg'])}"
            for x in s.scored_segments
        )
        lines.append(
            f"truth jump {len(s.truth_jumps)} step{'s' if len(s.truth_jumps) != 1 else ''} the "
            f"gyro does not show; re-anchored after each, segments scored: {seg}"
        )
    return lines


def _shift_line(s: ReplaySummary, check: dict) -> str:
    """The rate check with its best shift, and what ``--truth-offset auto`` would score."""
    verdict = "follows the gyro" if check["follows"] else "does NOT follow the gyro"
    hint = ""
    if s.offset_auto_rms_deg is not None and s.rms_error_deg is not None:
        auto, now = _fmt(s.offset_auto_rms_deg), _fmt(s.rms_error_deg)
        change = f"instead of {now}" if auto != now else "either way, to the digits shown"
        hint = f" (--truth-offset auto applies it: RMS {auto} {change})"
    return (
        f"truth rate {verdict}: correlation {check['correlation']:.2f}, best shift "
        f"{shift_ms(check['shift_s'])}{hint}, residual {check['residual_rad_s']:.3f} rad/s"
    )


def _error_lines(s: ReplaySummary) -> list[str]:
    """The error's lines: its statistics (one line per quantity), or, for a truth that
    carries heading only, the heading's line and why only that one."""
    lines: list[str] = []
    heading_only = s.rms_error_deg is not None and s.scored_on == "heading"
    if heading_only and s.evaluation:  # its statistics' heading line, and why only that one
        lines += [
            x
            for x in evaluation_lines(s.evaluation)
            if not x.startswith("error      ") or x.startswith("error      heading")
        ]
    if heading_only:
        lines.append(
            f"scored on  heading only (RMS {_fmt(s.rms_error_deg)}, max {_fmt(s.max_error_deg)}): "
            f"the truth carries heading only (roll and pitch zero in every sample)"
        )
    elif s.evaluation:
        lines += evaluation_lines(s.evaluation)
    elif s.rms_error_deg is not None:
        lines.append(
            f"error      total RMS {_fmt(s.rms_error_deg)}, max {_fmt(s.max_error_deg)}; "
            f"inclination RMS {_fmt(s.rms_inclination_deg)}, max "
            f"{_fmt(s.max_inclination_deg)}; heading RMS {_fmt(s.rms_heading_deg)}, "
            f"max {_fmt(s.max_heading_deg)}"
        )
    return lines


def format_summary(s: ReplaySummary) -> str:
    """The summary for a person, one fact per line."""
    lines = [
        f"log        {s.path}",
        (
            f"imu        {s.imu_topic} ({s.imu_type}): {s.samples} samples, "
            f"{s.duration_s:.3f} s, {s.rate_hz:.1f} Hz, units {s.gyro_units}, {s.time} time"
        ),
    ]
    check = s.truth_check
    if s.truth_topic:
        offset = f", offset {s.truth_offset_s * 1e3:+.1f} ms" if s.truth_offset_s else ""
        lines.append(
            f"truth      {s.truth_topic} ({s.truth_type}): {s.truth_samples_used} gyro "
            f"samples inside its coverage{offset}"
        )
    else:
        lines.append(
            f"truth      none: {s.truth_rejected} does not follow the gyro, not scored "
            f"(name it with --truth-topic to score it)"
            if s.truth_rejected
            else "truth      none (no error can be measured)"
        )
    if check and check.get("checked") and check.get("correlation") is None:
        verdict = "follows the gyro" if check["follows"] else "does NOT follow the gyro"
        lines.append(
            f"truth rate {verdict}: rate norms nearly constant, residual "
            f"{check['residual_rad_s']:.3f} rad/s"
        )
    elif check and check.get("checked"):
        lines.append(_shift_line(s, check))
    lines.extend(_judgement_lines(s))
    if s.notes:
        lines.append("notes      " + "; ".join(s.notes))
    n_gaps = len(s.gaps)
    lines.append(
        f"dropped    {s.dropped_nonfinite} NaN/Inf, {s.dropped_implausible} implausible, "
        f"{s.dropped_duplicate + s.dropped_backward} duplicate/backward stamps; "
        f"{n_gaps} gap{'s' if n_gaps != 1 else ''} over 5x the median step"
    )
    b = np.asarray(s.bias_rad_s)
    bias = f"({b[0]:+.5f}, {b[1]:+.5f}, {b[2]:+.5f}) rad/s"
    bdeg = np.degrees(b)
    if s.bias_mode == "auto" and not s.bias_segments:
        lines.append(f"bias       auto: no rest found: {s.no_rest}; no bias removed")
    elif s.bias_mode == "auto":
        nseg = len(s.bias_segments)
        how = _rest_evidence(s)
        lines.append(
            f"bias       auto: {nseg} rest segment{'s' if nseg != 1 else ''} ({how}; "
            f"{s.bias_rule}), mean {bias} = ({bdeg[0]:+.3f}, {bdeg[1]:+.3f}, {bdeg[2]:+.3f}) °/s"
            f"{_bias_axes(s)}"
        )
    else:
        lines.append(f"bias       {s.bias_mode}: {bias}{_bias_axes(s)}")
    if s.rest_agreement and s.rest_agreement["line"]:
        lines.append("rests      " + s.rest_agreement["line"])
    pf = f", pre-filter {s.prefilter}" if s.prefilter else ""
    lines.append(f"method     {s.method}{pf}; estimate from t = {s.start_time_s:.3f} s")
    if s.score_window != "all":
        lines.append(f"scored     {s.score_window} ({s.truth_samples_used} samples)")
    lines += _error_lines(s)
    lines.extend(_bias_choice_line(s))
    lines.extend(_sampling_line(s))
    lines += outcome_lines(s.final_q_w_b, s.rotation_deg, s.turned_deg, s.written)
    if s.stopped_at:
        lines.append(f"stopped    {s.stopped_at}")
    lines.append(f"elapsed    {s.elapsed_s:.3f} s")
    return "\n".join(lines)

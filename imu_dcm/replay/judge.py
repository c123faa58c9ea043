"""The truth side of one replay, judged against the gyro: which of the log's attitude candidates
(:func:`pick_truth`), its quaternion convention (:func:`apply_convention`), its offset and rate
check, rates that look like the wrong unit, its jumps, the mounting between the gyro's frame and
the truth's body frame (estimated, given or declared by ``/tf_static``), and the gyro's gaps
whose rotation it did not see (:func:`judge_truth`).

Conventions: ``q_w_b`` Hamilton ``[x, y, z, w]``, body to world; rates rad/s; ``t_s`` seconds
since the first gyro sample.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from imu_dcm.app.beside import Beside
from imu_dcm.arrays import row_finite, row_norm
from imu_dcm.errors import Diagnostics
from imu_dcm.gyro.rates import deg_evidence, truth_rate_ratio
from imu_dcm.logio import LogData
from imu_dcm.replay.convention import ConventionChoice, choose_convention, convert
from imu_dcm.replay.gyro import Gyro
from imu_dcm.replay.mounting import Mounting, estimate_mounting, from_rotation
from imu_dcm.replay.mounting_tf import MountingChoice, choose_mounting, tf_mounting
from imu_dcm.replay.rate_check import check_truth
from imu_dcm.replay.settings import ReplaySettings
from imu_dcm.replay.truth import (
    JUMP_DEG,
    AlignedTruth,
    TruthJump,
    align_truth,
    find_jumps,
)
from imu_dcm.so3 import quat_angle_rad

__all__ = [
    "Judged",
    "apply_convention",
    "judge_truth",
    "pick_truth",
    "plain_convention",
    "scored_truth",
]


@dataclass(slots=True, frozen=True)
class Judged:
    """What the truth side found: truth at the gyro stamps, jumps, mounting.

    ``truth_t_ns``: the stamps of the truth used, at the applied offset (or None); ``gaps``:
    the gyro's gaps re-anchored (a :class:`~imu_dcm.replay.truth.TruthJump` over each).
    """

    aligned: AlignedTruth
    truth_t_ns: NDArray[np.int64] | None
    jumps: tuple
    mounting: MountingChoice
    gaps: tuple = ()


def judge_truth(
    log: LogData, s: ReplaySettings, g: Gyro, omega: NDArray, notes: Diagnostics
) -> Judged:
    """Offset, rate check, jumps and mounting of the truth against the (bias-free) gyro."""
    imu = log.imu
    aligned = align_truth(
        log.truth, g.base, g.t_ns, g.omega, s.truth_offset_s, imu.log_t_ns,
        notes.add,
    )  # fmt: skip
    # the units' evidence on a thread of its own while the jumps and the mounting are judged
    # (pure passes; its line is said first, as when judged first)
    units = Beside(_units_line, s.gyro_units, imu.topic, g.omega, g.t_s, aligned.q_truth)
    truth = aligned.truth
    if truth is None:
        if line := units.result():
            notes.add(line)
        given = None if isinstance(s.mounting, str) else _given(s.mounting)
        return Judged(
            aligned, None, (), MountingChoice(given, given, "given" if given else "", None, "")
        )
    line, (on_gyro, residual, tt, est) = units.then(_jumps_and_mounting, s, g, omega, aligned)
    if line:
        notes.add(line)
    jumps = tuple(
        dataclasses.replace(j, t0_s=j.t0_s - residual, t1_s=j.t1_s - residual) for j in on_gyro
    )
    if jumps:
        shown = "; ".join(j.describe() for j in jumps[:5])
        more = f" and {len(jumps) - 5} more" if len(jumps) > 5 else ""
        notes.add(
            f"truth {truth.topic} jumps where the gyro does not: {shown}{more}; the estimate "
            f"re-anchors to the truth after each jump and the "
            f"{len(scored_truth(aligned.q_truth, g.t_s, jumps)[1])} segments between jumps are "
            f"scored",
        )
    declared = tf_mounting(log.static_transforms, imu.topic, imu.frame_id, truth)
    frames = f"{imu.frame_id or 'the gyro frame'} -> {truth.child_frame_id or truth.topic}"
    given = None if isinstance(s.mounting, str) else _given(s.mounting)
    choice = choose_mounting(s.mounting, est, declared, given, frames)
    if choice.line:
        notes.add(choice.line)
    gaps = _unseen_gaps(g, omega, aligned.q_truth, notes)
    return Judged(aligned, tt, jumps, choice, gaps)


def _units_line(units: str, topic: str, omega: NDArray, t_s: NDArray, q_truth: NDArray):
    """The line that says the rates look like the other unit than ``units`` declares, or None."""
    if units == "rad/s":
        evidence = deg_evidence(omega, t_s, q_truth)
        if evidence:
            return (
                f"{topic}: the rates look like deg/s: {evidence}; pass --gyro-units deg/s to "
                "convert"
            )
        return None
    # declared deg/s: a rad/s log converted reads 57.3x slower than its truth turns
    ratio = truth_rate_ratio(omega, t_s, q_truth)
    if ratio is not None and abs(ratio * (180 / np.pi) - 1) < 0.2:
        return (
            f"{topic}: the rates look like rad/s: converted from deg/s, the gyro rate "
            f"is 1/{1 / ratio:.1f} of the truth's rotation rate (1/57.3 for rad/s read as "
            f"deg/s); drop --gyro-units deg/s"
        )
    return None


def _jumps_and_mounting(s: ReplaySettings, g: Gyro, omega: NDArray, aligned: AlignedTruth):
    """The truth's jumps where the gyro does not jump, on the gyro's clock, and the mounting
    estimated outside them: ``(jumps, residual lag s, truth stamps, mounting estimate)``."""
    truth = aligned.truth
    tt = truth.t_ns if g.base == "header" else truth.log_t_ns
    if round(aligned.offset_s * 1e9):  # shifted (a copy); else the truth's own stamps
        tt = tt + np.int64(round(aligned.offset_s * 1e9))
    residual = 0.0  # the measured truth lag, not applied to the scoring with a fixed offset
    if s.truth_offset_s != "auto" and aligned.check and aligned.check.shift_s is not None:
        residual = aligned.check.shift_s
    shift = np.int64(round(residual * 1e9))
    # jumps are judged with the truth aligned to the gyro (a lagging truth would turn after the
    # gyro and look like a jump), then said and scored on the truth's own stamps
    on_gyro = find_jumps(g.t_ns, omega, tt + shift, truth.q_w_b)
    t00 = int(g.t_ns[0])
    skip = tuple((t00 + round(j.t0_s * 1e9), t00 + round(j.t1_s * 1e9)) for j in on_gyro)
    est = estimate_mounting(g.t_ns, omega, tt + shift, truth.q_w_b, skip)
    return on_gyro, residual, tt, est


def _unseen_gaps(g: Gyro, omega: NDArray, q_truth: NDArray, notes: Diagnostics) -> tuple:
    """The gyro's gaps whose rotation it did not see: where the truth turns across the gap, or
    the integrator's bridge of it (the mean of the rates at its ends times its length) would,
    more than a truth jump's :data:`JUMP_DEG`. The estimate re-anchors after each."""
    out = []
    for t_gap, length in g.clean.gaps:
        k = int(np.searchsorted(g.t_s, t_gap))
        if k + 1 >= len(g.t_s) or not (row_finite(q_truth[k : k + 2]).all()):
            continue
        truth_deg = float(np.degrees(quat_angle_rad(q_truth[k], q_truth[k + 1])))
        speed = row_norm(omega[k : k + 2])  # the rates at the gap's ends
        bridge_deg = float(np.degrees(0.5 * (speed[0] + speed[1]) * length))
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


def pick_truth(log: LogData, g: Gyro, omega: NDArray) -> tuple[LogData, tuple[dict, ...]]:
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


def apply_convention(log: LogData, s: ReplaySettings, g: Gyro, omega, notes):
    """The truth read in the convention stated, or the one its body rates fit clearly."""
    truth = log.truth
    if truth is None:
        return log, ConventionChoice()
    tt = truth.t_ns if g.base == "header" else truth.log_t_ns
    choice = choose_convention(
        g.t_ns, omega, tt, truth.q_w_b, s.truth_convention, truth.topic, g.accel
    )
    if choice.line:
        notes.add(choice.line)
    if choice.used == "as-is":
        return log, choice
    q = convert(truth.q_w_b, choice.used)
    return dataclasses.replace(log, truth=dataclasses.replace(truth, q_w_b=q)), choice


def plain_convention(c: ConventionChoice) -> dict:
    return c.as_dict()


def scored_truth(q_truth: NDArray, t_s: NDArray, jumps) -> tuple[NDArray, list[int]]:
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

"""The :class:`~imu_dcm.replay.summary.ReplaySummary` of one replay from its parts
(:func:`summarise`), and whether a truth carries heading only (:func:`heading_only`).

Angles in degrees, rates rad/s, times s since the first gyro sample.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from numpy.typing import NDArray

from imu_dcm.arrays import BLOCK_ROWS, median_diff, row_finite
from imu_dcm.logio.ned import in_log_axes
from imu_dcm.metrics import rms
from imu_dcm.replay.bias import BIAS_RULE
from imu_dcm.replay.gyro import Gyro
from imu_dcm.replay.judge import Judged
from imu_dcm.replay.summary import ReplaySummary
from imu_dcm.replay.truth import JUMP_DEG

__all__ = ["PLANAR_TOL", "heading_only", "summarise"]


def _record(obj) -> dict:
    """A reader record (dataclass or plain object) as a dict for the summary."""
    if dataclasses.is_dataclass(obj):
        return dataclasses.asdict(obj)
    return dict(vars(obj))


#: A truth component this small is zero by construction (float32 rounding of a unit
#: quaternion's components is ~6e-8).
PLANAR_TOL = 1e-9


def heading_only(q_truth: NDArray) -> bool:
    """The truth turns (its heading spans more than a truth jump's :data:`JUMP_DEG`) yet every
    sample turns about the world's vertical only (x and y components zero): planar by
    construction. A still, level truth is not: it is scored whole."""
    ok = row_finite(q_truth)
    if not ok.any():
        return False
    for a in range(0, len(ok), BLOCK_ROWS):  # the tilt first, a block at a time: no copy
        q = q_truth[a : a + BLOCK_ROWS][ok[a : a + BLOCK_ROWS], :2]
        if len(q) and float(np.max(np.abs(q))) > PLANAR_TOL:
            return False
    heading = np.unwrap(2.0 * np.arctan2(q_truth[ok, 2], q_truth[ok, 3]))
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


def summarise(log, s, g: Gyro, bias_est, judged: Judged, pf_summary, anchors, error, both):
    """The :class:`ReplaySummary` of a replay."""
    imu, aligned, truth = log.imu, judged.aligned, judged.aligned.truth
    start, n, t_s = anchors[0], len(g.t_s), g.t_s
    clean = g.clean
    q0 = np.asarray(judged.aligned.q_truth[start]) if both.any() else s.init_q_w_b
    q0 = np.array([0.0, 0.0, 0.0, 1.0]) if q0 is None or not np.all(np.isfinite(q0)) else q0

    every = bool(both.all())

    def stat_(a: NDArray, f) -> float | None:  # over the scored rows (all: no copy)
        return float(f(a if every else a[both])) if both.any() else None

    # a truth that carries only heading (2D odometry, a planar pose) is scored on heading only
    planar = heading_only(judged.aligned.q_truth)
    total = error.heading_deg if planar else error.total_deg

    mount = judged.mounting
    bias = bias_est.bias_b[start:]  # one vector on every row (a view of it) is that vector
    bias_mean = bias[0] if len(bias) and bias.strides[0] == 0 else bias.mean(axis=0)
    return ReplaySummary(
        path=str(log.path),
        container=getattr(log, "container", "ros2 mcap"),
        samples=int(n),
        samples_estimated=int(n - start),
        duration_s=float(t_s[-1]),
        rate_hz=1.0 / median_diff(t_s),
        imu_topic=imu.topic,
        imu_type=imu.type,
        truth_topic=truth.topic if truth is not None else None,
        truth_type=truth.type if truth is not None else None,
        time=g.base,
        method=s.method,
        gyro_units=s.gyro_units,
        bias_mode=bias_est.mode,
        bias_rad_s=tuple(float(x) for x in bias_mean),
        log_axes=getattr(imu, "log_axes", ""),
        bias_log_rad_s=in_log_axes(bias_mean, getattr(imu, "log_axes", "")),
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
        rest_agreement=bias_est.agreement,
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

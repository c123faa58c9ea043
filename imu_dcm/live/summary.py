"""What a live run reports: :class:`LiveResult` and its summary, JSON-ready.

The summary's keys are replay's where they apply (:func:`imu_dcm.live.run` lists them); a value
that cannot be measured is None, never NaN or Inf (:func:`imu_dcm.app.summary.json_ready`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from imu_dcm.app.summary import RunFigures, json_ready
from imu_dcm.live.pipeline import Pipeline
from imu_dcm.live.sources import Source

__all__ = ["LiveResult", "summary"]


@dataclass(slots=True, frozen=True)
class LiveResult:
    """What a live run produced.

    Attributes
    ----------
    summary : dict — JSON-ready summary (keys as replay's where they apply; see
        :func:`imu_dcm.live.run`).
    q_w_b : float64 (4,) or None — final attitude ``[x, y, z, w]`` at ``t_ns`` (None if the
        estimate never started).
    t_ns : int or None — source stamp of the final attitude, ns.
    latency_ms : float64 (n,) — receive -> view log call of the newest samples logged (at most
        :data:`imu_dcm.live.latency.LATENCY_KEEP` and one batch: memory stays bounded), ms.
    """

    summary: dict
    q_w_b: NDArray[np.float64] | None
    t_ns: int | None
    latency_ms: NDArray[np.float64] = field(repr=False)


def summary(
    pipe: Pipeline,
    src: Source,
    source: str,
    *,
    gyro_units: str,
    method: str,
    reason: str,
    recorder,
    started: float,
) -> dict:
    """The summary of a run (its keys: :func:`imu_dcm.live.run`), every value finite or None."""
    return json_ready(_fields(pipe, src, source, gyro_units, method, reason, recorder, started))


def _fields(pipe, src, source, gyro_units, method, reason, recorder, started) -> dict:
    r = pipe.reorder
    imu_ch, truth_ch = pipe.channels.get("imu"), pipe.channels.get("truth")
    dur = float(pipe.recent_t_s[-1]) if len(pipe.recent_t_s) else 0.0
    step = pipe.median_step_s
    st = pipe.stats
    have = st.n > 0
    rms_v = np.sqrt(st.sq / st.n) if have else [None] * 3
    segs, agreement = _rests(pipe)
    bias_mean = (pipe.bias_sum / pipe.bias_n).tolist() if pipe.bias_n else [0.0, 0.0, 0.0]
    figures = RunFigures(
        samples=int(pipe.n),
        samples_estimated=int(pipe.n - pipe.samples_before_start) if pipe.integ else 0,
        duration_s=float(dur),
        rate_hz=1.0 / step if step else None,
        imu_topic=imu_ch.topic if imu_ch else None,
        imu_type=(imu_ch.name or imu_ch.message_encoding) if imu_ch else None,
        truth_topic=truth_ch.topic if truth_ch else ("lines (q_w_b)" if pipe.truth_count else None),
        truth_type=truth_ch.name if truth_ch else None,
        method=method,
        gyro_units=gyro_units,
        bias_mode=pipe.bias_mode,
        bias_rad_s=tuple(bias_mean),
        bias_segments=tuple(segs),
        start_time_s=pipe.start_t_s,
        initial_q_w_b=None if pipe.q0 is None else tuple(float(v) for v in pipe.q0),
        final_q_w_b=None if pipe.q_last is None else tuple(float(v) for v in pipe.q_last),
        truth_samples_used=int(pipe.truth_used),
        rms_error_deg=float(rms_v[0]) if have else None,
        max_error_deg=float(st.max[0]) if have else None,
        rms_inclination_deg=float(rms_v[1]) if have else None,
        max_inclination_deg=float(st.max[1]) if have else None,
        rms_heading_deg=float(rms_v[2]) if have else None,
        max_heading_deg=float(st.max[2]) if have else None,
        dropped_nonfinite=r.dropped_nonfinite,
        dropped_implausible=r.dropped_implausible,
        dropped_duplicate=r.dropped_duplicate,
        dropped_backward=r.dropped_backward,
        gaps=tuple(pipe.gaps),
        elapsed_s=time.perf_counter() - started,
    )
    return {
        "source": source,
        **figures.to_dict(),
        "reordered": r.reordered,
        "malformed": int(pipe.malformed),
        "gap_count": pipe.gap_count,
        "reconnects": int(getattr(src, "reconnects", 0)),
        "lost_by_system": int(src.lost),
        "units_evidence": pipe.units_evidence,
        "rest_agreement": agreement,
        "bias_final_rad_s": list(pipe.rest.bias_rad_s) if pipe.rest else list(pipe.fixed_bias),
        "reorder_window_s": r.window_ns * 1e-9,
        "unscored_before_s": pipe.unscored_before_s,
        "final_t_s": None
        if pipe.t_last_ns is None or pipe.t0_ns is None
        else (pipe.t_last_ns - pipe.t0_ns) * 1e-9,
        "latency_p50_ms": pipe.latency.percentile(50),
        "latency_p99_ms": pipe.latency.percentile(99),
        "stopped": reason,
        "record": str(recorder.path) if recorder is not None else None,
        "cpu_s": pipe.cpu_s,
        "read_interval_s": pipe.read_interval_s,
    }


def _rests(pipe: Pipeline) -> tuple[list[dict], dict | None]:
    """The rest segments (each marked used or not, with the reason) and how their biases agree
    (replay's ``rest_agreement``; None with fewer than two rests or no rest rule)."""
    if pipe.rest is None:
        return [], None
    agreement = pipe.rest.agreement
    result = agreement.result()
    why = {id(s): r for s, r in result.outliers}
    segs = []
    for seg, used in zip(pipe.rest.segments, agreement.used, strict=True):
        d = {**seg.as_dict(), "used": used}
        if not used:
            d["reason"] = (
                f"its bias is {why[id(seg)]:.1f}x its noise from the two rests before it, "
                "which agree"
            )
        segs.append(d)
    return segs, result.as_dict(agreement.rests) if len(agreement.rests) > 1 else None

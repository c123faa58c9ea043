"""The figures every run reports, replay or live, under one set of names: :class:`RunFigures`.

A replay's summary (:class:`imu_dcm.replay.summary.ReplaySummary`) is these figures and its
own; a live run's summary (:func:`imu_dcm.live.run`) is :meth:`RunFigures.to_dict` and its
own keys; a batch row (:class:`imu_dcm.replay.table.LogRow`) takes its columns from a replay's.
So a figure has one name, one unit and one meaning in every JSON file and table the commands
write. :func:`json_ready` is the one rule that makes a summary JSON: lists, plain numbers, and
None for a value that cannot be measured (never NaN or Inf).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

__all__ = ["RunFigures", "figures_json", "gap_dicts", "json_ready"]


@dataclass(slots=True, frozen=True, kw_only=True)
class RunFigures:
    """What a run of the integrator measured (times in s since the first sample, angles in
    degrees, rates in rad/s; None where it cannot be measured).

    Attributes
    ----------
    samples : int — gyro samples taken (after cleaning).
    samples_estimated : int — of them, those integrated (from the start of the estimate on).
    duration_s : float — first to last sample, s.
    rate_hz : float or None — 1 / median sample step, Hz.
    imu_topic, imu_type : str or None — the gyro's channel and its message type.
    truth_topic, truth_type : str or None — the truth's channel and type (None without truth).
    method : str — the integrator's method (:data:`imu_dcm.integrator.batch.METHODS`).
    gyro_units : str — the unit the rates came in (``rad/s`` or ``deg/s``; converted).
    bias_mode : str — ``auto`` (from rest), ``none`` or ``fixed`` (given).
    bias_rad_s : tuple of 3 float — mean bias removed from the samples estimated, body, rad/s.
    bias_segments : tuple of dict — the rests the bias came from, each with its evidence.
    start_time_s : float or None — when the estimate starts, s (None: it never started).
    initial_q_w_b, final_q_w_b : tuple of 4 float or None — the estimate's first and last
        attitude ``q_w_b`` ``[x, y, z, w]``.
    truth_samples_used : int — samples scored against the truth.
    rms_error_deg, max_error_deg : float or None — total attitude error, deg.
    rms_inclination_deg, max_inclination_deg : float or None — its tilt part, deg.
    rms_heading_deg, max_heading_deg : float or None — its heading part, deg.
    dropped_nonfinite, dropped_implausible, dropped_duplicate, dropped_backward : int — samples
        dropped: NaN/Inf, a rate no gyro gives (:mod:`imu_dcm.gyro.rates`), a repeated stamp, a
        stamp
        that goes back.
    gaps : tuple of (t_s, length_s) — steps over 5x the median step (:func:`gap_dicts` in JSON).
    elapsed_s : float — wall time of the run, s.
    """

    samples: int
    samples_estimated: int
    duration_s: float
    rate_hz: float | None
    imu_topic: str | None
    imu_type: str | None
    truth_topic: str | None
    truth_type: str | None
    method: str
    gyro_units: str
    bias_mode: str
    bias_rad_s: tuple[float, float, float]
    bias_segments: tuple[dict, ...]
    start_time_s: float | None
    initial_q_w_b: tuple[float, float, float, float] | None
    final_q_w_b: tuple[float, float, float, float] | None = None
    truth_samples_used: int
    rms_error_deg: float | None
    max_error_deg: float | None
    rms_inclination_deg: float | None
    max_inclination_deg: float | None
    rms_heading_deg: float | None
    max_heading_deg: float | None
    dropped_nonfinite: int
    dropped_implausible: int
    dropped_duplicate: int
    dropped_backward: int
    gaps: tuple[tuple[float, float], ...]
    elapsed_s: float = 0.0

    def to_dict(self) -> dict[str, Any]:
        """The figures as a JSON-ready dict (:func:`figures_json`)."""
        return figures_json(self)


def gap_dicts(gaps) -> list[dict[str, float]]:
    """``(t_s, length_s)`` pairs as the JSON objects ``{"t_s", "length_s"}``."""
    return [{"t_s": a, "length_s": b} for a, b in gaps]


def figures_json(figures) -> dict[str, Any]:
    """A :class:`RunFigures` (or a dataclass made of one, such as a replay's summary) as a
    JSON-ready dict: tuples become lists, ``gaps`` :func:`gap_dicts`, NaN and Inf None."""
    d = dataclasses.asdict(figures)
    d["gaps"] = gap_dicts(figures.gaps)
    return json_ready(d)


def json_ready(x: Any) -> Any:
    """``x`` with tuples as lists, numpy scalars and arrays as Python values, and every
    non-finite float as None (JSON has no NaN or Inf)."""
    if isinstance(x, dict):
        return {str(k): json_ready(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [json_ready(v) for v in x]
    if hasattr(x, "tolist"):  # a numpy array or scalar (this module imports no numpy)
        return json_ready(x.tolist())
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x

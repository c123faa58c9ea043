"""Gyro bias from rest: the bias of each rest segment of a log, applied sample by sample.

Rest segments and their evidence come from :func:`imu_dcm.gyro.rest.rest_segments` (the rule of
:mod:`imu_dcm.gyro.rest_rule`, which live runs causally;
:class:`~imu_dcm.gyro.rest_rule.RestConfig`,
:class:`~imu_dcm.gyro.rest_rule.RestSegment` and :func:`~imu_dcm.gyro.rest.detect_rest` are
re-exported
here). Rests whose bias disagrees with the rests around it beyond their noise are not used
(:func:`imu_dcm.gyro.rest_agreement.rests_agree`). The bias applied to a sample follows
:data:`BIAS_RULE`:

* ``"latest"``: that of the latest rest segment that began at or before it (the estimate is
  *updated at each rest*); samples before the first rest use the first segment's bias;
* ``"interpolate"``: linear in time between the middles of the two rest segments around it
  (replay is offline, so the later rest is known), constant before the first and after the last.

Both were measured on the six BROAD trials (docs/replay.md); the better one is the default.

Conventions: ``omega_b`` (N, 3) body rate in body axes, rad/s; ``t_s`` (N,) seconds,
increasing. Bias vectors are in the same frame and unit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imu_dcm.app.checks import check_bias
from imu_dcm.errors import InputError
from imu_dcm.gyro.rest import GyroWindows, detect_rest, judge_rest
from imu_dcm.gyro.rest_agreement import rests_agree
from imu_dcm.gyro.rest_rule import RestConfig, RestSegment

__all__ = [
    "BIAS_RULES",
    "BiasEstimate",
    "RestConfig",
    "RestSegment",
    "detect_rest",
    "estimate_bias",
]

#: How the bias between rests is applied, and the default (measured, see the module docstring).
BIAS_RULES = ("latest", "interpolate")
BIAS_RULE = "interpolate"


@dataclass(frozen=True, slots=True)
class BiasEstimate:
    """Bias applied at each sample and the rest segments it came from.

    Attributes
    ----------
    bias_b : float64 (N, 3) — bias subtracted from each sample, body axes, rad/s (a read-only
        view of one vector when the bias is the same on every row: none, fixed, no rest).
    segments : the rest segments found (empty when none), each with its evidence.
    mode : "auto", "none" or "fixed".
    confirmed : True when a signal besides the gyro (accelerometer, truth) judged every rest.
    no_rest : why no rest was found ("" when found, or not "auto").
    conflict : one line where the evidence conflicts ("" when it does not).
    agreement : how the rests' biases agree (:func:`imu_dcm.gyro.rest_agreement.rests_agree`, its
        ``as_dict``; None with fewer than two rests): the outliers are not in ``segments``.
    """

    bias_b: NDArray[np.float64]
    segments: tuple[RestSegment, ...]
    mode: str
    confirmed: bool = False
    no_rest: str = ""
    conflict: str = ""
    agreement: dict | None = None


def estimate_bias(
    omega_b: ArrayLike,
    t_s: ArrayLike,
    mode: str | ArrayLike = "auto",
    config: RestConfig | None = None,
    accel_b: ArrayLike | None = None,
    rule: str | None = None,
    truth_q_w_b: ArrayLike | None = None,
    truth_noise: float = 0.0,
    r_t_g: ArrayLike | None = None,
    vehicle: tuple[ArrayLike, ArrayLike] | None = None,
    motion=None,
    windows: GyroWindows | None = None,
) -> BiasEstimate:
    """The gyro bias to subtract at each sample.

    Parameters
    ----------
    omega_b : array_like, shape (N, 3)
        Body rates, rad/s (all samples, also those without truth: rest is found everywhere).
    t_s : array_like, shape (N,)
        Sample times, s, increasing.
    mode : "auto", "none" or array_like (3,)
        ``"auto"``: from rest segments (zero if there is no rest); ``"none"``: zero; a vector:
        that constant bias in rad/s.
    config : RestConfig, optional
        Rest rule bounds (auto only).
    accel_b : array_like, shape (N, 3), optional
        Accelerometer on the same rows, m/s², finite (auto only).
    rule : "latest" or "interpolate", optional
        How the bias between rests is applied (default :data:`BIAS_RULE`).
    truth_q_w_b : array_like, shape (N, 4), optional
        Reference attitude ``[x, y, z, w]`` on the same rows, NaN where none (auto only).
    truth_noise : float
        Its angle noise per sample, rad (:func:`imu_dcm.gyro.rest_evidence.truth_noise_rad`).
    r_t_g : array_like, shape (3, 3), optional
        Rotation from the gyro's axes to the truth's body axes (the mounting; identity).
    vehicle : (landed, armed), optional
        The autopilot's landed and armed state on the same rows (auto only;
        :func:`imu_dcm.gyro.rest.rest_segments`).
    motion : imu_dcm.gyro.rest_evidence.Motion, optional
        The truth's position and odometry twist on the same rows (auto only).
    windows : imu_dcm.gyro.rest.GyroWindows, optional
        The gyro's rest windows, kept from an earlier estimate of the same rates (auto only).

    Returns
    -------
    BiasEstimate
    """
    w = np.asarray(omega_b, dtype=float)
    t = np.asarray(t_s, dtype=float)
    n = len(w)
    if isinstance(mode, str) and mode == "none":
        return BiasEstimate(_every_row(np.zeros(3), n), (), "none")
    mode = check_bias(mode)
    if not isinstance(mode, str):
        return BiasEstimate(_every_row(mode, n), (), "fixed")
    rule = rule or BIAS_RULE
    if rule not in BIAS_RULES:
        raise InputError(f"Expected a bias rule in {BIAS_RULES}, got {rule!r}")
    cfg = config or RestConfig()
    segs, conflict, why = judge_rest(
        w, t, cfg, accel_b, truth_q_w_b, truth_noise, r_t_g, vehicle, motion, windows
    )
    if not segs:
        if conflict:  # windows passed, and their stretches were found not to be rest
            why = conflict.split(": ", 1)[1]
        return BiasEstimate(_every_row(np.zeros(3), n), (), "auto", False, why, conflict)
    agree = rests_agree(w, segs, cfg.floor_spreads)  # the outliers are not used
    judged = agree.as_dict(segs) if len(segs) > 1 else None
    segs = list(agree.kept)
    confirmed = all(any(e != "gyro floor" for e in s.evidence) for s in segs)
    bias_b = _bias_at(segs, t, rule)
    return BiasEstimate(bias_b, tuple(segs), "auto", confirmed, "", conflict, judged)


def _every_row(bias, n: int) -> NDArray[np.float64]:
    """One bias on every row, (n, 3): a read-only view of the one vector, no memory per row."""
    return np.broadcast_to(np.asarray(bias, dtype=float), (n, 3))


def _bias_at(segs: list[RestSegment], t: NDArray, rule: str) -> NDArray[np.float64]:
    """The bias at every sample from the rest segments, by ``rule``."""
    values = np.array([s.bias_rad_s for s in segs])
    if rule == "interpolate":
        mid = np.array([0.5 * (t[s.lo] + t[s.hi - 1]) for s in segs])
        return np.stack([np.interp(t, mid, values[:, k]) for k in range(3)], axis=1)
    starts = np.array([s.start for s in segs])
    k = np.clip(np.searchsorted(starts, np.arange(len(t)), side="right") - 1, 0, len(segs) - 1)
    return values[k]

"""Rest evidence beyond the gyro and the accelerometer: the truth's rotation and its noise, the
autopilot's landed and armed state, the truth's position and odometry's twist, each on the gyro
rows (:mod:`imu_dcm.gyro.rest_rule` says how each judges a window and where its bound comes from),
and the truth's judgement of a whole rest (:func:`segment_doubt`).

Conventions: ``(landed, armed)`` int (N,) each, 1 true, 0 false, -1 unknown; positions in m;
rates in rad/s; windows of ``m`` gyro rows, row ``i`` the window ``[i, i + m)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imu_dcm._kernels.calls import second_steps, window_rates
from imu_dcm.arrays import median, row_finite, row_norm
from imu_dcm.errors import InputError
from imu_dcm.gyro.resample import step_rotvecs
from imu_dcm.gyro.windows import min_steps, step_var, windowed_mean_var
from imu_dcm.so3 import log_quat, quat_conjugate, quat_multiply

__all__ = [
    "Motion",
    "Signals",
    "airborne_between",
    "checked_vehicle",
    "gyro_path",
    "gyro_path_noise",
    "motion_windows",
    "position_noise_m",
    "segment_doubt",
    "step_rotvecs",
    "truth_noise_rad",
    "truth_rates",
    "twist_noise_rad_s",
    "vehicle_windows",
]


@dataclass(frozen=True, slots=True)
class Motion:
    """The truth's position and angular rate on the gyro rows (NaN where it has none).

    Attributes
    ----------
    p_w : float64 (N, 3) or None — position, m (any world frame: only its moves count).
    p_noise_m : float — its noise per sample, m (:func:`position_noise_m`).
    omega_b : float64 (N, 3) or None — odometry's angular rate, rad/s (only its size counts).
    omega_noise_rad_s : float — its noise per sample, rad/s (:func:`twist_noise_rad_s`).
    samples_per_s : float — the twist's own rate, Hz (how many samples a window averages).
    """

    p_w: NDArray | None = None
    p_noise_m: float = 0.0
    omega_b: NDArray | None = None
    omega_noise_rad_s: float = 0.0
    samples_per_s: float = 0.0


@dataclass(frozen=True, slots=True)
class Signals:
    """The signals of one log that judge its windows: accelerometer (N, 3) m/s², truth (N, 4)
    on the gyro rows, its angle noise (rad) and the rotation (3, 3) taking gyro axes to the
    truth's body axes (identity when not known)."""

    accel_b: NDArray | None = None
    truth_q_w_b: NDArray | None = None
    truth_noise_rad: float = 0.0
    r_t_g: NDArray | None = None
    vehicle: tuple[NDArray, NDArray] | None = None  # (landed, armed) int8 (N,), -1 unknown
    motion: Motion | None = None


def position_noise_m(p_w: ArrayLike) -> float:
    """A position's noise per sample, m: 1.4826 median |second difference| / √6 (largest axis).

    A position moving at a steady or slowly changing velocity has second differences of its
    noise alone (variance ``6 σ²``). 0 with fewer than 3 finite samples.
    """
    p = np.asarray(p_w, dtype=float)
    p = p[np.all(np.isfinite(p), axis=1)]
    if len(p) < 3:
        return 0.0
    d2 = np.abs(np.diff(p, 2, axis=0))
    return float(1.4826 * np.median(d2, axis=0, overwrite_input=True).max() / math.sqrt(6))


def twist_noise_rad_s(omega_b: ArrayLike) -> float:
    """A twist's noise per sample, rad/s: 1.4826 median |first difference| / √2 (largest axis),
    at least its quantisation (step²/12). 0 with fewer than 2 finite samples."""
    w = np.asarray(omega_b, dtype=float)
    w = w[np.all(np.isfinite(w), axis=1)]
    if len(w) < 2:
        return 0.0
    d1 = np.abs(np.diff(w, axis=0))
    mad = float(1.4826 * np.median(d1, axis=0, overwrite_input=True).max() / math.sqrt(2))
    return math.sqrt(max(mad * mad, step_var(min_steps(w))))


def truth_noise_rad(q_w_b: ArrayLike, step_ok: ArrayLike | None = None) -> float:
    """The truth's own angle noise per sample, rad: from second differences of its rotation.

    Each step's rotation ``log(q_k⁻¹ q_{k+1})`` differs from the next by the motion's change
    (``alpha dt²``, small at a truth's rate) and by white angle noise of variance ``6 σ²`` per
    axis. ``σ`` is taken robustly (1.4826 median absolute value / √6, largest axis); 0 with
    fewer than 3 finite samples. ``step_ok`` (M - 1,) marks the steps to use (default all; a
    jump of the truth's own is not its noise).
    """
    q = np.ascontiguousarray(q_w_b, dtype=float)
    n = len(q)
    if n < 3:
        return 0.0
    usable = np.ones(n - 1, bool) if step_ok is None else np.asarray(step_ok, dtype=bool)
    # |second differences| of the steps' rotations at the pairs of usable steps, in one
    # compiled pass (no whole-log array of the rotations), each axis's values then taken for
    # its median
    vals = np.empty((3, n - 2))
    filled = second_steps(q, row_finite(q), usable, vals)
    if not filled:
        return 0.0
    spread = max(median(vals[k, :filled], overwrite_input=True) for k in range(3))
    return 1.4826 * spread / math.sqrt(6.0)


def truth_rates(q: NDArray, t: NDArray, m: int) -> NDArray:
    """``|omega_T|`` of every window of ``m`` samples, rad/s (NaN where the truth is missing).

    ``omega_T`` is the mean of the truth's body rate step by step, ``log(q_k⁻¹ q_{k+1}) / dt``
    over the window's ``m - 1`` steps: the rate the gyro would read without bias (a rotation
    of many turns over the window is not folded into ±π). Each window's sum is the
    difference of the running sums of the steps' rates (each step added to the sum before it,
    in order), in one compiled pass that holds the last ``m`` running sums
    (:func:`imu_dcm._kernels.calls.window_rates`).
    """
    q = np.ascontiguousarray(q, dtype=float)
    rate = np.empty(max(len(q) - m + 1, 0))
    if len(rate) and m >= 2:
        window_rates(q, np.ascontiguousarray(t, dtype=float), row_finite(q), int(m), rate)
    else:  # windows of one sample hold no step
        rate[:] = np.nan
    return rate


def motion_windows(mo: Motion, m: int, z: float, rate_hz: float) -> list:
    """The motion conditions over every window of ``m`` gyro rows (NaN: undecided, passes)."""
    conds = []
    if mo.omega_b is not None:
        mean, _var = windowed_mean_var(np.nan_to_num(mo.omega_b), m)
        have = windowed_mean_var(np.isfinite(mo.omega_b[:, :1]).astype(float), m)[0][:, 0]
        k = max(1.0, mo.samples_per_s * m / rate_hz)
        value = np.where(have > 1.0 - 1e-9, row_norm(mean), np.nan)  # a whole window of twist
        conds.append(
            (
                "odometry twist",
                "twist |omega|",
                value,
                z * mo.omega_noise_rad_s / math.sqrt(k),
                "rad/s",
            )
        )
    if mo.p_w is not None:
        move = row_norm(mo.p_w[m - 1 :] - mo.p_w[: len(mo.p_w) - m + 1])
        conds.append(("position", "position move", move, z * math.sqrt(2.0) * mo.p_noise_m, "m"))
    return conds


def vehicle_windows(vehicle, m: int) -> tuple[NDArray, NDArray]:
    """Each window's share of airborne samples and whether it is landed and disarmed throughout.

    Airborne: not landed, and not known to be disarmed. Landed and disarmed: landed, and not
    known to be armed.
    """
    landed, armed = (np.asarray(x) for x in vehicle)
    count = []
    for flag in ((landed == 0) & (armed != 0), (landed == 1) & (armed != 1)):
        c = np.concatenate([[0], np.cumsum(flag)])
        count.append((c[m:] - c[:-m]) / m)
    return count[0], count[1] >= 1.0


def airborne_between(vehicle, a: int, b: int) -> bool:
    """Whether the landed state ``(landed, armed)`` says airborne on any sample of ``[a, b)``."""
    if vehicle is None:
        return False
    landed, armed = vehicle
    return bool(np.any((landed[a:b] == 0) & (armed[a:b] != 0)))


def checked_vehicle(vehicle, n: int):
    """``(landed, armed)`` as arrays of ``n`` rows each (None stays None); refused otherwise."""
    if vehicle is None:
        return None
    out = tuple(np.asarray(x) for x in vehicle)
    if len(out) != 2 or any(x.shape != (n,) for x in out):
        shapes = ", ".join(str(np.shape(x)) for x in out)
        raise InputError(f"Expected vehicle (landed, armed) of shape ({n},) each, got {shapes}")
    return out


def segment_doubt(w, t, lo: int, hi: int, m: int, std_limit: float, cfg, sig) -> str:
    """Why rest ``[lo, hi)`` (its bias span) is not a rest, "" when nothing says so.

    Only the truth can tell a rest from a motion the gyro's windows do not show (offline, over
    the whole span; ``z`` = ``floor_spreads``). The body moved where the truth's rotation is
    above its noise and nearer, as a vector in the truth's body axes, to what the gyro says
    than to none:

    * **turn**: the truth's rotation over the span against the gyro's mean turned over it (a
      slow steady turn, a hover: the mean is a turn, not bias); its noise ``z √6 σ``;
    * **sway**: the truth's path from the span's start, less its steady turn, against the
      gyro's rates less their mean, integrated: the RMS of their difference under half the
      truth path's RMS, and each path's largest excursion above its noise (the truth's
      ``z √6 σ``; the gyro's random walk ``z std_limit dt √n``).

    A truth that turns where the gyro does not is the truth's own wander (a motion capture's
    jitter, an estimator's correction), and a gyro that wanders alone has a wandering bias.
    """
    q = sig.truth_q_w_b
    if q is None:
        return ""
    span_q = q[lo:hi]
    ok = np.all(np.isfinite(span_q), axis=1)
    if not (ok[0] and ok[-1]):
        return ""
    r = np.eye(3) if sig.r_t_g is None else sig.r_t_g
    rel = log_quat(quat_multiply(quat_conjugate(span_q[0]), span_q))
    rel[~ok] = np.nan
    turn = rel[-1]
    mean = w[lo:hi].mean(axis=0)
    gyro_turn = r @ mean * (t[hi - 1] - t[lo])
    noise_t = cfg.floor_spreads * math.sqrt(6.0) * sig.truth_noise_rad
    if np.linalg.norm(turn) > noise_t and np.linalg.norm(turn - gyro_turn) < np.linalg.norm(turn):
        return (
            f"the truth turns {np.degrees(np.linalg.norm(turn)):.2f}° as the gyro's mean "
            f"would, {np.degrees(np.linalg.norm(gyro_turn)):.2f}°"
        )
    frac = ((t[lo:hi] - t[lo]) / (t[hi - 1] - t[lo]))[:, None]
    path_t = (rel - frac * turn)[ok]
    path_g = (gyro_path(w, t, lo, hi) @ r.T)[ok]
    swing_t, swing_g = float(row_norm(path_t).max()), float(row_norm(path_g).max())
    noise_g = gyro_path_noise(t, lo, hi, std_limit, cfg)
    apart = math.sqrt(float(np.mean(np.sum((path_t - path_g) ** 2, axis=1))))
    if swing_t > noise_t and swing_g > noise_g and apart < 0.5 * rms_norm(path_t):
        return (
            f"the truth sways {np.degrees(swing_t):.2f}° as the gyro does, "
            f"{np.degrees(swing_g):.2f}°"
        )
    return ""


def rms_norm(v: NDArray) -> float:
    """The root mean square of the rows' norms of ``v`` (n, 3)."""
    return math.sqrt(float(np.mean(np.sum(v * v, axis=1))))


def gyro_path(w, t, lo: int, hi: int) -> NDArray:
    """The gyro's rates over ``[lo, hi)`` less their mean, integrated (rad, gyro axes)."""
    dt = np.diff(t[lo:hi], prepend=t[lo])
    return np.cumsum((w[lo:hi] - w[lo:hi].mean(axis=0)) * dt[:, None], axis=0)


def gyro_path_noise(t, lo: int, hi: int, std_limit: float, cfg) -> float:
    """The random walk the gyro's noise allows its path over ``[lo, hi)``: ``z std dt √n``."""
    return cfg.floor_spreads * std_limit * float(np.median(np.diff(t[lo:hi]))) * math.sqrt(hi - lo)

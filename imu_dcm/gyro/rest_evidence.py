"""Rest evidence beyond the gyro and the accelerometer: the autopilot's landed and armed state,
the truth's position and odometry's twist, each on the gyro rows (:mod:`imu_dcm.gyro.rest` says
how each judges a window and where its bound comes from).

Conventions: ``(landed, armed)`` int (N,) each, 1 true, 0 false, -1 unknown; positions in m;
rates in rad/s; windows of ``m`` gyro rows, row ``i`` the window ``[i, i + m)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imu_dcm.arrays import row_norm
from imu_dcm.errors import InputError
from imu_dcm.gyro.windows import min_steps, step_var, windowed_mean_var

__all__ = [
    "Motion",
    "airborne_between",
    "checked_vehicle",
    "motion_windows",
    "position_noise_m",
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


def position_noise_m(p_w: ArrayLike) -> float:
    """A position's noise per sample, m: 1.4826 median |second difference| / √6 (largest axis).

    A position moving at a steady or slowly changing velocity has second differences of its
    noise alone (variance ``6 σ²``). 0 with fewer than 3 finite samples.
    """
    p = np.asarray(p_w, dtype=float)
    p = p[np.all(np.isfinite(p), axis=1)]
    if len(p) < 3:
        return 0.0
    return float(1.4826 * np.median(np.abs(np.diff(p, 2, axis=0)), axis=0).max() / math.sqrt(6))


def twist_noise_rad_s(omega_b: ArrayLike) -> float:
    """A twist's noise per sample, rad/s: 1.4826 median |first difference| / √2 (largest axis),
    at least its quantisation (step²/12). 0 with fewer than 2 finite samples."""
    w = np.asarray(omega_b, dtype=float)
    w = w[np.all(np.isfinite(w), axis=1)]
    if len(w) < 2:
        return 0.0
    mad = float(1.4826 * np.median(np.abs(np.diff(w, axis=0)), axis=0).max() / math.sqrt(2))
    return math.sqrt(max(mad * mad, step_var(min_steps(w))))


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

"""What the noise study runs and the records it returns: the pre-filter modes, the scenes, the
chart colours, one condition's and one BROAD trial's figures, and the attitude error every
figure is measured by. Shared by :mod:`benchmarks.noise_study` (which measures) and
:mod:`benchmarks.noise_report` (which draws and tabulates), so neither imports the other's
definitions.

Conventions: ``omega_b`` body rate relative to the world in body axes, rad/s; quaternions
``[x, y, z, w]``, ``q_w_b`` body to world; ``t_s`` seconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from numpy.typing import NDArray

from imu_dcm.integrator.batch import integrate
from imu_dcm.metrics import attitude_error_deg

MODES = ("none", "kalman", "rts")
#: model-based modes (``euler_prefilter``), run on the free box only (its inertia is known)
EULER_MODES = ("euler-kalman", "euler-rts")
#: unmodelled-torque density told to the model-based filter, N·m/√Hz (the box is torque-free)
EULER_TORQUE_NOISE = 1e-4
#: scene label -> (data_synth scene, parameters, duration s, quick duration s)
SCENES: dict[str, tuple[str, dict, float, float]] = {
    "heavy top, cusp": ("heavy-top", {"motion": "cusp"}, 4.0, 2.0),
    "free box, intermediate axis": ("free-body", {"case": "intermediate"}, 20.0, 10.0),
    "coning 10°, 1 Hz": ("coning", {"half_angle_deg": 10.0, "freq_hz": 1.0}, 10.0, 5.0),
    "coning 10°, 5 Hz": ("coning", {"half_angle_deg": 10.0, "freq_hz": 5.0}, 10.0, 5.0),
}
COLORS = {
    "none": "#444444",
    "kalman": "#d95f02",
    "rts": "#1b9e77",
    "euler-kalman": "#e7298a",
    "euler-rts": "#7570b3",
}


@dataclass(frozen=True)
class ModeStats:
    """Pooled figures of one pre-filter mode in one condition (over seeds)."""

    rate_rms_rad_s: float
    att_rms_deg: float
    att_max_deg: float
    lag_samples: float
    distortion_rate_rms_rad_s: float  # rate error when the same filter runs on the exact rates
    distortion_att_rms_deg: float  # attitude error from the exact rates through the same filter


@dataclass(frozen=True)
class Condition:
    scene: str
    density: float
    rate_hz: float
    seeds: int
    accel_rad_s2: float
    modes: dict[str, ModeStats]
    t_s: NDArray  # sample times of the seeds' common grid, s
    att_rms_series_deg: dict[str, NDArray]  # attitude error RMS over the seeds at each t_s, deg
    # nothing given (the scenes never rest): N from the log's spectrum, then rts with it
    noise_est_rad_s_sqrt_hz: float = math.nan  # mean over seeds
    rts_est_rate_rms_rad_s: float = math.nan
    rts_est_att_rms_deg: float = math.nan


@dataclass(frozen=True)
class BroadResult:
    trial: str
    n_samples: int
    summary: dict
    att_rms_deg: dict[str, float]
    att_max_deg: dict[str, float]
    rate_change_rms_rad_s: dict[str, float]  # |filtered - raw| RMS: how much the filter moved


def att_err_deg(omega_b: NDArray, t_s: NDArray, q_true: NDArray) -> NDArray:
    """Total attitude error (deg) of magnus4 from the true initial attitude, at each sample."""
    q = integrate(omega_b, t_s, q_true[0], "magnus4").as_quat()
    return attitude_error_deg(q, q_true).total_deg

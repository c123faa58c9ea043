"""Is the sample rate high enough for the recorded motion? The method's own error, estimated.

Each method's error per unit time shrinks as ``dt^p`` with its order ``p`` (docs/integrator.md:
1 for ``start``/``end``, 2 for ``trapezoid``/``coning``, 4 for ``magnus4``), made of the
truncation of the rate between samples and the coning term. For the rates and rate changes
this log actually has, integrating every second sample (step ``2 dt``) gives the error at
``2 dt`` minus that at ``dt``; Richardson's estimate of the error at ``dt`` is that difference
over ``2^p - 1``. It needs no truth, and no constant: it is the method's bound for this motion.

When the estimate is half the replay's total RMS error or more, the score measures the
sampling about as much as the gyro: the rate is too low for the motion, and one line says so
with the estimate.

Conventions: ``q_w_b`` ``[x, y, z, w]``; rates rad/s; angles in degrees.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from imu_dcm.arrays import BLOCK_ROWS
from imu_dcm.errors import Diagnostics
from imu_dcm.integrator.batch import integrate_quat
from imu_dcm.metrics import rms
from imu_dcm.so3 import quat_angle_rad

__all__ = ["ORDER", "TOO_SLOW_SHARE", "sampling_error_deg"]

#: Convergence order of each rate method (docs/integrator.md).
ORDER = {"start": 1, "end": 1, "trapezoid": 2, "coning": 2, "magnus4": 4}
#: The sampling's share of the score from which the rate is said to be too low.
TOO_SLOW_SHARE = 0.5


def sampling_error_deg(
    omega_b: NDArray[np.float64],
    t_s: NDArray[np.float64],
    q_est: NDArray[np.float64],
    method: str,
) -> float | None:
    """Richardson's estimate of the method's RMS attitude error over one segment, degrees.

    Parameters
    ----------
    omega_b : float64 (n, 3) — the rates integrated, rad/s.
    t_s : float64 (n,) — their stamps, s.
    q_est : float64 (n, 4) — the estimate integrated from them (row 0 the start).
    method : the method that integrated it.

    Returns
    -------
    float or None — None for a method without an order, or fewer than 8 samples.
    """
    p = ORDER.get(method)
    if p is None or len(t_s) < 8:
        return None
    said = Diagnostics()  # the record's gaps and method were said once, by the replay
    half = integrate_quat(omega_b[::2], t_s[::2], q_est[0], method, diagnostics=said)
    diff = np.empty(len(half))
    for a in range(0, len(half), BLOCK_ROWS):  # each angle its own: the temporaries of a block
        k = slice(a, a + BLOCK_ROWS)
        diff[k] = quat_angle_rad(q_est[2 * a : 2 * (a + BLOCK_ROWS) : 2], half[k])
    return float(np.degrees(rms(diff)) / (2**p - 1))

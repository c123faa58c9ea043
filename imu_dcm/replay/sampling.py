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

from imu_dcm._kernels.calls import quat_angles
from imu_dcm.arrays import BLOCK_ROWS
from imu_dcm.errors import Diagnostics
from imu_dcm.integrator.batch import integrate_quat
from imu_dcm.integrator.streaming import DcmIntegrator
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
    diff = _half_rate_angles(omega_b, t_s, q_est, method)
    return float(np.degrees(rms(diff)) / (2**p - 1))


def _half_rate_angles(omega_b, t_s, q_est, method: str) -> NDArray[np.float64]:
    """The angle, rad, between the estimate and the same integration of every second sample,
    at each of those samples: the half-rate run streamed a block at a time
    (:class:`~imu_dcm.integrator.streaming.DcmIntegrator`, the batch integration to rounding),
    so memory holds a block of it, not a second estimate.

    ``magnus4`` returns each attitude one sample late and commits the first two steps
    together: the attitude after the first half-rate step comes from the batch integration of
    the first four samples, whose second step is the whole run's (its stencil is interior).
    """
    w, t = omega_b[::2], t_s[::2]
    n = len(t)
    diff = np.empty(n)
    lag = method == "magnus4"
    said = Diagnostics()  # the record's gaps and method were said once, by replay
    integ = DcmIntegrator(q_est[0], method, diagnostics=said)
    for a in range(0, n, BLOCK_ROWS):
        b = min(n, a + BLOCK_ROWS)
        q = integ.update_many_quat(w[a:b], t[a:b])
        rows = np.arange(a, b) - 1 if lag else np.arange(a, b)
        keep = rows >= (2 if lag else 0)
        _angles(diff, rows[keep], q[keep], q_est)
    if lag:
        last = integ.finish()
        diff[n - 1] = quat_angle_rad(q_est[2 * (n - 1)], last)
        first = integrate_quat(w[:4], t[:4], q_est[0], method, diagnostics=said)
        _angles(diff, np.arange(2), first[:2], q_est)
    return diff


def _angles(diff: NDArray, rows: NDArray, q: NDArray, q_est: NDArray) -> None:
    """``diff[rows]``: the angle between ``q`` and the estimate at the half-rate ``rows``."""
    if len(rows):
        q_a, q_b, out = (
            np.ascontiguousarray(q_est[2 * rows]),
            np.ascontiguousarray(q),
            np.empty(len(rows)),
        )
        if quat_angles(q_a, q_b, out) >= 0:  # the same formula in one compiled pass
            out = quat_angle_rad(q_a, q_b)  # which names the quaternion it refuses
        diff[rows] = out

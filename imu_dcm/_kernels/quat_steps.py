"""The rotation of each step of an attitude series, written for numba: ``log(q_k⁻¹ q_{k+1})``
for every pair of consecutive rows in one pass (the truth checks and the rest judgement of a
replay run it over every truth row), and its entry point (:data:`ENTRIES`).

Imported only to compile, like :mod:`imu_dcm._kernels.integrator`.
"""

from __future__ import annotations

import math

import numpy as np

from imu_dcm.so3 import SMALL_ANGLE_RAD

__all__ = ["ENTRIES", "SIGNATURE", "step_rotvecs"]

SIGNATURE = "int64(float64[:, ::1], boolean[::1], float64[:, ::1])"


def step_rotvecs(q, ok, out):
    """``out[k] = log(q_k⁻¹ ⊗ q_{k+1})`` (rad, angle in ``[0, π]``) for ``k < len(q) - 1``,
    ``q`` ``[x, y, z, w]`` rows normalised here; NaN where ``ok[k]`` or ``ok[k + 1]`` is False.
    Returns the first pair whose product has a zero or non-finite norm (-1: none), its row
    left NaN.

    The same formulas as :func:`imu_dcm.so3.log_quat` of :func:`imu_dcm.so3.quat_multiply`
    (the Hamilton product of the conjugate, the shortest arc, ``2 atan2(s, w)`` and its series
    below :data:`imu_dcm.so3.SMALL_ANGLE_RAD`), row by row instead of plane by plane.
    """
    n = q.shape[0]
    bad = np.int64(-1)
    for k in range(n - 1):
        if not (ok[k] and ok[k + 1]):
            out[k, 0] = out[k, 1] = out[k, 2] = np.nan
            continue
        ax, ay, az, aw = q[k, 0], q[k, 1], q[k, 2], q[k, 3]
        bx, by, bz, bw = q[k + 1, 0], q[k + 1, 1], q[k + 1, 2], q[k + 1, 3]
        x = aw * bx - ax * bw - ay * bz + az * by
        y = aw * by + ax * bz - ay * bw - az * bx
        z = aw * bz - ax * by + ay * bx - az * bw
        w = aw * bw + ax * bx + ay * by + az * bz
        norm = math.sqrt(x * x + y * y + z * z + w * w)
        if not (norm > 0.0 and norm < math.inf):
            out[k, 0] = out[k, 1] = out[k, 2] = np.nan
            if bad < 0:
                bad = k
            continue
        if w < 0.0:
            norm = -norm
        x, y, z, w = x / norm, y / norm, z / norm, w / norm
        s = math.sqrt(x * x + y * y + z * z)
        if s < 0.5 * SMALL_ANGLE_RAD:
            r2 = s * s / (w * w)
            scale = 2.0 / w * (1.0 - r2 / 3.0 + r2 * r2 / 5.0)
        else:
            scale = 2.0 * math.atan2(s, w) / s
        out[k, 0], out[k, 1], out[k, 2] = x * scale, y * scale, z * scale
    return bad


#: ``name -> (function, signature)`` of this kernel's entry point.
ENTRIES = {"step_rotvecs": (step_rotvecs, SIGNATURE)}

"""Attitude error metrics: total, inclination and heading, in degrees.

The error of an estimate ``q_est`` against a truth ``q_true`` (both ``q_w_b``, body to world,
``[x, y, z, w]``) is the world-frame rotation ``q_e = q_est ⊗ q_true*`` that carries the true
attitude onto the estimate. Its angle is the total error. Split about the world vertical (ENU,
z up) by swing-twist: the **heading** error is the twist of ``q_e`` about world z,
``2 atan2(|e_z|, |e_w|)``, and the **inclination** error is the remaining swing,
``2 acos(sqrt(e_w² + e_z²))`` (the tilt of the estimated vertical; BROAD's definitions).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imu_dcm.so3 import product_planes, quat_checked_norm

__all__ = ["AttitudeError", "attitude_error_deg", "rms"]


@dataclass(frozen=True)
class AttitudeError:
    """Per-sample attitude errors in degrees, each of shape ``(N,)``.

    Attributes
    ----------
    total_deg : angle of ``q_est ⊗ q_true*``, deg, in [0, 180].
    inclination_deg : tilt part (swing about a horizontal axis), deg.
    heading_deg : part about the world vertical (twist about world z), deg.
    """

    total_deg: NDArray[np.float64]
    inclination_deg: NDArray[np.float64]
    heading_deg: NDArray[np.float64]


def attitude_error_deg(q_est: ArrayLike, q_true: ArrayLike) -> AttitudeError:
    """Total, inclination and heading error of ``q_est`` against ``q_true``.

    Parameters
    ----------
    q_est, q_true : array_like, shape (..., 4)
        Attitudes ``q_w_b`` as ``[x, y, z, w]``; broadcast against each other; sign-insensitive.

    Returns
    -------
    AttitudeError
    """
    # Each angle below is a ratio of components, the same for scaled quaternions: the norms
    # are only checked (zero or NaN refused), not divided out.
    q_est, q_true = np.asarray(q_est, dtype=float), np.asarray(q_true, dtype=float)
    quat_checked_norm(q_est)
    quat_checked_norm(q_true)
    ex, ey, ez, ew = np.abs(product_planes(q_est, q_true, conj_q=True))
    total = 2.0 * np.arctan2(np.sqrt(ex * ex + ey * ey + ez * ez), ew)
    heading = 2.0 * np.arctan2(ez, ew)
    # swing angle: 2 atan2(|(ex, ey)|, |(ew, ez)|) — equal to 2 acos(sqrt(ew²+ez²)), better
    # conditioned near zero.
    inclination = 2.0 * np.arctan2(np.sqrt(ex * ex + ey * ey), np.sqrt(ew * ew + ez * ez))
    return AttitudeError(np.degrees(total), np.degrees(inclination), np.degrees(heading))


def rms(x: ArrayLike) -> float:
    """Root mean square of an array (NaN if empty)."""
    x = np.asarray(x, dtype=float)
    return float(np.sqrt(np.mean(x * x))) if x.size else float("nan")

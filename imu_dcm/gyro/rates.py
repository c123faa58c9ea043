"""What no gyro produces: the rate rules replay and live share.

Replay's cleaning (:mod:`imu_dcm.replay.clean`) and live's pipeline (:mod:`imu_dcm.live.pipeline`)
judge every sample with these, so a rate one drops the other drops too.

* :func:`implausible_rates`: a component above :data:`MAX_RATE_RAD_S` (10⁴ rad/s = 5.7e5 °/s).
  The bound is physics, not a sensor's: the fastest MEMS full scale is ±4000 °/s = 70 rad/s, and
  even that read as deg/s (a unit error) stays under it; a flipped exponent bit (1e30, 3e38,
  1.7e308) is far above.
* :func:`deg_evidence`: evidence that rates declared rad/s are deg/s: against the truth's own
  rotation rate when a truth covers the samples (a ratio of 180/π), else a 99th percentile of
  ``|ω|`` above :data:`FULL_SCALE_RAD_S`, the ±2000 °/s full scale of common MEMS gyros (a body
  that turns faster than the usual full scale for 1 % of the time is far more likely a deg/s
  stream than a real motion).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imu_dcm._kernels.calls import rate_ratios
from imu_dcm.arrays import BLOCK_ROWS, median, percentile, row_finite, row_max, row_norm

__all__ = [
    "FULL_SCALE_RAD_S",
    "MAX_RATE_RAD_S",
    "deg_evidence",
    "implausible_rates",
    "truth_rate_ratio",
]

#: Full scale of common MEMS gyros (±2000 °/s): rates above it suggest a deg/s log.
FULL_SCALE_RAD_S = 2000.0 * np.pi / 180.0
#: Rates above this are no gyro's (rad/s): 10⁴ rad/s = 5.7e5 °/s.
MAX_RATE_RAD_S = 1.0e4
#: Truth rotation rates above this (rad/s) are motion well above a gyro's noise.
_MOVING_RAD_S = 0.2


def implausible_rates(omega_b: ArrayLike) -> NDArray[np.bool_]:
    """Rows with a component above :data:`MAX_RATE_RAD_S` (finite rows; NaN compares False).

    Parameters
    ----------
    omega_b : array_like, float (N, 3)
        Body rates, rad/s.

    Returns
    -------
    bool (N,)
    """
    w = np.asarray(omega_b, dtype=float).reshape(-1, 3)
    out = np.empty(len(w), bool)
    scratch = np.empty((min(len(w), BLOCK_ROWS), 3))  # reused: no whole-log |w|
    for a in range(0, len(w), BLOCK_ROWS):
        b = min(len(w), a + BLOCK_ROWS)
        out[a:b] = row_max(np.abs(w[a:b], out=scratch[: b - a])) > MAX_RATE_RAD_S
    return out


def truth_rate_ratio(omega_b: NDArray, t_s: NDArray, q_truth: NDArray) -> float | None:
    """Median ratio of the gyro's rate norm to the truth's rotation rate where the truth moves
    (over :data:`_MOVING_RAD_S`, well above noise), or None with 10 or fewer such steps.

    ``omega_b`` float64 (N, 3) rad/s as declared; ``t_s`` (N,) s; ``q_truth`` (N, 4) ``q_w_b``
    ``[x, y, z, w]`` (NaN rows where none covers the stamp)."""
    ok = row_finite(q_truth)
    if len(ok) < 2 or np.count_nonzero(ok[:-1] & ok[1:]) <= 10:
        return None
    # the ratio on every step where the truth moves, in one compiled pass (one array)
    ratio = np.empty(len(ok) - 1)
    filled = rate_ratios(
        np.ascontiguousarray(omega_b, dtype=float),
        np.ascontiguousarray(t_s, dtype=float),
        np.ascontiguousarray(q_truth, dtype=float),
        ok,
        _MOVING_RAD_S,
        ratio,
    )
    if filled <= 10:
        return None
    return median(ratio[:filled], overwrite_input=True)


def deg_evidence(omega_b: NDArray, t_s: NDArray, q_truth: NDArray) -> str | None:
    """Evidence that rates given as rad/s are deg/s, as one phrase, or None.

    Parameters
    ----------
    omega_b : float64 (N, 3)
        Body rates as declared rad/s.
    t_s : float64 (N,)
        Their stamps, s, increasing.
    q_truth : float64 (N, 4)
        The truth ``q_w_b`` ``[x, y, z, w]`` at each stamp (NaN rows where none covers it).

    Returns
    -------
    str or None
        With more than 10 moving covered pairs: the median ratio of the gyro's rate to the
        truth's, when it is within 20 % of 180/π. Else: the 99th percentile of ``|ω|`` when it
        is above :data:`FULL_SCALE_RAD_S`.
    """
    ratio = truth_rate_ratio(omega_b, t_s, q_truth)
    if ratio is not None:
        if abs(ratio / (180 / np.pi) - 1) < 0.2:
            return (
                f"the gyro rate is {ratio:.1f}x the truth's rotation rate (180/π = 57.3 for deg/s)"
            )
        return None
    p99 = percentile(row_norm(omega_b), 99) if len(omega_b) else 0.0
    if p99 > FULL_SCALE_RAD_S:
        return (
            f"the 99th percentile of |omega| is {p99:.0f} rad/s, above the ±2000 °/s = "
            f"{FULL_SCALE_RAD_S:.1f} rad/s full scale of common gyros (as deg/s it would be "
            f"{np.radians(p99):.2f} rad/s)"
        )
    return None

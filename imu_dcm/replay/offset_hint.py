"""What ``--truth-offset auto`` would change, said where the best shift is printed.

The rate check measures the shift that best aligns the truth's rotation rate with the gyro's.
When the replay did not apply it, :func:`auto_offset_rms_deg` scores the same estimate against
the truth shifted by it: the estimate's increments do not depend on the truth, only its first
attitude does, so the estimate is re-anchored at the first sample k inside the shifted truth
(``q' = q_truth'(k) ⊗ q(k)* ⊗ q``, a change of world frame) and scored on the samples it
covers. That is the RMS ``--truth-offset auto`` gives, up to the mounting and bias steps that
also look at the truth.

A shift shorter than half the gyro's median step cannot be told from none by the stamps: no
hint is given then, and a shift that rounds to 0.0 ms is printed without a sign.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from imu_dcm.arrays import median_diff, row_finite
from imu_dcm.gyro.resample import slerp_truth
from imu_dcm.metrics import rms
from imu_dcm.so3 import angle_between_deg, quat_conjugate, quat_multiply


def shift_ms(shift_s: float) -> str:
    """``+4.1 ms``; ``0.0 ms`` for any shift that rounds to zero (never ``-0.0 ms``)."""
    ms = round(shift_s * 1e3, 1)
    return "0.0 ms" if ms == 0 else f"{ms:+.1f} ms"


def auto_offset_rms_deg(
    aligned, base: str, t_ns: NDArray[np.int64], q_est: NDArray, anchors: list[int], scored
) -> float | None:
    """The RMS total error (deg) with the best shift applied, or None when there is nothing to
    say (no truth, the shift already applied or under half a gyro step, truth jumps)."""
    truth, check = aligned.truth, aligned.check
    if truth is None or check is None or check.shift_s is None or aligned.offset_s != 0.0:
        return None
    if len(anchors) != 1 or len(t_ns) < 2 or not scored.any():
        return None
    if abs(check.shift_s) * 1e9 < 0.5 * median_diff(t_ns):
        return None
    tt = (truth.t_ns if base == "header" else truth.log_t_ns) + np.int64(round(check.shift_s * 1e9))
    shifted = slerp_truth(tt, truth.q_w_b, t_ns)
    ok = row_finite(shifted) & row_finite(q_est)
    ok[: anchors[0]] = False
    if not ok.any():
        return None
    k = int(np.argmax(ok))  # the first sample inside the shifted truth: the new anchor
    q_new = quat_multiply(quat_multiply(shifted[k], quat_conjugate(q_est[k])), q_est)
    both = scored & ok
    if not both.any():
        return None
    return float(rms(angle_between_deg(q_new[both], shifted[both])))

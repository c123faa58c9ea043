"""The result every replay ends with, truth or not: the final attitude and how far it turned.

``final_q_w_b`` is the last estimate ``q_w_b`` (``[x, y, z, w]``, body to world, Hamilton);
``rotation_deg`` is the angle of the rotation from the estimate's first attitude to its last
(``q_first* ⊗ q_last``, in [0, 180]°); ``turned_deg`` is the angle turned on the way, the
integral of the rate's norm over the estimated samples (trapezoid rule on the stamps, in the
rates as integrated: bias removed). A body spinning at a constant 10 °/s for 100 s has
``turned_deg`` 1000 and ``rotation_deg`` 80.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from imu_dcm.arrays import BLOCK_ROWS, row_finite, row_norm, true_span
from imu_dcm.so3 import angle_between_deg


def outcome(
    t_s: NDArray[np.float64], omega_b: NDArray[np.float64], q_est: NDArray[np.float64], start: int
) -> dict:
    """``final_q_w_b``, ``rotation_deg`` and ``turned_deg`` of an estimate (module docstring).

    Parameters
    ----------
    t_s : float64 (N,) — stamps, s.
    omega_b : float64 (N, 3) — rates as integrated, body axes, rad/s.
    q_est : float64 (N, 4) — the estimate ``q_w_b`` ``[x, y, z, w]``; NaN rows not estimated.
    start : int — the first estimated sample.

    Returns
    -------
    dict
        The three fields of :class:`~imu_dcm.replay.summary.ReplaySummary`; None each when no
        sample was estimated.
    """
    span = true_span(row_finite(q_est[start:]))
    if span is None:
        return {"final_q_w_b": None, "rotation_deg": None, "turned_deg": None}
    first_row, last_row = start + span[0], start + span[1]
    first, last = q_est[first_row], q_est[last_row]
    turned = 0.0
    for a in range(first_row, last_row, BLOCK_ROWS):  # trapezoids of a block, with its next row
        b = min(last_row, a + BLOCK_ROWS) + 1
        speed = row_norm(omega_b[a:b])
        turned += float(np.sum(0.5 * (speed[1:] + speed[:-1]) * np.diff(t_s[a:b])))
    return {
        "final_q_w_b": tuple(float(v) for v in last),
        "rotation_deg": float(angle_between_deg(first, last)),
        "turned_deg": float(np.degrees(turned)),
    }


def outcome_lines(final_q_w_b, rotation_deg, turned_deg, written) -> list[str]:
    """The ``result`` line (final ``q_w_b``, rotation from the start, angle turned) and the
    ``written`` line (every output, or how to get one)."""
    if final_q_w_b is None:
        result = "result     no estimate (no sample was integrated)"
    else:
        q = ", ".join(f"{v:+.6f}" for v in final_q_w_b)
        result = (
            f"result     final q_w_b ({q}) [x, y, z, w]; {rotation_deg:.2f}° from the start "
            f"attitude, {turned_deg:.1f}° turned on the way"
        )
    wrote = (
        f"written    {', '.join(written)}"
        if written
        else "written    nothing (--out DIR, --export-tum DIR, --summary-json PATH or "
        "--rerun save:F.rrd write the estimate)"
    )
    return [result, wrote]

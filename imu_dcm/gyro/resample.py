"""Attitude series at other stamps: a recorded ``q_w_b`` series slerped to query times.

:func:`slerp_truth` is the one resampler of a truth (or any attitude) series: the replay judges
its estimate with it, and live compares against a truth topic with it. It slerps between the
two recorded samples around each query time and never bridges a gap longer than
:data:`TRUTH_BRIDGE_STEPS` median steps, so a hole in the truth stays a hole (NaN), never a
made-up attitude. Quaternions are ``[x, y, z, w]``, body to world; stamps int64 ns.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imu_dcm._kernels.calls import slerp_rows
from imu_dcm.arrays import median, row_norm

__all__ = ["TRUTH_BRIDGE_STEPS", "slerp_truth"]

#: Gaps between truth samples longer than this many median truth steps are not bridged.
TRUTH_BRIDGE_STEPS = 2.0


def slerp_truth(truth_t_ns: ArrayLike, q_w_b: ArrayLike, t_ns: ArrayLike) -> NDArray[np.float64]:
    """Truth attitudes at times ``t_ns`` by slerp, NaN outside coverage and across long gaps.

    Parameters
    ----------
    truth_t_ns : array_like, int64 (M,)
        Truth stamps (any order; sorted here, duplicates dropped).
    q_w_b : array_like, shape (M, 4)
        Truth ``[x, y, z, w]`` (body to world); need not be sign-continuous.
    t_ns : array_like, int64 (N,)
        Query stamps.

    Returns
    -------
    ndarray, shape (N, 4)
        Unit quaternions; NaN rows before the first / after the last truth sample and inside
        gaps longer than ``TRUTH_BRIDGE_STEPS`` median truth steps (never bridged).
    """
    tt = np.asarray(truth_t_ns, dtype=np.int64)
    q = np.asarray(q_w_b, dtype=float)
    t = np.asarray(t_ns, dtype=np.int64)
    norm = row_norm(q)
    ok = np.isfinite(norm) & (norm > 0.5)
    if not ok.all():  # the usual case keeps q and its stamps (rows are normalised as read)
        tt, q, norm = tt[ok], q[ok], norm[ok]
    steps = np.diff(tt)
    if len(tt) > 1 and not np.all(steps > 0):  # recorded truth is usually in order
        order = np.argsort(tt, kind="stable")
        tt, q, norm = tt[order], q[order], norm[order]
        uniq = np.concatenate([[True], np.diff(tt) > 0])
        tt, q, norm = tt[uniq], q[uniq], norm[uniq]
        steps = np.diff(tt)
    out = np.empty((len(t), 4))
    bridged = np.zeros(0, bool)
    if len(tt) > 1:  # each truth step is bridged or not, once; a query takes its step's verdict
        bridged = steps <= TRUTH_BRIDGE_STEPS * median(steps) * (1 + 1e-6)
    q = np.ascontiguousarray(q, dtype=float)
    slerp_rows(tt, q, np.ascontiguousarray(norm, dtype=float), bridged, t, out)  # one pass
    return out

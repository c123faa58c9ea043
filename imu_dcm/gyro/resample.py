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

from imu_dcm.arrays import median, row_norm
from imu_dcm.so3 import exp_quat, log_quat, quat_conjugate, quat_multiply

__all__ = ["TRUTH_BRIDGE_STEPS", "slerp_truth"]

#: Gaps between truth samples longer than this many median truth steps are not bridged.
TRUTH_BRIDGE_STEPS = 2.0
#: Query stamps resampled at a time: each query's result depends on it alone, so blocks give
#: the whole-log result exactly, with ~100 MB less of temporaries per million queries.
BLOCK = 1 << 17


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
    if ok.all():  # the usual case: no copies of the stamps
        q = q / norm[:, None]
    else:
        tt, q = tt[ok], q[ok] / norm[ok, None]
    steps = np.diff(tt)
    if len(tt) > 1 and not np.all(steps > 0):  # recorded truth is usually in order
        order = np.argsort(tt, kind="stable")
        tt, q = tt[order], q[order]
        uniq = np.concatenate([[True], np.diff(tt) > 0])
        tt, q = tt[uniq], q[uniq]
        steps = np.diff(tt)
    out = np.full((len(t), 4), np.nan)
    if len(tt) == 0:
        return out
    bridged = None
    if len(tt) > 1:  # each truth step is bridged or not, once; a query takes its step's verdict
        bridged = steps <= TRUTH_BRIDGE_STEPS * median(steps) * (1 + 1e-6)
    for a in range(0, len(t), BLOCK):  # the temporaries of one block, not of the whole log
        _slerp_block(tt, q, steps, bridged, t[a : a + BLOCK], out[a : a + BLOCK])
    return out


def _slerp_block(tt, q, steps, bridged, t, out) -> None:
    """:func:`slerp_truth` for the queries ``t``, written into ``out`` (rows of ``t``)."""
    j = np.searchsorted(tt, t, side="right") - 1  # tt[j] <= t < tt[j+1]
    exact = (j >= 0) & (tt[np.clip(j, 0, None)] == t)
    out[exact] = q[j[exact]]
    if bridged is None:
        return
    inner = ~exact & (j >= 0) & (j < len(tt) - 1)
    inner &= bridged[np.clip(j, 0, len(tt) - 2)]
    idx = np.flatnonzero(inner)
    jj = j[idx]
    u = (t[idx] - tt[jj]).astype(float) / steps[jj].astype(float)
    q0 = q[jj]
    rel = quat_multiply(quat_conjugate(q0), q[jj + 1])
    rel = np.where(rel[:, 3:4] < 0, -rel, rel)  # shortest arc
    out[idx] = quat_multiply(q0, exp_quat(u[:, None] * log_quat(rel)))

"""Attitude series: a recorded ``q_w_b`` series slerped to query times, and the rotation of each
of its steps (:func:`step_rotvecs`).

:func:`slerp_truth` is the one resampler of a truth (or any attitude) series: the replay judges
its estimate with it, and live compares against a truth topic with it. It slerps between the
two recorded samples around each query time and never bridges a gap longer than
:data:`TRUTH_BRIDGE_STEPS` median steps, so a hole in the truth stays a hole (NaN), never a
made-up attitude. Quaternions are ``[x, y, z, w]``, body to world; stamps int64 ns.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imu_dcm._kernels.calls import row_norms, slerp_rows
from imu_dcm._kernels.calls import step_rotvecs as kernel_step_rotvecs
from imu_dcm.arrays import median
from imu_dcm.errors import InputError

__all__ = ["TRUTH_BRIDGE_STEPS", "slerp_truth", "step_rotvecs"]

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
    norm = np.empty(len(q))
    row_norms(q.reshape(len(q), -1), norm)  # one compiled pass, numpy's order of sums
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
        if steps.max() <= TRUTH_BRIDGE_STEPS * steps.min() * (1 + 1e-6):
            bridged = np.ones(len(steps), bool)  # none over 2x the shortest, so the median
        else:
            bridged = steps <= TRUTH_BRIDGE_STEPS * median(steps) * (1 + 1e-6)
    q = np.ascontiguousarray(q, dtype=float)
    slerp_rows(tt, q, np.ascontiguousarray(norm, dtype=float), bridged, t, out)  # one pass
    return out


def step_rotvecs(q: ArrayLike, ok: ArrayLike, out: NDArray | None = None) -> NDArray[np.float64]:
    """Each step's rotation ``log(q_k⁻¹ ⊗ q_{k+1})`` of a series of attitudes, rad.

    The same numbers as :func:`~imu_dcm.so3.log_quat` of :func:`~imu_dcm.so3.quat_multiply` of
    the conjugate, in one compiled pass with no temporaries
    (:func:`imu_dcm._kernels.calls.step_rotvecs`).

    Parameters
    ----------
    q : array_like, shape (M, 4)
        ``[x, y, z, w]`` quaternions (normalised here).
    ok : array_like, bool (M,)
        The rows to use: a step with a row not ok is NaN.
    out : float64 C-contiguous (M - 1, 3), optional
        Written and returned instead of a new array.

    Returns
    -------
    ndarray, shape (M - 1, 3)
        Rotation vectors, angle in ``[0, π]``.

    Raises
    ------
    InputError
        If a step's quaternions have a zero norm.
    """
    q = np.ascontiguousarray(q, dtype=float)
    d = np.empty((max(len(q) - 1, 0), 3)) if out is None else out
    if kernel_step_rotvecs(q, np.asarray(ok, dtype=bool), d) >= 0:
        raise InputError("Expected quaternions with finite non-zero norm, got a zero or NaN one")
    return d

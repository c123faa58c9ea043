"""Attitude and rate series, written for numba: the rotation of each step of an attitude
series, ``log(q_k⁻¹ q_{k+1})`` for every pair of consecutive rows in one pass (the truth checks
and the rest judgement of a replay run it over every truth row), the series slerped at other
stamps (the truth on the gyro's rows), a rate's running integral at given stamps (the
gyro's turn over the truth's steps), and the statistics of every window of a series and its
smallest steps (the rest rule's), and the attitude error of an estimate against a truth, row by
row (the replay's score: its angles and its world and body vectors), the angle between two
attitudes row by row, the truth's own noise (the
changes between its steps), its mean rate over every window (the rest rule's), the gyro's rate
against the truth's (the units' evidence) and
the norms of rows; their entry points (:data:`ENTRIES`).

Imported only to compile, like :mod:`imu_dcm._kernels.integrator`.
"""

from __future__ import annotations

import math

import numpy as np

from imu_dcm._kernels.integrator import exp_quat, quat_mul
from imu_dcm._kernels.jit import inline
from imu_dcm.so3 import SMALL_ANGLE_RAD

__all__ = [
    "ANGLE_SIGNATURE",
    "ENTRIES",
    "ERROR_SIGNATURE",
    "NORM_SIGNATURE",
    "RATIO_SIGNATURE",
    "SECOND_SIGNATURE",
    "VECTOR_SIGNATURE",
    "WINDOW_RATE_SIGNATURE",
    "INTEGRAL_SIGNATURE",
    "SIGNATURE",
    "SLERP_SIGNATURE",
    "WINDOW_SIGNATURE",
    "attitude_errors",
    "error_vectors",
    "quat_angles",
    "integrated_rate",
    "rate_ratios",
    "row_norms",
    "second_steps",
    "window_rates",
    "min_steps",
    "slerp_rows",
    "step_rotvecs",
    "window_norms",
]

SIGNATURE = "int64(float64[:, ::1], boolean[::1], float64[:, ::1])"
SLERP_SIGNATURE = (
    "void(int64[::1], float64[:, ::1], float64[::1], boolean[::1], int64[::1], float64[:, ::1])"
)
INTEGRAL_SIGNATURE = "void(int64[::1], float64[:, ::1], int64[::1], float64[:, ::1])"
WINDOW_SIGNATURE = "void(float64[:, ::1], int64, float64[::1], float64[::1])"
STEPS_SIGNATURE = "void(float64[:, ::1], float64[::1])"
ERROR_SIGNATURE = "int64(float64[:, ::1], float64[:, ::1], float64[:, ::1])"
ANGLE_SIGNATURE = "int64(float64[:, ::1], float64[:, ::1], float64[::1])"
VECTOR_SIGNATURE = "void(float64[:, ::1], float64[:, ::1], float64[::1], float64[:, ::1])"
NORM_SIGNATURE = "void(float64[:, :], float64[::1])"
WINDOW_RATE_SIGNATURE = "void(float64[:, ::1], float64[::1], boolean[::1], int64, float64[::1])"
SECOND_SIGNATURE = "int64(float64[:, ::1], boolean[::1], boolean[::1], float64[:, ::1])"
RATIO_SIGNATURE = (
    "int64(float64[:, ::1], float64[::1], float64[:, ::1], boolean[::1], float64, float64[::1])"
)
#: A query this many truth steps past the last one's is found by bisection, not by walking.
_WALK = 32


@inline
def _log(x: float, y: float, z: float, w: float) -> tuple:
    """:func:`imu_dcm.so3.log_quat` of ``[x, y, z, w]`` (normalised here, shortest arc), for a
    finite non-zero quaternion."""
    norm = math.sqrt(x * x + y * y + z * z + w * w)
    if w < 0.0:
        norm = -norm
    x, y, z, w = x / norm, y / norm, z / norm, w / norm
    s = math.sqrt(x * x + y * y + z * z)
    if s < 0.5 * SMALL_ANGLE_RAD:
        r2 = s * s / (w * w)
        scale = 2.0 / w * (1.0 - r2 / 3.0 + r2 * r2 / 5.0)
    else:
        scale = 2.0 * math.atan2(s, w) / s
    return x * scale, y * scale, z * scale


@inline
def _step(q, k: int) -> tuple:
    """``log(q_k⁻¹ ⊗ q_{k+1})`` of rows ``k`` and ``k + 1`` of ``q`` (each step's rotation, as
    every pass here takes it): NaN where their product has a zero or non-finite norm."""
    a_conj = (-q[k, 0], -q[k, 1], -q[k, 2], q[k, 3])
    x, y, z, w = quat_mul(a_conj, (q[k + 1, 0], q[k + 1, 1], q[k + 1, 2], q[k + 1, 3]))
    norm = math.sqrt(x * x + y * y + z * z + w * w)
    if not (norm > 0.0 and norm < math.inf):
        return np.nan, np.nan, np.nan
    return _log(x, y, z, w)


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
        x, y, z = _step(q, k)
        if x != x and bad < 0:  # NaN: the product's norm is zero or not finite
            bad = k
        out[k, 0], out[k, 1], out[k, 2] = x, y, z
    return bad


def slerp_rows(tt, q, norm, bridged, t, out):
    """The attitudes ``q`` (rows ``q[j] / norm[j]`` at stamps ``tt``, strictly increasing) at
    the stamps ``t`` (any order) into ``out``: row ``j`` itself at ``tt[j]``, the slerp from
    ``j`` to ``j + 1`` (the shortest arc) between them where ``bridged[j]``, NaN before the
    first stamp, after the last and across a step not bridged.

    The same formulas as :func:`imu_dcm.gyro.resample.slerp_truth` in numpy: ``u`` the
    fraction of the step, ``q_j ⊗ exp(u log(q_j⁻¹ q_{j+1}))``; each step's logarithm is taken
    once for the run of queries inside it. Sorted queries walk forward from the last one's
    step; others (and long jumps ahead) are found by bisection.
    """
    m = len(tt)
    j = np.int64(-1)  # the step of the last query: tt[j] <= t < tt[j + 1]
    done = np.int64(-1)  # the step whose logarithm (px, py, pz) is held
    px = py = pz = 0.0
    for i in range(len(t)):
        ti = t[i]
        if m == 0 or ti < tt[0]:
            j = np.int64(-1)
        else:
            if j < 0 or ti < tt[j]:
                j = np.int64(-1)
            walk = 0
            while j + 1 < m and tt[j + 1] <= ti and walk < _WALK:
                j += 1
                walk += 1
            if j + 1 < m and tt[j + 1] <= ti:  # far ahead: the largest j with tt[j] <= ti
                lo, hi = j + 1, m - 1
                while lo < hi:
                    mid = (lo + hi + 1) // 2
                    if tt[mid] <= ti:
                        lo = mid
                    else:
                        hi = mid - 1
                j = lo
        if j < 0 or (tt[j] != ti and (j >= m - 1 or not bridged[j])):
            out[i, 0] = out[i, 1] = out[i, 2] = out[i, 3] = np.nan
            continue
        r = norm[j]
        q0 = (q[j, 0] / r, q[j, 1] / r, q[j, 2] / r, q[j, 3] / r)
        if tt[j] == ti:
            out[i, 0], out[i, 1], out[i, 2], out[i, 3] = q0
            continue
        if done != j:
            r1 = norm[j + 1]
            q1 = (q[j + 1, 0] / r1, q[j + 1, 1] / r1, q[j + 1, 2] / r1, q[j + 1, 3] / r1)
            rel = quat_mul((-q0[0], -q0[1], -q0[2], q0[3]), q1)
            px, py, pz = _log(rel[0], rel[1], rel[2], rel[3])
            done = j
        u = np.float64(ti - tt[j]) / np.float64(tt[j + 1] - tt[j])
        e = exp_quat(u * px, u * py, u * pz)
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = quat_mul(q0, e)


def integrated_rate(t_ns, w, at_ns, out):
    """The trapezoid integral of the rate ``w`` (N, C) over the stamps ``t_ns`` (N,
    increasing, ns) from the first sample to each of ``at_ns`` (non-decreasing), into ``out``
    (K, C): the running sum of ``(w_k + w_{k+1}) / 2 · (t_{k+1} - t_k)`` (times in s from the
    first stamp, each step added to the sum before it, in order), linear between samples as
    ``np.interp`` takes it (the first value before the first stamp, the last after the last;
    the same numbers for finite rates: between two infinite sums ``np.interp`` keeps inf where
    this gives NaN).
    One pass up to the last query."""
    n, c = w.shape
    t0 = t_ns[0]
    sums = np.zeros(c)  # the integral up to sample j
    nxt = np.zeros(c)  # ... and up to j + 1
    j = 0
    t_j = 0.0
    t_next = (t_ns[1] - t0) * 1e-9 if n > 1 else 0.0
    if n > 1:
        for k in range(c):
            nxt[k] = 0.5 * (w[1, k] + w[0, k]) * t_next
    for i in range(len(at_ns)):
        te = (at_ns[i] - t0) * 1e-9
        while j + 1 < n - 1 and te >= t_next:  # the step j .. j + 1 holding te
            j += 1
            t_j = t_next
            t_next = (t_ns[j + 1] - t0) * 1e-9
            for k in range(c):
                sums[k] = nxt[k]
                nxt[k] = nxt[k] + 0.5 * (w[j + 1, k] + w[j, k]) * (t_next - t_j)
        for k in range(c):
            if te <= t_j:  # at the sample (or before the first)
                out[i, k] = sums[k]
            elif te >= t_next:  # at the next (or after the last)
                out[i, k] = nxt[k]
            else:
                slope = (nxt[k] - sums[k]) / (t_next - t_j)
                out[i, k] = slope * (te - t_j) + sums[k]


def window_norms(x, m, norm, max_var):
    """The norm of the mean and the largest column's variance of every window of ``m`` rows of
    ``x`` (N, k) into ``norm`` and ``max_var`` (N - m + 1,).

    The same arithmetic as :func:`imu_dcm.gyro.windows.windowed_mean_var` in numpy: running
    sums of the rows and of their squares from the first row, each row added to the sum
    before it; a window's mean ``(S[i + m] - S[i]) / m`` and variance ``(Q[i + m] - Q[i]) / m
    - mean²``, at least 0; NaN taken through as ``np.maximum`` takes it. The sums of the last
    ``m + 1`` rows are kept in a ring, so a window needs no array of the whole log's sums.
    """
    n, k = x.shape
    s, q = np.zeros(k), np.zeros(k)  # the running sums before row j
    ring_s, ring_q = np.zeros((m + 1, k)), np.zeros((m + 1, k))  # ... of the last m + 1 rows
    for j in range(n + 1):
        slot = j % (m + 1)
        for c in range(k):
            ring_s[slot, c], ring_q[slot, c] = s[c], q[c]
        i = j - m  # the window of rows i .. j - 1 is complete
        if i >= 0:
            first = i % (m + 1)
            acc, top = 0.0, 0.0
            for c in range(k):
                mean = (s[c] - ring_s[first, c]) / m
                var = (q[c] - ring_q[first, c]) / m
                var -= mean * mean
                if var < 0.0:
                    var = 0.0
                acc += mean * mean
                if top == top and (c == 0 or var > top or var != var):  # a NaN stays
                    top = var
            norm[i], max_var[i] = math.sqrt(acc), top
        if j < n:
            for c in range(k):
                v = x[j, c]
                s[c] += v
                q[c] += v * v


def min_steps(x, out):
    """The smallest positive step ``|x[j + 1] - x[j]|`` of each column of ``x`` into ``out``
    (inf where none; a NaN step is none)."""
    n, k = x.shape
    for c in range(k):
        out[c] = math.inf
    for j in range(n - 1):
        for c in range(k):
            d = abs(x[j + 1, c] - x[j, c])
            if d > 0.0 and d < out[c]:
                out[c] = d


@inline
def _rows_product(p, q, k: int, conj_p: bool) -> tuple:
    """Whether rows ``p[k]`` and ``q[k]`` both have a finite non-zero norm, and their Hamilton
    product with one of them conjugated: ``p[k]* ⊗ q[k]`` with ``conj_p``, else
    ``p[k] ⊗ q[k]*``."""
    px, py, pz, pw = p[k, 0], p[k, 1], p[k, 2], p[k, 3]
    qx, qy, qz, qw = q[k, 0], q[k, 1], q[k, 2], q[k, 3]
    np_ = math.sqrt(px * px + py * py + pz * pz + pw * pw)
    nq = math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
    ok = 0.0 < np_ < math.inf and 0.0 < nq < math.inf
    if conj_p:
        return ok, quat_mul((-px, -py, -pz, pw), (qx, qy, qz, qw))
    return ok, quat_mul((px, py, pz, pw), (-qx, -qy, -qz, qw))


def attitude_errors(q_est, q_true, out):
    """The total, inclination and heading error of each row of ``q_est`` against ``q_true``
    (n, 4) ``[x, y, z, w]``, deg, into the rows of ``out`` (3, n); returns the first row where
    either quaternion has a zero or non-finite norm (-1: none), that row and those after it
    left unwritten.

    The formulas of :func:`imu_dcm.metrics.attitude_error_deg`, row by row: the components of
    ``q_est ⊗ q_true*`` (the Hamilton product of the conjugate, summed in the same order),
    taken by magnitude; the total ``2 atan2(|v|, w)``, the heading ``2 atan2(z, w)`` and the
    inclination ``2 atan2(|(x, y)|, |(w, z)|)``, ratios of components, so that the norms are
    only checked.
    """
    to_deg = 180.0 / math.pi
    for k in range(q_est.shape[0]):
        ok, (x, y, z, w) = _rows_product(q_est, q_true, k, False)
        if not ok:
            return np.int64(k)
        x, y, z, w = abs(x), abs(y), abs(z), abs(w)
        out[0, k] = 2.0 * math.atan2(math.sqrt(x * x + y * y + z * z), w) * to_deg
        out[1, k] = 2.0 * math.atan2(math.sqrt(x * x + y * y), math.sqrt(w * w + z * z)) * to_deg
        out[2, k] = 2.0 * math.atan2(z, w) * to_deg
    return np.int64(-1)


def error_vectors(q_est, q_true, angle, out):
    """The world and body error vectors of each row of ``q_est`` against ``q_true`` (n, 4)
    ``[x, y, z, w]``, rad, whose angles ``angle`` (n,) rad are known, into the rows of ``out``
    (6, n): rows 0-2 ``e_w``, the rotation vector of ``q_est ⊗ q_true*``, rows 3-5 ``e_b``, of
    ``q_true* ⊗ q_est``.

    The formulas of :func:`imu_dcm.metrics.error_vector_planes`, row by row: the two products
    share their scalar part and differ in the sign of ``v_est × v_true``; each vector part is
    scaled by ``angle / |v|`` (``2 / |w|`` where ``|v|`` is 0), signed by ``w``.
    """
    for k in range(q_est.shape[0]):
        ex, ey, ez, ew = q_est[k, 0], q_est[k, 1], q_est[k, 2], q_est[k, 3]
        tx, ty, tz, tw = q_true[k, 0], q_true[k, 1], q_true[k, 2], q_true[k, 3]
        lx, ly, lz = tw * ex - ew * tx, tw * ey - ew * ty, tw * ez - ew * tz
        cx, cy, cz = ey * tz - ez * ty, ez * tx - ex * tz, ex * ty - ey * tx
        wx, wy, wz = lx - cx, ly - cy, lz - cz
        w = ex * tx + ey * ty + ez * tz + ew * tw
        s = math.sqrt(wx * wx + wy * wy + wz * wz)
        scale = angle[k] / s if s > 0.0 else 2.0 / abs(w)
        scale = math.copysign(scale, w)
        out[0, k], out[1, k], out[2, k] = wx * scale, wy * scale, wz * scale
        out[3, k], out[4, k], out[5, k] = (lx + cx) * scale, (ly + cy) * scale, (lz + cz) * scale


def second_steps(q, ok, step_ok, out):
    """``|d_{k+1} - d_k|`` per axis, ``d_k`` the rotation of step ``k`` of ``q`` (n, 4), for
    each pair of consecutive usable steps, written in order into the columns of ``out``
    (3, >= n - 2); returns how many. Step ``k`` is usable where ``ok[k]``, ``ok[k + 1]`` and
    ``step_ok[k]`` (n - 1,) hold. Each step's rotation is taken once, as :func:`step_rotvecs`
    takes it (NaN where its product has a zero or non-finite norm)."""
    n = q.shape[0]
    filled = 0
    have = False  # whether (px, py, pz) holds step k - 1, usable
    px = py = pz = 0.0
    for k in range(n - 1):
        if not (ok[k] and ok[k + 1] and step_ok[k]):
            have = False
            continue
        x, y, z = _step(q, k)
        if have:
            out[0, filled] = abs(x - px)
            out[1, filled] = abs(y - py)
            out[2, filled] = abs(z - pz)
            filled += 1
        px, py, pz, have = x, y, z, True
    return np.int64(filled)


def rate_ratios(w, t, q, ok, moving, out):
    """The ratio of the gyro's rate to the truth's over each step where the truth moves, in
    order into ``out`` (>= n - 1); returns how many.

    Step ``k`` of ``q`` (n, 4), the truth at the gyro's stamps ``t`` (n,) s, counts where
    ``ok[k]`` and ``ok[k + 1]`` hold and the truth's rate ``|log(q_k⁻¹ q_{k+1})| / (t_{k+1} -
    t_k)`` is above ``moving`` rad/s; its ratio is ``|(w_k + w_{k+1}) / 2|`` over that rate."""
    filled = 0
    for k in range(q.shape[0] - 1):
        if not (ok[k] and ok[k + 1]):
            continue
        x, y, z = _step(q, k)
        rate = math.sqrt(x * x + y * y + z * z) / (t[k + 1] - t[k])
        if not rate > moving:
            continue
        gx = 0.5 * (w[k, 0] + w[k + 1, 0])
        gy = 0.5 * (w[k, 1] + w[k + 1, 1])
        gz = 0.5 * (w[k, 2] + w[k + 1, 2])
        out[filled] = math.sqrt(gx * gx + gy * gy + gz * gz) / rate
        filled += 1
    return np.int64(filled)


def row_norms(x, out):
    """The Euclidean norm of each row of ``x`` (n, k), any strides, into ``out`` (n,).

    The squares of the even and of the odd columns are summed apart, then added (for three
    columns ``(x0² + x2²) + x1²``, for four ``(x0² + x2²) + (x1² + x3²)``): the order of
    numpy's ``einsum`` over a short last axis, which :func:`imu_dcm.arrays.row_norm` uses."""
    k = x.shape[1]
    for i in range(x.shape[0]):
        even = 0.0
        odd = 0.0
        for j in range(0, k - 1, 2):
            even += x[i, j] * x[i, j]
            odd += x[i, j + 1] * x[i, j + 1]
        if k % 2:
            even += x[i, k - 1] * x[i, k - 1]
        out[i] = math.sqrt(even + odd)


def quat_angles(q_a, q_b, out):
    """The angle, rad in ``[0, π]``, of ``q_a* ⊗ q_b`` for each row of ``q_a`` and ``q_b``
    (n, 4) ``[x, y, z, w]``, into ``out`` (n,); returns the first row where either quaternion
    has a zero or non-finite norm (-1: none), that row and those after it left unwritten.

    The formula of :func:`imu_dcm.so3.quat_angle_rad`, row by row: ``2 atan2(|v|, |w|)`` of the
    Hamilton product of the conjugate (summed in the same order), a ratio of components."""
    for k in range(q_a.shape[0]):
        ok, (x, y, z, w) = _rows_product(q_a, q_b, k, True)
        if not ok:
            return np.int64(k)
        out[k] = 2.0 * math.atan2(math.sqrt(x * x + y * y + z * z), abs(w))
    return np.int64(-1)


def window_rates(q, t, ok, m, out):
    """``|omega_T|`` of every window of ``m >= 2`` rows of the attitudes ``q`` (n, 4) at ``t``
    (n,) s, rad/s, into ``out`` (n - m + 1,): the norm of the mean of the steps' rates
    ``log(q_k⁻¹ q_{k+1}) / (t_{k+1} - t_k)`` over its ``m - 1`` steps, NaN where one of them
    is not between two ``ok`` rows.

    The window's sum is the difference of the running sums of the steps' rates (each step added
    to the sum before it, in order; a step not between two ``ok`` rows adds 0), as
    :func:`imu_dcm.gyro.rest_evidence.truth_rates` took it, the running sums of the last ``m``
    steps held in a ring."""
    n = q.shape[0]
    ring = np.zeros((m, 3))
    count = np.zeros(m, np.int64)
    sx = sy = sz = 0.0
    c = 0
    for j in range(1, n):  # the running sum after step j - 1
        i = j - 1
        if ok[i] and ok[i + 1]:
            x, y, z = _step(q, i)
            dt = t[i + 1] - t[i]
            sx += x / dt
            sy += y / dt
            sz += z / dt
            c += 1
        r = j % m
        ring[r, 0], ring[r, 1], ring[r, 2], count[r] = sx, sy, sz, c
        a = j - (m - 1)
        if a >= 0:  # window a: the steps a .. j - 1
            s0 = a % m
            dx, dy, dz = sx - ring[s0, 0], sy - ring[s0, 1], sz - ring[s0, 2]
            if c - count[s0] < m - 1:
                out[a] = np.nan
            else:
                out[a] = math.sqrt((dx * dx + dz * dz) + dy * dy) / (m - 1)


#: ``name -> (function, signature)`` of this kernel's entry points.
ENTRIES = {
    "step_rotvecs": (step_rotvecs, SIGNATURE),
    "slerp_rows": (slerp_rows, SLERP_SIGNATURE),
    "integrated_rate": (integrated_rate, INTEGRAL_SIGNATURE),
    "window_norms": (window_norms, WINDOW_SIGNATURE),
    "min_steps": (min_steps, STEPS_SIGNATURE),
    "attitude_errors": (attitude_errors, ERROR_SIGNATURE),
    "quat_angles": (quat_angles, ANGLE_SIGNATURE),
    "error_vectors": (error_vectors, VECTOR_SIGNATURE),
    "second_steps": (second_steps, SECOND_SIGNATURE),
    "rate_ratios": (rate_ratios, RATIO_SIGNATURE),
    "row_norms": (row_norms, NORM_SIGNATURE),
    "window_rates": (window_rates, WINDOW_RATE_SIGNATURE),
}

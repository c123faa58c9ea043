"""The integrator kernel, written for numba: the DCM recursion ``q_{i+1} = q_i ⊗ exp(φ_i)`` as
one loop, the per-sample push, the end step, the input check and the delta-angle rules, and
their entry points (:data:`ENTRIES`).

This module is imported only to compile: by :mod:`imu_dcm._kernels.build` (ahead of time, at
install) and by :mod:`imu_dcm._kernels.loader` when no up-to-date module built ahead of time is
present (then each entry point is compiled by numba on first use, or loaded from numba's cache:
:mod:`imu_dcm._kernels.jit`). Both compile these same functions, so the two give the same bits.

Conventions: quaternions Hamilton ``[x, y, z, w]``, ``q_w_b`` body to world; rates ``ω`` rad/s
in body axes; stamps ``t`` s; increments multiply on the right. The formulas (increments, the
exponential, the product) are written out here, inline, on purpose: :mod:`imu_dcm.so3` holds the
vectorised versions of the same maths. The state array's fields are
:mod:`imu_dcm._kernels.state`'s.

Every sample goes through :func:`_push` (or the loop of :func:`_feed_for`, the same over an
array), which keeps what carries across samples in the state array and commits each step as soon
as its stencil is complete. Batch is "feed every sample, then close"; streaming feeds them as
they come, so the two are the same arithmetic.

Each entry point has one signature (float64 C-contiguous arrays, int64 codes:
:mod:`imu_dcm._kernels.calls` converts and checks at the Python boundary). The small helpers are
inlined into them or compiled once each.
"""

from __future__ import annotations

import math

from imu_dcm._kernels.jit import inline, njit
from imu_dcm._kernels.state import (
    CLOSED,
    IS_CLOSED,
    MAGNUS4,
    MAYBE_GAP,
    NOT_FINITE,
    NOT_INCREASING,
    OK,
    PHI_SUM,
    Q0,
    ROWS,
    N,
    Q,
    T,
    W,
    feed_entry,
    push_entry,
)
from imu_dcm.integrator.methods import GAP_FACTOR, DeltaMethod, Method
from imu_dcm.so3 import COS_HALF_SERIES, SERIES_THETA2, SINC_HALF_SERIES

__all__ = ["ENTRIES", "exp_quat", "quat_mul", "step"]

S0, S1, S2, S3, S4, S5, S6 = SINC_HALF_SERIES
C0, C1, C2, C3, C4, C5, C6 = COS_HALF_SERIES


# -- the maths of one step ---------------------------------------------------------------------


@njit
def exp_quat(px: float, py: float, pz: float) -> tuple:
    """``exp(φ) = [φ sin(θ/2)/θ, cos(θ/2)]``, ``θ = |φ|``: exact, with the series policy of
    :func:`imu_dcm.so3.exp_quat` (seven series terms up to 0.5 rad,
    ``sin``/``cos`` above)."""
    t2 = px * px + py * py + pz * pz
    if t2 <= SERIES_THETA2:
        s = S0 + t2 * (S1 + t2 * (S2 + t2 * (S3 + t2 * (S4 + t2 * (S5 + t2 * S6)))))
        c = C0 + t2 * (C1 + t2 * (C2 + t2 * (C3 + t2 * (C4 + t2 * (C5 + t2 * C6)))))
    else:
        theta = math.sqrt(t2)
        s = math.sin(0.5 * theta) / theta
        c = math.cos(0.5 * theta)
    return px * s, py * s, pz * s, c


@njit
def quat_mul(p: tuple, q: tuple) -> tuple:
    """Hamilton product ``p ⊗ q`` of ``[x, y, z, w]`` tuples."""
    px, py, pz, pw = p
    qx, qy, qz, qw = q
    return (
        pw * qx + px * qw + py * qz - pz * qy,
        pw * qy - px * qz + py * qw + pz * qx,
        pw * qz + px * qy - py * qx + pz * qw,
        pw * qw - px * qx - py * qy - pz * qz,
    )


@njit
def step(q: tuple, px: float, py: float, pz: float) -> tuple:
    """``q ⊗ exp(φ)``, pulled back to unit norm to first order.

    Each product moves ``|q|`` by a rounding error; ``q (3 - |q|²) / 2`` removes it (exact to
    second order in the error), so ``R(q)`` stays orthonormal however many steps follow.
    """
    x, y, z, w = quat_mul(q, exp_quat(px, py, pz))
    k = 1.5 - 0.5 * (x * x + y * y + z * z + w * w)
    return x * k, y * k, z * k, w * k


@njit
def increment(
    method: int, wm: tuple, w0: tuple, w1: tuple, w2: tuple, h_m: float, h_0: float, h_p: float
) -> tuple:
    """Rotation vector ``φ_i`` (rad, body) of step ``[t_i, t_{i+1}]`` of length ``h_0``.

    ``wm, w0, w1, w2`` are ``ω_{i-1}, ω_i, ω_{i+1}, ω_{i+2}``; ``h_m, h_p`` the steps before and
    after (only ``magnus4`` reads ``wm``, ``w2``, ``h_m``, ``h_p``).
    """
    x0, y0, z0 = w0
    x1, y1, z1 = w1
    if method == Method.MAGNUS4:
        # Simpson on the cubic through ω_{i-1..i+2} at their stamps, as weights on the samples:
        # φ = -c_m ω_{i-1} + c_0 ω_i + c_1 ω_{i+1} - c_2 ω_{i+2} + h²/12 ω_i × ω_{i+1};
        # uniform steps give (-1, 13, 13, -1) h/24.
        xm, ym, zm = wm
        x2, y2, z2 = w2
        u = 0.5 * h_0
        a_m = u + h_m
        a_p = u + h_p
        s_m0 = h_m + h_0
        s_0p = h_0 + h_p
        s_all = s_m0 + h_p
        h6 = h_0 * (1.0 / 6.0)
        g = h_0 * h_0 * h6
        p = h_0 * a_m * a_p * (1.0 / 3.0)
        # c_m = g a_p / (h_m s_m0 s_all), c_2 = g a_m / (h_p s_0p s_all),
        # c_0 = h6 + p / (h_m s_0p), c_1 = h6 + p / (h_p s_m0): over one common denominator
        # (one division per step instead of four).
        r = 1.0 / (h_m * h_p * s_m0 * s_0p * s_all)
        c_m = g * a_p * h_p * s_0p * r
        c_2 = g * a_m * h_m * s_m0 * r
        c_0 = h6 + p * h_p * s_m0 * s_all * r
        c_1 = h6 + p * h_m * s_0p * s_all * r
        k = h_0 * h_0 * (1.0 / 12.0)
        return (
            c_0 * x0 + c_1 * x1 - c_m * xm - c_2 * x2 + k * (y0 * z1 - z0 * y1),
            c_0 * y0 + c_1 * y1 - c_m * ym - c_2 * y2 + k * (z0 * x1 - x0 * z1),
            c_0 * z0 + c_1 * z1 - c_m * zm - c_2 * z2 + k * (x0 * y1 - y0 * x1),
        )
    if method == Method.TRAPEZOID:
        u = 0.5 * h_0
        return u * (x0 + x1), u * (y0 + y1), u * (z0 + z1)
    if method == Method.CONING:
        u = 0.5 * h_0
        k = h_0 * h_0 * (1.0 / 12.0)
        return (
            u * (x0 + x1) + k * (y0 * z1 - z0 * y1),
            u * (y0 + y1) + k * (z0 * x1 - x0 * z1),
            u * (z0 + z1) + k * (x0 * y1 - y0 * x1),
        )
    if method == Method.START:
        return h_0 * x0, h_0 * y0, h_0 * z0
    return h_0 * x1, h_0 * y1, h_0 * z1  # Method.END


@njit
def newest_step(
    method: int, a: tuple, b: tuple, c: tuple, d: tuple, ta: float, tb: float, tc: float, td: float
) -> tuple:
    """``φ`` of the step that the newest of four samples ``(ω_a, t_a) .. (ω_d, t_d)`` completes:
    ``[t_b, t_c]`` for ``magnus4`` (one sample of look-ahead), ``[t_c, t_d]`` for the others."""
    if method == Method.MAGNUS4:
        return increment(MAGNUS4, a, b, c, d, tb - ta, tc - tb, td - tc)
    h = td - tc
    return increment(method, c, c, d, d, h, h, h)


# -- the state -----------------------------------------------------------------------------------


@inline
def _rate(state, r: int) -> tuple:
    """Buffered rate ``r`` (0 = oldest of the last four)."""
    i = W + 3 * r
    return state[i], state[i + 1], state[i + 2]


@njit
def _ghost(state, m: int, t: float) -> tuple:
    """Rate at stamp ``t`` on the polynomial through the newest ``m`` buffered samples
    (Lagrange form; ``m`` = 2, 3 or 4: a line, a parabola, a cubic)."""
    x = y = z = 0.0
    for j in range(4 - m, 4):
        lj = 1.0
        for i in range(4 - m, 4):
            if i != j:
                lj *= (t - state[T + i]) / (state[T + j] - state[T + i])
        x += lj * state[W + 3 * j]
        y += lj * state[W + 3 * j + 1]
        z += lj * state[W + 3 * j + 2]
    return x, y, z


@inline
def _commit(state, phi: tuple, out, k: int, emit_phi: bool) -> int:
    """Apply one step to the state's attitude and write row ``k`` of ``out`` (the new attitude,
    or ``φ`` when ``emit_phi``); return ``k + 1``."""
    q = (state[Q], state[Q + 1], state[Q + 2], state[Q + 3])
    if emit_phi:
        out[k, 0], out[k, 1], out[k, 2], out[k, 3] = phi[0], phi[1], phi[2], 0.0
    else:
        q = step(q, phi[0], phi[1], phi[2])
        out[k, 0], out[k, 1], out[k, 2], out[k, 3] = q
    state[Q], state[Q + 1], state[Q + 2], state[Q + 3] = q
    return k + 1


@inline
def _push(
    state, x: float, y: float, z: float, t: float, out, k: int, method: int, emit_phi: bool
) -> int:
    """Take sample ``(ω, t)`` into the state and commit every step it completes (rows of
    ``out`` from ``k``); return the next free row. Inputs are already checked; ``method`` is
    the state's."""
    for i in range(W, W + 9):  # shift the window: the oldest sample leaves
        state[i] = state[i + 3]
    state[T], state[T + 1], state[T + 2] = state[T + 1], state[T + 2], state[T + 3]
    state[W + 9], state[W + 10], state[W + 11], state[T + 3] = x, y, z, t
    n = state[N] + 1.0
    state[N] = n
    if n < 2.0:
        return k
    a, b, c, d = _rate(state, 0), _rate(state, 1), _rate(state, 2), _rate(state, 3)
    ta, tb, tc, td = state[T], state[T + 1], state[T + 2], state[T + 3]
    if method == Method.ROTVEC_SUM:  # q = q_0 ⊗ exp(Σ h_j ω_j): adds rotation vectors
        h = td - tc
        sx = state[PHI_SUM] + h * c[0]
        sy = state[PHI_SUM + 1] + h * c[1]
        sz = state[PHI_SUM + 2] + h * c[2]
        state[PHI_SUM], state[PHI_SUM + 1], state[PHI_SUM + 2] = sx, sy, sz
        q = quat_mul((state[Q0], state[Q0 + 1], state[Q0 + 2], state[Q0 + 3]), exp_quat(sx, sy, sz))
        out[k, 0], out[k, 1], out[k, 2], out[k, 3] = q
        state[Q], state[Q + 1], state[Q + 2], state[Q + 3] = q
        return k + 1
    if method == Method.MAGNUS4:
        if n < 4.0:  # step [t_b, t_c] needs ω_a..ω_d: it is committed one sample late
            return k
        if n == 4.0:  # the first step, with a ghost sample before the record
            h = tb - ta
            ghost = _ghost(state, int(n), ta - h)  # n (= 4) a variable: one compiled _ghost
            k = _commit(state, increment(MAGNUS4, ghost, a, b, c, h, h, tc - tb), out, k, emit_phi)
    return _commit(state, newest_step(method, a, b, c, d, ta, tb, tc, td), out, k, emit_phi)


FEED_SIGNATURE = "int64(float64[::1], float64[:, ::1], float64[::1], float64[:, ::1])"


def _feed_for(method: int, emit_phi: bool):
    """:func:`feed` for one method, with the method a constant so that the compiler keeps only
    its branch (measured: a quarter less time per sample than one loop that tests the method
    at every step), and only the methods a process uses are compiled. The first samples (and
    every ``rotvec_sum`` sample) go through :func:`_push`; once four samples are in,
    :func:`_recursion` runs."""

    def feed_method(state, omega, t, out):
        j = 0
        k = 0
        while j < len(t) and (state[N] < 4.0 or method == Method.ROTVEC_SUM):
            k = _push(state, omega[j, 0], omega[j, 1], omega[j, 2], t[j], out, k, method, emit_phi)
            j += 1
        if j == len(t):
            return k
        return _recursion(state, omega, t, out, j, k, method, emit_phi)

    return feed_method


@inline
def _recursion(state, omega, t, out, j: int, k: int, method: int, emit_phi: bool) -> int:
    """Samples ``j..`` once the window is full: the DCM recursion ``q <- q ⊗ exp(φ)``, one step
    per sample, with the window of four samples in local variables."""
    q = (state[Q], state[Q + 1], state[Q + 2], state[Q + 3])
    a, b, c, d = _rate(state, 0), _rate(state, 1), _rate(state, 2), _rate(state, 3)
    ta, tb, tc, td = state[T], state[T + 1], state[T + 2], state[T + 3]
    state[N] += len(t) - j
    for i in range(j, len(t)):
        a, b, c, d = b, c, d, (omega[i, 0], omega[i, 1], omega[i, 2])
        ta, tb, tc, td = tb, tc, td, t[i]
        phi = newest_step(method, a, b, c, d, ta, tb, tc, td)
        if emit_phi:
            out[k, 0], out[k, 1], out[k, 2], out[k, 3] = phi[0], phi[1], phi[2], 0.0
        else:
            q = step(q, phi[0], phi[1], phi[2])
            out[k, 0], out[k, 1], out[k, 2], out[k, 3] = q
        k += 1
    state[Q], state[Q + 1], state[Q + 2], state[Q + 3] = q
    for r, w in enumerate((a, b, c, d)):
        state[W + 3 * r], state[W + 3 * r + 1], state[W + 3 * r + 2] = w
    state[T], state[T + 1], state[T + 2], state[T + 3] = ta, tb, tc, td
    return k


PUSH_SIGNATURE = "int64(float64[::1], float64[::1], float64)"


def _push_for(method: int):
    """Check one sample, then :func:`_push` it; ``method`` a constant (as in :func:`_feed_for`).

    The compiled function returns ``IS_CLOSED``, ``NOT_FINITE`` or ``NOT_INCREASING`` (state
    unchanged); ``MAYBE_GAP`` when the step exceeds ``GAP_FACTOR`` times the shortest of the
    last three (the caller then applies the gap rule to the buffered stamps); else ``OK``.
    """

    def push_method(state, omega, t):
        if state[CLOSED]:
            return IS_CLOSED
        if len(omega) != 3:
            return NOT_FINITE
        x, y, z = omega[0], omega[1], omega[2]
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z) and math.isfinite(t)):
            return NOT_FINITE
        n = state[N]
        gap = False
        if n >= 1.0:
            h = t - state[T + 3]
            if not h > 0.0:
                return NOT_INCREASING
            if n >= 2.0:
                shortest = state[T + 3] - state[T + 2]
                for r in range(max(1, 4 - int(n)), 3):
                    shortest = min(shortest, state[T + r + 1] - state[T + r])
                gap = h > GAP_FACTOR * shortest
        _push(state, x, y, z, t, state[ROWS : ROWS + 8].reshape((2, 4)), 0, method, False)
        if gap:
            return MAYBE_GAP
        return OK

    return push_method


CLOSE_SIGNATURE = "int64(float64[::1], boolean)"


def _close_magnus4(state, emit_phi: bool) -> int:
    """:func:`close` for ``magnus4`` with at least two samples: the last step, with a ghost
    sample after the record; with two or three samples the first step is still open too, with
    a ghost before the record (with two, that is the same step)."""
    out = state[ROWS : ROWS + 8].reshape((2, 4))
    n = int(state[N])
    tb, tc, td = state[T + 1], state[T + 2], state[T + 3]
    h_end = td - tc
    ghost_end = _ghost(state, min(n, 4), td + h_end)
    b, c, d = _rate(state, 1), _rate(state, 2), _rate(state, 3)
    h_b = h_end if n == 2 else tc - tb
    k = 0
    if n < 4:
        ghost_start = _ghost(state, n, (tc if n == 2 else tb) - h_b)
        if n == 2:
            b = ghost_start
        else:
            phi = increment(MAGNUS4, ghost_start, b, c, d, h_b, h_b, h_end)
            k = _commit(state, phi, out, 0, emit_phi)
    phi = increment(MAGNUS4, b, c, d, ghost_end, h_b, h_end, h_end)
    return _commit(state, phi, out, k, emit_phi)


# -- input checks ------------------------------------------------------------------------------


CHECK_SIGNATURE = (
    "Tuple((int64, int64, int64, float64, float64))(float64[:, ::1], float64[::1], float64)"
)


def check_record(values, t, t_before: float) -> tuple:
    """One pass over a record of samples ``values`` (n, 3) and stamps ``t``.

    Returns ``(row, stamp, order, dt_min, dt_max)``: the first row of ``values`` with a
    non-finite number, the first non-finite stamp, the first index ``i`` with ``t[i]`` not after
    the stamp before it (``t_before`` for ``i = 0``; ``-inf``: none), each ``-1`` when there is
    none; and the shortest and longest step (s, the one after ``t_before`` included).
    """
    row = -1
    for i in range(values.shape[0]):
        if not (
            math.isfinite(values[i, 0])
            and math.isfinite(values[i, 1])
            and math.isfinite(values[i, 2])
        ):
            row = i
            break
    stamp = -1
    order = -1
    dt_min = math.inf
    dt_max = -math.inf
    prev = t_before
    for i in range(len(t)):
        if not math.isfinite(t[i]):
            stamp = i
            break
        h = t[i] - prev
        if not h > 0.0 and order < 0:
            order = i
        if prev != -math.inf:
            dt_min = min(dt_min, h)
            dt_max = max(dt_max, h)
        prev = t[i]
    return row, stamp, order, dt_min, dt_max


# -- delta angles --------------------------------------------------------------------------------


@inline
def delta_rotvec(method: int, d1: tuple, d2: tuple, d3: tuple, a: float, b: float) -> tuple:
    """Rotation vector of one attitude update from delta angles (rad, body).

    ``one_plus_previous``: ``d1 = Δθ_{k-1}``, ``d2 = Δθ_k``, intervals ``a``, ``b``:
    ``Δθ_k + b²/(6 a (a + b)) Δθ_{k-1} × Δθ_k`` (1/12 for ``a = b``). ``two_sample``:
    ``Δθ1 + Δθ2 + (a + b)²/(6 a b) Δθ1 × Δθ2`` (2/3 for ``a = b``). ``three_sample``:
    ``ΣΔθ + 9/20 Δθ1 × Δθ3 + 27/40 Δθ2 × (Δθ3 − Δθ1)``. ``plain``: ``d2``.
    """
    x1, y1, z1 = d1
    x2, y2, z2 = d2
    if method == DeltaMethod.PLAIN:
        return d2
    if method == DeltaMethod.ONE_PLUS_PREVIOUS or method == DeltaMethod.TWO_SAMPLE:
        if method == DeltaMethod.ONE_PLUS_PREVIOUS:
            k = b * b / (6.0 * a * (a + b))
            bx, by, bz = x2, y2, z2
        else:
            k = (a + b) * (a + b) / (6.0 * a * b)
            bx, by, bz = x1 + x2, y1 + y2, z1 + z2
        return (
            bx + k * (y1 * z2 - z1 * y2),
            by + k * (z1 * x2 - x1 * z2),
            bz + k * (x1 * y2 - y1 * x2),
        )
    x3, y3, z3 = d3  # DeltaMethod.THREE_SAMPLE
    ex, ey, ez = x3 - x1, y3 - y1, z3 - z1
    return (
        x1 + x2 + x3 + 0.45 * (y1 * z3 - z1 * y3) + 0.675 * (y2 * ez - z2 * ey),
        y1 + y2 + y3 + 0.45 * (z1 * x3 - x1 * z3) + 0.675 * (z2 * ex - x2 * ez),
        z1 + z2 + z3 + 0.45 * (x1 * y3 - y1 * x3) + 0.675 * (x2 * ey - y2 * ex),
    )


FEED_DELTA_SIGNATURE = "void(float64[::1], float64[:, ::1], float64[::1], int64, float64[:, ::1])"


def feed_delta(q0, dtheta, dt, method: int, out) -> None:
    """Attitudes from checked delta angles: ``out[0] = q0``, then one row per update
    (per interval, or per set of 2 or 3 intervals)."""
    q = (q0[0], q0[1], q0[2], q0[3])
    out[0, 0], out[0, 1], out[0, 2], out[0, 3] = q
    m = 2 if method == DeltaMethod.TWO_SAMPLE else 3 if method == DeltaMethod.THREE_SAMPLE else 1
    zero = (0.0, 0.0, 0.0)
    for u in range(len(dtheta) // m):
        k = u * m
        d = (dtheta[k, 0], dtheta[k, 1], dtheta[k, 2])
        if m == 1:
            prev = zero if k == 0 else (dtheta[k - 1, 0], dtheta[k - 1, 1], dtheta[k - 1, 2])
            a = dt[k - 1] if k > 0 else dt[k]
            phi = delta_rotvec(method, prev, d, zero, a, dt[k])
        else:
            d2 = (dtheta[k + 1, 0], dtheta[k + 1, 1], dtheta[k + 1, 2])
            d3 = zero if m == 2 else (dtheta[k + 2, 0], dtheta[k + 2, 1], dtheta[k + 2, 2])
            phi = delta_rotvec(method, d, d2, d3, dt[k], dt[k + 1])
        q = step(q, phi[0], phi[1], phi[2])
        out[u + 1, 0], out[u + 1, 1], out[u + 1, 2], out[u + 1, 3] = q


# -- the entry points ----------------------------------------------------------------------------


def _entries() -> dict[str, tuple[object, str]]:
    """Every entry point of the integrator: its name (:func:`imu_dcm._kernels.state.feed_entry`
    and :func:`~imu_dcm._kernels.state.push_entry` name the per-method ones), the function, and
    its one signature. The per-method loops have the method (and ``emit_phi``) as a constant, so
    the compiler keeps only its branch."""
    entries: dict[str, tuple[object, str]] = {}
    for method in Method:
        for emit_phi in (False, True):
            feed = _feed_for(int(method), emit_phi)
            entries[feed_entry(int(method), emit_phi)] = (feed, FEED_SIGNATURE)
        entries[push_entry(int(method))] = (_push_for(int(method)), PUSH_SIGNATURE)
    entries["close_magnus4"] = (_close_magnus4, CLOSE_SIGNATURE)
    entries["check_record"] = (check_record, CHECK_SIGNATURE)
    entries["feed_delta"] = (feed_delta, FEED_DELTA_SIGNATURE)
    return entries


#: ``name -> (function, signature)`` of every entry point of the integrator.
ENTRIES = _entries()

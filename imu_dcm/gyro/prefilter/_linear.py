"""The linear rate model per body axis and its two engines (fast numpy, filterpy reference).

State ``[ω, α]`` (or ``[ω, α, j]``), optionally a bias; each step discretised with its own
``dt`` (continuous white-noise model). The fast engine propagates the covariances once for all
three axes (they do not depend on the data) and fills stationary runs in blocks by one
first-order IIR filter per eigenmode; the filterpy engine runs ``filterpy.kalman.predict`` /
``update`` / ``rts_smoother`` per axis and is the reference the fast one is tested against.

A private module of the pre-filter: :mod:`imu_dcm.gyro.prefilter` is its public face.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import linalg

from imu_dcm.gyro.prefilter.config import (
    DT_REL_TOL,
    PRIOR_SCALE,
    STATIONARY_REL_TOL,
    PrefilterConfig,
)


def motion_order(model: str) -> int:
    return 2 if model == "rate-accel" else 3


def q_scale(model: str, accel_rad_s2: float) -> float:
    """White-noise density driving the highest derivative (see the module docstring)."""
    return accel_rad_s2**2 if model == "rate-accel" else 3.0 * accel_rad_s2**2


def transition_matrices(dt: NDArray, n_motion: int, bias: bool) -> NDArray:
    """State transition matrices ``F_k``, shape (len(dt), d, d)."""
    d = n_motion + int(bias)
    F = np.zeros((len(dt), d, d))
    F[:, np.arange(d), np.arange(d)] = 1.0
    F[:, 0, 1] = dt
    if n_motion == 3:
        F[:, 0, 2] = 0.5 * dt * dt
        F[:, 1, 2] = dt
    return F


def process_noise(dt: NDArray, n_motion: int, q: float, bias: bool, q_bias: float) -> NDArray:
    """Discretised continuous white-noise process covariance ``Q_k``, shape (len(dt), d, d).

    Equal, per step, to ``filterpy.common.Q_continuous_white_noise(n_motion, dt, q)`` (plus
    ``q_bias · dt`` for the bias); vectorised over steps.
    """
    d = n_motion + int(bias)
    Q = np.zeros((len(dt), d, d))
    # entry (i, j) of the n-state integrator chain driven at its last state:
    # q dt^(2n-1-i-j) / ((n-1-i)! (n-1-j)! (2n-1-i-j)), with i, j counted from the rate.
    for i in range(n_motion):
        for j in range(n_motion):
            a, b = n_motion - 1 - i, n_motion - 1 - j
            p = a + b + 1
            Q[:, i, j] = q * dt**p / (math.factorial(a) * math.factorial(b) * p)
    if bias:
        Q[:, -1, -1] = q_bias * dt
    return Q


def stationary_prior(dt: float, n_motion: int, q: float, r: float) -> NDArray:
    """Stationary prior covariance of the motion states (discrete algebraic Riccati equation)."""
    F = transition_matrices(np.array([dt]), n_motion, False)[0]
    Q = process_noise(np.array([dt]), n_motion, q, False, 0.0)[0]
    H = np.zeros((1, n_motion))
    H[0, 0] = 1.0
    P = linalg.solve_discrete_are(F.T, H.T, Q, np.array([[r]]))
    return 0.5 * (P + P.T)


@dataclass(frozen=True)
class FilterModel:
    F: NDArray  # (N, d, d); F[0] = I (the prior at sample 0 is given)
    Q: NDArray  # (N, d, d); Q[0] = 0
    r: NDArray  # (N,) measurement variance, rad²/s²
    rest: NDArray  # (N,) bool: zero-rate pseudo-measurement at this sample
    H: NDArray  # (2, d): row 0 measures z = ω (+ b), row 1 the zero-rate pseudo-measurement
    r_zero: float
    x0: NDArray  # (d, 3) prior mean at sample 0
    P0: NDArray  # (d, d) prior covariance at sample 0
    run_start: NDArray  # (N,) first sample of the run of equal (dt, rest) containing each sample


def build_model(
    z: NDArray, t_s: NDArray, cfg: PrefilterConfig, rest: NDArray | None, bias0: NDArray | None
) -> FilterModel:
    n = len(t_s)
    nm = motion_order(cfg.model)
    bias = cfg.estimate_bias
    d = nm + int(bias)
    dt = np.diff(t_s)
    dt_full = np.concatenate([[dt[0]], dt])
    q = q_scale(cfg.model, cfg.angular_accel_rad_s2)
    F = transition_matrices(dt_full, nm, bias)
    Q = process_noise(dt_full, nm, q, bias, cfg.bias_random_walk_rad_s_sqrt_s**2)
    F[0] = np.eye(d)
    Q[0] = 0.0
    r = cfg.noise_density_rad_s_sqrt_hz**2 / dt_full
    H = np.zeros((2, d))
    H[:, 0] = 1.0
    if bias:
        H[0, -1] = 1.0
    rest = np.zeros(n, bool) if (rest is None or not bias) else rest
    P0 = np.zeros((d, d))
    # nearly diffuse prior: 100x the spread of the first samples' finite differences (rate
    # sigma, two-point slope sqrt(2) sigma / dt, three-point curvature sqrt(6) sigma / dt^2)
    sig, h = math.sqrt(float(r[0])), float(dt_full[0])
    spread = [sig, math.sqrt(2.0) * sig / h, math.sqrt(6.0) * sig / h**2][:nm]
    P0[np.arange(nm), np.arange(nm)] = (PRIOR_SCALE * np.array(spread)) ** 2
    x0 = np.zeros((d, 3))
    x0[0] = z[0]
    if bias:
        P0[-1, -1] = cfg.bias_prior_std_rad_s**2
        if bias0 is not None:
            x0[-1] = bias0
            x0[0] = z[0] - bias0
    change = np.ones(n, bool)
    change[1:] = (np.abs(np.diff(dt_full)) > DT_REL_TOL * dt_full[:-1]) | (rest[1:] != rest[:-1])
    change[1] = True  # sample 0 has no prediction step, so sample 1 starts a run
    starts = np.flatnonzero(change)
    run_start = starts[np.searchsorted(starts, np.arange(n), side="right") - 1]
    return FilterModel(F, Q, r, rest, H, cfg.zero_rate_std_rad_s**2, x0, P0, run_start)


# ------------------------------------------------------------------------------------------------
# fast path: covariances once for all axes, stationary runs filled in blocks


def _close(a: NDArray, b: NDArray) -> bool:
    """Covariances equal to ``STATIONARY_REL_TOL``, entry by entry on the scale sqrt(P_ii P_jj)."""
    d = np.sqrt(np.abs(np.diag(a)))
    return bool(np.all(np.abs(a - b) <= STATIONARY_REL_TOL * np.outer(d, d)))


def _forward_covariances(m: FilterModel) -> tuple[NDArray, NDArray, NDArray, NDArray]:
    """Prior/posterior covariances, gains ``K`` (N, d, 2) and a 'same as previous' flag."""
    n, d = m.F.shape[0], m.F.shape[1]
    Pm = np.empty((n, d, d))
    Pp = np.empty((n, d, d))
    K = np.zeros((n, d, 2))
    same = np.zeros(n, bool)
    run_end = np.empty(n, int)
    starts = np.flatnonzero(np.diff(np.concatenate([[-1], m.run_start])) != 0)
    ends = np.concatenate([starts[1:] - 1, [n - 1]])
    run_end[:] = ends[np.searchsorted(starts, np.arange(n), side="right") - 1]
    eye = np.eye(d)
    h0 = m.H[0]
    k = 0
    while k < n:
        P = m.P0 if k == 0 else m.F[k] @ Pp[k - 1] @ m.F[k].T + m.Q[k]
        if m.rest[k]:
            R = np.diag([m.r[k], m.r_zero])
            Kk = P @ m.H.T @ np.linalg.inv(m.H @ P @ m.H.T + R)
            IKH = eye - Kk @ m.H
            Pk = IKH @ P @ IKH.T + Kk @ R @ Kk.T  # Joseph form, as filterpy.kalman.update
            K[k] = Kk
        else:
            # one scalar measurement: K = P h / (h P h + r), P+ = P - K (P h)^T (equal to the
            # Joseph form for this optimal gain; no matrix inverse)
            Ph = P @ h0
            Kk = Ph / (float(h0 @ Ph) + m.r[k])
            Pk = P - np.outer(Kk, Ph)
            K[k, :, 0] = Kk
        Pm[k], Pp[k] = P, 0.5 * (Pk + Pk.T)
        if k > 0 and m.run_start[k] == m.run_start[k - 1] and _close(Pm[k], Pm[k - 1]):
            e = run_end[k]
            Pm[k + 1 : e + 1], Pp[k + 1 : e + 1], K[k + 1 : e + 1] = Pm[k], Pp[k], K[k]
            same[k + 1 : e + 1] = True
            k = e + 1
        else:
            k += 1
    return Pm, Pp, K, same


def _smoother_covariances(
    m: FilterModel, Pm: NDArray, Pp: NDArray, same: NDArray
) -> tuple[NDArray, NDArray]:
    """RTS gains ``G_k`` (N-1, d, d) and smoothed covariances (N, d, d)."""
    n = Pm.shape[0]
    G = Pp[:-1] @ np.swapaxes(m.F[1:], 1, 2) @ np.linalg.inv(Pm[1:])
    Ps = np.empty_like(Pp)
    Ps[-1] = Pp[-1]
    # the backward map at k equals the one at k+1 when the forward quantities at k+1, k+2 repeat
    fixed = np.zeros(n, bool)
    fixed[: n - 2] = same[1 : n - 1] & same[2:n]
    d = np.diff(np.concatenate([[0], fixed.astype(np.int8)]))
    run_lo = np.maximum.accumulate(np.where(d == 1, np.arange(n), 0))
    k = n - 2
    while k >= 0:
        Ps[k] = Pp[k] + G[k] @ (Ps[k + 1] - Pm[k + 1]) @ G[k].T
        Ps[k] = 0.5 * (Ps[k] + Ps[k].T)
        if fixed[k] and k + 1 < n - 1 and fixed[k + 1] and _close(Ps[k], Ps[k + 1]):
            lo = run_lo[k]
            Ps[lo:k] = Ps[k]
            k = lo - 1
        else:
            k -= 1
    return G, Ps


def _modal_scan(A: NDArray, b: NDArray, x0: NDArray) -> NDArray | None:
    """``x_k = A x_{k-1} + b_k`` for a constant ``A`` by one first-order IIR per eigenmode.

    ``A = V Λ V⁻¹``; each mode ``ξ_k = λ ξ_{k-1} + (V⁻¹ b_k)`` runs in ``scipy.signal.lfilter``.
    Returns None when ``V`` is too ill-conditioned for that to be accurate.
    """
    from scipy import signal  # imported here: slow to import, needed only for long runs

    lam, V = np.linalg.eig(A)
    if np.linalg.cond(V) > 1e6:
        return None
    Vi = np.linalg.inv(V)
    u = Vi @ b  # (n, d, 3) complex
    xi0 = Vi @ x0
    xi = np.empty_like(u)
    for i, li in enumerate(lam):
        zi = (li * xi0[i])[None]
        xi[:, i, :] = signal.lfilter([1.0], [1.0, -li], u[:, i, :], axis=0, zi=zi)[0]
    return (V @ xi).real


def _affine_scan(A: NDArray, b: NDArray, x0: NDArray, same: NDArray | None = None) -> NDArray:
    """``x_k = A_k x_{k-1} + b_k`` for k = 0..N-1 from ``x_{-1} = x0``; shape (N, d, 3).

    ``same[k]`` marks ``A_k == A_{k-1}``: long runs of a constant ``A`` go through
    :func:`_modal_scan`, the rest through a per-sample loop.
    """
    n = len(b)
    out = np.empty_like(b)
    if same is None:
        same = np.zeros(n, bool)
    starts = np.flatnonzero(~same[:n] | (np.arange(n) == 0))
    ends = np.concatenate([starts[1:], [n]])
    x = x0
    for s, e in zip(starts, ends, strict=True):
        # the run's first sample may have its own A (start of the run of equal values)
        if e - s >= 256:
            out[s] = x = A[s] @ x + b[s]
            y = _modal_scan(A[s + 1], b[s + 1 : e], x)
            if y is not None:
                out[s + 1 : e] = y
                x = y[-1]
                continue
            s += 1
        for k in range(s, e):
            x = A[k] @ x + b[k]
            out[k] = x
    return out


def run_fast(z: NDArray, m: FilterModel, smooth: bool) -> tuple[NDArray, NDArray]:
    """Filtered (or smoothed) states (N, d, 3) and their covariances (N, d, d)."""
    d = m.F.shape[1]
    Pm, Pp, K, same = _forward_covariances(m)
    A = (np.eye(d) - K @ m.H) @ m.F
    b = K[:, :, :1] * z[:, None, :]  # the zero-rate pseudo-measurement is 0
    X = _affine_scan(A, b, m.x0, same)
    if not smooth:
        return X, Pp
    G, Ps = _smoother_covariances(m, Pm, Pp, same)
    # x_s[k] = G_k x_s[k+1] + (I - G_k F_{k+1}) x_f[k], run backwards from x_s[N-1] = x_f[N-1]
    c = (np.eye(d) - G @ m.F[1:]) @ X[:-1]
    # G_k == G_{k+1} when the forward quantities at k+1 and k+2 repeat
    g_same = np.zeros(len(G), bool)
    g_same[:-1] = same[1:-1] & same[2:]
    Xs = np.empty_like(X)
    Xs[-1] = X[-1]
    # reversed order: element j is k = N-2-j; "same as previous" there means G_k == G_{k+1}
    Xs[:-1] = _affine_scan(G[::-1], c[::-1], X[-1], g_same[::-1])[::-1]
    return Xs, Ps


def run_filterpy(z: NDArray, m: FilterModel, smooth: bool) -> tuple[NDArray, NDArray]:
    """Reference: filterpy's functional predict/update and rts_smoother, one axis at a time."""
    from filterpy.kalman import predict, rts_smoother, update

    n, d = m.F.shape[0], m.F.shape[1]
    X = np.empty((n, d, 3))
    Pout = np.empty((n, d, d))
    for axis in range(3):
        x, P = m.x0[:, axis].copy(), m.P0.copy()
        Xs_f = np.empty((n, d))
        Ps_f = np.empty((n, d, d))
        for k in range(n):
            if k > 0:
                x, P = predict(x, P, F=m.F[k], Q=m.Q[k])
            if m.rest[k]:
                x, P = update(x, P, np.array([z[k, axis], 0.0]), np.diag([m.r[k], m.r_zero]), m.H)
            else:
                x, P = update(x, P, z[k, axis], np.array([[m.r[k]]]), m.H[:1])
            Xs_f[k], Ps_f[k] = x, P
        if smooth:
            # filterpy's functional smoother takes Fs[k] as the transition from k to k+1
            Fs = np.concatenate([m.F[1:], m.F[-1:]])
            Qs = np.concatenate([m.Q[1:], m.Q[-1:]])
            Xs_f, Ps_f, _, _ = rts_smoother(Xs_f, Ps_f, Fs, Qs)
        X[:, :, axis] = Xs_f
        Pout = Ps_f
    return X, Pout

"""Kalman pre-filtering and Rauch-Tung-Striebel smoothing of gyro rates (filterpy as the oracle).

Each body axis of the measured rate ``z_k = ω(t_k) + v_k`` (``omega_b``: body rate relative to the
world, in body axes, rad/s; ``v_k`` white, variance ``R_k = N² / dt_k`` for a gyro noise density
``N`` in rad/s/√Hz) is tracked with a linear state-space model, the same for the three axes:

* ``model="rate-accel"``: state ``[ω, α]`` (rate, angular acceleration); ``α`` is a Wiener
  process driven by white jerk of power spectral density ``q = σ_α²`` (rad²/s⁵), where
  ``σ_α = angular_accel_rad_s2`` is the spread the angular acceleration gains in one second.
* ``model="rate-accel-jerk"``: state ``[ω, α, j]``; white snap of density ``q = 3 σ_α²``
  (rad²/s⁷), chosen so that ``α`` again spreads by ``σ_α`` in one second.
* ``estimate_bias=True`` appends a gyro bias ``b`` (random walk), measured as ``z = ω + b``; the
  bias is observable only at rest, where a zero-rate pseudo-measurement ``0 = ω`` is added.

Every step is discretised with its own ``dt_k = t_k − t_{k−1}`` (the continuous white-noise
model, ``filterpy.common.Q_continuous_white_noise``). ``mode="kalman"`` is the causal filter
(for live use); ``mode="rts"`` adds the backward RTS pass (no lag, for offline replay). The
covariances do not depend on the data, so they are propagated once for all three axes, and with
a uniform ``dt`` the recursion stops as soon as it is stationary (steady-state gains, applied
by one first-order IIR filter per eigenmode). The filter starts from a nearly diffuse prior
(100x what the first samples' finite differences tell), so a record that begins in motion
is not pulled towards zero acceleration. ``engine="filterpy"`` runs the same model through
``filterpy.kalman.predict`` / ``update`` / ``rts_smoother`` per axis: the reference the fast
path is tested against.

:class:`StreamingRateFilter` is the per-sample twin of ``mode="kalman"``, and
:func:`euler_prefilter` a model-based variant (Euler's equations with a known inertia, filterpy's
unscented filter).

Parameters not given are estimated: the noise density from the Allan deviation of a rest segment
(``imu_dcm.allan``; its angle random walk and bias instability are reported), and ``σ_α`` by
maximum likelihood of the stationary filter's innovations.

Which to use (``python -m benchmarks.noise_study``; README "Noise"): smoothing cuts the *rate*
error when the noise lies above the motion's band, but no unity-gain low-pass removes the
attitude random walk, and the causal filter's lag makes the attitude worse; integrate the
unfiltered rates for attitude.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import linalg

from imu_dcm.allan import allan_deviation, noise_density_from_allan
from imu_dcm.errors import InputError
from imu_dcm.integrate import check_samples
from imu_dcm.replay.bias import RestConfig, detect_rest

__all__ = [
    "MODELS",
    "MODES",
    "NoiseEstimate",
    "PrefilterConfig",
    "PrefilterResult",
    "StreamingRateFilter",
    "estimate_noise_from_rest",
    "euler_prefilter",
    "prefilter",
]

MODES = ("kalman", "rts")
MODELS = ("rate-accel", "rate-accel-jerk")

# Fewest rest samples accepted for an Allan-deviation noise estimate: with n samples the
# estimate at one-sample clusters has a relative spread of about 1/sqrt(n) (7 % at 200).
_MIN_REST_SAMPLES = 200
# Steps whose dt differs by less than this (relative) share one discretisation.
_DT_REL_TOL = 1e-9
# A covariance that moves by less than this (relative) in one step is stationary (the backward
# smoother recursion settles at a round-off floor of about 1e-13).
_STATIONARY_REL_TOL = 1e-11
# Width of the initial prior, in units of what the first samples' finite differences tell.
_PRIOR_SCALE = 100.0
# Search range of the angular-acceleration scale for the likelihood fit, rad/s².
_ACCEL_SEARCH_RAD_S2 = (1e-4, 1e6)
# Bias allan-deviation minimum to bias instability (IEEE Std 952: flicker floor 0.664 B).
_FLICKER_FACTOR = 0.664


@dataclass(frozen=True)
class PrefilterConfig:
    """Settings of the rate pre-filter; ``None`` means "estimate it from the log".

    Attributes
    ----------
    noise_density_rad_s_sqrt_hz : float or None
        Gyro white-noise density (angle random walk), rad/s/√Hz, the same on all axes; per-sample
        standard deviation ``N √(1/dt)``. None: estimated from a rest segment (Allan deviation).
    angular_accel_rad_s2 : float or None
        Process-noise scale ``σ_α``, rad/s²: how far the angular acceleration may wander in one
        second (white jerk density ``σ_α²``, or white snap ``3 σ_α²`` for the jerk model).
        None: maximum-likelihood estimate from the log.
    model : {"rate-accel", "rate-accel-jerk"}
        State per axis: rate and angular acceleration, optionally jerk.
    estimate_bias : bool
        Add a gyro-bias state (rad/s), updated by zero-rate pseudo-measurements at detected rest.
    bias_random_walk_rad_s_sqrt_s : float
        Bias random-walk density, rad/s/√s (only with ``estimate_bias``).
    bias_prior_std_rad_s : float
        Prior standard deviation of the bias, rad/s (only with ``estimate_bias``).
    zero_rate_std_rad_s : float
        Standard deviation of the zero-rate pseudo-measurement at rest, rad/s.
    rest_interval_s : tuple of float or None
        ``(start, end)`` in the units of ``t_s``: the rest segment for the noise estimate. None:
        the longest rest found by ``imu_dcm.replay.bias.detect_rest``.
    min_rest_s : float
        Shortest rest segment accepted for the noise estimate, s.
    rest_window_s : float
        Window of the rest detector, s (``RestConfig.min_duration_s``).
    rest_max_rate_rad_s : float
        Rest: window-mean rate magnitude below this, rad/s (``RestConfig.max_rate_rad_s``).
    rest_max_std_rad_s : float or None
        Rest: every axis's window standard deviation below this, rad/s. None: the larger of
        0.01 rad/s and 1.5 per-sample noise sigmas (from the noise density when given, else the
        quietest window of the log).
    """

    noise_density_rad_s_sqrt_hz: float | None = None
    angular_accel_rad_s2: float | None = None
    model: str = "rate-accel"
    estimate_bias: bool = False
    bias_random_walk_rad_s_sqrt_s: float = 1e-4
    bias_prior_std_rad_s: float = 0.02
    zero_rate_std_rad_s: float = 1e-3
    rest_interval_s: tuple[float, float] | None = None
    min_rest_s: float = 1.0
    rest_window_s: float = 0.5
    rest_max_rate_rad_s: float = 0.035
    rest_max_std_rad_s: float | None = None


@dataclass(frozen=True)
class NoiseEstimate:
    """Gyro noise read off the Allan deviation of a rest segment.

    Attributes
    ----------
    noise_density_rad_s_sqrt_hz : ndarray, shape (3,)
        Angle random walk per body axis, rad/s/√Hz (= rad/√s).
    bias_instability_rad_s : ndarray, shape (3,)
        Flicker floor per axis, ``min σ_Allan / 0.664``, rad/s (only an upper bound when the
        minimum sits at the longest cluster time, where the deviation may still be falling; see
        ``bias_instability_tau_s``).
    bias_instability_tau_s : ndarray, shape (3,)
        Cluster time of that minimum, s.
    mean_rate_rad_s : ndarray, shape (3,)
        Mean rate over the segment (the gyro bias if the body was at rest), rad/s.
    interval_s : tuple of float
        ``(first, last)`` sample time of the segment, in the units of ``t_s``.
    n_samples : int
        Samples in the segment.
    """

    noise_density_rad_s_sqrt_hz: NDArray[np.float64]
    bias_instability_rad_s: NDArray[np.float64]
    bias_instability_tau_s: NDArray[np.float64]
    mean_rate_rad_s: NDArray[np.float64]
    interval_s: tuple[float, float]
    n_samples: int


@dataclass(frozen=True)
class PrefilterResult:
    """Filtered body rates and what the filter used.

    Attributes
    ----------
    omega_b : ndarray, shape (N, 3)
        Estimated body rate relative to the world, body axes, rad/s, at the input stamps (the
        bias removed when ``estimate_bias``).
    rate_std_rad_s : ndarray, shape (N, 3)
        Posterior standard deviation of ``omega_b`` by the filter's own covariance, rad/s
        (filtered for ``kalman``, smoothed for ``rts``).
    angular_accel_b : ndarray, shape (N, 3)
        Estimated angular acceleration, body axes, rad/s².
    bias_b : ndarray, shape (N, 3), or None
        Estimated gyro bias, rad/s (None without ``estimate_bias``).
    rest : ndarray of bool, shape (N,), or None
        Samples taken as rest (None when rest detection did not run).
    mode : str
        ``"kalman"`` or ``"rts"``.
    config : PrefilterConfig
        The configuration with every estimated parameter filled in.
    summary : dict
        Parameters used and how they were obtained (``noise_source``, ``accel_source``), the
        Allan-deviation estimates (angle random walk, bias instability) when they ran, the
        likelihood fit, the final bias, sample counts.
    """

    omega_b: NDArray[np.float64]
    rate_std_rad_s: NDArray[np.float64]
    angular_accel_b: NDArray[np.float64]
    bias_b: NDArray[np.float64] | None
    rest: NDArray[np.bool_] | None
    mode: str
    config: PrefilterConfig
    summary: dict[str, Any]


# ------------------------------------------------------------------------------------------------
# input checks


def _check_rates(omega_b: ArrayLike, t_s: ArrayLike) -> tuple[NDArray, NDArray]:
    """The integrator's sample checks (shape, finite, strictly increasing stamps, gaps warned),
    plus the three samples a rate-and-acceleration model needs."""
    omega_b, t_s, _dt = check_samples(omega_b, t_s)
    if omega_b.shape[0] < 3:
        raise InputError(f"Expected at least 3 samples, got {omega_b.shape[0]}")
    return omega_b, t_s


def _check_positive(name: str, value: float | None, allow_none: bool = True) -> None:
    if value is None and allow_none:
        return
    if value is None or not isinstance(value, (int, float, np.floating, np.integer)) or not (
        math.isfinite(value) and value > 0
    ):
        raise InputError(f"Expected `{name}` finite and > 0, got {value!r}")


def _check_config(config: PrefilterConfig) -> None:
    if not isinstance(config, PrefilterConfig):
        raise InputError(
            f"Expected `config` a PrefilterConfig or None, got {type(config).__name__}"
        )
    _check_positive("noise_density_rad_s_sqrt_hz", config.noise_density_rad_s_sqrt_hz)
    _check_positive("angular_accel_rad_s2", config.angular_accel_rad_s2)
    if config.model not in MODELS:
        raise InputError(f"Expected `model` in {MODELS}, got {config.model!r}")
    if not isinstance(config.estimate_bias, (bool, np.bool_)):
        raise InputError(f"Expected `estimate_bias` a bool, got {config.estimate_bias!r}")
    for name in (
        "bias_random_walk_rad_s_sqrt_s",
        "bias_prior_std_rad_s",
        "zero_rate_std_rad_s",
        "min_rest_s",
        "rest_window_s",
        "rest_max_rate_rad_s",
    ):
        _check_positive(name, getattr(config, name), allow_none=False)
    _check_positive("rest_max_std_rad_s", config.rest_max_std_rad_s)
    if config.rest_interval_s is not None:
        iv = config.rest_interval_s
        if len(iv) != 2 or not all(math.isfinite(v) for v in iv) or not iv[0] < iv[1]:
            raise InputError(
                f"Expected `rest_interval_s` = (start, end) with start < end, got {iv!r}"
            )


# ------------------------------------------------------------------------------------------------
# rest detection and noise from the Allan deviation


def _quietest_std(omega_b: NDArray, t_s: NDArray, window_s: float) -> float:
    """Smallest windowed rate spread (largest axis), rad/s: the noise floor when the log rests."""
    m = max(3, min(len(t_s), round(window_s / float(np.median(np.diff(t_s))))))
    c1 = np.concatenate([np.zeros((1, 3)), np.cumsum(omega_b, axis=0)])
    c2 = np.concatenate([np.zeros((1, 3)), np.cumsum(omega_b * omega_b, axis=0)])
    mean = (c1[m:] - c1[:-m]) / m
    var = np.maximum((c2[m:] - c2[:-m]) / m - mean * mean, 0.0)
    return float(np.sqrt(var.max(axis=1).min()))


def _longest_run(mask: NDArray[np.bool_]) -> tuple[int, int]:
    """``[start, stop)`` of the longest run of True (``(0, 0)`` when none)."""
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    starts, stops = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
    if len(starts) == 0:
        return 0, 0
    j = int(np.argmax(stops - starts))
    return int(starts[j]), int(stops[j])


def estimate_noise_from_rest(
    omega_b: ArrayLike, t_s: ArrayLike, min_rest_s: float = 1.0
) -> NoiseEstimate:
    """Angle random walk and bias instability from a rest segment's Allan deviation.

    Parameters
    ----------
    omega_b : array_like, shape (M, 3)
        Body rate over a segment at rest, rad/s.
    t_s : array_like, shape (M,)
        Its sample times, s (the rate is taken as ``1 / median(dt)``).
    min_rest_s : float
        Shortest segment accepted, s; fewer than 200 samples are refused as well.

    Returns
    -------
    NoiseEstimate

    Raises
    ------
    InputError
        When the segment is too short for the Allan deviation.
    """
    omega_b, t_s = _check_rates(omega_b, t_s)
    n = len(t_s)
    span = float(t_s[-1] - t_s[0])
    if n < _MIN_REST_SAMPLES or span < min_rest_s:
        raise InputError(
            f"Expected a rest segment of at least {min_rest_s:g} s and {_MIN_REST_SAMPLES} samples "
            f"for the Allan deviation, got {span:.3g} s and {n} samples"
        )
    rate_hz = 1.0 / float(np.median(np.diff(t_s)))
    arw = np.atleast_1d(noise_density_from_allan(omega_b, rate_hz))
    tau, adev = allan_deviation(omega_b, rate_hz)
    i_min = np.argmin(adev, axis=0)
    return NoiseEstimate(
        noise_density_rad_s_sqrt_hz=arw,
        bias_instability_rad_s=adev[i_min, np.arange(3)] / _FLICKER_FACTOR,
        bias_instability_tau_s=tau[i_min],
        mean_rate_rad_s=omega_b.mean(axis=0),
        interval_s=(float(t_s[0]), float(t_s[-1])),
        n_samples=n,
    )


# ------------------------------------------------------------------------------------------------
# the linear model


def _n_motion(model: str) -> int:
    return 2 if model == "rate-accel" else 3


def _q_scale(model: str, accel_rad_s2: float) -> float:
    """White-noise density driving the highest derivative (see the module docstring)."""
    return accel_rad_s2**2 if model == "rate-accel" else 3.0 * accel_rad_s2**2


def _transition(dt: NDArray, n_motion: int, bias: bool) -> NDArray:
    """State transition matrices ``F_k``, shape (len(dt), d, d)."""
    d = n_motion + int(bias)
    F = np.zeros((len(dt), d, d))
    F[:, np.arange(d), np.arange(d)] = 1.0
    F[:, 0, 1] = dt
    if n_motion == 3:
        F[:, 0, 2] = 0.5 * dt * dt
        F[:, 1, 2] = dt
    return F


def _process_noise(dt: NDArray, n_motion: int, q: float, bias: bool, q_bias: float) -> NDArray:
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


def _stationary_prior(dt: float, n_motion: int, q: float, r: float) -> NDArray:
    """Stationary prior covariance of the motion states (discrete algebraic Riccati equation)."""
    F = _transition(np.array([dt]), n_motion, False)[0]
    Q = _process_noise(np.array([dt]), n_motion, q, False, 0.0)[0]
    H = np.zeros((1, n_motion))
    H[0, 0] = 1.0
    P = linalg.solve_discrete_are(F.T, H.T, Q, np.array([[r]]))
    return 0.5 * (P + P.T)


@dataclass(frozen=True)
class _Model:
    F: NDArray  # (N, d, d); F[0] = I (the prior at sample 0 is given)
    Q: NDArray  # (N, d, d); Q[0] = 0
    r: NDArray  # (N,) measurement variance, rad²/s²
    rest: NDArray  # (N,) bool: zero-rate pseudo-measurement at this sample
    H: NDArray  # (2, d): row 0 measures z = ω (+ b), row 1 the zero-rate pseudo-measurement
    r_zero: float
    x0: NDArray  # (d, 3) prior mean at sample 0
    P0: NDArray  # (d, d) prior covariance at sample 0
    run_start: NDArray  # (N,) first sample of the run of equal (dt, rest) containing each sample


def _build_model(
    z: NDArray, t_s: NDArray, cfg: PrefilterConfig, rest: NDArray | None, bias0: NDArray | None
) -> _Model:
    n = len(t_s)
    nm = _n_motion(cfg.model)
    bias = cfg.estimate_bias
    d = nm + int(bias)
    dt = np.diff(t_s)
    dt_full = np.concatenate([[dt[0]], dt])
    q = _q_scale(cfg.model, cfg.angular_accel_rad_s2)
    F = _transition(dt_full, nm, bias)
    Q = _process_noise(dt_full, nm, q, bias, cfg.bias_random_walk_rad_s_sqrt_s**2)
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
    P0[np.arange(nm), np.arange(nm)] = (_PRIOR_SCALE * np.array(spread)) ** 2
    x0 = np.zeros((d, 3))
    x0[0] = z[0]
    if bias:
        P0[-1, -1] = cfg.bias_prior_std_rad_s**2
        if bias0 is not None:
            x0[-1] = bias0
            x0[0] = z[0] - bias0
    change = np.ones(n, bool)
    change[1:] = (np.abs(np.diff(dt_full)) > _DT_REL_TOL * dt_full[:-1]) | (rest[1:] != rest[:-1])
    change[1] = True  # sample 0 has no prediction step, so sample 1 starts a run
    starts = np.flatnonzero(change)
    run_start = starts[np.searchsorted(starts, np.arange(n), side="right") - 1]
    return _Model(F, Q, r, rest, H, cfg.zero_rate_std_rad_s**2, x0, P0, run_start)


# ------------------------------------------------------------------------------------------------
# fast path: covariances once for all axes, stationary runs filled in blocks


def _close(a: NDArray, b: NDArray) -> bool:
    """Covariances equal to ``_STATIONARY_REL_TOL``, entry by entry on the scale sqrt(P_ii P_jj)."""
    d = np.sqrt(np.abs(np.diag(a)))
    return bool(np.all(np.abs(a - b) <= _STATIONARY_REL_TOL * np.outer(d, d)))


def _forward_covariances(m: _Model) -> tuple[NDArray, NDArray, NDArray, NDArray]:
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
    m: _Model, Pm: NDArray, Pp: NDArray, same: NDArray
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
    for s, e in zip(starts, ends):
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


def _run_fast(z: NDArray, m: _Model, smooth: bool) -> tuple[NDArray, NDArray]:
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


def _run_filterpy(z: NDArray, m: _Model, smooth: bool) -> tuple[NDArray, NDArray]:
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


# ------------------------------------------------------------------------------------------------
# maximum-likelihood process-noise scale


def _innovation_nll(z: NDArray, dt: float, nm: int, q: float, r: float, burn: int) -> float:
    """Negative log-likelihood of the stationary filter's innovations (all axes)."""
    P = _stationary_prior(dt, nm, q, r)
    F = _transition(np.array([dt]), nm, False)[0]
    H = np.zeros((1, nm))
    H[0, 0] = 1.0
    S = float(P[0, 0] + r)
    K = P[:, :1] / S
    from scipy import signal

    # predicted measurement: s_{k+1} = F (I - K H) s_k + F K z_k, y_k = H s_k, from s_0 = z_0;
    # in the eigenbasis of F (I - K H) = V Λ V⁻¹ it is a sum of first-order IIR filters
    lam, V = np.linalg.eig(F @ (np.eye(nm) - K @ H))
    if np.linalg.cond(V) > 1e6:
        return math.inf
    g = np.linalg.solve(V, F @ K)[:, 0] * V[0, :]
    zc = z - z[0]
    y = np.zeros(zc.shape)
    for li, gi in zip(lam, g):
        y += (gi * signal.lfilter([0.0, 1.0], [1.0, -li], zc, axis=0)).real
    e = (zc - y)[burn:]
    return 0.5 * float(np.sum(e * e) / S + e.size * math.log(S))


def _fit_accel(z: NDArray, t_s: NDArray, model: str, density: float) -> dict[str, Any]:
    """Maximum-likelihood ``σ_α`` (rad/s²) of the stationary filter at the median step."""
    from scipy import optimize

    dt = float(np.median(np.diff(t_s)))
    nm = _n_motion(model)
    r = density**2 / dt
    burn = min(len(z) // 10, 1000)

    def nll(log_a: float) -> float:
        return _innovation_nll(z, dt, nm, _q_scale(model, 10.0**log_a), r, burn)

    lo, hi = (math.log10(v) for v in _ACCEL_SEARCH_RAD_S2)
    grid = np.arange(lo, hi + 1e-9, 0.5)
    vals = np.array([nll(g) for g in grid])
    j = int(np.argmin(vals))
    at_bound = j in (0, len(grid) - 1)
    a, b = grid[max(j - 1, 0)], grid[min(j + 1, len(grid) - 1)]
    res = optimize.minimize_scalar(nll, bounds=(a, b), method="bounded", options={"xatol": 1e-3})
    return {
        "angular_accel_rad_s2": float(10.0**res.x),
        "at_search_bound": bool(at_bound),
        "neg_log_likelihood": float(res.fun),
        "dt_s": dt,
    }


# ------------------------------------------------------------------------------------------------
# public entry point


def prefilter(
    omega_b: ArrayLike,
    t_s: ArrayLike,
    mode: str = "rts",
    config: PrefilterConfig | None = None,
    *,
    engine: str = "numpy",
) -> PrefilterResult:
    """Kalman-filter (``kalman``) or RTS-smooth (``rts``) measured body rates.

    Parameters
    ----------
    omega_b : array_like, shape (N, 3)
        Measured body rate relative to the world, body axes, rad/s.
    t_s : array_like, shape (N,)
        Sample times, s, strictly increasing (uneven spacing is used as is).
    mode : {"kalman", "rts"}
        Causal filter, or filter plus Rauch-Tung-Striebel smoother.
    config : PrefilterConfig, optional
        Model and noise settings; parameters left ``None`` are estimated from the log.
    engine : {"numpy", "filterpy"}
        ``numpy``: covariances once for all axes, steady-state runs in blocks (fast).
        ``filterpy``: ``filterpy.kalman.predict`` / ``update`` / ``rts_smoother`` per axis
        (the reference; about 100x slower).

    Returns
    -------
    PrefilterResult

    Raises
    ------
    InputError
        Bad shapes, non-finite values, non-increasing stamps, a bad mode, model or parameter
        (negative or NaN noise), or no rest segment long enough to estimate a missing noise
        density.
    """
    omega_b, t_s = _check_rates(omega_b, t_s)
    if mode not in MODES:
        raise InputError(f"Expected `mode` in {MODES}, got {mode!r}")
    if engine not in ("numpy", "filterpy"):
        raise InputError(f"Expected `engine` in ('numpy', 'filterpy'), got {engine!r}")
    cfg = PrefilterConfig() if config is None else config
    _check_config(cfg)
    summary: dict[str, Any] = {"mode": mode, "model": cfg.model, "engine": engine,
                               "n_samples": len(t_s)}
    dt_med = float(np.median(np.diff(t_s)))
    summary["rate_hz"] = 1.0 / dt_med

    rest = None
    noise_std = (
        cfg.noise_density_rad_s_sqrt_hz / math.sqrt(dt_med)
        if cfg.noise_density_rad_s_sqrt_hz is not None
        else None
    )
    if cfg.noise_density_rad_s_sqrt_hz is None or cfg.estimate_bias:
        max_std = cfg.rest_max_std_rad_s
        if max_std is None:
            floor = noise_std if noise_std is not None else _quietest_std(omega_b, t_s,
                                                                          cfg.rest_window_s)
            max_std = max(0.01, 1.5 * floor)
        rest = detect_rest(omega_b, t_s, RestConfig(cfg.rest_window_s, cfg.rest_max_rate_rad_s,
                                                    max_std))
        summary["rest_samples"] = int(rest.sum())

    bias0 = None
    if cfg.noise_density_rad_s_sqrt_hz is None:
        if cfg.rest_interval_s is not None:
            sel = (t_s >= cfg.rest_interval_s[0]) & (t_s <= cfg.rest_interval_s[1])
            idx = np.flatnonzero(sel)
            i0, i1 = (int(idx[0]), int(idx[-1]) + 1) if len(idx) else (0, 0)
            source = "rest_interval_s"
        else:
            i0, i1 = _longest_run(rest)
            source = "detected rest"
        if i1 - i0 < 2:
            raise InputError(
                f"Expected a rest segment ({source}) to estimate the gyro noise density, got none; "
                "pass noise_density_rad_s_sqrt_hz (replay: --gyro-noise-density)"
            )
        est = estimate_noise_from_rest(omega_b[i0:i1], t_s[i0:i1], cfg.min_rest_s)
        density = float(np.sqrt(np.mean(est.noise_density_rad_s_sqrt_hz**2)))
        cfg = replace(cfg, noise_density_rad_s_sqrt_hz=density)
        bias0 = est.mean_rate_rad_s
        summary.update(
            noise_source=f"Allan deviation of {source}",
            rest_interval_s=est.interval_s,
            angle_random_walk_rad_s_sqrt_hz=est.noise_density_rad_s_sqrt_hz.tolist(),
            angle_random_walk_deg_sqrt_h=np.degrees(est.noise_density_rad_s_sqrt_hz * 60).tolist(),
            bias_instability_rad_s=est.bias_instability_rad_s.tolist(),
            bias_instability_deg_h=np.degrees(est.bias_instability_rad_s * 3600).tolist(),
            bias_instability_tau_s=est.bias_instability_tau_s.tolist(),
            rest_mean_rate_rad_s=est.mean_rate_rad_s.tolist(),
        )
    else:
        summary["noise_source"] = "given"
    summary["noise_density_rad_s_sqrt_hz"] = cfg.noise_density_rad_s_sqrt_hz

    if cfg.angular_accel_rad_s2 is None:
        z_fit = omega_b if bias0 is None else omega_b - bias0
        fit = _fit_accel(z_fit, t_s, cfg.model, cfg.noise_density_rad_s_sqrt_hz)
        cfg = replace(cfg, angular_accel_rad_s2=fit["angular_accel_rad_s2"])
        summary["accel_source"] = "maximum likelihood"
        summary["accel_fit"] = fit
    else:
        summary["accel_source"] = "given"
    summary["angular_accel_rad_s2"] = cfg.angular_accel_rad_s2

    m = _build_model(omega_b, t_s, cfg, rest, bias0 if cfg.estimate_bias else None)
    run = _run_fast if engine == "numpy" else _run_filterpy
    X, P = run(omega_b, m, mode == "rts")
    nm = _n_motion(cfg.model)
    rate_std = np.repeat(np.sqrt(P[:, 0, 0])[:, None], 3, axis=1)
    bias_b = X[:, -1, :] if cfg.estimate_bias else None
    if bias_b is not None:
        summary["bias_final_rad_s"] = bias_b[-1].tolist()
    # stationary posterior rate std of the causal filter at the median step, rad/s
    r_med = cfg.noise_density_rad_s_sqrt_hz**2 / dt_med
    p_med = _stationary_prior(dt_med, nm, _q_scale(cfg.model, cfg.angular_accel_rad_s2), r_med)
    summary["stationary_rate_std_rad_s"] = math.sqrt(p_med[0, 0] * r_med / (p_med[0, 0] + r_med))
    summary["raw_rate_std_rad_s"] = math.sqrt(r_med)
    return PrefilterResult(
        omega_b=X[:, 0, :].copy(),
        rate_std_rad_s=rate_std,
        angular_accel_b=X[:, 1, :].copy(),
        bias_b=None if bias_b is None else bias_b.copy(),
        rest=rest,
        mode=mode,
        config=cfg,
        summary=summary,
    )


# ------------------------------------------------------------------------------------------------
# model-based variant: Euler's equations of a rigid body with known inertia (filterpy UKF)


def _euler_rates_dot(w: NDArray, inertia: NDArray, torque_b: NDArray | None) -> NDArray:
    """``ω̇ = I⁻¹ (τ − ω × I ω)``, principal inertias ``inertia`` (3,), rates ``w`` (..., 3)."""
    h = w * inertia  # angular momentum, body axes
    x, y, z = w[..., 0], w[..., 1], w[..., 2]
    acc = -np.stack([y * h[..., 2] - z * h[..., 1], z * h[..., 0] - x * h[..., 2],
                     x * h[..., 1] - y * h[..., 0]], axis=-1)  # -(ω × I ω), np.cross is slow
    if torque_b is not None:
        acc = acc + torque_b
    return acc / inertia


def _euler_step(w: NDArray, dt: float, inertia: NDArray, torque_b: NDArray | None) -> NDArray:
    """One classical Runge-Kutta step of Euler's equations over ``dt`` (rows of ``w``)."""
    k1 = _euler_rates_dot(w, inertia, torque_b)
    k2 = _euler_rates_dot(w + 0.5 * dt * k1, inertia, torque_b)
    k3 = _euler_rates_dot(w + 0.5 * dt * k2, inertia, torque_b)
    k4 = _euler_rates_dot(w + dt * k3, inertia, torque_b)
    return w + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


def euler_prefilter(
    omega_b: ArrayLike,
    t_s: ArrayLike,
    inertia_kg_m2: ArrayLike,
    mode: str = "rts",
    *,
    noise_density_rad_s_sqrt_hz: float,
    torque_noise_n_m_sqrt_hz: float,
    torque_b: ArrayLike | None = None,
) -> PrefilterResult:
    """Filter or smooth body rates with Euler's equations as the process model (known inertia).

    The state is the body rate ``ω`` (body axes, rad/s); between samples it follows
    ``I ω̇ = τ − ω × I ω`` (one RK4 step per sample interval) with ``τ`` the known torque (zero
    for a torque-free body) plus white torque noise of density ``torque_noise_n_m_sqrt_hz``
    (N·m/√Hz): the unmodelled torques. Measurements are ``z = ω + v``, ``v`` white of density
    ``noise_density_rad_s_sqrt_hz``. The forward pass is ``filterpy.kalman.UnscentedKalmanFilter``
    (Merwe sigma points); ``rts`` adds the unscented RTS smoother (Särkkä 2008), written out
    because filterpy's ``UnscentedKalmanFilter.rts_smoother`` applies one ``Q`` and the step into
    ``k`` rather than out of it, which is wrong for uneven stamps.

    Unlike the generic model (:func:`prefilter`), this one knows how the rate must evolve, so it
    can average the noise over many samples without lagging the motion.

    Parameters
    ----------
    omega_b : array_like, shape (N, 3)
        Measured body rate, body (principal) axes, rad/s.
    t_s : array_like, shape (N,)
        Sample times, s, strictly increasing.
    inertia_kg_m2 : array_like, shape (3,)
        Principal moments of inertia about the body axes, kg·m².
    mode : {"kalman", "rts"}
    noise_density_rad_s_sqrt_hz : float
        Gyro white-noise density, rad/s/√Hz.
    torque_noise_n_m_sqrt_hz : float
        Density of the unmodelled torque, N·m/√Hz.
    torque_b : array_like, shape (3,), optional
        Known constant torque in body axes, N·m (default: none).

    Returns
    -------
    PrefilterResult
        ``angular_accel_b`` from Euler's equations at the estimate; ``config`` holds the noise
        density; ``summary["model"] == "euler"`` with the inertia and torque noise.
    """
    from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

    omega_b, t_s = _check_rates(omega_b, t_s)
    if mode not in MODES:
        raise InputError(f"Expected `mode` in {MODES}, got {mode!r}")
    inertia = np.asarray(inertia_kg_m2, dtype=float)
    if inertia.shape != (3,) or not (np.isfinite(inertia).all() and (inertia > 0).all()):
        raise InputError(f"Expected `inertia_kg_m2` three finite values > 0, got {inertia_kg_m2!r}")
    _check_positive("noise_density_rad_s_sqrt_hz", noise_density_rad_s_sqrt_hz, allow_none=False)
    _check_positive("torque_noise_n_m_sqrt_hz", torque_noise_n_m_sqrt_hz, allow_none=False)
    tau = None
    if torque_b is not None:
        tau = np.asarray(torque_b, dtype=float)
        if tau.shape != (3,) or not np.isfinite(tau).all():
            raise InputError(f"Expected `torque_b` three finite values, got {torque_b!r}")

    n = len(t_s)
    dt = np.diff(t_s)
    q_w = (torque_noise_n_m_sqrt_hz / inertia) ** 2  # rate random-walk density per axis, rad²/s³

    class _UKF(UnscentedKalmanFilter):
        # propagate all sigma points at once, and keep them for the smoother's cross-covariance
        def compute_process_sigmas(self, dt, fx=None, **fx_args):
            self.sig_in = self.points_fn.sigma_points(self.x, self.P)
            self.sig_out = _euler_step(self.sig_in, dt, inertia, tau)
            self.sigmas_f = self.sig_out.copy()

    points = MerweScaledSigmaPoints(3, alpha=0.1, beta=2.0, kappa=0.0)
    ukf = _UKF(dim_x=3, dim_z=3, dt=float(np.median(dt)), hx=lambda x: x,
               fx=lambda x, h: _euler_step(x, h, inertia, tau), points=points)
    r0 = noise_density_rad_s_sqrt_hz**2 / float(dt[0])
    ukf.x = omega_b[0].copy()
    ukf.P = np.eye(3) * r0 * _PRIOR_SCALE**2
    X = np.empty((n, 3))
    P = np.empty((n, 3, 3))
    Xm = np.empty((n, 3))  # prior means
    Pm = np.empty((n, 3, 3))  # prior covariances
    C = np.empty((n, 3, 3))  # cross-covariance of x_{k-1} (filtered) and x_k (prior)
    for k in range(n):
        if k > 0:
            ukf.Q = np.diag(q_w * dt[k - 1])
            ukf.predict(dt=float(dt[k - 1]))
            Xm[k], Pm[k] = ukf.x, ukf.P
            d_in = ukf.sig_in - X[k - 1]
            d_out = ukf.sig_out - Xm[k]
            C[k] = (ukf.Wc[:, None] * d_in).T @ d_out
        r = noise_density_rad_s_sqrt_hz**2 / float(dt[max(k - 1, 0)])
        ukf.update(omega_b[k], R=np.eye(3) * r)
        X[k], P[k] = ukf.x, ukf.P
    if mode == "rts":
        for k in range(n - 2, -1, -1):
            G = C[k + 1] @ np.linalg.inv(Pm[k + 1])
            X[k] = X[k] + G @ (X[k + 1] - Xm[k + 1])
            P[k] = P[k] + G @ (P[k + 1] - Pm[k + 1]) @ G.T
    summary = {"mode": mode, "model": "euler", "engine": "filterpy UKF", "n_samples": n,
               "inertia_kg_m2": inertia.tolist(),
               "torque_noise_n_m_sqrt_hz": float(torque_noise_n_m_sqrt_hz),
               "noise_density_rad_s_sqrt_hz": float(noise_density_rad_s_sqrt_hz),
               "noise_source": "given"}
    return PrefilterResult(
        omega_b=X,
        rate_std_rad_s=np.sqrt(np.diagonal(P, axis1=1, axis2=2)).copy(),
        angular_accel_b=_euler_rates_dot(X, inertia, tau),
        bias_b=None,
        rest=None,
        mode=mode,
        config=PrefilterConfig(noise_density_rad_s_sqrt_hz=float(noise_density_rad_s_sqrt_hz)),
        summary=summary,
    )


# ------------------------------------------------------------------------------------------------
# streaming twin of mode="kalman"


class StreamingRateFilter:
    """Causal rate filter fed one gyro sample at a time: the streaming twin of ``"kalman"``.

    The same model and equations as ``prefilter(..., "kalman", config)`` (a test asserts that
    both agree); it keeps only the state ``(d, 3)``, its covariance and the last stamp. Both
    noise parameters must be given (nothing is estimated from a log that has not arrived yet);
    the bias state is not supported here.

    Parameters
    ----------
    config : PrefilterConfig
        With ``noise_density_rad_s_sqrt_hz`` and ``angular_accel_rad_s2`` set.

    Examples
    --------
    >>> f = StreamingRateFilter(PrefilterConfig(noise_density_rad_s_sqrt_hz=1e-3,
    ...                                         angular_accel_rad_s2=5.0))
    >>> omega_f_b, std_rad_s = f.update([0.1, 0.0, -0.2], 0.0)
    """

    def __init__(self, config: PrefilterConfig) -> None:
        _check_config(config)
        if config.noise_density_rad_s_sqrt_hz is None or config.angular_accel_rad_s2 is None:
            raise InputError(
                "Expected `noise_density_rad_s_sqrt_hz` and `angular_accel_rad_s2` given for "
                f"streaming, got {config.noise_density_rad_s_sqrt_hz!r} and "
                f"{config.angular_accel_rad_s2!r}"
            )
        if config.estimate_bias:
            raise InputError("Expected `estimate_bias=False` for streaming, got True")
        self.config = config
        self._nm = _n_motion(config.model)
        self._q = _q_scale(config.model, config.angular_accel_rad_s2)
        self._h = np.zeros(self._nm)
        self._h[0] = 1.0
        self._x: NDArray | None = None  # (d, 3)
        self._P: NDArray | None = None  # (d, d)
        self._t: float | None = None

    def update(self, omega_b: ArrayLike, t_s: float) -> tuple[NDArray, float]:
        """Add one sample; return the filtered rate (3,) rad/s and its std, rad/s.

        Parameters
        ----------
        omega_b : array_like, shape (3,)
            Measured body rate, body axes, rad/s.
        t_s : float
            Its time, s, later than the previous sample's.
        """
        z = np.asarray(omega_b, dtype=float)
        if z.shape != (3,) or not np.isfinite(z).all():
            raise InputError(f"Expected `omega_b` three finite rates, got {omega_b!r}")
        t = float(t_s)
        if not math.isfinite(t) or (self._t is not None and t <= self._t):
            raise InputError(f"Expected `t_s` finite and > {self._t!r}, got {t_s!r}")
        dens2 = self.config.noise_density_rad_s_sqrt_hz**2
        if self._t is None:
            self._t = t
            self._x = np.zeros((self._nm, 3))
            self._x[0] = z
            return z.copy(), math.nan  # the first sample: its dt (and so its noise) is unknown
        dt = t - self._t
        if self._P is None:
            # the batch filter's prior at its sample 0 uses the first step's dt (dt_full[0])
            sig, h = math.sqrt(dens2 / dt), dt
            spread = [sig, math.sqrt(2.0) * sig / h, math.sqrt(6.0) * sig / h**2][: self._nm]
            P = np.diag((_PRIOR_SCALE * np.array(spread)) ** 2)
            z0 = self._x[0].copy()
            Ph = P @ self._h
            K = Ph / (float(self._h @ Ph) + dens2 / dt)
            self._x = self._x + np.outer(K, z0 - self._x[0])
            self._P = P - np.outer(K, Ph)
        F = _transition(np.array([dt]), self._nm, False)[0]
        Q = _process_noise(np.array([dt]), self._nm, self._q, False, 0.0)[0]
        x = F @ self._x
        P = F @ self._P @ F.T + Q
        Ph = P @ self._h
        K = Ph / (float(self._h @ Ph) + dens2 / dt)
        self._x = x + np.outer(K, z - x[0])
        P = P - np.outer(K, Ph)
        self._P = 0.5 * (P + P.T)
        self._t = t
        return self._x[0].copy(), math.sqrt(self._P[0, 0])

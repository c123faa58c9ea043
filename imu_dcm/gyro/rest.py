"""Rest: the still segments of a gyro log, the evidence behind each, and the bias they give.

One rule serves replay (offline: it looks both ways) and live (causal). A window of
``min_duration_s`` (0.5 s) is still when every independent signal the log has agrees that the
body does not rotate:

* **gyro floor**: every per-axis rate standard deviation is at the log's own noise floor. The
  floor is the spread of the log's stillest window (replay: of the whole log; live: of the
  windows seen so far), at least the output's quantisation (step²/12). A window passes up to
  ``exp(2 z / sqrt(2 (m - 1)))`` times the floor (``m`` samples, ``z = floor_spreads`` = 4):
  the log of a window's spread varies by ``1 / sqrt(2 (m - 1))`` for Gaussian noise, the floor
  window lies about ``z`` of those below the typical one, and a still window may lie ``z``
  above it. No bound comes from one sensor.
* **accelerometer** (where ``accel_b`` is given, m/s²): its per-axis spread at its own floor by
  the same rule, and ``|mean a|`` within ``max_gravity_error_m_s2`` (0.05 g, the scale and bias
  error of MEMS accelerometers) of g. Necessary, not sufficient: a constant velocity and a
  hover pass it too.
* **truth** (where a reference attitude covers the window): its rotation over the window, as a
  mean rate ``|omega_T|``, is at most ``max(n_T, |mean omega| / 2)``: nearer to no rotation
  than to the gyro's mean rate. ``n_T`` is the truth's own noise, measured from the second
  differences of its rotation sample to sample (:func:`truth_noise_rad`), as a rate over the
  window (``z`` spreads). Where the truth rotates as the gyro does, the gyro's mean is motion,
  not bias.
* **landed state** (where the log has the autopilot's landed and armed state, per sample,
  :attr:`imu_dcm.logio.LogData.vehicle_state`): a window with any sample where the vehicle is
  airborne (not landed, and not disarmed) is not rest, whatever the gyro and the accelerometer
  say (a hover holds both still); a window landed and disarmed throughout supports rest. The
  autopilot's own land detector judges this from its thrust, climb rate and rotation, which
  this gyro alone cannot see.
* **odometry twist** (where the truth is odometry with ``twist.twist.angular``, on the gyro
  rows, :class:`Motion`): the body rotates where the twist's mean ``|omega|`` over the window
  is above its noise, ``z sigma_w / sqrt(k)`` (``sigma_w`` from the twist's first differences,
  at least its quantisation; ``k`` twist samples per window): that window is not rest, and its
  gyro mean is motion, not bias (a slow turn while driving). A twist within its noise
  supports rest.
* **position** (where the truth carries one, :class:`Motion`): a window whose position moves
  by more than ``z sqrt(2) sigma_p`` from its first sample to its last (``sigma_p`` from the
  position's second differences, as for the truth's angle) is not rest. A body that moves
  is not still: translating straight does not rotate it, but the mean of a gyro on a moving
  vehicle holds its vibration and its small steering turns, which no window's spread shows;
  the zero-rate assumption behind the bias is the vehicle's standstill.
* **mean rate**: where the truth shows no rotation there is no bound on the mean (it is the
  bias); where only the accelerometer or the landed and disarmed state confirms, it may be up
  to ``max_bias_rad_s`` (10 °/s, the largest biases of uncalibrated MEMS: an accelerometer
  cannot tell a constant turn from a bias); with the gyro alone, nothing tells a smooth
  constant turn from a bias, so the mean must stay under ``max_rate_rad_s`` (2 °/s) and the
  rest is *unconfirmed*.

A run of consecutive still windows (starts ``[p, q)``) is one rest segment, samples
``[p, q - 1 + m)``. Its bias is the mean rate over it, leaving out one window next to motion
(windows that straddle a slow start of motion still pass), or its middle half when that leaves
less than a window (:func:`bias_span`). :func:`rest_segments` is the rule over a whole log;
:class:`CausalRestBias` runs it sample by sample and ends each segment on the same value.
:func:`detect_rest` marks the samples a still window covers (the pre-filter's rest), and
:func:`explain_no_rest` names the condition that failed where no window passed.

Conventions: ``omega_b`` (N, 3) body rate relative to the world in body axes, rad/s; ``t_s``
(N,) seconds, increasing; ``q_w_b`` Hamilton ``[x, y, z, w]``, body to world.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imu_dcm.arrays import median, row_max, row_norm
from imu_dcm.errors import InputError
from imu_dcm.gyro.rest_evidence import (
    Motion,
    airborne_between,
    checked_vehicle,
    motion_windows,
    position_noise_m,
    twist_noise_rad_s,
    vehicle_windows,
)
from imu_dcm.gyro.windows import min_steps, step_var, windowed_mean_var
from imu_dcm.so3 import log_quat, quat_conjugate, quat_multiply

#: Standard gravity, m/s² (a still accelerometer reads about this much).
GRAVITY_M_S2 = 9.80665

__all__ = [
    "GRAVITY_M_S2",
    "CausalRestBias",
    "Motion",
    "RestConfig",
    "RestSegment",
    "bias_span",
    "detect_rest",
    "explain_no_rest",
    "floor_factor",
    "longest_run",
    "position_noise_m",
    "quietest_std",
    "rest_segments",
    "runs",
    "truth_noise_rad",
    "twist_noise_rad_s",
    "window_samples",
    "windowed_mean_var",
]


@dataclass(frozen=True, slots=True)
class RestConfig:
    """Bounds of the rest rule (see the module docstring for where each comes from).

    Attributes
    ----------
    min_duration_s : window and shortest rest, s (default 0.5).
    max_rate_rad_s : largest window-mean rate magnitude when nothing but the gyro judges the
        window, rad/s (default 0.035 ≈ 2 °/s).
    max_std_rad_s : largest per-axis rate standard deviation, rad/s; None (default): from the
        log's own noise floor.
    max_bias_rad_s : largest window-mean rate magnitude when only the accelerometer confirms
        the stillness, rad/s (default 0.175 = 10 °/s).
    max_accel_std_m_s2 : largest per-axis accelerometer standard deviation, m/s²; None
        (default): from the accelerometer's own floor.
    max_gravity_error_m_s2 : largest difference between ``|mean a|`` and g, m/s² (default 0.5
        ≈ 0.05 g).
    floor_spreads : ``z``, spreads of a window's noise between the floor and a still window.
    """

    min_duration_s: float = 0.5
    max_rate_rad_s: float = 0.035
    max_std_rad_s: float | None = None
    max_bias_rad_s: float = 0.175
    max_accel_std_m_s2: float | None = None
    max_gravity_error_m_s2: float = 0.5
    floor_spreads: float = 4.0


@dataclass(frozen=True, slots=True)
class RestSegment:
    """One rest segment: samples ``[start, stop)``, times (s), its bias (rad/s, body axes).

    ``lo``, ``hi``: the samples ``[lo, hi)`` whose mean is the bias. ``evidence``: the signals
    that judged every window of it ("gyro floor", "accelerometer", "truth"; "truth (part)" when
    the truth covered only some windows).
    """

    start: int
    stop: int
    start_s: float
    end_s: float
    bias_rad_s: tuple[float, float, float]
    lo: int = 0
    hi: int = 0
    evidence: tuple[str, ...] = ()

    def as_dict(self) -> dict:
        """The segment for a summary: times, bias and evidence."""
        return {
            "start_s": self.start_s,
            "end_s": self.end_s,
            "bias_rad_s": [float(v) for v in self.bias_rad_s],
            "evidence": list(self.evidence),
        }


def window_samples(t_s: NDArray, duration_s: float) -> int:
    """Samples in a window of ``duration_s`` seconds at the median step (at least 2)."""
    dt = median(np.diff(t_s)) if len(t_s) > 1 else 1.0
    return max(2, int(np.ceil(duration_s / dt)))


def runs(mask: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """``[start, stop)`` of every run of True in a boolean mask, in order."""
    edges = np.diff(np.concatenate([[0], np.asarray(mask).astype(np.int8), [0]]))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    return list(zip(starts.tolist(), stops.tolist(), strict=True))


def longest_run(mask: NDArray[np.bool_]) -> tuple[int, int]:
    """``[start, stop)`` of the longest run of True (the first of equals; ``(0, 0)`` when none)."""
    found = runs(mask)
    if not found:
        return 0, 0
    return max(found, key=lambda r: r[1] - r[0])


def quietest_std(omega_b: NDArray, t_s: NDArray, window_s: float) -> float:
    """Smallest windowed rate spread (largest axis), rad/s: the noise floor when the log rests.

    Parameters
    ----------
    omega_b : ndarray, shape (N, 3)
        Body rate, rad/s.
    t_s : ndarray, shape (N,)
        Sample times, s.
    window_s : float
        Window length, s (at least 3 samples, at most the whole log).
    """
    m = max(3, min(len(t_s), round(window_s / median(np.diff(t_s)))))
    _mean, var = windowed_mean_var(omega_b, m)
    return float(np.sqrt(row_max(var).min()))


def floor_factor(m: int, spreads: float = 4.0) -> float:
    """How far above the floor a still window's spread may lie: ``exp(2 z / sqrt(2 (m - 1)))``.

    ``m`` samples a window (at least 2), ``z`` = ``spreads`` (see the module docstring).
    """
    return math.exp(2.0 * spreads / math.sqrt(2.0 * max(m - 1, 1)))


def truth_noise_rad(q_w_b: ArrayLike, step_ok: ArrayLike | None = None) -> float:
    """The truth's own angle noise per sample, rad: from second differences of its rotation.

    Each step's rotation ``log(q_k⁻¹ q_{k+1})`` differs from the next by the motion's change
    (``alpha dt²``, small at a truth's rate) and by white angle noise of variance ``6 σ²`` per
    axis. ``σ`` is taken robustly (1.4826 median absolute value / √6, largest axis); 0 with
    fewer than 3 finite samples. ``step_ok`` (M - 1,) marks the steps to use (default all; a
    jump of the truth's own is not its noise).
    """
    q = np.asarray(q_w_b, dtype=float)
    ok = np.all(np.isfinite(q), axis=1)
    step = ok[:-1] & ok[1:]
    if step_ok is not None:
        step &= np.asarray(step_ok, dtype=bool)
    pair = step[:-1] & step[1:]
    if not pair.any():
        return 0.0
    qq = np.where(ok[:, None], q, [0.0, 0.0, 0.0, 1.0])
    d = log_quat(quat_multiply(quat_conjugate(qq[:-1]), qq[1:]))
    dd = np.abs(np.diff(d, axis=0))[pair]
    return float(1.4826 * np.median(dd, axis=0).max() / math.sqrt(6.0))


def _truth_rates(q: NDArray, t: NDArray, m: int) -> NDArray:
    """``|omega_T|`` of every window of ``m`` samples, rad/s (NaN where the truth is missing).

    ``omega_T`` is the mean of the truth's body rate step by step, ``log(q_k⁻¹ q_{k+1}) / dt``
    over the window's ``m - 1`` steps: the rate the gyro would read without bias (a rotation
    of many turns over the window is not folded into ±π).
    """
    ok = np.all(np.isfinite(q), axis=1)
    qq = np.where(ok[:, None], q, [0.0, 0.0, 0.0, 1.0])
    d = log_quat(quat_multiply(quat_conjugate(qq[:-1]), qq[1:])) / np.diff(t)[:, None]
    valid = ok[:-1] & ok[1:]
    d[~valid] = 0.0
    sums = np.concatenate([np.zeros((1, 3)), np.cumsum(d, axis=0)])
    count = np.concatenate([[0], np.cumsum(valid)])
    rate = row_norm(sums[m - 1 :] - sums[: len(sums) - m + 1]) / (m - 1)
    rate[count[m - 1 :] - count[: len(count) - m + 1] < m - 1] = np.nan
    return rate


@dataclass(frozen=True, slots=True)
class _Signals:
    """The signals of one log that judge its windows: accelerometer (N, 3) m/s², truth (N, 4)
    on the gyro rows, its angle noise (rad) and the rotation (3, 3) taking gyro axes to the
    truth's body axes (identity when not known)."""

    accel_b: NDArray | None = None
    truth_q_w_b: NDArray | None = None
    truth_noise_rad: float = 0.0
    r_t_g: NDArray | None = None
    vehicle: tuple[NDArray, NDArray] | None = None  # (landed, armed) int8 (N,), -1 unknown
    motion: Motion | None = None


def _std_limit(floor_var, m: int, cfg: RestConfig):
    """The gyro's bound on a window's spread, rad/s, from its floor (variance, rad²/s²)."""
    if cfg.max_std_rad_s is not None:
        return cfg.max_std_rad_s
    return np.sqrt(floor_var) * floor_factor(m, cfg.floor_spreads)


def _conditions(w, t, m: int, cfg: RestConfig, sig: _Signals):
    """Each condition over every window of ``m`` samples, and what the segments' check needs.

    Returns ``(conds, std_limit, truth)``: ``conds`` a list of (signal, name, value, limit,
    unit), a window passing a condition when its value is at most the limit; ``std_limit`` the
    gyro's bound, rad/s; ``truth`` each window's ``|omega_T|`` (rad/s, NaN without truth) or
    None.
    """
    z = floor_factor(m, cfg.floor_spreads)
    mean, var = windowed_mean_var(w, m)
    spread = np.sqrt(row_max(var))
    rate = row_norm(mean)
    floor_var = max(float(spread.min()) ** 2, step_var(min_steps(w)))
    std_limit = _std_limit(floor_var, m, cfg)
    conds = [("gyro floor", "rate std", spread, std_limit, "rad/s")]
    mean_limit = np.full(len(rate), cfg.max_rate_rad_s)
    if sig.accel_b is not None:
        a_mean, a_var = windowed_mean_var(sig.accel_b, m)
        a_spread = np.sqrt(row_max(a_var))
        a_floor = math.sqrt(max(float(a_spread.min()) ** 2, step_var(min_steps(sig.accel_b))))
        a_limit = cfg.max_accel_std_m_s2 if cfg.max_accel_std_m_s2 is not None else a_floor * z
        g_err = np.abs(row_norm(a_mean) - GRAVITY_M_S2)
        conds += [
            ("accelerometer", "accel std", a_spread, a_limit, "m/s²"),
            ("accelerometer", "| |a| - g |", g_err, cfg.max_gravity_error_m_s2, "m/s²"),
        ]
        mean_limit[:] = cfg.max_bias_rad_s
    if sig.motion is not None:
        rate_hz = (len(t) - 1) / (t[-1] - t[0]) if t[-1] > t[0] else 1.0
        conds += motion_windows(sig.motion, m, cfg.floor_spreads, rate_hz)
    if sig.vehicle is not None:
        airborne, grounded = vehicle_windows(sig.vehicle, m)
        conds.append(("landed state", "airborne share", airborne, 0.5 / m, ""))
        mean_limit[grounded] = np.maximum(mean_limit[grounded], cfg.max_bias_rad_s)
    truth = None
    if sig.truth_q_w_b is not None:
        # the truth's rate is nearer to none than to the gyro's mean, or within its own noise:
        # the mean is bias, whatever its size
        truth = _truth_rates(sig.truth_q_w_b, t, m)
        n_t = cfg.floor_spreads * math.sqrt(6.0) * sig.truth_noise_rad / (t[m - 1] - t[0])
        mean_limit[truth <= np.maximum(n_t, 0.5 * rate)] = np.inf
    name = "mean |omega|" if sig.accel_b is not None else "mean |omega| (no accelerometer)"
    conds.append(("gyro floor", name, rate, mean_limit, "rad/s"))
    return conds, std_limit, truth


def _segment_doubt(w, t, lo: int, hi: int, m: int, std_limit: float, cfg, sig) -> str:
    """Why rest ``[lo, hi)`` (its bias span) is not a rest, "" when nothing says so.

    Only the truth can tell a rest from a motion the gyro's windows do not show (offline, over
    the whole span; ``z`` = ``floor_spreads``). The body moved where the truth's rotation is
    above its noise and nearer, as a vector in the truth's body axes, to what the gyro says
    than to none:

    * **turn**: the truth's rotation over the span against the gyro's mean turned over it (a
      slow steady turn, a hover: the mean is a turn, not bias); its noise ``z √6 σ``;
    * **sway**: the truth's path from the span's start, less its steady turn, against the
      gyro's rates less their mean, integrated: the RMS of their difference under half the
      truth path's RMS, and each path's largest excursion above its noise (the truth's
      ``z √6 σ``; the gyro's random walk ``z std_limit dt √n``).

    A truth that turns where the gyro does not is the truth's own wander (a motion capture's
    jitter, an estimator's correction), and a gyro that wanders alone has a wandering bias.
    """
    q = sig.truth_q_w_b
    if q is None:
        return ""
    span_q = q[lo:hi]
    ok = np.all(np.isfinite(span_q), axis=1)
    if not (ok[0] and ok[-1]):
        return ""
    r = np.eye(3) if sig.r_t_g is None else sig.r_t_g
    rel = log_quat(quat_multiply(quat_conjugate(span_q[0]), span_q))
    rel[~ok] = np.nan
    turn = rel[-1]
    mean = w[lo:hi].mean(axis=0)
    gyro_turn = r @ mean * (t[hi - 1] - t[lo])
    noise_t = cfg.floor_spreads * math.sqrt(6.0) * sig.truth_noise_rad
    if np.linalg.norm(turn) > noise_t and np.linalg.norm(turn - gyro_turn) < np.linalg.norm(turn):
        return (
            f"the truth turns {np.degrees(np.linalg.norm(turn)):.2f}° as the gyro's mean "
            f"would, {np.degrees(np.linalg.norm(gyro_turn)):.2f}°"
        )
    frac = ((t[lo:hi] - t[lo]) / (t[hi - 1] - t[lo]))[:, None]
    path_t = (rel - frac * turn)[ok]
    path_g = (_gyro_path(w, t, lo, hi) @ r.T)[ok]
    swing_t, swing_g = float(row_norm(path_t).max()), float(row_norm(path_g).max())
    noise_g = _gyro_path_noise(t, lo, hi, std_limit, cfg)
    apart = math.sqrt(float(np.mean(np.sum((path_t - path_g) ** 2, axis=1))))
    if swing_t > noise_t and swing_g > noise_g and apart < 0.5 * _rms_norm(path_t):
        return (
            f"the truth sways {np.degrees(swing_t):.2f}° as the gyro does, "
            f"{np.degrees(swing_g):.2f}°"
        )
    return ""


def _rms_norm(v: NDArray) -> float:
    return math.sqrt(float(np.mean(np.sum(v * v, axis=1))))


def _gyro_path(w, t, lo: int, hi: int) -> NDArray:
    """The gyro's rates over ``[lo, hi)`` less their mean, integrated (rad, gyro axes)."""
    dt = np.diff(t[lo:hi], prepend=t[lo])
    return np.cumsum((w[lo:hi] - w[lo:hi].mean(axis=0)) * dt[:, None], axis=0)


def _gyro_path_noise(t, lo: int, hi: int, std_limit: float, cfg) -> float:
    """The random walk the gyro's noise allows its path over ``[lo, hi)``: ``z std dt √n``."""
    return cfg.floor_spreads * std_limit * float(np.median(np.diff(t[lo:hi]))) * math.sqrt(hi - lo)


def _passes(value, limit) -> NDArray:
    return ~(value > limit)  # NaN (undecided) passes


def _checked(omega_b: ArrayLike, t_s: ArrayLike, accel_b: ArrayLike | None, truth=None):
    w = np.asarray(omega_b, dtype=float)
    t = np.asarray(t_s, dtype=float)
    if w.ndim != 2 or w.shape[1] != 3 or len(t) != len(w):
        raise InputError(f"Expected omega_b (N, 3) and t_s (N,), got {w.shape} and {t.shape}")
    acc = None if accel_b is None else np.asarray(accel_b, dtype=float)
    if acc is not None and acc.shape != w.shape:
        raise InputError(f"Expected accel_b of shape {w.shape}, got {acc.shape}")
    q = None if truth is None else np.asarray(truth, dtype=float)
    if q is not None and q.shape != (len(w), 4):
        raise InputError(f"Expected truth_q_w_b of shape {(len(w), 4)}, got {q.shape}")
    return w, t, acc, q


def bias_span(a: int, b: int, n: int, m: int) -> tuple[int, int]:
    """The samples ``[lo, hi)`` of rest ``[a, b)`` (of ``n``) whose mean is its bias.

    One window ``m`` is left out next to motion (not at the ends of the log); when less than a
    window remains, the middle half.
    """
    lo = a + m if a > 0 else a
    hi = b - m if b < n else b
    if hi - lo < m:
        lo, hi = a + (b - a) // 4, b - (b - a) // 4
    return lo, hi


def _still(conds) -> NDArray:
    still = np.ones(len(conds[0][2]), dtype=bool)
    for _sig, _name, value, limit, _unit in conds:
        still &= _passes(value, limit)
    return still


def _evidence(conds, truth, grounded, p: int, q: int) -> tuple[str, ...]:
    """The signals that judged windows ``[p, q)``: all of them, or "(part)" of them.

    The landed state counts where it said landed and disarmed (``grounded``, per window).
    """
    out = list(dict.fromkeys(c[0] for c in conds if c[0] in ("gyro floor", "accelerometer")))
    for name, _n, value, _lim, _u in conds:  # the motion signals count where they decided
        if name in ("odometry twist", "position") and name not in out:
            decided = np.isfinite(value[p:q])
            out += [name] if decided.all() else [f"{name} (part)"] if decided.any() else []
    for name, decided in (
        ("landed state", None if grounded is None else grounded[p:q]),
        ("truth", None if truth is None else np.isfinite(truth[p:q])),
    ):
        if decided is not None:
            out += [name] if decided.all() else [f"{name} (part)"] if decided.any() else []
    return tuple(out)


def rest_segments(
    omega_b: ArrayLike,
    t_s: ArrayLike,
    config: RestConfig | None = None,
    accel_b: ArrayLike | None = None,
    truth_q_w_b: ArrayLike | None = None,
    truth_noise: float = 0.0,
    r_t_g: ArrayLike | None = None,
    vehicle: tuple[ArrayLike, ArrayLike] | None = None,
    motion: Motion | None = None,
) -> tuple[list[RestSegment], str]:
    """The rest segments of a log, and one line on conflicting evidence ("" when none).

    Parameters
    ----------
    omega_b : array_like, shape (N, 3)
        Body rates, rad/s.
    t_s : array_like, shape (N,)
        Sample times, s, increasing.
    config : RestConfig, optional
    accel_b : array_like, shape (N, 3), optional
        Specific force on the same rows, m/s², finite.
    truth_q_w_b : array_like, shape (N, 4), optional
        Reference attitude on the same rows (NaN rows where it has none).
    truth_noise : float
        The truth's angle noise per sample, rad (:func:`truth_noise_rad`).
    r_t_g : array_like, shape (3, 3), optional
        Rotation from the gyro's axes to the truth's body axes (default identity).
    vehicle : (landed, armed), optional
        The autopilot's state on the same rows, int (N,) each: 1 true, 0 false, -1 unknown
        (:meth:`imu_dcm.logio.types.VehicleState.at`).
    motion : Motion, optional
        The truth's position and odometry twist on the same rows.
    """
    cfg = config or RestConfig()
    w, t, acc, q = _checked(omega_b, t_s, accel_b, truth_q_w_b)
    n, m = len(w), window_samples(t, cfg.min_duration_s)
    if n < m:
        return [], ""
    rg = None if r_t_g is None else np.asarray(r_t_g, float)
    sig = _Signals(acc, q, truth_noise, rg, checked_vehicle(vehicle, n), motion)
    conds, std_limit, truth = _conditions(w, t, m, cfg, sig)
    grounded = None if sig.vehicle is None else vehicle_windows(sig.vehicle, m)[1]
    segs, doubts = [], []
    for p, q_ in _touching(runs(_still(conds)), m):
        a, b = p, q_ - 1 + m
        lo, hi = bias_span(a, b, n, m)
        doubt = _segment_doubt(w, t, lo, hi, m, std_limit, cfg, sig)
        if doubt:
            doubts.append(f"{t[a]:.2f}-{t[b - 1]:.2f} s ({doubt})")
            continue
        if segs:  # a disturbance that moves nothing: the rest before goes on
            a0, p0 = segs[-1][0], segs[-1][2]
            lo0, hi0 = bias_span(a0, b, n, m)
            swing = float(row_norm(_gyro_path(w, t, lo0, hi0)).max())
            if (
                swing <= _gyro_path_noise(t, lo0, hi0, std_limit, cfg)
                and not airborne_between(sig.vehicle, a0, b)
                and not _segment_doubt(w, t, lo0, hi0, m, std_limit, cfg, sig)
            ):
                segs[-1] = (a0, b, p0, q_)
                continue
        segs.append((a, b, p, q_))
    out = []
    for a, b, p, q_ in segs:
        lo, hi = bias_span(a, b, n, m)
        bias = tuple(w[lo:hi].mean(axis=0).tolist())
        evidence = _evidence(conds, truth, grounded, p, q_)
        out.append(RestSegment(a, b, float(t[a]), float(t[b - 1]), bias, lo, hi, evidence))
    return out, _conflict(conds, doubts)


def _touching(found: list[tuple[int, int]], m: int) -> list[tuple[int, int]]:
    """Runs of still windows merged where the samples they cover touch (a gap under ``m``)."""
    out: list[tuple[int, int]] = []
    for p, q in found:
        if out and p <= out[-1][1] - 1 + m:
            out[-1] = (out[-1][0], q)
        else:
            out.append((p, q))
    return out


def _conflict(conds, doubts: list[str]) -> str:
    """One line for the stretches the windows call still that are not rests ("" for none)."""
    if not doubts:
        return ""
    signals = "the gyro and the accelerometer" if conds[1][0] == "accelerometer" else "the gyro"
    more = f" and {len(doubts) - 3} more" if len(doubts) > 3 else ""
    return (
        f"rest evidence conflicts: {signals} call {len(doubts)} stretch"
        f"{'es' if len(doubts) != 1 else ''} still that are not rest: "
        + "; ".join(doubts[:3])
        + more
    )


def detect_rest(
    omega_b: ArrayLike,
    t_s: ArrayLike,
    config: RestConfig | None = None,
    accel_b: ArrayLike | None = None,
) -> NDArray:
    """Boolean mask (N,) of the samples a still window covers (the module docstring's rule).

    Parameters
    ----------
    omega_b : array_like, shape (N, 3)
        Body rates, rad/s.
    t_s : array_like, shape (N,)
        Sample times, s, increasing.
    config : RestConfig, optional
    accel_b : array_like, shape (N, 3), optional
        Specific force on the same rows, m/s², finite; confirms stillness when given.
    """
    cfg = config or RestConfig()
    w, t, acc, _q = _checked(omega_b, t_s, accel_b)
    n, win = len(w), window_samples(t, cfg.min_duration_s)
    rest = np.zeros(n, dtype=bool)
    if n < win:
        return rest
    starts = np.flatnonzero(_still(_conditions(w, t, win, cfg, _Signals(acc))[0]))
    cover = np.zeros(n + 1, dtype=np.int64)  # spread each still start over its window
    np.add.at(cover, starts, 1)
    np.add.at(cover, starts + win, -1)
    rest[:] = np.cumsum(cover[:-1]) > 0
    return rest


def explain_no_rest(
    omega_b: ArrayLike,
    t_s: ArrayLike,
    config: RestConfig | None = None,
    accel_b: ArrayLike | None = None,
    truth_q_w_b: ArrayLike | None = None,
    truth_noise: float = 0.0,
    vehicle: tuple[ArrayLike, ArrayLike] | None = None,
    motion: Motion | None = None,
) -> str:
    """Why no window passed: the conditions that failed in the window closest to passing.

    The closest window is the one whose worst condition (value over limit) is smallest. Returns
    one clause, e.g. ``"the stillest 0.50 s, at 12.30 s, has rate std 0.015 rad/s > 0.01 (1.5x)"``.
    """
    cfg = config or RestConfig()
    w, t, acc, q = _checked(omega_b, t_s, accel_b, truth_q_w_b)
    win = window_samples(t, cfg.min_duration_s)
    if len(w) < win:
        return f"the log ({t[-1] - t[0]:.2f} s) is shorter than a {cfg.min_duration_s:.2f} s window"
    sig = _Signals(acc, q, truth_noise, None, checked_vehicle(vehicle, len(w)), motion)
    conds = _conditions(w, t, win, cfg, sig)[0]
    with np.errstate(invalid="ignore", divide="ignore"):
        ratios = [np.nan_to_num(v / np.broadcast_to(lim, v.shape)) for _s, _n, v, lim, _u in conds]
    worst = np.max(ratios, axis=0)
    i = int(np.argmin(worst))
    if worst[i] <= 1.0:
        return "every stretch the windows call still was found not to be rest"
    failed = [
        f"the vehicle airborne on {value[i]:.0%} of it (landed state)"
        if sig_name == "landed state"
        else f"{name} {value[i]:.4g} {unit} > {np.broadcast_to(limit, value.shape)[i]:.4g} "
        f"({ratio[i]:.1f}x)"
        for (sig_name, name, value, limit, unit), ratio in zip(conds, ratios, strict=True)
        if ratio[i] > 1.0
    ]
    return f"the stillest {cfg.min_duration_s:.2f} s, at {t[i] - t[0]:.2f} s, has " + ", ".join(
        failed
    )


class CausalRestBias:
    """The rest rule of :func:`rest_segments`, run causally as samples arrive (live).

    A live gyro stream carries no accelerometer or truth, so the gyro judges alone: the noise
    floor is the stillest window seen so far (offline: of the whole log), and the mean rate
    stays under ``max_rate_rad_s``. The window ending at the newest sample ``k`` is judged
    when ``k`` arrives. While a segment ``[a, ...)`` lasts, the bias is the mean over
    ``[lo, k + 1 - m)`` (``lo`` from :func:`bias_span`): one window behind the newest sample.
    When motion starts, the last still window ends at ``b - 1``, and the segment's bias becomes
    :func:`bias_span`'s for ``[a, b)`` (its first ``3 m`` samples are kept for the middle half
    of a short rest), the value :func:`rest_segments` gives it under the same floor. The bias
    applied to a sample is the estimate available when it arrives. :meth:`update_many` applies
    the rule to a batch as arrays and returns, for each sample, what :meth:`update` would have
    returned (to rounding). The window length comes from the median of the first ``probe``
    steps (offline: of the whole log).

    Parameters
    ----------
    config : RestConfig, optional
        The rest rule (default ``RestConfig()``).
    probe : int
        Steps used to fix the window length (median step).

    Attributes
    ----------
    bias_rad_s : tuple of 3 floats — current estimate, body axes, rad/s (zeros before any rest).
    segments : list of RestSegment — each finished segment (``lo``/``hi`` as in replay).
    updates : int — how many times the estimate changed.
    """

    def __init__(self, config: RestConfig | None = None, probe: int = 64) -> None:
        self.config = config or RestConfig()
        self.probe = probe
        self.bias_rad_s = (0.0, 0.0, 0.0)
        self.segments: list[RestSegment] = []
        self.updates = 0
        self.at_rest = False
        self.win = 0
        self._floor_var = math.inf  # the stillest window so far (variance, largest axis)
        self._min_steps = np.full(3, np.inf)  # the smallest step of each axis so far
        self._probe_w: list[NDArray] = []  # samples before the window length is known
        self._probe_t: list[NDArray] = []
        self._tail_w = np.zeros((0, 3))  # the last win samples
        self._tail_t = np.zeros(0)
        self._k = -1  # index of the newest sample
        self._seg_start = -1  # a, or -1 when not in a segment
        self._seg_t0 = 0.0
        self._seg_end = 0  # b - 1 of the open segment so far
        self._seg_end_t = 0.0
        self._head = np.zeros((0, 3))  # the open segment's first 3 win samples
        self._lo = 0  # the segment's bias averages the samples [lo, acc_hi)
        self._acc_hi = 0
        self._acc = np.zeros(3)

    def update(self, w: tuple[float, float, float], t_s: float) -> tuple[float, float, float]:
        """Add one sample (rad/s, body axes; stamp s); return the bias to subtract from it."""
        self.update_many(np.array([w], dtype=float), np.array([t_s], dtype=float))
        return self.bias_rad_s

    def update_many(self, omega_b: NDArray, t_s: NDArray) -> NDArray:
        """Add samples in order; return the bias to subtract from each, as :meth:`update` would.

        Parameters
        ----------
        omega_b : float64 (n, 3) — body rates, rad/s.
        t_s : float64 (n,) — their stamps, s, increasing.

        Returns
        -------
        float64 (n, 3) — row ``j``: the estimate available once sample ``j`` has arrived.
        """
        w = np.asarray(omega_b, dtype=float).reshape(-1, 3)
        t = np.asarray(t_s, dtype=float).reshape(-1)
        if self.win:
            return self._steps(w, t)
        # the window length needs the median of the first `probe` steps
        self._probe_w.append(w)
        self._probe_t.append(t)
        seen = sum(len(x) for x in self._probe_t)
        if seen < self.probe:
            return np.tile(self.bias_rad_s, (len(w), 1))
        pw, pt = np.concatenate(self._probe_w), np.concatenate(self._probe_t)
        self._probe_w, self._probe_t = [], []
        p = self.probe
        steps = np.diff(pt[:p])
        dt = float(np.sort(steps)[len(steps) // 2]) if len(steps) else 1.0
        self.win = max(2, math.ceil(self.config.min_duration_s / dt))
        before = np.tile(self.bias_rad_s, (p - 1 - (seen - len(w)), 1))  # this call's, held
        out = self._steps(pw, pt)
        return np.concatenate([before, out[p - 1 :]])[-len(w) :]

    def _still(self, X: NDArray, T: NDArray, rows: NDArray) -> NDArray:
        """The rule for the windows starting at ``rows`` of ``X``, the floor as it was then."""
        m, cfg = self.win, self.config
        mean, var = windowed_mean_var(X, m)
        mean, var = mean[rows], var[rows]
        self._min_steps = np.minimum(self._min_steps, min_steps(X))
        floor = np.minimum.accumulate(np.minimum(row_max(var), self._floor_var))
        floor = np.maximum(floor, step_var(self._min_steps))
        if len(floor):
            self._floor_var = float(floor[-1])
        limit = _std_limit(floor, m, cfg)
        return (np.sqrt(row_max(var)) <= limit) & (row_norm(mean) <= cfg.max_rate_rad_s)

    def _steps(self, w: NDArray, t: NDArray) -> NDArray:
        """The rule over a batch: windows ending at each sample, then the segments' runs."""
        n, m = len(w), self.win
        X = np.concatenate([self._tail_w, w])
        T = np.concatenate([self._tail_t, t])
        base = self._k + 1 - len(self._tail_w)  # index of X[0]
        k0 = self._k + 1  # index of w[0]
        still = np.zeros(n, dtype=bool)
        first_full = max(0, m - 1 - k0)  # the first sample whose window is full
        if first_full < n:
            rows = np.arange(first_full, n) + (k0 - base) - m + 1  # window ending at sample j
            still[first_full:] = self._still(X, T, rows)
        out = np.full((n, 3), np.nan)
        before = self.bias_rad_s
        for p, q in runs(still):
            if self._seg_start >= 0 and k0 + p - m + 1 > self._seg_end + 1:
                self._close_segment(out, k0)  # motion of a window or more since its end
            self._run(X, T, base, k0, p, q, out)
        self.at_rest = bool(n and still[-1])
        if self._seg_start >= 0 and k0 + n - 1 >= self._seg_end + m:
            self._close_segment(out, k0)  # no window that can still come touches it
        # each sample keeps the newest estimate at its arrival (forward fill)
        have = ~np.isnan(out[:, 0])
        if have.any():
            last = np.maximum.accumulate(np.where(have, np.arange(n), -1))
            filled = np.where((last >= 0)[:, None], out[np.maximum(last, 0)], before)
        else:
            filled = np.tile(before, (n, 1))
        self._k += n
        self._tail_w, self._tail_t = X[-m:], T[-m:]
        return filled

    def _run(self, X, T, base: int, k0: int, p: int, q: int, out: NDArray) -> None:
        """Still samples ``p..q-1`` of the batch: open (or go on with) the segment and write the
        bias after each sample into ``out`` (NaN while the segment has no sample yet)."""
        m = self.win
        if self._seg_start < 0:
            a = k0 + p - m + 1  # a segment starts with the first sample of its first still window
            self._seg_start, self._seg_t0 = a, float(T[a - base])
            self._lo = a if a == 0 else a + m
            self._acc_hi, self._acc = self._lo, np.zeros(3)
            self._head = X[a - base : a - base + 3 * m].copy()
        elif len(self._head) < 3 * m:
            have = self._seg_start + len(self._head) - base
            self._head = np.concatenate([self._head, X[have : have + 3 * m - len(self._head)]])
        hi = k0 + np.arange(p, q) + 1 - m  # sample k's estimate: the mean over [lo, k + 1 - m)
        grow = hi > self._acc_hi  # a suffix of the run: hi grows by one per sample
        if self._acc_hi > self._lo:  # samples whose window adds nothing keep the estimate
            keep = np.flatnonzero(~grow) + p
            out[keep] = self._acc / (self._acc_hi - self._lo)
            self.updates += len(keep)
        if grow.any():
            start = self._acc_hi - base
            partial = np.cumsum(X[start : hi[-1] - base], axis=0)
            sums = self._acc + partial[hi[grow] - base - start - 1]
            out[np.flatnonzero(grow) + p] = sums / (hi[grow] - self._lo)[:, None]
            self._acc, self._acc_hi = sums[-1], int(hi[-1])
            self.updates += len(sums)
        if not np.isnan(out[q - 1, 0]):
            self.bias_rad_s = tuple(out[q - 1].tolist())
        self._seg_end = k0 + q - 1
        self._seg_end_t = float(T[k0 + q - 1 - base])

    def _close_segment(self, out: NDArray | None = None, k0: int = 0, at_end: bool = False) -> None:
        """End the open segment ``[a, b)``; its final bias holds from sample ``b - 1 + m`` (row
        of ``out`` for a batch starting at sample ``k0``). ``at_end``: the stream ended in it."""
        a, b, m = self._seg_start, self._seg_end + 1, self.win
        lo, hi = bias_span(a, b, b + (0 if at_end else 1), m)
        if at_end and hi > self._acc_hi:  # the last window's samples: the tail
            self._acc = self._acc + self._tail_w[len(self._tail_w) - (hi - self._acc_hi) :].sum(0)
            self._acc_hi = hi
        if lo != self._lo or hi != self._acc_hi:  # a short rest: its middle half
            self.bias_rad_s = tuple(self._head[lo - a : hi - a].mean(axis=0).tolist())
        elif hi > lo:
            self.bias_rad_s = tuple((self._acc / (hi - lo)).tolist())
        self.segments.append(
            RestSegment(
                a, b, self._seg_t0, self._seg_end_t, self.bias_rad_s, lo, hi, ("gyro floor",)
            )
        )
        self._seg_start = -1
        j = b - 1 + m - k0
        if out is not None and 0 <= j < len(out):
            out[j] = self.bias_rad_s

    def finish(self) -> None:
        """Close an open segment (at stop): the stream ended in it."""
        if self._seg_start >= 0:
            self._close_segment(at_end=True)
            self.at_rest = False

"""The rest rule: when a window is still, which windows make a rest, which samples its bias.

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
  mean rate ``|omega_T|``, is at most ``max(n_T, |mean omega| / 2)``: nearer to no rotation than
  to the gyro's mean rate. ``n_T`` is the truth's own noise, measured from the second
  differences of its rotation sample to sample
  (:func:`~imu_dcm.gyro.rest_evidence.truth_noise_rad`),
  as a rate over the window (``z`` spreads). Where the truth rotates as the gyro does, the
  gyro's mean is motion, not bias.
* **landed state** (where the log has the autopilot's landed and armed state, per sample,
  :attr:`imu_dcm.logio.LogData.vehicle_state`): a window with any sample where the vehicle is
  airborne (not landed, and not disarmed) is not rest, whatever the gyro and the accelerometer
  say (a hover holds both still); a window landed and disarmed throughout supports rest. The
  autopilot's own land detector judges this from its thrust, climb rate and rotation, which this
  gyro alone cannot see.
* **odometry twist** (where the truth is odometry with ``twist.twist.angular``, on the gyro
  rows, :class:`~imu_dcm.gyro.rest_evidence.Motion`): the body rotates where the twist's mean
  ``|omega|`` over the window is above its noise, ``z sigma_w / sqrt(k)`` (``sigma_w`` from the
  twist's first differences, at least its quantisation; ``k`` twist samples per window): that
  window is not rest, and its gyro mean is motion, not bias (a slow turn while driving). A twist
  within its noise supports rest.
* **position** (where the truth carries one, :class:`~imu_dcm.gyro.rest_evidence.Motion`): a window
  whose position moves by more than ``z sqrt(2) sigma_p`` from its first sample to its last
  (``sigma_p`` from the position's second differences, as for the truth's angle) is not rest. A
  body that moves is not still: translating straight does not rotate it, but the mean of a gyro
  on a moving vehicle holds its vibration and its small steering turns, which no window's spread
  shows; the zero-rate assumption behind the bias is the vehicle's standstill.
* **mean rate**: where the truth shows no rotation there is no bound on the mean (it is the
  bias); where only the accelerometer or the landed and disarmed state confirms, it may be up
  to ``max_bias_rad_s`` (10 °/s, the largest biases of uncalibrated MEMS: an accelerometer
  cannot tell a constant turn from a bias); with the gyro alone, nothing tells a smooth
  constant turn from a bias, so the mean must stay under ``max_rate_rad_s`` (2 °/s) and the
  rest is *unconfirmed*.

A run of consecutive still windows (starts ``[p, q)``) is one rest segment, samples
``[p, q - 1 + m)``; runs whose samples touch are one (:func:`touching`). Its bias is the mean
rate over it, leaving out one window next to motion (windows that straddle a slow start of
motion still pass), or its middle half when that leaves less than a window (:func:`bias_span`).

The window test (:func:`window_conditions`, :func:`still_windows`) and the trimming are written
once here. Offline, :func:`imu_dcm.gyro.rest.rest_segments` looks both ways: the floor is the
stillest window of the whole log, and the truth judges each whole rest. Live,
:class:`imu_dcm.gyro.rest_causal.CausalRestBias` runs the same test looking back only: the floor is
the stillest window so far (:func:`noise_floor_var`).

Conventions: ``omega_b`` (N, 3) body rate relative to the world in body axes, rad/s; ``t_s``
(N,) seconds, increasing; ``q_w_b`` Hamilton ``[x, y, z, w]``, body to world.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from imu_dcm.arrays import median_diff
from imu_dcm.gyro.rest_evidence import Signals, motion_windows, truth_rates, vehicle_windows
from imu_dcm.gyro.windows import min_steps, step_var, window_norms

#: Standard gravity, m/s² (a still accelerometer reads about this much).
GRAVITY_M_S2 = 9.80665

__all__ = [
    "GRAVITY_M_S2",
    "RestConfig",
    "RestSegment",
    "bias_span",
    "evidence_of",
    "floor_factor",
    "noise_floor_var",
    "longest_run",
    "runs",
    "std_limit",
    "still_windows",
    "touches",
    "touching",
    "window_conditions",
    "window_samples",
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
    """Samples in a window of ``duration_s`` seconds at the median step (at least 2).

    A window of a whole number of steps is that many samples, whatever the rounding of the
    stamps' differences (a relative 1e-9 of slack: 0.5 s at 5 ms is 100 samples, not 101).
    """
    dt = median_diff(t_s) if len(t_s) > 1 else 1.0
    return max(2, math.ceil(duration_s / dt * (1.0 - 1e-9)))


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


def floor_factor(m: int, spreads: float = 4.0) -> float:
    """How far above the floor a still window's spread may lie: ``exp(2 z / sqrt(2 (m - 1)))``.

    ``m`` samples a window (at least 2), ``z`` = ``spreads`` (see the module docstring).
    """
    return math.exp(2.0 * spreads / math.sqrt(2.0 * max(m - 1, 1)))


def noise_floor_var(
    max_var: NDArray, steps: NDArray, before: float = math.inf, causal: bool = False
):
    """A sensor's noise floor (variance, its unit²): its stillest window's, at least step²/12.

    Parameters
    ----------
    max_var : ndarray, shape (k,)
        The largest per-axis variance of each window, in time order
        (:func:`imu_dcm.gyro.windows.window_norms`).
    steps : ndarray, shape (3,)
        The smallest output step of each axis (:func:`imu_dcm.gyro.windows.min_steps`).
    before : float
        The floor of the windows before these (causal only; inf when none).
    causal : bool
        False (offline): one floor, the stillest of all ``k`` windows. True (live): the floor
        each window is judged against, the stillest of it and those before it, shape (k,).
    """
    v = max_var
    floor = np.minimum.accumulate(np.minimum(v, before)) if causal else v.min()
    return np.maximum(floor, step_var(steps))


def std_limit(floor_var, m: int, cfg: RestConfig):
    """The gyro's bound on a window's spread, rad/s, from its floor (variance, rad²/s²)."""
    if cfg.max_std_rad_s is not None:
        return cfg.max_std_rad_s
    return np.sqrt(floor_var) * floor_factor(m, cfg.floor_spreads)


def window_conditions(
    rate, max_var, floor_var, t, m: int, cfg: RestConfig, sig: Signals, accel_floor=None,
    truth_rate=None,
):  # fmt: skip
    """Each condition of the rule over windows of ``m`` samples (the module docstring).

    Parameters
    ----------
    rate, max_var : ndarray, shape (k,)
        Each window's ``|mean|`` of the gyro (rad/s) and its largest per-axis variance
        (rad²/s²) (:func:`imu_dcm.gyro.windows.window_norms`).
    floor_var : float or ndarray (k,)
        The gyro's noise floor each window is judged against (:func:`noise_floor_var`).
    t : ndarray, shape (N,)
        Sample times, s, on the rows of ``sig``'s signals (only read when it has some).
    m : int
        Window length, samples.
    cfg : RestConfig
    sig : Signals
        The other signals on the same ``k + m - 1`` rows (none: the gyro judges alone).
    accel_floor : callable, optional
        Given the accelerometer's largest per-axis window variances (k,), its noise floor each
        window is judged against (m²/s⁴, scalar or (k,)). None (offline): the stillest window
        of these rows (:func:`noise_floor_var`); live passes the causal floor.
    truth_rate : ndarray, shape (k,), optional
        :func:`~imu_dcm.gyro.rest_evidence.truth_rates` of ``sig``'s truth, when the caller
        has it already (computed here otherwise).

    Returns ``(conds, limit, truth)``: ``conds`` a list of (signal, name, value, limit, unit),
    a window passing a condition when its value is at most the limit (NaN: undecided, passes);
    ``limit`` the gyro's bound on a window's spread, rad/s; ``truth`` each window's
    ``|omega_T|`` (rad/s, NaN without truth) or None.
    """
    z = floor_factor(m, cfg.floor_spreads)
    spread = np.sqrt(max_var)
    limit = std_limit(floor_var, m, cfg)
    conds = [("gyro floor", "rate std", spread, limit, "rad/s")]
    mean_limit = np.full(len(rate), cfg.max_rate_rad_s)
    if sig.accel_b is not None:
        a_norm, a_var = window_norms(sig.accel_b, m)
        a_spread = np.sqrt(a_var)
        if accel_floor is None:
            a_floor = np.sqrt(noise_floor_var(a_var, min_steps(sig.accel_b)))
        else:
            a_floor = np.sqrt(accel_floor(a_var))
        a_limit = cfg.max_accel_std_m_s2 if cfg.max_accel_std_m_s2 is not None else a_floor * z
        g_err = np.abs(a_norm - GRAVITY_M_S2)
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
        truth = truth_rates(sig.truth_q_w_b, t, m) if truth_rate is None else truth_rate
        n_t = cfg.floor_spreads * math.sqrt(6.0) * sig.truth_noise_rad / (t[m - 1] - t[0])
        mean_limit[truth <= np.maximum(n_t, 0.5 * rate)] = np.inf
    name = "mean |omega|" if sig.accel_b is not None else "mean |omega| (no accelerometer)"
    conds.append(("gyro floor", name, rate, mean_limit, "rad/s"))
    return conds, limit, truth


def still_windows(conds) -> NDArray:
    """Whether each window passes every condition (NaN, undecided, passes)."""
    still = np.ones(len(conds[0][2]), dtype=bool)
    for _sig, _name, value, limit, _unit in conds:
        still &= ~(value > limit)
    return still


def touches(stop: int, start: int) -> bool:
    """Whether a still window starting at sample ``start`` joins the rest ``[a, stop)`` before
    it: the samples they cover touch (offline and live join runs by this)."""
    return start <= stop


def touching(found: list[tuple[int, int]], m: int) -> list[tuple[int, int]]:
    """Runs of still windows merged where the samples they cover touch (:func:`touches`)."""
    out: list[tuple[int, int]] = []
    for p, q in found:
        if out and touches(out[-1][1] - 1 + m, p):
            out[-1] = (out[-1][0], q)
        else:
            out.append((p, q))
    return out


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


def evidence_of(conds, truth, grounded, p: int, q: int) -> tuple[str, ...]:
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

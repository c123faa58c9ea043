"""Rest offline: the rest segments of a whole gyro log, the line on conflicting evidence, and why
no rest was found.

The rule is :mod:`imu_dcm.gyro.rest_rule`'s (its docstring says where each bound comes from);
offline
it looks both ways. The gyro's noise floor is the stillest window of the whole log
(:func:`~imu_dcm.gyro.rest_rule.noise_floor_var`), and the truth, where the log has one, judges each
whole rest (:func:`~imu_dcm.gyro.rest_evidence.segment_doubt`): a stretch the windows call still
whose truth turns or sways as the gyro does is not rest. A disturbance that moves nothing (the
gyro's path over the joined rest within its noise, no airborne sample, no doubt from the truth)
joins the rests either side of it. :func:`rest_segments` is the rule over a whole log, and
:class:`imu_dcm.gyro.rest_causal.CausalRestBias` runs it as samples arrive (live).
:func:`detect_rest` marks the samples a still window covers (the pre-filter's rest), and
:func:`explain_no_rest` names the condition that failed where no window passed.
:func:`judge_rest` gives the segments, the conflict line and that reason from one pass over the
windows (a replay's bias estimate needs all three).

Conventions: ``omega_b`` (N, 3) body rate relative to the world in body axes, rad/s; ``t_s``
(N,) seconds, increasing; ``q_w_b`` Hamilton ``[x, y, z, w]``, body to world.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imu_dcm.arrays import BLOCK_ROWS, median_diff, row_norm
from imu_dcm.errors import InputError
from imu_dcm.gyro.rest_evidence import (
    Motion,
    Signals,
    airborne_between,
    checked_vehicle,
    gyro_path,
    gyro_path_noise,
    segment_doubt,
    truth_rates,
    vehicle_windows,
)
from imu_dcm.gyro.rest_rule import (
    RestConfig,
    RestSegment,
    bias_span,
    evidence_of,
    noise_floor_var,
    runs,
    still_windows,
    touching,
    window_conditions,
    window_samples,
)
from imu_dcm.gyro.windows import min_steps, window_norms

__all__ = [
    "GyroWindows",
    "RestFinding",
    "detect_rest",
    "explain_no_rest",
    "judge_rest",
    "quietest_std",
    "rest_segments",
]


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
    m = max(3, min(len(t_s), round(window_s / median_diff(t_s))))
    return float(np.sqrt(window_norms(omega_b, m)[1].min()))


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


class GyroWindows:
    """The gyro's windows of the rest rule, made once for rates judged more than once (a replay
    judges rest from the gyro alone, then again with its truth): each window's ``|mean|`` and
    largest variance (:func:`~imu_dcm.gyro.windows.window_norms`) and the floor they give, for
    the rates and window last asked for."""

    def __init__(self) -> None:
        self._for: tuple | None = None
        self._value: tuple | None = None

    def of(self, w: NDArray, m: int) -> tuple[NDArray, NDArray, float]:
        """``(rate, max_var, floor_var)`` of the windows of ``m`` rows of ``w``."""
        if self._for is None or self._for[0] is not w or self._for[1] != m:
            self._value = None  # the old windows go before the new ones come
            rate, max_var = window_norms(w, m)
            self._value = (rate, max_var, noise_floor_var(max_var, min_steps(w)))
            self._for = (w, m)
        return self._value


def _conditions(w, t, m: int, cfg: RestConfig, sig: Signals, windows: GyroWindows | None = None):
    """The rule's conditions over every window of the whole log, judged against one floor: the
    stillest window of the whole log (offline looks both ways)."""
    # the truth's window rates first: their temporaries come and go before the gyro's windows
    truth = None if sig.truth_q_w_b is None else truth_rates(sig.truth_q_w_b, t, m)
    rate, max_var, floor = (windows or GyroWindows()).of(w, m)
    return window_conditions(rate, max_var, floor, t, m, cfg, sig, truth_rate=truth)


def rest_segments(*args, **kwargs) -> tuple[list[RestSegment], str]:
    """The rest segments of a log, and one line on conflicting evidence ("" when none):
    :func:`judge_rest` (the same arguments) without the reason for finding none."""
    found = judge_rest(*args, **kwargs)
    return found.segments, found.conflict


class RestFinding(NamedTuple):
    """What :func:`judge_rest` found: the rest segments, one line on conflicting evidence ("" for
    none) and, when no window passed, why ("" otherwise)."""

    segments: list[RestSegment]
    conflict: str
    why: str


def judge_rest(
    omega_b: ArrayLike,
    t_s: ArrayLike,
    config: RestConfig | None = None,
    accel_b: ArrayLike | None = None,
    truth_q_w_b: ArrayLike | None = None,
    truth_noise: float = 0.0,
    r_t_g: ArrayLike | None = None,
    vehicle: tuple[ArrayLike, ArrayLike] | None = None,
    motion: Motion | None = None,
    windows: GyroWindows | None = None,
) -> RestFinding:
    """The rest segments of a log, one line on conflicting evidence ("" when none), and, when
    no window passed, why (:func:`explain_no_rest`'s clause, from the same windows).

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
        The truth's angle noise per sample, rad
        (:func:`~imu_dcm.gyro.rest_evidence.truth_noise_rad`).
    r_t_g : array_like, shape (3, 3), optional
        Rotation from the gyro's axes to the truth's body axes (default identity).
    vehicle : (landed, armed), optional
        The autopilot's state on the same rows, int (N,) each: 1 true, 0 false, -1 unknown
        (:meth:`imu_dcm.logio.types.VehicleState.at`).
    motion : Motion, optional
        The truth's position and odometry twist on the same rows.
    windows : GyroWindows, optional
        The gyro's windows kept from an earlier judgement of the same rates (made here, and
        kept in it, when it has none).
    """
    cfg = config or RestConfig()
    w, t, acc, q = _checked(omega_b, t_s, accel_b, truth_q_w_b)
    n, m = len(w), window_samples(t, cfg.min_duration_s)
    if n < m:
        return RestFinding([], "", _too_short(t, cfg))
    rg = None if r_t_g is None else np.asarray(r_t_g, float)
    sig = Signals(acc, q, truth_noise, rg, checked_vehicle(vehicle, n), motion)
    conds, std_limit, truth = _conditions(w, t, m, cfg, sig, windows)
    still = still_windows(conds)
    if not still.any():
        return RestFinding([], "", _explain(conds, t, cfg))
    grounded = None if sig.vehicle is None else vehicle_windows(sig.vehicle, m)[1]
    segs, doubts = [], []
    for p, q_ in touching(runs(still), m):
        a, b = p, q_ - 1 + m
        lo, hi = bias_span(a, b, n, m)
        doubt = segment_doubt(w, t, lo, hi, m, std_limit, cfg, sig)
        if doubt:
            doubts.append(f"{t[a]:.2f}-{t[b - 1]:.2f} s ({doubt})")
            continue
        if segs:  # a disturbance that moves nothing: the rest before goes on
            a0, p0 = segs[-1][0], segs[-1][2]
            lo0, hi0 = bias_span(a0, b, n, m)
            swing = float(row_norm(gyro_path(w, t, lo0, hi0)).max())
            if (
                swing <= gyro_path_noise(t, lo0, hi0, std_limit, cfg)
                and not airborne_between(sig.vehicle, a0, b)
                and not segment_doubt(w, t, lo0, hi0, m, std_limit, cfg, sig)
            ):
                segs[-1] = (a0, b, p0, q_)
                continue
        segs.append((a, b, p, q_))
    out = []
    for a, b, p, q_ in segs:
        lo, hi = bias_span(a, b, n, m)
        bias = tuple(w[lo:hi].mean(axis=0).tolist())
        evidence = evidence_of(conds, truth, grounded, p, q_)
        out.append(RestSegment(a, b, float(t[a]), float(t[b - 1]), bias, lo, hi, evidence))
    return RestFinding(out, _conflict(conds, doubts), "")


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
    starts = np.flatnonzero(still_windows(_conditions(w, t, win, cfg, Signals(acc))[0]))
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
        return _too_short(t, cfg)
    sig = Signals(acc, q, truth_noise, None, checked_vehicle(vehicle, len(w)), motion)
    return _explain(_conditions(w, t, win, cfg, sig)[0], t, cfg)


def _too_short(t: NDArray, cfg: RestConfig) -> str:
    return f"the log ({t[-1] - t[0]:.2f} s) is shorter than a {cfg.min_duration_s:.2f} s window"


def _explain(conds, t: NDArray, cfg: RestConfig) -> str:
    """Why no window passed: the conditions that failed in the window closest to passing (the
    one whose worst value over limit is smallest, the first of equals), a block of windows at
    a time."""
    k = len(conds[0][2])
    best, i, ratios = np.inf, 0, None
    for a in range(0, k, BLOCK_ROWS):
        r = _ratios(conds, slice(a, a + BLOCK_ROWS))
        worst = np.max(r, axis=0)
        j = int(np.argmin(worst))
        if worst[j] < best:
            best, i, ratios = float(worst[j]), a + j, r[:, j]
    if best <= 1.0:
        return "every stretch the windows call still was found not to be rest"
    failed = [
        f"the vehicle airborne on {value[i]:.0%} of it (landed state)"
        if sig_name == "landed state"
        else f"{name} {value[i]:.4g} {unit} > {np.broadcast_to(limit, value.shape)[i]:.4g} "
        f"({ratio:.1f}x)"
        for (sig_name, name, value, limit, unit), ratio in zip(conds, ratios, strict=True)
        if ratio > 1.0
    ]
    return f"the stillest {cfg.min_duration_s:.2f} s, at {t[i] - t[0]:.2f} s, has " + ", ".join(
        failed
    )


def _ratios(conds, k: slice) -> NDArray:
    """Each condition's value over its limit in the windows ``k``, (conditions, windows); 0
    where undecided (NaN)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.array(
            [np.nan_to_num(v[k] / np.broadcast_to(lim, v.shape)[k]) for _s, _n, v, lim, _u in conds]
        )

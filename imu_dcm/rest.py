"""Rest detection: the still segments of a gyro log, and the windowed statistics behind them.

A gyro at rest measures its bias plus noise. Rest is stillness, judged over windows of
``min_duration_s`` (0.5 s):

* the rate is at its noise floor: every per-axis standard deviation below ``max_std_rad_s``;
* where the log has an accelerometer (``accel_b``, m/s²), it is still too: every per-axis
  standard deviation below ``max_accel_std_m_s2`` (vibration of smooth driving shows here,
  not in the gyro), and ``|mean a|`` within ``max_gravity_error_m_s2`` of g. Stillness is then
  confirmed, and the rate's mean (the bias) may be as large as ``max_bias_rad_s`` (several
  °/s: a EuRoC ADIS16448 sits at 4.6 °/s);
* without an accelerometer nothing tells a smooth constant turn from a bias, so the mean rate
  must stay below ``max_rate_rad_s`` (2 °/s, above most MEMS biases): such rest is
  *unconfirmed*, and a larger bias needs ``--bias x,y,z``.

A sample is at rest when a still window covers it; consecutive rest samples form a rest segment.
When none is found, :func:`explain_no_rest` names the condition that failed and by how much.
The bias estimate (:mod:`imu_dcm.replay.bias`), the pre-filter's noise estimate
(:mod:`imu_dcm.prefilter`) and the live command's causal bias (:class:`CausalRestBias`, the
rule without accelerometer, online) all start from here.

Conventions: ``omega_b`` (N, 3) body rate relative to the world in body axes, rad/s; ``t_s`` (N,)
seconds, increasing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imu_dcm.errors import InputError
from imu_dcm.so3 import median, row_max, row_norm

#: Standard gravity, m/s² (a still accelerometer reads about this much).
GRAVITY_M_S2 = 9.80665

__all__ = [
    "GRAVITY_M_S2",
    "CausalRestBias",
    "RestConfig",
    "detect_rest",
    "explain_no_rest",
    "longest_run",
    "quietest_std",
    "runs",
    "window_samples",
    "windowed_mean_var",
]


@dataclass(frozen=True)
class RestConfig:
    """Thresholds of the rest detector.

    Attributes
    ----------
    min_duration_s : shortest rest that counts, s (default 0.5).
    max_rate_rad_s : largest magnitude of the window-mean rate, rad/s (default 0.035 ≈ 2 °/s;
        above the largest MEMS biases seen, far below deliberate motion).
    max_std_rad_s : largest per-axis standard deviation in the window, rad/s (default 0.01 ≈
        0.6 °/s; 2–5x the noise of a consumer gyro at a few hundred Hz).
    max_bias_rad_s : largest window-mean rate magnitude when an accelerometer confirms the
        stillness, rad/s (default 0.175 = 10 °/s: the largest biases of uncalibrated MEMS).
    max_accel_std_m_s2 : largest per-axis accelerometer standard deviation in the window, m/s²
        (default 0.2 ≈ 0.02 g: 3x the noise of the BROAD accelerometers at rest; vibration of a
        driving vehicle is several times more).
    max_gravity_error_m_s2 : largest difference between ``|mean a|`` and g, m/s² (default 0.5
        ≈ 0.05 g: scale errors and biases of MEMS accelerometers).
    """

    min_duration_s: float = 0.5
    max_rate_rad_s: float = 0.035
    max_std_rad_s: float = 0.01
    max_bias_rad_s: float = 0.175
    max_accel_std_m_s2: float = 0.2
    max_gravity_error_m_s2: float = 0.5


def window_samples(t_s: NDArray, duration_s: float) -> int:
    """Samples in a window of ``duration_s`` seconds at the median step (at least 2)."""
    dt = median(np.diff(t_s)) if len(t_s) > 1 else 1.0
    return max(2, int(np.ceil(duration_s / dt)))


def windowed_mean_var(x: NDArray, m: int) -> tuple[NDArray, NDArray]:
    """Mean and (population) variance of every window of ``m`` consecutive rows.

    Parameters
    ----------
    x : ndarray, shape (N, k)
        Samples (any unit).
    m : int
        Window length in samples, ``1 <= m <= N``.

    Returns
    -------
    mean, var : ndarray, shape (N - m + 1, k)
        Row ``i`` describes the window of samples ``[i, i + m)`` (variance in the unit squared,
        clipped at 0 against cancellation in the running sums).
    """
    sums = np.empty((2, len(x) + 1) + x.shape[1:])  # running sums of x and x², in place
    sums[:, 0] = 0.0
    np.cumsum(x, axis=0, out=sums[0, 1:])
    np.cumsum(np.square(x), axis=0, out=sums[1, 1:])
    mean, var = sums[:, m:] - sums[:, :-m]
    mean /= m
    var /= m
    var -= mean * mean
    return mean, np.maximum(var, 0.0, out=var)


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


def _checked(omega_b: ArrayLike, t_s: ArrayLike, accel_b: ArrayLike | None):
    w = np.asarray(omega_b, dtype=float)
    t = np.asarray(t_s, dtype=float)
    if w.ndim != 2 or w.shape[1] != 3 or len(t) != len(w):
        raise InputError(f"Expected omega_b (N, 3) and t_s (N,), got {w.shape} and {t.shape}")
    acc = None if accel_b is None else np.asarray(accel_b, dtype=float)
    if acc is not None and acc.shape != w.shape:
        raise InputError(f"Expected accel_b of shape {w.shape}, got {acc.shape}")
    return w, t, acc


def _window_conditions(
    w: NDArray, acc: NDArray | None, win: int, cfg: RestConfig
) -> list[tuple[str, NDArray, float, str]]:
    """Each rest condition over every window of ``win`` samples: (name, value, limit, unit).

    A window passes a condition when its value is below the limit.
    """
    mean, var = windowed_mean_var(w, win)
    rate = row_norm(mean)
    conds = [("rate std", np.sqrt(row_max(var)), cfg.max_std_rad_s, "rad/s")]
    if acc is None:
        conds.append(("mean |omega| (no accelerometer)", rate, cfg.max_rate_rad_s, "rad/s"))
        return conds
    a_mean, a_var = windowed_mean_var(acc, win)
    conds += [
        ("mean |omega|", rate, cfg.max_bias_rad_s, "rad/s"),
        ("accel std", np.sqrt(row_max(a_var)), cfg.max_accel_std_m_s2, "m/s²"),
        (
            "| |a| - g |",
            np.abs(row_norm(a_mean) - GRAVITY_M_S2),
            cfg.max_gravity_error_m_s2,
            "m/s²",
        ),
    ]
    return conds


def detect_rest(
    omega_b: ArrayLike,
    t_s: ArrayLike,
    config: RestConfig | None = None,
    accel_b: ArrayLike | None = None,
) -> NDArray:
    """Boolean mask (N,) of samples at rest (see the module docstring for the rule).

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
    w, t, acc = _checked(omega_b, t_s, accel_b)
    n = len(w)
    win = window_samples(t, cfg.min_duration_s)
    rest = np.zeros(n, dtype=bool)
    if n < win:
        return rest
    still = np.ones(n - win + 1, dtype=bool)  # window starting at i: samples [i, i + win)
    for _name, value, limit, _unit in _window_conditions(w, acc, win, cfg):
        still &= value < limit
    # a sample is at rest when any still window covers it: spread each still start over win
    cover = np.zeros(n + 1, dtype=np.int64)
    starts = np.flatnonzero(still)
    np.add.at(cover, starts, 1)
    np.add.at(cover, starts + win, -1)
    rest[:] = np.cumsum(cover[:-1]) > 0
    return rest


def explain_no_rest(
    omega_b: ArrayLike,
    t_s: ArrayLike,
    config: RestConfig | None = None,
    accel_b: ArrayLike | None = None,
) -> str:
    """Why no window passed: the conditions that failed in the window closest to passing.

    The closest window is the one whose worst condition (value over limit) is smallest. Returns
    one clause, e.g. ``"the stillest 0.50 s, at 12.30 s, has rate std 0.015 rad/s > 0.01 (1.5x)"``.
    """
    cfg = config or RestConfig()
    w, t, acc = _checked(omega_b, t_s, accel_b)
    win = window_samples(t, cfg.min_duration_s)
    if len(w) < win:
        return f"the log ({t[-1] - t[0]:.2f} s) is shorter than a {cfg.min_duration_s:.2f} s window"
    conds = _window_conditions(w, acc, win, cfg)
    worst = np.max([value / limit for _n, value, limit, _u in conds], axis=0)
    i = int(np.argmin(worst))
    failed = [
        f"{name} {value[i]:.4g} {unit} > {limit:.4g} ({value[i] / limit:.1f}x)"
        for name, value, limit, unit in conds
        if value[i] >= limit
    ]
    return f"the stillest {cfg.min_duration_s:.2f} s, at {t[i] - t[0]:.2f} s, has " + ", ".join(
        failed
    )


class CausalRestBias:
    """Online rest detector and bias estimate: the causal twin of :func:`detect_rest`.

    It runs the rule without an accelerometer (a live gyro stream carries none): rate spread at
    the noise floor and mean rate under ``max_rate_rad_s``, the same thresholds as the batch rule
    given no ``accel_b`` (a test holds the two equal).

    The gyro bias from rest, estimated causally as samples arrive (replay's rule, online).

    Replay's rule (``imu_dcm.replay.bias``): a sample is at rest when a window of ``win`` samples
    (``min_duration_s`` over the step) covering it has a mean rate magnitude below
    ``max_rate_rad_s`` and every per-axis standard deviation below ``max_std_rad_s``; consecutive
    rest samples form a segment ``[a, b)`` whose bias is the mean over ``[a + win, b - win)``
    (``a`` itself at the start of the log), the middle half when that is shorter than a window.

    Online, the window ending at the newest sample ``k`` is tested when ``k`` arrives. While the
    segment lasts, the bias is the mean over ``[a + win, k + 1 - win)``: one window behind the
    newest sample. When motion starts, the last still window ends at ``b - 1``, so the last update
    covers exactly ``[a + win, b - win)``, replay's value for the segment. The bias applied to a
    sample is the estimate available when it arrives (causal; replay applies a segment's bias from
    its start). :meth:`update_many` applies the same rule to a batch as arrays (windows from
    :func:`windowed_mean_var`, the segment's running mean from cumulative sums) and returns,
    for each sample, what :meth:`update` would have returned (to rounding). The step ``dt`` is
    the median of the first ``probe`` steps (replay: of the whole log).

    Parameters
    ----------
    config : RestConfig, optional
        The rest rule (default ``RestConfig()``, as :func:`detect_rest`).
    probe : int
        Steps used to fix the window length (median step).

    Attributes
    ----------
    bias_rad_s : tuple of 3 floats — current estimate, body axes, rad/s (zeros before any rest).
    segments : list of dict — ``start_s``, ``end_s``, ``bias_rad_s`` of each finished segment.
    updates : int — how many times the estimate changed.
    """

    def __init__(self, config: RestConfig | None = None, probe: int = 64) -> None:
        config = config or RestConfig()
        self.min_duration_s = config.min_duration_s
        self.max_rate = config.max_rate_rad_s
        self.max_var = config.max_std_rad_s**2
        self.probe = probe
        self.bias_rad_s = (0.0, 0.0, 0.0)
        self.segments: list[dict] = []
        self.updates = 0
        self.at_rest = False
        self.win = 0
        self._probe_w: list[NDArray] = []  # samples before the window length is known
        self._probe_t: list[NDArray] = []
        self._tail_w = np.zeros((0, 3))  # the last win samples
        self._tail_t = np.zeros(0)
        self._k = -1  # index of the newest sample
        self._seg_start = -1  # a, or -1 when not in a segment
        self._seg_t0 = 0.0
        self._seg_end_t = 0.0
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
        self.win = max(2, math.ceil(self.min_duration_s / dt))
        before = np.tile(self.bias_rad_s, (p - 1 - (seen - len(w)), 1))  # this call's, held
        out = self._steps(pw, pt)
        return np.concatenate([before, out[p - 1 :]])[-len(w) :]

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
            mean, var = windowed_mean_var(X, m)
            rows = np.arange(first_full, n) + (k0 - base) - m + 1  # window ending at sample j
            still[first_full:] = (np.linalg.norm(mean[rows], axis=1) < self.max_rate) & np.all(
                var[rows] < self.max_var, axis=1
            )
        out = np.full((n, 3), np.nan)
        before = self.bias_rad_s
        pos = 0
        for p, q in runs(still):
            if self._seg_start >= 0 and p > pos:
                self._close_segment()  # motion between the open segment and this run
            self._run(X, T, base, k0, p, q, out)
            pos = q
        if self._seg_start >= 0 and pos < n:
            self._close_segment()
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
        if self._seg_start < 0 or p > 0:
            a = k0 + p - m + 1  # a segment starts with the first sample of its first still window
            self._seg_start, self._seg_t0 = a, float(T[a - base])
            self._lo = a if a == 0 else a + m
            self._acc_hi, self._acc = self._lo, np.zeros(3)
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
        self.at_rest = True
        self._seg_end_t = float(T[k0 + q - 1 - base])

    def _close_segment(self) -> None:
        self.segments.append(
            {"start_s": self._seg_t0, "end_s": self._seg_end_t, "bias_rad_s": list(self.bias_rad_s)}
        )
        self._seg_start = -1
        self.at_rest = False

    def finish(self) -> None:
        """Close an open segment (at stop)."""
        if self._seg_start >= 0:
            self._close_segment()

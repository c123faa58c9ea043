"""Rest detection: the still segments of a gyro log, and the windowed statistics behind them.

A gyro at rest measures its bias plus noise. A sample is *at rest* when it lies in a window of at
least ``min_duration_s`` (0.5 s) whose mean rate magnitude is below ``max_rate_rad_s`` and whose
per-axis standard deviation is below ``max_std_rad_s``. Consecutive rest samples form a rest
segment. The bias estimate (:mod:`imu_dcm.replay.bias`) and the noise estimate of the pre-filter
(:mod:`imu_dcm.prefilter`) both start from here.

Conventions: ``omega_b`` (N, 3) body rate relative to the world in body axes, rad/s; ``t_s`` (N,)
seconds, increasing.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imu_dcm.errors import InputError

__all__ = [
    "RestConfig",
    "detect_rest",
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
    """

    min_duration_s: float = 0.5
    max_rate_rad_s: float = 0.035
    max_std_rad_s: float = 0.01


def window_samples(t_s: NDArray, duration_s: float) -> int:
    """Samples in a window of ``duration_s`` seconds at the median step (at least 2)."""
    dt = float(np.median(np.diff(t_s))) if len(t_s) > 1 else 1.0
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
    c1 = np.concatenate([np.zeros((1,) + x.shape[1:]), np.cumsum(x, axis=0)])
    c2 = np.concatenate([np.zeros((1,) + x.shape[1:]), np.cumsum(x * x, axis=0)])
    mean = (c1[m:] - c1[:-m]) / m
    var = np.maximum((c2[m:] - c2[:-m]) / m - mean * mean, 0.0)
    return mean, var


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
    m = max(3, min(len(t_s), round(window_s / float(np.median(np.diff(t_s))))))
    _mean, var = windowed_mean_var(omega_b, m)
    return float(np.sqrt(var.max(axis=1).min()))


def detect_rest(omega_b: ArrayLike, t_s: ArrayLike, config: RestConfig | None = None) -> NDArray:
    """Boolean mask (N,) of samples at rest (see the module docstring for the rule).

    Parameters
    ----------
    omega_b : array_like, shape (N, 3)
        Body rates, rad/s.
    t_s : array_like, shape (N,)
        Sample times, s, increasing.
    config : RestConfig, optional
    """
    cfg = config or RestConfig()
    w = np.asarray(omega_b, dtype=float)
    t = np.asarray(t_s, dtype=float)
    if w.ndim != 2 or w.shape[1] != 3 or len(t) != len(w):
        raise InputError(f"Expected omega_b (N, 3) and t_s (N,), got {w.shape} and {t.shape}")
    n = len(w)
    win = window_samples(t, cfg.min_duration_s)
    rest = np.zeros(n, dtype=bool)
    if n < win:
        return rest
    mean, var = windowed_mean_var(w, win)  # window starting at i: samples [i, i + win)
    still = (np.linalg.norm(mean, axis=1) < cfg.max_rate_rad_s) & np.all(
        var < cfg.max_std_rad_s**2, axis=1
    )
    # a sample is at rest when any still window covers it: spread each still start over win
    cover = np.zeros(n + 1, dtype=np.int64)
    starts = np.flatnonzero(still)
    np.add.at(cover, starts, 1)
    np.add.at(cover, starts + win, -1)
    rest[:] = np.cumsum(cover[:-1]) > 0
    return rest

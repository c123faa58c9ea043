"""Windowed statistics the rest rule and its evidence share: running mean and variance of
every window, the smallest output step and the quantisation noise it implies."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["min_steps", "step_var", "windowed_mean_var"]


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


def min_steps(x: NDArray) -> NDArray:
    """The smallest positive step of each column (inf where none)."""
    d = np.abs(np.diff(x, axis=0))
    return np.where(d > 0, d, np.inf).min(axis=0) if len(d) else np.full(x.shape[1], np.inf)


def step_var(steps: NDArray) -> float:
    """The output's quantisation noise, step²/12 (largest axis with a step; 0 without)."""
    finite = steps[np.isfinite(steps)]
    return float(finite.max()) ** 2 / 12.0 if len(finite) else 0.0

"""Windowed statistics the rest rule and its evidence share: running mean and variance of
every window, the smallest output step and the quantisation noise it implies."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from imu_dcm._kernels.calls import min_steps as kernel_min_steps
from imu_dcm._kernels.calls import window_norms as kernel_window_norms
from imu_dcm.arrays import BLOCK_ROWS, cumsum_rows

__all__ = ["min_steps", "step_var", "window_norms", "windowed_mean_var"]


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
        clipped at 0 against cancellation in the running sums). Both are views of one buffer
        of the running sums, which are turned into the windows' figures in place (the memory
        of two copies of ``x``, not six).
    """
    n = len(x)
    sums = np.empty((2, n + 1) + x.shape[1:])  # running sums of x and x², then the windows'
    sums[:, 0] = 0.0
    cumsum_rows(x, sums[0, 1:])
    squares = sums[1, 1:]
    for a in range(0, n, BLOCK_ROWS):
        np.square(x[a : a + BLOCK_ROWS], out=squares[a : a + BLOCK_ROWS])
    cumsum_rows(squares, squares)
    k = n - m + 1
    for a in range(0, k, BLOCK_ROWS):  # in place, block by block: a window's sums are read
        b = min(k, a + BLOCK_ROWS)  # before a block at or after them is written
        np.subtract(sums[:, a + m : b + m], sums[:, a:b], out=sums[:, a:b])
        mean, var = sums[0, a:b], sums[1, a:b]
        mean /= m
        var /= m
        var -= mean * mean
        np.maximum(var, 0.0, out=var)
    return sums[0, :k], sums[1, :k]


def window_norms(x: NDArray, m: int) -> tuple[NDArray, NDArray]:
    """The norm of the mean and the largest axis's variance of every window of ``m`` rows:
    ``row_norm(mean)`` and ``row_max(var)`` of :func:`windowed_mean_var` (the same sums; the
    norm's three squares added in order, a rounding apart from numpy's), in one compiled pass
    (:func:`imu_dcm._kernels.calls.window_norms`) with the memory of the two results only.

    Parameters
    ----------
    x : ndarray, shape (N, k)
    m : int
        Window length in samples, ``1 <= m <= N``.

    Returns
    -------
    norm, max_var : ndarray, shape (N - m + 1,)
    """
    k = len(x) - m + 1
    norm, max_var = np.empty(k), np.empty(k)
    kernel_window_norms(np.ascontiguousarray(x, dtype=float), int(m), norm, max_var)
    return norm, max_var


def min_steps(x: NDArray) -> NDArray:
    """The smallest positive step of each column (inf where none), in one compiled pass."""
    x = np.ascontiguousarray(x, dtype=float)
    out = np.empty(x.shape[1])
    kernel_min_steps(x, out)
    return out


def step_var(steps: NDArray) -> float:
    """The output's quantisation noise, step²/12 (largest axis with a step; 0 without)."""
    finite = steps[np.isfinite(steps)]
    return float(finite.max()) ** 2 / 12.0 if len(finite) else 0.0

"""A synthetic strapdown gyro sampling a trajectory's truth (docs/design.md, "Ground truth").

Conventions: rates ``omega_b`` in rad/s in body axes (relative to the world), angles in rad,
``t_s`` seconds from the start of the trajectory, ``t_ns`` int64 nanoseconds since the Unix
epoch (``epoch_ns + round(t_s · 1e9)``).

Each error term is off unless given (``None`` means off), and the order of operations is fixed:
truth → + constant bias → + bias random walk → + white noise → saturation → quantization.
The random draws come from one ``numpy.random.default_rng(seed)`` in a fixed order (stamp
jitter, white noise, bias walk), so the same seed gives the same samples, bit for bit.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import sys
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from data_synth.rigid_body import Trajectory
from imu_dcm.arrays import BLOCK_ROWS
from imu_dcm.errors import InputError

__all__ = [
    "DEFAULT_EPOCH_NS",
    "MAX_STAMP_NS",
    "OUTPUTS",
    "GyroModel",
    "GyroRecord",
    "sample_count",
    "synthetic_gyro",
    "synthetic_gyro_blocks",
]

#: Default stamp of ``t_s = 0``: 2023-11-14T22:13:20Z, the epoch of the BROAD bags.
DEFAULT_EPOCH_NS = 1_700_000_000_000_000_000
#: Stamps stay below this: ROS 2 ``header.stamp.sec`` is an int32.
MAX_STAMP_NS = 2**31 * 10**9
OUTPUTS = ("rate", "delta-angle")


@dataclass(frozen=True)
class GyroModel:
    """Error terms of the synthetic gyro; each ``None`` (the default) is off.

    Attributes
    ----------
    noise_density_rad_s_sqrt_hz : float or None
        White rate noise (angle random walk) density ``N``, rad/s/√Hz. Per rate sample
        ``σ = N √rate_hz``; per delta angle ``σ = N √dt``.
    bias_rad_s : tuple of 3 float or None
        Constant bias, rad/s, body axes.
    bias_walk_rad_s2_sqrt_hz : float or None
        Bias random walk (rate random walk) density ``K``, rad/s²/√Hz = rad/s/√s: the bias
        changes by ``K √dt`` (standard deviation) per sample interval, starting at 0.
    quantization_rad_s : float or None
        Step of the output, rad/s. For delta angles the step is ``quantization_rad_s / rate_hz``
        rad, applied to the accumulated angle (the residual carries over, as in delta-angle
        IMUs).
    range_rad_s : float or None
        Full-scale range, rad/s: each axis saturates at ``±range_rad_s`` (delta angles at
        ``±range_rad_s · dt``).
    stamp_jitter_s : float or None
        Standard deviation of the sample instants about the nominal grid ``k / rate_hz``, s
        (clipped to ±0.4 of a period so that the order is kept). The stamps are the true,
        jittered instants: the log is unevenly spaced, not mis-stamped.
    """

    noise_density_rad_s_sqrt_hz: float | None = None
    bias_rad_s: tuple[float, float, float] | None = None
    bias_walk_rad_s2_sqrt_hz: float | None = None
    quantization_rad_s: float | None = None
    range_rad_s: float | None = None
    stamp_jitter_s: float | None = None

    def __post_init__(self) -> None:
        for name in ("noise_density_rad_s_sqrt_hz", "bias_walk_rad_s2_sqrt_hz", "stamp_jitter_s"):
            v = getattr(self, name)
            if v is not None and not (math.isfinite(v) and v >= 0):
                raise InputError(f"Expected `{name}` >= 0 or None, got {v!r}")
        for name in ("quantization_rad_s", "range_rad_s"):
            v = getattr(self, name)
            # > the smallest normal float: 1 / step of a subnormal step overflows
            if v is not None and not (math.isfinite(v) and v >= sys.float_info.min):
                raise InputError(
                    f"Expected `{name}` >= {sys.float_info.min:.4g} (a normal "
                    f"positive float) or None, got {v!r}"
                )
        if self.bias_rad_s is not None:
            b = tuple(float(x) for x in self.bias_rad_s)
            if len(b) != 3 or not all(math.isfinite(x) for x in b):
                raise InputError(
                    f"Expected `bias_rad_s` three finite rates, got {self.bias_rad_s!r}"
                )
            object.__setattr__(self, "bias_rad_s", b)

    def as_dict(self) -> dict[str, Any]:
        """The terms that are on, by field name (for log metadata)."""
        return {
            k: (list(v) if isinstance(v, tuple) else v)
            for k, v in asdict(self).items()
            if v is not None
        }


@dataclass(frozen=True)
class GyroRecord:
    """Samples of the synthetic gyro.

    Attributes
    ----------
    t_s : ndarray, shape (N,)
        Sample instants, s from the trajectory start (exactly ``(t_ns − epoch_ns) · 1e-9``).
    t_ns : ndarray of int64, shape (N,)
        Stamps, ns since the Unix epoch.
    values : ndarray, shape (N, 3)
        ``output="rate"``: ``omega_b(t_k)`` with errors, rad/s. ``output="delta-angle"``: the
        integral of ``omega_b`` over ``(t_{k−1}, t_k]`` with errors, rad (the first stamp is the
        start of the first interval and is not in ``t_s``).
    output : str
        ``"rate"`` or ``"delta-angle"``.
    rate_hz : float
        Nominal sample rate, Hz.
    epoch_ns : int
        Stamp of ``t_s = 0``.
    model : GyroModel
        The error terms used.
    seed : int
        Seed of the random draws.
    bias_b_rad_s : ndarray, shape (N, 3)
        The total bias (constant + random walk) in each sample, rad/s (diagnostic).
    t_start_s : float
        Start of the first interval, s (delta-angle output; 0 for the whole log, the last
        sample before it for a block of :func:`synthetic_gyro_blocks`).
    """

    t_s: NDArray[np.float64]
    t_ns: NDArray[np.int64]
    values: NDArray[np.float64]
    output: str
    rate_hz: float
    epoch_ns: int
    model: GyroModel
    seed: int
    bias_b_rad_s: NDArray[np.float64]
    t_start_s: float = 0.0

    def rate_rad_s(self, t_start_s: float | None = None) -> NDArray[np.float64]:
        """The samples as rates, rad/s, shape (N, 3).

        For ``delta-angle`` output, the mean rate over each interval, ``Δθ_k / (t_k − t_{k−1})``
        (what an IMU that integrates internally publishes as ``angular_velocity``);
        ``t_start_s`` is the start of the first interval (default: the record's own).
        """
        if self.output == "rate":
            return self.values
        start = self.t_start_s if t_start_s is None else t_start_s
        dt = np.diff(np.concatenate([[start], self.t_s]))
        return self.values / dt[:, None]


def sample_count(rate_hz: float, duration_s: float) -> int:
    """Samples at ``k / rate_hz`` for ``0 <= k / rate_hz <= duration_s``."""
    return math.floor(duration_s * rate_hz * (1.0 + 1e-12)) + 1


class _Draws:
    """The random draws of one seed in blocks: stamp jitter (one per sample), white noise (three
    per output sample), bias walk (three per output interval), each term reading its own copy of
    the one ``default_rng(seed)`` stream from where the whole-log draws of the terms before it
    end. So a block's draws are those of the whole log's, bit for bit, at any block size."""

    def __init__(self, seed: int, model: GyroModel, n: int, n_out: int) -> None:
        rng = np.random.default_rng(seed)
        self.jitter = copy.deepcopy(rng) if model.stamp_jitter_s else None
        if model.stamp_jitter_s:
            _skip(rng, n)
        self.noise = copy.deepcopy(rng) if model.noise_density_rad_s_sqrt_hz else None
        if model.noise_density_rad_s_sqrt_hz:
            _skip(rng, 3 * n_out)
        self.walk = rng if model.bias_walk_rad_s2_sqrt_hz else None


def _skip(rng: np.random.Generator, count: int) -> None:
    """Advance ``rng`` past ``count`` normal draws (one block at a time: no whole-log array)."""
    for a in range(0, count, 3 * BLOCK_ROWS):
        rng.standard_normal(min(3 * BLOCK_ROWS, count - a))


def _block_times(
    rate_hz: float, duration_s: float, jitter_s: float | None, rng, k: NDArray
) -> NDArray[np.int64]:
    """Sample instants of the sample indices ``k`` (a run of consecutive ones), ns from t = 0."""
    t_nom_ns = np.round(k * (1e9 / rate_hz)).astype(np.int64)
    if not jitter_s:
        return t_nom_ns
    period_ns = 1e9 / rate_hz
    j = np.clip(rng.normal(scale=jitter_s * 1e9, size=k.size), -0.4 * period_ns, 0.4 * period_ns)
    if k[0] == 0:
        j[0] = 0.0  # keep the first sample at t = 0 (inside the trajectory)
    return np.clip(t_nom_ns + np.round(j).astype(np.int64), 0, round(duration_s * 1e9))


def _ordered_times(rate_hz, duration_s, jitter_s, rng, k: NDArray, prev_ns: int | None):
    """:func:`_block_times` of the samples ``k``, after the block before's last stamp
    ``prev_ns`` (None for the first block), refused when jitter breaks their order."""
    t_rel_ns = _block_times(rate_hz, duration_s, jitter_s, rng, k)
    if prev_ns is not None:
        t_rel_ns = np.concatenate([[prev_ns], t_rel_ns])
    if np.any(np.diff(t_rel_ns) <= 0):  # only possible at ns resolution for huge rates
        raise InputError(
            f"Expected stamp jitter to keep the order at {rate_hz} Hz, got "
            f"repeated stamps with stamp_jitter_s = {jitter_s}"
        )
    return t_rel_ns


def _truth_of(traj: Trajectory, t_all: NDArray, first: int, delta: bool):
    """What the gyro measures over a block's instants ``t_all`` (the block before's last one
    first, when ``first`` is 1): ``(y, dt, rows, start)``, the true rates at its own samples, or
    the true delta angles over every interval with their lengths (N, 1); the rows of
    ``t_all`` they are output at, and the start of the first interval."""
    if delta:
        return traj.delta_angles(t_all), np.diff(t_all)[:, None], slice(1, None), t_all[0]
    return traj.at(t_all[first:])[1], None, slice(first, None), 0.0


def _check_finite(values: NDArray, model: GyroModel) -> None:
    if not np.all(np.isfinite(values)):
        raise InputError(
            "Expected a finite gyro output, got "
            f"{np.count_nonzero(~np.isfinite(values))}"
            f" non-finite values from the model {model.as_dict()}"
        )


def synthetic_gyro(*args, **kwargs) -> GyroRecord:
    """Sample a trajectory with a gyro: stamps and rate (or delta-angle) samples, the whole
    record (the blocks of :func:`synthetic_gyro_blocks`, whose arguments it takes, joined).

    Examples
    --------
    >>> import data_synth
    >>> traj = data_synth.simulate("coning", duration_s=1.0)
    >>> rec = synthetic_gyro(traj, 400.0, model=GyroModel(noise_density_rad_s_sqrt_hz=1e-4))
    """
    blocks = list(synthetic_gyro_blocks(*args, **kwargs))
    return dataclasses.replace(
        blocks[0],
        **{
            name: np.concatenate([getattr(b, name) for b in blocks])
            for name in ("t_s", "t_ns", "values", "bias_b_rad_s")
        },
    )


def synthetic_gyro_blocks(
    traj: Trajectory,
    rate_hz: float,
    duration_s: float | None = None,
    model: GyroModel | None = None,
    output: str = "rate",
    seed: int = 0,
    epoch_ns: int = DEFAULT_EPOCH_NS,
) -> Iterator[GyroRecord]:
    """Sample a trajectory with a gyro, one block of ``BLOCK_ROWS`` samples at a time.

    The blocks joined are the whole record bit for bit, whatever the block size: the random
    draws (:class:`_Draws`), the bias walk and the delta-angle quantization carry over from block
    to block in the order the whole log adds them. Each block's ``t_start_s`` is the start of
    its first interval (delta-angle output), so ``block.rate_rad_s()`` gives its rates. Memory
    holds one block, not the log.

    Parameters
    ----------
    traj : Trajectory
        Truth to sample (``data_synth.simulate(...)``).
    rate_hz : float
        Nominal sample rate, Hz; samples at ``k / rate_hz`` for ``0 <= k / rate_hz <=
        duration_s`` (plus jitter when modelled).
    duration_s : float, optional
        Length sampled, s, at most ``traj.duration_s`` (default: all of it).
    model : GyroModel, optional
        Error terms; default: an ideal gyro.
    output : {"rate", "delta-angle"}
        ``rate``: instantaneous ``omega_b(t_k)``; ``delta-angle``: exact ``∫ omega_b dt`` over
        each interval from the dense truth.
    seed : int
        Seed of the random terms.
    epoch_ns : int
        Stamp of ``t_s = 0``, ns since the Unix epoch.

    Yields
    ------
    GyroRecord
        A block of the record.
    """
    model = model or GyroModel()
    duration_s = _check_request(traj, rate_hz, duration_s, output, seed, epoch_ns)
    n = sample_count(rate_hz, duration_s)
    delta = output == "delta-angle"
    draws = _Draws(seed, model, n, n - 1 if delta else n)
    walk = np.zeros(3)  # the bias walk so far, and the accumulated angle and its counts so far
    acc = np.zeros(3) if delta and model.quantization_rad_s is not None else None
    counts = np.zeros(3)
    prev_ns = prev_s = None  # the last sample of the block before
    for a in range(0, n, BLOCK_ROWS):
        k = np.arange(a, min(n, a + BLOCK_ROWS))
        t_rel_ns = _ordered_times(rate_hz, duration_s, model.stamp_jitter_s, draws.jitter, k,
                                  prev_ns)  # fmt: skip
        t_all = t_rel_ns * 1e-9  # with the block before's last sample, when there is one
        first = 0 if prev_ns is None else 1  # this block's own samples start here
        prev_ns = int(t_rel_ns[-1])
        y, dt, rows, start = _truth_of(traj, t_all, first, delta)
        t_s, t_ns = t_all[rows], epoch_ns + t_rel_ns[rows]
        if len(t_s) == 0:
            continue
        bias, walk = _bias(model, draws.walk, t_s, prev_s, walk)
        prev_s = float(t_s[-1])
        noise = None if draws.noise is None else draws.noise.standard_normal((len(t_s), 3))
        values, acc, counts = _measure(y, bias, noise, model, rate_hz, dt, acc, counts)
        _check_finite(values, model)
        yield GyroRecord(
            t_s=t_s,
            t_ns=t_ns,
            values=values,
            output=output,
            rate_hz=float(rate_hz),
            epoch_ns=int(epoch_ns),
            model=model,
            seed=int(seed),
            bias_b_rad_s=bias,
            t_start_s=float(start),
        )


def _bias(model: GyroModel, rng, t_s: NDArray, prev_s: float | None, walk: NDArray):
    """The bias of the output samples ``t_s`` (constant plus random walk), rad/s, (n, 3), and
    the walk at the last of them. ``b_k = b_0 + Σ_{j<k} K √(t_{j+1} − t_j) ν_j``: one step per
    sample interval, those ending in ``t_s`` (``prev_s`` the sample before, None at the start;
    ``walk`` the walk there), summed in the whole log's order."""
    bias = np.zeros((len(t_s), 3))
    if model.bias_rad_s is not None:
        bias += np.asarray(model.bias_rad_s)
    if rng is None:
        return bias, walk
    t_w = t_s if prev_s is None else np.concatenate([[prev_s], t_s])
    steps = rng.standard_normal((len(t_w) - 1, 3)) * model.bias_walk_rad_s2_sqrt_hz
    w = np.cumsum(np.concatenate([walk[None], steps * np.sqrt(np.diff(t_w))[:, None]]), axis=0)
    lead = len(t_s) - (len(w) - 1)  # 1 for the log's first output sample: no walk yet
    bias[lead:] += w[1:]
    return bias, w[-1].copy()


def _check_request(
    traj: Trajectory,
    rate_hz: float,
    duration_s: float | None,
    output: str,
    seed: int,
    epoch_ns: int,
) -> float:
    """Refuse a request the trajectory or the stamps cannot serve; the duration to sample, s."""
    if output not in OUTPUTS:
        raise InputError(f"Expected output in {OUTPUTS}, got {output!r}")
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise InputError(f"Expected `rate_hz` > 0, got {rate_hz!r}")
    if duration_s is None:
        duration_s = traj.duration_s
    if not (math.isfinite(duration_s) and 0 < duration_s <= traj.duration_s + 1e-12):
        raise InputError(
            f"Expected `duration_s` in (0, {traj.duration_s}] (the trajectory's "
            f"length), got {duration_s!r}"
        )
    if duration_s * rate_hz < 1:
        raise InputError(
            f"Expected at least two samples, got duration {duration_s} s at {rate_hz} Hz"
        )
    if not 0 <= int(epoch_ns) <= MAX_STAMP_NS - math.ceil(duration_s * 1e9):
        raise InputError(
            f"Expected `epoch_ns` in [0, {MAX_STAMP_NS - math.ceil(duration_s * 1e9)}]"
            f" (stamps end before header.stamp.sec, an int32, overflows), got "
            f"{epoch_ns!r}"
        )
    if not (isinstance(seed, (int, np.integer)) and seed >= 0):
        raise InputError(f"Expected `seed` an integer >= 0, got {seed!r}")
    return duration_s


def _measure(
    y: NDArray,
    bias: NDArray,
    noise: NDArray | None,
    model: GyroModel,
    rate_hz: float,
    dt: NDArray | None,
    acc: NDArray | None,
    counts: NDArray,
) -> tuple[NDArray, NDArray | None, NDArray]:
    """The gyro's output from the true rates (``dt`` None) or true delta-angles over intervals
    ``dt`` (N, 1), s: bias, noise, saturation, then quantization. ``acc`` and ``counts`` are the
    accumulated delta angle and its rounded step count before these rows (delta-angle
    quantization); returned with the output, updated."""
    if dt is None:
        values = y + bias
        if noise is not None:
            values = values + noise * (model.noise_density_rad_s_sqrt_hz * math.sqrt(rate_hz))
        lim = model.range_rad_s
        step = model.quantization_rad_s
    else:
        values = y + bias * dt
        if noise is not None:
            values = values + noise * (model.noise_density_rad_s_sqrt_hz * np.sqrt(dt))
        lim = None if model.range_rad_s is None else model.range_rad_s * dt
        step = None if model.quantization_rad_s is None else model.quantization_rad_s / rate_hz
    if lim is not None:
        values = np.clip(values, -lim, lim)
    if step is None:
        return values, acc, counts
    if acc is None:
        return _step_counts(values, values, step, model.quantization_rad_s) * step, acc, counts
    # delta angles: round the accumulated angle, as a delta-angle IMU does, so the residual is
    # carried to the next sample instead of accumulating (the sum carried from the rows before,
    # added in the same order as over the whole log)
    total = np.cumsum(np.concatenate([acc[None], values]), axis=0)[1:]
    whole = _step_counts(total, values, step, model.quantization_rad_s)
    out = np.diff(np.concatenate([counts[None], whole]), axis=0) * step
    return out, total[-1].copy(), whole[-1].copy()


def _step_counts(x: NDArray, values: NDArray, step: float, step_rad_s: float) -> NDArray:
    """``x / step`` rounded to whole steps (``values``: the output, for the message)."""
    with np.errstate(over="ignore"):  # a step far below the rates: refused just below
        counts = x / step
    if not np.all(np.isfinite(counts)):
        raise InputError(
            f"Expected `quantization_rad_s` large enough that rate / step is "
            f"finite, got {step_rad_s!r} for rates up to "
            f"{float(np.max(np.abs(values))):.3g}"
        )
    return np.round(counts)

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

import math
import sys
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from data_synth.rigid_body import Trajectory
from imu_dcm.errors import InputError

__all__ = [
    "DEFAULT_EPOCH_NS",
    "MAX_STAMP_NS",
    "OUTPUTS",
    "GyroModel",
    "GyroRecord",
    "synthetic_gyro",
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

    def rate_rad_s(self, t_start_s: float = 0.0) -> NDArray[np.float64]:
        """The samples as rates, rad/s, shape (N, 3).

        For ``delta-angle`` output, the mean rate over each interval, ``Δθ_k / (t_k − t_{k−1})``
        (what an IMU that integrates internally publishes as ``angular_velocity``);
        ``t_start_s`` is the start of the first interval.
        """
        if self.output == "rate":
            return self.values
        dt = np.diff(np.concatenate([[t_start_s], self.t_s]))
        return self.values / dt[:, None]


def _sample_times(
    rate_hz: float,
    duration_s: float,
    jitter_s: float | None,
    rng: np.random.Generator,
    epoch_ns: int,
) -> tuple[NDArray, NDArray]:
    n = math.floor(duration_s * rate_hz * (1.0 + 1e-12)) + 1
    k = np.arange(n)
    t_nom_ns = np.round(k * (1e9 / rate_hz)).astype(np.int64)
    if jitter_s:
        period_ns = 1e9 / rate_hz
        j = np.clip(rng.normal(scale=jitter_s * 1e9, size=n), -0.4 * period_ns, 0.4 * period_ns)
        j[0] = 0.0  # keep the first sample at t = 0 (inside the trajectory)
        t_rel_ns = t_nom_ns + np.round(j).astype(np.int64)
        t_rel_ns = np.clip(t_rel_ns, 0, round(duration_s * 1e9))
        if np.any(np.diff(t_rel_ns) <= 0):  # only possible at ns resolution for huge rates
            raise InputError(
                f"Expected stamp jitter to keep the order at {rate_hz} Hz, got "
                f"repeated stamps with stamp_jitter_s = {jitter_s}"
            )
    else:
        t_rel_ns = t_nom_ns
    return t_rel_ns * 1e-9, epoch_ns + t_rel_ns


def synthetic_gyro(
    traj: Trajectory,
    rate_hz: float,
    duration_s: float | None = None,
    model: GyroModel | None = None,
    output: str = "rate",
    seed: int = 0,
    epoch_ns: int = DEFAULT_EPOCH_NS,
) -> GyroRecord:
    """Sample a trajectory with a gyro: stamps and rate (or delta-angle) samples.

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

    Returns
    -------
    GyroRecord
    """
    model = model or GyroModel()
    duration_s = _check_request(traj, rate_hz, duration_s, output, seed, epoch_ns)
    rng = np.random.default_rng(seed)
    t_s, t_ns = _sample_times(rate_hz, duration_s, model.stamp_jitter_s, rng, int(epoch_ns))
    if output == "rate":
        _, y = traj.at(t_s)
        dt = None
    else:
        y = traj.delta_angles(t_s)
        dt = np.diff(t_s)[:, None]
        t_s, t_ns = t_s[1:], t_ns[1:]
    bias, noise = _random_terms(model, t_s, rng)
    values = _measure(y, bias, noise, model, rate_hz, dt)
    if not np.all(np.isfinite(values)):
        raise InputError(
            "Expected a finite gyro output, got "
            f"{np.count_nonzero(~np.isfinite(values))}"
            f" non-finite values from the model {model.as_dict()}"
        )
    return GyroRecord(
        t_s=t_s,
        t_ns=t_ns,
        values=values,
        output=output,
        rate_hz=float(rate_hz),
        epoch_ns=int(epoch_ns),
        model=model,
        seed=int(seed),
        bias_b_rad_s=bias,
    )


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


def _random_terms(
    model: GyroModel, t_s: NDArray, rng: np.random.Generator
) -> tuple[NDArray, NDArray | None]:
    """The bias at each sample (constant plus random walk), rad/s, (N, 3); and unit white noise
    (N, 3), or None without a noise term. The noise is drawn before the walk (same seed, same
    bytes)."""
    n = len(t_s)
    bias = np.zeros((n, 3))
    if model.bias_rad_s is not None:
        bias += np.asarray(model.bias_rad_s)
    noise = None
    if model.noise_density_rad_s_sqrt_hz:
        noise = rng.standard_normal((n, 3))
    if model.bias_walk_rad_s2_sqrt_hz:
        steps = rng.standard_normal((n - 1, 3)) * model.bias_walk_rad_s2_sqrt_hz
        # b_k = b_0 + Σ_{j<k} K √(t_{j+1} − t_j) ν_j: one step per sample interval.
        bias[1:] += np.cumsum(steps * np.sqrt(np.diff(t_s))[:, None], axis=0)
    return bias, noise


def _measure(
    y: NDArray,
    bias: NDArray,
    noise: NDArray | None,
    model: GyroModel,
    rate_hz: float,
    dt: NDArray | None,
) -> NDArray:
    """The gyro's output from the true rates (``dt`` None) or true delta-angles over intervals
    ``dt`` (N, 1), s: bias, noise, saturation, then quantization."""
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
    if step is not None:
        values = _quantize(values, step, model.quantization_rad_s, accumulate=dt is not None)
    return values


def _quantize(values: NDArray, step: float, step_rad_s: float, accumulate: bool) -> NDArray:
    """Round to multiples of ``step``; with ``accumulate`` (delta-angles) round the accumulated
    angle instead, as a delta-angle IMU does, so the residual is carried to the next sample
    instead of accumulating."""
    with np.errstate(over="ignore"):  # a step far below the rates: refused just below
        counts = (np.cumsum(values, axis=0) if accumulate else values) / step
    if not np.all(np.isfinite(counts)):
        raise InputError(
            f"Expected `quantization_rad_s` large enough that rate / step is "
            f"finite, got {step_rad_s!r} for rates up to "
            f"{float(np.max(np.abs(values))):.3g}"
        )
    if not accumulate:
        return np.round(counts) * step
    total = np.round(counts)
    return np.diff(np.concatenate([np.zeros((1, 3)), total]), axis=0) * step

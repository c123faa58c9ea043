"""Settings, results and input checks of the rate pre-filter.

Conventions: ``omega_b`` (N, 3) body rate relative to the world in body axes, rad/s; ``t_s`` (N,)
seconds, strictly increasing; noise densities in rad/s/√Hz.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imu_dcm.errors import Diagnostics, InputError
from imu_dcm.integrator.batch import check_samples

MODES = ("kalman", "rts")
MODELS = ("rate-accel", "rate-accel-jerk")

# Fewest rest samples accepted for an Allan-deviation noise estimate: with n samples the
# estimate at one-sample clusters has a relative spread of about 1/sqrt(n) (7 % at 200).
MIN_REST_SAMPLES = 200
# Steps whose dt differs by less than this (relative) share one discretisation.
DT_REL_TOL = 1e-9
# A covariance that moves by less than this (relative) in one step is stationary (the backward
# smoother recursion settles at a round-off floor of about 1e-13).
STATIONARY_REL_TOL = 1e-11
# Width of the initial prior, in units of what the first samples' finite differences tell.
PRIOR_SCALE = 100.0
# Search range of the angular-acceleration scale for the likelihood fit, rad/s².
ACCEL_SEARCH_RAD_S2 = (1e-4, 1e6)
# Bias allan-deviation minimum to bias instability (IEEE Std 952: flicker floor 0.664 B).
FLICKER_FACTOR = 0.664


@dataclass(frozen=True)
class PrefilterConfig:
    """Settings of the rate pre-filter; ``None`` means "estimate it from the log".

    Attributes
    ----------
    noise_density_rad_s_sqrt_hz : float or None
        Gyro white-noise density (angle random walk), rad/s/√Hz, the same on all axes; per-sample
        standard deviation ``N √(1/dt)``. None: estimated from a rest segment (Allan deviation),
        or from the upper band of the spectrum when the log never rests.
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
        the longest rest found by :func:`imu_dcm.gyro.rest.detect_rest`; when the log has none (or
        none long enough), the density comes from the spectrum of the log itself.
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
class SpectralNoiseEstimate:
    """Gyro white-noise density read off the upper band of a log's spectrum (no rest needed).

    Attributes
    ----------
    noise_density_rad_s_sqrt_hz : ndarray, shape (3,)
        White-noise density per body axis, rad/s/√Hz.
    band_hz : tuple of float
        ``(low, high)`` frequency band the estimate was read from, Hz.
    n_bins : int
        Periodogram values per axis that entered the median.
    """

    noise_density_rad_s_sqrt_hz: NDArray[np.float64]
    band_hz: tuple[float, float]
    n_bins: int


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


def check_rates(
    omega_b: ArrayLike, t_s: ArrayLike, diagnostics: Diagnostics | None = None
) -> tuple[NDArray, NDArray]:
    """The integrator's sample checks (shape, finite, strictly increasing stamps, gaps warned
    or added to ``diagnostics``), plus the three samples a rate-and-acceleration model needs."""
    omega_b, t_s, _dt = check_samples(omega_b, t_s, diagnostics=diagnostics)
    if omega_b.shape[0] < 3:
        raise InputError(f"Expected at least 3 samples, got {omega_b.shape[0]}")
    return omega_b, t_s


def check_prefilter_mode(mode: str) -> None:
    if mode not in MODES:
        raise InputError(f"Expected `mode` in {MODES}, got {mode!r}")


def check_positive(name: str, value: float | None, allow_none: bool = True) -> None:
    if value is None and allow_none:
        return
    if (
        value is None
        or not isinstance(value, (int, float, np.floating, np.integer))
        or not (math.isfinite(value) and value > 0)
    ):
        raise InputError(f"Expected `{name}` finite and > 0, got {value!r}")


def check_config(config: PrefilterConfig) -> None:
    if not isinstance(config, PrefilterConfig):
        raise InputError(
            f"Expected `config` a PrefilterConfig or None, got {type(config).__name__}"
        )
    check_positive("noise_density_rad_s_sqrt_hz", config.noise_density_rad_s_sqrt_hz)
    check_positive("angular_accel_rad_s2", config.angular_accel_rad_s2)
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
        check_positive(name, getattr(config, name), allow_none=False)
    check_positive("rest_max_std_rad_s", config.rest_max_std_rad_s)
    if config.rest_interval_s is not None:
        iv = config.rest_interval_s
        if len(iv) != 2 or not all(math.isfinite(v) for v in iv) or not iv[0] < iv[1]:
            raise InputError(
                f"Expected `rest_interval_s` = (start, end) with start < end, got {iv!r}"
            )

"""What the pre-filter estimates from the log: the noise density and the process-noise scale.

* :func:`estimate_noise_from_rest`: angle random walk and bias instability from the Allan
  deviation of a rest segment (IEEE Std 952).
* :func:`estimate_noise_from_spectrum`: the white-noise density of a log with no rest, from the
  upper band of the spectrum of its second differences (the motion of a rigid body has little
  power there; the few lines it has do not move a median).
* ``σ_α`` by maximum likelihood of the stationary filter's innovations.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imu_dcm.errors import Diagnostics, InputError
from imu_dcm.gyro.allan import allan_deviation, noise_density_from_allan
from imu_dcm.gyro.prefilter._linear import (
    motion_order,
    q_scale,
    stationary_prior,
    transition_matrices,
)
from imu_dcm.gyro.prefilter.config import (
    ACCEL_SEARCH_RAD_S2,
    FLICKER_FACTOR,
    MIN_REST_SAMPLES,
    NoiseEstimate,
    SpectralNoiseEstimate,
    check_rates,
)


def estimate_noise_from_rest(
    omega_b: ArrayLike,
    t_s: ArrayLike,
    min_rest_s: float = 1.0,
    *,
    diagnostics: Diagnostics | None = None,
) -> NoiseEstimate:
    """Angle random walk and bias instability from a rest segment's Allan deviation.

    Parameters
    ----------
    omega_b : array_like, shape (M, 3)
        Body rate over a segment at rest, rad/s.
    t_s : array_like, shape (M,)
        Its sample times, s (the rate is taken as ``1 / median(dt)``).
    min_rest_s : float
        Shortest segment accepted, s; fewer than 200 samples are refused as well.

    Returns
    -------
    NoiseEstimate

    Raises
    ------
    InputError
        When the segment is too short for the Allan deviation.
    """
    omega_b, t_s = check_rates(omega_b, t_s, diagnostics)
    n = len(t_s)
    span = float(t_s[-1] - t_s[0])
    if n < MIN_REST_SAMPLES or span < min_rest_s:
        raise InputError(
            f"Expected a rest segment of at least {min_rest_s:g} s and {MIN_REST_SAMPLES} samples "
            f"for the Allan deviation, got {span:.3g} s and {n} samples"
        )
    rate_hz = 1.0 / float(np.median(np.diff(t_s)))
    arw = np.atleast_1d(noise_density_from_allan(omega_b, rate_hz))
    tau, adev = allan_deviation(omega_b, rate_hz)
    i_min = np.argmin(adev, axis=0)
    return NoiseEstimate(
        noise_density_rad_s_sqrt_hz=arw,
        bias_instability_rad_s=adev[i_min, np.arange(3)] / FLICKER_FACTOR,
        bias_instability_tau_s=tau[i_min],
        mean_rate_rad_s=omega_b.mean(axis=0),
        interval_s=(float(t_s[0]), float(t_s[-1])),
        n_samples=n,
    )


# Spectral noise estimate: segment length (samples) and the band, as fractions of the Nyquist
# frequency, where the white noise of a gyro lies above the motion of a rigid body.
_SPECTRUM_SEGMENT = 256
_SPECTRUM_BAND = (0.5, 0.95)
# A spectral estimate below this many float64 roundings of the rates is no noise at all.
_ROUNDOFF_FACTOR = 100.0
# Differences taken before the periodogram: they flatten the motion's low-frequency power, so
# that the window's leakage from it stays far below the noise in the upper band.
_DIFFERENCE_ORDER = 2
# Largest ratio of the noise level between the lower and the upper half of the band that still
# counts as white (white noise: 1 within ~20 % for the shortest logs accepted).
_MAX_BAND_TILT = 2.0
# Fewest periodogram values per axis for a spectral estimate (median spread ~ 1.4/sqrt(n)).
_MIN_SPECTRUM_BINS = 30


def estimate_noise_from_spectrum(
    omega_b: ArrayLike, t_s: ArrayLike, *, diagnostics: Diagnostics | None = None
) -> SpectralNoiseEstimate:
    """White-noise density of a gyro log with no rest, from the upper band of its spectrum.

    The rates are differenced twice (``d_k = z_{k+1} − 2 z_k + z_{k−1}``, whose gain at
    frequency ``f`` is ``(2 sin(π f / f_s))²``), cut into Hann-windowed segments, and their
    periodograms divided by that gain and by the window's energy. For white noise of per-sample
    variance ``σ²`` every such value in the band is ``σ²`` times an exponential variable of mean
    1, whose median is ``ln 2``: ``σ² = median / ln 2``, and the density is ``σ √dt``. A median
    over the band (half to 0.95 of the Nyquist frequency) ignores the few spectral lines a
    rigid body's motion puts there (a spinning top's harmonics).

    Parameters
    ----------
    omega_b : array_like, shape (N, 3)
        Measured body rate, body axes, rad/s (in motion or not).
    t_s : array_like, shape (N,)
        Sample times, s, strictly increasing (the rate is taken as ``1 / median(dt)``).

    Returns
    -------
    SpectralNoiseEstimate

    Raises
    ------
    InputError
        When the log is too short, when the band holds no noise above the float64 rounding of
        the rates, or when the level is not flat across the band (not white: a gyro's own
        low-pass filter, or motion reaching the Nyquist frequency).
    """
    omega_b, t_s = check_rates(omega_b, t_s, diagnostics)
    dt = float(np.median(np.diff(t_s)))
    k = _DIFFERENCE_ORDER
    d = np.diff(omega_b, n=k, axis=0)
    seg = min(_SPECTRUM_SEGMENT, len(d))
    f = np.fft.rfftfreq(seg, dt)
    nyquist = 0.5 / dt
    band = (f >= _SPECTRUM_BAND[0] * nyquist) & (f <= _SPECTRUM_BAND[1] * nyquist)
    starts = sorted({*range(0, len(d) - seg + 1, seg), len(d) - seg})
    n_bins = int(band.sum()) * len(starts)
    if n_bins < _MIN_SPECTRUM_BINS:
        raise InputError(
            f"Expected at least {_MIN_SPECTRUM_BINS} spectral values in the upper band to "
            f"estimate the gyro noise density, got {n_bins} from {len(t_s)} samples; "
            "pass noise_density_rad_s_sqrt_hz (replay: --gyro-noise-density)"
        )
    window = np.hanning(seg + 2)[1:-1]
    segments = np.stack([d[s : s + seg] for s in starts])  # (n_seg, seg, 3)
    spec = np.fft.rfft(segments * window[None, :, None], axis=1)[:, band, :]
    gain = (2.0 * np.sin(np.pi * f[band] * dt)) ** (2 * k)
    p = (np.abs(spec) ** 2 / (np.sum(window**2) * gain[None, :, None])).reshape(-1, 3)
    level = np.median(p, axis=0)  # per axis, = ln 2 σ² for white noise
    sigma = np.sqrt(level / math.log(2.0))
    floor = _ROUNDOFF_FACTOR * np.finfo(float).eps * np.sqrt(np.mean(omega_b**2, axis=0))
    if np.any(sigma <= floor):
        axis = int(np.argmax(sigma <= floor))
        raise InputError(
            f"Expected gyro noise above the float64 rounding of the rates to estimate its "
            f"density, got a per-sample spread of {sigma[axis]:.3g} rad/s on axis {axis}; "
            "pass noise_density_rad_s_sqrt_hz (replay: --gyro-noise-density)"
        )
    fb = np.tile(f[band], len(starts))
    mid = 0.5 * (fb.min() + fb.max())
    rel = p / level
    tilt = float(np.median(rel[fb < mid]) / np.median(rel[fb >= mid]))
    if not 1.0 / _MAX_BAND_TILT <= tilt <= _MAX_BAND_TILT:
        raise InputError(
            f"Expected white noise in the upper band of the spectrum to estimate the gyro noise "
            f"density, got a level {tilt:.3g}x higher in its lower half than in its upper half; "
            "pass noise_density_rad_s_sqrt_hz (replay: --gyro-noise-density)"
        )
    return SpectralNoiseEstimate(
        noise_density_rad_s_sqrt_hz=sigma * math.sqrt(dt),
        band_hz=(float(f[band][0]), float(f[band][-1])),
        n_bins=n_bins,
    )


# ------------------------------------------------------------------------------------------------
# maximum-likelihood process-noise scale


def _innovation_nll(z: NDArray, dt: float, nm: int, q: float, r: float, burn: int) -> float:
    """Negative log-likelihood of the stationary filter's innovations (all axes)."""
    P = stationary_prior(dt, nm, q, r)
    F = transition_matrices(np.array([dt]), nm, False)[0]
    H = np.zeros((1, nm))
    H[0, 0] = 1.0
    S = float(P[0, 0] + r)
    K = P[:, :1] / S
    from scipy import signal

    # predicted measurement: s_{k+1} = F (I - K H) s_k + F K z_k, y_k = H s_k, from s_0 = z_0;
    # in the eigenbasis of F (I - K H) = V Λ V⁻¹ it is a sum of first-order IIR filters
    lam, V = np.linalg.eig(F @ (np.eye(nm) - K @ H))
    if np.linalg.cond(V) > 1e6:
        return math.inf
    g = np.linalg.solve(V, F @ K)[:, 0] * V[0, :]
    zc = z - z[0]
    y = np.zeros(zc.shape)
    for li, gi in zip(lam, g, strict=True):
        y += (gi * signal.lfilter([0.0, 1.0], [1.0, -li], zc, axis=0)).real
    e = (zc - y)[burn:]
    return 0.5 * float(np.sum(e * e) / S + e.size * math.log(S))


def fit_accel(z: NDArray, t_s: NDArray, model: str, density: float) -> dict[str, Any]:
    """Maximum-likelihood ``σ_α`` (rad/s²) of the stationary filter at the median step."""
    from scipy import optimize

    dt = float(np.median(np.diff(t_s)))
    nm = motion_order(model)
    r = density**2 / dt
    burn = min(len(z) // 10, 1000)

    def nll(log_a: float) -> float:
        return _innovation_nll(z, dt, nm, q_scale(model, 10.0**log_a), r, burn)

    lo, hi = (math.log10(v) for v in ACCEL_SEARCH_RAD_S2)
    grid = np.arange(lo, hi + 1e-9, 0.5)
    vals = np.array([nll(g) for g in grid])
    j = int(np.argmin(vals))
    at_bound = j in (0, len(grid) - 1)
    a, b = grid[max(j - 1, 0)], grid[min(j + 1, len(grid) - 1)]
    res = optimize.minimize_scalar(nll, bounds=(a, b), method="bounded", options={"xatol": 1e-3})
    return {
        "angular_accel_rad_s2": float(10.0**res.x),
        "at_search_bound": bool(at_bound),
        "neg_log_likelihood": float(res.fun),
        "dt_s": dt,
    }

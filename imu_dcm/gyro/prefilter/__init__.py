"""Kalman pre-filtering and Rauch-Tung-Striebel smoothing of gyro rates (filterpy as the oracle).

Each body axis of the measured rate ``z_k = ω(t_k) + v_k`` (``omega_b``: body rate relative to the
world, in body axes, rad/s; ``v_k`` white, variance ``R_k = N² / dt_k`` for a gyro noise density
``N`` in rad/s/√Hz) is tracked with a linear state-space model, the same for the three axes:

* ``model="rate-accel"``: state ``[ω, α]`` (rate, angular acceleration); ``α`` is a Wiener
  process driven by white jerk of power spectral density ``q = σ_α²`` (rad²/s⁵), where
  ``σ_α = angular_accel_rad_s2`` is the spread the angular acceleration gains in one second.
* ``model="rate-accel-jerk"``: state ``[ω, α, j]``; white snap of density ``q = 3 σ_α²``
  (rad²/s⁷), chosen so that ``α`` again spreads by ``σ_α`` in one second.
* ``estimate_bias=True`` appends a gyro bias ``b`` (random walk), measured as ``z = ω + b``; the
  bias is observable only at rest, where a zero-rate pseudo-measurement ``0 = ω`` is added.

Every step is discretised with its own ``dt_k = t_k − t_{k−1}`` (the continuous white-noise
model, ``filterpy.common.Q_continuous_white_noise``). ``mode="kalman"`` is the causal filter
(for live use); ``mode="rts"`` adds the backward RTS pass (no lag, for offline replay). The
covariances do not depend on the data, so they are propagated once for all three axes, and with
a uniform ``dt`` the recursion stops as soon as it is stationary (steady-state gains, applied
by one first-order IIR filter per eigenmode). The filter starts from a nearly diffuse prior
(100x what the first samples' finite differences tell), so a record that begins in motion
is not pulled towards zero acceleration. ``engine="filterpy"`` runs the same model through
``filterpy.kalman.predict`` / ``update`` / ``rts_smoother`` per axis: the reference the fast
path is tested against.

:class:`StreamingRateFilter` is the per-sample twin of ``mode="kalman"``, and
:func:`euler_prefilter` a model-based variant (Euler's equations with a known inertia, filterpy's
unscented filter).

Parameters not given are estimated: the noise density from the Allan deviation of a rest segment
(``imu_dcm.gyro.allan``; its angle random walk and bias instability are reported), or, when the log
never rests, from the upper band of its spectrum; and ``σ_α`` by maximum likelihood of the
stationary filter's innovations. ``summary["noise_source"]`` says which noise estimate was used.

Modules: ``config`` (settings, results, checks), ``linear`` (the model and its two engines),
``tuning`` (noise and ``σ_α`` estimates), ``batch`` (:func:`prefilter`), ``euler`` (the
model-based variant), ``streaming`` (the per-sample twin).

Which to use (``python -m benchmarks.noise_study``; docs/integrator.md, "Noise"): smoothing cuts
the *rate* error when the noise lies above the motion's band, but no unity-gain low-pass removes
the attitude random walk, and the causal filter's lag makes the attitude worse; integrate the
unfiltered rates for attitude.
"""

from __future__ import annotations

from imu_dcm.gyro.prefilter.batch import prefilter
from imu_dcm.gyro.prefilter.config import (
    MODELS,
    MODES,
    NoiseEstimate,
    PrefilterConfig,
    PrefilterResult,
    SpectralNoiseEstimate,
)
from imu_dcm.gyro.prefilter.euler import euler_prefilter
from imu_dcm.gyro.prefilter.streaming import StreamingRateFilter
from imu_dcm.gyro.prefilter.tuning import estimate_noise_from_rest, estimate_noise_from_spectrum

__all__ = [
    "MODELS",
    "MODES",
    "NoiseEstimate",
    "PrefilterConfig",
    "PrefilterResult",
    "SpectralNoiseEstimate",
    "StreamingRateFilter",
    "estimate_noise_from_rest",
    "estimate_noise_from_spectrum",
    "euler_prefilter",
    "prefilter",
]

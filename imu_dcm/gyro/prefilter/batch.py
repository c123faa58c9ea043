"""The batch entry point :func:`prefilter`: resolve the parameters, then run the linear model."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imu_dcm.errors import Diagnostics, InputError
from imu_dcm.gyro.prefilter._linear import (
    build_model,
    motion_order,
    q_scale,
    run_fast,
    run_filterpy,
    stationary_prior,
)
from imu_dcm.gyro.prefilter.config import (
    MIN_REST_SAMPLES,
    PrefilterConfig,
    PrefilterResult,
    check_config,
    check_prefilter_mode,
    check_rates,
)
from imu_dcm.gyro.prefilter.tuning import (
    estimate_noise_from_rest,
    estimate_noise_from_spectrum,
    fit_accel,
)
from imu_dcm.gyro.rest import detect_rest, quietest_std
from imu_dcm.gyro.rest_rule import RestConfig, longest_run


def prefilter(
    omega_b: ArrayLike,
    t_s: ArrayLike,
    mode: str = "rts",
    config: PrefilterConfig | None = None,
    *,
    engine: str = "numpy",
    diagnostics: Diagnostics | None = None,
) -> PrefilterResult:
    """Kalman-filter (``kalman``) or RTS-smooth (``rts``) measured body rates.

    Parameters
    ----------
    omega_b : array_like, shape (N, 3)
        Measured body rate relative to the world, body axes, rad/s.
    t_s : array_like, shape (N,)
        Sample times, s, strictly increasing (uneven spacing is used as is).
    mode : {"kalman", "rts"}
        Causal filter, or filter plus Rauch-Tung-Striebel smoother.
    config : PrefilterConfig, optional
        Model and noise settings; parameters left ``None`` are estimated from the log.
    engine : {"numpy", "filterpy"}
        ``numpy``: covariances once for all axes, steady-state runs in blocks (fast).
        ``filterpy``: ``filterpy.kalman.predict`` / ``update`` / ``rts_smoother`` per axis
        (the reference; about 100x slower).
    diagnostics : Diagnostics, optional
        Where the warnings (gaps) go instead of being warned.

    Returns
    -------
    PrefilterResult

    Raises
    ------
    InputError
        Bad shapes, non-finite values, non-increasing stamps, a bad mode, model or parameter
        (negative or NaN noise), an explicit rest interval too short for the Allan deviation, or,
        with no rest, a log whose spectrum holds no white noise to estimate a missing density.
    """
    omega_b, t_s = check_rates(omega_b, t_s, diagnostics)
    check_prefilter_mode(mode)
    if engine not in ("numpy", "filterpy"):
        raise InputError(f"Expected `engine` in ('numpy', 'filterpy'), got {engine!r}")
    cfg = PrefilterConfig() if config is None else config
    check_config(cfg)
    summary: dict[str, Any] = {
        "mode": mode,
        "model": cfg.model,
        "engine": engine,
        "n_samples": len(t_s),
    }
    dt_med = float(np.median(np.diff(t_s)))
    summary["rate_hz"] = 1.0 / dt_med
    rest = _find_rest(omega_b, t_s, cfg, dt_med, summary)
    cfg, bias0 = _resolve_noise(omega_b, t_s, cfg, rest, summary)
    cfg = _resolve_accel(omega_b, t_s, cfg, bias0, summary)
    m = build_model(omega_b, t_s, cfg, rest, bias0 if cfg.estimate_bias else None)
    run = run_fast if engine == "numpy" else run_filterpy
    X, P = run(omega_b, m, mode == "rts")
    bias_b = X[:, -1, :] if cfg.estimate_bias else None
    if bias_b is not None:
        summary["bias_final_rad_s"] = bias_b[-1].tolist()
    _stationary_summary(cfg, dt_med, summary)
    return PrefilterResult(
        omega_b=X[:, 0, :].copy(),
        rate_std_rad_s=np.repeat(np.sqrt(P[:, 0, 0])[:, None], 3, axis=1),
        angular_accel_b=X[:, 1, :].copy(),
        bias_b=None if bias_b is None else bias_b.copy(),
        rest=rest,
        mode=mode,
        config=cfg,
        summary=summary,
    )


def _find_rest(
    omega_b: NDArray, t_s: NDArray, cfg: PrefilterConfig, dt_med: float, summary: dict[str, Any]
) -> NDArray[np.bool_] | None:
    """The rest mask (None when neither the noise density nor the bias needs a rest). Without a
    given rate-spread limit, the limit is 1.5 times the given noise (per sample) or, without
    one, 1.5 times the quietest window's spread, and at least 0.01 rad/s."""
    if cfg.noise_density_rad_s_sqrt_hz is not None and not cfg.estimate_bias:
        return None
    max_std = cfg.rest_max_std_rad_s
    if max_std is None:
        floor = (
            cfg.noise_density_rad_s_sqrt_hz / math.sqrt(dt_med)
            if cfg.noise_density_rad_s_sqrt_hz is not None
            else quietest_std(omega_b, t_s, cfg.rest_window_s)
        )
        max_std = max(0.01, 1.5 * floor)
    rest = detect_rest(
        omega_b, t_s, RestConfig(cfg.rest_window_s, cfg.rest_max_rate_rad_s, max_std)
    )
    summary["rest_samples"] = int(rest.sum())
    return rest


def _rest_segment(
    t_s: NDArray, cfg: PrefilterConfig, rest: NDArray[np.bool_]
) -> tuple[int, int, str]:
    """Samples ``[i0, i1)`` of the rest to estimate the noise from (empty: use the spectrum), and
    where they came from. A given ``rest_interval_s`` must hold two samples; a detected rest
    must be long enough for the Allan deviation, else it is not used."""
    if cfg.rest_interval_s is not None:
        sel = (t_s >= cfg.rest_interval_s[0]) & (t_s <= cfg.rest_interval_s[1])
        idx = np.flatnonzero(sel)
        i0, i1 = (int(idx[0]), int(idx[-1]) + 1) if len(idx) else (0, 0)
        if i1 - i0 < 2:
            raise InputError(
                "Expected a rest segment (rest_interval_s) to estimate the gyro noise "
                "density, got none; pass noise_density_rad_s_sqrt_hz "
                "(replay: --gyro-noise-density)"
            )
        return i0, i1, "rest_interval_s"
    i0, i1 = longest_run(rest)
    if i1 - i0 < MIN_REST_SAMPLES or t_s[max(i1 - 1, i0)] - t_s[i0] < cfg.min_rest_s:
        i0 = i1 = 0  # no rest long enough for the Allan deviation: use the spectrum
    return i0, i1, "detected rest"


def _resolve_noise(
    omega_b: NDArray,
    t_s: NDArray,
    cfg: PrefilterConfig,
    rest: NDArray[np.bool_] | None,
    summary: dict[str, Any],
) -> tuple[PrefilterConfig, NDArray | None]:
    """The configuration with its noise density (given, from a rest, or from the spectrum) and
    the rest's mean rate (the bias, rad/s; None unless a rest gave the density)."""
    bias0 = None
    if cfg.noise_density_rad_s_sqrt_hz is None:
        i0, i1, source = _rest_segment(t_s, cfg, rest)
        if i1 > i0:
            density, bias0 = _noise_from_rest(
                omega_b[i0:i1], t_s[i0:i1], cfg.min_rest_s, source, summary
            )
        else:
            density = _noise_from_spectrum(omega_b, t_s, summary)
        cfg = replace(cfg, noise_density_rad_s_sqrt_hz=density)
    else:
        summary["noise_source"] = "given"
    summary["noise_density_rad_s_sqrt_hz"] = cfg.noise_density_rad_s_sqrt_hz
    return cfg, bias0


def _resolve_accel(
    omega_b: NDArray,
    t_s: NDArray,
    cfg: PrefilterConfig,
    bias0: NDArray | None,
    summary: dict[str, Any],
) -> PrefilterConfig:
    """The configuration with its process noise (the angular acceleration scale): given, or
    fitted by maximum likelihood to the rates less the rest bias."""
    if cfg.angular_accel_rad_s2 is None:
        z_fit = omega_b if bias0 is None else omega_b - bias0
        fit = fit_accel(z_fit, t_s, cfg.model, cfg.noise_density_rad_s_sqrt_hz)
        cfg = replace(cfg, angular_accel_rad_s2=fit["angular_accel_rad_s2"])
        summary["accel_source"] = "maximum likelihood"
        summary["accel_fit"] = fit
    else:
        summary["accel_source"] = "given"
    summary["angular_accel_rad_s2"] = cfg.angular_accel_rad_s2
    return cfg


def _stationary_summary(cfg: PrefilterConfig, dt_med: float, summary: dict[str, Any]) -> None:
    """The stationary posterior rate std of the causal filter at the median step, and the raw
    per-sample noise, rad/s, into ``summary``."""
    r_med = cfg.noise_density_rad_s_sqrt_hz**2 / dt_med
    nm = motion_order(cfg.model)
    p_med = stationary_prior(dt_med, nm, q_scale(cfg.model, cfg.angular_accel_rad_s2), r_med)
    summary["stationary_rate_std_rad_s"] = math.sqrt(p_med[0, 0] * r_med / (p_med[0, 0] + r_med))
    summary["raw_rate_std_rad_s"] = math.sqrt(r_med)


def _noise_from_rest(
    omega_b: NDArray, t_s: NDArray, min_rest_s: float, source: str, summary: dict[str, Any]
) -> tuple[float, NDArray]:
    """Noise density (RMS over the axes) from a rest segment's Allan deviation, and the rest
    mean rate (the bias, rad/s); what was found goes into ``summary``."""
    said = Diagnostics()  # the gaps were said once, by prefilter's check of the whole record
    est = estimate_noise_from_rest(omega_b, t_s, min_rest_s, diagnostics=said)
    arw = est.noise_density_rad_s_sqrt_hz
    summary.update(
        noise_source=f"Allan deviation of {source}",
        rest_interval_s=est.interval_s,
        angle_random_walk_rad_s_sqrt_hz=arw.tolist(),
        angle_random_walk_deg_sqrt_h=np.degrees(arw * 60).tolist(),
        bias_instability_rad_s=est.bias_instability_rad_s.tolist(),
        bias_instability_deg_h=np.degrees(est.bias_instability_rad_s * 3600).tolist(),
        bias_instability_tau_s=est.bias_instability_tau_s.tolist(),
        rest_mean_rate_rad_s=est.mean_rate_rad_s.tolist(),
    )
    return float(np.sqrt(np.mean(arw**2))), est.mean_rate_rad_s


def _noise_from_spectrum(omega_b: NDArray, t_s: NDArray, summary: dict[str, Any]) -> float:
    """Noise density (RMS over the axes) from the upper band of the log's spectrum (no rest);
    what was found goes into ``summary``."""
    said = Diagnostics()  # the gaps were said once, by prefilter's check
    est = estimate_noise_from_spectrum(omega_b, t_s, diagnostics=said)
    density = est.noise_density_rad_s_sqrt_hz
    summary.update(
        noise_source="spectrum of the log (no rest long enough for the Allan deviation)",
        spectrum_band_hz=est.band_hz,
        spectrum_noise_density_rad_s_sqrt_hz=density.tolist(),
    )
    return float(np.sqrt(np.mean(density**2)))

"""``--noise-params FILE.yaml``: the error budget of a scored replay, in one line.

What the gyro's noise alone would give over the scored time, what the integration method itself
adds on these samples, and the rest, set against the observed total RMS error:

* **Noise** (the noise parameters of ``imu-dcm-replay noise --yaml``, Kalibr's keys). From each
  anchor (the error is 0 there), per axis, angle random walk ``σ² = N² t``, rate random walk
  ``K² t³ / 3`` and a bias of the size of the bias instability ``B² t²`` (B is not a constant
  bias, so this term is an order of magnitude). Over three axes and averaged over a segment of
  length ``T``: ``E|θ|² = 1.5 N² T + K² T³ / 4 + B² T²``, weighted by the segments' lengths;
  the noise term is its square root (an RMS, like the observed one).
* **Method**: for a method other than ``magnus4``, the RMS angle between its estimate and
  ``magnus4``'s on the same rates and anchors (fourth order: its own error is far smaller, and
  both integrate the same noise samples, whose sum they share). For ``magnus4``, the same
  difference for ``coning`` (second order) times ``y²``, the mean squared rotation per step
  (``|ω| dt``, rad): two orders gain about ``y²``; an order of magnitude, said with ``~``.
* **The rest**: ``√(observed² − ARW² − method²)`` (independent sources add in quadrature; the
  angle random walk is the term a short rest determines well, K and B are often bounds only):
  bias left after the rest's estimate, scale factor, misalignment, timing, and the truth's own
  error. The line gives the angle random walk's share and, when K or B are given, the noise
  "up to" with them.
"""

from __future__ import annotations

import contextlib
import os
from dataclasses import dataclass

import numpy as np
import yaml

from imu_dcm.errors import InputError
from imu_dcm.metrics import attitude_error_deg
from imu_dcm.replay.compare import compare_methods

__all__ = ["NoiseParams", "budget", "budget_line", "read_noise_params"]


@dataclass(slots=True, frozen=True)
class NoiseParams:
    """Gyro noise in continuous time: ``N`` rad/s/√Hz, ``K`` rad/s²/√Hz, ``B`` rad/s (or 0)."""

    N: float
    K: float = 0.0
    B: float = 0.0


def read_noise_params(path: str | os.PathLike) -> NoiseParams:
    """Read ``gyroscope_noise_density`` (required), ``gyroscope_random_walk`` and
    ``gyroscope_bias_instability`` from a Kalibr-style YAML file.

    Raises
    ------
    InputError
        Unreadable file, or a key missing, not a number or negative.
    """
    try:
        with open(path, encoding="utf-8") as f:
            doc = yaml.safe_load(f)
    except (OSError, yaml.YAMLError, UnicodeDecodeError) as exc:
        raise InputError(
            f"Expected a readable YAML file for --noise-params, got {type(exc).__name__}: "
            f"{str(exc).splitlines()[0] if str(exc) else path}"
        ) from None
    if not isinstance(doc, dict) or "gyroscope_noise_density" not in doc:
        raise InputError(f"Expected gyroscope_noise_density in {str(path)!r}, got none")
    values = {}
    for key in ("gyroscope_noise_density", "gyroscope_random_walk", "gyroscope_bias_instability"):
        v = doc.get(key, 0.0)
        if isinstance(v, str):  # YAML 1.1 reads 2e-06 (no point) as text
            with contextlib.suppress(ValueError):
                v = float(v)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not (0 <= v < np.inf):
            raise InputError(f"Expected {key} a number >= 0 in {str(path)!r}, got {v!r}")
        values[key] = float(v)
    return NoiseParams(*values.values())


def _segments_s(result) -> list[float]:
    s = result.summary
    if s.scored_segments:
        return [x["end_s"] - x["start_s"] for x in s.scored_segments if x["samples"]]
    ok = np.flatnonzero(np.isfinite(result.error.total_deg))
    return [float(result.t_s[ok[-1]] - result.t_s[result.start_index])] if len(ok) else []


def noise_rms_deg(params: NoiseParams, lengths_s: list[float]) -> float:
    """RMS over the scored time of the total error the noise alone gives, deg."""
    T = np.asarray(lengths_s, dtype=float)
    if T.sum() <= 0:
        return float("nan")
    per = 1.5 * params.N**2 * T + params.K**2 * T**3 / 4.0 + params.B**2 * T**2
    return float(np.degrees(np.sqrt(np.sum(per * T) / np.sum(T))))


def _angle_rms_deg(q_a, q_b) -> float:
    ok = np.isfinite(q_a).all(axis=1) & np.isfinite(q_b).all(axis=1)
    if not ok.any():
        return float("nan")
    e = attitude_error_deg(q_a[ok], q_b[ok]).total_deg
    return float(np.sqrt(np.mean(e * e)))


def method_rms_deg(result) -> tuple[float, bool]:
    """The method's own error on these samples, deg, and whether it is an order of magnitude
    (``magnus4``: scaled from ``coning``'s)."""
    method = result.summary.method
    scored = np.isfinite(result.error.total_deg)
    if method == "magnus4":
        (row,) = compare_methods(result, ("coning",))
        diff = _angle_rms_deg(np.where(scored[:, None], row.q_est, np.nan), result.q_est)
        dt = np.diff(result.t_s, prepend=result.t_s[0])
        y2 = float(np.mean((np.linalg.norm(result.omega_b, axis=1) * dt)[scored] ** 2))
        return diff * y2, True
    (row,) = compare_methods(result, ("magnus4",))
    return _angle_rms_deg(np.where(scored[:, None], row.q_est, np.nan), result.q_est), False


def budget(result, params: NoiseParams) -> dict | None:
    """The budget of a scored replay (deg), or None without truth."""
    observed = result.summary.rms_error_deg
    if observed is None:
        return None
    lengths = _segments_s(result)
    noise = noise_rms_deg(params, lengths)
    arw = noise_rms_deg(NoiseParams(params.N), lengths)
    method, rough = method_rms_deg(result)
    rest = float(np.sqrt(max(observed**2 - arw**2 - method**2, 0.0)))
    return {
        "observed_rms_deg": observed,
        "noise_rms_deg": noise,
        "arw_rms_deg": arw,
        "method_rms_deg": method,
        "method_order_of_magnitude": rough,
        "rest_rms_deg": rest,
        "noise_density_rad_s_sqrt_hz": params.N,
        "random_walk_rad_s2_sqrt_hz": params.K,
        "bias_instability_rad_s": params.B,
    }


def _g(x: float) -> str:
    return f"{x:.2g}°" if abs(x) < 0.1 else f"{x:.2f}°"


def budget_line(b: dict | None) -> str:
    """``budget     observed RMS 3.72°; noise explains ~0.4° ..., the method ~0.001°, ...``."""
    if b is None:
        return "budget     not scored: no truth"
    obs, noise, arw = b["observed_rms_deg"], b["noise_rms_deg"], b["arw_rms_deg"]
    method = b["method_rms_deg"]
    walks = b["random_walk_rad_s2_sqrt_hz"] > 0 or b["bias_instability_rad_s"] > 0
    noise_text = f"~{_g(arw)} (angle random walk" + (
        f"; up to {_g(noise)} with K and B)" if walks else ")"
    )
    if arw >= 0.8 * obs:
        verdict = "the noise explains it: a better gyro, not a better calibration"
    elif noise >= 0.8 * obs:
        verdict = "only the random walk and instability terms reach it: check them on a longer rest"
    elif method >= 0.5 * obs:
        verdict = "the method dominates: a higher-order method or a higher rate"
    else:
        verdict = "the rest is bias, scale factor, misalignment or the truth: calibrate"
    return (
        f"budget     observed RMS {_g(obs)}; noise explains {noise_text}, the method "
        f"~{_g(method)}, the rest ~{_g(b['rest_rms_deg'])}: {verdict}"
    )

"""The synthetic gyro: each error term appears as specified and only when asked; seeded."""

from __future__ import annotations

import math

import numpy as np
import pytest

import data_synth
from data_synth.gyro import DEFAULT_EPOCH_NS, GyroModel, synthetic_gyro
from imu_dcm.errors import InputError
from imu_dcm.gyro.allan import noise_density_from_allan

EPS = np.finfo(float).eps  # 2.2e-16: unit round-off bounds below are multiples of it


@pytest.fixture(scope="module")
def still():
    """A body at rest for 1000 s (free body with zero rate): the gyro sees only its errors."""
    return data_synth.free_body(1000.0, omega0_b=(0.0, 0.0, 0.0))


@pytest.fixture(scope="module")
def top():
    return data_synth.simulate("heavy-top", duration_s=1.2, motion="looping")


def test_ideal_gyro_samples_the_truth_exactly(top):
    rec = synthetic_gyro(top, 2000.0)
    assert rec.t_s.shape == (2401,) and rec.t_ns.dtype == np.int64
    assert np.array_equal(rec.t_ns, DEFAULT_EPOCH_NS + np.arange(2401) * 500_000)
    _, w = top.at(rec.t_s)
    assert np.array_equal(rec.values, w)


@pytest.mark.parametrize("output", ["rate", "delta-angle"])
def test_white_noise_density_by_allan_deviation(still, output):
    density = 2e-3  # rad/s/√Hz
    rate_hz = 100.0
    rec = synthetic_gyro(
        still, rate_hz, model=GyroModel(noise_density_rad_s_sqrt_hz=density), output=output, seed=11
    )
    # Allan deviation of white rate noise: σ(τ) = N / √τ (imu_dcm.gyro.allan); 1e5 samples pin N to
    # ~1%, so the 10% bound is met with a wide margin on every axis.
    est = noise_density_from_allan(rec.rate_rad_s(), rate_hz)
    assert np.all(np.abs(est / density - 1.0) < 0.10)
    # Per-sample σ = N √rate (docs/design.md, "Ground truth"), checked directly as well.
    assert np.all(np.abs(rec.rate_rad_s().std(axis=0) / (density * math.sqrt(rate_hz)) - 1) < 0.02)


def test_constant_bias_appears_as_given(top):
    bias = (0.01, -0.02, 0.003)
    rec = synthetic_gyro(top, 500.0, model=GyroModel(bias_rad_s=bias))
    _, w = top.at(rec.t_s)
    # values = fl(w + b): one rounding, |error| <= eps/2 |w + b|; subtracting w adds at most as
    # much again. No sum over samples, but the bound scales with the rates (125 rad/s here).
    assert np.allclose(rec.values - w, bias, rtol=0, atol=2 * EPS * np.abs(rec.values).max())
    rec_d = synthetic_gyro(top, 500.0, model=GyroModel(bias_rad_s=bias), output="delta-angle")
    dt = np.diff(np.concatenate([[0.0], rec_d.t_s]))
    exact = top.delta_angles(np.concatenate([[0.0], rec_d.t_s]))
    assert np.allclose((rec_d.values - exact) / dt[:, None], bias, rtol=0, atol=1e-9)


def test_quantization_steps_and_error(top):
    step = 1e-3
    rec = synthetic_gyro(top, 1000.0, model=GyroModel(quantization_rad_s=step))
    _, w = top.at(rec.t_s)
    k = rec.values / step
    assert np.abs(k - np.round(k)).max() < 1e-6  # whole multiples of the step
    assert np.abs(rec.values - w).max() <= 0.5 * step * (1 + 1e-9)  # rounded, not truncated


def test_delta_angle_quantization_carries_the_residual(top):
    step = 1e-2  # rad/s → 1e-5 rad per sample at 1000 Hz
    rec = synthetic_gyro(
        top, 1000.0, model=GyroModel(quantization_rad_s=step), output="delta-angle"
    )
    grid = np.concatenate([[0.0], rec.t_s])
    exact = top.delta_angles(grid)
    # The accumulated angle never drifts more than half a step from the truth: rounding error
    # does not build up over 1200 samples (it would grow like √N without the carry).
    drift = np.abs(np.cumsum(rec.values - exact, axis=0)).max()
    assert drift <= 0.5 * step / 1000.0 * (1 + 1e-6)


def test_saturation_clips_at_the_range(top):
    rec = synthetic_gyro(top, 1000.0, model=GyroModel(range_rad_s=100.0))
    _, w = top.at(rec.t_s)
    # The spin (~125.7 rad/s about z) exceeds the 100 rad/s range: clipped there exactly.
    assert np.all(rec.values[:, 2] == 100.0)
    assert np.array_equal(rec.values[:, :2], w[:, :2])  # in range: untouched


def test_bias_random_walk_increments(still):
    k = 1e-4  # rad/s²/√Hz
    rec = synthetic_gyro(still, 100.0, model=GyroModel(bias_walk_rad_s2_sqrt_hz=k), seed=5)
    inc = np.diff(rec.values, axis=0)
    # Each step of the walk has σ = K √dt; 1e5 steps estimate σ to ~0.3%.
    assert np.all(np.abs(inc.std(axis=0) / (k * math.sqrt(0.01)) - 1.0) < 0.02)
    assert np.array_equal(rec.values[0], [0.0, 0.0, 0.0])  # the walk starts at zero


def test_stamp_jitter_moves_instants_and_truth_follows(top):
    jitter = 2e-5
    rec = synthetic_gyro(top, 2000.0, model=GyroModel(stamp_jitter_s=jitter), seed=2)
    offsets = rec.t_s - np.arange(rec.t_s.size) / 2000.0
    assert np.all(np.diff(rec.t_ns) > 0)
    # σ of the offsets (clipped at ±0.4 period = 2e-4 s, 10 σ: no effect) within 10% for 2400.
    assert abs(offsets[1:].std() / jitter - 1.0) < 0.1
    _, w = top.at(rec.t_s)
    assert np.array_equal(rec.values, w)  # stamps are the true instants of the samples
    assert np.array_equal(rec.t_ns - DEFAULT_EPOCH_NS, np.round(rec.t_s * 1e9).astype(np.int64))


def test_delta_angle_output_of_constant_rate_is_rate_times_dt():
    spin = data_synth.free_body(1.0, omega0_b=(0.0, 0.0, 2.0))  # constant rate about z
    rec = synthetic_gyro(spin, 100.0, output="delta-angle")
    assert rec.values.shape == (100, 3)
    # The exact delta angles are differences of the ODE's running integral θ (up to 2 rad), a
    # sum over the solver's steps: each step adds ~2 roundings of |θ|, the dense-output
    # polynomial ~16 more. nfev (>= steps) counts the terms: |error| <= 2 (nfev + 16) eps |θ|.
    atol = 2 * (spin.nfev + 16) * EPS * 2.0
    assert np.allclose(rec.values, [0.0, 0.0, 0.02], rtol=0, atol=atol)
    # rate = Δθ / Δt with Δt from ns stamps (relative error ~2 eps): atol / Δt + 4 eps · rate.
    assert np.allclose(rec.rate_rad_s(), [0.0, 0.0, 2.0], rtol=0, atol=atol / 0.01 + 4 * EPS * 2)
    assert rec.t_ns[0] == DEFAULT_EPOCH_NS + 10_000_000  # stamped at the end of interval 1


def test_same_seed_same_samples_other_seed_other_samples(top):
    model = GyroModel(
        noise_density_rad_s_sqrt_hz=1e-3, bias_walk_rad_s2_sqrt_hz=1e-3, stamp_jitter_s=1e-5
    )
    a = synthetic_gyro(top, 1000.0, model=model, seed=7)
    b = synthetic_gyro(top, 1000.0, model=model, seed=7)
    c = synthetic_gyro(top, 1000.0, model=model, seed=8)
    assert a.values.tobytes() == b.values.tobytes() and np.array_equal(a.t_ns, b.t_ns)
    assert not np.array_equal(a.values, c.values)


def test_terms_are_off_unless_given(top):
    assert GyroModel().as_dict() == {}
    assert GyroModel(bias_rad_s=(1, 2, 3)).as_dict() == {"bias_rad_s": [1.0, 2.0, 3.0]}


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"noise_density_rad_s_sqrt_hz": -1.0}, "noise_density"),
        ({"quantization_rad_s": 0.0}, "quantization"),
        ({"range_rad_s": float("nan")}, "range"),
        ({"bias_rad_s": (1.0, 2.0)}, "bias_rad_s"),
    ],
)
def test_model_rejects_bad_values(kwargs, match):
    with pytest.raises(InputError, match=match):
        GyroModel(**kwargs)


def test_sampling_rejects_bad_arguments(top):
    with pytest.raises(InputError, match="rate_hz"):
        synthetic_gyro(top, 0.0)
    with pytest.raises(InputError, match="duration_s"):
        synthetic_gyro(top, 100.0, duration_s=2.0)
    with pytest.raises(InputError, match="output"):
        synthetic_gyro(top, 100.0, output="angle")

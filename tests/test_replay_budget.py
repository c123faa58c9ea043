"""Tests of the error budget (``--noise-params``, imu_dcm.replay.budget): the noise term
against the observed error of synthetic gyros with white noise only, within the spread of the
observed error; the method term of a first-order method against the difference it stands for;
the YAML keys read and refused.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import raises_naming

from imu_dcm.errors import InputError
from imu_dcm.logio.writers import StampedSeries, write_bag
from imu_dcm.replay import replay
from imu_dcm.replay.budget import NoiseParams, budget, budget_line, read_noise_params

N_TRUE, RATE_HZ, SECONDS, LOGS = 2e-3, 200.0, 30.0, 16


def _still_log(path, seed):
    """A body at rest (identity truth) read by a gyro with white noise N only."""
    t = np.arange(int(SECONDS * RATE_HZ) + 1) / RATE_HZ
    rng = np.random.default_rng(seed)
    omega = rng.standard_normal((len(t), 3)) * N_TRUE * np.sqrt(RATE_HZ)
    t_ns = 1_700_000_000_000_000_000 + np.round(t * 1e9).astype(np.int64)
    q = np.tile([0.0, 0.0, 0.0, 1.0], (len(t), 1))
    quats = {"/ground_truth/orientation": StampedSeries(t_ns, q, "world")}
    return write_bag(path, imu=StampedSeries(t_ns, omega, "imu"), quaternions=quats)


def test_noise_term_matches_white_noise_within_its_spread(tmp_path):
    ratios = []
    for seed in range(LOGS):
        r = replay(_still_log(tmp_path / f"s{seed}", seed), bias="none")
        b = budget(r, NoiseParams(N_TRUE))
        ratios.append((b["observed_rms_deg"] / b["noise_rms_deg"]) ** 2)
        assert b["arw_rms_deg"] == b["noise_rms_deg"]  # no K, no B given
    # The observed mean square over [0, T] of a 3-axis Brownian angle has mean 1.5 N² T (the
    # budget's figure) and relative std sqrt(1/3)/(1/2)/sqrt(3) = 2/3 (per axis
    # Var ∫W² = T²/3 against a mean T/2). Over 16 independent logs the mean ratio has
    # std (2/3)/4 = 0.17: three of them bound it.
    assert abs(np.mean(ratios) - 1.0) < 3 * (2 / 3) / np.sqrt(LOGS)


def test_method_term_of_a_first_order_method_is_its_distance_to_magnus4(tmp_path):
    from data_synth.cli import main as synth_main

    out = tmp_path / "top"
    args = ["heavy-top", "--motion", "cusp", "--rate", "2000", "--duration", "1.2"]
    assert synth_main([*args, "--out", str(out)]) == 0
    end = replay(out, bias="none", method="end")
    b = budget(end, NoiseParams(0.0))
    # exact rate samples: end's error is all method; magnus4 is 6e-5° off here, so the
    # distance to magnus4 equals end's observed RMS to that
    assert b["method_rms_deg"] == pytest.approx(b["observed_rms_deg"], abs=1e-3)
    assert b["noise_rms_deg"] == 0 and "the method dominates" in budget_line(b)
    m4 = budget(replay(out, bias="none"), NoiseParams(0.0))
    # magnus4's own: coning's distance times y² (20 Hz spin at 2000 Hz: y ≈ 0.063 rad),
    # an order of magnitude of its observed 6e-5° RMS
    assert m4["method_order_of_magnitude"]
    assert 0.1 < m4["method_rms_deg"] / m4["observed_rms_deg"] < 10


def test_noise_params_yaml(tmp_path):
    good = tmp_path / "imu.yaml"
    good.write_text("gyroscope_noise_density: 1.5e-4\ngyroscope_random_walk: 2e-6\n")
    p = read_noise_params(good)
    assert (p.N, p.K, p.B) == (1.5e-4, 2e-6, 0.0)
    for text in ("rostopic: /imu\n", "gyroscope_noise_density: -1\n", "[1, 2]\n"):
        bad = tmp_path / "bad.yaml"
        bad.write_text(text)
        with raises_naming(InputError, str(bad)):
            read_noise_params(bad)
    with pytest.raises(InputError, match="readable YAML"):
        read_noise_params(tmp_path / "missing.yaml")

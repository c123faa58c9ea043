"""Rest is where the body does not rotate, confirmed by every signal the log has. Each case is
simulated with a known motion: its gyro is the body rate plus a known bias and noise, its
accelerometer the specific force of that motion (gravity alone at constant velocity or in a
hover), its truth the attitude the motion gives (scipy ``Rotation``, not the replay's code)."""

from __future__ import annotations

import warnings

import numpy as np
from scipy.spatial.transform import Rotation

from imu_dcm.gyro.rest_evidence import truth_noise_rad
from imu_dcm.gyro.rest_rule import GRAVITY_M_S2
from imu_dcm.logio.types import ImuSeries, LogData, TruthSeries
from imu_dcm.replay import replay
from imu_dcm.replay.bias import estimate_bias
from imu_dcm.replay.summary import format_summary

RATE_HZ = 200.0
DEG = np.pi / 180.0
G_B = np.array([0.0, 0.0, GRAVITY_M_S2])  # specific force of a level body not accelerating


def _noise(rng, n: int, sigma: float) -> np.ndarray:
    return sigma * rng.standard_normal((n, 3))


def test_a_hover_that_turns_slowly_is_not_rest():
    # A copter hovers 3 s, yawing at 1.3 °/s: its accelerometer reads gravity alone (a hover)
    # and its gyro is smooth, so both call it still. The truth turns as the gyro's mean says.
    rng = np.random.default_rng(21)
    n = int(3 * RATE_HZ)
    t = np.arange(n) / RATE_HZ
    rate = np.array([0.0, 0.0, 1.3 * DEG])
    w = rate + _noise(rng, n, 0.002)
    acc = G_B + _noise(rng, n, 0.03)
    q = Rotation.from_rotvec(np.outer(t, rate)).as_quat()
    assert estimate_bias(w, t, "auto", accel_b=acc).segments  # the gyro and accelerometer alone
    est = estimate_bias(w, t, "auto", accel_b=acc, truth_q_w_b=q)
    assert not est.segments and np.all(est.bias_b == 0.0)
    turned = float(est.conflict.split("the truth turns ")[1].split("°")[0])
    assert abs(turned - 1.3 * t[-1]) < 0.006, est.conflict  # 1.3 °/s over 2.995 s, rounded


def test_a_standing_persons_sway_is_not_rest():
    # A pelvis sways 1° at 0.25 Hz about x (rate peak 1.57 °/s, under the 2 °/s of a gyro-only
    # rest); no accelerometer. Every window of the log sways alike, so the gyro's floor is the
    # sway's; the truth's path follows the gyro's.
    rng = np.random.default_rng(22)
    n = int(12 * RATE_HZ)
    t = np.arange(n) / RATE_HZ
    f, amp = 0.25, 1.0 * DEG
    angle = amp * np.sin(2 * np.pi * f * t)
    bias = np.array([0.002, -0.001, 0.0015])
    w = bias + _noise(rng, n, 0.001)
    w[:, 0] += amp * 2 * np.pi * f * np.cos(2 * np.pi * f * t)
    q = Rotation.from_rotvec(np.outer(angle, [1.0, 0.0, 0.0])).as_quat()
    assert estimate_bias(w, t, "auto").segments  # the gyro alone cannot tell
    est = estimate_bias(w, t, "auto", truth_q_w_b=q)
    assert not est.segments, est.segments
    # the windows near the sway's turning points pass; over each, the truth turns as the gyro
    assert "as the gyro" in est.conflict, est.conflict


def _static_adis(rng, n: int):
    # An ADIS16448-like gyro at rest: 4.6 °/s bias, noise std 0.012 rad/s, no accelerometer.
    bias = np.array([4.6 * DEG, -1.0 * DEG, 0.5 * DEG])
    return bias, bias + _noise(rng, n, 0.012)


def test_a_large_bias_at_rest_is_found_from_the_logs_own_floor_and_a_static_truth():
    rng = np.random.default_rng(23)
    n = int(10 * RATE_HZ)
    t = np.arange(n) / RATE_HZ
    bias, w = _static_adis(rng, n)
    q = np.tile([0.0, 0.0, 0.0, 1.0], (n, 1))
    est = estimate_bias(w, t, "auto", truth_q_w_b=q)
    assert len(est.segments) == 1 and est.confirmed and est.conflict == ""
    seg = est.segments[0]
    assert (seg.start, seg.stop) == (0, n) and seg.evidence == ("gyro floor", "truth")
    # the whole log is the mean: within 4 standard errors (σ / √n) of the true bias
    assert np.all(np.abs(np.array(seg.bias_rad_s) - bias) < 4 * 0.012 / np.sqrt(n))
    # without the truth, nothing tells a 4.7 °/s mean from a turn
    alone = estimate_bias(w, t, "auto")
    assert not alone.segments and "mean |omega| (no accelerometer)" in alone.no_rest


def test_a_noisy_truth_at_rest_judges_its_noise_not_a_turn():
    # The truth at rest with white angle noise σ = 0.05° per axis: truth_noise_rad measures σ
    # (its median-based estimate has a spread of ~1.7 % over 2000 samples), and the rest stands.
    rng = np.random.default_rng(24)
    n = int(10 * RATE_HZ)
    t = np.arange(n) / RATE_HZ
    sigma = 0.05 * DEG
    q = Rotation.from_rotvec(_noise(rng, n, sigma)).as_quat()
    assert abs(truth_noise_rad(q) / sigma - 1.0) < 0.1
    bias, w = _static_adis(rng, n)
    est = estimate_bias(w, t, "auto", truth_q_w_b=q, truth_noise=truth_noise_rad(q))
    assert len(est.segments) == 1 and est.segments[0].evidence == ("gyro floor", "truth")


def test_replay_names_the_evidence_of_each_rest():
    # The static ADIS16448 log through replay: the summary names the signals (JSON and line).
    rng = np.random.default_rng(25)
    n = int(10 * RATE_HZ)
    t_ns = 1_000_000_000 + np.arange(n, dtype=np.int64) * 5_000_000
    _bias, w = _static_adis(rng, n)
    imu = ImuSeries(t_ns, t_ns, w, None, "/imu", "sensor_msgs/msg/Imu", "imu")
    # the sensor sits still on a table that is not quite level (2° and 1° of tilt)
    q = np.tile(Rotation.from_euler("xy", [2.0, 1.0], degrees=True).as_quat(), (n, 1))
    truth = TruthSeries(t_ns, t_ns, q, "/truth", "geometry_msgs/msg/PoseStamped", "world")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = replay(LogData("static.mcap", imu, truth, ()))
    s = res.summary
    assert [seg["evidence"] for seg in s.bias_segments] == [["gyro floor", "truth"]]
    assert s.to_dict()["bias_segments"][0]["evidence"] == ["gyro floor", "truth"]
    assert "1 rest segment (still by gyro floor, truth; interpolate)" in format_summary(s)
    # the bias removed is the log's mean, so the error is a Brownian bridge of the noise: per
    # axis variance σ² dt t (T - t) / T, over the log and three axes an RMS of
    # σ √(dt T / 2) = 0.11°; twice that bounds it with margin
    assert s.rms_error_deg < 2 * 0.012 * np.sqrt(0.005 * 10 / 2) / DEG
    # removing the bias changes the score by far more than 2x: the line gives the other score.
    # Without it the estimate turns at the constant bias, so the error is |b| t (noise aside)
    t_s = (t_ns - t_ns[0]) * 1e-9
    expected = np.linalg.norm(_bias) * np.sqrt(np.mean(t_s**2)) / DEG
    assert abs(s.rms_error_no_bias_deg - expected) < 0.01 * expected
    line = next(x for x in format_summary(s).splitlines() if "without the bias" in x)
    assert f"{s.rms_error_no_bias_deg:.2f}°" in line

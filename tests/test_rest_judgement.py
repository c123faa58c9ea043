"""Rest is stillness: the rate at its noise floor and, where the log has one, a still
accelerometer reading |a| = g. Each case is simulated with a known answer."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from imu_dcm.gyro.rest import detect_rest, explain_no_rest
from imu_dcm.gyro.rest_rule import GRAVITY_M_S2, RestConfig
from imu_dcm.replay.bias import estimate_bias

RATE_HZ = 200.0
DEG = np.pi / 180.0


def _still_accel(n: int, rng, sigma: float = 0.03) -> np.ndarray:
    return np.array([0.0, 0.0, GRAVITY_M_S2]) + sigma * rng.standard_normal((n, 3))


def test_smooth_constant_rate_with_vibration_is_not_rest():
    # A vehicle stands for 3 s (accelerometer noise 0.03 m/s²), then drives with a steady yaw
    # rate of 1.5 °/s: its gyro is as smooth as at rest (rate noise 0.002 rad/s throughout), but
    # its accelerometer vibrates (0.5 m/s² per axis), far above its own floor at the stand.
    rng = np.random.default_rng(1)
    n0, n = int(3 * RATE_HZ), int(20 * RATE_HZ)
    t = np.arange(n) / RATE_HZ
    w = 0.002 * rng.standard_normal((n, 3))
    w[n0:, 2] += 1.5 * DEG
    acc = _still_accel(n, rng)
    acc[n0:] = _still_accel(n - n0, rng, sigma=0.5)
    rest = detect_rest(w, t, accel_b=acc)
    assert rest[: n0 - 10].all() and not rest[n0 + 10 :].any()
    est = estimate_bias(w, t, "auto", accel_b=acc)
    assert len(est.segments) == 1 and est.segments[0].stop <= n0 + 1
    assert est.segments[0].evidence == ("gyro floor", "accelerometer")
    # without the stand nothing in the gyro or accelerometer tells the drive from rest (their
    # floors are the drive's): the truth does, turning at the gyro's 1.5 °/s about z
    drive, td = w[n0:], t[n0:] - t[n0]
    assert estimate_bias(drive, td, "auto", accel_b=acc[n0:]).segments
    q = Rotation.from_rotvec(np.outer(1.5 * DEG * td, [0, 0, 1])).as_quat()
    est = estimate_bias(drive, td, "auto", accel_b=acc[n0:], truth_q_w_b=q)
    assert not est.segments
    assert est.conflict.startswith("rest evidence conflicts: the gyro and the accelerometer")
    # the whole drive is one stretch; the truth turns 1.5 °/s over it (to print rounding)
    turned = float(est.conflict.split("the truth turns ")[1].split("°")[0])
    assert abs(turned - 1.5 * td[-1]) < 0.006, est.conflict


def test_large_bias_at_rest_is_found_with_an_accelerometer():
    # A 5 °/s bias (x and z), still accelerometer: the whole log is one rest segment and the
    # bias is its mean, within 4 standard errors of the noise (σ / √N per axis).
    rng = np.random.default_rng(2)
    n = int(10 * RATE_HZ)
    sigma = 0.003
    t = np.arange(n) / RATE_HZ
    bias = np.array([5.0 * DEG, -1.0 * DEG, 5.0 * DEG])
    w = bias + sigma * rng.standard_normal((n, 3))
    est = estimate_bias(w, t, "auto", accel_b=_still_accel(n, rng))
    assert len(est.segments) == 1 and est.confirmed
    seg = est.segments[0]
    assert (seg.start, seg.stop) == (0, n)
    assert np.all(np.abs(np.array(seg.bias_rad_s) - bias) < 4 * sigma / np.sqrt(n))


def test_large_bias_without_accelerometer_is_unconfirmed_and_says_by_how_much():
    # Without an accelerometer a 5 °/s mean cannot be told from a smooth turn: no rest, and the
    # line names the failed bound with the measured value.
    rng = np.random.default_rng(3)
    n = int(10 * RATE_HZ)
    t = np.arange(n) / RATE_HZ
    w = np.array([0.0, 0.0, 5.0 * DEG]) + 0.001 * rng.standard_normal((n, 3))
    assert not detect_rest(w, t).any()
    why = explain_no_rest(w, t)
    assert "mean |omega| (no accelerometer)" in why and "> 0.035" in why, why
    value = float(why.split("accelerometer) ")[1].split(" ")[0])
    assert abs(value - 5.0 * DEG) < 0.01 * 5.0 * DEG


def test_tilted_or_falling_accelerometer_is_not_rest():
    # |a| far from g (free fall, or a unit in g read as m/s²) is not stillness.
    rng = np.random.default_rng(4)
    n = int(5 * RATE_HZ)
    t = np.arange(n) / RATE_HZ
    w = 0.001 * rng.standard_normal((n, 3))
    acc = _still_accel(n, rng) / GRAVITY_M_S2  # in g, not m/s²
    assert not detect_rest(w, t, accel_b=acc).any()
    assert "| |a| - g |" in explain_no_rest(w, t, accel_b=acc)
    assert detect_rest(w, t, RestConfig(), _still_accel(n, rng)).all()


def test_interpolated_bias_follows_a_drift_between_rests():
    # Two rests with biases b1 and b2, motion between: the bias applied in the middle of the
    # motion is the mean of the two, at the rests each rest's own mean.
    rng = np.random.default_rng(5)
    seg = int(2 * RATE_HZ)
    b1, b2 = np.array([0.01, 0.0, 0.0]), np.array([0.02, 0.0, 0.0])
    move = np.tile([0.0, 0.0, 1.0], (seg, 1))  # 1 rad/s about z
    w = np.concatenate([b1 + 0 * move, move, b2 + 0 * move]) + 1e-4 * rng.standard_normal(
        (3 * seg, 3)
    )
    t = np.arange(3 * seg) / RATE_HZ
    est = estimate_bias(w, t, "auto", rule="interpolate")
    assert len(est.segments) == 2
    mid = 3 * seg // 2
    assert abs(est.bias_b[mid, 0] - 0.015) < 2e-4
    assert abs(est.bias_b[0, 0] - 0.01) < 1e-4 and abs(est.bias_b[-1, 0] - 0.02) < 1e-4

"""A sample rate too low for the motion: Richardson's estimate of the method's own error
against the true error on analytic pure coning (data_synth.analytic, exact rates and
attitude), and the replay's line when that error is most of the score."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from data_synth.analytic import coning_attitude, coning_rates
from imu_dcm.integrator.batch import integrate_quat
from imu_dcm.logio.types import ImuSeries, LogData, TruthSeries
from imu_dcm.replay import replay
from imu_dcm.replay.sampling import sampling_error_deg
from imu_dcm.replay.summary import format_summary
from imu_dcm.so3 import quat_angle_rad

BETA, FREQ_HZ = np.radians(30.0), 1.0  # a 30° cone swept once a second


def _true_rms_deg(rate_hz: float, method: str) -> tuple[float, float]:
    t = np.arange(0.0, 10.0, 1.0 / rate_hz)
    w = coning_rates(t, BETA, FREQ_HZ)
    q_true = coning_attitude(t, BETA, FREQ_HZ)
    q = integrate_quat(w, t, q_true[0], method)
    err = np.degrees(quat_angle_rad(q, q_true))
    return float(np.sqrt(np.mean(err**2))), sampling_error_deg(w, t, q, method)


@pytest.mark.parametrize(("method", "rate_hz"), [("magnus4", 24.0), ("coning", 50.0)])
def test_the_estimate_tracks_the_true_error_of_a_slow_rate(method, rate_hz):
    # In the asymptotic range the estimate is the leading error term: it misses only the next
    # one, a power of dt smaller (its relative size ~ 2 π f dt = 0.26 at 24 Hz, times the ratio
    # of the terms' constants): within 10 % of the true error
    true, est = _true_rms_deg(rate_hz, method)
    assert true > 1e-4 and abs(est / true - 1) < 0.1, (true, est)


def test_the_estimate_is_rounding_where_the_method_is_exact():
    # a constant-axis rotation is integrated exactly by every method
    t = np.arange(0.0, 5.0, 0.04)
    w = np.tile([0.0, 0.0, 2.0], (len(t), 1))
    q0 = np.array([0.0, 0.0, 0.0, 1.0])
    assert sampling_error_deg(w, t, integrate_quat(w, t, q0), "magnus4") < 1e-9


def test_replay_says_when_the_sampling_is_the_score():
    # A perfect gyro on the cone at 12 Hz with its exact attitude as truth: all of the error is
    # the sampling's, so the line names the rate and the estimate
    t = np.arange(0.0, 10.0, 1.0 / 12.0)
    t_ns = (1_000_000_000 + np.round(t * 1e9)).astype(np.int64)
    imu = ImuSeries(t_ns, t_ns, coning_rates(t, BETA, FREQ_HZ), None, "/imu", "Imu", "imu")
    q = coning_attitude(t, BETA, FREQ_HZ)
    truth = TruthSeries(t_ns, t_ns, q, "/truth", "PoseStamped", "world")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        s = replay(LogData("cone", imu, truth, ()), bias="none").summary
    assert s.sampling_error_deg > 0.5 * s.rms_error_deg
    line = next(x for x in format_summary(s).splitlines() if x.startswith("sampling"))
    assert "12 Hz is too slow" in line

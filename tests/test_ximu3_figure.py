"""The x-IMU3 foot log scored by the replay equals the same score computed independently with
scipy (R_est = R_truth(0) · Π exp(φ_k), error angle of R_truth^T R_est, RMS over every sample),
for each first-order increment φ_k: the rate at the start, at the end, or their mean over the
step. The strangers README's 4.6° (no bias) is the mean-rate (trapezoid) figure; the default
magnus4 scores differently on this 50 Hz log with 420 °/s peaks."""

from __future__ import annotations

import json

import numpy as np
import pytest
from drone_logs import XIMU3_INERTIAL, XIMU3_QUATERNION, ximu3_convert_argv
from scipy.spatial.transform import Rotation

from imu_dcm.replay.__main__ import main


@pytest.fixture(scope="module")
def converted(tmp_path_factory):
    out = tmp_path_factory.mktemp("xio") / "xio.mcap"
    argv = ximu3_convert_argv(out)
    assert main(argv) == 0
    return out


def _independent(rule: str) -> float:
    """RMS error (degrees) of the gyro-only estimate, from the two CSVs with numpy and scipy."""
    gyro = np.loadtxt(XIMU3_INERTIAL, delimiter=",", skiprows=1)
    quat = np.loadtxt(XIMU3_QUATERNION, delimiter=",", skiprows=1)
    assert np.array_equal(gyro[:, 0], quat[:, 0])  # shared stamps: joined row by row
    dt_s = np.diff(gyro[:, 0]) * 1e-6
    omega = np.radians(gyro[:, 1:4])
    rate = {"start": omega[:-1], "end": omega[1:], "trapezoid": 0.5 * (omega[:-1] + omega[1:])}
    truth = Rotation.from_quat(quat[:, [2, 3, 4, 1]])  # W,X,Y,Z -> scipy's x,y,z,w
    est = [truth[0]]
    for step in Rotation.from_rotvec(rate[rule] * dt_s[:, None]):
        est.append(est[-1] * step)
    angle = (truth.inv() * Rotation.concatenate(est)).magnitude()
    return float(np.degrees(np.sqrt(np.mean(angle**2))))


@pytest.mark.parametrize("rule", ["start", "end", "trapezoid"])
def test_the_replay_scores_as_scipy_does(converted, tmp_path, rule):
    s = tmp_path / "s.json"
    argv = [str(converted), "--rerun", "off", "--bias", "none", "--method", rule]
    assert main([*argv, "--summary-json", str(s)]) == 0
    got = json.loads(s.read_text())
    assert got["mounting_applied"] is False and got["truth_offset_s"] == 0.0
    assert got["truth_samples_used"] == 921  # every sample scored, from the truth's first
    # 920 steps in double precision: rounding stays far below 1e-9 rad
    assert got["rms_error_deg"] == pytest.approx(_independent(rule), abs=1e-6)
    if rule == "trapezoid":
        assert round(got["rms_error_deg"], 1) == 4.6  # the strangers README's figure

"""A gyro candidate must look like a gyro: an accelerometer published as a Vector3Stamped and
an Imu that marks its angular velocity absent are refused, with the channel that would work."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import raises_naming

from imu_dcm.errors import LogError
from imu_dcm.logio import read_log
from imu_dcm.logio.writers import StampedSeries, write_bag
from imu_dcm.replay.__main__ import main

N = 400
T_NS = 1_700_000_000_000_000_000 + np.arange(N, dtype=np.int64) * 5_000_000  # 200 Hz


def _accel(rng) -> np.ndarray:
    # a still accelerometer, tilted: 9.81 m/s² of gravity plus 0.05 m/s² of noise
    g = 9.80665 * np.array([0.1, -0.2, 0.97]) / np.linalg.norm([0.1, -0.2, 0.97])
    return g + 0.05 * rng.standard_normal((N, 3))


def _gyro(rng) -> np.ndarray:
    return np.array([0.0, 0.0, 0.5]) + 0.01 * rng.standard_normal((N, 3))


def test_accelerometer_as_vector3_is_refused_and_the_gyro_used(tmp_path):
    rng = np.random.default_rng(1)
    path = write_bag(
        tmp_path / "b",
        vectors={
            "/imu/accel": StampedSeries(T_NS, _accel(rng), "imu"),
            "/imu/gyro": StampedSeries(T_NS, _gyro(rng), "imu"),
        },
    )
    log = read_log(path)
    assert log.imu.topic == "/imu/gyro"
    (note,) = log.notes
    assert note.startswith("/imu/accel: refused as the gyro: |omega| stays at 9.8")
    assert "an accelerometer, not a gyro; using /imu/gyro" in note


def test_accelerometer_alone_is_refused_in_one_line(tmp_path, capsys):
    rng = np.random.default_rng(2)
    path = write_bag(tmp_path / "b", vectors={"/imu/accel": StampedSeries(T_NS, _accel(rng), "i")})
    with raises_naming(LogError, "/imu/accel", "|omega|", "9.81", "gyro"):
        read_log(path)
    assert main([str(path), "--rerun", "off", "--imu-topic", "/imu/accel"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "an accelerometer, not a gyro" in err[0], err


def test_imu_marking_its_gyro_absent_is_refused_naming_the_gyro_channel(tmp_path):
    rng = np.random.default_rng(3)
    absent = np.zeros((3, 3))
    absent[0, 0] = -1.0  # angular_velocity_covariance[0] = -1: no angular velocity
    path = write_bag(
        tmp_path / "b",
        imu=StampedSeries(T_NS, np.zeros((N, 3)), "imu"),
        imu_linear_acceleration=_accel(rng),
        imu_angular_velocity_covariance=absent,
        vectors={"/sensor/rates": StampedSeries(T_NS, _gyro(rng), "imu")},
    )
    with pytest.raises(LogError) as info:
        read_log(path)
    msg = str(info.value)
    assert "/imu/data: its messages mark the angular velocity absent" in msg
    assert "try /sensor/rates with --imu-topic" in msg
    assert read_log(path, imu_topic="/sensor/rates").imu.topic == "/sensor/rates"


def test_a_gyro_spinning_near_g_rad_s_with_spread_is_kept(tmp_path):
    # A rate norm near 9.8 rad/s that varies (a real fast turn) is a gyro.
    rng = np.random.default_rng(4)
    w = np.stack(
        [9.8 * np.sin(np.linspace(0, 6, N)), np.zeros(N), 9.8 * np.cos(np.linspace(0, 6, N))], 1
    )
    w[:, 2] += 3 * np.sin(np.linspace(0, 20, N)) + 0.01 * rng.standard_normal(N)
    path = write_bag(tmp_path / "b", vectors={"/gyro": StampedSeries(T_NS, w, "imu")})
    assert read_log(path).imu.topic == "/gyro"

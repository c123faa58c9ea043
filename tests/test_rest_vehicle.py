"""The autopilot's landed and armed state as rest evidence (PX4 ULog, ArduPilot DataFlash).

A hover holds the gyro at its floor and the accelerometer at g: only the vehicle's own state
tells it from a rest. The right answers here come from the synthetic log's construction (the
bias it was written with, the times it flew) or, for real logs, from the state topics read
with pyulog, independently of the reader.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from conftest import need_data

from imu_dcm.errors import ImuDcmWarning
from imu_dcm.gyro.rest import rest_segments
from imu_dcm.gyro.rest_rule import GRAVITY_M_S2
from imu_dcm.logio import read_log
from imu_dcm.logio.types import VehicleState
from tests.drone_logs import STRANGERS, ULogSpec, UTopic, write_ulog

RATE_HZ = 250.0
SIGMA = 0.003  # gyro noise, rad/s
BIAS_FLU = np.array([0.004, -0.003, 0.002])  # rad/s
YAW_DRIFT = np.radians(0.5)  # the hover's slow yaw, rad/s
# (start s, landed, armed): on the ground disarmed, armed, airborne (hover), landed, disarmed
PHASES = [(0.0, 1, 0), (5.0, 1, 1), (6.0, 0, 1), (16.0, 1, 1), (17.0, 1, 0)]
END_S = 22.0
AIRBORNE = (6.0, 16.0)


def _hover_arrays(seed: int = 7):
    """Gyro (FLU, rad/s) and accelerometer (FLU, m/s²) of the hover log, stamps in µs."""
    rng = np.random.default_rng(seed)
    t_s = np.arange(round(END_S * RATE_HZ)) / RATE_HZ
    w = BIAS_FLU + SIGMA * rng.standard_normal((len(t_s), 3))
    flying = (t_s >= AIRBORNE[0]) & (t_s < AIRBORNE[1])
    w[flying, 2] += YAW_DRIFT  # a constant slow turn: the gyro's spread stays at its floor
    a = np.array([0.0, 0.0, GRAVITY_M_S2]) + 0.02 * rng.standard_normal((len(t_s), 3))
    t_us = (1_000_000 + t_s * 1e6).round().astype(np.int64)
    return t_us, t_s, w, a


def _hover_ulog(path, with_state: bool = True):
    t_us, _t_s, w, a = _hover_arrays()
    frd = np.array([1.0, -1.0, -1.0])
    comb = UTopic(
        "sensor_combined",
        [
            ("uint64_t", 0, "timestamp"),
            ("float", 3, "gyro_rad"),
            ("int32_t", 0, "accelerometer_timestamp_relative"),
            ("float", 3, "accelerometer_m_s2"),
        ],
        {
            "timestamp": t_us,
            "gyro_rad": w * frd,
            "accelerometer_timestamp_relative": np.zeros(len(t_us)),
            "accelerometer_m_s2": a * frd,
        },
    )
    topics = [comb]
    if with_state:
        stamps = np.array([t_us[0] + round(p[0] * 1e6) for p in PHASES])
        topics += [
            UTopic(
                "vehicle_land_detected",
                [("uint64_t", 0, "timestamp"), ("bool", 0, "landed")],
                {"timestamp": stamps, "landed": np.array([p[1] for p in PHASES])},
            ),
            UTopic(
                "actuator_armed",
                [("uint64_t", 0, "timestamp"), ("bool", 0, "armed")],
                {"timestamp": stamps, "armed": np.array([p[2] for p in PHASES])},
            ),
        ]
    return write_ulog(path, ULogSpec(topics, start_us=int(t_us[0])))


def test_vehicle_state_holds_each_value_until_the_next():
    s = VehicleState.of("x", landed=([10, 30], [1, 0]), armed=([20], [1]))
    landed, armed = s.at(np.array([5, 10, 25, 30, 99]))
    assert landed.tolist() == [-1, 1, 1, 0, 0]
    assert armed.tolist() == [-1, -1, 1, 1, 1]
    assert VehicleState.of("x") is None


def test_ulog_reader_gives_the_written_state(tmp_path):
    log = read_log(_hover_ulog(tmp_path / "hover.ulg"))
    assert log.vehicle_state is not None
    assert log.vehicle_state.source == "vehicle_land_detected, actuator_armed"
    landed, armed = log.vehicle_state.at(log.imu.t_ns)
    t_s = (log.imu.t_ns - log.imu.t_ns[0]) * 1e-9
    ends = [p[0] for p in PHASES[1:]] + [END_S + 1.0]
    for (t0, want_landed, want_armed), t1 in zip(PHASES, ends, strict=True):
        inside = (t_s >= t0) & (t_s < t1)
        assert np.all(landed[inside] == want_landed) and np.all(armed[inside] == want_armed)
    assert read_log(_hover_ulog(tmp_path / "bare.ulg", False)).vehicle_state is None


def _tolerance(n: int) -> float:
    """Four standard errors of the mean of ``n`` samples of the gyro's noise, rad/s."""
    return 4.0 * SIGMA / np.sqrt(n)


def test_hover_is_not_rest_and_the_bias_is_the_written_one():
    t_us, t_s, w, a = _hover_arrays()
    landed = np.ones(len(t_s), np.int8)
    armed = np.zeros(len(t_s), np.int8)
    for t0, lv, av in PHASES:
        landed[t_s >= t0], armed[t_s >= t0] = lv, av
    segs, _conflict = rest_segments(w, t_s, accel_b=a, vehicle=(landed, armed))
    assert segs, "the log rests on the ground before and after the flight"
    for s in segs:
        assert s.end_s < AIRBORNE[0] or s.start_s >= AIRBORNE[1], (s.start_s, s.end_s)
        assert "landed state" in s.evidence or "landed state (part)" in s.evidence
        n = s.hi - s.lo
        np.testing.assert_allclose(s.bias_rad_s, BIAS_FLU, atol=_tolerance(n))
    # the same gyro and accelerometer without the state: the hover passes for a rest, and its
    # "bias" carries part of the yaw drift (what the state is there to prevent)
    bare, _ = rest_segments(w, t_s, accel_b=a)
    over = [s for s in bare if s.start_s < AIRBORNE[1] and s.end_s >= AIRBORNE[0]]
    assert over and abs(over[0].bias_rad_s[2] - BIAS_FLU[2]) > 0.25 * YAW_DRIFT


def test_a_log_airborne_throughout_says_so():
    from imu_dcm.gyro.rest import explain_no_rest

    _t_us, t_s, w, a = _hover_arrays()
    n = len(t_s)
    flying = (np.zeros(n, np.int8), np.ones(n, np.int8))
    assert rest_segments(w, t_s, accel_b=a, vehicle=flying)[0] == []
    why = explain_no_rest(w, t_s, accel_b=a, vehicle=flying)
    assert why.endswith("has the vehicle airborne on 100% of it (landed state)"), why


def test_hover_ulog_replay_says_landed_state(tmp_path):
    from imu_dcm.replay import replay

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ImuDcmWarning)
        summary = replay(_hover_ulog(tmp_path / "hover.ulg")).summary.to_dict()
    segs = summary["bias_segments"]
    assert segs
    for s in segs:
        assert s["end_s"] < AIRBORNE[0] or s["start_s"] >= AIRBORNE[1]
        assert any(e.startswith("landed state") for e in s["evidence"])
        # float32 rates in the log: rounding far under the noise's standard error
        np.testing.assert_allclose(s["bias_rad_s"], BIAS_FLU, atol=_tolerance(RATE_HZ * 3))


def _airborne_us(path) -> list[tuple[int, int]]:
    """The stretches (µs) where vehicle_land_detected says not landed, read with pyulog."""
    pyulog = pytest.importorskip("pyulog")
    u = pyulog.ULog(str(path), ["vehicle_land_detected"])
    d = u.get_dataset("vehicle_land_detected").data
    t, landed = d["timestamp"].astype(np.int64), d["landed"].astype(bool)
    out, start = [], None
    for ti, li in zip(t, landed, strict=True):
        if not li and start is None:
            start = ti
        elif li and start is not None:
            out.append((start, ti))
            start = None
    return out + ([(start, t[-1] + 10**9)] if start is not None else [])


@pytest.mark.parametrize(
    "name", ["sample_px4_events.ulg", "px4_fmuv5_flight.ulg", "px4_cubeorange_reset.ulg"]
)
def test_real_px4_rests_stay_out_of_the_flight(name):
    from imu_dcm.replay import replay

    path = need_data(STRANGERS / name)
    flights = _airborne_us(path)
    assert flights, f"{name} flies"
    log = read_log(path)
    t0_us = log.imu.t_ns[0] // 1000
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ImuDcmWarning)
        summary = replay(path).summary.to_dict()
    for s in summary["bias_segments"]:
        a, b = t0_us + s["start_s"] * 1e6, t0_us + s["end_s"] * 1e6
        for f0, f1 in flights:
            # PX4 stamps the state at publication; its sample time lies up to one gyro step
            # before (the rows the state is held on): a millisecond covers it
            assert b <= f0 + 1000 or a >= f1 - 1000, (name, s, (f0, f1))


# ------------------------------------------------------------------------------ ArduPilot
def _hover_dataflash(path):
    """The hover as a DataFlash log: IMU and the EV events of arming, take-off and landing."""
    pytest.importorskip("pymavlink")
    from tests.drone_logs import DFMessage, write_dataflash

    t_us, _t_s, w, a = _hover_arrays()
    frd = np.array([1.0, -1.0, -1.0])
    imu = [
        (int(t), 0, *map(float, wi), *map(float, ai))
        for t, wi, ai in zip(t_us, w * frd, a * frd, strict=True)
    ]
    # ArduPilot's LogEvent ids: ARMED 10, DISARMED 11, LAND_COMPLETE 18, NOT_LANDED 28; one
    # list per phase of PHASES
    events = [(18, 11), (10,), (28,), (18,), (11,)]
    ev = [
        (int(t_us[0] + round(p[0] * 1e6)), e)
        for p, ids in zip(PHASES, events, strict=True)
        for e in ids
    ]
    cols = ["TimeUS", "I", "GyrX", "GyrY", "GyrZ", "AccX", "AccY", "AccZ"]
    return write_dataflash(
        path,
        [DFMessage("IMU", "QBffffff", cols, imu), DFMessage("EV", "QB", ["TimeUS", "Id"], ev)],
    )


def test_dataflash_events_give_the_state(tmp_path):
    log = read_log(_hover_dataflash(tmp_path / "hover.bin"))
    assert log.vehicle_state is not None and log.vehicle_state.source == "EV"
    landed, armed = log.vehicle_state.at(log.imu.t_ns)
    t_s = (log.imu.t_ns - log.imu.t_ns[0]) * 1e-9
    ends = [p[0] for p in PHASES[1:]] + [END_S + 1.0]
    for (t0, want_landed, want_armed), t1 in zip(PHASES, ends, strict=True):
        inside = (t_s >= t0) & (t_s < t1)
        assert np.all(landed[inside] == want_landed) and np.all(armed[inside] == want_armed)


def test_dataflash_hover_is_not_rest(tmp_path):
    from imu_dcm.replay import replay

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ImuDcmWarning)
        summary = replay(_hover_dataflash(tmp_path / "hover.bin")).summary.to_dict()
    segs = summary["bias_segments"]
    assert segs
    for s in segs:
        assert s["end_s"] < AIRBORNE[0] or s["start_s"] >= AIRBORNE[1]
        assert any(e.startswith("landed state") for e in s["evidence"])
        np.testing.assert_allclose(s["bias_rad_s"], BIAS_FLU, atol=_tolerance(RATE_HZ * 3))


def _sitl(name: str):
    pytest.importorskip("pymavlink")
    return need_data(STRANGERS / name)


def _stat(path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``STAT`` (TimeUS, isFlying, Armed) read with pymavlink, record by record."""
    from pymavlink import DFReader

    r = DFReader.DFReader_binary(str(path))
    rows = []
    while (m := r.recv_match(type="STAT")) is not None:
        rows.append((m.TimeUS, m.isFlying, m.Armed))
    r.filehandle.close()
    return tuple(np.array(c) for c in zip(*rows, strict=True))


def test_sitl_ground_log_never_arms_and_rests_throughout():
    from imu_dcm.replay import replay

    path = _sitl("ardupilot_sitl_plane_ground.BIN")
    _t, flying, armed = _stat(path)
    assert not flying.any() and not armed.any()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ImuDcmWarning)
        summary = replay(path).summary.to_dict()
    (seg,) = summary["bias_segments"]
    log = read_log(path)
    length_s = (log.imu.t_ns[-1] - log.imu.t_ns[0]) * 1e-9
    assert seg["start_s"] == 0.0 and seg["end_s"] == pytest.approx(length_s)
    # the first STAT comes 0.16 s after the first IMU sample: the state covers the rest in part
    assert "landed state (part)" in seg["evidence"]


def test_sitl_flight_rests_end_before_it_flies():
    from imu_dcm.replay import replay

    path = _sitl("ardupilot_sitl_plane_flight.BIN")
    t_us, flying, armed = _stat(path)
    take_off_us = t_us[np.flatnonzero(flying)[0]]
    assert armed[: np.flatnonzero(flying)[0]].any(), "armed on the ground before take-off"
    log = read_log(path)
    t0_us = log.imu.t_ns[0] // 1000
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ImuDcmWarning)
        summary = replay(path).summary.to_dict()
    assert summary["bias_segments"]
    for s in summary["bias_segments"]:
        assert t0_us + s["end_s"] * 1e6 <= take_off_us
        # armed on the ground (motors may run) supports no rest
        assert not any(e.startswith("landed state") for e in s["evidence"])

"""``imu-dcm-replay info LOG``: what a log holds, driven as a user runs it.

The synthetic bag is written here with known counts, rates, a gap and declared intervals, so
every figure ``info`` prints is checked against what was written; the real logs beside the
repository (BROAD, PX4, ArduPilot) are checked against what their READMEs say they hold.
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from conftest import STRANGERS, need_data
from test_logio_euroc import SHIPPED, _csv, _dataset

from imu_dcm.logio.writers import StampedSeries, write_bag
from imu_dcm.replay.__main__ import main
from imu_dcm.replay.kinds import ESTIMATE, INDEPENDENT

T0_NS = 1_700_000_000_000_000_000
PERIOD_NS = 5_000_000  # 200 Hz


@pytest.fixture
def bag(tmp_path):
    """A bag: gyro at 200 Hz for 10 s with one 0.5 s hole at 4 s, truth at 100 Hz, a
    magnetometer-like Vector3Stamped at 200 Hz, and two declared intervals."""
    k = np.arange(2000, dtype=np.int64)
    t = T0_NS + k * PERIOD_NS
    t_gyro = t[(t < T0_NS + 4_000_000_000) | (t >= T0_NS + 4_500_000_000)]
    w = np.zeros((len(t_gyro), 3))
    q = np.tile([0.0, 0.0, 0.0, 1.0], (1000, 1))
    spans = [[T0_NS + 1_000_000_000, T0_NS + 3_000_000_000], [T0_NS + 6 * 10**9, T0_NS + 9 * 10**9]]
    return write_bag(
        tmp_path / "bag",
        imu=StampedSeries(t_gyro, w, "imu"),
        quaternions={"/ground_truth/orientation": StampedSeries(t[::2], q, "world")},
        vectors={"/imu/mag": StampedSeries(t, np.ones((2000, 3)), "imu")},
        imu_linear_acceleration=np.tile([0.0, 0.0, 9.81], (len(t_gyro), 1)),
        custom_data={"test.movement_intervals_stamp_ns": json.dumps(spans)},
    )


def test_info_json_gives_what_was_written(bag, capsys):
    assert main(["info", str(bag), "--json"]) == 0
    got = json.loads(capsys.readouterr().out)
    rows = {c["topic"]: c for c in got["channels"]}
    assert rows["/imu/data"]["count"] == 1900 and rows["/imu/data"]["role"] == "gyro"
    assert rows["/ground_truth/orientation"]["count"] == 1000
    assert rows["/imu/mag"]["count"] == 2000 and not rows["/imu/mag"]["exact"]
    # truth: 1000 stamps 10 ms apart: 999 steps of 10 ms: 9.99 s
    assert rows["/ground_truth/orientation"]["rate_hz"] == pytest.approx(100.0, rel=1e-12)
    assert rows["/ground_truth/orientation"]["duration_s"] == pytest.approx(9.99, abs=1e-9)
    assert got["gyro"] == "/imu/data" and got["gyro_count"] == 1900
    # the one hole: the last stamp before it is 3.995 s, the step 0.505 s
    assert got["gaps"] == [[pytest.approx(3.995, abs=1e-9), pytest.approx(0.505, abs=1e-9)]]
    (truth,) = got["truths"]
    assert truth["kind"] == "independent reference" and truth["picked"]
    (iv,) = got["intervals"]
    assert iv["name"] == "test.movement"
    assert iv["spans_s"] == [[1.0, 3.0], [6.0, 9.0]]
    assert "1900 samples" in got["accel"]


def test_info_lines_name_gyro_truth_gap_and_intervals(bag, capsys):
    assert main(["info", str(bag)]) == 0
    out = capsys.readouterr().out
    assert "gyro       /imu/data, frame imu: 1900 samples" in out
    assert "1 gap(s)" in out and "3.995 s (+0.505 s)" in out
    assert "independent reference, 1000 messages, the replay's truth" in out
    assert "test.movement: 2 (1.00-3.00 s, 6.00-9.00 s)" in out
    assert "warning" not in out


def test_info_as_a_module_and_on_bad_input(bag, tmp_path):
    run = subprocess.run(
        [sys.executable, "-m", "imu_dcm.replay", "info", str(bag / "bag.mcap")],
        capture_output=True,
        text=True,
    )
    assert run.returncode == 0, run.stderr
    assert "/imu/data" in run.stdout
    missing = subprocess.run(
        [sys.executable, "-m", "imu_dcm.replay", "info", str(tmp_path / "nope")],
        capture_output=True,
        text=True,
    )
    assert missing.returncode == 2
    assert str(tmp_path / "nope") in missing.stderr and "Traceback" not in missing.stderr


def test_info_on_broad_declares_its_movement_phases(broad_dir, capsys):
    bag = broad_dir / "05_undisturbed_slow_rotation_with_breaks_B"
    assert main(["info", str(bag), "--json"]) == 0
    got = json.loads(capsys.readouterr().out)
    # the BROAD README: 59212 IMU samples, 57203 ground-truth messages, 4 movement phases
    assert got["gyro_count"] == 59212
    assert got["truths"][0]["count"] == 57203
    assert got["truths"][0]["kind"] == "independent reference"
    (iv,) = got["intervals"]
    assert len(iv["spans_s"]) == 4
    # sample k is stamped k x 3.5 ms; the first phase starts at index 10111
    assert iv["spans_s"][0][0] == pytest.approx(10111 * 3.5e-3, abs=1e-9)


@pytest.mark.parametrize(
    ("name", "gyro", "truth", "kind"),
    [
        ("sample_px4_events.ulg", "sensor_combined", "vehicle_attitude", ESTIMATE),
        ("ardupilot_sitl_plane_flight.BIN", "IMU[0]", "SIM", INDEPENDENT),
    ],
)
def test_info_on_drone_logs_says_what_the_truth_is(name, gyro, truth, kind, capsys):
    path = need_data(STRANGERS / name)
    assert main(["info", str(path), "--json"]) == 0
    got = json.loads(capsys.readouterr().out)
    assert got["gyro"] == gyro
    assert (got["truths"][0]["topic"], got["truths"][0]["kind"]) == (truth, kind)
    kinds = {t["topic"]: t["kind"] for t in got["truths"]}
    if name.endswith(".BIN"):  # ATT is ArduPilot's estimate; POS holds positions only
        assert kinds["ATT"] == "the vehicle's own estimate" and kinds["POS"] == "positions only"


def _messages(bag):
    from mcap.reader import make_reader

    with open(bag / "bag.mcap", "rb") as f:
        return [(c.topic, s.name, m.log_time, m.data) for s, c, m in make_reader(f).iter_messages()]


@pytest.mark.parametrize("container", ["sqlite3", "ros1"])
def test_info_counts_the_same_in_other_containers(bag, tmp_path, container, capsys):
    from rosbags.typesys import Stores, get_typestore

    ros2 = get_typestore(Stores.ROS2_HUMBLE)
    if container == "sqlite3":
        from rosbags.rosbag2 import StoragePlugin, Writer

        path, w, store = tmp_path / "db", None, ros2
        w = Writer(path, version=9, storage_plugin=StoragePlugin.SQLITE3)
    else:
        from rosbags.rosbag1 import Writer

        path, store = tmp_path / "x.bag", get_typestore(Stores.ROS1_NOETIC)
        w = Writer(path)
    with w:
        conns = {}
        for topic, name, t, data in _messages(bag):
            if topic not in conns:
                conns[topic] = w.add_connection(topic, name, typestore=store)
            payload = data if container == "sqlite3" else ros2.cdr_to_ros1(data, name)
            w.write(conns[topic], t, payload)
    assert main(["info", str(path), "--json"]) == 0
    got = json.loads(capsys.readouterr().out)
    counts = {c["topic"]: c["count"] for c in got["channels"]}
    assert counts == {"/imu/data": 1900, "/ground_truth/orientation": 1000, "/imu/mag": 2000}
    assert len(got["gaps"]) == 1 and got["truths"][0]["kind"] == "independent reference"


def test_info_on_a_euroc_dataset_names_leica_as_positions_only(tmp_path, capsys):
    from imu_dcm.logio import read_log

    log = read_log(SHIPPED)  # the shipped trial, written as an ASL dataset
    trial = (log, log.imu.accel_b)
    root = _dataset(tmp_path / "ds", trial)
    _csv(
        root / "mav0" / "leica0" / "data.csv",
        "#timestamp [ns], p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m]",
        trial[0].truth.t_ns[:5],
        np.zeros((5, 3)),
    )
    assert main(["info", str(root), "--json"]) == 0
    got = json.loads(capsys.readouterr().out)
    kinds = {t["topic"]: (t["kind"], t["count"]) for t in got["truths"]}
    assert kinds["state_groundtruth_estimate0"][0] == INDEPENDENT
    assert kinds["leica0"] == ("positions only", 5)
    assert got["gyro"] == "imu0" and got["gyro_count"] == len(trial[0].imu.t_ns)


def _state_spans(phases, end_s: float, column: int) -> list[list[float]]:
    """Where a phase table's flag (column 1 landed, 2 armed) is true, to the log's end."""
    out = []
    for k, p in enumerate(phases):
        stop = phases[k + 1][0] if k + 1 < len(phases) else end_s
        if p[column]:
            if out and out[-1][1] == p[0]:
                out[-1][1] = stop
            else:
                out.append([p[0], stop])
    return out


@pytest.mark.parametrize("container", ["ulog", "dataflash"])
def test_info_lists_the_landed_and_armed_state_as_rest_evidence(tmp_path, container, capsys):
    # The hover logs of the rest tests: on the ground disarmed, armed, airborne, landed,
    # disarmed (PHASES, seconds from the first gyro sample); the log ends at its last sample.
    from test_rest_vehicle import END_S, PHASES, RATE_HZ, _hover_dataflash, _hover_ulog

    path = (
        _hover_ulog(tmp_path / "hover.ulg")
        if container == "ulog"
        else _hover_dataflash(tmp_path / "hover.bin")
    )
    end_s = (round(END_S * RATE_HZ) - 1) / RATE_HZ
    assert main(["info", str(path), "--json"]) == 0
    got = json.loads(capsys.readouterr().out)["vehicle"]
    assert got["source"] == (
        "vehicle_land_detected, actuator_armed" if container == "ulog" else "EV"
    )
    for key, column in (("landed_s", 1), ("armed_s", 2)):
        want = _state_spans(PHASES, end_s, column)
        assert np.allclose(got[key], want, atol=1e-6), (key, got[key], want)
    assert main(["info", str(path)]) == 0
    line = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("vehicle    "))
    assert f"landed 0.00-6.00 s, 16.00-{end_s:.2f} s; armed 5.00-17.00 s" in line
    assert "rest evidence" in line


def test_info_without_a_vehicle_state_says_so(bag, capsys):
    assert main(["info", str(bag), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["vehicle"] is None
    assert main(["info", str(bag)]) == 0
    assert "vehicle    none (no landed or armed state" in capsys.readouterr().out


def test_info_on_a_real_px4_log_gives_pyulogs_flight(capsys):
    # Between the landed spans the vehicle flies: the stretches pyulog reads as not landed
    from test_rest_vehicle import _airborne_us

    path = STRANGERS / "sample_px4_events.ulg"
    if not path.is_file():
        pytest.skip("sample_px4_events.ulg is absent (real logs of other projects)")
    pyulog = pytest.importorskip("pyulog")
    u = pyulog.ULog(str(path), ["sensor_combined"])
    t0_us = int(u.get_dataset("sensor_combined").data["timestamp"][0])
    assert main(["info", str(path), "--json"]) == 0
    landed = json.loads(capsys.readouterr().out)["vehicle"]["landed_s"]
    gaps = [(a[1], b[0]) for a, b in zip(landed[:-1], landed[1:], strict=True)]
    flights = [((f0 - t0_us) * 1e-6, (f1 - t0_us) * 1e-6) for f0, f1 in _airborne_us(path)]
    assert np.allclose(gaps, flights, atol=1e-3), (gaps, flights)

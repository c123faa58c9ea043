"""``--record``: the live run written as a ROS 2 bag as it goes, read back with the project's
reader and with rosbags — after a normal stop (WebSocket source, raw payloads as received) and
after SIGTERM to the command (UDP source)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from loopback import free_udp_port
from test_live_udp import sample_lines, send
from test_live_ws import IMU, SLICE, TRIAL, TRUTH, Publisher, decode_slice, read_slice, start_live

from imu_dcm.logio import read_log

EST = "/estimate/orientation"
REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def trial():
    if not TRIAL.is_dir():
        pytest.skip("shipped trial replay/broad_07_undisturbed_fast_rotation_B missing")
    return read_slice(SLICE[0], SLICE[0] + 600)


def rosbags_messages(bag: Path) -> dict[str, list]:
    """(header stamp ns, message) per topic, read with rosbags' AnyReader."""
    from rosbags.highlevel import AnyReader

    out: dict[str, list] = {}
    with AnyReader([bag]) as reader:
        for conn, _, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            st = msg.header.stamp
            out.setdefault(conn.topic, []).append((st.sec * 10**9 + st.nanosec, msg))
    return out


def check_bag(bag: Path, imu_t, imu_w, tr_t, tr_q, summary: dict) -> None:
    # the project's reader: gyro and truth exactly as sent, the estimate as the run ended
    log = read_log(bag)
    assert log.imu.topic == IMU
    assert np.array_equal(log.imu.t_ns, imu_t)
    assert np.array_equal(log.imu.omega_b, imu_w)
    assert log.truth.topic == TRUTH  # /estimate is never taken for the truth
    assert np.array_equal(log.truth.t_ns, tr_t)
    assert np.array_equal(log.truth.q_w_b, tr_q)
    est = read_log(bag, truth_topic=EST).truth
    assert len(est.t_ns) == summary["samples_estimated"]
    assert np.all(np.diff(est.t_ns) > 0)
    assert est.q_w_b[-1].tolist() == summary["final_q_w_b"]
    # rosbags: every topic, same counts and values
    msgs = rosbags_messages(bag)
    assert [t for t, _ in msgs[IMU]] == imu_t.tolist()
    assert msgs[IMU][-1][1].angular_velocity.z == imu_w[-1, 2]
    assert [t for t, _ in msgs[TRUTH]] == tr_t.tolist()
    assert len(msgs[EST]) == summary["samples_estimated"]
    q = msgs[EST][-1][1].quaternion
    assert [q.x, q.y, q.z, q.w] == summary["final_q_w_b"]


def test_record_after_a_normal_stop_websocket(trial, tmp_path):
    msgs = trial["messages"]
    pub = Publisher(trial["schemas"])
    bag = tmp_path / "live_bag"
    try:
        th, said, out, _ = start_live(
            f"ws://127.0.0.1:{pub.port}", bias="none", record=bag, idle_stop_s=1.0
        )
        pub.wait_subscribed()
        pub.publish(msgs, speed=10.0)
        th.join(60)
    finally:
        pub.stop()
    s = out["result"].summary
    assert s["record"] == str(bag), said
    imu_t, imu_w, tr_t, tr_q = decode_slice(msgs)
    check_bag(bag, imu_t, imu_w, tr_t, tr_q, s)
    # the IMU payloads are the bytes the server sent, under the server's schema
    from mcap.reader import make_reader

    with open(next(bag.glob("*.mcap")), "rb") as f:
        got = [bytes(m.data) for _, c, m in make_reader(f).iter_messages(topics=[IMU])]
    assert got == [p for topic, _, p in msgs if topic == IMU]


def test_record_after_sigterm_to_the_command(trial, tmp_path):
    msgs = trial["messages"]
    bag = tmp_path / "sigterm_bag"
    summary = tmp_path / "summary.json"
    port = free_udp_port()
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "imu_dcm.live",
            f"udp://127.0.0.1:{port}",
            "--rerun",
            "off",
            "--bias",
            "none",
            "--record",
            str(bag),
            "--summary-json",
            str(summary),
            "--no-status",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=env,
        cwd=tmp_path,
    )
    try:
        deadline = time.monotonic() + 30
        while not (bag / "metadata.yaml").is_file():  # the bag exists once the run is up
            assert proc.poll() is None and time.monotonic() < deadline
            time.sleep(0.05)
        time.sleep(0.3)
        send(sample_lines(msgs), ("127.0.0.1", port), tmp_path, 2000.0)
        time.sleep(0.5)
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 143, err.decode()  # 128 + SIGTERM: the exit-code convention
    text = out.decode()
    assert "stopped    stopped by SIGTERM" in text
    s = json.loads(summary.read_text())
    imu_t, imu_w, tr_t, tr_q = decode_slice(msgs)
    assert s["samples"] == len(imu_t)
    check_bag(bag, imu_t, imu_w, tr_t, tr_q, s)


def test_record_closed_cleanly_when_the_source_is_lost(trial, tmp_path):
    """The server goes away for good: after give_up_s the run stops by itself, says why, and
    the bag holds everything received."""
    msgs = trial["messages"][:400]
    pub = Publisher(trial["schemas"])
    bag = tmp_path / "lost_bag"
    try:
        th, said, out, _ = start_live(
            f"ws://127.0.0.1:{pub.port}", bias="none", record=bag, give_up_s=1.0
        )
        pub.wait_subscribed()
        pub.publish(msgs, speed=10.0)
        time.sleep(0.3)
    finally:
        pub.stop()
    th.join(60)
    assert not th.is_alive(), said
    s = out["result"].summary
    assert s["stopped"].startswith("source lost"), s["stopped"]
    imu_t, imu_w, tr_t, tr_q = decode_slice(msgs)
    check_bag(bag, imu_t, imu_w, tr_t, tr_q, s)

"""Live from UDP lines sent by a separate process on loopback: the same BROAD slice as the
WebSocket test (CSV gyro lines with exact decimal stamps, JSON truth lines), with malformed
lines, a burst of duplicates, a backward stamp and a swapped pair mixed in: each is counted,
none is fatal, and the final attitude equals replay's on the clean messages to 1e-9 deg."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from test_live_ws import (
    IMU,
    SLICE,
    TOL_DEG,
    TRIAL,
    angle_deg,
    decode_slice,
    live_thread,
    read_slice,
    replay_of,
)

SENDER = r"""
import socket, sys, time
path, host, port, rate = sys.argv[1], sys.argv[2], int(sys.argv[3]), float(sys.argv[4])
lines = open(path, "rb").read().splitlines()
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
t0 = time.monotonic()
for i, line in enumerate(lines):
    delay = t0 + i / rate - time.monotonic()
    if delay > 0:
        time.sleep(delay)
    s.sendto(line, (host, port))
"""


@pytest.fixture(scope="module")
def trial():
    if not TRIAL.is_dir():
        pytest.skip("shipped trial replay/broad_07_undisturbed_fast_rotation_B missing")
    return read_slice(*SLICE)


def sample_lines(messages: list) -> list[bytes]:
    """CSV ``sec.nanosec,gx,gy,gz`` (repr floats: exact) and JSON truth lines, in file order."""
    imu_t, imu_w, tr_t, tr_q = decode_slice(messages)
    out, i, j = [], 0, 0
    for topic, _, _ in messages:
        if topic == IMU:
            t = int(imu_t[i])
            w = [float(v) for v in imu_w[i]]
            out.append(f"{t // 10**9}.{t % 10**9:09d},{w[0]!r},{w[1]!r},{w[2]!r}".encode())
            i += 1
        else:
            q = ", ".join(repr(float(v)) for v in tr_q[j])
            out.append(f'{{"t_ns": {int(tr_t[j])}, "q_w_b": [{q}]}}'.encode())
            j += 1
    return out


def send(lines: list[bytes], address, tmp_path, rate_hz: float) -> None:
    f = tmp_path / "lines.txt"
    f.write_bytes(b"\n".join(lines))
    subprocess.run(
        [sys.executable, "-c", SENDER, str(f), address[0], str(address[1]), str(rate_hz)],
        check=True,
        timeout=120,
    )


def run_udp(lines, tmp_path, rate_hz=1500.0, **kw):
    live = live_thread("udp://127.0.0.1:0", idle_stop_s=1.0, **kw)
    said, out, addr, th = live.said, live.out, live.addr, live.thread
    assert live.ready.wait(20)
    send(lines, addr["address"], tmp_path, rate_hz)
    th.join(60)
    assert not th.is_alive()
    return out["result"], said


def test_udp_lines_equal_replay_with_bad_lines_counted(trial, tmp_path):
    msgs = trial["messages"]
    clean = sample_lines(msgs)
    imu_rows = [k for k, line in enumerate(clean) if not line.startswith(b"{")]
    lines = list(clean)
    # mixed in, from the back so the indices hold: a swapped pair (inside the reorder window),
    # a backward stamp (1 s before), a burst of 5 duplicates, 3 malformed lines
    a, b = imu_rows[400], imu_rows[401]
    lines[a], lines[b] = lines[b], lines[a]
    t300 = clean[imu_rows[300]].split(b",")
    sec, frac = t300[0].split(b".")
    back = b",".join([str(int(sec) - 1).encode() + b"." + frac] + t300[1:])
    lines.insert(imu_rows[300] + 1, back)
    k200 = imu_rows[200]
    lines[k200 + 1 : k200 + 1] = [clean[r] for r in imu_rows[196:201]]
    lines[imu_rows[100] + 1 : imu_rows[100] + 1] = [b"garbage", b"1.0,2.0,3.0", b'{"t_s": 1, ']
    res, _ = run_udp(lines, tmp_path, method="magnus4", bias="none")
    s = res.summary
    assert s["malformed"] == 3
    assert s["dropped_duplicate"] == 5
    assert s["dropped_backward"] == 1
    assert s["reordered"] == 1
    assert s["samples"] == len(imu_rows)
    assert s["gaps"] == []
    q_replay, rep = replay_of(msgs, tmp_path, "magnus4", "none")
    assert res.t_ns == int(rep.t_ns[-1])
    assert angle_deg(res.q_w_b, q_replay) <= TOL_DEG
    assert s["truth_samples_used"] == rep.summary.to_dict()["truth_samples_used"]
    assert s["rms_error_deg"] == pytest.approx(rep.summary.to_dict()["rms_error_deg"], rel=1e-9)


def test_udp_deg_per_s_and_fixed_bias_equal_replay(trial, tmp_path):
    """Rates sent in deg/s with --gyro-units deg/s and a constant bias give replay's attitude
    for the same bias in rad/s (conversion by the same DEG factor)."""
    msgs = trial["messages"][:800]
    imu_t, imu_w, _, _ = decode_slice(msgs)
    lines = []
    for line in sample_lines(msgs):
        if line.startswith(b"{"):
            lines.append(line)
            continue
        f = line.split(b",")
        w = [float(v) * 180.0 / np.pi for v in f[1:]]
        lines.append(f[0] + b"," + ",".join(repr(v) for v in w).encode())
    bias = np.array([0.002, -0.001, 0.0005])
    res, _ = run_udp(lines, tmp_path, method="trapezoid", bias=bias, gyro_units="deg/s")
    q_replay, _ = replay_of(msgs, tmp_path, "trapezoid", bias)
    # deg -> rad round trip: each rate carries a relative rounding of a few eps; over n steps
    # the attitude differs by at most ~n * |omega| * dt * 4 eps rad
    n = len(imu_t)
    bound_deg = np.degrees(n * np.abs(imu_w).max() * 0.0035 * 4 * np.finfo(float).eps) + 1e-12
    assert angle_deg(res.q_w_b, q_replay) <= bound_deg

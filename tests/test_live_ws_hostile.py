"""A WebSocket server that sends what the Foxglove protocol never sends: each bad message is
dropped, counted as malformed and said once in the project's words (no Python exception's
text), and the source goes on; when the server then closes, the client reconnects and takes the
next connection's samples."""

from __future__ import annotations

import json
import struct
import threading
import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from test_live_ws import live_thread

from imu_dcm.logio.writers import MSG_DEFINITIONS, cdr_messages, imu_doubles
from imu_dcm.so3 import angle_between_deg

server_mod = pytest.importorskip("websockets.sync.server")

N, RATE_HZ, W_Z = 101, 100, 0.5  # 1 s at 0.5 rad/s about z
IMU = {
    "id": 7,
    "topic": "/imu/data",
    "encoding": "cdr",
    "schemaName": "sensor_msgs/msg/Imu",
    "schemaEncoding": "ros2msg",
    "schema": MSG_DEFINITIONS["sensor_msgs/msg/Imu"],
}
DEEP = "[" * 100_000 + "]" * 100_000
BAD = [
    json.dumps({"op": "advertise", "channels": "not a list"}),
    json.dumps({"op": "advertise", "channels": [{k: v for k, v in IMU.items() if k != "id"}]}),
    '{"op": "advertise", "channels": ' + DEEP + "}",
    json.dumps({"op": "advertise", "channels": [{**IMU, "id": 8, "schema": 5}]}),
    json.dumps({"op": "unadvertise", "channelIds": "all"}),
]


def _payloads() -> list[bytes]:
    t_ns = 1_700_000_000 * 10**9 + np.arange(N, dtype=np.int64) * (10**9 // RATE_HZ)
    rates = np.tile([0.0, 0.0, W_Z], (N, 1))
    rows = cdr_messages(t_ns, "imu", imu_doubles(rates, None, None))
    return [bytes(r) for r in rows]


def _handler_factory():
    count = {"n": 0}

    def handler(conn):
        count["n"] += 1
        conn.send(json.dumps({"op": "serverInfo", "name": "hostile", "capabilities": []}))
        if count["n"] == 1:  # the first connection: bad messages only, then close
            for text in BAD:
                conn.send(text)
            time.sleep(0.5)
            return
        conn.send(json.dumps({"op": "advertise", "channels": [IMU]}))
        sub = json.loads(conn.recv(timeout=10))
        sid = sub["subscriptions"][0]["id"]
        for p in _payloads():
            conn.send(struct.pack("<BIQ", 1, sid, 0) + p)
        time.sleep(3.0)

    return handler


def test_bad_advertises_are_dropped_counted_said_once_and_the_client_reconnects():
    with server_mod.serve(
        _handler_factory(),
        "127.0.0.1",
        0,
        subprotocols=["foxglove.websocket.v1"],
        compression=None,
        max_size=None,
    ) as server:
        threading.Thread(target=server.serve_forever, daemon=True).start()
        port = server.socket.getsockname()[1]
        live = live_thread(f"ws://127.0.0.1:{port}", bias="none", method="magnus4", idle_stop_s=1.5)
        live.thread.join(60)
        server.shutdown()
    assert not live.thread.is_alive()
    s = live.out["result"].summary
    said = "\n".join(live.said)
    assert s["malformed"] == len(BAD)
    assert s["reconnects"] == 1 and s["samples"] == N
    for word in ("Error", "Traceback", "KeyError", "Recursion", "AttributeError"):
        assert word not in said, said
    assert said.count("counted as malformed") == 4  # once per kind: two bad channels, one kind
    q_end = Rotation.from_rotvec([0, 0, W_Z * (N - 1) / RATE_HZ]).as_quat()
    assert angle_between_deg(live.out["result"].q_w_b, q_end) < 1e-9


BAD_BINARY = [b"", b"\x01\x00\x00", b"\x07" + b"x" * 20, b"\xff"]


def test_a_short_or_unknown_binary_frame_is_dropped_counted_and_said_once():
    def handler(conn):
        conn.send(json.dumps({"op": "serverInfo", "name": "hostile", "capabilities": []}))
        conn.send(json.dumps({"op": "advertise", "channels": [IMU]}))
        sid = json.loads(conn.recv(timeout=10))["subscriptions"][0]["id"]
        for k, p in enumerate(_payloads()):
            conn.send(struct.pack("<BIQ", 1, sid, 0) + p)
            if k == 50:
                for b in BAD_BINARY:
                    conn.send(b)
        time.sleep(3.0)

    with server_mod.serve(
        handler, "127.0.0.1", 0, subprotocols=["foxglove.websocket.v1"], compression=None
    ) as server:
        threading.Thread(target=server.serve_forever, daemon=True).start()
        port = server.socket.getsockname()[1]
        live = live_thread(f"ws://127.0.0.1:{port}", bias="none", method="magnus4", idle_stop_s=1.0)
        live.thread.join(60)
        server.shutdown()
    s = live.out["result"].summary
    assert s["malformed"] == len(BAD_BINARY) and s["samples"] == N and s["reconnects"] == 0
    said = "\n".join(live.said)
    assert said.count("counted as malformed") == 2  # once per kind: short, unknown opcode

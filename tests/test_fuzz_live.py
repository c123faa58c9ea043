"""The fuzz campaign's live class: a bad message on each live source (stdin lines, UDP
datagrams, a Foxglove WebSocket server, MAVLink over UDP), among known good samples.

Each case is one run of ``python -m imu_dcm.live SOURCE --idle-stop 0.4 --summary-json F``
(bounded by ``fuzzlive.RUN_TIMEOUT_S``), with 1 to 4 bad messages of one damage class (garbage
bytes, truncated messages, huge numbers, NaN/Inf, wrong JSON types, deep nesting, out-of-range
stamps, oversize lines; for WebSocket and MAVLink their own frames) drawn from
``numpy.random.default_rng(SEED)``. For every case (:func:`fuzzlive.violations`):

* no traceback and no Python exception name in stdout or stderr; no hang;
* exit 0 (good samples were sent, as docs/live.md says) or 1/2, never another code;
* a ``--summary-json`` without NaN or Infinity, and the final attitude the exact spin;
* each bad message counted (malformed + NaN/Inf + implausible), and every good sample
  integrated: exactly on the lossless transports (stdin, WebSocket); on UDP the datagrams the
  system dropped (``lost_by_system``) close the account exactly.

The case lists are printed per class when one fails.
"""

from __future__ import annotations

import json
import struct
import threading
from concurrent.futures import ThreadPoolExecutor

import fuzzlive
import loopback
import numpy as np
import pytest

pytestmark = pytest.mark.slow

SEED = 20261202
N_GOOD = 201  # 1 s at 200 Hz


def _report(results: list[tuple[str, list[str]]]) -> None:
    bad = [f"{name}: {'; '.join(v)}" for name, v in results if v]
    assert not bad, f"{len(bad)} of {len(results)} cases failed:\n" + "\n".join(bad)


def _in_pairs(fn, cases):
    with ThreadPoolExecutor(2) as ex:  # two cores in CI: two runs at a time
        return list(ex.map(fn, cases))


def test_bad_lines_on_stdin(tmp_path):
    cases = fuzzlive.line_cases(np.random.default_rng([SEED, 1]), 3, N_GOOD, udp=False)

    def one(c):
        summary = tmp_path / f"{c.name}.json"
        proc = fuzzlive.start(fuzzlive.live_argv("-", summary), stdin=True)
        run = fuzzlive.finish(proc, summary, b"\n".join(c.lines()) + b"\n")
        v = fuzzlive.violations(run, expect_samples=True)
        if run.summary is not None and not v:
            s = run.summary
            if s["samples"] != c.n_good:
                v.append(f"{s['samples']} samples integrated of {c.n_good} good")
            if fuzzlive.bad_counted(s) != len(c.bad):
                v.append(f"{fuzzlive.bad_counted(s)} counted of {len(c.bad)} bad lines")
        return c.name, v

    _report(_in_pairs(one, cases))


def test_bad_datagrams_on_udp(tmp_path):
    cases = fuzzlive.line_cases(np.random.default_rng([SEED, 2]), 2, N_GOOD, udp=True)

    def one(c):
        summary = tmp_path / f"{c.name}.json"
        port = loopback.free_udp_port()
        proc = fuzzlive.start(fuzzlive.live_argv(f"udp://127.0.0.1:{port}", summary))
        if loopback.wait_bound(port, proc):
            fuzzlive.send_datagrams(port, c.lines())
        run = fuzzlive.finish(proc, summary)
        v = fuzzlive.violations(run, expect_samples=True)
        if run.summary is not None and not v:
            s = run.summary
            lost = s["lost_by_system"]
            # one line a datagram: every datagram is integrated, counted bad or lost
            if s["samples"] + fuzzlive.bad_counted(s) + lost != c.n_good + len(c.bad):
                v.append(
                    f"{s['samples']} samples + {fuzzlive.bad_counted(s)} counted + {lost} "
                    f"lost != {c.n_good} good + {len(c.bad)} bad"
                )
            if s["samples"] > c.n_good:
                v.append(f"{s['samples']} samples integrated of {c.n_good} good")
        return c.name, v

    _report(_in_pairs(one, cases))


# ------------------------------------------------------------------------- WebSocket
IMU_CHANNEL = {
    "id": 7,
    "topic": "/imu/data",
    "encoding": "cdr",
    "schemaName": "sensor_msgs/msg/Imu",
    "schemaEncoding": "ros2msg",
}
T0_NS = 1_700_000_000 * 10**9
STEP_NS = 10**9 // fuzzlive.RATE_HZ


def _cdr(t_ns: list[int], rates: list[list[float]]) -> list[bytes]:
    from imu_dcm.logio.writers import cdr_messages, imu_doubles

    rows = cdr_messages(np.array(t_ns, np.int64), "imu", imu_doubles(np.array(rates), None, None))
    return [bytes(r) for r in rows]


def _ws_bad(rng, k: int, good: bytes) -> tuple[str, bytes | str]:
    """One bad WebSocket message (kind, data: bytes a binary frame, str a text frame) to sit
    after good sample k; its stamp, where it has one, is a half step after k's."""
    t = T0_NS + k * STEP_NS + STEP_NS // 2
    kind = ("garbage", "truncated", "short", "opcode", "nan", "huge", "text", "deep", "advertise")[
        int(rng.integers(9))
    ]
    head = struct.pack("<BIQ", 1, 0, 0)  # subscription 0: the client's first
    if kind == "garbage":
        return kind, head + fuzzlive.garbage(rng, 1, 400)
    if kind == "truncated":
        return kind, head + good[: int(rng.integers(4, len(good) - 1))]
    if kind == "short":
        return kind, head[: int(rng.integers(1, len(head)))]
    if kind == "opcode":
        return kind, bytes([int(rng.integers(5, 256))]) + fuzzlive.garbage(rng, 0, 40)
    if kind in ("nan", "huge"):
        v = float(rng.choice([np.nan, np.inf, -np.inf])) if kind == "nan" else 1e30
        return kind, head + _cdr([t], [[0.0, v, 0.0]])[0]
    if kind == "text":
        return kind, fuzzlive.garbage(rng, 1, 200).decode("latin-1")
    if kind == "deep":
        d = int(rng.integers(1000, 100_000))
        return kind, '{"op": "advertise", "channels": ' + "[" * d + "]" * d + "}"
    bad = [
        {"op": "advertise", "channels": "not a list"},
        {"op": "advertise", "channels": [{"topic": "/x"}]},
        {"op": "advertise", "channels": [{**IMU_CHANNEL, "id": 9, "schema": 5}]},
    ]
    return kind, json.dumps(bad[int(rng.integers(len(bad)))])


def _ws_handler(good: list[bytes], bad: dict[int, list], schema: str):
    from websockets.exceptions import ConnectionClosed

    count = {"n": 0}

    def handler(conn):
        count["n"] += 1
        conn.send(json.dumps({"op": "serverInfo", "name": "fuzz", "capabilities": []}))
        conn.send(json.dumps({"op": "advertise", "channels": [{**IMU_CHANNEL, "schema": schema}]}))
        sub = json.loads(conn.recv(timeout=10))
        sid = sub["subscriptions"][0]["id"]
        if count["n"] == 1:
            for k, p in enumerate(good):
                conn.send(struct.pack("<BIQ", 1, sid, 0) + p)
                for _kind, data in bad.get(k, []):
                    if isinstance(data, bytes) and data[:1] == b"\x01" and len(data) >= 5:
                        data = data[:1] + struct.pack("<I", sid) + data[5:]
                    conn.send(data)
        try:
            while True:
                conn.recv(timeout=fuzzlive.RUN_TIMEOUT_S)
        except (ConnectionClosed, TimeoutError):
            return

    return handler


def test_bad_messages_from_a_websocket_server(tmp_path):
    server_mod = pytest.importorskip("websockets.sync.server")
    from imu_dcm.logio.writers import MSG_DEFINITIONS

    rng = np.random.default_rng([SEED, 3])
    t_ns = [T0_NS + k * STEP_NS for k in range(N_GOOD)]
    good = _cdr(t_ns, [[0.0, 0.0, np.radians(fuzzlive.SPIN_DEG_S)]] * N_GOOD)
    results = []
    for i in range(12):
        bad: dict[int, list] = {}
        for k in rng.integers(0, N_GOOD - 1, int(rng.integers(1, 4))):
            bad.setdefault(int(k), []).append(_ws_bad(rng, int(k), good[int(k)]))
        kinds = sorted(kind for msgs in bad.values() for kind, _ in msgs)
        name = f"ws-{i}-{'+'.join(kinds)}"
        summary = tmp_path / f"ws-{i}.json"
        with server_mod.serve(
            _ws_handler(good, bad, MSG_DEFINITIONS["sensor_msgs/msg/Imu"]),
            "127.0.0.1",
            0,
            subprotocols=["foxglove.websocket.v1"],
            compression=None,
            max_size=None,
        ) as server:
            threading.Thread(target=server.serve_forever, daemon=True).start()
            port = server.socket.getsockname()[1]
            argv = fuzzlive.live_argv(f"ws://127.0.0.1:{port}", summary)
            argv[argv.index("--gyro-units") + 1] = "rad/s"
            # the idle time counts from the start: connecting on a loaded machine takes time
            argv[argv.index("--idle-stop") + 1] = "1.0"
            run = fuzzlive.finish(fuzzlive.start(argv), summary)
            server.shutdown()
        v = fuzzlive.violations(run, expect_samples=True)
        if run.summary is not None and not v:
            s = run.summary
            if s["samples"] != N_GOOD:
                v.append(f"{s['samples']} samples integrated of {N_GOOD} good")
            n_bad = len(kinds)
            if fuzzlive.bad_counted(s) != n_bad:
                v.append(f"{fuzzlive.bad_counted(s)} counted of {n_bad} bad messages")
        results.append((name, v))
    _report(results)


# --------------------------------------------------------------------------- MAVLink
MAV_W_Z = 1.5  # rad/s about FRD z (exact in float32 and in mrad/s): -1.5 about FLU z
MAV_T0_US = 10_000_000


def _mav_stream(rng, kind: str):
    """The datagrams of one MAVLink case: a good IMU message per 5 ms, and 1 to 4 bad ones
    after random good ones. Returns (datagrams, good count, value-damaged count, bad count)."""
    from pymavlink.dialects.v20 import common

    mav = common.MAVLink(None, srcSystem=1, srcComponent=1)

    def imu(t_us, wz):
        if kind == "highres":
            return mav.highres_imu_encode(t_us, 0, 0, -9.8, 0, 0, wz, 0, 0, 0, 0, 0, 0, 0, 0x3F)
        if kind == "scaled":
            return mav.scaled_imu_encode(t_us // 1000, 0, 0, -1000, 0, 0, int(wz * 1000), 0, 0, 0)
        return mav.raw_imu_encode(t_us, 0, 0, -1000, 0, 0, int(wz / 5e-4), 0, 0, 0)

    # SCALED_IMU's time_boot_ms (uint32 ms) has no value out of range; its int16 rates no NaN
    damage = ["garbage", "truncated", "flip"]
    damage += ["stamp", "nan", "huge"] if kind == "highres" else ["stamp"] if kind == "raw" else []
    after = {int(a) for a in rng.integers(0, N_GOOD - 1, int(rng.integers(1, 5)))}
    out, n_value, n_bad = [], 0, 0
    for k in range(N_GOOD):
        t_us = MAV_T0_US + k * 5000
        out.append(imu(t_us, MAV_W_Z).pack(mav))
        if k not in after:
            continue
        d = damage[int(rng.integers(len(damage)))]
        n_bad += 1
        if d == "garbage":
            out.append(fuzzlive.garbage(rng, 1, 300))
        elif d in ("truncated", "flip"):
            p = bytearray(imu(t_us + 2500, MAV_W_Z).pack(mav))
            if d == "truncated":
                p = p[: int(rng.integers(1, len(p) - 1))]
            else:
                p[int(rng.integers(1, len(p)))] ^= 1 << int(rng.integers(8))
            out.append(bytes(p))
        elif d == "stamp":
            out.append(imu(2**64 - 1, MAV_W_Z).pack(mav))
        else:
            n_value += 1
            v = float(rng.choice([np.nan, np.inf, -np.inf])) if d == "nan" else 3e38
            out.append(imu(t_us + 2500, v).pack(mav))
    return out, N_GOOD, n_value, n_bad


def test_bad_messages_over_mavlink(tmp_path):
    pytest.importorskip("pymavlink")
    kinds = ["highres"] * 4 + ["scaled"] * 3 + ["raw"]

    def one(args):
        i, kind = args
        datagrams, n_good, n_value, n_bad = _mav_stream(np.random.default_rng([SEED, 4, i]), kind)
        summary = tmp_path / f"mav-{i}.json"
        port = loopback.free_udp_port()
        url = f"mavlink:udpin:127.0.0.1:{port}" + (
            "?raw_gyro_scale=0.0005" if kind == "raw" else ""
        )
        argv = fuzzlive.live_argv(url, summary)
        argv[argv.index("--gyro-units") + 1] = "rad/s"
        if kind == "raw":  # no sample while RAW_IMU waits 1 s for a scaled one: no idle stop
            argv[argv.index("--idle-stop") + 1] = "1.5"
        proc = fuzzlive.start(argv)
        if loopback.wait_bound(port, proc):
            # RAW_IMU is taken after 1 s of wall time without a scaled message: 1.2 s of it
            fuzzlive.send_datagrams(port, datagrams, *((1, 0.006) if kind == "raw" else ()))
        run = fuzzlive.finish(proc, summary)
        v = fuzzlive.violations(run, expect_samples=True, rate_z_rad_s=-MAV_W_Z)
        if run.summary is not None and not v:
            s = run.summary
            lost = s["lost_by_system"]
            floor = 0 if kind == "raw" else n_good - lost  # RAW_IMU waits 1 s for a scale
            if not floor <= s["samples"] <= n_good:
                v.append(f"{s['samples']} samples integrated of {n_good} good ({lost} lost)")
            if s["dropped_nonfinite"] + s["dropped_implausible"] > n_value:
                v.append("more rates dropped than were damaged")
            if fuzzlive.bad_counted(s) + lost < min(n_bad, 1):
                v.append(f"none of {n_bad} bad messages counted")
        return f"mav-{i}-{kind}", v, run.summary

    results = _in_pairs(one, list(enumerate(kinds)))
    _report([(n, v) for n, v, _ in results])

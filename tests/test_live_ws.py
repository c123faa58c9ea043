"""Live from a real Foxglove WebSocket server (foxglove-sdk, on 127.0.0.1) publishing the CDR IMU
and truth messages of the shipped BROAD trial 07 at 5x speed.

The final attitude must equal replay's on the same messages (written to a bag with the project's
writer) to 1e-9 deg; killing the server mid-stream and starting it again must end in a reconnect,
one reported gap of exactly the skipped stretch, and the attitude replay gives for the messages
that were published.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from imu_dcm.errors import GapWarning, ImuDcmWarning
from imu_dcm.integrator.batch import integrate_quat
from imu_dcm.live import run
from imu_dcm.logio.writers import StampedSeries, write_bag
from imu_dcm.metrics import attitude_error_deg
from imu_dcm.replay import replay

foxglove = pytest.importorskip("foxglove")

TRIAL = Path(__file__).resolve().parents[1] / "replay" / "broad_07_undisturbed_fast_rotation_B"
IMU, TRUTH = "/imu/data", "/ground_truth/orientation"
SPEED = 5.0
#: Slice of the trial (IMU message indices): inside the motion, with optical truth.
SLICE = (9000, 10400)
TOL_DEG = 1e-9


def read_slice(lo: int, hi: int) -> dict:
    """Raw CDR messages of the slice, in file order: (topic, log_time_ns, payload), schemas."""
    from mcap.reader import make_reader

    mcap = next(TRIAL.glob("*.mcap"))
    out, schemas, n_imu = [], {}, -1
    with open(mcap, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages(topics=[IMU, TRUTH]):
            schemas[channel.topic] = schema
            if channel.topic == IMU:
                n_imu += 1
            if lo <= n_imu < hi and not (channel.topic == TRUTH and n_imu == lo - 1):
                out.append((channel.topic, message.log_time, bytes(message.data)))
            if n_imu >= hi:
                break
    return {"messages": out, "schemas": schemas}


def decode_slice(messages: list) -> tuple:
    """Stamps and values of the slice's messages (independent of live: plain struct reads of the
    fixed CDR layouts written by BROAD's converter: header with frame id, then doubles)."""
    import struct

    def head(p: bytes) -> tuple[int, int]:
        sec, nsec, n = struct.unpack_from("<iII", p, 4)
        off = 16 + n
        off += (-(off - 4)) % 8
        return sec * 1_000_000_000 + nsec, off

    imu_t, imu_w, tr_t, tr_q = [], [], [], []
    for topic, _, p in messages:
        t, off = head(p)
        if topic == IMU:
            # orientation (4), orientation_covariance (9), angular_velocity (3)
            vals = struct.unpack_from("<16d", p, off)
            imu_t.append(t)
            imu_w.append(vals[13:16])
        else:
            tr_t.append(t)
            tr_q.append(struct.unpack_from("<4d", p, off))
    return (np.array(imu_t, np.int64), np.array(imu_w), np.array(tr_t, np.int64), np.array(tr_q))


def replay_of(messages: list, tmp: Path, method: str, bias) -> np.ndarray:
    """Replay's final attitude on these messages (written as a bag with the project's writer)."""
    imu_t, imu_w, tr_t, tr_q = decode_slice(messages)
    bag = tmp / f"slice_{len(messages)}_{method}"
    write_bag(
        bag,
        imu=StampedSeries(imu_t, imu_w, "imu"),
        quaternions={TRUTH: StampedSeries(tr_t, tr_q, "world")},
    )
    res = replay(bag, method=method, bias=bias)
    return res.q_est[-1], res


class Publisher:
    """A foxglove-sdk WebSocket server on 127.0.0.1 with the trial's two channels."""

    def __init__(self, schemas: dict, port: int = 0) -> None:
        self.ctx = foxglove.Context()
        self.channels = {}
        for topic, sc in schemas.items():
            self.channels[topic] = foxglove.Channel(
                topic,
                schema=foxglove.Schema(name=sc.name, encoding=sc.encoding, data=sc.data),
                message_encoding="cdr",
                context=self.ctx,
            )
        self.server = None
        self.start(port)

    def start(self, port: int = 0) -> None:
        self.server = foxglove.start_server(
            host="127.0.0.1", port=port, context=self.ctx, message_backlog_size=1 << 16
        )
        self.port = self.server.port

    def stop(self) -> None:
        self.server.stop()

    def wait_subscribed(self, timeout_s: float = 20.0) -> None:
        deadline = time.monotonic() + timeout_s
        while not all(c.has_sinks() for c in self.channels.values()):
            if time.monotonic() > deadline:
                raise TimeoutError("no client subscribed to both channels")
            time.sleep(0.01)

    def publish(self, messages: list, speed: float = SPEED) -> None:
        """Publish at ``speed`` x the recorded rate (paced by the log times)."""
        t0_log, t0 = messages[0][1], time.monotonic()
        for topic, log_ns, payload in messages:
            delay = t0 + (log_ns - t0_log) * 1e-9 / speed - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            self.channels[topic].log(payload, log_time=log_ns)


@pytest.fixture(scope="module")
def trial():
    if not TRIAL.is_dir():
        pytest.skip("shipped trial replay/broad_07_undisturbed_fast_rotation_B missing")
    return read_slice(*SLICE)


@dataclass
class LiveThread:
    """A live run in a thread: what it said, its result once done (``out["result"]``), the
    event that stops it, and the source's address once it is up (``ready``, ``addr``)."""

    thread: threading.Thread
    said: list[str]
    out: dict
    stop: threading.Event
    ready: threading.Event
    addr: dict


def live_thread(source: str, say=None, **kw) -> LiveThread:
    """Start ``imu_dcm.live.run(source, **kw)`` in a thread, without a view or status line."""
    said: list[str] = []
    out: dict = {}
    addr: dict = {}
    stop, ready = threading.Event(), threading.Event()

    def on_ready(info):
        addr.update(info)
        ready.set()

    def target():
        out["result"] = run(
            source,
            rerun="off",
            status=False,
            say=say or said.append,
            stop=stop,
            on_ready=on_ready,
            **kw,
        )

    th = threading.Thread(target=target, daemon=True)
    th.start()
    return LiveThread(th, said, out, stop, ready, addr)


def start_live(url: str, **kw):
    live = live_thread(url, **kw)
    return live.thread, live.said, live.out, live.stop


def angle_deg(q_a, q_b) -> float:
    return float(attitude_error_deg(np.asarray(q_a), np.asarray(q_b)).total_deg)


#: How the source is read: by the session's loop at each wake-up (the default with a wake-up
#: interval of 25 ms or more), or by the source's thread (a shorter one).
READS = {"inline": None, "thread": 0.01}


def spy_reads(monkeypatch) -> dict:
    """Count the WebSocket source's reads of each kind: ``poll`` (inline) and ``session``."""
    from imu_dcm.live.sources.foxglove import WsSource

    calls = {"poll": 0, "session": 0}
    poll, session = WsSource.poll, WsSource._session

    def counted_poll(self):
        calls["poll"] += self._live is not None
        return poll(self)

    def counted_session(self, ws):
        calls["session"] += 1
        return session(self, ws)

    monkeypatch.setattr(WsSource, "poll", counted_poll)
    monkeypatch.setattr(WsSource, "_session", counted_session)
    return calls


def assert_read(calls: dict, read: str) -> None:
    if read == "inline":
        assert calls["poll"] > 0 and calls["session"] == 0, calls
    else:
        assert calls["poll"] == 0 and calls["session"] > 0, calls


@pytest.mark.parametrize(("method", "read"), [("magnus4", "inline"), ("coning", "thread")])
def test_ws_live_equals_replay_on_the_same_messages(trial, tmp_path, monkeypatch, method, read):
    calls = spy_reads(monkeypatch)
    msgs = trial["messages"]
    pub = Publisher(trial["schemas"])
    try:
        th, said, out, _ = start_live(
            f"ws://127.0.0.1:{pub.port}",
            method=method,
            bias="none",
            idle_stop_s=1.5,
            view_interval_s=READS[read],
        )
        pub.wait_subscribed()
        pub.publish(msgs)
        th.join(60)
    finally:
        pub.stop()
    assert not th.is_alive(), said
    res = out["result"]
    s = res.summary
    q_replay, rep = replay_of(msgs, tmp_path, method, "none")
    n_imu = sum(1 for m in msgs if m[0] == IMU)
    assert s["samples"] == n_imu, said
    assert s["dropped_duplicate"] == s["dropped_backward"] == s["malformed"] == 0
    assert s["imu_topic"] == IMU and s["truth_topic"] == TRUTH
    assert res.t_ns == int(rep.t_ns[-1])
    # same messages, same stamps, same start (truth at the first sample): same attitude
    assert angle_deg(res.q_w_b, q_replay) <= TOL_DEG
    assert s["initial_q_w_b"] == pytest.approx(rep.q_truth[rep.start_index], abs=1e-15)
    # the live error statistics are those of replay (same estimates, same truth)
    assert s["truth_samples_used"] == rep.summary.to_dict()["truth_samples_used"]
    assert s["rms_error_deg"] == pytest.approx(rep.summary.to_dict()["rms_error_deg"], rel=1e-9)
    assert s["max_error_deg"] == pytest.approx(rep.summary.to_dict()["max_error_deg"], rel=1e-9)
    assert any("subscribed to /imu/data" in line for line in said)
    assert_read(calls, read)


@pytest.mark.parametrize("read", ["inline", "thread"])
def test_ws_server_killed_and_restarted_reconnects_reports_the_gap(
    trial, tmp_path, monkeypatch, read
):
    calls = spy_reads(monkeypatch)
    msgs = trial["messages"]
    imu_idx = [i for i, m in enumerate(msgs) if m[0] == IMU]
    cut = imu_idx[500]  # first message not published by the first server
    resume = imu_idx[700]  # first message published by the second server
    pub = Publisher(trial["schemas"])
    port = pub.port
    try:
        th, said, out, _ = start_live(
            f"ws://127.0.0.1:{port}",
            method="magnus4",
            bias="none",
            idle_stop_s=4.0,
            view_interval_s=READS[read],
        )
        pub.wait_subscribed()
        pub.publish(msgs[:cut])
        time.sleep(0.3)  # let the last frames reach the client
        pub.stop()
        deadline = time.monotonic() + 20
        while not any("reconnecting" in s for s in said):
            assert time.monotonic() < deadline, said
            time.sleep(0.02)
        pub.start(port)
        pub.wait_subscribed()
        pub.publish(msgs[resume:])
        th.join(60)
    finally:
        pub.stop()
    assert not th.is_alive()
    s = out["result"].summary
    assert any(line.startswith("reconnected") for line in said), said
    assert s["reconnects"] == 1
    published = msgs[:cut] + msgs[resume:]
    imu_t = decode_slice(published)[0]
    assert s["samples"] == len(imu_t)
    # one gap: from the last sample before the cut to the first after it, in source time
    k = int(np.flatnonzero(np.diff(imu_t) > 10 * np.median(np.diff(imu_t)))[0])
    assert len(s["gaps"]) == 1
    g = s["gaps"][0]
    assert g["t_s"] == (imu_t[k] - imu_t[0]) * 1e-9
    assert g["length_s"] == pytest.approx((imu_t[k + 1] - imu_t[k]) * 1e-9, rel=1e-12)
    assert any(line.startswith("1 gap(s) longer than") for line in said), said
    assert_read(calls, read)
    with (
        pytest.warns(GapWarning, match=r"1 gap\(s\)"),  # replay sees the same gap
        pytest.warns(ImuDcmWarning, match=r"1 gap the gyro did not see"),  # and re-anchors
    ):
        _, rep = replay_of(published, tmp_path, "magnus4", "none")
    rep_gaps = rep.summary.to_dict()["gaps"]
    assert len(rep_gaps) == len(s["gaps"])
    for live_gap, rep_gap in zip(s["gaps"], rep_gaps, strict=True):  # approx: no nesting
        for key in ("t_s", "length_s"):
            assert live_gap[key] == pytest.approx(rep_gap[key], rel=1e-12), key
    # live integrates across the gap (it does not re-anchor after one, replay does): it equals
    # the same rates integrated from replay's start through the gap
    a = rep.start_index
    with pytest.warns(GapWarning):
        q_across = integrate_quat(rep.omega_b[a:], rep.t_s[a:], rep.q_est[a], "magnus4")[-1]
    assert angle_deg(out["result"].q_w_b, q_across) <= TOL_DEG


def test_a_live_imu_payloads_accelerometer_is_decoded_in_bulk_with_its_rate():
    # sensor_msgs/Imu as a Foxglove server sends it: the linear acceleration decodes with the
    # angular velocity, bit for bit; a message flagging none (covariance[0] = -1) gives NaN,
    # a batch of only those none
    from imu_dcm.logio.ros.payload import classify_schema, decode_cdr_batch
    from imu_dcm.logio.writers.messages import MSG_DEFINITIONS, cdr_messages, imu_doubles

    name = "sensor_msgs/msg/Imu"
    text = MSG_DEFINITIONS[name]
    kind = classify_schema(name, "ros2msg", text)
    rng = np.random.default_rng(0)
    w, a = rng.normal(size=(6, 3)), rng.normal(size=(6, 3)) + [0.0, 0.0, 9.8]
    t = 10**9 + np.arange(6, dtype=np.int64) * 5_000_000

    def decoded(doubles):
        payloads = [bytes(r) for r in cdr_messages(t, "imu", doubles)]
        return decode_cdr_batch(kind, name, "ros2msg", text, payloads, IMU)

    dec = decoded(imu_doubles(w, a, None))
    assert np.array_equal(dec.values, w) and np.array_equal(dec.accel, a)
    assert decoded(imu_doubles(w, None, None)).accel is None
    mixed = imu_doubles(w, a, None)
    mixed[::2] = imu_doubles(w[::2], None, None)
    dec = decoded(mixed)
    assert np.isnan(dec.accel[::2]).all() and np.array_equal(dec.accel[1::2], a[1::2])


def test_ws_live_rests_by_the_accelerometer_the_imu_messages_carry():
    # A real server publishing sensor_msgs/Imu with linear_acceleration: a body shaken at the
    # gyro's floor between two rests (test_rest_causal.shaken_log). Live's rest rule gets the
    # accelerometer and finds the two rests, not the shaking, each "still by the gyro floor
    # and the accelerometer", as replay's rest_segments does on the same arrays.
    from types import SimpleNamespace

    from test_rest_causal import shaken_log

    from imu_dcm.gyro.rest import rest_segments
    from imu_dcm.logio.writers.messages import MSG_DEFINITIONS, cdr_messages, imu_doubles

    w, a, t, spans = shaken_log(seed=33)
    t_ns = 10**9 + np.round(t * 1e9).astype(np.int64)
    rows = cdr_messages(t_ns, "imu", imu_doubles(w, a, None))
    msgs = [(IMU, int(s), bytes(r)) for s, r in zip(t_ns, rows, strict=True)]
    name = "sensor_msgs/msg/Imu"
    schema = SimpleNamespace(name=name, encoding="ros2msg", data=MSG_DEFINITIONS[name].encode())
    pub = Publisher({IMU: schema})
    try:
        th, said, out, _ = start_live(
            f"ws://127.0.0.1:{pub.port}", method="trapezoid", bias="auto", idle_stop_s=1.5
        )
        pub.wait_subscribed()
        pub.publish(msgs, speed=10.0)
        th.join(60)
    finally:
        pub.stop()
    assert not th.is_alive(), said
    s = out["result"].summary
    assert s["samples"] == len(w), said
    t_s = (t_ns - t_ns[0]) * 1e-9
    segs = s["bias_segments"]
    assert [(g["start_s"], g["end_s"]) for g in segs] == [(t_s[i], t_s[j - 1]) for i, j in spans]
    assert all(g["evidence"] == ["gyro floor", "accelerometer"] for g in segs)
    offline, _conflict = rest_segments(w, t_s, accel_b=a)
    assert [(o.start, o.stop) for o in offline] == spans

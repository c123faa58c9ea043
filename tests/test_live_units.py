"""Live building blocks: the reorder window, line parsing, the causal rest bias (against
replay's batch rule), and the command on stdin (90 deg about z; bad input: one line, exit 2)."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import assert_names, own_stderr, raises_naming

from imu_dcm.errors import InputError
from imu_dcm.gyro.rest_causal import CausalRestBias
from imu_dcm.live.lines import parse_lines
from imu_dcm.live.reorder import ReorderBuffer
from imu_dcm.live.sources import parse_source
from imu_dcm.replay.bias import estimate_bias

REPO = Path(__file__).resolve().parents[1]
W = (0.0, 0.0, 1.0)


def push_one(buf: ReorderBuffer, t: int, w=W, arrival: int = 0) -> list[int]:
    t_out, _, _ = buf.push(np.array([t], np.int64), np.array([w]), np.array([arrival], np.int64))
    return t_out.tolist()


def push_all(buf: ReorderBuffer, stamps) -> list[int]:
    out: list = []
    for t in stamps:
        out += push_one(buf, t)
    return out + buf.flush()[0].tolist()


def counters(buf: ReorderBuffer) -> tuple[int, int, int, int]:
    return buf.reordered, buf.dropped_duplicate, buf.dropped_backward, buf.dropped_nonfinite


def test_reorder_window_puts_late_samples_in_order_and_counts_the_rest():
    ms = 1_000_000
    buf = ReorderBuffer(50 * ms)
    # 30 ms late (inside 50 ms): reordered; 3 duplicates (held, and the last released);
    # one 200 ms late: backward
    stamps = [0, 10, 20, 50, 40, 30, 60, 60, 70, 80, 90, 100, 150, 200, 300, 100, 300, 305]
    got = push_all(buf, [t * ms for t in stamps])
    assert got == [t * ms for t in [0, 10, 20, 30, 40, 50, 60, 70, 80, 90, 100, 150, 200, 300, 305]]
    assert buf.reordered == 2  # 40 and 30
    assert buf.dropped_duplicate == 2  # 60 held, 300 held
    assert buf.dropped_backward == 1  # 100 after 150, 200 were released
    assert push_one(buf, 310 * ms, (math.nan, 0.0, 0.0)) == []
    assert buf.dropped_nonfinite == 1


def test_reorder_window_zero_releases_at_once():
    buf = ReorderBuffer(0)
    assert push_one(buf, 5) == [5]
    assert push_one(buf, 5) == [] and push_one(buf, 4) == []
    assert buf.dropped_duplicate == 1 and buf.dropped_backward == 1


@pytest.mark.parametrize("window_ms", [0, 3, 50])
def test_reorder_batches_release_what_sample_by_sample_releases(window_ms):
    """The same arrivals pushed in batches of any size (sliced in order, or judged one by one
    when a batch holds a late sample or a duplicate) release the same samples, with the same
    rates and arrival stamps, and count the same drops."""
    rng = np.random.default_rng(7)
    ms = 1_000_000
    t = np.arange(400, dtype=np.int64) * ms
    swap = rng.choice(398, 40, replace=False)  # neighbours swapped: late by one step
    t[swap], t[swap + 1] = t[swap + 1], t[swap].copy()
    t[rng.choice(400, 10, replace=False)] = t[rng.choice(400, 10, replace=False)]  # duplicates
    t[rng.choice(400, 5, replace=False)] -= 80 * ms  # far behind
    w = rng.normal(size=(400, 3))
    w[rng.choice(400, 5, replace=False), 1] = math.nan
    arrival = np.arange(400, dtype=np.int64)
    one = ReorderBuffer(window_ms * ms)
    ref = [one.push(t[i : i + 1], w[i : i + 1], arrival[i : i + 1]) for i in range(400)]
    ref.append(one.flush())
    edges = np.unique(np.concatenate([[0, 400], rng.integers(0, 400, 60)]))
    many = ReorderBuffer(window_ms * ms)
    got = [
        many.push(t[a:b], w[a:b], arrival[a:b]) for a, b in zip(edges[:-1], edges[1:], strict=True)
    ]
    got.append(many.flush())
    for k in range(3):
        np.testing.assert_array_equal(
            np.concatenate([r[k] for r in got]), np.concatenate([r[k] for r in ref])
        )
    assert counters(many) == counters(one)
    assert counters(one)[1] > 0 and counters(one)[2] > 0 and counters(one)[3] == 5
    t_all = np.concatenate([r[0] for r in ref])
    assert np.all(np.diff(t_all) > 0)


def test_lines_csv_json_units_and_malformed():
    lines = [
        b"t_s,gx,gy,gz",  # header: skipped, not counted
        b"1700000026.505500001,1,2,3",  # exact decimal stamp (1 ns resolution)
        b'{"t_ns": 1700000026509000000, "omega_b": [0.5, 0, 0]}',
        b'{"t_s": "1700000026.5125", "gx": 1, "gy": 0, "gz": 0, "q_w_b": [0, 0, 0.6, 0.8]}',
        b'{"t_ns": 1700000026516000000, "q_w_b": [0, 0, 0, 1]}',  # truth only
        b"1700000026.52,nan,0,0",  # a sample: the pipeline counts its NaN (not malformed)
        b"1,2,3",  # 3 fields
        b"{broken",
        b'{"t_ns": 1.5, "omega_b": [0, 0, 0]}',  # t_ns must be an integer
        b"",
    ]
    t, w, tt, q, bad = parse_lines(lines, gyro_units="deg/s", first=True)
    assert t.tolist() == [
        1700000026505500001,
        1700000026509000000,
        1700000026512500000,
        1700000026520000000,
    ]
    want = np.radians([[1, 2, 3], [0.5, 0, 0], [1, 0, 0]])
    assert np.allclose(w[:3], want, rtol=1e-15, atol=0) and np.isnan(w[3, 0])
    assert tt.tolist() == [1700000026512500000, 1700000026516000000]
    assert q.tolist() == [[0, 0, 0.6, 0.8], [0, 0, 0, 1]]
    assert bad == 3
    t, _, _, _, bad = parse_lines([b"12.5,0,0,1", b"13,0,0,1"], time_units="ms")
    assert t.tolist() == [12_500_000, 13_000_000] and bad == 0
    _, _, _, _, bad = parse_lines([b"t_s,gx,gy,gz"], first=False)  # not first: malformed
    assert bad == 1


def test_parse_source():
    assert parse_source("-").kind == "stdin"
    s = parse_source("ws://127.0.0.1:8765")
    assert (s.kind, s.host, s.port) == ("ws", "127.0.0.1", 8765)
    assert parse_source("udp://localhost:9870").port == 9870
    for bad in ("tcp://x:1", "ws://host", "udp://:5", "file.mcap"):
        with raises_naming(InputError, "SOURCE", repr(bad), "ws://HOST:PORT"):
            parse_source(bad)


def rest_motion_log(seed: int = 3, rate_hz: float = 256.0):
    """Rest 2 s, motion 3 s, rest 1.5 s, motion 1 s, rest 2 s; bias changes between rests.

    256 Hz: the step is exact in binary, so the rest window (0.5 s / median step) is the same
    number of samples online (first steps) and in replay (all steps)."""
    rng = np.random.default_rng(seed)
    parts, biases = [], [(0.004, -0.002, 0.001), (0.006, -0.001, -0.002), (0.003, 0.0, 0.002)]
    b_i = 0
    for kind, dur in [("rest", 2.0), ("move", 3.0), ("rest", 1.5), ("move", 1.0), ("rest", 2.0)]:
        n = int(dur * rate_hz)
        w = rng.normal(0, 0.002, (n, 3)) + biases[min(b_i, 2)]
        if kind == "move":
            tt = np.arange(n) / rate_hz
            w += np.stack([np.sin(3 * tt), np.cos(2 * tt), 0.5 + 0 * tt], axis=1)
            b_i += 1
        parts.append(w)
    w = np.concatenate(parts)
    t = np.arange(len(w)) / rate_hz
    return w, t


def test_causal_rest_bias_ends_each_segment_on_replays_value():
    # Live runs replay's rule causally: every segment (the last too, closed at the end of the
    # stream) ends on replay's samples and mean (a sum of n samples: relative rounding <= n eps).
    # The rests share one noise level, so the floor seen so far is replay's to within the
    # windows' spread.
    w, t = rest_motion_log()
    batch = estimate_bias(w, t, "auto")
    live = CausalRestBias()
    applied = np.array(
        [live.update(tuple(x), s) for x, s in zip(w.tolist(), t.tolist(), strict=False)]
    )
    live.finish()
    assert len(live.segments) == len(batch.segments) == 3
    for seg_live, seg in zip(live.segments, batch.segments, strict=True):
        n = seg.stop - seg.start
        assert (seg_live.start, seg_live.stop, seg_live.lo, seg_live.hi) == (
            seg.start,
            seg.stop,
            seg.lo,
            seg.hi,
        )
        assert seg_live.bias_rad_s == pytest.approx(
            seg.bias_rad_s, abs=4 * n * np.finfo(float).eps * 0.01
        )
        assert seg_live.start_s == seg.start_s and seg_live.end_s == seg.end_s
    # causal: the bias uses samples one window behind the newest, so the first sample with a
    # bias is number win (the first still window ends at win - 1 and holds nothing older)
    win = math.ceil(0.5 / (t[1] - t[0]))
    assert np.all(applied[:win] == 0.0)
    assert np.all(applied[win] == w[0])


def test_causal_rest_bias_takes_a_short_rests_middle_half_as_replay_does():
    # A rest of 0.9 s (1.8 windows) between motions: one window off each side would leave
    # nothing, so both take its middle half, known once motion starts again.
    rng = np.random.default_rng(4)
    rate_hz, bias = 200.0, np.array([0.004, -0.002, 0.003])
    parts = []
    for kind, dur in [("rest", 2.0), ("move", 1.0), ("rest", 0.9), ("move", 1.0)]:
        n = int(dur * rate_hz)
        x = rng.normal(0, 0.002, (n, 3)) + bias
        if kind == "move":
            x[:, 2] += 1.0
        parts.append(x)
    w = np.concatenate(parts)
    t = np.arange(len(w)) / rate_hz
    batch = estimate_bias(w, t, "auto")
    live = CausalRestBias()
    live.update_many(w, t)
    live.finish()
    assert len(batch.segments) == len(live.segments) == 2
    short, short_live = batch.segments[1], live.segments[1]
    a, b = short.start, short.stop
    assert b - a < 3 * 100 and (short.lo, short.hi) == (a + (b - a) // 4, b - (b - a) // 4)
    assert (short_live.start, short_live.stop, short_live.lo, short_live.hi) == (
        a,
        b,
        short.lo,
        short.hi,
    )
    np.testing.assert_allclose(short_live.bias_rad_s, w[short.lo : short.hi].mean(axis=0))
    np.testing.assert_allclose(short.bias_rad_s, w[short.lo : short.hi].mean(axis=0))


def run_cli(args: list[str], stdin: bytes = b"", timeout: float = 60):
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    return subprocess.run(
        [sys.executable, "-m", "imu_dcm.live", *args],
        input=stdin,
        capture_output=True,
        env=env,
        timeout=timeout,
        check=False,
    )


def test_stdin_constant_rate_gives_90_deg_about_z(tmp_path):
    # 1 s at 90 deg/s about body z, in deg/s with millisecond stamps
    lines = "".join(f"{k * 10},0,0,90\n" for k in range(101)).encode()
    out = tmp_path / "summary.json"
    r = run_cli(
        [
            "-",
            "--rerun",
            "off",
            "--bias",
            "none",
            "--gyro-units",
            "deg/s",
            "--time-units",
            "ms",
            "--method",
            "trapezoid",
            "--no-status",
            "--summary-json",
            str(out),
        ],
        lines,
    )
    assert r.returncode == 0, r.stderr.decode()
    text = r.stdout.decode()
    assert "stopped    end of input" in text
    assert "final      q_w_b [x, y, z, w] = [+0.000000, +0.000000, +0.707107, +0.707107]" in text
    summary = json.loads(out.read_text())
    q = np.array(summary["final_q_w_b"])
    h = math.sqrt(0.5)
    # constant axis: exact up to rounding of 100 steps
    assert np.allclose(q, [0, 0, h, h], atol=100 * 4 * np.finfo(float).eps)
    assert summary["final_t_s"] == 1.0 and summary["samples"] == 101


def test_stdin_ms_stamps_declared_as_s_get_one_line_naming_the_unit():
    """200 Hz stamps in ms read as s are a 0.2 Hz log no IMU produces: one line says so and
    names the option that fixes it; the same stamps declared as ms say nothing."""
    lines = "".join(f"{k * 5},0,0,0.1\n" for k in range(50)).encode()
    args = ["-", "--rerun", "off", "--bias", "none", "--no-status"]
    r = run_cli(args, lines)
    err = r.stderr.decode()
    hints = [line for line in err.splitlines() if "no step of hours" in line]
    assert len(hints) == 1, err
    assert "got a median step of 5 s (0.2 Hz)" in hints[0]
    assert "stamps in ms declared as s? (--time-units ms)" in hints[0]
    r = run_cli([*args, "--time-units", "ms"], lines)
    assert r.returncode == 0 and "no step of hours" not in r.stderr.decode()


def test_time_unit_hint_names_the_unit_that_makes_an_imu_rate():
    from imu_dcm.live.lines import time_unit_hint

    assert time_unit_hint(0.005, 0.005, "s") is None  # 200 Hz
    # the stated range, 1 Hz to 100 kHz, ends included, as steps of float seconds give them
    t0 = 1_700_000_000 * 10**9
    for step_ns in (10_000, 1_000_000_000):
        t_s = (t0 + step_ns * np.arange(100, dtype=np.int64) - t0 - 17 * step_ns) * 1e-9
        step = float(np.median(np.diff(t_s)))
        assert time_unit_hint(step, step, "s") is None, step
    for step in (np.nextafter(1e-5, 0.0), np.nextafter(1.0, 2.0)):  # a rounding off the ends
        assert time_unit_hint(step, step, "s") is None
    assert time_unit_hint(0.99e-5, 0.99e-5, "s") is not None  # 101 kHz
    assert time_unit_hint(1.01, 1.01, "s") is not None
    assert time_unit_hint(0.005, 7200.0, "s").endswith(
        "check the unit of the stamps (--time-units)"
    )
    assert "stamps in us declared as ms? (--time-units us)" in time_unit_hint(2.5, 2.5, "ms")
    assert "stamps in ms declared as ns? (--time-units ms)" in time_unit_hint(2.5e-9, 2.5e-9, "ns")
    assert time_unit_hint(5.0, 5.0, None).endswith("the source's stamps are not an IMU's")


@pytest.mark.parametrize(
    "args, facts",
    [
        (["tcp://x:1"], ("SOURCE", "'tcp://x:1'")),
        (["-", "--rerun", "window"], ("--rerun", "'window'")),
        (["-", "--bias", "1,2"], ("--bias", 3, "'1,2'")),
        (["-", "--init-quat", "0,0,0"], ("--init-quat", 4, "'0,0,0'")),
        (["-", "--method", "rk4"], ("--method", "'rk4'")),
    ],
)
def test_cli_bad_input_one_line_exit_2(args, facts):
    r = run_cli([*args, "--no-status"], b"")
    assert r.returncode == 2
    err = own_stderr(r.stderr.decode()).strip().splitlines()
    assert len(err) == 1 and err[0].startswith("imu-dcm-live: error:"), err
    assert_names(err[0], *facts)


def test_stdin_bias_auto_reports_replays_rest_segments(tmp_path):
    w, t = rest_motion_log()
    lines = "".join(
        f"{s!r},{a!r},{b!r},{c!r}\n" for s, (a, b, c) in zip(t.tolist(), w.tolist(), strict=False)
    ).encode()
    out = tmp_path / "s.json"
    r = run_cli(["-", "--rerun", "off", "--no-status", "--summary-json", str(out)], lines)
    assert r.returncode == 0, r.stderr.decode()
    s = json.loads(out.read_text())
    batch = estimate_bias(w, t, "auto")
    assert s["bias_mode"] == "auto" and len(s["bias_segments"]) == len(batch.segments)
    for seg_live, seg in zip(s["bias_segments"][:2], batch.segments[:2], strict=False):
        n = seg.stop - seg.start
        assert seg_live["bias_rad_s"] == pytest.approx(
            seg.bias_rad_s, abs=4 * n * np.finfo(float).eps * 0.01
        )
    assert "bias       auto: 3 rest segments" in r.stdout.decode()


def test_causal_rest_bias_in_batches_equals_sample_by_sample():
    """update_many over batches of any size applies, to each sample, the bias that update
    gives it one by one (sums taken in another order: rounding of a mean of <= n values of
    |w| <= 0.02 rad/s), and finds the same segments."""
    w, t = rest_motion_log()
    one = CausalRestBias()
    ref = np.array([one.update(tuple(x), s) for x, s in zip(w.tolist(), t.tolist(), strict=True)])
    one.finish()
    rng = np.random.default_rng(11)
    for _ in range(3):
        edges = np.unique(np.concatenate([[0, len(w)], rng.integers(0, len(w), 40)]))
        many = CausalRestBias()
        got = np.concatenate(
            [many.update_many(w[a:b], t[a:b]) for a, b in zip(edges[:-1], edges[1:], strict=True)]
        )
        many.finish()
        np.testing.assert_allclose(got, ref, rtol=0, atol=len(w) * np.finfo(float).eps * 0.02)
        assert [(s.start_s, s.end_s) for s in many.segments] == [
            (s.start_s, s.end_s) for s in one.segments
        ]
        assert many.updates == one.updates


@pytest.mark.parametrize("method", ["magnus4", "coning", "trapezoid"])
@pytest.mark.parametrize("sizes", [(1,), (2, 1), (3,), (5,), (97, 1, 4)])
def test_pipeline_in_batches_equals_batch_integrate(method, sizes):
    """The estimate rows of a live pipeline fed in batches (any size, the first holding fewer
    or more than magnus4's four warm-up samples) are the batch integrator's attitudes at every
    stamp: the same compiled kernel on the same samples."""
    from imu_dcm.integrator.batch import integrate
    from imu_dcm.live.events import Received
    from imu_dcm.live.pipeline import Pipeline

    rows = []

    class Recorder:
        def add_estimate(self, t_ns, q):
            rows.append((t_ns, q))

    n = 300
    t_ns = 10**18 + np.arange(n, dtype=np.int64) * 2_500_000
    w = np.random.default_rng(5).normal(0, 2.0, (n, 3))
    q0 = np.array([0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)])  # 90 deg about z
    pipe = Pipeline(
        method=method,
        bias="none",
        init_q_w_b=q0,
        window_ns=0,
        truth_wait_s=1.0,
        lines=True,
        view=None,
        recorder=Recorder(),
        say=lambda _: None,
    )
    i = k = 0
    while i < n:
        sl = slice(i, i + sizes[k % len(sizes)])
        zeros = np.zeros(len(t_ns[sl]), np.int64)
        pipe.on_imu(Received("imu", t_ns[sl], w[sl], zeros, zeros))
        pipe.flush()
        i, k = sl.stop, k + 1
    pipe.finish()
    pipe.flush(final=True)
    got_t = np.concatenate([r[0] for r in rows])
    got_q = np.concatenate([r[1] for r in rows])
    ref = integrate(w, (t_ns - t_ns[0]) * 1e-9, q0, method).as_quat()
    np.testing.assert_array_equal(got_t, t_ns)
    np.testing.assert_array_equal(got_q, ref)


def test_line_decode_of_several_wake_ups_keeps_each_line_and_its_arrival():
    """The session's loop decodes the items of several source wake-ups at once: one numpy parse
    for plain CSV, item by item otherwise; each sample keeps the arrival of its own wake-up."""
    from imu_dcm.live.events import Malformed, Received
    from imu_dcm.live.sources.stdin import StdinSource

    items = [
        (b"1.0,0,0,1\n\n1.001,0,0,2", 100, 1000),  # a blank line: ignored
        (b"1.002,nan,0,3\n1.003,0,0,4\n", 200, 2000),  # a NaN rate: the pipeline's count
    ]
    for first, csv_only in ((False, True), (True, True), (False, False)):
        src = StdinSource("rad/s", "s")
        src._first = first  # first: a header may start the stream (parsed line by line)
        batch = (
            items if csv_only else [*items, (b'{"t_s": 1.004, "omega_b": [0, 0, 5]}', 300, 3000)]
        )
        events = src.decode("lines", batch)
        assert not [ev for ev in events if isinstance(ev, Malformed)]
        recs = [ev for ev in events if isinstance(ev, Received)]
        t = np.concatenate([r.t_ns for r in recs])
        w = np.concatenate([r.values for r in recs])
        arrival = np.concatenate([r.arrival_ns for r in recs])
        wall = np.concatenate([r.wall_ns for r in recs])
        n = 4 if csv_only else 5
        want_t = [1_000_000_000, 1_001_000_000, 1_002_000_000, 1_003_000_000, 1_004_000_000]
        assert t.tolist() == want_t[:n]
        assert np.isnan(w[2, 0])  # the NaN sample, for the pipeline to count
        assert w[:, 2].tolist() == [1.0, 2.0, 3.0, 4.0, 5.0][:n]
        assert arrival.tolist() == [100, 100, 200, 200, 300][:n]
        assert wall.tolist() == [1000, 1000, 2000, 2000, 3000][:n]

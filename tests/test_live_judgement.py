"""Live judges every sample as replay does: non-finite and implausible rates are dropped and
counted before the rest rule or the integrator sees them
(:func:`imu_dcm.gyro.rates.implausible_rates`,
the rule of replay's cleaning), so no NaN or Inf reaches the attitude, the console or the JSON,
and a NaN line is counted once, as NaN/Inf, not as malformed."""

from __future__ import annotations

import json
import math
import os
import socket
import threading

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from test_live_ws import live_thread
from test_rest_causal import BIAS, REST_S, SIGMA, TURN_OFF, M, agreement_log
from test_rest_causal import RATE_HZ as RATE_HZ_REST

from imu_dcm.gyro.rates import MAX_RATE_RAD_S, implausible_rates
from imu_dcm.live import run
from imu_dcm.live.__main__ import format_summary
from imu_dcm.so3 import angle_between_deg

RATE_HZ, SPIN_DEG_S, N = 1000, 90.0, 2001  # 2 s at 90 deg/s about z: a half turn


def _spin_lines(bad: dict[int, str]) -> list[bytes]:
    """``t,gx,gy,gz`` in deg/s, 1 kHz, a constant 90 deg/s about z; line k replaced by the
    rate text ``bad[k]`` on z."""
    return [f"{k / RATE_HZ:.3f},0,0,{bad.get(k, repr(SPIN_DEG_S))}".encode() for k in range(N)]


def _truth_end() -> np.ndarray:
    # a constant rate about a fixed axis integrates exactly by every method, over any step
    # (a dropped sample only makes one step twice as long)
    return Rotation.from_rotvec([0, 0, np.radians(SPIN_DEG_S) * (N - 1) / RATE_HZ]).as_quat()


def _run_stdin(lines: list[bytes], tmp_path, gyro_units_given: str = "deg/s", **kw):
    r, w = os.pipe()

    def feed():
        with os.fdopen(w, "wb") as f:
            f.write(b"\n".join(lines) + b"\n")

    feeder = threading.Thread(target=feed)
    feeder.start()
    summary = tmp_path / "summary.json"
    try:
        res = run(
            "-",
            stdin_fd=r,
            rerun="off",
            status=False,
            gyro_units=gyro_units_given,
            say=kw.pop("say", lambda _s: None),
            summary_json=summary,
            **kw,
        )
    finally:
        feeder.join()
        os.close(r)
    return res, json.loads(summary.read_text())


def test_the_rule_is_replays():
    w = np.array([[0, 0, MAX_RATE_RAD_S], [0, -1.0001 * MAX_RATE_RAD_S, 0], [np.nan, 0, 0]])
    assert implausible_rates(w).tolist() == [False, True, False]
    from imu_dcm.arrays import BLOCK_ROWS  # a long log: block by block, the same rows

    long = np.zeros((2 * BLOCK_ROWS + 5, 3))
    rows = [0, BLOCK_ROWS - 1, BLOCK_ROWS, 2 * BLOCK_ROWS + 4]
    long[rows, [0, 1, 2, 1]] = [2 * MAX_RATE_RAD_S, -np.inf, -3 * MAX_RATE_RAD_S, np.inf]
    long[7] = np.nan
    assert np.flatnonzero(implausible_rates(long)).tolist() == rows


@pytest.mark.parametrize("text", ["1e30", "1.7e308", "-3e38"])
def test_one_absurd_line_in_a_spin_is_dropped_and_counted(text, tmp_path):
    res, saved = _run_stdin(_spin_lines({1000: text}), tmp_path, bias="auto")
    s = res.summary
    assert s["dropped_implausible"] == 1 and s["dropped_nonfinite"] == 0
    assert s["malformed"] == 0 and s["samples"] == N - 1
    assert s["bias_segments"] == []  # turning at 90 deg/s: no rest, whatever one sample says
    assert s["bias_rad_s"] == [0.0, 0.0, 0.0]
    assert np.all(np.isfinite(res.q_w_b))
    assert angle_between_deg(res.q_w_b, _truth_end()) < 1e-9
    assert saved.pop("written_by").startswith("imu_dcm ")  # signed (the output rule)
    assert saved == s  # the JSON holds the summary as it is
    assert "1 implausible" in format_summary(s)


def test_a_nan_line_is_counted_once_as_nan(tmp_path):
    res, _ = _run_stdin(_spin_lines({500: "nan", 501: "inf"}), tmp_path, bias="none")
    s = res.summary
    assert s["dropped_nonfinite"] == 2 and s["malformed"] == 0
    assert "2 NaN/Inf" in format_summary(s) and "0 malformed" in format_summary(s)
    assert angle_between_deg(res.q_w_b, _truth_end()) < 1e-9


def test_over_udp_too(tmp_path):
    live = live_thread("udp://127.0.0.1:0", gyro_units="deg/s", bias="auto", idle_stop_s=0.5)
    assert live.ready.wait(20)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
        for line in _spin_lines({1000: "1e30", 1500: "1.7e308"}):
            tx.sendto(line, live.addr["address"])
    live.thread.join(30)
    assert not live.thread.is_alive()
    res = live.out["result"]
    s = res.summary
    assert s["lost_by_system"] == 0 and s["samples"] == N - 2
    assert s["dropped_implausible"] == 2 and s["bias_segments"] == []
    assert angle_between_deg(res.q_w_b, _truth_end()) < 1e-9
    json.dumps(s, allow_nan=False)


def _json_lines(rate_given: float, rate_true_rad_s: float, n: int = 3001) -> list[bytes]:
    """JSON lines at 1 kHz: the gyro ``rate_given`` about z, and the truth of a body turning
    at ``rate_true_rad_s`` about z."""
    out = []
    for k in range(n):
        t = k / RATE_HZ
        q = Rotation.from_rotvec([0, 0, rate_true_rad_s * t]).as_quat().tolist()
        out.append(json.dumps({"t_s": t, "omega_b": [0, 0, rate_given], "q_w_b": q}).encode())
    return out


@pytest.mark.parametrize(
    ("given", "true_rad_s", "flagged", "why"),
    [
        (20.0, np.radians(20.0), True, "57.3"),  # 20 deg/s given as rad/s: the truth says so
        (1.5, 1.5, False, None),  # a real 1.5 rad/s spin, its truth agreeing
    ],
)
def test_deg_per_s_given_as_rad_per_s_is_flagged_against_the_truth(
    given, true_rad_s, flagged, why, tmp_path
):
    r, w = os.pipe()
    lines = _json_lines(given, true_rad_s)

    def feed():
        with os.fdopen(w, "wb") as f:
            f.write(b"\n".join(lines) + b"\n")

    said: list[str] = []
    feeder = threading.Thread(target=feed)
    feeder.start()
    try:
        res = run("-", stdin_fd=r, rerun="off", status=False, bias="none", say=said.append)
    finally:
        feeder.join()
        os.close(r)
    s = res.summary
    hits = [line for line in said if line.startswith("the rates look like deg/s")]
    assert bool(hits) is flagged and bool(s["units_evidence"]) is flagged
    if flagged:
        assert len(hits) == 1 and why in hits[0] and "--gyro-units deg/s" in hits[0]


def test_deg_per_s_given_as_rad_per_s_is_flagged_by_the_full_scale_without_truth(tmp_path):
    # 90 deg/s as "90 rad/s": above the +-2000 deg/s = 34.9 rad/s full scale of common gyros
    res, _ = _run_stdin(_spin_lines({}), tmp_path, bias="none", gyro_units_given="rad/s")
    assert "full scale" in res.summary["units_evidence"]
    res, _ = _run_stdin(_spin_lines({}), tmp_path, bias="none")  # declared deg/s: not judged
    assert res.summary["units_evidence"] is None


def test_the_summary_holds_no_value_json_cannot_hold():
    from imu_dcm.app.summary import json_ready

    got = json_ready({"a": float("nan"), "b": [1.0, float("inf")], "c": {"d": -float("inf")}})
    assert got == {"a": None, "b": [1.0, None], "c": {"d": None}}
    json.dumps(got, allow_nan=False)


def test_live_help_names_every_source():
    from imu_dcm.live.__main__ import build_parser
    from imu_dcm.live.sources import SCHEMES

    text = build_parser().format_help()
    for scheme in SCHEMES:
        assert (scheme if scheme == "-" else f"{scheme}:") in text
    assert "mavlink:udpin:HOST:PORT" in text


def test_a_line_without_end_costs_itself_not_memory(tmp_path):
    # 1 MB with no line end between two good stretches: dropped as one malformed line (said
    # once), never held whole; the samples around it are integrated
    from imu_dcm.live.sources.stdin import MAX_LINE_BYTES

    lines = _spin_lines({})
    junk = b"9" * (16 * MAX_LINE_BYTES)
    res, _ = _run_stdin([*lines[:1000], junk, *lines[1000:]], tmp_path, bias="none")
    s = res.summary
    assert s["malformed"] == 1 and s["samples"] == N
    assert angle_between_deg(res.q_w_b, _truth_end()) < 1e-9


def test_a_rest_that_disagrees_is_said_and_in_the_summary_as_replays(tmp_path):
    # Three rests at one bias, a slow turn the window rule takes for rest, a fourth rest: the
    # turn is not used, said once as it closes, and the summary carries replay's
    # rest_agreement and marks the segment.
    zero = np.zeros(3)
    w, t, spans = agreement_log([zero, zero, zero, TURN_OFF, zero], seed=7)
    rows = zip(t.tolist(), w.tolist(), strict=True)
    lines = [f"{a!r},{x!r},{y!r},{z!r}".encode() for a, (x, y, z) in rows]
    said: list[str] = []
    res, saved = _run_stdin(lines, tmp_path, gyro_units_given="rad/s", bias="auto", say=said.append)
    s = res.summary
    assert saved["rest_agreement"] == s["rest_agreement"]
    a, b = spans[3][:2]
    (out,) = s["rest_agreement"]["outliers"]
    assert (out["start_s"], out["end_s"]) == pytest.approx((t[a], t[b - 1]), abs=1e-9)
    assert [seg["used"] for seg in s["bias_segments"]] == [True, True, True, False, True]
    assert "reason" in s["bias_segments"][3] and "reason" not in s["bias_segments"][2]
    not_used = [x for x in said if "not used" in x]
    assert len(not_used) == 1 and f"{t[a]:.3f}-{t[b - 1]:.3f} s" in not_used[0], said
    assert "rests      " + s["rest_agreement"]["line"] in format_summary(s)
    assert "(1 not used)" in format_summary(s)
    se = SIGMA / math.sqrt(REST_S * RATE_HZ_REST - 2 * M)
    assert np.all(np.abs(np.array(s["bias_final_rad_s"]) - BIAS) < 4 * se)


def _pipeline_rests(w, t, accel, batch: int):
    """The live pipeline fed ``w`` (and ``accel`` where given, None batches where a row of it
    is None) in batches, as a source delivers them; its rest rule afterwards."""
    from imu_dcm.live.events import Received
    from imu_dcm.live.pipeline import Pipeline

    pipe = Pipeline(
        method="trapezoid",
        bias="auto",
        init_q_w_b=None,
        window_ns=0,
        truth_wait_s=0.0,
        lines=True,
        view=None,
        recorder=None,
        say=lambda _text: None,
    )
    t_ns = np.round(t * 1e9).astype(np.int64)
    for i in range(0, len(w), batch):
        sl = slice(i, i + batch)
        n = len(t_ns[sl])
        acc = None if accel is None or accel[sl] is None else accel[sl]
        zero = np.zeros(n, np.int64)
        pipe.on_imu(Received("imu", t_ns[sl], w[sl], zero, zero, accel=acc))
    pipe.finish()
    return pipe.rest, (t_ns - t_ns[0]) * 1e-9


def test_live_takes_the_accelerometer_a_source_gives_to_its_rest_rule():
    from test_rest_causal import shaken_log

    from imu_dcm.gyro.rest_causal import CausalRestBias

    w, a, t, spans = shaken_log(seed=32)
    rest, t_s = _pipeline_rests(w, t, a, batch=50)
    # the shaken body at the gyro floor is not rest: the two rests, by gyro and accelerometer
    assert [(s.start, s.stop) for s in rest.segments] == spans
    assert all(s.evidence == ("gyro floor", "accelerometer") for s in rest.segments)
    # without the accelerometer: bit for bit the gyro-only rule on the same samples
    alone, _ = _pipeline_rests(w, t, None, batch=50)
    ref = CausalRestBias()
    for i in range(0, len(w), 50):  # the same batches: the same sums
        ref.update_many(w[i : i + 50], t_s[i : i + 50])
    ref.finish()
    assert alone.segments == ref.segments and alone.bias_rad_s == ref.bias_rad_s
    assert all(s.evidence == ("gyro floor",) for s in alone.segments)
    assert alone.segments[0].stop == 2 * spans[0][1]  # the gyro alone took the shaking for rest

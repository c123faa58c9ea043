"""Live anchors to the truth when the truth first arrives, as replay does.

BROAD trial 25 has its optical truth start about 12 s after the gyro. Fed the trial's messages
in file order (as a WebSocket source delivers them, the truth on its own announced channel),
live starts from the identity when no truth has come within ``truth_wait_s``, re-anchors at the
first gyro sample the truth covers, reports the start before it as unscored, and then scores
exactly what replay scores on the same messages (``--bias none``: the same samples, the same
start, the same compiled kernel).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from imu_dcm.live.events import Received
from imu_dcm.live.pipeline import Pipeline
from imu_dcm.replay import replay

IMU, TRUTH = "/imu/data", "/ground_truth/orientation"
TRIAL = "25_disturbed_tapping_B"


def file_order_messages(bag) -> list[tuple[str, bytes]]:
    from mcap.reader import make_reader

    with open(next(bag.glob("*.mcap")), "rb") as f:
        return [
            (channel.topic, bytes(message.data))
            for _, channel, message in make_reader(f).iter_messages(topics=[IMU, TRUTH])
        ]


def decode(topic: str, payloads: list[bytes]) -> tuple[np.ndarray, np.ndarray]:
    """Stamps and values from BROAD's fixed CDR layouts (independent of live's decoder)."""
    import struct

    t, v = [], []
    for p in payloads:
        sec, nsec, n = struct.unpack_from("<iII", p, 4)
        off = 16 + n
        off += (-(off - 4)) % 8
        t.append(sec * 1_000_000_000 + nsec)
        vals = struct.unpack_from("<16d" if topic == IMU else "<4d", p, off)
        v.append(vals[13:16] if topic == IMU else vals)
    return np.array(t, np.int64), np.array(v, dtype=float)


def test_live_reanchors_to_a_late_truth_and_scores_as_replay(broad_dir):
    bag = broad_dir / TRIAL
    said: list[str] = []
    pipe = Pipeline(
        method="magnus4",
        bias="none",
        init_q_w_b=None,
        window_ns=50_000_000,
        truth_wait_s=1.0,
        lines=False,  # the truth comes on an announced channel, as over a WebSocket
        view=None,
        recorder=None,
        say=said.append,
    )
    pipe.truth_channel = True
    msgs = file_order_messages(bag)
    for k in range(0, len(msgs), 64):  # one wake-up: the messages of ~0.1 s, per channel
        chunk = msgs[k : k + 64]
        for topic in dict.fromkeys(m[0] for m in chunk):
            t, v = decode(topic, [p for name, p in chunk if name == topic])
            rec = Received("imu" if topic == IMU else "truth", t, v, t * 0, t * 0)
            (pipe.on_imu if topic == IMU else pipe.on_truth)(rec)
        pipe.flush()
    pipe.finish()
    pipe.flush(final=True)

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # replay's notes on the trial are not under test here
        rep = replay(bag, bias="none", method="magnus4").summary.to_dict()
    assert rep["start_time_s"] > 5.0  # the case: the truth starts long after the gyro
    assert pipe.unscored_before_s == rep["start_time_s"]
    assert any("unscored" in line for line in said), said
    assert pipe.truth_used == rep["truth_samples_used"]
    rms = float(np.sqrt(pipe.stats.sq[0] / pipe.stats.n))
    # the same estimates against the same truth: equal up to the rounding of two sums of
    # squares over ~50000 terms (relative <= n eps)
    assert rms == pytest.approx(rep["rms_error_deg"], rel=1e-9)
    assert float(pipe.stats.max[0]) == pytest.approx(rep["max_error_deg"], rel=1e-12)

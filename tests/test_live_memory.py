"""Live memory is bounded by its buffers, not by the samples seen: the pipeline fed batch after
batch (what :func:`imu_dcm.live.run` does) holds the same memory after 150 000 samples as after
30 000 more batches' worth (measured with tracemalloc, which counts every allocation Python and
numpy make, so the check is structural: no wall clock). Keeping any per-sample value, as the
latency list did (8 bytes a sample), grows it by megabytes."""

from __future__ import annotations

import gc
import tracemalloc

import numpy as np

from imu_dcm.live.events import Received
from imu_dcm.live.latency import LATENCY_KEEP, Latency
from imu_dcm.live.pipeline import Pipeline

BATCH, RATE_HZ = 500, 10_000


def _pipeline() -> Pipeline:
    return Pipeline(
        method="magnus4",
        bias="auto",
        init_q_w_b=None,
        window_ns=50_000_000,
        truth_wait_s=1.0,
        lines=True,
        view=None,
        recorder=None,
        say=lambda _s: None,
    )


def _feed(pipe: Pipeline, k0: int, batches: int) -> None:
    for k in range(k0, k0 + batches):
        i = k * BATCH + np.arange(BATCH)
        t_ns = (i * (10**9 // RATE_HZ)).astype(np.int64)
        t = i / RATE_HZ
        w = np.stack([np.sin(t), np.cos(t), 0.1 + 0 * t], axis=1)  # moving: no rest
        if k % 50 == 0:  # a still half-second now and then: rest segments open and close
            w[:] = 0.001
        arrival = np.full(BATCH, 0, np.int64)
        pipe.on_imu(Received("imu", t_ns, w, arrival, arrival))
        pipe.flush()


def test_pipeline_memory_does_not_grow_with_samples():
    pipe = _pipeline()
    tracemalloc.start()  # from the start: what is freed later was traced when made
    try:
        _feed(pipe, 0, 300)  # 150 000 samples (15 s): every buffer at its size
        gc.collect()
        before = tracemalloc.get_traced_memory()[0]
        _feed(pipe, 300, 600)  # 300 000 more
        gc.collect()
        after = tracemalloc.get_traced_memory()[0]
    finally:
        tracemalloc.stop()
    assert pipe.n + len(pipe.reorder) == 450_000  # the window holds the newest 50 ms
    # one byte a sample would be 300 kB; the old per-sample latency list grew 2.4 MB here
    assert after - before < 100_000, after - before


def test_latency_percentiles_from_the_histogram_match_the_values():
    rng = np.random.default_rng(3)
    lat = Latency()
    values = rng.lognormal(np.log(20.0), 0.8, 200_000)
    for part in np.array_split(values, 97):
        lat.add(part)
    for p in (50, 99):
        exact = np.percentile(values, p, method="inverted_cdf")
        assert abs(lat.percentile(p) / exact - 1) <= 1e-3  # the bin's relative width
    assert len(lat.recent()) <= LATENCY_KEEP + 200_000 // 97 + 1
    assert lat.recent()[-1] == values[-1]

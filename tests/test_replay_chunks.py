"""A replay whose long-log steps run in small pieces (chunks read in batches of one chunk, truth
resampled, rests judged, errors scored and evaluated a few samples at a time) gives the
whole-log results: RMS errors to 1e-9 deg, the bias to 1e-12 rad/s, every array and the
evaluation equal."""

from __future__ import annotations

import io

import numpy as np
from conftest import estimate_bag, small_blocks

from data_synth.scenes import simulate
from imu_dcm.logio.containers import chunks
from imu_dcm.logio.writers import StampedSeries
from imu_dcm.logio.writers import bag as writer
from imu_dcm.replay import replay

EPOCH_NS = 1_700_000_000_000_000_000
BIAS_RAD_S = np.array([0.01, -0.02, 0.005])


def _coning_log(tmp_path):
    """3 s of rest, then 12 s of coning at 200 Hz (exact rates plus a constant bias and seeded
    noise), truth at every sample; an .mcap of 4 KiB chunks (~150 of them)."""
    t_s = np.arange(0, 15.0, 0.005)
    q, w = simulate("coning", 12.0).at(np.clip(t_s - 3.0, 0.0, None))
    w[t_s < 3.0] = 0.0
    gyro = w + BIAS_RAD_S + np.random.default_rng(3).normal(scale=1e-4, size=w.shape)
    t_ns = EPOCH_NS + np.round(t_s * 1e9).astype(np.int64)
    imu = StampedSeries(t_ns, gyro, "imu")
    truth = StampedSeries(t_ns, q, "world")
    topics = [
        writer._encoded(
            "/imu/data", "sensor_msgs/msg/Imu", *writer._imu_topic(imu, "/", None, None)[2:]
        ),
        writer._encoded(
            "/ground_truth/orientation",
            "geometry_msgs/msg/QuaternionStamped",
            truth,
            truth.values.__getitem__,
        ),
    ]
    f = io.BytesIO()
    writer.write_mcap(f, [topics], lambda w: {}, chunk_size=4096)
    path = tmp_path / "coning.mcap"
    path.write_bytes(f.getvalue())
    return path


def test_replay_in_small_pieces_equals_whole_log(tmp_path, monkeypatch):
    path = _coning_log(tmp_path)
    whole = replay(path)
    assert whole.summary.rms_error_deg is not None and whole.summary.bias_segments
    # the bias came from the rest: the constant written, to the noise's mean over the rest
    np.testing.assert_allclose(whole.summary.bias_rad_s, BIAS_RAD_S, atol=2e-5)
    monkeypatch.setattr(chunks, "BATCH_BYTES", 1)  # every chunk its own batch
    patched = small_blocks(monkeypatch, 89)
    for mod in ("gyro.windows", "replay.sampling", "replay.core"):  # the truth's passes: compiled
        assert f"imu_dcm.{mod}" in patched
    pieces = replay(path)
    for field in ("rms_error_deg", "rms_inclination_deg", "rms_heading_deg"):
        a, b = getattr(whole.summary, field), getattr(pieces.summary, field)
        assert abs(a - b) <= 1e-9, field
    np.testing.assert_allclose(
        pieces.summary.bias_rad_s, whole.summary.bias_rad_s, rtol=0, atol=1e-12
    )
    for name in ("t_ns", "q_est", "q_truth", "bias_b"):
        np.testing.assert_array_equal(getattr(pieces, name), getattr(whole, name))
    np.testing.assert_array_equal(pieces.error.total_deg, whole.error.total_deg)
    # the evaluation's figures are sums taken block by block: each of the ~3000 terms' rounding
    # (2^-53 relative) adds up to ~3e-13 of a sum; the fit's R² and standard errors come from a
    # difference of such sums, whose cancellation a line that fits well amplifies (1e-9 bounds it)
    _assert_close(pieces.summary.evaluation, whole.summary.evaluation, "evaluation")
    assert pieces.summary.sampling_error_deg == whole.summary.sampling_error_deg
    # --out writes the estimate a block of 89 rows at a time: every row, in order, as computed
    from imu_dcm.replay.__main__ import _write_out

    out = _write_out(tmp_path / "estimate", pieces, force=False, inputs=(path,))
    q_bag, t_bag = estimate_bag(out)
    k = slice(pieces.start_index, None)
    np.testing.assert_array_equal(t_bag, pieces.t_ns[k])
    np.testing.assert_array_equal(q_bag, pieces.q_est[k])


def _assert_close(a, b, path: str) -> None:
    """Two JSON-like trees: equal keys and flags, numbers within 1e-9 relative."""
    if isinstance(a, dict):
        assert a.keys() == b.keys(), path
        for k in a:
            _assert_close(a[k], b[k], f"{path}/{k}")
    elif isinstance(a, float) and isinstance(b, float):
        np.testing.assert_allclose(b, a, rtol=1e-9, atol=1e-12, err_msg=path)
    else:
        assert a == b, path

"""Tests of the replay's statistics (imu_dcm.metrics: error_stats, drift_fit, world/body error;
imu_dcm.replay.stats: the summary's evaluation and the bias self-check).

Oracles: numpy's own reductions, numpy's least squares with one intercept column per segment,
scipy's Rotation, and a data_synth log with a known constant gyro bias about the spin axis of a
sleeping top (rotations about one axis commute, so the heading error grows exactly as b·t).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from imu_dcm.metrics import (
    DriftSums,
    body_error_rad,
    drift_fit,
    error_stats,
    world_error_rad,
)
from imu_dcm.replay import replay
from imu_dcm.replay.stats import DOUBT_RATIO
from imu_dcm.replay.summary import format_summary

DEG_H = np.degrees(1.0) * 3600.0  # rad/s -> °/h


def test_error_stats_equal_numpy():
    x = np.abs(np.random.default_rng(3).standard_t(4, 10_001))
    s = error_stats(x)
    # the same reductions in another order of operations: equal to a few ulps
    np.testing.assert_allclose(
        [s.rms, s.mean, s.median, s.std, s.p95, s.max],
        [
            np.sqrt(np.mean(x**2)),
            np.mean(x),
            np.median(x),
            np.std(x),
            np.percentile(x, 95),
            np.max(x),
        ],
        rtol=1e-12,
    )
    assert s.samples == 10_001
    assert np.isnan(error_stats([]).rms) and error_stats([]).samples == 0


def test_drift_fit_equals_least_squares_with_an_intercept_per_segment():
    rng = np.random.default_rng(7)
    t = np.sort(rng.uniform(0, 100, 3000))
    seg = np.searchsorted([30.0, 70.0], t)  # three segments, each re-anchored
    e = (
        np.c_[0.02 * t, -0.5 * t]
        + np.array([1.0, 5.0, -3.0])[seg, None]
        + rng.normal(0, 1, (3000, 2))
    )
    fit = drift_fit(t, e.T, seg)  # one series per row
    design = np.c_[t, np.eye(3)[seg]]
    coef, res, *_ = np.linalg.lstsq(design, e, rcond=None)
    np.testing.assert_allclose(fit.slope, coef[0], rtol=1e-10)
    # the standard error of the slope from the normal equations' inverse
    cov = np.linalg.inv(design.T @ design)[0, 0]
    np.testing.assert_allclose(fit.stderr, np.sqrt(res / (3000 - 4) * cov), rtol=1e-8)
    centred = e - np.array([e[seg == k].mean(axis=0) for k in range(3)])[seg]
    np.testing.assert_allclose(fit.r2(), 1 - res.sum() / np.sum(centred**2), rtol=1e-10)
    np.testing.assert_allclose(fit.r2([1]), 1 - res[1] / np.sum(centred[:, 1] ** 2), rtol=1e-10)
    one = drift_fit(t, e[:, 0])
    np.testing.assert_allclose(one.slope[0], np.polyfit(t, e[:, 0], 1)[0], rtol=1e-10)
    assert np.isnan(drift_fit(t[:2], e[:2, 0]).slope[0])  # no degree of freedom left


def test_drift_sums_in_blocks_equal_the_whole_fit():
    # blocks of 7 samples across the segments' starts (100 mid-block, 203 = 7 * 29 a block's
    # first sample) give the fit of the whole series: the same sums, taken in pieces
    rng = np.random.default_rng(8)
    t = np.sort(rng.uniform(0, 100, 300))
    seg = np.searchsorted([100, 203], np.arange(300), side="right")  # 203 = 7 * 29
    e = np.stack([0.3 * t, -0.1 * t]) + rng.normal(0, 1, (2, 300)) + seg
    whole = drift_fit(t, e, seg)
    sums = DriftSums(t, 2, seg)
    for a in range(0, 300, 7):
        sums.add(a, e[:, a : a + 7])
    pieces = sums.fit()
    for name in ("slope", "stderr", "ss_res", "ss_tot"):
        np.testing.assert_allclose(getattr(pieces, name), getattr(whole, name), rtol=1e-12)
    assert pieces.samples == whole.samples == 300


def test_world_and_body_error_vectors_match_scipy():
    rng = np.random.default_rng(11)
    q_true = Rotation.random(200, random_state=rng)
    q_est = Rotation.from_rotvec(rng.normal(0, 0.3, (200, 3))) * q_true
    np.testing.assert_allclose(
        world_error_rad(q_est.as_quat(), q_true.as_quat()),
        (q_est * q_true.inv()).as_rotvec(),
        atol=1e-12,
    )
    np.testing.assert_allclose(
        body_error_rad(q_est.as_quat(), q_true.as_quat()),
        (q_true.inv() * q_est).as_rotvec(),
        atol=1e-12,
    )
    # the 90° about z boundary case: a body error about body x, seen from a yawed body
    q_z90 = np.array([0.0, 0.0, np.sqrt(0.5), np.sqrt(0.5)])
    est = Rotation.from_quat(q_z90) * Rotation.from_rotvec([0.1, 0, 0])
    np.testing.assert_allclose(body_error_rad(est.as_quat(), q_z90), [0.1, 0, 0], atol=1e-15)
    np.testing.assert_allclose(world_error_rad(est.as_quat(), q_z90), [0, 0.1, 0], atol=1e-15)


@pytest.fixture(scope="module")
def biased_top(tmp_path_factory):
    """A sleeping top (spin about world z = body z) sampled with a constant z bias b."""
    from data_synth.cli import main as synth_main

    out = tmp_path_factory.mktemp("synth") / "sleeping"
    args = ["heavy-top", "--motion", "sleeping", "--rate", "200", "--duration", "20"]
    assert synth_main([*args, "--gyro-bias", "0,0,0.002", "--out", str(out)]) == 0
    return out, 0.002


def test_unremoved_bias_gives_its_heading_drift(biased_top, tmp_path):
    log, b = biased_top
    r = replay(log, bias="none")
    ev = r.summary.evaluation
    # rotations about one axis commute: the heading error is b·t exactly, up to the magnus4
    # step on a constant rate (exact) and stamps rounded to 1 ns (1e-9 relative of 5 ms)
    expect = b * DEG_H  # 412.5 °/h
    assert ev["drift"]["heading"]["rate_deg_h"] == pytest.approx(expect, rel=1e-6)
    assert ev["drift"]["total"]["rate_deg_h"] == pytest.approx(expect, rel=1e-6)
    assert ev["drift"]["body_deg_h"]["z"] == pytest.approx(expect, rel=1e-6)
    assert abs(ev["drift"]["inclination"]["rate_deg_h"]) < 1e-6 * expect
    assert ev["drift"]["heading"]["r2"] > 1 - 1e-9
    # the statistics are numpy's on the replay's own per-sample errors
    scored = np.isfinite(r.error.total_deg)
    tot = r.error.total_deg[scored]
    assert ev["total_deg"]["rms"] == pytest.approx(np.sqrt(np.mean(tot**2)), rel=1e-12)
    assert ev["total_deg"]["p95"] == pytest.approx(np.percentile(tot, 95), rel=1e-12)
    # the error after 20 s is b·20 s = 2.29°: the max
    assert ev["heading_deg"]["max"] == pytest.approx(np.degrees(b * 20), rel=1e-6)
    # no bias removed: nothing to doubt
    assert ev["bias_check"]["ratio"] is None and not ev["bias_check"]["doubtful"]
    text = format_summary(r.summary)
    assert "error      heading RMS" in text and "drift +413 °/h" in text  # 412.53 to 3 digits
    json.dumps(r.summary.to_dict(), allow_nan=False)


@pytest.mark.parametrize(
    ("given", "doubtful"),
    [(1.0, False), (1.5, False), (0.5, True), (0.0, False)],
)
def test_bias_check_flags_a_residual_drift_as_large_as_the_bias(biased_top, given, doubtful):
    log, b = biased_top
    r = replay(log, bias=[0.0, 0.0, given * b])
    chk = r.summary.evaluation["bias_check"]
    residual = abs(1.0 - given) * b * DEG_H
    assert chk["residual_drift_deg_h"] == pytest.approx(residual, rel=1e-6, abs=1e-3)
    if given:
        # residual |1 - g| b against g b removed: ratio 0, 1/3 and 1 for g = 1, 1.5, 0.5
        assert chk["ratio"] == pytest.approx(abs(1 - given) / given, abs=1e-6)
        assert (chk["ratio"] >= DOUBT_RATIO) == doubtful
    assert chk["doubtful"] == doubtful
    assert ("bias check DOUBTFUL" in format_summary(r.summary)) == doubtful


def test_error_vectors_of_known_angles_row_by_row_match_scipy_and_the_planes():
    # the score's compiled pass (rows against rows, the angles known) against scipy, at any sign
    # and scale of either quaternion and angles from 0 to π, and equal to numpy's planes (the
    # same formulas, the same order of operations: no transcendental function in it)
    from imu_dcm._kernels.calls import error_vectors
    from imu_dcm.metrics import attitude_error_deg, error_vector_planes

    rng = np.random.default_rng(13)
    n = 3000
    q_true = Rotation.random(n, random_state=rng)
    rv = rng.normal(size=(n, 3))
    rv *= (np.logspace(-9, np.log10(3.1), n) / np.linalg.norm(rv, axis=1))[:, None]
    q_est = Rotation.from_rotvec(rv) * q_true
    a, b = q_est.as_quat(), q_true.as_quat()
    a[::3] *= -2.0
    b[1::5] *= 0.25
    a[7] = b[7]  # no error at all: the vector part is 0
    angle = np.radians(attitude_error_deg(a, b).total_deg)
    e = np.empty((6, n))
    error_vectors(a, b, angle, e)
    est, true = Rotation.from_quat(a), Rotation.from_quat(b)
    np.testing.assert_allclose(e[:3].T, (est * true.inv()).as_rotvec(), rtol=1e-9, atol=1e-14)
    np.testing.assert_allclose(e[3:].T, (true.inv() * est).as_rotvec(), rtol=1e-9, atol=1e-14)
    np.testing.assert_array_equal(e[:, 7], np.zeros(6))
    np.testing.assert_array_equal(e, error_vector_planes(a, b, angle))

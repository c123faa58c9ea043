"""Tests of the replay pipeline (imu_dcm.replay): cleaning, bias from rest, the
estimate against analytic and simulated truth, unit detection and bad input.

Oracles: scipy's Rotation, closed-form rotations about a fixed axis (which commute,
so the attitude is exp of the integrated angle), and the data_synth rigid-body simulator.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import raises_naming
from scipy.spatial.transform import Rotation

from imu_dcm.errors import GapWarning, ImuDcmWarning, InputError, LogError
from imu_dcm.logio.writers import StampedSeries, write_bag
from imu_dcm.replay import ReplayResult, replay
from imu_dcm.replay.bias import RestConfig, detect_rest, estimate_bias
from imu_dcm.replay.clean import clean_imu

T0_NS = 1_700_000_000_000_000_000
Q_Z90 = np.array([0.0, 0.0, np.sqrt(0.5), np.sqrt(0.5)])  # 90° about z, [x, y, z, w]


# ---------------------------------------------------------------------------- cleaning
def test_clean_imu_drops_nonfinite_and_backward_stamps_with_counts():
    t = T0_NS + np.array([0, 1, 2, 2, 3, 1, 4, 5, 6], dtype=np.int64) * 1_000_000
    w = np.zeros((9, 3))
    w[4, 1] = np.nan
    w[7, 2] = np.inf
    with pytest.warns(ImuDcmWarning) as rec:
        c = clean_imu(t, w, "/imu")
    text = " ".join(str(r.message) for r in rec)
    assert "dropped 2 samples with NaN/Inf" in text
    assert "dropped 2 samples with duplicate or backward stamps" in text  # t=2 again, t=1 back
    np.testing.assert_array_equal((c.t_ns - T0_NS) // 1_000_000, [0, 1, 2, 4, 6])
    assert (c.dropped_nonfinite, c.dropped_nonincreasing) == (2, 2)
    assert c.dropped_duplicate == 2  # both repeats are exact copies (zeros)


def test_clean_imu_warns_gaps_with_their_times():
    t = T0_NS + np.concatenate([np.arange(100), np.arange(150, 200)]).astype(np.int64) * 10**7
    with pytest.warns(
        GapWarning,
        match=r"1 gap\(s\) longer than 5x the median step at 0.990 s \(\+0.510 s\)",
    ):
        c = clean_imu(t, np.zeros((150, 3)))
    assert c.gaps == ((pytest.approx(0.99), pytest.approx(0.51)),)


# ------------------------------------------------------------------------- bias from rest
def _rest_move_rest(rate_hz=200.0, bias=(0.01, -0.02, 0.005), sigma=0.002, seed=0):
    """Rest 0–2 s, rotation about a fixed axis 2–6 s, rest 6–9 s; returns t, true and measured."""
    t = np.arange(0, 9.0, 1 / rate_hz)
    axis = np.array([1.0, 2.0, 2.0]) / 3.0
    s = np.clip(t - 2.0, 0.0, 4.0)
    a = np.where((t > 2) & (t < 6), 2 * np.sin(np.pi * s / 4) ** 2, 0.0)  # rad/s, smooth
    angle = s - (2 / np.pi) * np.sin(np.pi * s / 2)  # ∫ a dt, closed form
    omega_true = a[:, None] * axis
    rng = np.random.default_rng(seed)
    omega = omega_true + np.asarray(bias) + rng.normal(0, sigma, omega_true.shape)
    q_true = Rotation.from_rotvec(angle[:, None] * axis).as_quat()
    return t, omega, q_true


def test_rest_segments_found_and_bias_recovered():
    bias = np.array([0.01, -0.02, 0.005])
    t, omega, _ = _rest_move_rest(bias=bias)
    rest = detect_rest(omega, t)
    # the motion rate exceeds 0.035 rad/s from ~2.3 s to ~5.7 s; windows of 0.5 s reach in
    assert np.all(rest[t < 1.9]) and np.all(rest[t > 6.1])
    assert not np.any(rest[(t > 2.4) & (t < 5.6)])
    est = estimate_bias(omega, t, "auto")
    assert len(est.segments) == 2
    for seg in est.segments:
        # mean of >= 300 samples (the segment less 0.5 s next to the motion) of noise sigma
        # 0.002 rad/s: standard error 1.2e-4 rad/s; 6e-4 is 5 standard errors
        np.testing.assert_allclose(seg.bias_rad_s, bias, rtol=0, atol=6e-4)
    np.testing.assert_array_equal(estimate_bias(omega, t, "none").bias_b, 0.0)
    np.testing.assert_array_equal(estimate_bias(omega, t, [1.0, 2.0, 3.0]).bias_b[-1], [1, 2, 3])
    with raises_naming(InputError, "'auto'", "'none'", "x,y,z", "'sometimes'"):
        estimate_bias(omega, t, "sometimes")


def test_no_rest_in_motion():
    t = np.arange(0, 5, 0.005)
    omega = np.c_[np.sin(t), np.cos(t), 0.2 + 0 * t]  # |omega| >= 1 rad/s
    assert not detect_rest(omega, t).any()
    assert estimate_bias(omega, t, "auto").segments == ()
    short = RestConfig(min_duration_s=0.1, max_rate_rad_s=5.0, max_std_rad_s=1.0)
    assert detect_rest(omega, t, short).all()  # thresholds do what they say


# ------------------------------------------------------------------- end-to-end on logs
def _write_log(path, t_s, omega, q_true=None, truth_from_s=None, epoch_ns=T0_NS):
    t_ns = epoch_ns + np.round(np.asarray(t_s) * 1e9).astype(np.int64)
    quats = {}
    if q_true is not None:
        keep = np.ones(len(t_s), bool) if truth_from_s is None else t_s >= truth_from_s
        quats["/ground_truth/orientation"] = StampedSeries(t_ns[keep], q_true[keep], "world")
    return write_bag(path, imu=StampedSeries(t_ns, omega, "imu"), quaternions=quats)


def test_bias_auto_removes_bias_found_at_rest_before_truth(tmp_path):
    # Truth only from 1 s on (as in BROAD): rest is still detected on all samples.
    t, omega, q_true = _rest_move_rest(sigma=0.001)
    log = _write_log(tmp_path / "b", t, omega, q_true, truth_from_s=1.0)
    r = replay(log, bias="auto")
    assert isinstance(r, ReplayResult)
    assert r.t_s[r.start_index] == pytest.approx(1.0)
    assert np.all(np.isnan(r.q_est[: r.start_index]))
    assert len(r.bias.segments) == 2 and r.bias.segments[0].start_s == 0.0
    # residual: bias error 5 standard errors 5·0.001/√300 rad/s over 7 s ≈ 0.12°, plus the
    # noise's angle random walk 0.001·√(0.005·8) rad ≈ 0.01°
    assert r.summary.max_error_deg < 0.15
    none = replay(log, bias="none")
    # uncorrected: |bias| = 0.023 rad/s integrates to 0.023·3 rad = 4° over the last rest
    # alone (the body's rotation spreads earlier drift): removal must win by a large factor
    assert none.summary.max_error_deg > 1.0
    assert none.summary.max_error_deg > 10 * r.summary.max_error_deg
    fixed = replay(log, bias=[0.01, -0.02, 0.005])
    assert fixed.summary.max_error_deg < 0.05  # the true bias: only the random walk is left
    assert fixed.summary.bias_rad_s == pytest.approx([0.01, -0.02, 0.005])


def test_data_synth_heavy_top_log_matches_truth(tmp_path):
    # The heavy symmetric top (data_synth) at 2000 Hz, exact rate samples, through a log.
    from data_synth.cli import main as synth_main

    out = tmp_path / "top"
    assert (
        synth_main(
            [
                "heavy-top",
                "--motion",
                "cusp",
                "--rate",
                "2000",
                "--duration",
                "1.2",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    good = replay(out, bias="none", method="magnus4")
    # magnus4 (fourth order) is about 6e-5° off after 1.2 s on this top (docs/benchmarks.md,
    # speed against accuracy); stamps rounded to ns add < 1e-6°
    assert good.summary.max_error_deg < 1e-3
    assert good.summary.samples == 2401 and good.summary.truth_samples_used == 2401
    first = replay(out, bias="none", method="end")
    # the first-order rule with ω(t_{i+1}) is a few degrees off in full attitude on this top
    assert 1.0 < first.summary.max_error_deg < 6.0
    auto = replay(out)  # the top spins at 20 Hz: no rest, no bias removed
    assert auto.bias.segments == () and auto.summary.max_error_deg < 1e-3


def test_rates_in_deg_per_s_are_detected_and_converted(tmp_path):
    t, omega, q_true = _rest_move_rest(bias=(0, 0, 0), sigma=1e-4)
    log = _write_log(tmp_path / "d", t, np.degrees(omega), q_true)
    with pytest.warns(
        ImuDcmWarning,
        match=r"look like deg/s: the gyro rate is 5\d\.\dx the "
        r"truth's rotation rate",
    ):
        bad = replay(log, bias="none")
    assert bad.summary.max_error_deg > 30.0
    good = replay(log, bias="none", gyro_units="deg/s")
    assert good.summary.max_error_deg < 0.05  # noise 1e-4 rad/s: walk ≈ 2e-5 rad


def test_rates_above_full_scale_without_truth_warn():
    t = np.arange(0, 1, 0.01)
    w = np.tile([100.0, 0, 0], (len(t), 1))  # 100 rad/s = 5700 °/s: above a ±2000 °/s gyro
    from imu_dcm.gyro.rates import deg_evidence

    assert "above the ±2000 °/s" in deg_evidence(w, t, np.full((len(t), 4), np.nan))
    assert deg_evidence(w / 10, t, np.full((len(t), 4), np.nan)) is None


def test_without_truth_starts_from_init_quat(tmp_path):
    # Constant rate about body x from 90° about world z: q(t) = q0 ⊗ exp(ω t) (scipy oracle).
    t = np.arange(0, 2.0, 0.01)
    w = np.array([0.7, 0.0, 0.0])
    log = _write_log(tmp_path / "n", t, np.tile(w, (len(t), 1)))
    r = replay(log, bias="none", init_q_w_b=Q_Z90)
    ref = Rotation.from_quat(Q_Z90) * Rotation.from_rotvec(np.outer(t, w))
    ang = (Rotation.from_quat(r.q_est) * ref.inv()).magnitude()
    assert np.max(ang) < 1e-12  # constant axis: every method is exact up to round-off
    assert r.summary.truth_topic is None and r.summary.rms_error_deg is None
    # the body x-axis (first column of R_w_b) starts along world y
    np.testing.assert_allclose(
        Rotation.from_quat(r.q_est[0]).as_matrix()[:, 0], [0, 1, 0], atol=1e-15
    )
    ident = replay(log, bias="none")
    np.testing.assert_array_equal(ident.q_est[0], [0, 0, 0, 1])


def test_truth_that_never_overlaps_is_an_error(tmp_path):
    t = np.arange(0, 1.0, 0.01)
    t_ns = T0_NS + np.round(t * 1e9).astype(np.int64)
    q = np.tile([0, 0, 0, 1.0], (len(t), 1))
    log = write_bag(
        tmp_path / "late",
        imu=StampedSeries(t_ns, np.zeros((len(t), 3)), "imu"),
        quaternions={"/truth": StampedSeries(t_ns + 5 * 10**9, q, "world")},
    )
    with raises_naming(LogError, "/truth", "0..0.990", "5.000..5.990"):  # the two spans, s
        replay(log)


def test_bad_options():
    with raises_naming(InputError, "method", "'magnus4'", "'rk45'"):
        replay("whatever", method="rk45")
    with raises_naming(InputError, "gyro units", "'deg/s'", "'rpm'"):
        replay("whatever", gyro_units="rpm")
    with pytest.raises(InputError, match="init_q_w_b"):
        replay("whatever", init_q_w_b=[1.0, 0.0, 0.0])
    with raises_naming(InputError, "bias", 3, "nan"):
        replay("whatever", bias=[0.1, np.nan, 0.0])
    with raises_naming(InputError, "time", "'log'", "'gps'"):
        replay("whatever", time="gps")
    with raises_naming(InputError, "truth offset", "'auto'", "'soon'"):
        replay("whatever", truth_offset_s="soon")
    # text is parsed by the command line only, with the same one-line messages
    from imu_dcm.app.options import parse_numbers

    with raises_naming(InputError, "init quaternion x,y,z,w", 4, "'1,0,0'"):
        parse_numbers("1,0,0", 4, "init quaternion x,y,z,w")
    with raises_naming(InputError, "bias (rad/s)", 3, "'0.1,x,0'"):
        parse_numbers("0.1,x,0", 3, "bias (rad/s)")


def test_result_and_summary_are_frozen_and_json_ready(tmp_path):
    import dataclasses
    import json

    t = np.arange(0, 2.0, 0.01)
    log = _write_log(tmp_path / "f", t, np.tile([0.1, 0.0, 0.0], (len(t), 1)))
    r = replay(log, bias="none")
    with pytest.raises(dataclasses.FrozenInstanceError):
        r.summary.samples = 0
    with pytest.raises(dataclasses.FrozenInstanceError):
        r.start_index = 3
    d = json.loads(json.dumps(r.summary.to_dict(), allow_nan=False))
    contract = {
        "path",
        "samples",
        "duration_s",
        "rate_hz",
        "imu_topic",
        "truth_topic",
        "method",
        "bias_rad_s",
        "rms_error_deg",
        "max_error_deg",
        "rms_inclination_deg",
        "max_inclination_deg",
        "rms_heading_deg",
        "max_heading_deg",
        "dropped_nonfinite",
        "dropped_implausible",
        "dropped_duplicate",
        "dropped_backward",
        "gaps",
        "warnings",
        "elapsed_s",
    }
    assert contract <= set(d)
    assert d["samples"] == 200 and d["truth_topic"] is None and d["rms_error_deg"] is None

"""Replay judges a log from its data: the mounting between gyro and truth, and truth jumps the
gyro does not show. Each case is built from the shipped BROAD trial with a known answer."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest
from conftest import REPO_ROOT
from scipy.spatial.transform import Rotation

from imu_dcm.logio import read_log
from imu_dcm.replay import replay
from imu_dcm.replay.mounting import axis_permutation

TRIAL = REPO_ROOT / "replay" / "broad_07_undisturbed_fast_rotation_B"


@pytest.fixture(scope="module")
def log():
    return read_log(TRIAL)


@pytest.fixture(scope="module")
def clean(log):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return replay(log)


def _quiet_replay(log, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return replay(log, **kw)


def _mounted(log, r: Rotation):
    """The log as if its IMU were mounted at ``r`` (omega_G = r omega_T): gyro and accelerometer
    rotated together."""
    imu = dataclasses.replace(
        log.imu, omega_b=r.apply(log.imu.omega_b), accel_b=r.apply(log.imu.accel_b)
    )
    return dataclasses.replace(log, imu=imu)


def test_random_mountings_are_recovered_and_scored_as_unmounted(log, clean):
    # The unrotated trial's own gyro frame lies e0 from the optical body frame (a small
    # mounting, below the threshold, not applied). A rotated gyro's mounting must be recovered
    # within 1°; the replay then integrates the rates in a frame e from the unrotated one
    # (e = angle between the recovered rotation and the applied one), and a constant frame
    # error e moves every attitude error by at most 2e (R' = R0 E R_rel Eᵀ), so the RMS moves
    # by at most 2e too.
    for r in Rotation.random(3, random_state=np.random.default_rng(18)):
        res = _quiet_replay(_mounted(log, r))
        m = res.summary.mounting
        assert res.summary.mounting_applied and m["axes_determined"] == 3
        e = Rotation.from_quat(m["q_t_g"]) * r  # identity when recovered exactly
        assert np.degrees(e.magnitude()) < 1.0, m
        assert abs(m["angle_deg"] - np.degrees(r.magnitude())) < 1.0
        bound = 2 * np.degrees(e.magnitude()) + 1e-9
        assert abs(res.summary.rms_error_deg - clean.summary.rms_error_deg) <= bound
        assert any(w.startswith("mounting (") and "applied" in w for w in res.summary.warnings)


def test_axis_permutation_is_named(log):
    # IMU y along the body's z (q_t_g: 90° about x takes gyro y to truth z).
    q_t_g = Rotation.from_rotvec([np.pi / 2, 0, 0])
    res = _quiet_replay(_mounted(log, q_t_g.inv()))
    m = res.summary.mounting
    assert "gyro y = truth z" in m["permutation"] and "gyro z = truth -y" in m["permutation"]
    assert m["permutation_deg"] < 1.0
    words, deg = axis_permutation(q_t_g.as_matrix())
    assert words == "gyro x = truth x, gyro y = truth z, gyro z = truth -y" and deg < 1e-9


def test_mounting_none_reports_but_does_not_apply(log, clean):
    r = Rotation.from_rotvec([0.0, 0.0, np.pi / 2])
    res = _quiet_replay(_mounted(log, r), mounting="none")
    assert not res.summary.mounting_applied
    assert abs(res.summary.mounting["angle_deg"] - 90.0) < 1.0
    assert res.summary.rms_error_deg > 10 * clean.summary.rms_error_deg
    given = _quiet_replay(_mounted(log, r), mounting=r.inv().as_quat())
    assert given.summary.mounting_applied and given.summary.mounting["source"] == "given"
    assert abs(given.summary.rms_error_deg - clean.summary.rms_error_deg) < 2 * 0.1


def _jumped(log, times_s, jumps):
    """The log with its truth turned by world-frame rotations from each time on (the steps a
    re-initialised estimator makes)."""
    t = log.truth
    rel = (t.t_ns - log.imu.t_ns.min()) * 1e-9
    q = Rotation.from_quat(t.q_w_b)
    for ts, j in zip(times_s, jumps, strict=True):
        after = rel >= ts
        q = Rotation.concatenate([q[~after], j * q[after]]) if after.any() else q
        order = np.argsort(np.concatenate([np.flatnonzero(~after), np.flatnonzero(after)]))
        q = q[order]
    truth = dataclasses.replace(t, q_w_b=q.as_quat())
    return dataclasses.replace(log, truth=truth)


def test_truth_jumps_are_named_and_segments_score_as_clean(log, clean):
    times = (60.0, 120.0)
    jumps = (Rotation.from_rotvec([0, 0, 1.2]), Rotation.from_rotvec([0.5, -0.3, 0.2]))
    # no bias: the rests are judged by the truth's motion too, so a truth cut at a jump would
    # change them (the segments, not the rests, are what this compares)
    res = _quiet_replay(_jumped(log, times, jumps), bias="none")
    found = res.summary.truth_jumps
    assert len(found) == 2
    for f, ts, j in zip(found, times, jumps, strict=True):
        assert f["t0_s"] < ts - clean.t_s[0] + 0.01 and f["t1_s"] >= ts - 0.02
        # the truth turns the jump plus the body's own turn over one truth step
        assert abs(f["truth_deg"] - np.degrees(j.magnitude())) < f["gyro_deg"] + 1e-6
    line = next(w for w in res.summary.warnings if "jumps where the gyro does not" in w)
    assert line.count("° at ") == 2 and "3 segments" in line
    segs = res.summary.scored_segments
    assert len(segs) == 3
    # Each segment equals a clean replay anchored at the same sample: the clean truth from the
    # jump on. magnus4 looks one sample ahead, so a segment's last sample may differ; compare
    # the others.
    for k, seg in enumerate(segs):
        a = int(np.searchsorted(res.t_s, seg["start_s"]))
        b = int(np.searchsorted(res.t_s, seg["end_s"]))  # last sample left out
        if k == 0:
            ref = _quiet_replay(log, bias="none")
        else:
            cut = log.truth.t_ns >= res.t_ns[a]
            truth = dataclasses.replace(
                log.truth, t_ns=log.truth.t_ns[cut], log_t_ns=log.truth.log_t_ns[cut],
                q_w_b=log.truth.q_w_b[cut],
            )  # fmt: skip
            ref = _quiet_replay(dataclasses.replace(log, truth=truth), bias="none")
            assert ref.start_index == a
        mine, theirs = res.error.total_deg[a:b], ref.error.total_deg[a:b]
        ok = np.isfinite(mine)
        assert ok.sum() > 0.9 * (b - a)
        # same rates, same start, same steps: equal to rounding (1e-9° over 1e4 steps)
        assert np.max(np.abs(mine[ok] - theirs[ok])) < 1e-6


def test_truth_is_picked_among_candidates_by_how_it_follows_the_gyro(log, clean, tmp_path):
    # Two attitude topics: the optical truth and another body's (the truth played backwards).
    # The reader offers both; the replay scores the one that follows the gyro, whatever the
    # reader's order, and lists the other with its fit.
    from imu_dcm.logio.writers import StampedSeries, write_bag

    t = log.truth
    other = StampedSeries(t.t_ns, t.q_w_b[::-1].copy(), "world")
    path = write_bag(
        tmp_path / "two",
        imu=StampedSeries(log.imu.t_ns, log.imu.omega_b, "imu"),
        quaternions={"/a_other_body": other, "/b_mocap": StampedSeries(t.t_ns, t.q_w_b, "world")},
    )
    read = read_log(path)
    assert read.truth.topic == "/a_other_body"  # the reader's first, by name
    assert [c.topic for c in read.truth_candidates] == ["/b_mocap"]
    res = _quiet_replay(read)
    s = res.summary
    assert s.truth_topic == "/b_mocap"
    picked = [c for c in s.truth_candidates if c["picked"]]
    assert [c["topic"] for c in picked] == ["/b_mocap"] and picked[0]["follows"]
    rejected = next(c for c in s.truth_candidates if not c["picked"])
    assert (
        rejected["topic"] == "/a_other_body" and rejected["correlation"] < picked[0]["correlation"]
    )
    # the same figure as the log with the optical truth alone (gyro only: the bag has no accel)
    alone = _quiet_replay(dataclasses.replace(log, imu=dataclasses.replace(log.imu, accel_b=None)))
    assert abs(s.rms_error_deg - alone.summary.rms_error_deg) < 1e-6


def test_yaw_only_motion_determines_one_axis_and_its_mounting_is_applied():
    # A ground robot that only yaws (ψ(t) = 2 sin(0.5 t) rad), its IMU mounted with y along the
    # robot's vertical: only that axis is determined, and the smallest rotation taking gyro y to
    # truth z makes the replay score as the unmounted gyro (exact rates: far below 0.01°).
    from imu_dcm.logio import ImuSeries, LogData, TruthSeries

    rate, n = 200.0, 6000
    t = np.arange(n) / rate
    t_ns = (t * 1e9).astype(np.int64)
    psi = 2.0 * np.sin(0.5 * t)
    omega_t = np.stack([np.zeros(n), np.zeros(n), np.cos(0.5 * t)], axis=1)  # dψ/dt about z
    q = Rotation.from_rotvec(np.outer(psi, [0, 0, 1])).as_quat()
    q_t_g = Rotation.from_rotvec([np.pi / 2, 0, 0])  # gyro y = truth z
    imu = ImuSeries(t_ns, t_ns, q_t_g.inv().apply(omega_t), None, "/imu", "Imu", "imu_link")
    truth = TruthSeries(t_ns, t_ns, q, "/odom", "nav_msgs/msg/Odometry", "odom", "base_link", True)
    log = LogData(TRIAL, imu, truth, ())
    res = _quiet_replay(log, bias="none")
    m = res.summary.mounting
    assert m["axes_determined"] == 1 and res.summary.mounting_applied
    assert "gyro y = truth z" in m["permutation"]
    assert res.summary.rms_error_deg < 0.01
    line = next(w for w in res.summary.warnings if w.startswith("mounting (imu_link -> base_link)"))
    assert "1 of 3 axes (the rotation about it is unknown" in line


def test_a_5_deg_s_bias_is_found_at_rest_and_scores_as_without_it(log, clean):
    # The shipped trial with 5 °/s more bias on x and z: its accelerometer confirms the rests,
    # so the larger mean still counts as bias; the same rests are found, each bias is the old one
    # plus the added one, and the estimate is the same to rounding.
    added = np.radians([5.0, 0.0, 5.0])
    imu = dataclasses.replace(log.imu, omega_b=log.imu.omega_b + added)
    res = _quiet_replay(dataclasses.replace(log, imu=imu))
    assert res.summary.rest_confirmed
    old, new = clean.bias.segments, res.bias.segments
    assert [(s.start, s.stop) for s in new] == [(s.start, s.stop) for s in old]
    for a, b in zip(old, new, strict=True):
        np.testing.assert_allclose(np.subtract(b.bias_rad_s, a.bias_rad_s), added, atol=1e-12)
    assert abs(res.summary.rms_error_deg - clean.summary.rms_error_deg) < 1e-9
    # without the accelerometer the truth judges: where it covers a rest it shows no rotation,
    # so the 5 °/s mean is bias (an ADIS16448 at rest), and the rests before it (no truth yet)
    # are left out, a 5 °/s mean being a turn as far as the gyro alone can tell
    gyro_only = dataclasses.replace(imu, accel_b=None)
    res = _quiet_replay(dataclasses.replace(log, imu=gyro_only))
    first_truth_s = (log.truth.t_ns[0] - log.imu.t_ns[0]) * 1e-9
    assert res.bias.segments and res.summary.rest_confirmed
    for seg in res.bias.segments:
        assert seg.evidence == ("gyro floor", "truth") and seg.start_s >= first_truth_s - 0.5
        # the same rest as with the accelerometer, seen over less of it: the bias within 1 % of
        # the added 5 °/s (the clean rests' biases differ by under 0.02 °/s)
        near = min(old, key=lambda o: abs(o.start_s - seg.start_s))
        got = np.subtract(seg.bias_rad_s, near.bias_rad_s)
        assert np.all(np.abs(got - added) < 0.01 * np.radians(5.0)), (got, added)
    assert abs(res.summary.rms_error_deg - clean.summary.rms_error_deg) < 0.5
    # without truth too, nothing tells a 5 °/s mean from a turn: no rest, and it says why
    res = _quiet_replay(dataclasses.replace(log, imu=gyro_only, truth=None))
    assert not res.bias.segments and "mean |omega| (no accelerometer)" in res.summary.no_rest

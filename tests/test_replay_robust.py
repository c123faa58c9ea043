"""Replay under damaged or unusual logs: implausible samples, wild and shuffled stamps,
duplicates, the time base, a truth that is not the IMU's attitude, a truth offset, a non-finite
estimate. Built from the shipped BROAD trial 07 (real IMU, optical truth), rewritten with the
damage; the undamaged trial is the oracle (same samples, same answer)."""

from __future__ import annotations

import dataclasses
import warnings
from pathlib import Path

import numpy as np
import pytest
from conftest import BROAD_TRIALS, raises_naming
from scipy.spatial.transform import Rotation

from imu_dcm.errors import ImuDcmWarning, LogError
from imu_dcm.logio import read_log
from imu_dcm.logio.writers import StampedSeries, write_bag
from imu_dcm.replay import replay
from imu_dcm.replay.clean import clean_imu

REPO = Path(__file__).resolve().parents[1]
SHIPPED = REPO / "replay" / "broad_07_undisturbed_fast_rotation_B"
TRUTH = "/ground_truth/orientation"
DAY_NS = 86_400 * 10**9


@pytest.fixture(scope="module")
def trial():
    """The shipped trial's arrays and its undamaged replay (the oracle). The bags written here
    carry the gyro only, so the oracle judges rest from the gyro alone too."""
    log = read_log(SHIPPED)
    imu = dataclasses.replace(log.imu, accel_b=None)
    return imu, log.truth, replay(dataclasses.replace(log, imu=imu))


def _bag(path, imu, truth, *, t=None, w=None, log_t=None, tt=None, q=None, tlog=None, topic=TRUTH):
    return write_bag(
        path,
        imu=StampedSeries(
            imu.t_ns if t is None else t, imu.omega_b if w is None else w, "imu", log_t
        ),
        quaternions={
            topic: StampedSeries(
                truth.t_ns if tt is None else tt, truth.q_w_b if q is None else q, "world", tlog
            )
        },
    )


def _run(path, **kw):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        r = replay(path, **kw)
    return r, [str(c.message) for c in caught]


# ------------------------------------------------------------- the rule changes no good log
def _assert_untouched(t_ns, omega, name):
    with warnings.catch_warnings():
        warnings.simplefilter("error", ImuDcmWarning)  # not a word about a good log
        c = clean_imu(t_ns, omega, name)
    assert (c.dropped_implausible, c.dropped_nonincreasing, c.sorted_out_of_order) == (0, 0, 0)
    assert len(c.t_ns) == len(t_ns), name


@pytest.mark.parametrize(
    "name", sorted(p.name for p in (REPO / "replay").iterdir() if (p / "metadata.yaml").is_file())
)
def test_cleaning_leaves_shipped_logs_untouched(name):
    log = read_log(REPO / "replay" / name)
    _assert_untouched(log.imu.t_ns, log.imu.omega_b, name)


def test_cleaning_leaves_every_broad_trial_untouched(broad_dir):
    for trial in BROAD_TRIALS:
        log = read_log(broad_dir / trial)
        _assert_untouched(log.imu.t_ns, log.imu.omega_b, trial)


def test_cleaning_leaves_synthetic_scenes_untouched(tmp_path):
    from data_synth.cli import main as synth_main

    for scene in (
        ["heavy-top", "--motion", "wavy"],
        ["free-body", "--case", "intermediate"],
        ["coning"],
    ):
        out = tmp_path / scene[0]
        assert (
            synth_main(
                [
                    *scene,
                    "--rate",
                    "400",
                    "--duration",
                    "5",
                    "--gyro-noise-density",
                    "1e-2",
                    "--seed",
                    "3",
                    "--out",
                    str(out),
                ]
            )
            == 0
        )
        log = read_log(out)
        _assert_untouched(log.imu.t_ns, log.imu.omega_b, scene[0])


# ----------------------------------------------------------- implausible samples: one each
def test_implausible_samples_cost_one_sample_each(trial, tmp_path):
    imu, truth, ref = trial
    w = imu.omega_b.copy()
    bad = [10_000, 20_000, 30_000, 40_000]
    w[bad[0]] = 1e300  # a gyro of 1e300: no estimate at all before
    w[bad[1], 0] = 1e6  # a single 1e6 rad/s spike
    w[bad[2], 2] = -1.9e72  # one flipped exponent byte
    w[bad[3]] *= 256.0  # a flipped low exponent bit: 256x, below the hard limit
    assert 8 * np.percentile(np.linalg.norm(imu.omega_b, axis=1), 99.9) < np.linalg.norm(
        w[bad[3]]
    )  # the last is an isolated spike by the log's own statistics
    r, said = _run(_bag(tmp_path / "spikes", imu, truth, w=w))
    s = r.summary
    assert s.dropped_implausible == 4 and s.samples == ref.summary.samples - 4
    expect = (imu.t_ns[bad] - imu.t_ns[0]) * 1e-9
    np.testing.assert_allclose(s.implausible_t_s, expect, rtol=0, atol=1e-9)
    assert any("dropped 4 implausible samples" in x for x in said)
    # four missing 3.5 ms samples among 52 518: the answer is the undamaged one (3.80°), not
    # the 128° an integrated spike gives
    assert abs(s.rms_error_deg - ref.summary.rms_error_deg) < 0.02


def test_a_log_of_only_implausible_rates_is_an_error(tmp_path):
    t_ns = 1_700_000_000_000_000_000 + np.arange(100, dtype=np.int64) * 10**7
    log = write_bag(tmp_path / "huge", imu=StampedSeries(t_ns, np.full((100, 3), 1e300), "imu"))
    with raises_naming(LogError, 2, "/imu/data", 0):  # the least, the channel, the count
        _run(log)


def test_a_non_finite_estimate_is_an_error_never_a_score(trial, tmp_path, monkeypatch):
    from imu_dcm.replay import core

    monkeypatch.setattr(
        core, "integrate_quat", lambda w, t, q0, method, **kw: np.full((len(t), 4), np.nan)
    )
    with raises_naming(LogError, "NaN", "/imu/data"):
        _run(SHIPPED)


# ---------------------------------------------------------------------------- stamps
def test_one_wild_stamp_costs_one_sample(trial, tmp_path):
    imu, truth, ref = trial
    for k, jump in ((5_000, DAY_NS), (30_000, -DAY_NS), (len(imu.t_ns) - 1, DAY_NS)):
        t = imu.t_ns.copy()
        t[k] += jump
        # file order is arrival order: the log times stay right, one header stamp is wild
        r, said = _run(_bag(tmp_path / f"wild{k}", imu, truth, t=t, log_t=imu.t_ns))
        assert r.summary.samples == ref.summary.samples - 1  # was 62 % of the log
        assert r.summary.dropped_backward == 1 and r.summary.gaps == ()
        assert any("1 wild stamps" in x for x in said)
        assert abs(r.summary.rms_error_deg - ref.summary.rms_error_deg) < 0.01


def test_out_of_file_order_messages_are_sorted_and_duplicates_dropped(trial, tmp_path):
    imu, truth, ref = trial
    n = len(imu.t_ns)
    rng = np.random.default_rng(7)
    swap = rng.choice(np.arange(1, n - 2, 3), size=n // 100, replace=False)  # 1 % of messages
    rows = np.arange(n)
    rows[swap], rows[swap + 1] = swap + 1, swap  # neighbours arrive in the wrong order
    calm = np.setdiff1d(np.arange(n), np.concatenate([swap, swap + 1]))
    dup = np.sort(rng.choice(calm, size=200, replace=False))  # duplicates of in-order messages
    where = np.argsort(rows)[dup] + 1
    rows = np.insert(rows, where, dup)  # each duplicate right after its original
    arrival = np.sort(imu.t_ns[rows])  # log times increase in file order
    r, _said = _run(
        _bag(
            tmp_path / "shuffled", imu, truth, t=imu.t_ns[rows], w=imu.omega_b[rows], log_t=arrival
        )
    )
    s = r.summary
    assert s.time == "header" and s.samples == ref.summary.samples
    assert s.dropped_duplicate == 200 and s.sorted_out_of_order == len(swap)
    assert s.dropped_backward == 0
    np.testing.assert_array_equal(r.t_ns, ref.t_ns)
    assert abs(s.rms_error_deg - ref.summary.rms_error_deg) < 1e-6


def test_zero_header_stamps_use_log_time_and_say_why(trial, tmp_path):
    imu, truth, ref = trial
    r, said = _run(
        _bag(
            tmp_path / "zero",
            imu,
            truth,
            t=np.zeros_like(imu.t_ns),
            log_t=imu.t_ns,
            tt=np.zeros_like(truth.t_ns),
            tlog=truth.t_ns,
        )
    )
    assert r.summary.time == "log" and r.summary.samples == ref.summary.samples
    assert (
        sum(
            "using log time, not header stamps: the IMU header stamps are all equal" in x
            for x in said
        )
        == 1
    )
    assert abs(r.summary.rms_error_deg - ref.summary.rms_error_deg) < 1e-6
    with raises_naming(LogError, 2, "/imu/data", 1, "--time log"):
        _run(tmp_path / "zero", time="header")  # as asked: every stamp equal, with the hint


def test_device_clock_imu_against_wall_clock_truth_uses_log_time(trial, tmp_path):
    imu, truth, ref = trial
    device = imu.t_ns - imu.t_ns[0] + 5 * 10**9  # the IMU's own clock, from 5 s
    r, said = _run(_bag(tmp_path / "device", imu, truth, t=device, log_t=imu.t_ns))
    assert r.summary.time == "log" and any(
        "never overlap while their log times do" in x for x in said
    )
    assert abs(r.summary.rms_error_deg - ref.summary.rms_error_deg) < 1e-6
    with raises_naming(LogError, "/ground_truth/orientation", "0..183.810", "--time log"):
        _run(tmp_path / "device", time="header")


# ----------------------------------------------------------------------------- truth check
def test_truth_that_does_not_follow_the_gyro(trial, tmp_path):
    # Wheel-odometry-like truth: yaw only, unrelated to the IMU's motion.
    imu, truth, ref = trial
    t = (truth.t_ns - truth.t_ns[0]) * 1e-9
    yaw = Rotation.from_rotvec(
        np.outer(0.8 * np.sin(0.3 * t) + 0.5 * np.sin(1.1 * t), [0, 0, 1])
    ).as_quat()
    bag = _bag(tmp_path / "odom", imu, truth, q=yaw, topic="/odom")
    r, said = _run(bag)  # auto-picked: not scored, and said so in one line
    assert r.summary.truth_topic is None and r.summary.rms_error_deg is None
    line = [x for x in said if "does not follow the gyro" in x]
    assert len(line) == 1 and "replaying without truth" in line[0]
    assert r.summary.truth_check["correlation"] < 0.6
    named, said = _run(bag, truth_topic="/odom")  # named: scored anyway, mismatch recorded
    assert named.summary.truth_topic == "/odom" and named.summary.rms_error_deg > 20
    assert not named.summary.truth_check["follows"]
    assert any("scored anyway" in x for x in named.summary.warnings)
    # the real truth follows: correlation near 1 (the optical truth is the IMU's attitude)
    assert ref.summary.truth_check["follows"] and ref.summary.truth_check["correlation"] > 0.95


def test_truth_offset_is_measured_and_auto_applies_it(trial, tmp_path):
    imu, truth, ref = trial
    late = _bag(tmp_path / "late", imu, truth, tt=truth.t_ns + 30_000_000)  # truth 30 ms late
    r, _ = _run(late)
    base = ref.summary.truth_check["shift_s"]  # the trial's own small offset
    # the measured shift moves by the 30 ms added; grid of 10 ms refined by a parabola
    assert r.summary.truth_check["shift_s"] - base == pytest.approx(-0.030, abs=0.002)
    assert r.summary.truth_offset_s == 0.0 and r.summary.rms_error_deg > ref.summary.rms_error_deg
    auto, _ = _run(late, truth_offset_s="auto")
    own, _ = _run(SHIPPED, truth_offset_s="auto")
    assert auto.summary.truth_offset_s == pytest.approx(
        own.summary.truth_offset_s - 0.030, abs=0.002
    )
    assert abs(auto.summary.rms_error_deg - own.summary.rms_error_deg) < 0.02
    fixed, _ = _run(late, truth_offset_s=-0.030)  # seconds: exactly undoes the shift
    assert abs(fixed.summary.rms_error_deg - ref.summary.rms_error_deg) < 1e-6


def test_steady_spin_truth_is_kept_and_still_truth_under_motion_is_not(tmp_path):
    # A constant-rate spin: the rate norm is flat (nothing to correlate), the gyro noisy. Truth
    # is exp(ω t) in closed form; it must be kept. The same gyro against a still truth must not.
    t = np.arange(0, 4.0, 1 / 400)
    w = np.array([0.3, -0.2, 2.0])
    rng = np.random.default_rng(1)
    gyro = w + rng.normal(0, 0.05, (len(t), 3))  # |ω| noise far above the 0.05 rad/s threshold
    t_ns = 1_700_000_000_000_000_000 + np.round(t * 1e9).astype(np.int64)
    spin = Rotation.from_rotvec(np.outer(t, w)).as_quat()
    still = np.tile([0.0, 0.0, 0.0, 1.0], (len(t), 1))
    for name, q, kept in (("spin", spin, True), ("still", still, False)):
        bag = write_bag(
            tmp_path / name,
            imu=StampedSeries(t_ns, gyro, "imu"),
            quaternions={TRUTH: StampedSeries(t_ns, q, "world")},
        )
        r, said = _run(bag, bias="none")
        assert (r.summary.truth_topic == TRUTH) is kept, said
        assert r.summary.truth_check["correlation"] is None  # a flat norm: levels compared
        assert r.summary.truth_check["follows"] is kept


def test_header_stamps_that_do_not_increase_use_log_time(trial, tmp_path):
    # A driver that stamps in bursts: within every block of 4 messages the header stamps run
    # backwards (3 of 4 steps fall), while the log (receive) times are right.
    imu, truth, ref = trial
    n = len(imu.t_ns) // 4 * 4
    backwards = imu.t_ns[:n].reshape(-1, 4)[:, ::-1].ravel()
    t = imu.t_ns.copy()
    t[:n] = backwards
    r, said = _run(_bag(tmp_path / "bursts", imu, truth, t=t, log_t=imu.t_ns))
    assert r.summary.time == "log"
    assert sum("header stamps fall at 75 % of the steps" in x for x in said) == 1
    assert abs(r.summary.rms_error_deg - ref.summary.rms_error_deg) < 1e-6


@pytest.mark.parametrize("holes", [True, False])
@pytest.mark.parametrize("offset", [0.0, 50.0])
def test_lagged_correlation_equals_numpy_corrcoef_per_lag(holes, offset):
    # with and without invalid rows (the two ways the sums are taken), and on a steady spin's
    # rate norm (a large mean, small changes: the sums are of the centred series)
    from imu_dcm.replay.rate_check import lagged_correlation

    rng = np.random.default_rng(5)
    n, lags = 500, 40
    g = offset + np.cumsum(rng.normal(size=n))
    h = np.roll(g, 7) + rng.normal(0, 0.5, n)  # h[i] ≈ g[i - 7]: the best lag is k = -7
    valid = rng.random(n) > 0.1 if holes else np.ones(n, dtype=bool)
    corr, count = lagged_correlation(g, h, valid, lags)
    for k in range(-lags, lags + 1):
        m = valid[max(-k, 0) : n - max(k, 0)]
        a = g[max(k, 0) : n + min(k, 0)][m]
        b = h[max(-k, 0) : n - max(k, 0)][m]
        assert count[k + lags] == len(a)
        # sums of n products: round-off grows with n (n·eps·C, C for the data's range)
        tol = n * np.finfo(float).eps * 1e3
        assert abs(corr[k + lags] - np.corrcoef(a, b)[0, 1]) < tol, k
    assert int(np.argmax(corr)) - lags == -7


def test_integrated_rate_is_scipys_cumulative_trapezoid_interpolated():
    from scipy.integrate import cumulative_trapezoid

    from imu_dcm.replay.rate_check import integrated_rate

    rng = np.random.default_rng(6)
    n = 20_000
    t = np.cumsum(rng.integers(900_000, 1_100_000, n)).astype(np.int64)  # ~1 kHz, jittered
    w = rng.normal(size=(n, 3))
    ts = (t - t[0]) * 1e-9
    cum = cumulative_trapezoid(w, ts, axis=0, initial=0.0)
    # in order, out of order, on the samples, before the first and after the last
    at = np.concatenate([rng.integers(t[0] - 10**8, t[-1] + 10**8, 3000), t[::97]])
    for stamps in (np.sort(at), at):
        got = integrated_rate(t, w, stamps)
        te = (stamps - t[0]) * 1e-9
        want = np.stack([np.interp(te, ts, cum[:, k]) for k in range(3)], axis=1)
        # sums of n steps in another order: n·eps of the largest partial sum (~sqrt(n) rad)
        np.testing.assert_allclose(got, want, rtol=0, atol=n * np.finfo(float).eps * 200)


@pytest.mark.parametrize(
    "rows", ["every row, in order", "every row, from before the gyro", "a row without attitude"]
)
def test_find_jumps_equals_every_step_judged_in_full(rows):
    """The jump search screens steps by |q_i . q_i+1| before computing exact angles: the jumps
    it finds are those of judging every truth step against the gyro's path (brute force),
    whether the truth's rows are read in place or gathered (a row left out)."""
    from scipy.spatial.transform import Rotation

    from imu_dcm.replay.truth import JUMP_DEG, JUMP_RATIO, find_jumps

    rng = np.random.default_rng(21)
    t_ns = np.arange(2001, dtype=np.int64) * 5_000_000  # 200 Hz, 10 s
    omega = 0.3 * np.sin(np.outer(t_ns * 1e-9, [0.7, 1.1, 1.9]) + rng.random(3))
    tt = t_ns[::2] + 1_000_000  # 100 Hz truth, between gyro stamps
    if rows == "every row, from before the gyro":
        tt = tt - 50_000_000  # its first five rows before the gyro's first sample
    steps = Rotation.from_rotvec(omega[::2][:-1] * 0.01)
    rots = [Rotation.identity()]
    for k, step in enumerate(steps):
        rots.append(rots[-1] * step)
        jump = {100: 4.9, 300: 5.3, 500: 20.0, 700: 170.0, 800: 4.0}.get(k)
        if jump:  # a turn about a random axis the gyro does not show
            axis = rng.normal(size=3)
            turn = Rotation.from_rotvec(np.radians(jump) * axis / np.linalg.norm(axis))
            rots[-1] = turn * rots[-1]
    q = Rotation.concatenate(rots).as_quat() * rng.choice([-1.0, 1.0], size=(len(rots), 1))
    if rows != "every row, in order":
        q[50] = np.nan  # far from the jumps: the steps 49 and 50 become one
    got = find_jumps(t_ns, omega, tt, q)
    kept = np.isfinite(q[:, 0])
    tt, q = tt[kept], q[kept]
    # brute force: every step's angle (scipy) and the gyro's path length over it (trapezoid of
    # |omega|, linear between samples), the rule of JUMP_DEG and JUMP_RATIO
    ts = (t_ns - t_ns[0]) * 1e-9
    speed = np.linalg.norm(omega, axis=1)
    cum = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(ts))])
    inside = (tt >= t_ns[0]) & (tt <= t_ns[-1])
    te = (tt[inside] - t_ns[0]) * 1e-9
    r = Rotation.from_quat(q[inside])
    truth_deg = np.degrees((r[:-1].inv() * r[1:]).magnitude())
    gyro_deg = np.degrees(np.diff(np.interp(te, ts, cum)))
    want = np.flatnonzero((truth_deg - gyro_deg > JUMP_DEG) & (truth_deg > JUMP_RATIO * gyro_deg))
    assert len(want) == 3  # 5.3°, 20° and 170°; not 4.9° or 4°
    assert len(got) == len(want)
    for j, i in zip(got, want, strict=True):
        assert abs(j.t0_s - te[i]) < 1e-9 and abs(j.t1_s - te[i + 1]) < 1e-9
        # angles: scipy's and ours differ by rounding (1e-12 deg); the path by its sum order
        assert abs(j.truth_deg - truth_deg[i]) < 1e-9 and abs(j.gyro_deg - gyro_deg[i]) < 1e-9


@pytest.mark.parametrize(
    ("gyro_hz", "truth_hz", "seconds", "want_s"),
    [
        (1000, 1000, 30, 0.01),  # both fast: the 10 ms floor
        (1000, 20, 30, 0.1),  # a slow truth: two of its steps
        (5, 1000, 30, 0.2),  # a slow gyro: one of its steps
        (1000, 1000, 3000, 0.01),  # long: the same floor, whatever the length
    ],
)
def test_the_rate_grids_step_is_the_floor_or_the_median_steps(gyro_hz, truth_hz, seconds, want_s):
    # the grid's step is max(10 ms, 2 truth steps, 1 gyro step), whatever the length, the medians
    # taken only where a step is longer than that floor (jittered stamps: medians, not means)
    from imu_dcm.replay.rate_check import rate_grid

    rng = np.random.default_rng(3)

    def stamps(hz):
        n = int(seconds * hz) + 1
        return (np.arange(n) * 1e9 / hz + rng.uniform(-0.05, 0.05, n) * 1e9 / hz).astype(np.int64)

    t, tt = stamps(gyro_hz), stamps(truth_hz)
    q = np.tile([0.0, 0.0, 0.0, 1.0], (len(tt), 1))
    grid = rate_grid(t, np.zeros((len(t), 3)), tt, q)
    assert grid is not None
    want = max(0.01, 2 * np.median(np.diff(tt)) * 1e-9, np.median(np.diff(t)) * 1e-9)
    assert grid.step_s == want
    assert abs(grid.step_s - want_s) < 0.01 * want_s


def test_the_rate_grid_is_as_fine_for_a_long_log_as_for_a_short_one():
    # the grid step comes from the stamps (2 truth steps, the gyro step, 10 ms at least), not
    # from the log's length: 50 min at 100 Hz is judged on the 20 ms steps of 5 min
    from scipy.spatial.transform import Rotation

    from imu_dcm.replay.rate_check import rate_grid

    for minutes in (5, 50):
        n = minutes * 60 * 100 + 1
        t = np.arange(n, dtype=np.int64) * 10_000_000
        w = np.tile([0.0, 0.0, 0.3], (n, 1))
        q = Rotation.from_rotvec(np.outer(t * 1e-9, [0.0, 0.0, 0.3])).as_quat()
        grid = rate_grid(t, w, t, q)
        assert grid.step_s == pytest.approx(0.02, abs=1e-12)
        # each step turns 0.3 rad/s x 20 ms about z, in the gyro's integral and the truth's
        ok = np.isfinite(grid.truth_rotvec[:, 2])
        np.testing.assert_allclose(grid.gyro_rotvec[:, 2], 0.3 * grid.dt_s, rtol=1e-9)
        np.testing.assert_allclose(grid.truth_rotvec[ok, 2], 0.3 * grid.dt_s[ok], rtol=1e-6)

"""Units and time a new user gets wrong: ms stamps declared as s, deg/s declared as rad/s, a Git
LFS pointer in place of the log. Each gets one line naming the likely fix."""

from __future__ import annotations

import re
import warnings

import numpy as np
import pytest

from imu_dcm.errors import ImuDcmWarning, LogError
from imu_dcm.gyro.stamps import timing_doubt
from imu_dcm.logio import read_log
from imu_dcm.replay import replay
from imu_dcm.replay.csv_import import convert_csv

N = 4000


def _csv(path, t, w):
    rows = "\n".join(f"{a:.6f},{b:.6f},{c:.6f},{d:.6f}" for a, (b, c, d) in zip(t, w, strict=True))
    path.write_text("t,gx,gy,gz\n" + rows + "\n")
    return path


def _rates(rng):
    return 0.3 * np.sin(np.linspace(0, 30, N))[:, None] + 0.01 * rng.standard_normal((N, 3))


def test_ms_stamps_declared_as_s_are_flagged_in_convert_and_replay(tmp_path):
    # 200 Hz for 20 s, stamped in ms (0, 5, 10, ...) and declared as seconds: "0.2 Hz over
    # 5.6 h" unless told; as ms it is 200 Hz over 20 s.
    rng = np.random.default_rng(1)
    csv_path = _csv(tmp_path / "g.csv", np.arange(N) * 5.0, _rates(rng))
    cols = {"time_col": "t", "gyro_cols": "gx,gy,gz", "gyro_units": "rad/s"}
    with pytest.warns(ImuDcmWarning, match="no IMU produces") as said:
        bag = convert_csv(csv_path, tmp_path / "bag", time_unit="s", **cols)
    (line,) = [str(w.message) for w in said if "no IMU produces" in str(w.message)]
    assert "0.2 Hz (median step 5 s)" in line and "as ms: 200 Hz over 20 s" in line
    assert line.endswith("pass --time-units ms if that is the column's unit")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = replay(bag, truth_topic="none")
    said = [w for w in res.summary.warnings if "stamps no IMU produces" in w]
    assert len(said) == 1 and "convert-csv --time-units ms" in said[0], said
    assert any("stamps no IMU produces" in str(c.message) for c in caught)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the right unit: not a word
        convert_csv(csv_path, tmp_path / "ok", time_unit="ms", **cols)


def test_plausible_stamps_say_nothing_and_days_are_flagged():
    step = np.int64(5_000_000)
    assert timing_doubt(np.arange(N, dtype=np.int64) * step) is None  # 200 Hz
    assert timing_doubt(np.arange(N, dtype=np.int64) * 1_000_000_000) is None  # 1 Hz: slow
    days = np.arange(N, dtype=np.int64) * 100_000_000 + np.int64(
        np.concatenate([np.zeros(N // 2), np.full(N - N // 2, 3 * 86400)]) * 1e9
    )
    clause, _fix = timing_doubt(days)
    assert "days" in clause


def test_deg_per_s_warning_says_one_consistent_thing(tmp_path):
    # Rates in deg/s declared as rad/s, no truth: the warning quotes the 99th percentile and
    # what it would be as deg/s, both true of the data.
    rng = np.random.default_rng(2)
    w_deg = np.degrees(2.0 * np.sin(np.linspace(0, 30, N))[:, None]) + rng.standard_normal((N, 3))
    csv_path = _csv(tmp_path / "g.csv", np.arange(N) * 0.005, w_deg)
    bag = convert_csv(
        csv_path, tmp_path / "bag", time_col="t", time_unit="s", gyro_cols="gx,gy,gz",
        gyro_units="rad/s",
    )  # fmt: skip
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = replay(bag, truth_topic="none")
    (line,) = [w for w in res.summary.warnings if "look like deg/s" in w]
    m = re.search(
        r"99th percentile of \|omega\| is (\d+) rad/s, above.*as deg/s it would be ([\d.]+) rad/s",
        line,
    )
    assert m, line
    p99 = np.percentile(np.linalg.norm(w_deg, axis=1), 99)
    assert abs(float(m.group(1)) - p99) <= 0.5 and p99 > 34.9
    assert abs(float(m.group(2)) - np.radians(p99)) <= 0.005


def test_git_lfs_pointer_is_named_with_git_lfs_pull(tmp_path):
    pointer = (
        "version https://git-lfs.github.com/spec/v1\n"
        "oid sha256:4d7a214614ab2935c943f9e0ff69d22eadbb8f32b1258daaa5e2ca24d17e2393\n"
        "size 52428800\n"
    )
    f = tmp_path / "run.mcap"
    f.write_text(pointer)
    with pytest.raises(LogError) as info:
        read_log(f)
    msg = str(info.value)
    assert "a Git LFS pointer to a 52.4 MB file" in msg and "`git lfs pull`" in msg
    assert "\n" not in msg


def test_ms_stamps_declared_as_s_at_1_khz_are_caught_by_the_gyros_content():
    # 1 kHz for 20 s stamped in ms and declared as s: 1 Hz over 20 000 s, a rate an IMU may
    # have. The content contradicts it: a 2 rad/s turn, smooth sample to sample (resolved), would
    # turn 2 rad per 1 s step. As ms: 1000 Hz over 20 s.
    rng = np.random.default_rng(7)
    n = 20_000
    t_ns = np.arange(n, dtype=np.int64) * 1_000_000_000  # each ms read as a second
    tt = np.arange(n) / 1000.0
    w = np.stack([2.0 * np.sin(tt), 2.0 * np.cos(0.5 * tt), 0.1 + 0 * tt], axis=1)
    w += 1e-3 * rng.standard_normal((n, 3))
    clause, fix = timing_doubt(t_ns, "s", w)
    assert fix == "ms" and "1 Hz" in clause and "as ms: 1000 Hz over 20 s" in clause
    assert "smooth" in clause
    # the same stamps with rates that really change from second to second are a slow log
    assert timing_doubt(t_ns, "s", rng.standard_normal((n, 3))) is None
    # and a slow log that hardly turns per step is plausible
    assert timing_doubt(t_ns, "s", 0.01 * w) is None


@pytest.mark.parametrize("declared", ["deg/s", "rad/s"])
def test_gyro_units_are_judged_against_the_truth_both_ways(declared):
    # The shipped trial's rates are rad/s. Declared deg/s they read 57.3x slower than the truth
    # turns; written in deg/s and declared rad/s, 57.3x faster. Either way one line says so.
    from conftest import REPO_ROOT

    log = read_log(REPO_ROOT / "replay" / "broad_07_undisturbed_fast_rotation_B")
    if declared == "rad/s":
        import dataclasses

        log = dataclasses.replace(
            log, imu=dataclasses.replace(log.imu, omega_b=np.degrees(log.imu.omega_b))
        )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = replay(log, gyro_units=declared)
    lines = [w for w in res.summary.warnings if "the rates look like" in w]
    assert len(lines) == 1, res.summary.warnings
    if declared == "deg/s":
        assert "look like rad/s" in lines[0] and "1/57" in lines[0]
    else:
        assert "look like deg/s" in lines[0] and "57." in lines[0]


def test_the_rate_ratio_is_the_median_over_steps_where_the_truth_moves():
    # Oracle: scipy's relative rotations step by step and numpy's median, over every step at
    # once; the ratio is taken a block of steps at a time (several blocks and a partial one).
    from scipy.spatial.transform import Rotation

    from imu_dcm.arrays import BLOCK_ROWS
    from imu_dcm.gyro.rates import _MOVING_RAD_S, truth_rate_ratio

    rng = np.random.default_rng(5)
    n = 2 * BLOCK_ROWS + 1001
    t_s = np.cumsum(rng.uniform(0.9e-3, 1.1e-3, n))
    w = rng.normal(size=(n, 3)) * np.where(np.arange(n) % 7 < 2, 0.0, 1.0)[:, None]  # some still
    q = (Rotation.from_rotvec(np.cumsum(w * 1e-3, axis=0) % 3)).as_quat()
    q[[10, BLOCK_ROWS, n - 3]] = np.nan  # uncovered rows: their steps do not count
    gyro = 0.87 * w
    got = truth_rate_ratio(gyro, t_s, q)
    r = Rotation.from_quat(np.nan_to_num(q, nan=1.0))
    rate = (r[:-1].inv() * r[1:]).magnitude() / np.diff(t_s)
    pair = np.isfinite(q[:-1, 0]) & np.isfinite(q[1:, 0])
    moving = pair & (rate > _MOVING_RAD_S)
    mid = np.linalg.norm(0.5 * (gyro[:-1] + gyro[1:]), axis=1)
    want = np.median(mid[moving] / rate[moving])
    # each step's angle differs from scipy's by rounding (~1e-16 of ~1e-3 rad): ~1e-13 relative
    assert abs(got - want) < 1e-12 * want
    assert truth_rate_ratio(gyro[:12], t_s[:12], np.full((12, 4), np.nan)) is None

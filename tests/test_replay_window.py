"""``--score-window``: the error scored on a window or on the intervals the log declares.

A still body with a known gyro bias b about z, replayed with ``--bias none``, has the heading
error b t at every stamp t (the truth is the identity): the RMS over any window is
b sqrt(mean(t_k^2)) over the stamps inside it, computed here from the input alone. BROAD's
declared movement phases are checked against the phases by sample index (BROAD's own form).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import assert_names
from test_replay_broad import movement_rms_deg

from imu_dcm.logio.writers import StampedSeries, write_bag
from imu_dcm.replay import replay
from imu_dcm.replay.__main__ import main

B_RAD_S, HZ, N = 0.01, 100, 2001  # 20 s
T0_NS = 1_000_000_000


@pytest.fixture
def drifting(tmp_path):
    t_ns = T0_NS + np.arange(N, dtype=np.int64) * (10**9 // HZ)
    w = np.tile([0.0, 0.0, B_RAD_S], (N, 1))
    q = np.tile([0.0, 0.0, 0.0, 1.0], (N, 1))
    spans = [[T0_NS + 2 * 10**9, T0_NS + 5 * 10**9], [T0_NS + 12 * 10**9, T0_NS + 15 * 10**9]]
    return write_bag(
        tmp_path / "bag",
        imu=StampedSeries(t_ns, w, "imu"),
        quaternions={"/ground_truth/orientation": StampedSeries(t_ns, q, "world")},
        custom_data={"demo.still_intervals_stamp_ns": json.dumps(spans)},
    )


def _expected_rms_deg(inside) -> float:
    t = np.arange(N) / HZ
    return float(np.degrees(B_RAD_S) * np.sqrt(np.mean(t[inside(t)] ** 2)))


@pytest.mark.parametrize(
    ("window", "inside"),
    [
        ("all", lambda t: t >= 0),
        ("5:10", lambda t: (t >= 5 - 1e-9) & (t <= 10 + 1e-9)),
        (
            "declared",
            lambda t: ((t >= 2 - 1e-9) & (t <= 5 + 1e-9)) | ((t >= 12) & (t <= 15 + 1e-9)),
        ),
    ],
)
def test_score_window_scores_only_its_samples(drifting, tmp_path, capsys, window, inside):
    out = tmp_path / "s.json"
    argv = [str(drifting), "--rerun", "off", "--bias", "none", "--mounting", "none"]
    assert main([*argv, "--score-window", window, "--summary-json", str(out)]) == 0
    got = json.loads(out.read_text())
    # the error is b t to rounding (magnus4 is exact for a constant rate)
    assert got["rms_error_deg"] == pytest.approx(_expected_rms_deg(inside), rel=1e-9)
    assert got["truth_samples_used"] == int(inside(np.arange(N) / HZ).sum())
    text = capsys.readouterr().out
    if window == "declared":
        assert "scored     declared demo.still: 2 intervals, 6.00 s (602 samples)" in text


@pytest.mark.parametrize("bad", ["3:1", "a:b", "1:2:3", "nan:4", "phases"])
def test_a_bad_window_is_one_line_and_writes_nothing(drifting, tmp_path, capsys, bad):
    out = tmp_path / "s.json"
    assert (
        main([str(drifting), "--rerun", "off", "--score-window", bad, "--summary-json", str(out)])
        == 2
    )
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1
    assert_names(err, "--score-window", "T0:T1", repr(bad))
    assert not out.exists()


def test_declared_on_a_log_declaring_none_is_refused(tmp_path, capsys):
    t_ns = T0_NS + np.arange(100, dtype=np.int64) * 10_000_000
    bag = write_bag(tmp_path / "plain", imu=StampedSeries(t_ns, np.zeros((100, 3)), "imu"))
    out = tmp_path / "s.json"
    assert (
        main([str(bag), "--rerun", "off", "--score-window", "declared", "--summary-json", str(out)])
        == 2
    )
    assert_names(capsys.readouterr().err, "--score-window declared", "intervals_stamp_ns")
    assert not out.exists()


@pytest.mark.broad
def test_broad_declared_phases_are_the_movement_phases(broad_dir):
    bag = broad_dir / "05_undisturbed_slow_rotation_with_breaks_B"
    got = replay(bag, score_window="declared")
    assert got.summary.rms_error_deg == pytest.approx(movement_rms_deg(replay(bag), bag), rel=1e-12)


# ------------------------------------------------------------------ the best shift's hint
def _lagged(tmp_path, lag_ns: int):
    """A rate 2 sin(pi t) rad/s about z for 20 s at 200 Hz; the truth is the closed form
    theta(t) = (2 / pi)(1 - cos(pi t)), stamped ``lag_ns`` late."""
    n = 4001
    t_ns = T0_NS + np.arange(n, dtype=np.int64) * 5_000_000
    t = (t_ns - T0_NS) * 1e-9
    w = np.zeros((n, 3))
    w[:, 2] = 2 * np.sin(np.pi * t)
    theta = 2 / np.pi * (1 - np.cos(np.pi * t))
    q = np.stack([0 * t, 0 * t, np.sin(theta / 2), np.cos(theta / 2)], axis=1)
    return write_bag(
        tmp_path / f"lag{lag_ns}",
        imu=StampedSeries(t_ns, w, "imu"),
        quaternions={"/ground_truth/orientation": StampedSeries(t_ns + lag_ns, q, "world")},
    )


def _summary(bag, tmp_path, *extra):
    out = tmp_path / "s.json"
    argv = [str(bag), "--rerun", "off", "--bias", "none", "--mounting", "none"]
    assert main([*argv, *extra, "--summary-json", str(out)]) == 0
    return json.loads(out.read_text())


def test_a_clear_best_shift_names_truth_offset_auto_and_its_rms(tmp_path, capsys):
    bag = _lagged(tmp_path, 40_000_000)  # 40 ms: 8 gyro steps
    plain = _summary(bag, tmp_path)
    text = capsys.readouterr().out
    auto = _summary(bag, tmp_path, "--truth-offset", "auto")
    # the hint scores the samples both truths cover (8 fewer of 4000 than the auto run): the
    # same residual of the found shift over a near-equal set
    assert plain["offset_auto_rms_deg"] == pytest.approx(auto["rms_error_deg"], rel=0.05)
    # 40 ms of a rate up to 2 rad/s is up to 4.6°; the shift found removes nearly all of it
    assert auto["rms_error_deg"] < plain["rms_error_deg"] / 1000
    # stamped 40 ms late: -40 ms added to the truth stamps aligns it
    assert auto["truth_offset_s"] == pytest.approx(-0.040, abs=0.5e-3)
    assert "(--truth-offset auto applies it: RMS " in text
    assert auto["offset_auto_rms_deg"] is None  # applied: nothing to suggest


def test_no_shift_gives_no_hint_and_no_negative_zero(tmp_path, capsys):
    got = _summary(_lagged(tmp_path, 0), tmp_path)
    text = capsys.readouterr().out
    assert got["offset_auto_rms_deg"] is None
    assert "-0.0 ms" not in text and "--truth-offset auto" not in text


@pytest.mark.parametrize(
    ("shift_s", "text"),
    [(-1e-6, "0.0 ms"), (4e-5, "0.0 ms"), (0.0041, "+4.1 ms"), (-0.02, "-20.0 ms")],
)
def test_shift_is_printed_without_a_negative_zero(shift_s, text):
    from imu_dcm.replay.offset_hint import shift_ms

    assert shift_ms(shift_s) == text

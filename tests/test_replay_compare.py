"""Tests of ``--compare`` (imu_dcm.replay.compare): magnus4 in a comparison is the plain replay,
a peer is its direct call on the same rates and start, each segment starts from the replay's
anchor, and a missing peer names what installs it.
"""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from imu_dcm.errors import ImuDcmWarning, InputError
from imu_dcm.integrator.peers import PEERS
from imu_dcm.replay import replay
from imu_dcm.replay.__main__ import main
from imu_dcm.replay.compare import compare_methods, parse_compare


@pytest.fixture(scope="module")
def top(tmp_path_factory):
    """A wavy heavy top at 400 Hz, 3 s, with white noise and a bias (the replay removes none:
    no rest): every method differs, and a peer's first-order error is far above magnus4's."""
    from data_synth.cli import main as synth_main

    out = tmp_path_factory.mktemp("cmp") / "top"
    args = ["heavy-top", "--motion", "wavy", "--rate", "400", "--duration", "3"]
    noise = ["--gyro-noise-density", "1e-4", "--gyro-bias", "0.001,0,0", "--out", str(out)]
    assert synth_main([*args, *noise]) == 0
    return out


def test_magnus4_in_a_comparison_is_the_plain_replay(top):
    r = replay(top)
    rows = compare_methods(r, ("magnus4", "trapezoid"))
    np.testing.assert_array_equal(rows[0].q_est, r.q_est)  # the same kernel on the same rates
    assert rows[0].evaluation == r.summary.evaluation
    assert rows[0].evaluation["total_deg"]["rms"] == r.summary.rms_error_deg
    # trapezoid is second order: on this 20 Hz spin at 400 Hz, far worse than magnus4
    assert rows[1].evaluation["total_deg"]["rms"] > 10 * r.summary.rms_error_deg
    assert all(row.ns_per_sample > 0 for row in rows)


@pytest.mark.parametrize("name,peer", [("vqf", "vqf_batch"), ("imufusion", "imufusion_gain0")])
def test_a_peer_equals_its_direct_call(top, name, peer):
    pytest.importorskip(name)  # the peer's own module
    r = replay(top)
    (row,) = compare_methods(r, (name,))
    a = r.start_index
    direct = PEERS[peer].fn(r.omega_b[a:], r.t_s[a:], r.q_est[a])  # the same rates and start
    np.testing.assert_array_equal(row.q_est[a:], direct)
    assert np.isnan(row.q_est[:a]).all()


def test_each_segment_starts_from_the_replays_anchor(tmp_path):
    """After a truth jump, every method re-anchors where the replay did."""
    from scipy.spatial.transform import Rotation

    from imu_dcm.logio.writers import StampedSeries, write_bag

    t = np.arange(0, 6.0, 0.005)
    rate = np.c_[0.4 * np.sin(t), 0.2 + 0 * t, 0.1 * np.cos(2 * t)]
    q = Rotation.identity()
    qs = [q]
    for k in range(1, len(t)):  # truth: the exact product of constant-rate steps, then a jump
        qs.append(qs[-1] * Rotation.from_rotvec(rate[k] * 0.005))
    q_true = Rotation.concatenate(qs)
    jump = t >= 3.0
    q_true = Rotation.concatenate([q_true[~jump], Rotation.from_rotvec([0, 0.6, 0]) * q_true[jump]])
    t_ns = 1_700_000_000_000_000_000 + np.round(t * 1e9).astype(np.int64)
    log = write_bag(
        tmp_path / "j",
        imu=StampedSeries(t_ns, rate, "imu"),
        quaternions={"/ground_truth/orientation": StampedSeries(t_ns, q_true.as_quat(), "world")},
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ImuDcmWarning)
        r = replay(log, truth_topic="/ground_truth/orientation", bias="none", method="end")
    assert len(r.summary.scored_segments) == 2
    rows = compare_methods(r, ("end", "reference"))
    np.testing.assert_array_equal(rows[0].q_est, r.q_est)
    # the reference loop takes the same end-of-step rule: equal to rounding over 600 steps
    ok = np.isfinite(r.q_est[:, 0])
    np.testing.assert_allclose(np.abs(rows[1].q_est[ok]), np.abs(r.q_est[ok]), atol=1e-12)


def test_compare_names_are_checked_and_a_missing_peer_names_its_install(monkeypatch):
    assert parse_compare("magnus4, end ,vqf") == ("magnus4", "end", "vqf")
    with pytest.raises(InputError, match="got 'nope'"):
        parse_compare("magnus4,nope")
    with pytest.raises(InputError, match="once"):
        parse_compare("end,end")
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda n, *a: None if n == "vqf" else real(n, *a)
    )
    with pytest.raises(InputError, match=r"pip install vqf \(or pip install 'imu_dcm\[bench\]'\)"):
        parse_compare("magnus4,vqf")


def test_compare_command_prints_a_table_and_writes_json_and_a_figure(top, tmp_path, capsys):
    pytest.importorskip("matplotlib")
    js, fig = tmp_path / "s.json", tmp_path / "c.png"
    argv = [str(top), "--rerun", "off", "--compare", "magnus4,end", "--summary-json", str(js)]
    assert main([*argv, "--plot", str(fig)]) == 0
    out = capsys.readouterr().out
    table = [ln for ln in out.splitlines() if ln.startswith(("compare", "      "))]
    assert table[0].split()[:3] == ["compare", "method", "total"]
    assert [ln.split()[0] for ln in table[1:3]] == ["magnus4", "end"]
    data = json.loads(js.read_text())
    assert [c["method"] for c in data["compare"]] == ["magnus4", "end"]
    assert data["compare"][0]["evaluation"]["total_deg"]["rms"] == data["rms_error_deg"]
    assert fig.stat().st_size > 10_000
    assert main([str(top), "--rerun", "off", "--compare", "bogus"]) == 2

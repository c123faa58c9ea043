"""Tests of ``--export-csv`` (imu_dcm.replay.export_csv): the table reads back equal to the
replay's arrays and to the summary's figures, its header names each column with its unit, and
an unsafe path is refused before the log is read.

Oracle: Python's csv module and numpy on the text as written (an independent reader).
"""

from __future__ import annotations

import csv
import json
import warnings

import numpy as np
import pytest

from imu_dcm.errors import ImuDcmWarning
from imu_dcm.replay import replay
from imu_dcm.replay.__main__ import main
from imu_dcm.replay.export_csv import CSV_COLUMNS

# named: the jump's one 140 rad/s step would fail the automatic pick's rate check
TRUTH = "/ground_truth/orientation"


@pytest.fixture(scope="module")
def jump_log(tmp_path_factory):
    """A constant-axis turn with a bias and a truth that jumps 40° once (two segments), so the
    table holds unscored rows (before the truth, across the jump) and re-anchored ones."""
    from scipy.spatial.transform import Rotation

    from imu_dcm.logio.writers import StampedSeries, write_bag

    t = np.arange(0, 12.0, 0.005)
    axis = np.array([1.0, 2.0, 2.0]) / 3.0
    rate = 0.3 * np.sin(0.5 * t)
    angle = 0.6 * (1 - np.cos(0.5 * t))  # ∫ rate dt
    q = Rotation.from_rotvec(angle[:, None] * axis)
    jump = t >= 6.0
    q = Rotation.concatenate([q[~jump], Rotation.from_rotvec([0.7, 0, 0]) * q[jump]])
    omega = rate[:, None] * axis + [0.001, -0.002, 0.0015]
    t_ns = 1_700_000_000_000_000_000 + np.round(t * 1e9).astype(np.int64)
    keep = t >= 1.0  # truth from 1 s on
    out = tmp_path_factory.mktemp("csv") / "jump"
    write_bag(
        out,
        imu=StampedSeries(t_ns, omega, "imu"),
        quaternions={
            "/ground_truth/orientation": StampedSeries(t_ns[keep], q.as_quat()[keep], "world")
        },
    )
    return out


def _read(path):
    with open(path, newline="") as f:
        first = f.readline()
        rows = list(csv.reader(f))
    assert first.startswith("# imu_dcm ")  # signed: a later run may replace its own export
    header, body = rows[0], rows[1:]
    cols = {
        name: np.array([float(r[i]) if r[i] else np.nan for r in body])
        for i, name in enumerate(header)
    }
    cols["t_ns"] = np.array([int(r[0]) for r in body], dtype=np.int64)
    return header, cols


def test_csv_reads_back_equal_to_the_summary(jump_log, tmp_path):
    out, js = tmp_path / "run.csv", tmp_path / "s.json"
    code = main([str(jump_log), "--rerun", "off", "--quiet", "--export-csv", str(out),
                 "--summary-json", str(js), "--bias", "none", "--truth-topic", TRUTH])  # fmt: skip
    assert code == 0
    header, c = _read(out)
    assert tuple(header) == CSV_COLUMNS
    assert all(h.endswith(("_ns", "_s", "_deg")) or h.startswith("q_") for h in header)
    s = json.loads(js.read_text())
    with warnings.catch_warnings():  # the truth check and the jump, said by the run above
        warnings.simplefilter("ignore", ImuDcmWarning)
        r = replay(jump_log, bias="none", truth_topic=TRUTH)
    k = slice(r.start_index, None)
    # every estimate sample, the estimate as written (shortest round-trip text: exact)
    np.testing.assert_array_equal(c["t_ns"], r.t_ns[k])
    np.testing.assert_array_equal(np.c_[tuple(c[f"q_w_b_{a}"] for a in "xyzw")], r.q_est[k])
    tot = c["error_total_deg"]
    scored = np.isfinite(tot)
    assert scored.sum() == s["truth_samples_used"]
    assert np.isnan(c["q_true_w"][~scored]).all() and np.isfinite(c["q_true_w"][scored]).all()
    ev = s["evaluation"]
    # the figures from the file's numbers (a different summation order: a few ulps)
    assert np.sqrt(np.mean(tot[scored] ** 2)) == pytest.approx(s["rms_error_deg"], rel=1e-12)
    assert np.max(tot[scored]) == s["max_error_deg"]
    assert np.percentile(tot[scored], 95) == pytest.approx(ev["total_deg"]["p95"], rel=1e-12)
    head = c["error_heading_deg"][scored]
    assert np.median(head) == pytest.approx(ev["heading_deg"]["median"], rel=1e-12)
    bx = c["error_body_x_deg"][scored]
    assert np.sqrt(np.mean(bx**2)) == pytest.approx(ev["body_axes_deg"]["x"]["rms"], rel=1e-9)
    # re-anchored after the jump: the error restarts at 0 there
    seg = s["scored_segments"]
    assert len(seg) == 2
    first_after = np.flatnonzero(scored & (c["t_s"] >= seg[1]["start_s"]))[0]
    assert tot[first_after] < 1e-6


def test_csv_path_inside_the_input_is_refused_before_reading(jump_log, capsys):
    code = main([str(jump_log), "--rerun", "off", "--export-csv", str(jump_log / "x.csv")])
    assert code == 2 and "--export-csv" in capsys.readouterr().err
    assert not (jump_log / "x.csv").exists()

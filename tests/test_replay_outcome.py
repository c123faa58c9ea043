"""Every replay ends with a result: the final attitude, the rotation from the start and the angle
turned, with or without truth, checked against the closed form of a constant spin."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from imu_dcm.logio.writers import StampedSeries, write_bag
from imu_dcm.replay.__main__ import main

RATE_DEG_S, SECONDS, HZ = 10.0, 100.0, 100


@pytest.fixture
def spin(tmp_path):
    """A constant 10 °/s about body z for 100 s at 100 Hz, with truth and without."""
    n = int(SECONDS * HZ) + 1
    t_ns = 1_000_000_000 + np.arange(n, dtype=np.int64) * (1_000_000_000 // HZ)
    w = np.tile([0.0, 0.0, np.radians(RATE_DEG_S)], (n, 1))
    t_s = (t_ns - t_ns[0]) * 1e-9
    q = Rotation.from_rotvec(np.outer(t_s, w[0])).as_quat()  # [x, y, z, w], q_w_b from identity
    imu = StampedSeries(t_ns, w, "imu")
    with_truth = write_bag(
        tmp_path / "truth",
        imu=imu,
        quaternions={"/ground_truth/orientation": StampedSeries(t_ns, q, "world")},
    )
    without = write_bag(tmp_path / "none", imu=imu)
    return with_truth, without


def _run(log, tmp_path, capsys, name):
    out = tmp_path / f"{name}.json"
    assert main([str(log), "--rerun", "off", "--bias", "none", "--summary-json", str(out)]) == 0
    return json.loads(out.read_text()), capsys.readouterr().out


def test_a_log_without_truth_ends_with_its_attitude(spin, tmp_path, capsys):
    got, text = _run(spin[1], tmp_path, capsys, "none")
    assert got["truth_topic"] is None and got["rms_error_deg"] is None
    turned = RATE_DEG_S * SECONDS  # 1000°
    expect = Rotation.from_euler("z", turned, degrees=True)
    # magnus4 is exact for a constant rate: only rounding over 10 000 steps remains
    assert np.degrees((Rotation.from_quat(got["final_q_w_b"]) * expect.inv()).magnitude()) < 1e-8
    assert got["rotation_deg"] == pytest.approx(80.0, abs=1e-8)  # 1000° = 2 x 360° + 280°
    assert got["turned_deg"] == pytest.approx(turned, rel=1e-12)  # trapezoid exact for a constant
    assert got["written"] == [str(tmp_path / "none.json")]
    assert "result     final q_w_b (" in text and "80.00° from the start attitude" in text
    assert f"written    {tmp_path / 'none.json'}" in text


def test_the_summary_has_the_same_fields_with_or_without_truth(spin, tmp_path, capsys):
    scored, _ = _run(spin[0], tmp_path, capsys, "truth")
    unscored, _ = _run(spin[1], tmp_path, capsys, "none")
    assert scored.keys() == unscored.keys()
    assert scored["rms_error_deg"] < 1e-6
    assert scored["rotation_deg"] == pytest.approx(unscored["rotation_deg"], abs=1e-8)


def test_nothing_written_is_said(spin, capsys):
    assert main([str(spin[1]), "--rerun", "off"]) == 0
    assert "written    nothing (--out DIR" in capsys.readouterr().out

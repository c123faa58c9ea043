"""EuRoC / ASL dataset folders: a dataset built from the shipped trial (gyro, accelerometer and
truth written as ASL CSVs) reads as the same arrays and replays to the same error as the trial's
MCAP; the motion-capture variants recover the IMU's attitude through ``T_BS`` (scipy
``Rotation`` as the oracle); a bad CSV is one line naming the file and the line."""

from __future__ import annotations

import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
from conftest import raises_naming
from scipy.spatial.transform import Rotation

from imu_dcm.errors import LogError
from imu_dcm.logio import find_logs, read_log
from imu_dcm.replay import replay

REPO = Path(__file__).resolve().parents[1]
SHIPPED = REPO / "replay" / "broad_07_undisturbed_fast_rotation_B"
IMU_HEADER = (
    "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
    "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]"
)
POSE_HEADER = (
    "#timestamp [ns], p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], "
    "q_RS_y [], q_RS_z []"
)
# The ground-truth estimate's 17 columns (position, quaternion, velocity, gyro and accel bias).
GT_HEADER = (
    POSE_HEADER
    + ", v_RS_R_x [m s^-1], v_RS_R_y, v_RS_R_z, b_w_RS_S_x, b_w_RS_S_y, "
    + ("b_w_RS_S_z, b_a_RS_S_x, b_a_RS_S_y, b_a_RS_S_z")
)
#: A marker body turned 90° about z (the boundary case a wrong quaternion order breaks), then
#: 30° about x, with a lever arm: T_BS of the motion-capture sensor.
R_BS = Rotation.from_euler("zx", [90, 30], degrees=True)


def _sensor_yaml(folder: Path, rot: Rotation, opencv_header: bool = False) -> None:
    m = np.eye(4)
    m[:3, :3] = rot.as_matrix()
    m[:3, 3] = [0.05, -0.02, 0.11]
    rows = ",\n         ".join(", ".join(repr(float(x)) for x in row) for row in m)
    head = "%YAML:1.0\n" if opencv_header else ""
    folder.joinpath("sensor.yaml").write_text(
        f"{head}sensor_type: visual-inertial\nT_BS:\n  cols: 4\n  rows: 4\n  data: [{rows}]\n"
    )


def _csv(path: Path, header: str, t_ns: np.ndarray, values: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    lines = [header]
    lines += [
        f"{int(t)}," + ",".join(repr(float(x)) for x in row)
        for t, row in zip(t_ns, values, strict=True)
    ]
    path.write_text("\n".join(lines) + "\n")


@pytest.fixture(scope="module")
def trial():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        log = read_log(SHIPPED)
    accel = log.imu.accel_b  # the trial's own accelerometer: the replay judges rest from it
    if accel is None:
        rng = np.random.default_rng(7)
        accel = rng.normal(scale=0.3, size=log.imu.omega_b.shape) + [0.0, 0.0, 9.81]
    return log, accel


def _dataset(root: Path, trial, truth: str = "state_groundtruth_estimate0", **kw) -> Path:
    """An ASL dataset of the trial: imu0 and one truth folder (``mav0`` inside ``root``)."""
    log, accel = trial
    mav = root / "mav0"
    _csv(mav / "imu0" / "data.csv", IMU_HEADER, log.imu.t_ns, np.hstack([log.imu.omega_b, accel]))
    _sensor_yaml(mav / "imu0", kw.get("r_b_imu", Rotation.identity()))
    q_w_b = log.truth.q_w_b
    pos = np.zeros((len(q_w_b), 3))
    if truth == "state_groundtruth_estimate0":
        q_rs = q_w_b
        extra = np.full((len(q_w_b), 9), 0.25)
        values = np.hstack([pos, q_rs[:, [3, 0, 1, 2]], extra])
        header = GT_HEADER
    else:  # the marker body's attitude: R_RS = R_w_imu R_B,imu^-1 R_BS
        r_b_imu = kw.get("r_b_imu", Rotation.identity())
        q_rs = (Rotation.from_quat(q_w_b) * r_b_imu.inv() * R_BS).as_quat(canonical=False)
        values = np.hstack([pos, q_rs[:, [3, 0, 1, 2]]])
        header = POSE_HEADER
    _csv(mav / truth / "data.csv", header, log.truth.t_ns, values)
    if truth != "state_groundtruth_estimate0":
        _sensor_yaml(mav / truth, R_BS, opencv_header=True)
    return root


def _rms_deg(path, bias: str = "none") -> float:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return replay(path, bias=bias).summary.rms_error_deg


def test_ground_truth_dataset_reads_and_replays_as_the_mcap(tmp_path, trial):
    log, accel = trial
    root = _dataset(tmp_path / "MH_test", trial)
    for given in (root, root / "mav0"):
        got = read_log(given)
        np.testing.assert_array_equal(got.imu.t_ns, log.imu.t_ns)
        np.testing.assert_array_equal(got.imu.log_t_ns, log.imu.t_ns)
        np.testing.assert_array_equal(got.imu.omega_b, log.imu.omega_b)
        np.testing.assert_array_equal(got.imu.accel_b, accel)
        np.testing.assert_array_equal(got.truth.t_ns, log.truth.t_ns)
        np.testing.assert_array_equal(got.truth.q_w_b, log.truth.q_w_b)  # wxyz -> xyzw exact
        assert got.container == "euroc/asl folder" and got.truth.auto
        assert got.truth.topic == "state_groundtruth_estimate0"
    for bias in ("none", "auto"):  # "auto": rest judged from the same gyro and accelerometer
        want = _rms_deg(SHIPPED, bias)
        assert want > 0.01  # a real error to compare, not zero
        assert abs(_rms_deg(root, bias) - want) < 1e-6, bias


@pytest.mark.parametrize(
    "truth, r_b_imu",
    [
        ("mocap0", Rotation.identity()),
        ("vicon0", Rotation.identity()),
        ("vicon0", Rotation.from_euler("y", 180, degrees=True)),
    ],
)
def test_motion_capture_through_t_bs_recovers_the_imu_attitude(tmp_path, trial, truth, r_b_imu):
    log, _ = trial
    root = _dataset(tmp_path / "ds", trial, truth=truth, r_b_imu=r_b_imu)
    got = read_log(root)
    assert got.truth.topic == truth
    # The same attitude up to the sign of the quaternion and rounding (a few products of unit
    # quaternions: ~1e-15 rad); 1e-12 rad would be far beyond any rounding.
    angle = Rotation.from_quat(got.truth.q_w_b).inv() * Rotation.from_quat(log.truth.q_w_b)
    assert angle.magnitude().max() < 1e-12
    assert any("T_BS of " + truth in n for n in got.notes)
    assert abs(_rms_deg(root) - _rms_deg(SHIPPED)) < 1e-6


def test_truth_order_candidates_and_leica(tmp_path, trial):
    log, _ = trial
    root = _dataset(tmp_path / "ds", trial)
    _dataset(tmp_path / "ds", trial, truth="vicon0")
    mav = root / "mav0"
    _csv(
        mav / "leica0" / "data.csv",
        "#timestamp [ns], p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m]",
        log.truth.t_ns[:5],
        np.zeros((5, 3)),
    )
    got = read_log(root)
    assert got.truth.topic == "state_groundtruth_estimate0"
    assert [c.topic for c in got.truth_candidates] == ["vicon0"]
    assert any(n.startswith("leica0: ") and "no attitude" in n for n in got.notes)
    assert read_log(root, truth_topic="vicon0").truth.topic == "vicon0"
    assert read_log(root, truth_topic="none").truth is None
    with pytest.raises(LogError, match="positions only"):
        read_log(root, truth_topic="leica0")
    (mav / "state_groundtruth_estimate0" / "data.csv").unlink()  # a truth folder, no data
    with pytest.raises(LogError, match="state_groundtruth_estimate0/data.csv, got none"):
        read_log(root)
    shutil.rmtree(mav / "state_groundtruth_estimate0")
    shutil.rmtree(mav / "vicon0")
    only_leica = read_log(root)
    assert only_leica.truth is None and any("leica0" in n for n in only_leica.notes)


def _bad(tmp_path, body: str) -> str:
    mav = tmp_path / "bad" / "mav0"
    (mav / "imu0").mkdir(parents=True)
    (mav / "imu0" / "data.csv").write_text(IMU_HEADER + "\n" + body)
    with pytest.raises(LogError) as info:
        read_log(tmp_path / "bad")
    msg = str(info.value)
    assert "\n" not in msg and "imu0/data.csv" in msg
    return msg


GOOD = "1000,0.1,0.2,0.3,0.0,0.0,9.8\n"


def test_bad_csv_is_one_line_naming_file_and_line(tmp_path):
    assert "at line 4" in _bad(
        tmp_path / "a", GOOD + "2000,0.1,0.2,0.3,0,0,9.8\n1500,0,0,0,0,0,0\n"
    )
    assert "at line 3" in _bad(tmp_path / "b", GOOD + "2000,0.1,0.2\n")  # truncated line
    assert "at line 2" in _bad(tmp_path / "c", "1000,0.1,0.2,0.3\n")  # wrong columns
    assert "at line 3" in _bad(tmp_path / "d", GOOD + "2000,0.1,zero,0.3,0,0,9.8\n")
    assert "got none" in _bad(tmp_path / "e", "")


def test_spaces_around_fields_are_numbers_still(tmp_path):
    mav = tmp_path / "ds" / "mav0"
    (mav / "imu0").mkdir(parents=True)
    (mav / "imu0" / "data.csv").write_text(
        IMU_HEADER + "\n1000, 0.5, 0.25, 1, 0, 0, 9.8\n2000, 0.5, 0.25, 1, 0, 0, 9.8\n"
    )
    got = read_log(tmp_path / "ds")
    np.testing.assert_array_equal(got.imu.omega_b, [[0.5, 0.25, 1.0]] * 2)
    assert got.truth is None


def test_find_logs_takes_a_dataset_as_one_log(tmp_path, trial):
    root = _dataset(tmp_path / "data" / "MH_01", trial)
    (tmp_path / "data" / "notes").mkdir()
    found = find_logs(tmp_path / "data")
    assert found == [root]


# ----------------------------------------------------------------- bad folders, one line
def _small(root: Path) -> Path:
    """imu0 (50 samples) and a vicon0 truth (the identity), no sensor.yaml."""
    t = 1_000_000_000 + 5_000_000 * np.arange(50)
    _csv(root / "mav0" / "imu0" / "data.csv", IMU_HEADER, t, np.tile([0.0] * 5 + [9.81], (50, 1)))
    _csv(
        root / "mav0" / "vicon0" / "data.csv",
        POSE_HEADER,
        t,
        np.tile([0.0] * 3 + [1, 0, 0, 0], (50, 1)),
    )
    return root


def test_an_imu_line_with_extra_cells_is_refused(tmp_path):
    for extra in (1, 100_000):
        root = _small(tmp_path / f"x{extra}")
        csv = root / "mav0" / "imu0" / "data.csv"
        lines = csv.read_text().splitlines()
        lines[20] += ",0" * extra
        csv.write_text("\n".join(lines) + "\n")
        with pytest.raises(
            LogError, match=rf"got {7 + extra} columns at line 21 \(the first .*7\)"
        ):
            read_log(root)


@pytest.mark.parametrize("what", ["fifo", "folder", "missing"])
def test_a_truth_data_csv_that_is_not_a_file_is_one_line(tmp_path, what):
    import os

    root = _small(tmp_path / what)
    csv = root / "mav0" / "vicon0" / "data.csv"
    csv.unlink()
    if what == "fifo":
        os.mkfifo(csv)  # a reader that opened it would wait for a writer (no test timeout here)
    elif what == "folder":
        csv.mkdir()
    want = {"fifo": "a FIFO", "folder": "a folder", "missing": "none"}[what]
    with pytest.raises(LogError, match=f"vicon0/data.csv.*{want}.*--truth-topic none"):
        read_log(root)
    assert read_log(root, truth_topic="none").truth is None


def test_a_missing_imu_data_csv_is_named(tmp_path):
    root = _small(tmp_path / "d")
    (root / "mav0" / "imu0" / "data.csv").unlink()
    for given in (root, root / "mav0"):
        missing = str(root / "mav0" / "imu0" / "data.csv")
        with raises_naming(LogError, "imu0/data.csv", "no such file", missing):
            read_log(given)

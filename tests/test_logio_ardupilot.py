"""ArduPilot DataFlash reader: Euler angles and frames against scipy, a log of known content
written with pymavlink's own record builders from the shipped trial, instances, damage.

No public ArduPilot log ships with pymavlink or beside the repository, so every log here is
written by :func:`tests.drone_logs.write_dataflash`.
"""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
from conftest import assert_names, assert_quiet, raises_naming
from scipy.spatial.transform import Rotation

from imu_dcm.errors import ImuDcmWarning, LogError
from imu_dcm.logio import ned, read_log
from imu_dcm.logio.containers import ardupilot
from imu_dcm.so3 import angle_between_deg
from tests.drone_logs import (
    TRIAL,
    DFMessage,
    trial_arrays,
    trial_dataflash,
    write_dataflash,
)

pytest.importorskip("pymavlink")


# ------------------------------------------------------------------------------ frames
def test_euler_matches_scipy_zyx():
    rng = np.random.default_rng(4)
    rpy = np.column_stack(
        [rng.uniform(-180, 180, 300), rng.uniform(-89, 89, 300), rng.uniform(0, 360, 300)]
    )
    q = ned.q_wxyz_from_euler_deg(rpy[:, 0], rpy[:, 1], rpy[:, 2])
    want = Rotation.from_euler("ZYX", rpy[:, ::-1], degrees=True)
    got = Rotation.from_quat(np.column_stack([q[:, 1:], q[:, :1]]))
    assert np.max((got.inv() * want).magnitude()) < 1e-12


def test_yaw_0_is_90_deg_about_z_in_enu_and_yaw_90_the_identity():
    s = np.sqrt(0.5)
    north = ned.q_enu_flu(ned.q_wxyz_from_euler_deg(0.0, 0.0, 0.0))
    east = ned.q_enu_flu(ned.q_wxyz_from_euler_deg(0.0, 0.0, 90.0))
    assert angle_between_deg(north, [0, 0, s, s]) < 1e-12
    assert angle_between_deg(east, [0, 0, 0, 1.0]) < 1e-12


def test_nose_up_pitch_is_nose_up_in_enu():
    q = ned.q_enu_flu(ned.q_wxyz_from_euler_deg(0.0, 30.0, 90.0))  # facing east, nose up 30
    nose = Rotation.from_quat(q).apply([1.0, 0, 0])
    assert np.allclose(nose, [np.cos(np.radians(30)), 0, np.sin(np.radians(30))], atol=1e-12)


# ------------------------------------------------------------------------------ proof
@pytest.fixture(scope="module")
def trial_bin(tmp_path_factory):
    return trial_dataflash(tmp_path_factory.mktemp("df") / "trial.bin")


def test_pymavlink_reads_the_written_log(trial_bin):
    from pymavlink import DFReader

    df = DFReader.DFReader_binary(str(trial_bin))
    m = df.recv_match(type="IMU")
    a = trial_arrays()
    assert m.TimeUS * 1000 == a.t_ns[0] and m.GyrY == -a.omega_b[0, 1]
    df.close()


def test_trial_dataflash_gives_the_trials_arrays(trial_bin):
    """Doubles: the rates pass through sign flips only (exact); the truth goes through Euler
    angles (scipy writes them, the reader composes them back), a few ulp per angle, and the
    composed rotation differs by at most the sum of the three angle errors: ~1e-13 deg."""
    a = trial_arrays()
    d = read_log(trial_bin)
    assert d.container == "ardupilot dataflash"
    assert np.array_equal(d.imu.t_ns, a.t_ns)
    assert np.array_equal(d.imu.omega_b, a.omega_b)
    assert np.array_equal(d.imu.accel_b, a.accel_b)
    assert np.array_equal(d.truth.t_ns, a.truth_t_ns)
    assert np.max(angle_between_deg(d.truth.q_w_b, a.q_w_b)) < 1e-9
    assert d.truth.topic == "ATT" and d.truth.estimate_of == "ArduPilot's own estimate"
    assert any("ArduPilot's own estimate" in n for n in d.notes)


@pytest.mark.slow
def test_trial_dataflash_replays_to_the_trials_rms(trial_bin):
    """|RMS(a) - RMS(b)| <= max |a - b| (the triangle inequality of the l2 norm), and the
    estimate starts from the truth, which moves it by no more: with truth within 1e-9 deg the
    RMS agrees within 2e-9 deg, far inside 1e-6 deg."""
    from imu_dcm.replay import replay

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ImuDcmWarning)
        want = replay(TRIAL).summary
        got = replay(trial_bin).summary
    assert got.rms_error_deg == pytest.approx(want.rms_error_deg, abs=1e-6)
    assert got.max_error_deg == pytest.approx(want.max_error_deg, abs=1e-6)


def test_float_log_is_within_float32_rounding(tmp_path):
    """ArduPilot logs floats: rates within half an ulp (2^-24 relative); each Euler angle
    within 2^-24 of its size, so the attitude within 2^-24 (|roll| + |pitch| + |yaw|) <=
    2^-24 * 630 deg = 3.8e-5 deg."""
    a = trial_arrays()
    d = read_log(trial_dataflash(tmp_path / "f.bin", real="f"))
    assert np.all(np.abs(d.imu.omega_b - a.omega_b) <= np.abs(a.omega_b) * 2.0**-24)
    assert np.max(angle_between_deg(d.truth.q_w_b, a.q_w_b)) <= 2.0**-24 * 630


# ------------------------------------------------------------------------ instances
def _imu(rows_per: dict[int, float], n=50, accel=True) -> DFMessage:
    rows = []
    for i in range(n):
        for inst, g in rows_per.items():
            r = (1000 + 2500 * i, inst, g, 2 * g, 3 * g)
            rows.append(r + ((0.0, 0.0, -9.81) if accel else ()))
    cols = ["TimeUS", "I", "GyrX", "GyrY", "GyrZ"] + (["AccX", "AccY", "AccZ"] if accel else [])
    return DFMessage("IMU", "QB" + "f" * (len(cols) - 2), cols, rows)


def _att(n=20, name="ATT") -> DFMessage:
    rows = [(1000 + 5000 * i, 1.0, 2.0, 350.0) for i in range(n)]
    return DFMessage(name, "Qfff", ["TimeUS", "Roll", "Pitch", "Yaw"], rows)


def test_first_instance_by_default_and_imu_1_on_request(tmp_path):
    p = write_dataflash(tmp_path / "two.bin", [_imu({0: 0.1, 1: 0.5}), _att()])
    d = read_log(p)
    assert d.imu.topic == "IMU[0]"
    assert np.allclose(d.imu.omega_b, np.float32([0.1, -0.2, -0.3]))
    assert np.allclose(d.imu.accel_b, [0, 0, 9.81])  # FRD -9.81 (up) -> FLU +9.81
    assert "IMU[1]: 50 samples at 400 Hz" in d.notes[0] and d.notes[0].endswith("used IMU[0]")
    one = read_log(p, imu_topic="IMU[1]")
    assert np.allclose(one.imu.omega_b, np.float32([0.5, -1.0, -1.5]))
    with raises_naming(LogError, "'IMU[2]'", "IMU[0]", "IMU[1]"):
        read_log(p, imu_topic="IMU[2]")


def test_older_logs_imu2_message(tmp_path):
    imu = _imu({0: 0.1}, accel=False)
    old = DFMessage(
        "IMU", "Qfff", ["TimeUS", "GyrX", "GyrY", "GyrZ"], [r[:1] + r[2:] for r in imu.rows]
    )
    imu2 = DFMessage(
        "IMU2",
        "Qfff",
        ["TimeUS", "GyrX", "GyrY", "GyrZ"],
        [(r[0], 1.0, 1.0, 1.0) for r in imu.rows],
    )
    p = write_dataflash(tmp_path / "old.bin", [old, imu2, _att()])
    assert read_log(p).imu.topic == "IMU[0]" and read_log(p).imu.accel_b is None
    assert np.allclose(read_log(p, imu_topic="IMU2").imu.omega_b, [1.0, -1.0, -1.0])


def test_sim_is_preferred_and_att_kept_as_candidate(tmp_path):
    p = write_dataflash(tmp_path / "sitl.bin", [_imu({0: 0.1}), _att(), _att(name="SIM")])
    d = read_log(p)
    assert d.truth.topic == "SIM" and d.truth.estimate_of == ""
    assert [c.topic for c in d.truth_candidates] == ["ATT"]
    assert read_log(p, truth_topic="ATT").truth.estimate_of == "ArduPilot's own estimate"
    assert read_log(p, truth_topic="none").truth is None
    with raises_naming(LogError, "'XKF1'", "SIM", "ATT"):
        read_log(p, truth_topic="XKF1")


def test_truncated_log_is_read_with_a_warning(tmp_path):
    full = write_dataflash(tmp_path / "full.bin", [_imu({0: 0.1}), _att()])
    cut = tmp_path / "cut.bin"
    cut.write_bytes(full.read_bytes()[:-5])  # the last record (an IMU one) loses 5 bytes
    with pytest.warns(ImuDcmWarning, match="cut short"):
        d = read_log(cut)
    assert len(d.imu.t_ns) == 49


def test_missing_pymavlink_is_one_line(monkeypatch, tmp_path):
    import builtins

    real_import = builtins.__import__

    def no_pymavlink(name, *args, **kwargs):
        if name.startswith("pymavlink"):
            raise ImportError(name)
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_pymavlink)
    p = tmp_path / "x.bin"
    p.write_bytes(ardupilot.MAGIC + bytes(100))
    with pytest.raises(LogError, match=r"pip install 'imu_dcm\[mavlink\]'"):
        read_log(p)


def test_probe():
    assert ardupilot.probe(None, b"\xa3\x95\x80\x80\x59BBnNZ")
    assert not ardupilot.probe(None, b"ULog\x01\x12\x35\x01")
    assert not ardupilot.probe(None, b"")


# --------------------------------------------------------------------------- damage
def _imu_offsets(raw: bytes, n_types: int, imu_len: int, other_len: int) -> list[int]:
    """Byte offsets of the IMU records of a log of write_dataflash (FMTs first, then records
    of type 0x81 = IMU and 0x82 by time), found by walking the known lengths."""
    ofs, out = 89 * (1 + n_types), []
    while ofs < len(raw):
        t = raw[ofs + 2]
        if t == 0x81:
            out.append(ofs)
        ofs += imu_len if t == 0x81 else other_len
    return out


@pytest.fixture(scope="module")
def small_log(tmp_path_factory):
    """2000 IMU records of 36 bytes (QB and six f), 400 ATT records of 23 bytes (Qfff)."""
    rows = [(1000 + 2500 * i, 0, 0.01 * i, 0.5, -0.25, 0.0, 0.0, -9.81) for i in range(2000)]
    imu = DFMessage(
        "IMU", "QBffffff", ["TimeUS", "I", "GyrX", "GyrY", "GyrZ", "AccX", "AccY", "AccZ"], rows
    )
    p = write_dataflash(tmp_path_factory.mktemp("dmg") / "log.bin", [imu, _att(400)])
    raw = p.read_bytes()
    return raw, _imu_offsets(raw, 2, 3 + 8 + 1 + 24, 3 + 8 + 12)


def _read_damaged(tmp_path, raw: bytes):
    p = tmp_path / "d.bin"
    p.write_bytes(raw)
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        d = read_log(p)
    return d, [str(w.message) for w in said]


def _patched(raw: bytes, at: int, byte: int) -> bytes:
    out = bytearray(raw)
    out[at] = byte
    return bytes(out)


def _quiet(capfd) -> None:
    """Nothing on stdout, and nothing on stderr but another module's Python warning."""
    out, err = capfd.readouterr()
    assert out == ""
    assert_quiet(err)


def test_an_unknown_record_costs_only_itself(tmp_path, small_log, capfd):
    """Record 1000's type byte set to 0x7f (no FMT declares it): the other 1999 samples are
    read, and one line says where (pymavlink stopped there, silently: 1000 samples)."""
    raw, imu_at = small_log
    d, said = _read_damaged(tmp_path, _patched(raw, imu_at[1000] + 2, 0x7F))
    want = np.delete(np.arange(2000), 1000) * 0.01
    assert np.array_equal(d.imu.omega_b[:, 0], np.float32(want))
    assert len(said) == 1 and "unknown type 0x7f" in said[0]
    assert f"file offset {imu_at[1000]}" in said[0] and "one IMU record" in said[0]
    _quiet(capfd)  # no other program's line


def test_a_record_retagged_as_fmt_costs_only_itself(tmp_path, small_log, capfd):
    raw, imu_at = small_log
    d, said = _read_damaged(tmp_path, _patched(raw, imu_at[700] + 2, 0x80))
    assert len(d.imu.t_ns) == 1999 and 1000 + 2500 * 700 not in d.imu.t_ns // 1000
    assert len(said) == 1 and f"file offset {imu_at[700]}" in said[0]
    _quiet(capfd)


def test_a_flipped_sync_byte_costs_only_its_record(tmp_path, small_log, capfd):
    raw, imu_at = small_log
    d, said = _read_damaged(tmp_path, _patched(raw, imu_at[300], 0x00))
    assert len(d.imu.t_ns) == 1999 and 1000 + 2500 * 300 not in d.imu.t_ns // 1000
    assert len(said) == 1 and "no record header" in said[0]
    _quiet(capfd)


def test_random_flipped_bytes_cost_at_most_two_records(tmp_path, small_log, capfd):
    """Any byte of the records (after the FMTs) flipped: a header byte breaks the chain at
    its record (and at worst the record before, whose end can no longer be confirmed), a
    payload byte changes one record's values. So at least 1997 of the 2000 rows are read
    unchanged. pymavlink's indexer lost 79 % for one such flip."""
    raw, _ = small_log
    want = {(1000 + 2500 * i, np.float32(0.01 * i)) for i in range(2000)}
    rng = np.random.default_rng(27)
    for at in rng.integers(89 * 3, len(raw), 40).tolist():
        d, said = _read_damaged(tmp_path, _patched(raw, at, raw[at] ^ int(rng.integers(1, 256))))
        got = set(zip((d.imu.t_ns // 1000).tolist(), np.float32(d.imu.omega_b[:, 0]), strict=True))
        assert len(got & want) >= 1997, at
        assert len(said) <= 1
    _quiet(capfd)


def test_an_imu_fmt_length_off_by_one_is_read_by_its_format(tmp_path, small_log, capfd):
    """The IMU FMT (the second one, at 89) declares 37 bytes where its characters give 36:
    pymavlink printed a line for every record; the records chain at 36, and one line says so."""
    raw, _ = small_log
    d, said = _read_damaged(tmp_path, _patched(raw, 89 + 4, 37))
    assert len(d.imu.t_ns) == 2000 and d.truth is not None
    assert len(said) == 1 and "declaring 37 bytes" in said[0] and "read as 36" in said[0]
    _quiet(capfd)


def test_padding_at_the_end_is_not_damage(tmp_path, small_log):
    raw, _ = small_log
    for pad in (b"\0" * 249, b"\xff" * 100):
        d, said = _read_damaged(tmp_path, raw + pad)
        assert len(d.imu.t_ns) == 2000 and said == []


def test_a_gyro_column_typed_as_a_string_is_one_line(tmp_path):
    rows = [(1000 + 2500 * i, 0, b"x", 0.5, -0.25) for i in range(50)]
    imu = DFMessage("IMU", "QBZff", ["TimeUS", "I", "GyrX", "GyrY", "GyrZ"], rows)
    p = write_dataflash(tmp_path / "s.bin", [imu, _att()])
    with raises_naming(LogError, "IMU[0].GyrX", "string"):
        read_log(p)


def test_a_truth_column_typed_as_a_string_skips_that_truth(tmp_path):
    att = DFMessage("ATT", "QZff", ["TimeUS", "Roll", "Pitch", "Yaw"], [(1000, b"x", 0.0, 0.0)] * 5)
    d = read_log(write_dataflash(tmp_path / "t.bin", [_imu({0: 0.1}), att]))
    assert d.truth is None and any("ATT skipped as truth" in n for n in d.notes)


# --------------------------------------------------------------- logs of 2013-2015
def test_timems_logs_of_2013_to_2015(tmp_path):
    """ArduCopter 3.1/3.2 logs: IMU ``Iffffff`` (TimeMS, gyro, accel), ATT ``IccccCC`` with
    centidegrees. Stamps are ms -> ns exactly; angles are the centidegree integers / 100; the
    truth against scipy's ZYX Euler of those angles (FRD/NED -> FLU/ENU by hand)."""
    n = 60
    imu = DFMessage(
        "IMU",
        "Iffffff",
        ["TimeMS", "GyrX", "GyrY", "GyrZ", "AccX", "AccY", "AccZ"],
        [(100 + 20 * i, 0.25, 0.5, -1.0, 0.0, 0.0, -9.81) for i in range(n)],
    )
    att_rows = [(100 + 100 * i, 0, 1234 + i, 0, -567, 0, 35990 - i) for i in range(n // 5)]
    att = DFMessage(
        "ATT",
        "IccccCC",
        ["TimeMS", "DesRoll", "Roll", "DesPitch", "Pitch", "DesYaw", "Yaw"],
        att_rows,
    )
    d = read_log(write_dataflash(tmp_path / "old.bin", [imu, att], order_by="TimeMS"))
    assert np.array_equal(d.imu.t_ns, (100 + 20 * np.arange(n)) * 1_000_000)
    assert np.array_equal(d.imu.omega_b, np.tile([0.25, -0.5, 1.0], (n, 1)))
    assert np.allclose(d.imu.accel_b, [0, 0, 9.81], rtol=0, atol=1e-6)
    assert np.array_equal(d.truth.t_ns, (100 + 100 * np.arange(n // 5)) * 1_000_000)
    rpy = np.array([(r[2] / 100, r[4] / 100, r[6] / 100) for r in att_rows])
    r_ned_frd = Rotation.from_euler("ZYX", rpy[:, ::-1], degrees=True)
    m_enu_ned = np.array([[0.0, 1, 0], [1, 0, 0], [0, 0, -1]])
    want = (
        Rotation.from_matrix(m_enu_ned) * r_ned_frd * Rotation.from_matrix(np.diag([1.0, -1, -1]))
    )
    got = Rotation.from_quat(d.truth.q_w_b)
    assert np.max((got.inv() * want).magnitude()) < 1e-9  # doubles after a centidegree scale


def test_a_log_with_no_time_column_is_one_line(tmp_path):
    imu = DFMessage("IMU", "ffffff", ["GyrX", "GyrY", "GyrZ", "AccX", "AccY", "AccZ"], [])
    imu.rows = [(0.1, 0.2, 0.3, 0.0, 0.0, -9.8)] * 10
    p = write_dataflash(tmp_path / "v30.bin", [imu], order_by="GyrX")
    with raises_naming(LogError, "TimeUS", "TimeMS", "IMU[0]"):
        read_log(p)


def test_every_cut_inside_a_record_is_said(tmp_path, small_log):
    """Cut at each of the last 80 offsets: a cut at a record boundary is a shorter log (no
    warning); any other cut leaves a record incomplete, whatever its type, and says so once.
    (Only a cut IMU record was said; a cut ATT header lost the IMU samples after it silently.)"""
    raw, _ = small_log
    bounds, ofs = set(), 89 * 3
    while ofs < len(raw):
        ofs += 36 if raw[ofs + 2] == 0x81 else 23
        bounds.add(ofs)
    for cut in range(len(raw) - 80, len(raw)):
        d, said = _read_damaged(tmp_path, raw[:cut])
        assert len(said) == (0 if cut in bounds else 1), cut
        assert all("cut short" in s or "bytes skipped" in s for s in said)


def test_the_command_line_on_damaged_and_old_logs(tmp_path, small_log, capsys):
    """Through the command: an unknown record is one warning and exit 0 with 1999 samples; a
    TimeMS log replays (it ended in KeyError 'TimeUS'); a string-typed gyro is one error line."""
    from imu_dcm.replay.__main__ import main

    raw, imu_at = small_log
    bad = tmp_path / "bad.bin"
    bad.write_bytes(_patched(raw, imu_at[1000] + 2, 0x7F))
    out = tmp_path / "s.json"
    assert main([str(bad), "--rerun", "off", "--quiet", "--summary-json", str(out)]) == 0
    err = [x for x in capsys.readouterr().err.splitlines() if "truncated or corrupt" in x]
    assert len(err) == 1 and "unknown type 0x7f" in err[0]
    assert json.loads(out.read_text())["samples"] == 1999

    old = DFMessage(
        "IMU",
        "Iffffff",
        ["TimeMS", "GyrX", "GyrY", "GyrZ", "AccX", "AccY", "AccZ"],
        [(100 + 5 * i, 0.0, 0.0, 0.5, 0.0, 0.0, -9.81) for i in range(400)],
    )
    p = write_dataflash(tmp_path / "old.bin", [old], order_by="TimeMS")
    assert main([str(p), "--rerun", "off", "--quiet"]) == 0
    assert "Traceback" not in capsys.readouterr().err

    rows = [(1000 + 2500 * i, 0, b"x", 0.5, -0.25) for i in range(50)]
    s = write_dataflash(
        tmp_path / "s.bin",
        [DFMessage("IMU", "QBZff", ["TimeUS", "I", "GyrX", "GyrY", "GyrZ"], rows)],
    )
    assert main([str(s), "--rerun", "off", "--quiet"]) == 2
    lines = [x for x in capsys.readouterr().err.splitlines() if x.strip()]
    assert len(lines) == 1
    assert_names(lines[0], "IMU[0].GyrX", "string")


def test_the_bias_is_said_in_the_logs_frd_axes_too(tmp_path):
    """An ArduPilot log at rest, gyro FRD = b + white noise (float32 columns): the bias is the
    mean over the rest, so within 5 sigma/sqrt(N) (and the float32 rounding of b) of b in the
    log's axes (FRD) and of (b_x, -b_y, -b_z) in FLU, as for a PX4 log."""
    from imu_dcm.replay import replay

    n, sigma = 2000, 1e-3
    b_frd = np.array([0.01, 0.02, -0.03])
    rng = np.random.default_rng(27)
    g = b_frd + rng.normal(scale=sigma, size=(n, 3))
    a = np.array([0.0, 0.0, -9.81]) + rng.normal(scale=0.01, size=(n, 3))
    rows = [(1000 + 2500 * i, 0, *g[i], *a[i]) for i in range(n)]
    cols = ["TimeUS", "I", "GyrX", "GyrY", "GyrZ", "AccX", "AccY", "AccZ"]
    p = write_dataflash(tmp_path / "rest.bin", [DFMessage("IMU", "QB" + "f" * 6, cols, rows)])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        s = replay(p, bias="auto").summary
    tol = 5 * sigma / np.sqrt(n) + 2.0**-24 * np.abs(b_frd).max()
    assert s.bias_segments and s.log_axes == "FRD"
    assert np.allclose(s.bias_log_rad_s, b_frd, atol=tol, rtol=0)
    assert np.allclose(s.bias_rad_s, b_frd * [1, -1, -1], atol=tol, rtol=0)

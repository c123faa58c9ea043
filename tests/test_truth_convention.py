"""The truth's convention is judged by how its body-rate vectors fit the gyro's: a conjugated or
reordered truth of the shipped trial is named, applied when the fit determines it clearly (then
it scores as the clean truth does) or when stated, and an all-zero gyro follows no truth."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest
from conftest import REPO_ROOT
from scipy.spatial.transform import Rotation

from imu_dcm.logio import read_log
from imu_dcm.replay import replay
from imu_dcm.replay.convention import choose_convention, convert
from imu_dcm.replay.rate_check import check_truth

TRIAL = REPO_ROOT / "replay" / "broad_07_undisturbed_fast_rotation_B"


@pytest.fixture(scope="module")
def log():
    return read_log(TRIAL)


@pytest.fixture(scope="module")
def clean(log):
    return _quiet(log)


def _quiet(log, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return replay(log, **kw)


def _with_truth(log, q):
    return dataclasses.replace(log, truth=dataclasses.replace(log.truth, q_w_b=q))


def test_convert_undoes_each_convention(log):
    q = log.truth.q_w_b[:50]
    assert np.array_equal(convert(convert(q, "conjugate"), "conjugate"), q)
    assert np.array_equal(convert(q[:, [3, 0, 1, 2]], "w-first"), q)  # written w, x, y, z
    assert np.array_equal(convert(q[:, [1, 2, 3, 0]], "w-last"), q)


@pytest.mark.parametrize(
    ("written", "name"),
    [
        (lambda q: q * [-1.0, -1.0, -1.0, 1.0], "conjugate"),  # world to body
        (lambda q: q[:, [3, 0, 1, 2]], "w-first"),  # w, x, y, z in the x, y, z, w columns
    ],
)
def test_a_truth_in_another_convention_is_found_and_applied(log, clean, written, name):
    # The norms of the conjugate's rates are the same: only the vectors tell. As given, the
    # best constant mounting leaves a quarter of the truth's rotation unexplained; the named
    # convention leaves as little as the clean truth (under 1 %): applied, the same score. The
    # other two of the conjugate family fit as well, with a mounting near 180°.
    res = _quiet(_with_truth(log, written(log.truth.q_w_b)))
    conv = res.summary.truth_convention
    assert conv["used"] == name and conv["how"] == "fit"
    fits = dict(conv["fits"])
    assert fits["as-is"] < 0.9 and 10 * (1 - fits[name]) < 1 - fits["as-is"]
    line = next(w for w in res.summary.warnings if "read as" in w)
    assert f"read as {name}" in line and "applied" in line and "fit as well" in line
    assert abs(res.summary.rms_error_deg - clean.summary.rms_error_deg) < 1e-6


def test_a_stated_convention_is_applied_and_as_is_keeps_the_truth(log, clean):
    conj = _with_truth(log, log.truth.q_w_b * [-1.0, -1.0, -1.0, 1.0])
    stated = _quiet(conj, truth_convention="conjugate")
    assert stated.summary.truth_convention["how"] == "given"
    assert abs(stated.summary.rms_error_deg - clean.summary.rms_error_deg) < 1e-6
    kept = _quiet(conj, truth_convention="as-is")
    assert kept.summary.truth_convention["used"] == "as-is"
    assert kept.summary.rms_error_deg > 10 * clean.summary.rms_error_deg
    # the clean truth fits as given: nothing tried, nothing said
    assert clean.summary.truth_convention == {"used": "as-is", "how": "", "fits": [], "line": ""}
    assert dict(kept.summary.to_dict()["truth_convention"]["fits"]) == {}


def test_an_all_zero_gyro_follows_no_truth(log):
    # A steady 1 rad/s spin as truth: its rate norm hardly varies, the gyro's is zero
    t = log.imu.t_ns[:3000]
    ts = (t - t[0]) * 1e-9
    q = np.stack([np.zeros_like(ts), np.zeros_like(ts), np.sin(ts / 2), np.cos(ts / 2)], axis=1)
    chk = check_truth(t, np.zeros((len(t), 3)), t, q)
    assert chk.checked and not chk.follows
    # a turning gyro under it follows (the same spin)
    spin = np.tile([0.0, 0.0, 1.0], (len(t), 1))
    assert check_truth(t, spin, t, q).follows
    assert choose_convention(t, spin, t, q).used == "as-is"


def _crashed(log, crash_s: float):
    # At crash_s the body stops (the gyro reads what it read at rest, before the truth began)
    # and its motion-capture pose flips 180° about x every 0.5 s (the markers' ambiguity)
    t_imu = (log.imu.t_ns - log.imu.t_ns[0]) * 1e-9
    after = t_imu >= crash_s
    w = log.imu.omega_b.copy()
    w[after] = w[: after.sum()]  # the first seconds of the log are at rest
    ts = (log.truth.t_ns - log.imu.t_ns[0]) * 1e-9
    late = ts >= crash_s
    q = log.truth.q_w_b.copy()
    lying = Rotation.from_quat(q[np.flatnonzero(late)[0]])
    flipped = lying * Rotation.from_rotvec([np.pi, 0.0, 0.0])
    odd = np.floor((ts[late] - crash_s) / 0.5) % 2 == 1
    q[late] = np.where(odd[:, None], flipped.as_quat(), lying.as_quat())
    imu = dataclasses.replace(log.imu, omega_b=w)
    return dataclasses.replace(_with_truth(log, q), imu=imu)


def test_a_truth_that_follows_until_a_crash_is_scored_until_it(log):
    # The whole truth no longer follows (its rate norms correlate badly); between its jumps it
    # follows until the first flip, 0.5 s after the crash (the body lies still as the gyro
    # does until then): scored there, exactly as the clean truth is, and nothing after
    crash_s, flip_s = 60.0, 60.5
    clean = _quiet(log, bias="none")
    res = _quiet(_crashed(log, crash_s), bias="none")
    assert res.summary.truth_check["correlation"] < 0.6
    line = next(w for w in res.summary.warnings if "does not follow the gyro as a whole" in w)
    first = line.split("it follows in ")[1].split(" s (")[0]
    lo, hi = (float(x) for x in first.split("-"))
    assert lo == 0.0 and abs(hi - flip_s) < 0.01, line
    # every flip is a jump; the stretches after the first are all refused, as one span
    ts = (log.truth.t_ns - log.imu.t_ns[0]) * 1e-9
    late = ts[ts >= crash_s]
    flips = int(np.count_nonzero(np.diff(np.floor((late - crash_s) / 0.5) % 2)))
    assert f"between its {flips} jumps" in line and "not in 60.50-" in line
    assert f"({flips} stretches)" in line
    before = res.t_s < crash_s - 0.1
    scored = np.isfinite(res.error.total_deg)
    assert not scored[res.t_s > flip_s + 0.01].any()
    mine, theirs = res.error.total_deg[before & scored], clean.error.total_deg[before & scored]
    assert scored[before].sum() > 0.9 * (before & np.isfinite(clean.error.total_deg)).sum()
    assert np.max(np.abs(mine - theirs)) < 1e-6


def test_after_a_gap_the_gyro_did_not_see_the_estimate_re_anchors(log):
    # 10 s of gyro samples lost (60-70 s) while the body turns: the integrator would bridge the
    # gap with the rates at its ends. The estimate re-anchors at the first sample after it, and
    # that segment scores exactly as a replay whose truth begins there.
    keep = ~((log.imu.t_ns - log.imu.t_ns[0] > 60e9) & (log.imu.t_ns - log.imu.t_ns[0] < 70e9))
    imu = dataclasses.replace(
        log.imu, t_ns=log.imu.t_ns[keep], log_t_ns=log.imu.log_t_ns[keep],
        omega_b=log.imu.omega_b[keep], accel_b=log.imu.accel_b[keep],
    )  # fmt: skip
    gapped = dataclasses.replace(log, imu=imu)
    res = _quiet(gapped, bias="none")
    (gap,) = res.summary.gap_reanchors
    # the last sample before the gap and the first after it (3.5 ms apart)
    assert 59.99 < gap["t0_s"] <= 60.0 and 70.0 <= gap["t1_s"] < 70.01
    line = next(w for w in res.summary.warnings if "the gyro did not see" in w)
    assert "re-anchors to the truth" in line
    segs = res.summary.scored_segments
    assert len(segs) == 2 and abs(segs[1]["start_s"] - gap["t1_s"]) < 1e-9
    a = int(np.searchsorted(res.t_s, gap["t1_s"]))
    cut = log.truth.t_ns >= res.t_ns[a]
    truth = dataclasses.replace(
        log.truth, t_ns=log.truth.t_ns[cut], log_t_ns=log.truth.log_t_ns[cut],
        q_w_b=log.truth.q_w_b[cut],
    )  # fmt: skip
    ref = _quiet(dataclasses.replace(gapped, truth=truth), bias="none")
    assert ref.start_index == a
    mine, theirs = res.error.total_deg[a:-1], ref.error.total_deg[a:-1]
    ok = np.isfinite(mine)
    assert ok.sum() > 0.9 * len(mine) and np.max(np.abs(mine[ok] - theirs[ok])) < 1e-6


def test_a_heading_only_truth_is_scored_on_heading_only():
    # A robot yaws (ψ = 2 sin 0.5t) and rocks 5° about its x axis (φ = 5° sin 3t); its planar
    # odometry carries only ψ. The estimate follows the true attitude Rz(ψ) Rx(φ); against the
    # planar truth its error is the rocking, a swing about a horizontal axis: no heading error.
    from imu_dcm.logio.types import ImuSeries, LogData, TruthSeries
    from imu_dcm.replay.summary import format_summary

    t = np.arange(0.0, 20.0, 0.005)
    t_ns = (1_000_000_000 + np.round(t * 1e9)).astype(np.int64)
    psi, dpsi = 2.0 * np.sin(0.5 * t), np.cos(0.5 * t)
    amp = np.radians(5.0)
    phi, dphi = amp * np.sin(3.0 * t), 3.0 * amp * np.cos(3.0 * t)
    # body rates of Rz(ψ) Rx(φ): Rx(φ)ᵀ (0, 0, ψ') + (φ', 0, 0)
    w = np.stack([dphi, np.sin(phi) * dpsi, np.cos(phi) * dpsi], axis=1)
    q_planar = Rotation.from_rotvec(np.outer(psi, [0.0, 0.0, 1.0])).as_quat()
    q_planar[:, :2] = 0.0  # by construction, as 2D odometry writes it
    imu = ImuSeries(t_ns, t_ns, w, None, "/imu", "Imu", "base_link")
    truth = TruthSeries(t_ns, t_ns, q_planar, "/odom", "nav_msgs/msg/Odometry", "odom", "base_link")
    s = _quiet(LogData("planar", imu, truth, ()), bias="none").summary
    assert s.scored_on == "heading" and s.rms_inclination_deg is None
    assert s.rms_error_deg < 1e-6  # magnus4 at 200 Hz on ~1 rad/s: (ω dt)⁴ ~ 1e-9 a step
    lines = format_summary(s).splitlines()
    assert next(x for x in lines if x.startswith("error ")).startswith("error      heading RMS")
    assert any(x.startswith("scored on  heading only") for x in lines)  # and says why
    # scored on the whole attitude, the rocking would be the score: 5°/√2 RMS
    full = _quiet(
        LogData("tilted", imu, dataclasses.replace(truth, q_w_b=q_planar + [1e-6, 0, 0, 0]), ()),
        bias="none",
    ).summary
    assert full.scored_on == "attitude" and abs(full.rms_error_deg - 5.0 / np.sqrt(2)) < 0.05


#: NED from ENU (x and y swap, z flips), written out here from the two frames' definitions
R_NED_ENU = Rotation.from_matrix([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
G = 9.80665


def _coning_log(world: str, seed: int = 3):
    """A gyro and accelerometer on a coning body (data_synth, 200 Hz, 20 s) pivoting in place
    (its specific force is gravity's reaction alone, up in the world), and its truth at 100 Hz
    body to ENU or to NED."""
    import data_synth
    from imu_dcm.logio.types import ImuSeries, LogData, TruthSeries

    traj = data_synth.simulate("coning", 20.0, half_angle_deg=20.0, freq_hz=0.5)
    model = data_synth.GyroModel(noise_density_rad_s_sqrt_hz=1e-3)
    rec = data_synth.synthetic_gyro(traj, 200.0, model=model, seed=seed)
    q_imu, _w = traj.at(rec.t_s)
    rng = np.random.default_rng(seed)
    accel = Rotation.from_quat(q_imu).inv().apply([0.0, 0.0, G]) + rng.normal(
        0, 0.05, (len(q_imu), 3)
    )
    imu = ImuSeries(
        rec.t_ns, rec.t_ns, rec.values, None, "/imu", "sensor_msgs/msg/Imu", "imu", accel
    )
    t_truth = np.arange(0.0, 20.0, 0.01)
    q_enu, _ = traj.at(t_truth)
    q = q_enu if world == "enu" else (R_NED_ENU * Rotation.from_quat(q_enu)).as_quat()
    t_ns = rec.epoch_ns + np.round(t_truth * 1e9).astype(np.int64)
    truth = TruthSeries(t_ns, t_ns, q, "/truth", "geometry_msgs/msg/PoseStamped", world)
    return LogData("coning.mcap", imu, truth, ())


def test_a_truth_in_a_ned_world_is_found_by_gravity_and_applied():
    # The body rates of a NED truth fit the gyro as well as ENU's (a constant rotation on the
    # world side): only gravity tells. In the NED truth's world the accelerometer's mean points
    # down, (0, 0, -g) within the accelerometer's noise; it is named and applied, and the score
    # is the ENU truth's (the error of a constant world rotation is the same).
    enu = _quiet(_coning_log("enu"), bias="none")
    ned = _quiet(_coning_log("ned"), bias="none")
    assert enu.summary.truth_convention == {"used": "as-is", "how": "", "fits": [], "line": ""}
    conv = ned.summary.truth_convention
    assert conv["used"] == "ned" and conv["how"] == "fit", conv
    # a body pivoting in place reads gravity's reaction alone: in the NED world each row is
    # (0, 0, -g) plus noise, averaging 0.05 / √4000 m/s² per axis (0.02 is 25 of those, left
    # for the estimated mounting's error)
    np.testing.assert_allclose(conv["gravity_w_m_s2"], [0.0, 0.0, -G], atol=0.02)
    line = next(w for w in ned.summary.warnings if "NED" in w)
    assert "its world is NED, not ENU" in line and "applied" in line
    assert abs(ned.summary.rms_error_deg - enu.summary.rms_error_deg) < 1e-6
    # stated, it is applied to an ENU truth too; as-is keeps the NED one as read
    stated = _quiet(_coning_log("enu"), bias="none", truth_convention="ned")
    assert stated.summary.truth_convention["used"] == "ned"
    assert stated.summary.truth_convention["how"] == "given"
    kept = _quiet(_coning_log("ned"), bias="none", truth_convention="as-is")
    assert kept.summary.truth_convention["used"] == "as-is"

"""Tests of ``imu-dcm-replay noise`` (imu_dcm.gyro.allan.fit_noise, imu_dcm.replay.noise_cli): the
angle random walk N and the rate random walk K of a synthetic gyro (data_synth's white noise
and bias random walk, known densities) are recovered within the statistical bound of the record
length; the Kalibr YAML says the same numbers in continuous time; outputs are checked before
the log is read. (data_synth has no flicker noise, so no known B to recover: B is only checked
to sit at the deviation's floor.)
"""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from conftest import assert_names

from imu_dcm.gyro.allan import B_FACTOR, allan_deviation, fit_noise, octave_clusters

N_TRUE, K_TRUE, RATE_HZ, SECONDS = 5e-4, 1e-4, 200.0, 1200.0


class _Still:
    """A body at rest (identity attitude, zero rate): what data_synth's gyro samples."""

    duration_s = SECONDS

    def at(self, t_s):
        t = np.asarray(t_s)
        q = np.zeros((len(t), 4))
        q[:, 3] = 1.0
        return q, np.zeros((len(t), 3))


@pytest.fixture(scope="module")
def still_log(tmp_path_factory):
    from data_synth.gyro import GyroModel, synthetic_gyro
    from imu_dcm.logio.writers import StampedSeries, write_bag

    model = GyroModel(noise_density_rad_s_sqrt_hz=N_TRUE, bias_walk_rad_s2_sqrt_hz=K_TRUE)
    rec = synthetic_gyro(_Still(), RATE_HZ, model=model, seed=4)
    out = tmp_path_factory.mktemp("noise") / "still"
    write_bag(out, imu=StampedSeries(rec.t_ns, rec.values, "imu"))
    return out, rec


def test_n_and_k_recovered_within_the_record_bound(still_log):
    _, rec = still_log
    n = len(rec.t_s)
    tau, adev = allan_deviation(rec.values, RATE_HZ, m=octave_clusters(n))
    for axis in range(3):
        f = fit_noise(tau, adev[:, axis], n)
        assert f.N.reached and f.K.reached
        # three standard errors of the Allan deviation from the clusters at the τ read
        assert abs(f.N.value / N_TRUE - 1) < 3 * f.N.rel_uncertainty
        assert abs(f.K.value / K_TRUE - 1) < 3 * f.K.rel_uncertainty
        # the bounds are those of this record: N from ~240 000 differences (0.2 %), K from
        # a few dozen clusters (10-20 %)
        assert f.N.rel_uncertainty < 0.005 and f.K.rel_uncertainty < 0.25
        assert f.B.value * B_FACTOR == pytest.approx(np.min(adev[:, axis]))


def test_white_noise_alone_has_no_rate_random_walk():
    rng = np.random.default_rng(9)
    y = rng.standard_normal((200_000, 1)) * N_TRUE * np.sqrt(RATE_HZ)
    tau, adev = allan_deviation(y, RATE_HZ, m=octave_clusters(len(y)))
    f = fit_noise(tau, adev[:, 0], len(y))
    assert abs(f.N.value / N_TRUE - 1) < 3 * f.N.rel_uncertainty
    assert not f.K.reached and not f.B.reached  # no floor, no +1/2 slope: bounds only
    # the bound holds: K√(τ/3) at the longest τ does not exceed the deviation there
    assert f.K.value * np.sqrt(tau[-1] / 3) == pytest.approx(adev[-1, 0])


def test_noise_command_prints_and_writes_kalibr_yaml(still_log, tmp_path, capsys):
    from imu_dcm.replay.__main__ import main

    log, rec = still_log
    out = tmp_path / "imu.yaml"
    assert main(["noise", str(log), "--yaml", str(out)]) == 0
    text = capsys.readouterr().out
    assert "the whole log (static)" in text and "ARW N" in text and "RRW K" in text
    doc = yaml.safe_load(out.read_text())
    assert doc["rostopic"] == "/imu/data"
    assert doc["update_rate"] == pytest.approx(RATE_HZ, rel=1e-9)
    # continuous-time densities, not per-sample std (which would be N·√200 = 14x larger)
    assert doc["gyroscope_noise_density"] == pytest.approx(N_TRUE, rel=0.01)
    assert doc["gyroscope_random_walk"] == pytest.approx(K_TRUE, rel=0.5)
    assert "rad/s/sqrt(Hz)" in out.read_text() and "rad/s^2/sqrt(Hz)" in out.read_text()


def test_noise_plot_and_bad_outputs(still_log, tmp_path, capsys):
    pytest.importorskip("matplotlib")
    from imu_dcm.replay.__main__ import main

    log, _ = still_log
    fig = tmp_path / "allan.png"
    assert main(["noise", str(log), "--plot", str(fig)]) == 0
    assert fig.stat().st_size > 10_000
    capsys.readouterr()
    assert main(["noise", str(log), "--plot", str(tmp_path / "a.gif")]) == 2
    assert_names(capsys.readouterr().err, "--plot", ".png", ".svg", str(tmp_path / "a.gif"))
    assert main(["noise", str(log), "--yaml", str(log / "x.yaml")]) == 2
    assert not (log / "x.yaml").exists()


def test_the_prefilter_takes_the_noise_density_from_the_yaml(still_log, tmp_path, capsys):
    """``--prefilter kalman --noise-params IMU.yaml`` runs the filter with the YAML's
    ``gyroscope_noise_density``: the same summary as the density given by hand."""
    import json

    from imu_dcm.replay.__main__ import main

    log, _ = still_log
    yml = tmp_path / "imu.yaml"
    assert main(["noise", str(log), "--yaml", str(yml)]) == 0
    density = yaml.safe_load(yml.read_text())["gyroscope_noise_density"]
    runs = {
        "yaml": ["--noise-params", str(yml)],
        "hand": ["--gyro-noise-density", repr(density)],
        "rest": [],
    }
    got = {}
    for name, extra in runs.items():
        out = tmp_path / f"{name}.json"
        argv = [str(log), "--rerun", "off", "--quiet", "--prefilter", "kalman", *extra]
        assert main([*argv, "--summary-json", str(out)]) == 0, capsys.readouterr().err
        got[name] = json.loads(out.read_text())["prefilter_summary"]
    assert got["yaml"] == got["hand"]
    assert got["yaml"] != got["rest"]  # the YAML's value was used, not the one from rest

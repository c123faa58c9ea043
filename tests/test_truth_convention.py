"""The truth's convention is judged by how its body-rate vectors fit the gyro's: a conjugated or
reordered truth of the shipped trial is named, applied when the fit determines it clearly (then
it scores as the clean truth does) or when stated, and an all-zero gyro follows no truth."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest
from conftest import REPO_ROOT

from imu_dcm.logio import read_log
from imu_dcm.replay import replay
from imu_dcm.replay.convention import choose_convention, convert
from imu_dcm.replay.truth import check_truth

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

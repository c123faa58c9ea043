"""Streaming integrator: equals its batch twin for every method; state, lag and bad input."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from imu_dcm import GapWarning, ImuDcmWarning, InputError
from imu_dcm.errors import Diagnostics
from imu_dcm.integrator.batch import METHODS, integrate
from imu_dcm.integrator.streaming import DcmIntegrator

Q0 = Rotation.from_euler("zyx", [1.0, -0.4, 0.3]).as_quat()
# Streaming and batch run the same compiled kernel, so they agree to rounding at most (the
# bound the integrator promises; in practice they are bit for bit equal).
TOL_DEG = 1e-9


def record(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    t = 2.0 + np.cumsum(rng.uniform(0.5e-3, 1.5e-3, n))
    omega = np.cumsum(rng.normal(scale=0.5, size=(n, 3)), axis=0)  # a wandering rate, rad/s
    return omega, t


def angle_deg(q_a, q_b) -> np.ndarray:
    return np.degrees((Rotation.from_quat(q_a).inv() * Rotation.from_quat(q_b)).magnitude())


def quiet(method: str):
    if method == "rotvec_sum":
        return pytest.warns(ImuDcmWarning)
    return warnings.catch_warnings()


def lagged_index(k: int, method: str) -> int:
    """Sample whose attitude update() returns after sample k (see DcmIntegrator's doc)."""
    if method != "magnus4":
        return k
    return k - 1 if k >= 3 else 0


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("n", [2, 3, 4, 5, 400])
def test_update_equals_batch(method, n):
    omega, t = record(n, seed=n)
    with quiet(method):
        batch = integrate(omega, t, Q0, method).as_quat()
    with quiet(method):
        integ = DcmIntegrator(Q0, method)
    got = np.array([integ.update(omega[k], t[k]) for k in range(n)])
    idx = [lagged_index(k, method) for k in range(n)]
    assert angle_deg(got, batch[idx]).max() <= TOL_DEG
    assert integ.t_s == t[idx[-1]]
    final = integ.finish()
    assert angle_deg(final, batch[-1]) <= TOL_DEG
    assert integ.t_s == t[-1]


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("chunk", [1, 3, 7, 1000])
def test_update_many_equals_batch(method, chunk):
    n = 700
    omega, t = record(n, seed=11)
    with quiet(method):
        batch = integrate(omega, t, Q0, method).as_quat()
        integ = DcmIntegrator(Q0, method)
    rows = [
        integ.update_many(omega[i : i + chunk], t[i : i + chunk]).as_quat()
        for i in range(0, n, chunk)
    ]
    got = np.vstack(rows)
    idx = [lagged_index(k, method) for k in range(n)]
    assert got.shape == (n, 4)
    assert angle_deg(got, batch[idx]).max() <= TOL_DEG
    assert angle_deg(integ.finish(), batch[-1]) <= TOL_DEG


def test_mixing_update_and_update_many():
    omega, t = record(300, seed=12)
    batch = integrate(omega, t, Q0).as_quat()
    integ = DcmIntegrator(Q0)
    integ.update_many(omega[:2], t[:2])
    for k in range(2, 10):
        integ.update(omega[k], t[k])
    integ.update_many(omega[10:250], t[10:250])
    integ.update(omega[250], t[250])
    integ.update_many(omega[251:], t[251:])
    assert angle_deg(integ.finish(), batch[-1]) <= TOL_DEG


def test_t0_s_holds_the_first_rate_from_t0():
    omega, t = record(50, seed=13)
    t0 = t[0] - 0.002
    integ = DcmIntegrator(Q0, "trapezoid", t0_s=t0)
    assert integ.t_s == t0
    for k in range(50):
        q = integ.update(omega[k], t[k])
    ref = integrate(np.vstack([omega[:1], omega]), np.concatenate([[t0], t]), Q0, "trapezoid")
    assert angle_deg(q, ref.as_quat()[-1]) <= TOL_DEG


def test_magnus4_lags_one_sample_and_names_the_stamp():
    omega, t = record(6, seed=14)
    integ = DcmIntegrator(Q0)
    assert integ.t_s is None
    integ.update(omega[0], t[0])
    integ.update(omega[1], t[1])
    np.testing.assert_allclose(integ.q_w_b, Q0, atol=1e-15)  # nothing final yet
    assert integ.t_s == t[0]
    integ.update(omega[2], t[2])
    assert integ.t_s == t[0]  # the first step needs four samples (start ghost)
    for k in range(3, 6):
        integ.update(omega[k], t[k])
        assert integ.t_s == t[k - 1]
    assert integ.n_samples == 6


def test_rotation_property_and_renormalisation():
    # 20000 steps: the attitude stays unit (|q| pulled back to 1 after every step) to
    # rounding, without growing with the number of steps.
    rng = np.random.default_rng(15)
    integ = DcmIntegrator(Q0, "coning")
    for k in range(20000):
        q = integ.update(rng.normal(scale=3.0, size=3), 1e-3 * k)
    assert abs(np.linalg.norm(q) - 1.0) <= 1e-14
    np.testing.assert_allclose(integ.rotation.as_quat(), q / np.linalg.norm(q), atol=1e-15)


def test_rotvec_sum_warns_on_construction():
    with pytest.warns(ImuDcmWarning, match="rotvec_sum"):
        DcmIntegrator(Q0, "rotvec_sum")


def test_bad_input():
    integ = DcmIntegrator(Q0)
    with pytest.raises(InputError, match="3 numbers"):
        integ.update([1.0, 2.0], 0.0)
    with pytest.raises(InputError, match="3 numbers"):
        integ.update(["a", 1.0, 2.0], 0.0)
    with pytest.raises(InputError, match="finite"):
        integ.update([np.nan, 0.0, 0.0], 0.0)
    integ.update([0.0, 0.0, 1.0], 0.0)
    integ.update([0.0, 0.0, 1.0], 0.01)
    with pytest.raises(InputError, match=r"t_s\[2\] = 0.01 s after t_s\[1\] = 0.01 s"):
        integ.update([0.0, 0.0, 1.0], 0.01)
    with pytest.raises(InputError, match=r"strictly increasing"):
        integ.update_many(np.zeros((2, 3)), [0.02, 0.005])
    with pytest.raises(InputError, match=r"\(n, 3\)"):
        integ.update_many(np.zeros((2, 2)), [0.02, 0.03])
    with pytest.raises(InputError, match="method"):
        DcmIntegrator(Q0, "euler")
    with pytest.raises(InputError, match="t0_s"):
        DcmIntegrator(Q0, t0_s="soon")
    with pytest.raises(InputError, match="t0_s"):
        DcmIntegrator(Q0, t0_s=np.nan)
    integ.finish()
    with pytest.raises(InputError, match="finish"):
        integ.update([0.0, 0.0, 1.0], 0.5)


def test_gap_warns_in_streaming():
    integ = DcmIntegrator(Q0, "trapezoid")
    for k in range(10):
        integ.update([0.0, 0.0, 1.0], 0.01 * k)
    with pytest.warns(GapWarning, match=r"at 0.090 s \(\+0.410 s\)"):
        integ.update([0.0, 0.0, 1.0], 0.5)
    with pytest.warns(GapWarning, match="gap"):
        integ.update_many(np.zeros((3, 3)), [0.51, 0.52, 1.5])


def test_gaps_go_to_diagnostics_when_given_and_no_warning_is_raised():
    # a pass on a thread of its own must leave the process's warning filters alone: its gaps
    # (and rotvec_sum's caution) go to the diagnostics it was given, in the words a warning has
    said = Diagnostics()
    integ = DcmIntegrator(Q0, "trapezoid", diagnostics=said)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # any warning would raise here
        for k in range(10):
            integ.update([0.0, 0.0, 1.0], 0.01 * k)
        integ.update([0.0, 0.0, 1.0], 0.5)
        integ.update_many(np.zeros((3, 3)), [0.51, 0.52, 1.5])
        DcmIntegrator(Q0, "rotvec_sum", diagnostics=said)
    lines = [(m, c) for m, c in said.said]
    assert [c for _m, c in lines] == [GapWarning, GapWarning, ImuDcmWarning]
    assert "at 0.090 s (+0.410 s)" in lines[0][0] and "gap" in lines[1][0]
    assert "rotvec_sum" in lines[2][0]


def test_readme_usage_example_runs(repo_root, capsys):
    # The README's usage block must run as printed and show 90 deg about z twice.
    text = (repo_root / "README.md").read_text(encoding="utf-8")
    section = text.split("<!-- section: usage -->", 1)[1].split("<!-- end: usage -->", 1)[0]
    code = section.split("```python", 1)[1].split("```", 1)[0]
    exec(compile(code, "README usage", "exec"), {})
    assert capsys.readouterr().out.count("0.7071 0.7071]") == 2


@pytest.mark.parametrize("method", ["magnus4", "trapezoid"])
def test_any_array_layout_gives_the_same_bits(method):
    # The kernel takes float64 C-contiguous arrays; the Python boundary converts whatever the
    # caller holds (columns of a table, float32, lists, ints) to those, so the result is the
    # batch result of the same numbers, bit for bit.
    omega, t = record(60, seed=7)
    table = np.asfortranarray(np.column_stack([t, omega]))  # every column strided
    want = integrate(omega, t, Q0, method).as_quat()
    assert np.array_equal(integrate(table[:, 1:], table[:, 0], Q0, method).as_quat(), want)
    chunked = DcmIntegrator(Q0, method)
    got = np.vstack(
        [chunked.update_many_quat(table[i : i + 20, 1:], table[i : i + 20, 0]) for i in (0, 20, 40)]
    )
    single = DcmIntegrator(Q0, method)
    rows = [single.update(list(table[k, 1:]), t[k]) for k in range(30)]
    rows += [single.update(table[k, 1:], t[k]) for k in range(30, 60)]  # strided rows
    assert np.array_equal(got, np.array(rows))
    idx = [lagged_index(k, method) for k in range(60)]
    assert np.array_equal(got, want[idx])


def test_update_many_quat_is_update_many_as_an_array():
    omega, t = record(50, seed=3)
    a, b = DcmIntegrator(Q0), DcmIntegrator(Q0)
    for i, j in ((0, 2), (2, 30), (30, 50)):  # the warm-up inside the first chunks
        assert np.array_equal(
            a.update_many_quat(omega[i:j], t[i:j]),
            b.update_many(omega[i:j], t[i:j]).as_quat(canonical=False),
        )


def test_state_is_a_copy_by_field():
    integ = DcmIntegrator([0, 0, 0, 1], method="trapezoid")
    integ.update(np.array([0.0, 0.0, 1.0]), 0.0)
    integ.update(np.array([0.0, 0.0, 1.0]), 0.01)
    state = integ.state()
    # 1 rad/s about z for 10 ms: 0.01 rad, q = [0, 0, sin 0.005, cos 0.005].
    assert np.allclose(state["q"], [0, 0, np.sin(0.005), np.cos(0.005)], rtol=0, atol=1e-15)
    assert state["n"][0] == 2 and state["t"][-2:].tolist() == [0.0, 0.01]
    state["q"][:] = 0.0
    assert integ.q_w_b[3] > 0.99  # a copy: the integrator is unchanged

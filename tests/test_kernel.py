"""The compiled kernel against a plain per-sample reference loop written here, independently.

The reference evaluates each method's formula as written (magnus4: Simpson's rule with the mid-step
rate read off the cubic through four samples in Lagrange form, not the kernel's weight form; ghost
samples on the same kind of polynomial) and composes the steps with a textbook Hamilton product, in
Python floats. Random rates and uneven stamps; record lengths that the earlier blocked product
split unevenly (1, 2, 3, 17, 5003 and 10^5 steps).
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from imu_dcm import DcmIntegrator, GapWarning, ImuDcmWarning, kernel
from imu_dcm.integrate import (
    DELTA_METHODS,
    METHODS,
    find_gaps,
    gap_message,
    integrate,
    integrate_delta,
)
from imu_dcm.methods import DeltaMethod, Method
from imu_dcm.so3 import quat_angle_rad

EPS = np.finfo(float).eps
STEPS = (1, 2, 3, 17, 5003, 100_000)


def tolerance_rad(n_steps: int) -> float:
    """Two chains of ``n`` products that differ by rounding drift apart by at most a few eps
    per step (4 n eps, linear worst case); the bound asked of the kernel is 1e-12 rad."""
    return min(1e-12, 4.0 * n_steps * EPS)


def record(n_steps: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Random rates (rad/s, |ω| ~ 3) at uneven stamps (0.5-1.5 ms)."""
    rng = np.random.default_rng(seed)
    t = 0.7 + np.concatenate([[0.0], np.cumsum(rng.uniform(0.5e-3, 1.5e-3, n_steps))])
    return rng.normal(scale=2.0, size=(n_steps + 1, 3)), t


def poly_value(ts: list[float], ws: list[list[float]], t: float) -> list[float]:
    """Value at ``t`` of the polynomial of degree len(ts) - 1 through the points, in
    Lagrange form (a least-squares fit would add ~1e-14 relative error per step)."""
    out = [0.0, 0.0, 0.0]
    for j, tj in enumerate(ts):
        lj = math.prod((t - ti) / (tj - ti) for i, ti in enumerate(ts) if i != j)
        out = [o + lj * v for o, v in zip(out, ws[j], strict=False)]
    return out


def qmul(p, q):
    px, py, pz, pw = p
    qx, qy, qz, qw = q
    return (
        pw * qx + px * qw + py * qz - pz * qy,
        pw * qy - px * qz + py * qw + pz * qx,
        pw * qz + px * qy - py * qx + pz * qw,
        pw * qw - px * qx - py * qy - pz * qz,
    )


def qexp(phi):
    theta = math.sqrt(phi[0] ** 2 + phi[1] ** 2 + phi[2] ** 2)
    s = 0.5 if theta == 0.0 else math.sin(0.5 * theta) / theta
    return (phi[0] * s, phi[1] * s, phi[2] * s, math.cos(0.5 * theta))


def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def reference(omega: np.ndarray, t: np.ndarray, q0, method: str) -> np.ndarray:
    """Attitudes at every stamp by the plain loop ``q <- q ⊗ exp(φ_i)``."""
    w = omega.tolist()
    ts = t.tolist()
    n = len(ts)
    q = tuple(q0)
    out = [q]
    if method == "rotvec_sum":
        acc = [0.0, 0.0, 0.0]
        for i in range(n - 1):
            h = ts[i + 1] - ts[i]
            acc = [acc[c] + h * w[i][c] for c in range(3)]
            out.append(qmul(q0, qexp(acc)))
        return np.array(out)
    m = min(n, 4)
    # Ghost samples one step beyond each end, on the polynomial through the end samples. Times
    # are taken relative to a nearby sample: differences of neighbouring stamps are exact in
    # floats, while a polynomial in absolute time (t ~ 100 s) would lose 1e-14 s to rounding.
    head = [x - ts[0] for x in ts[:m]]
    tail = [x - ts[-1] for x in ts[-m:]]
    tx = [ts[0] - (ts[1] - ts[0])] + ts + [ts[-1] + (ts[-1] - ts[-2])]
    wx = (
        [poly_value(head, w[:m], -(ts[1] - ts[0]))]
        + w
        + [poly_value(tail, w[-m:], ts[-1] - ts[-2])]
    )
    for i in range(n - 1):
        h = ts[i + 1] - ts[i]
        w0, w1 = w[i], w[i + 1]
        if method == "start":
            phi = [h * v for v in w0]
        elif method == "end":
            phi = [h * v for v in w1]
        elif method == "trapezoid":
            phi = [0.5 * h * (a + b) for a, b in zip(w0, w1, strict=False)]
        elif method == "coning":
            c = cross(w0, w1)
            phi = [
                0.5 * h * (a + b) + h * h / 12.0 * cc for a, b, cc in zip(w0, w1, c, strict=False)
            ]
        else:  # magnus4: Simpson with the mid-step rate of the cubic through ω_{i-1..i+2}
            nodes = [
                tx[i] - ts[i] if i == 0 else ts[i - 1] - ts[i],
                0.0,
                h,
                tx[i + 3] - ts[i] if i == n - 2 else ts[i + 2] - ts[i],
            ]
            w_mid = poly_value(nodes, wx[i : i + 4], 0.5 * h)
            c = cross(w0, w1)
            phi = [
                h / 6.0 * (a + 4.0 * b + d) + h * h / 12.0 * cc
                for a, b, d, cc in zip(w0, w_mid, w1, c, strict=False)
            ]
        q = qmul(q, qexp(phi))
        out.append(q)
    return np.array(out)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("n_steps", STEPS)
def test_kernel_equals_reference_loop(method, n_steps):
    omega, t = record(n_steps, seed=n_steps)
    q0 = np.array([0.1, -0.5, 0.3, 0.8]) / math.sqrt(0.99)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ImuDcmWarning)  # rotvec_sum warns by design
        got = integrate(omega, t, q0, method).as_quat()
    ref = reference(omega, t, q0, method)
    assert got.shape == (n_steps + 1, 4)
    assert quat_angle_rad(got, ref).max() <= tolerance_rad(n_steps)


@pytest.mark.parametrize("method", ["plain", "one_plus_previous", "two_sample", "three_sample"])
def test_delta_kernel_equals_reference_loop(method):
    # Delta-angle rules as written (equal intervals: 1/12, 2/3, 9/20 and 27/40).
    rng = np.random.default_rng(7)
    n = 600
    d = rng.normal(scale=0.02, size=(n, 3)).tolist()
    tb = np.arange(n + 1) * 1e-3
    q0 = (0.0, 0.0, 0.0, 1.0)
    q = q0
    ref = [q]
    m = {"two_sample": 2, "three_sample": 3}.get(method, 1)
    for k in range(0, n, m):
        if method == "plain":
            phi = d[k]
        elif method == "one_plus_previous":
            c = cross(d[k - 1], d[k]) if k else (0.0, 0.0, 0.0)
            phi = [a + cc / 12.0 for a, cc in zip(d[k], c, strict=False)]
        elif method == "two_sample":
            c = cross(d[k], d[k + 1])
            phi = [a + b + 2.0 / 3.0 * cc for a, b, cc in zip(d[k], d[k + 1], c, strict=False)]
        else:
            d1, d2, d3 = d[k], d[k + 1], d[k + 2]
            c13 = cross(d1, d3)
            c2 = cross(d2, [a - b for a, b in zip(d3, d1, strict=False)])
            phi = [
                a + b + e + 9.0 / 20.0 * x + 27.0 / 40.0 * y
                for a, b, e, x, y in zip(d1, d2, d3, c13, c2, strict=False)
            ]
        q = qmul(q, qexp(phi))
        ref.append(q)
    got = integrate_delta(np.array(d), tb, q0, method).as_quat()
    assert quat_angle_rad(got, np.array(ref)).max() <= tolerance_rad(n // m)


def test_state_layout_fits():
    state = kernel.new_state(np.array([0.0, 0.0, 0.0, 1.0]), kernel.MAGNUS4)
    assert state.shape == (kernel.STATE_SIZE,)
    assert kernel.T + 4 <= kernel.N < kernel.METHOD < kernel.STATE_SIZE


def test_state_fields_tile_the_state_and_name_what_new_state_sets():
    offsets = sorted((o, w) for o, w, _ in kernel.STATE_FIELDS.values())
    ends = [o + w for o, w in offsets]
    assert offsets[0][0] == 0 and ends[-1] == kernel.STATE_SIZE
    assert [o for o, _ in offsets[1:]] == ends[:-1]  # no gap, no overlap
    q0 = np.array([0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)])  # 90 deg about z
    fields = kernel.state_fields(kernel.new_state(q0, Method.CONING))
    assert fields["q"].tolist() == q0.tolist() and fields["q0"].tolist() == q0.tolist()
    assert fields["method"][0] == Method.CONING and fields["n"][0] == 0.0
    assert fields["omega"].shape == (12,) and fields["t"].shape == (4,)


def test_method_names_are_the_enum_names_in_code_order():
    assert tuple(m.name.lower() for m in sorted(Method)) == METHODS
    assert tuple(m.name.lower() for m in sorted(DeltaMethod)) == DELTA_METHODS
    assert all(Method[name.upper()].label == name for name in METHODS)


def test_entry_points_have_one_signature_and_refuse_other_types():
    # Each entry point is compiled for one signature; other argument types are refused (the
    # callers convert at the Python boundary) instead of compiling a second version.
    w, t = np.zeros((5, 3)), 1e-3 * np.arange(5)
    integrate(w, t, [0, 0, 0, 1], "magnus4")
    check = kernel.check_record.compiled()
    assert len(check.signatures) == 1
    with pytest.raises(TypeError):
        check(np.zeros((5, 3), dtype=np.int64), t, -math.inf)
    with pytest.raises(TypeError):
        check(np.asfortranarray(np.zeros((5, 3))), t, -math.inf)
    push = kernel.push_for(int(Method.MAGNUS4))
    assert len(push.signatures) == 1
    with pytest.raises(TypeError):
        push(kernel.new_state(np.array([0.0, 0, 0, 1]), Method.MAGNUS4), [0.0, 0.0, 0.0], 0.0)
    assert all(len(fn.signatures) == 1 for fn in kernel._FEEDS.values())


def _kernel_env(cache: Path) -> dict[str, str]:
    return {
        **os.environ,
        "NUMBA_CACHE_DIR": str(cache),
        "PYTHONPATH": os.pathsep.join(
            [str(Path(kernel.__file__).parents[1]), os.environ.get("PYTHONPATH", "")]
        ),
    }


def test_compile_notice_once_on_a_cache_miss_and_never_from_the_cache(tmp_path):
    # An empty cache: the kernel compiles, and says so once on stderr before it does. The same
    # cache again: it loads, silently.
    code = (
        "import numpy as np, imu_dcm; w, t = np.zeros((9, 3)), 1e-3 * np.arange(9); "
        "imu_dcm.integrate(w, t, [0, 0, 0, 1]); integ = imu_dcm.DcmIntegrator([0, 0, 0, 1]); "
        "[integ.update(w[k], float(t[k])) for k in range(9)]; integ.finish()"
    )
    runs = [
        subprocess.run(
            [sys.executable, "-c", code],
            env=_kernel_env(tmp_path / "cache"),
            capture_output=True,
            text=True,
            check=False,
            timeout=600,
        )
        for _ in range(2)
    ]
    assert [r.returncode for r in runs] == [0, 0], runs[0].stderr + runs[1].stderr
    notice = "compiling the integrator kernel once, about"
    assert runs[0].stderr.count(notice) == 1, runs[0].stderr
    assert "later runs load it from the cache" in runs[0].stderr
    assert runs[1].stderr == "", runs[1].stderr


def test_no_writable_cache_folder_warns_once_and_still_imports(tmp_path):
    # A read-only install with no user cache either: numba finds no cache folder. The kernel
    # must still import (compiled per process) and say so once. Simulated by allowing only
    # numba's NUMBA_CACHE_DIR locator and pointing it below a regular file.
    blocker = tmp_path / "file"
    blocker.write_text("")
    env = {
        **os.environ,
        "NUMBA_CACHE_LOCATOR_CLASSES": "UserProvidedCacheLocator",
        "NUMBA_CACHE_DIR": str(blocker / "cache"),
        "PYTHONPATH": os.pathsep.join(
            [str(Path(kernel.__file__).parents[1]), os.environ.get("PYTHONPATH", "")]
        ),
    }
    code = "import warnings; warnings.simplefilter('always'); import imu_dcm.kernel"
    res = subprocess.run(
        [sys.executable, "-c", code],
        env=env,
        capture_output=True,
        text=True,
        check=False,
        timeout=300,
    )
    assert res.returncode == 0, res.stderr
    assert res.stderr.count("Expected a writable folder to cache") == 1


def test_find_gaps_is_the_one_rule():
    t = np.concatenate([np.arange(10) * 0.01, 0.5 + np.arange(3) * 0.01])
    assert find_gaps(t) == ((0.09, pytest.approx(0.41)),)
    assert find_gaps(t, factor=50.0) == ()
    assert find_gaps([0.0, 0.01, 1.0]) == ()  # two steps: no median to stand out from
    # Streaming applies the same rule to the stamps it holds, with the same message.
    integ = DcmIntegrator([0, 0, 0, 1], "trapezoid")
    for k in range(10):
        integ.update(np.zeros(3), t[k])
    with pytest.warns(GapWarning) as caught:
        integ.update(np.zeros(3), t[10])
    assert str(caught[0].message) == gap_message(find_gaps(t[7:11]))

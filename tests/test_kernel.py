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
from conftest import assert_quiet, own_stderr

from imu_dcm import DcmIntegrator, GapWarning, ImuDcmWarning
from imu_dcm import _kernels as kernel
from imu_dcm._kernels import entries, loader
from imu_dcm.errors import InputError
from imu_dcm.integrator.batch import (
    DELTA_METHODS,
    METHODS,
    find_gaps,
    gap_message,
    integrate,
    integrate_delta,
)
from imu_dcm.integrator.methods import DeltaMethod, Method
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


def test_batch_entry_points_refuse_arrays_the_compiled_code_would_misread():
    # The compiled code reads float64 C-contiguous arrays without checking them; the kernel's
    # batch functions refuse anything else (the callers convert at the Python boundary).
    t = 1e-3 * np.arange(5)
    with pytest.raises(TypeError, match="float64 C-contiguous"):
        kernel.check_record(np.zeros((5, 3), dtype=np.int64), t, -math.inf)
    with pytest.raises(TypeError, match="float64 C-contiguous"):
        kernel.check_record(np.asfortranarray(np.zeros((5, 3))), t, -math.inf)
    state = kernel.new_state(np.array([0.0, 0, 0, 1]), Method.MAGNUS4)
    with pytest.raises(TypeError, match="`out`"):
        kernel.feed(state, np.zeros((5, 3)), t, np.zeros((4, 6))[:, ::2], False)
    with pytest.raises(TypeError, match="`omega`"):
        kernel.push(state, [0.0, 0.0, 0.0], 0.0)


def test_streaming_update_converts_any_sample_type_to_the_same_bits():
    # Lists, ints, strided views, other byte orders and numpy scalars reach the unchecked
    # compiled push as float64 C arrays: every form gives the float64 path's attitude exactly.
    w, t = record(40, seed=5)
    w[:, 0] = np.round(w[:, 0])  # ints are exact as floats
    forms = {
        "float64": lambda k: (w[k].copy(), float(t[k])),
        "list": lambda k: (w[k].tolist(), float(t[k])),
        "strided": lambda k: (np.repeat(w[k], 2)[::2], np.float64(t[k])),
        "big-endian": lambda k: (w[k].astype(">f8"), t[k].item()),
        "2-d row": lambda k: (w[k : k + 1][0], t[k]),
    }
    got = {}
    for name, form in forms.items():
        integ = DcmIntegrator([0, 0, 0, 1])
        got[name] = np.array([integ.update(*form(k)) for k in range(len(t))])
    for name in forms:
        assert np.array_equal(got[name], got["float64"]), name
    integ = DcmIntegrator([0, 0, 0, 1])
    for k in range(3):
        integ.update(np.round(w[k]).astype(np.int64), int(k))
    assert integ.n_samples == 3
    with pytest.raises(InputError, match="3 numbers"):
        integ.update(np.zeros(4), 5.0)
    with pytest.raises(InputError, match="3 numbers"):
        integ.update(np.zeros(3), "later")


def _aot_or_skip():
    """The module built ahead of time, or a skip (a failure when the environment requires
    it: CI does, after its install built it)."""
    if kernel.backend() == "ahead-of-time":
        return loader._aot()
    reason = f"no up-to-date kernel built ahead of time{loader._AOT[1]}"
    if os.environ.get("IMU_DCM_REQUIRE_AOT") == "1":
        pytest.fail(reason)
    pytest.skip(reason)


@pytest.mark.parametrize("method", [int(m) for m in Method])
@pytest.mark.parametrize("emit_phi", [False, True])
def test_built_kernel_equals_numba_compile_bit_for_bit(method, emit_phi):
    # The two ways to load the kernel compile the same functions; the built module and numba's
    # compile must agree in every bit (no fast-math: no reassociation, no fused multiply-add).
    aot = _aot_or_skip()
    w, t = record(3000, seed=method)
    outs, states = [], []
    for fn in (
        getattr(aot, kernel.feed_entry(method, emit_phi)),
        entries.compiled(kernel.feed_entry(method, emit_phi)),
    ):
        state = kernel.new_state(np.array([0.0, 0.6, 0.0, 0.8]), method)
        out = np.zeros((len(t) + 1, 4))
        k = fn(state, w, t, out)
        outs.append(out[:k])
        states.append(state)
    assert np.array_equal(outs[0].view(np.int64), outs[1].view(np.int64))
    assert np.array_equal(states[0].view(np.int64), states[1].view(np.int64))


def test_built_push_close_check_and_delta_equal_numba_compile():
    aot = _aot_or_skip()
    w, t = record(50, seed=9)
    t[30:] += 0.05  # a gap: the push says MAYBE_GAP
    for method in (int(Method.MAGNUS4), int(Method.CONING)):
        runs = []
        for push, close in (
            (getattr(aot, kernel.push_entry(method)), aot.close_magnus4),
            (entries.compiled(kernel.push_entry(method)), entries.compiled("close_magnus4")),
        ):
            state = kernel.new_state(np.array([0.0, 0.0, 0.0, 1.0]), method)
            codes = [push(state, w[k], float(t[k])) for k in range(len(t))]
            codes.append(push(state, w[0], float(t[0])))  # not after the last stamp
            if method == kernel.MAGNUS4:
                close(state, False)
            runs.append((codes, state))
        assert runs[0][0] == runs[1][0] and kernel.MAYBE_GAP in runs[0][0]
        assert runs[0][0][-1] == kernel.NOT_INCREASING
        assert np.array_equal(runs[0][1], runs[1][1])
    bad = w.copy()
    bad[7, 1] = np.nan
    assert aot.check_record(bad, t, -math.inf) == entries.compiled("check_record")(
        bad, t, -math.inf
    )
    for method in DeltaMethod:
        outs = []
        for fn in (aot.feed_delta, entries.compiled("feed_delta")):
            out = np.zeros((49, 4))
            fn(np.array([0.0, 0.0, 0.0, 1.0]), 1e-3 * w[:48], np.diff(t)[:48], int(method), out)
            outs.append(out)
        assert np.array_equal(outs[0], outs[1]), method.name


def test_numba_compiles_each_entry_point_for_one_signature():
    for name in ("check_record", kernel.feed_entry(kernel.MAGNUS4, False)):
        assert len(entries.compiled(name).signatures) == 1


def _batch(rng, n: int):
    """Two MCAP chunks of ``n`` message records each in one buffer (channels 1, 2, 3 in
    random turns, a 7-byte hole before the first record, 3 bytes after the last, and a hole
    between the chunks), with each chunk's message index per channel (offsets in the chunk)."""
    chunks, want, buf = [], {1: [], 2: [], 3: []}, np.zeros(0, np.uint8)
    for seq in (4, 9):
        buf = np.concatenate([buf, np.zeros(11, np.uint8)])  # the hole between chunks
        base = len(buf)
        lens = rng.integers(22, 80, n)  # record length field: 22 header bytes and a payload
        offs = np.concatenate([[0], np.cumsum(9 + lens)[:-1]]).astype(np.int64) + 7
        data = np.zeros(int(offs[-1] + 9 + lens[-1]) + 3, np.uint8)
        cid = rng.integers(1, 4, n)
        lt = rng.integers(0, 2**62, n)
        for o, ln, c, t in zip(offs, lens, cid, lt, strict=True):
            data[o] = 0x05
            data[o + 1 : o + 9] = np.frombuffer(int(ln).to_bytes(8, "little"), np.uint8)
            data[o + 9 : o + 11] = np.frombuffer(int(c).to_bytes(2, "little"), np.uint8)
            data[o + 15 : o + 23] = np.frombuffer(int(t).to_bytes(8, "little"), np.uint8)
            want[int(c)].append((base + o + 31, ln - 22, t, (seq << 32) + o))
        buf = np.concatenate([buf, data])
        index = {int(c): offs[cid == c] for c in (1, 2, 3)}
        chunks.append((base, len(data), seq, index, offs, lens))
    return buf, chunks, want


def _segments(chunks, cids=(1, 2, 3)):
    offs, seg, seg_chunk, seg_slot = [], [0], [], []
    for k, (_, _, _, index, _, _) in enumerate(chunks):
        for c, o in index.items():
            offs.append(o)
            seg.append(seg[-1] + len(o))
            seg_chunk.append(k)
            seg_slot.append(cids.index(c))
    bases, sizes, seqs = (np.array([ch[i] for ch in chunks], np.int64) for i in (0, 1, 2))
    return np.concatenate(offs), seg, seg_chunk, seg_slot, bases, sizes, seqs, list(cids)


@pytest.mark.parametrize("order", ["indexed", "an index out of order"])
def test_locate_batch_groups_every_record_by_channel_in_file_order(order):
    # The compiled location of a batch's indexed MCAP records: each channel's payloads (start,
    # length), log times and file-order keys, in file order, and the bytes no record covers
    rng = np.random.default_rng(7)
    buf, chunks, want = _batch(rng, 200)
    if order != "indexed":  # a writer that indexes in another order: sorted, the same result
        index = chunks[1][3]
        index[2] = index[2][::-1].copy()
    start, length, lt, key, bounds, gaps, bad = kernel.locate_batch(buf, *_segments(chunks))
    assert bad == -1
    for slot, c in enumerate((1, 2, 3)):
        got = np.stack([a[bounds[slot] : bounds[slot + 1]] for a in (start, length, lt, key)], 1)
        np.testing.assert_array_equal(got, np.array(want[c]))
    holes = [(b, b + 7) for b, *_ in chunks] + [(b + n - 3, b + n) for b, n, *_ in chunks]
    assert sorted(map(tuple, gaps.reshape(-1, 2).tolist())) == sorted(holes)


@pytest.mark.parametrize(
    "fault", ["opcode", "short length", "past the next", "past the chunk", "channel", "twice"]
)
def test_locate_batch_names_a_record_that_does_not_check_out(fault):
    # Any record that fails a check (its opcode, a length under the 22 header bytes or running
    # into the next record or out of its chunk, another channel than its index's, indexed twice)
    # is named, and the batch is then read chunk by chunk
    rng = np.random.default_rng(8)
    buf, chunks, _ = _batch(rng, 200)
    base, size, _, index, offs, lens = chunks[1]
    k = 117
    o = base + int(offs[k])
    if fault == "opcode":
        buf[o] = 0x06
    elif fault == "short length":
        buf[o + 1 : o + 9] = np.frombuffer((21).to_bytes(8, "little"), np.uint8)
    elif fault == "past the next":
        longer = int(lens[k]) + 1
        buf[o + 1 : o + 9] = np.frombuffer(longer.to_bytes(8, "little"), np.uint8)
    elif fault == "past the chunk":
        chunks[1] = (base, int(offs[k]) + 20, *chunks[1][2:])
    elif fault == "channel":
        buf[o + 9] = 1 + buf[o + 9] % 3
    else:
        index[1] = np.sort(np.concatenate([index[1], index[1][5:6]]))  # one record, twice
    assert kernel.locate_batch(buf, *_segments(chunks))[-1] >= 0


def test_an_out_of_date_built_kernel_is_not_used(monkeypatch):
    # A module built from other sources than these (an edited kernel) is left alone: numba
    # compiles instead, and the compile line says why.
    monkeypatch.setattr(loader, "_AOT", [])
    monkeypatch.setattr(loader, "digest_entry", lambda: "source_no_such_build")
    assert kernel.backend() == "jit"
    if "out of date" not in loader._AOT[1]:
        assert "no kernel built ahead of time" in loader._AOT[1]
    monkeypatch.setattr(loader, "_AOT", [])
    monkeypatch.setenv(loader.ENV, "jit")
    assert kernel.backend() == "jit" and "IMU_DCM_KERNEL=jit" in loader._AOT[1]


def test_the_digest_covers_every_file_the_entry_points_are_compiled_from():
    # A kernel file the digest left out could be edited without the built module going stale.
    modules = {fn.__module__ for fn, _ in entries.ENTRIES.values()}
    files = {Path(sys.modules[m].__file__).name for m in modules}
    assert files == {
        "integrator.py",
        "ulog_scan.py",
        "mcap_scan.py",
        "csv_scan.py",
        "series.py",
        "ros_fields.py",
    }
    shared = {"state.py", "field_steps.py", "entries.py", "jit.py"}  # what the kernels import
    assert files | shared == set(loader.KERNEL_SOURCES)


def _kernel_env(cache: Path, **extra: str) -> dict[str, str]:
    return {
        **os.environ,
        "NUMBA_CACHE_DIR": str(cache),
        "PYTHONPATH": os.pathsep.join(
            [str(Path(loader.__file__).parents[2]), os.environ.get("PYTHONPATH", "")]
        ),
        **extra,
    }


_RUN_BOTH = (
    "import sys, numpy as np, imu_dcm; w, t = np.zeros((9, 3)), 1e-3 * np.arange(9); "
    "imu_dcm.integrate(w, t, [0, 0, 0, 1]); integ = imu_dcm.DcmIntegrator([0, 0, 0, 1]); "
    "[integ.update(w[k], float(t[k])) for k in range(9)]; integ.finish(); "
    "print('numba' in sys.modules)"
)


def _run(code: str, env: dict[str, str]) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", code],
        env=env,
        capture_output=True,
        text=True,
        check=False,
        timeout=600,
    )


def test_compile_notice_once_on_a_cache_miss_and_never_from_the_cache(tmp_path):
    # Compiling with numba (forced here): an empty cache compiles, and says so once on stderr
    # before it does. The same cache again: it loads, silently.
    env = _kernel_env(tmp_path / "cache", IMU_DCM_KERNEL="jit")
    code = _RUN_BOTH + "; print('numba.pycc' in sys.modules)"
    runs = [_run(code, env) for _ in range(2)]
    assert [r.returncode for r in runs] == [0, 0], runs[0].stderr + runs[1].stderr
    # numba runs the kernel, and its ahead-of-time builder (pending deprecation, it warns on
    # import) is never loaded: only a build imports it
    assert [r.stdout.split() for r in runs] == [["True", "False"]] * 2
    notice = "compiling the integrator kernel once, about"
    assert runs[0].stderr.count(notice) == 1, runs[0].stderr
    assert "later runs load it from the cache (IMU_DCM_KERNEL=jit)" in runs[0].stderr
    assert_quiet(runs[1].stderr)


def test_the_built_kernel_runs_without_numba_and_without_a_compile_line(tmp_path):
    _aot_or_skip()
    res = _run(_RUN_BOTH, _kernel_env(tmp_path / "cache"))
    assert res.returncode == 0, res.stderr
    assert_quiet(res.stderr)
    assert res.stdout.strip() == "False"
    assert not (tmp_path / "cache").exists()  # nothing compiled, nothing cached


def test_no_writable_cache_folder_warns_once_and_still_imports(tmp_path):
    # A read-only install with no user cache either: numba finds no cache folder. The kernel
    # must still compile (in every process) and say so once. Simulated by allowing only
    # numba's NUMBA_CACHE_DIR locator and pointing it below a regular file.
    blocker = tmp_path / "file"
    blocker.write_text("")
    env = _kernel_env(blocker / "cache", NUMBA_CACHE_LOCATOR_CLASSES="UserProvidedCacheLocator")
    code = "import warnings; warnings.simplefilter('always'); import imu_dcm._kernels.entries"
    res = _run(code, env)
    assert res.returncode == 0, res.stderr
    assert res.stderr.count("NUMBA_CACHE_DIR") == 1 and "ImuDcmWarning" in res.stderr  # once


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


def test_record_chain_walks_ulog_framing_and_stops_at_an_incomplete_record():
    # [uint16 size][uint8 type] headers: sizes 2, 0 and 300 (little endian), then a header whose
    # record runs past the end. Positions and types by hand; both loaders agree.
    records = [(2, 65), (0, 66), (300, 68)]
    buf = bytearray()
    for size, typ in records:
        buf += bytes([size & 0xFF, size >> 8, typ]) + bytes(size)
    end = len(buf)
    buf += bytes([9, 0, 70, 1, 2])  # incomplete
    b = np.frombuffer(bytes(buf), np.uint8)  # read-only, as the reader passes it
    at, typ, stop = kernel.record_chain(b, 0)
    assert at.tolist() == [0, 5, 8] and typ.tolist() == [65, 66, 68] and stop == end
    jit = entries.compiled("record_chain")(np.array(b), 0)
    assert [a.tolist() for a in jit[:2]] == [at.tolist(), typ.tolist()] and jit[2] == stop
    with pytest.raises(TypeError, match="uint8"):
        kernel.record_chain(b.astype(np.int16), 0)


def test_a_failed_build_is_one_line_and_leaves_no_module(tmp_path):
    # The build's errors (numba, the C compiler, the disk) come out as one line, exit 1; here
    # the output folder cannot be made (a regular file stands in its way).
    blocker = tmp_path / "file"
    blocker.write_text("")
    out = str(blocker / "x")
    code = (
        f"import sys; from imu_dcm._kernels.build import main; sys.exit(main(['--out', {out!r}]))"
    )
    res = _run(code, _kernel_env(tmp_path / "cache"))
    assert res.returncode == 1, res.stderr
    lines = own_stderr(res.stderr).strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("imu_dcm: the kernel was not built:"), lines
    assert "Traceback" not in res.stderr and not list(tmp_path.rglob("*_aot*"))

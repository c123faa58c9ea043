"""The rerun view: what lands in the .rrd (read back with rerun's own RrdReader), and the modes.

Truth for the geometry is scipy's Rotation (an independent implementation): the arrows of a body
axis must equal the columns of ``Rotation.from_quat(q_w_b).as_matrix()``.
"""

from __future__ import annotations

import math
import sys

import numpy as np
import pytest
from conftest import raises_naming
from scipy.spatial.transform import Rotation

from imu_dcm import viz
from imu_dcm.errors import InputError
from imu_dcm.viz import ENTITY, TIMELINE, ViewData, gyro_needs_split, save_rrd, show_replay

RATE_HZ = 100.0
N = 200  # 2 s at 100 Hz
GAP = slice(50, 70)  # samples without truth
NO_EST = slice(0, 5)  # samples before the estimate starts (the replay starts it at the truth)

# The boundary case every convention test carries: 90° about z, [x, y, z, w] = [0, 0, √½, √½];
# body x must point along world y.
Q_90Z = np.array([0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)])


def _view(omega_raw: bool = False, n: int = N) -> ViewData:
    """Constant-rate rotation about a tilted axis, truth exact, estimate off by a known 3° yaw."""
    rng = np.random.default_rng(7)
    t_s = 12.5 + np.arange(n) / RATE_HZ  # stamps need not start at 0
    axis = np.array([0.3, -0.2, 0.93]) / np.linalg.norm([0.3, -0.2, 0.93])
    rate_rad_s = 2.0
    truth = Rotation.from_quat(Q_90Z) * Rotation.from_rotvec(
        (t_s - t_s[0])[:, None] * rate_rad_s * axis
    )
    est = Rotation.from_euler("z", 3.0, degrees=True) * truth
    q_est = est.as_quat()
    q_est[NO_EST] = np.nan
    q_truth = truth.as_quat()
    q_truth[GAP] = np.nan
    omega_b = np.tile(rate_rad_s * axis, (n, 1))
    err = np.full(n, 3.0)
    err[GAP] = np.nan
    return ViewData(
        t_s=t_s,
        q_est=q_est,
        q_truth=q_truth,
        omega_b=omega_b,
        error_total_deg=err,
        error_inclination_deg=np.where(np.isnan(err), np.nan, 0.0),
        error_heading_deg=err,
        title="unit test/view",
        omega_raw_b=omega_b + rng.normal(0.0, 0.01, (n, 3)) if omega_raw else None,
    )


def _read(path) -> dict[str, dict]:
    """Every entity of the first recording: static columns, and time-indexed rows sorted by time."""
    from rerun.chunk import RrdReader

    out: dict[str, dict] = {}
    for chunk in RrdReader(path).stream():
        batch = chunk.to_record_batch()
        entry = out.setdefault(chunk.entity_path, {"static": {}, "rows": {}})
        if chunk.is_static:
            for name in batch.schema.names:
                entry["static"][name] = batch.column(name).to_pylist()
            continue
        for name in batch.schema.names:
            col = batch.column(name)
            if name == TIMELINE:
                col = col.cast("int64")  # durations as integer ns
            entry["rows"].setdefault(name, []).extend(col.to_pylist())
    for entry in out.values():
        rows = entry["rows"]
        if TIMELINE in rows:
            order = np.argsort(rows[TIMELINE], kind="stable")
            for name in rows:
                rows[name] = [rows[name][k] for k in order]
    return out


@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    view = _view(omega_raw=True)
    path = save_rrd(view, tmp_path_factory.mktemp("rrd") / "view.rrd")
    return view, path, _read(path)


def _time_ns(rows) -> np.ndarray:
    return np.array(rows[TIMELINE], dtype=np.int64)


def test_entity_paths_and_one_row_per_sample(saved):
    view, path, data = saved
    per_sample = [
        ENTITY["errors"],
        *(ENTITY[f"gyro_{a}"] for a in "xyz"),
        *(ENTITY[f"gyro_raw_{a}"] for a in "xyz"),
    ]
    for key in per_sample:
        assert key in data, f"missing entity {key}; found {sorted(data)}"
        t_ns = _time_ns(data[key]["rows"])
        assert len(t_ns) == N, key
        # Timeline = time since the first stamp, stored as integer ns (rounded).
        expected = (view.t_s - view.t_s[0]) * 1e9
        assert np.all(np.abs(t_ns - expected) <= 0.5 + 1e-6), key
    # The 3D axes: one row per 1/AXES_HZ s of log time (the last sample at or before each
    # frame time) and the last sample, so a long log's view stays bounded.
    rel = view.t_s - view.t_s[0]
    frames = np.arange(math.floor(rel[-1] * viz.AXES_HZ) + 1) / viz.AXES_HZ
    expected_rows = sorted({int(np.flatnonzero(rel <= f)[-1]) for f in frames} | {N - 1})
    assert len(expected_rows) < N
    for key in (ENTITY["truth_axes"], ENTITY["estimate_axes"]):
        t_ns = _time_ns(data[key]["rows"])
        np.testing.assert_allclose(t_ns, rel[expected_rows] * 1e9, rtol=0, atol=0.5 + 1e-6)
    for key in ("truth_trail", "estimate_trail", "truth_trace", "estimate_trace"):
        assert ENTITY[key] in data
    from rerun.chunk import RrdReader

    assert RrdReader(path).blueprints(), "the layout (blueprint) must be saved with the data"


def test_axes_are_the_columns_of_r_w_b(saved):
    view, _, data = saved
    rows = data[ENTITY["truth_axes"]]["rows"]
    has_truth = np.ones(N, bool)
    has_truth[GAP] = False
    # each row's sample, from its own stamp (the axes are thinned to AXES_HZ)
    sample = np.rint(_time_ns(rows) * 1e-9 * RATE_HZ).astype(int)
    assert sample[0] == 0 and sample[-1] == N - 1
    assert np.any(~has_truth[sample]), "a thinned row falls in the truth gap"
    for row, k in enumerate(sample):
        vectors = rows["Arrows3D:vectors"][row]
        if not has_truth[k]:
            # No truth: an empty row (clears the arrows), never a stale or invented attitude.
            assert vectors == [], k
            continue
        R = Rotation.from_quat(view.q_truth[k]).as_matrix()
        # float32 storage: 1e-6 relative is the rounding of unit vectors.
        np.testing.assert_allclose(np.array(vectors), R.T, atol=2e-6)
    # At t = 0 the truth is 90° about z: body x along world y, body y along world -x.
    np.testing.assert_allclose(rows["Arrows3D:vectors"][0][0], [0, 1, 0], atol=2e-6)
    np.testing.assert_allclose(rows["Arrows3D:vectors"][0][1], [-1, 0, 0], atol=2e-6)
    est_rows = data[ENTITY["estimate_axes"]]["rows"]
    est = est_rows["Arrows3D:vectors"]
    est_sample = np.rint(_time_ns(est_rows) * 1e-9 * RATE_HZ).astype(int)
    started = est_sample >= NO_EST.stop
    assert not started.all() and started.any()
    assert all(row == [] for row, s in zip(est, started, strict=True) if not s)  # no arrows yet
    for row, k in enumerate(est_sample):
        if started[row]:
            R = Rotation.from_quat(view.q_est[k]).as_matrix()
            np.testing.assert_allclose(np.array(est[row]), R.T, atol=2e-6)


def test_error_and_gyro_series_round_trip(saved):
    view, _, data = saved
    errors = np.array(data[ENTITY["errors"]]["rows"]["Scalars:scalars"], dtype=float)
    assert errors.shape == (N, 3)
    expected = np.stack(
        [view.error_total_deg, view.error_inclination_deg, view.error_heading_deg], axis=1
    )
    np.testing.assert_array_equal(np.isnan(errors), np.isnan(expected))  # gaps stay gaps
    np.testing.assert_allclose(errors[~np.isnan(errors)], expected[~np.isnan(expected)])
    names = data[ENTITY["errors"]]["static"]["SeriesLines:names"][0]
    assert names == ["total", "inclination", "heading"]
    for k, a in enumerate("xyz"):
        got = np.array(data[ENTITY[f"gyro_{a}"]]["rows"]["Scalars:scalars"], dtype=float)
        np.testing.assert_allclose(got[:, 0], view.omega_b[:, k])
        raw = np.array(data[ENTITY[f"gyro_raw_{a}"]]["rows"]["Scalars:scalars"], dtype=float)
        np.testing.assert_allclose(raw[:, 0], view.omega_raw_b[:, k])


def test_trailing_window_of_the_z_tip(saved):
    view, _, data = saved
    rows = data[ENTITY["estimate_trail"]]["rows"]
    t_ns = _time_ns(rows)
    # One frame per 1/30 s of log time over 1.99 s: frames at 0, 1/30, ..., 59/30 s.
    span_s = view.t_s[-1] - view.t_s[0]
    assert len(t_ns) == math.floor(span_s * viz.TRAIL_FPS) + 1
    rel = view.t_s - view.t_s[0]
    q_est = np.where(np.isnan(view.q_est), [0.0, 0.0, 0.0, 1.0], view.q_est)
    tip = Rotation.from_quat(q_est).apply([0.0, 0.0, 1.0])  # body z in world (oracle)
    for k in (10, 30, len(t_ns) - 1):
        strip = np.array(rows["LineStrips3D:strips"][k][0])
        end = int(np.argmin(np.abs(rel * 1e9 - t_ns[k])))
        # The strip runs from the tip TRAIL_S before the frame (or the first estimate, if later)
        # to the tip at the frame. Windows here span < TRAIL_POINTS samples: none is skipped.
        start = max(int(np.searchsorted(rel, rel[end] - viz.TRAIL_S)), NO_EST.stop)
        np.testing.assert_allclose(strip[0], tip[start], atol=2e-6)
        np.testing.assert_allclose(strip[-1], tip[end], atol=2e-6)
        np.testing.assert_allclose(np.linalg.norm(strip, axis=1), 1.0, atol=2e-6)
    # Trails leave out samples without an attitude (no NaN points reach the viewer): frames at
    # 0 and 1/30 s end at samples 0 and 3, before the estimate starts (sample 5), so they are
    # empty; the frame at 2/30 s (sample 6) starts at the first estimate.
    assert rows["LineStrips3D:strips"][0] in ([], [[]])
    assert rows["LineStrips3D:strips"][1] in ([], [[]])
    np.testing.assert_allclose(rows["LineStrips3D:strips"][2][0][0], tip[NO_EST.stop], atol=2e-6)
    for key in ("truth_trail", "estimate_trail"):
        for strip in data[ENTITY[key]]["rows"]["LineStrips3D:strips"]:
            for s in strip:
                assert np.all(np.isfinite(np.array(s, dtype=float)))


def test_realtime_sends_the_same_rows_in_chunks(tmp_path, monkeypatch):
    import rerun as rr

    sleeps: list[float] = []
    monkeypatch.setattr("imu_dcm.viz.log.time.sleep", sleeps.append)  # pacing without waiting
    view = _view()
    rec = rr.RecordingStream("imu_dcm_test")
    path = tmp_path / "rt.rrd"
    rec.save(path)
    viz.send_view(view, rec, realtime=True, chunk_s=0.25)
    rec.flush()
    rec.disconnect()
    live = _read(path)
    whole = _read(save_rrd(view, tmp_path / "whole.rrd"))
    for key in (ENTITY["truth_axes"], ENTITY["errors"], ENTITY["gyro_z"], ENTITY["truth_trail"]):
        assert _time_ns(live[key]["rows"]).tolist() == _time_ns(whole[key]["rows"]).tolist()
        for name, col in whole[key]["rows"].items():
            if name != "rerun.controls.RowId":
                assert repr(live[key]["rows"][name]) == repr(col), (key, name)  # NaN-safe
    # 1.99 s in 0.25 s chunks: 8 chunks, a sleep after each one that finished early.
    assert 1 <= len(sleeps) <= 8


def test_view_data_rejects_bad_input():
    good = _view()
    fields = dict(good.__dict__)
    with raises_naming(InputError, "q_est", "(200, 4)", "(200, 3)"):
        ViewData(**{**fields, "q_est": good.q_est[:, :3]})
    with raises_naming(InputError, "error_heading_deg", "(200)", "(199,)"):
        ViewData(**{**fields, "error_heading_deg": good.error_heading_deg[:-1]})
    t = good.t_s.copy()
    t[5] = t[4]
    with pytest.raises(InputError, match=r"strictly increasing, got t_s\[5\]"):
        ViewData(**{**fields, "t_s": t})
    with raises_naming(InputError, "title", "''"):
        ViewData(**{**fields, "title": ""})
    # InputError is also a ValueError (callers may catch either).
    with pytest.raises(ValueError):
        ViewData(**{**fields, "omega_b": good.omega_b[:, :2]})


def test_modes(tmp_path, monkeypatch):
    view = _view(n=40)
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    if sys.platform.startswith("linux"):
        # No display: the default writes nothing and names the two ways to see the view.
        line = show_replay(view, None, tmp_path)
        assert list(tmp_path.iterdir()) == []
        assert "--rerun serve" in line and "--rerun save:" in line and "127.0.0.1" in line
        with raises_naming(InputError, "DISPLAY", "WAYLAND_DISPLAY", "'spawn'"):
            show_replay(view, "spawn", tmp_path)
    assert show_replay(view, "off", tmp_path) == ""
    target = tmp_path / "sub" / "x.rrd"
    line = show_replay(view, f"save:{target}", tmp_path)
    assert target.is_file() and f"rerun {target}" in line
    for bad in ("web", "save:", "save:out.txt", "SPAWN", 3):
        with raises_naming(InputError, "mode", repr(bad)):
            show_replay(view, bad, tmp_path)
    assert not list(tmp_path.glob(".*.tmp")), "no temporary file left behind"


def test_gyro_layout_splits_only_when_a_channel_would_be_squashed():
    t = np.linspace(0.0, 5.0, 1000)
    wobble = 7.0 * np.sin(2 * np.pi * 4.0 * t)
    # A spinning top: ω_z ≈ 125 rad/s constant, ω_x,y ±7 rad/s (squashed on a shared axis).
    top = np.stack([wobble, np.cos(2 * np.pi * 4.0 * t) * 7.0, 125.0 + 0.0 * t], axis=1)
    assert gyro_needs_split(top)
    # Three channels of the same amplitude around 0: one shared plot.
    hand = np.stack([wobble, 0.8 * wobble[::-1], 8.0 * np.cos(3.0 * t)], axis=1)
    assert not gyro_needs_split(hand)


def test_serve_mode_serves_the_web_viewer_on_loopback(tmp_path):
    import os
    import re
    import signal
    import urllib.request

    line = show_replay(_view(n=40), "serve", tmp_path)
    # its temporary .rrd lies under the folder given (tests write only under tmp_path)
    (folder,) = [p for p in tmp_path.iterdir() if p.name.startswith("imu_dcm_rerun_")]
    assert [p.suffix for p in folder.iterdir()] == [".rrd"]
    m = re.search(r"web viewer at (http://127\.0\.0\.1:(\d+)/\?url=\S+) .*kill (\d+);", line)
    assert m, line
    url, pid = m.group(1), int(m.group(3))
    try:
        # The page is the viewer, pointed at the gRPC proxy on 127.0.0.1 too.
        assert "rerun%2Bhttp%3A%2F%2F127.0.0.1%3A" in url
        with urllib.request.urlopen(f"http://127.0.0.1:{m.group(2)}/", timeout=10) as page:
            assert page.status == 200
            assert b"<html" in page.read(4096).lower()
    finally:
        os.killpg(pid, signal.SIGTERM)  # the server runs in its own process group
        os.waitpid(pid, 0)


def test_a_kept_web_viewer_stops_with_the_one_kill_it_names_and_leaves_nothing(tmp_path):
    import os
    import re
    import socket
    import time

    line = show_replay(_view(n=40), "serve", tmp_path)
    m = re.search(r"stop it with: kill (\d+);.*ssh -L (\d+):127\.0\.0\.1:\2 -L (\d+):127", line)
    assert m, line
    pid, ports = int(m.group(1)), (int(m.group(2)), int(m.group(3)))
    (folder,) = [p for p in tmp_path.iterdir() if p.name.startswith("imu_dcm_rerun_")]
    for port in ports:  # both ports listen, on loopback
        socket.create_connection(("127.0.0.1", port), timeout=5).close()
    os.kill(pid, 15)  # what the line says: SIGTERM to that one pid, not to its group
    os.waitpid(pid, 0)
    deadline = time.monotonic() + 10
    while folder.exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not folder.exists()  # its temporary .rrd is gone with it
    for port in ports:  # and the server itself, not only its keeper
        with pytest.raises(OSError), socket.create_connection(("127.0.0.1", port), timeout=2):
            pass

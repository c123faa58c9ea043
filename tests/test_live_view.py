"""The live view: what its batches put in the .rrd, read back with rerun's own RrdReader.

The live view builds its columns' arrow arrays itself (cheaper than rerun's archetype builders)
and sends the axes' and trails' colours, radii and labels once, statically. Checked here against
independent truth: the arrows of a body axis equal the columns of scipy's
``Rotation.from_quat(q_w_b).as_matrix()``, the scalars equal the values fed, the stamps are the
fed times rounded to the ns, and the static styles are replay's values.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from test_viz import _read, _time_ns

from imu_dcm.viz import ENTITY
from imu_dcm.viz.live import LiveView
from imu_dcm.viz.log import EST_RGB, TRUTH_RGB

Q_90Z = np.array([0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)])  # body x along world y
RATE_HZ = 1000.0


def _motion(n: int):
    t_s = np.arange(n) / RATE_HZ
    rot = Rotation.from_quat(Q_90Z) * Rotation.from_rotvec(
        np.stack([0.4 * np.sin(3 * t_s), 0.2 * t_s, 1.5 * t_s], axis=1)
    )
    rng = np.random.default_rng(3)
    return t_s, rot.as_quat(), rng.normal(size=(n, 3)), rng.uniform(0, 5, size=(n, 3))


@pytest.fixture(scope="module")
def live_rrd(tmp_path_factory):
    """Half a second at 1 kHz in 25 batches of 20 rows, as the live pipeline flushes them."""
    path = tmp_path_factory.mktemp("live_view") / "live.rrd"
    n, rows = 500, 20
    t_s, q, w, err = _motion(n)
    view = LiveView(f"save:{path}", title="live test", say=lambda line: None)
    for a in range(0, n, rows):
        s = slice(a, a + rows)
        view.log(
            gyro_t_s=t_s[s],
            omega_b=w[s],
            est_t_s=t_s[s],
            q_est=q[s],
            truth_t_s=t_s[s],
            q_truth=q[s],
            err_t_s=t_s[s],
            err_deg=err[s],
        )
    view.close()
    return (t_s, q, w, err), _read(path)


def test_scalars_are_every_row_fed(live_rrd):
    (t_s, _, w, err), data = live_rrd
    want_ns = np.rint(t_s * 1e9).astype(np.int64)
    rows = data[ENTITY["gyro"]]["rows"]  # x, y, z: three series of one entity
    assert _time_ns(rows).tolist() == want_ns.tolist()
    np.testing.assert_array_equal(np.array(rows["Scalars:scalars"], dtype=float), w)
    names = data[ENTITY["gyro"]]["static"]["SeriesLines:names"]
    assert names == [["ω_x", "ω_y", "ω_z"]]
    rows = data[ENTITY["errors"]]["rows"]
    assert _time_ns(rows).tolist() == want_ns.tolist()
    np.testing.assert_array_equal(np.array(rows["Scalars:scalars"], dtype=float), err)


def test_axes_are_the_rotation_matrix_columns(live_rrd):
    (t_s, q, _, _), data = live_rrd
    for key in ("estimate_axes", "truth_axes"):
        rows = data[ENTITY[key]]["rows"]
        t_ns = _time_ns(rows)
        assert len(t_ns) >= 25  # thinned to AXES_HZ rows per second of source time
        for k in (0, len(t_ns) // 2, len(t_ns) - 1):
            i = int(np.flatnonzero(np.rint(t_s * 1e9).astype(np.int64) == t_ns[k])[0])
            arrows = np.array(rows["Arrows3D:vectors"][k], dtype=float)
            matrix = Rotation.from_quat(q[i]).as_matrix()  # oracle: columns are the body axes
            np.testing.assert_allclose(arrows, matrix.T, atol=1e-6)  # float32 vectors
        first = np.array(rows["Arrows3D:vectors"][0], dtype=float)
        np.testing.assert_allclose(first[0], [0.0, 1.0, 0.0], atol=1e-6)  # 90 deg about z


def test_trail_ends_at_the_newest_z_tip(live_rrd):
    (t_s, q, _, _), data = live_rrd
    rows = data[ENTITY["truth_trail"]]["rows"]
    t_ns = _time_ns(rows)
    strip = np.array(rows["LineStrips3D:strips"][-1][0], dtype=float)
    i = int(np.flatnonzero(np.rint(t_s * 1e9).astype(np.int64) == t_ns[-1])[0])
    np.testing.assert_allclose(strip[-1], Rotation.from_quat(q[i]).apply([0, 0, 1]), atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(strip, axis=1), 1.0, atol=1e-6)


def test_axes_and_trail_styles_are_static_and_replays(live_rrd):
    _, data = live_rrd
    est = data[ENTITY["estimate_axes"]]["static"]
    truth = data[ENTITY["truth_axes"]]["static"]
    rgba = [int.from_bytes(bytes([*c, 255]), "big") for c in EST_RGB.tolist()]
    assert est["Arrows3D:colors"] == [rgba]
    assert truth["Arrows3D:labels"] == [["x", "y", "z"]]
    rgba = [int.from_bytes(bytes([*c, 255]), "big") for c in TRUTH_RGB.tolist()]
    assert truth["Arrows3D:colors"] == [rgba]
    np.testing.assert_allclose(truth["Arrows3D:radii"], [[0.035]], rtol=1e-6)
    assert "LineStrips3D:colors" in data[ENTITY["estimate_trail"]]["static"]

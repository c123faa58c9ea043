"""The peer integrators of ``imu_dcm.integrator.peers`` follow this project's conventions.

A constant-axis rotation has an exact answer, ``q_w_b(t) = q0 ⊗ exp(ω t)``, so it checks each
peer's quaternion order, sign and side of multiplication (with a non-identity ``q0``, a peer that
multiplied on the left would be off by the angle between ``q0 ⊗ p`` and ``p ⊗ q0``, here > 0.5 rad).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

pytest.importorskip("ahrs")
pytest.importorskip("imufusion")
pytest.importorskip("vqf")

from imu_dcm.integrator.peers import PEERS

# Exact-exponential peers in float64 over ~1000 steps: rounding only, ~1000 * 1e-16 rad.
EXACT_TOL_RAD = 1e-12
# imufusion works in float32 (unit roundoff 6e-8) with a first-order, renormalised step
# (per-step angle error θ³/12 = 3e-10 rad here): 1000 steps give at most ~1000 * 6e-8 = 6e-5 rad.
FLOAT32_TOL_RAD = 1e-4


def _angle_rad(q_a, q_b):
    return (Rotation.from_quat(q_a).inv() * Rotation.from_quat(q_b)).magnitude()


@pytest.mark.parametrize("name", list(PEERS))
@pytest.mark.parametrize("axis", [(1.0, 0.0, 0.0), (0.0, 0.0, 1.0), (0.6, -0.48, 0.64)])
def test_peer_tracks_constant_axis_rotation(name, axis):
    q0 = Rotation.from_euler("xyz", [0.3, -0.5, 1.1]).as_quat()
    rate = 0.5 * np.pi  # rad/s, 90 deg over the 1 s record
    n = 1001
    t_s = np.linspace(0.0, 1.0, n)
    omega_b = np.tile(rate * np.asarray(axis), (n, 1))
    truth = (Rotation.from_quat(q0) * Rotation.from_rotvec(np.outer(rate * t_s, axis))).as_quat()
    peer = PEERS[name]
    q = peer.fn(omega_b, t_s, q0)
    assert q.shape == (n, 4)
    np.testing.assert_allclose(q[0], q0, atol=1e-6)
    tol = FLOAT32_TOL_RAD if name == "imufusion_gain0" else EXACT_TOL_RAD
    assert _angle_rad(q, truth).max() <= tol
    # The left-multiplied answer exp(ω t) ⊗ q0 is far away: the check above can fail.
    wrong = (Rotation.from_rotvec(np.outer(rate * t_s, axis)) * Rotation.from_quat(q0)).as_quat()
    assert _angle_rad(q[-1:], wrong[-1:])[0] > 0.5


@pytest.mark.parametrize("name", list(PEERS))
def test_peer_90_deg_about_z_is_scalar_last(name):
    # 90 deg about world z from the identity is [0, 0, sqrt(1/2), sqrt(1/2)] in [x, y, z, w].
    n = 501
    t_s = np.linspace(0.0, 1.0, n)
    omega_b = np.tile([0.0, 0.0, 0.5 * np.pi], (n, 1))
    q = PEERS[name].fn(omega_b, t_s, np.array([0.0, 0.0, 0.0, 1.0]))
    tol = 1e-4 if name == "imufusion_gain0" else 1e-12
    np.testing.assert_allclose(
        np.sign(q[-1, 3]) * q[-1], [0, 0, np.sqrt(0.5), np.sqrt(0.5)], atol=tol
    )


def test_peers_table_is_complete():
    assert set(PEERS) == {
        "reference_loop",
        "scipy_loop",
        "ahrs_angular_rate",
        "imufusion_gain0",
        "vqf_batch",
        "vqf_update_gyr",
    }
    assert all(p.order == "first" and p.description for p in PEERS.values())

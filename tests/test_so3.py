"""Rotation maths against scipy Rotation as the independent oracle."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from imu_dcm.errors import InputError
from imu_dcm.so3 import as_quat_xyzw, exp_matrix, exp_quat, quat_multiply, quat_rotate

SQRT_HALF = np.sqrt(0.5)


def test_90_deg_about_z_is_xyzw_0_0_r_r():
    q = exp_quat([0.0, 0.0, np.pi / 2])
    np.testing.assert_allclose(q, [0.0, 0.0, SQRT_HALF, SQRT_HALF], atol=1e-15)
    # body x maps to world y under an active 90 deg yaw
    np.testing.assert_allclose(quat_rotate(q, [1.0, 0.0, 0.0]), [0.0, 1.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(exp_matrix([0.0, 0.0, np.pi / 2])[:, 0], [0.0, 1.0, 0.0], atol=1e-15)


def test_exp_and_product_match_scipy():
    rng = np.random.default_rng(1)
    a, b = rng.normal(size=(2, 100, 3))
    qa, qb = exp_quat(a), exp_quat(b)
    ra, rb = Rotation.from_rotvec(a), Rotation.from_rotvec(b)
    np.testing.assert_allclose(exp_matrix(a), ra.as_matrix(), atol=1e-14)
    got = Rotation.from_quat(quat_multiply(qa, qb))
    assert np.max((got.inv() * (ra * rb)).magnitude()) < 1e-14


def test_as_quat_rejects_bad_attitudes():
    with pytest.raises(InputError, match="shape"):
        as_quat_xyzw(np.zeros(3))
    with pytest.raises(InputError, match="rotation matrix"):
        as_quat_xyzw(2 * np.eye(3))

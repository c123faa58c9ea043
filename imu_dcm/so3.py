"""Rotation maths on SO(3): pure, vectorised functions over leading axes.

Conventions (README, "Frames and units"), the same in every function here:

* Rotations are **active**. ``R_w_b`` maps body coordinates to world, ``v_w = R_w_b @ v_b``;
  its columns are the body axes expressed in world coordinates.
* Quaternions are Hamilton, **scalar-last** ``[x, y, z, w]`` (the order of scipy ``Rotation``,
  ROS messages and rerun). ``q`` and ``-q`` are the same rotation.
* A rotation vector ``phi`` (rad) is axis times angle; ``exp(phi)`` rotates by ``|phi|`` about
  ``phi / |phi|`` by the right-hand rule. Body increments multiply on the **right**:
  ``R_{i+1} = R_i @ exp(phi_i)``, ``q_{i+1} = q_i ⊗ exp(phi_i)``.

Arrays have shapes ``(..., 3)`` (vectors), ``(..., 4)`` (quaternions) and ``(..., 3, 3)``
(matrices); every leading shape, including ``()``, is accepted and kept.
"""

from __future__ import annotations

import math
import sys
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imu_dcm.arrays import row_norm
from imu_dcm.errors import InputError

if TYPE_CHECKING:
    from scipy.spatial.transform import Rotation

__all__ = [
    "angle_between_deg",
    "as_quat_xyzw",
    "exp_matrix",
    "exp_quat",
    "hat",
    "log_quat",
    "product_planes",
    "quat_angle_rad",
    "quat_as_matrix",
    "quat_checked_norm",
    "quat_conjugate",
    "quat_from_matrix",
    "quat_multiply",
    "quat_normalize",
    "quat_rotate",
]

#: Below this angle (rad) the Taylor branches of exp_matrix and log_quat (here and in the compiled
#: kernels of attitude series) are used: their truncation error (theta^6/5040 for sin(x)/x) is
#: far below double precision there, and they avoid 0/0.
SMALL_ANGLE_RAD = 1e-3
#: exp(φ) as a quaternion (here and in the compiled kernel): up to this θ² (θ <= 0.5 rad), seven
#: Taylor terms of sin(θ/2)/θ and cos(θ/2) in θ²; the first terms left out, θ¹⁴/(2¹⁵ 15!) < 2e-21
#: and θ¹⁴/(4⁷ 14!) < 5e-20, are far below double rounding. Above, sin and cos.
SERIES_THETA2 = 0.25
#: Coefficients of θ^(2k), k = 0..6, of sin(θ/2)/θ = Σ (-1)^k θ^(2k) / (2^(2k+1) (2k+1)!).
SINC_HALF_SERIES = tuple(
    (-1) ** k / (2 ** (2 * k + 1) * math.factorial(2 * k + 1)) for k in range(7)
)
#: Coefficients of θ^(2k), k = 0..6, of cos(θ/2) = Σ (-1)^k θ^(2k) / (4^k (2k)!).
COS_HALF_SERIES = tuple((-1) ** k / (4**k * math.factorial(2 * k)) for k in range(7))


#: Multiplying by this conjugates ``[x, y, z, w]`` (a sign flip is exact).
_CONJUGATE = np.array([-1.0, -1.0, -1.0, 1.0])


#: The Hamilton product ``p ⊗ q`` component by component: ``(i, j, sign)`` terms
#: ``sign p_i q_j`` of x, y, z and w, in order (indices into ``[x, y, z, w]``).
_PRODUCT = (
    ((3, 0, 1), (0, 3, 1), (1, 2, 1), (2, 1, -1)),
    ((3, 1, 1), (0, 2, -1), (1, 3, 1), (2, 0, 1)),
    ((3, 2, 1), (0, 1, 1), (1, 0, -1), (2, 3, 1)),
    ((3, 3, 1), (0, 0, -1), (1, 1, -1), (2, 2, -1)),
)


def _horner(t2: NDArray, coefs: tuple) -> NDArray:
    acc = np.full_like(t2, coefs[-1])
    for c in coefs[-2::-1]:
        acc = acc * t2 + c
    return acc


def hat(v: ArrayLike) -> NDArray[np.float64]:
    """Skew-symmetric matrix ``[v×]`` with ``hat(v) @ u == cross(v, u)``.

    Parameters
    ----------
    v : array_like, shape (..., 3)

    Returns
    -------
    ndarray, shape (..., 3, 3)
    """
    v = np.asarray(v, dtype=float)
    out = np.zeros(v.shape + (3,))
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    out[..., 0, 1], out[..., 0, 2] = -z, y
    out[..., 1, 0], out[..., 1, 2] = z, -x
    out[..., 2, 0], out[..., 2, 1] = -y, x
    return out


def _planes(a: ArrayLike) -> NDArray[np.float64]:
    """The components of ``(..., k)`` values as contiguous planes ``(k, ...)``: numpy is several
    times slower on the strided columns of an ``(N, k)`` array."""
    return np.ascontiguousarray(np.moveaxis(np.asarray(a, dtype=float), -1, 0))


def _rows(planes: NDArray[np.float64]) -> NDArray[np.float64]:
    """Planes ``(k, ...)`` back to a C-contiguous ``(..., k)`` array."""
    return np.ascontiguousarray(np.moveaxis(planes, 0, -1))


def _half_angle_terms(t2: NDArray[np.float64]) -> tuple[NDArray, NDArray]:
    """Return ``sin(θ/2)/θ`` and ``cos(θ/2)`` for ``θ² = t2``, exact near zero (the sine and
    cosine are evaluated only when some ``θ`` is beyond the series)."""
    small = t2 <= SERIES_THETA2
    sinc_half = _horner(t2, SINC_HALF_SERIES)
    cos_half = _horner(t2, COS_HALF_SERIES)
    if not np.all(small):
        theta = np.sqrt(np.where(small, 1.0, t2))
        sinc_half = np.where(small, sinc_half, np.sin(0.5 * theta) / theta)
        cos_half = np.where(small, cos_half, np.cos(0.5 * theta))
    return sinc_half, cos_half


def exp_quat(phi: ArrayLike) -> NDArray[np.float64]:
    """Quaternion ``exp(phi)`` of a rotation vector, exact (series up to 0.5 rad).

    Parameters
    ----------
    phi : array_like, shape (..., 3)
        Rotation vector, rad.

    Returns
    -------
    ndarray, shape (..., 4)
        Unit quaternion ``[x, y, z, w]`` with ``w >= 0`` for ``|phi| <= π``.
    """
    x, y, z = P = _planes(phi)
    s, c = _half_angle_terms(x * x + y * y + z * z)
    out = np.empty((4,) + c.shape)
    out[:3] = P * s
    out[3] = c
    return _rows(out)


def exp_matrix(phi: ArrayLike) -> NDArray[np.float64]:
    """Rotation matrix ``exp([phi×])`` by Rodrigues' formula (the Cayley–Klein matrix ``CK``).

    ``R = I + sin θ/θ [φ×] + (1 − cos θ)/θ² [φ×]²``, with Taylor branches for tiny ``θ``.

    Parameters
    ----------
    phi : array_like, shape (..., 3)
        Rotation vector, rad.

    Returns
    -------
    ndarray, shape (..., 3, 3)
    """
    phi = np.asarray(phi, dtype=float)
    theta2 = np.einsum("...i,...i->...", phi, phi)
    theta = np.sqrt(theta2)
    small = theta < SMALL_ANGLE_RAD
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta2 / 6.0 + theta2 * theta2 / 120.0, np.sin(safe) / safe)
    b = np.where(
        small, 0.5 - theta2 / 24.0 + theta2 * theta2 / 720.0, (1.0 - np.cos(safe)) / (safe * safe)
    )
    K = hat(phi)
    return np.eye(3) + a[..., None, None] * K + b[..., None, None] * (K @ K)


def log_quat(q: ArrayLike) -> NDArray[np.float64]:
    """Rotation vector of a unit quaternion, the inverse of :func:`exp_quat`.

    The result has angle in ``[0, π]`` (``q`` and ``-q`` give the same vector, except exactly
    at ``π`` where both ``±axis·π`` are valid).

    Parameters
    ----------
    q : array_like, shape (..., 4)
        Quaternion ``[x, y, z, w]``; normalised internally.

    Returns
    -------
    ndarray, shape (..., 3)
        Rotation vector, rad.
    """
    Q = _planes(q)
    Q = Q / _checked(np.sqrt(Q[0] * Q[0] + Q[1] * Q[1] + Q[2] * Q[2] + Q[3] * Q[3]))
    Q = np.where(Q[3] < 0.0, -Q, Q)
    (x, y, z), w = Q[:3], Q[3]
    s = np.sqrt(x * x + y * y + z * z)
    theta = 2.0 * np.arctan2(s, w)
    small = s < 0.5 * SMALL_ANGLE_RAD
    safe = np.where(small, 1.0, s)
    # theta / sin(theta/2); near 0, 2/w * (1 - s²/(3 w²) + s⁴/(5 w⁴)) from the series of atan.
    w_small = np.where(small, w, 1.0)  # w is near 1 there; elsewhere it may be 0 (half turns)
    r2 = s * s / (w_small * w_small)
    scale = np.where(small, 2.0 / w_small * (1.0 - r2 / 3.0 + r2 * r2 / 5.0), theta / safe)
    return _rows(Q[:3] * scale)


def quat_multiply(p: ArrayLike, q: ArrayLike) -> NDArray[np.float64]:
    """Hamilton product ``p ⊗ q`` of ``[x, y, z, w]`` quaternions (apply ``q`` first, then ``p``).

    Parameters
    ----------
    p, q : array_like, shape (..., 4)
        Broadcast against each other.

    Returns
    -------
    ndarray, shape (..., 4)
    """
    return _rows(product_planes(p, q))


def product_planes(
    p: ArrayLike, q: ArrayLike, conj_p: bool = False, conj_q: bool = False
) -> NDArray[np.float64]:
    """:func:`quat_multiply` as component planes, shape ``(4, ...)``: ``[x, y, z, w]`` of
    ``p ⊗ q`` first, each plane contiguous (for the callers that use the components).
    ``conj_p`` / ``conj_q``: of the conjugate of ``p`` / ``q`` instead (the same numbers as
    conjugating first: a sign flip is exact).

    numpy is several times slower on the strided columns of an ``(N, 4)`` array, so the
    operands are turned into planes once; each component is summed in the order of the
    formula.
    """
    P, Q = _planes(p), _planes(q)
    rest = np.broadcast_shapes(P.shape[1:], Q.shape[1:])
    out = np.empty((4,) + rest)
    term = np.empty(rest)
    for k, terms in enumerate(_PRODUCT):
        o = out[k, ...]
        for n, (i, j, sign) in enumerate(terms):
            if (conj_p and i < 3) != (conj_q and j < 3):
                sign = -sign
            if n == 0:
                np.multiply(P[i], Q[j], out=o)
                if sign < 0:
                    np.negative(o, out=o)
            else:
                np.multiply(P[i], Q[j], out=term)
                (np.add if sign > 0 else np.subtract)(o, term, out=o)
    return out


def quat_conjugate(q: ArrayLike) -> NDArray[np.float64]:
    """Conjugate ``[-x, -y, -z, w]``: the inverse rotation of a unit quaternion."""
    return np.asarray(q, dtype=float) * _CONJUGATE


def quat_normalize(q: ArrayLike) -> NDArray[np.float64]:
    """Scale quaternions ``(..., 4)`` to unit norm.

    Raises
    ------
    InputError
        If a quaternion has zero or non-finite norm.
    """
    q = np.asarray(q, dtype=float)
    return q / quat_checked_norm(q)[..., None]


def quat_checked_norm(q: ArrayLike) -> NDArray[np.float64]:
    """Norms of quaternions ``(..., 4)``, shape ``(...)``.

    Raises
    ------
    InputError
        If a quaternion has zero or non-finite norm.
    """
    return _checked(row_norm(q))


def _checked(n: NDArray[np.float64]) -> NDArray[np.float64]:
    """Quaternion norms ``n``, or :class:`InputError` for a zero or NaN one."""
    if not np.isfinite(n).all() or (n == 0.0).any():
        raise InputError("Expected quaternions with finite non-zero norm, got a zero or NaN one")
    return n


def quat_rotate(q: ArrayLike, v: ArrayLike) -> NDArray[np.float64]:
    """Rotate vectors by unit quaternions: ``v' = q ⊗ v ⊗ q*`` (body to world for ``q_w_b``).

    Parameters
    ----------
    q : array_like, shape (..., 4)
    v : array_like, shape (..., 3)

    Returns
    -------
    ndarray, shape (..., 3)
    """
    q = np.asarray(q, dtype=float)
    v = np.asarray(v, dtype=float)
    u, w = q[..., :3], q[..., 3:4]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def quat_as_matrix(q: ArrayLike) -> NDArray[np.float64]:
    """Rotation matrix ``R_w_b`` of quaternions ``q_w_b`` (``v_w = R @ v_b``, active).

    Parameters
    ----------
    q : array_like, shape (..., 4)
        ``[x, y, z, w]``; normalised here.

    Returns
    -------
    ndarray, shape (..., 3, 3)
        Its columns are the body axes in world coordinates.
    """
    q = quat_normalize(q)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    rows = (
        (1.0 - 2.0 * (yy + zz), 2.0 * (xy - wz), 2.0 * (xz + wy)),
        (2.0 * (xy + wz), 1.0 - 2.0 * (xx + zz), 2.0 * (yz - wx)),
        (2.0 * (xz - wy), 2.0 * (yz + wx), 1.0 - 2.0 * (xx + yy)),
    )
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


#: A matrix with ``max |R Rᵀ - I|`` beyond this is projected on the nearest rotation first.
_ORTHONORMAL_TOL = 1e-12


def quat_from_matrix(R: ArrayLike) -> NDArray[np.float64]:
    """Unit quaternion ``[x, y, z, w]`` of rotation matrices (the nearest rotation's).

    A matrix that is not orthonormal to 1e-12 is first replaced by the nearest rotation
    (``U Vᵀ`` of its SVD, in the Frobenius norm). The quaternion is then Markley's: the
    largest of ``x², y², z², w²`` is computed from the diagonal, the others from the
    off-diagonal sums and differences, and that largest component is positive (the sign
    scipy ``Rotation.from_matrix`` gives too).

    Parameters
    ----------
    R : array_like, shape (..., 3, 3)
        ``R_w_b`` with ``det > 0``; the determinant is not checked here.

    Returns
    -------
    ndarray, shape (..., 4)
    """
    R = np.array(R, dtype=float)  # a copy: projected rows are written back
    gram = R @ np.swapaxes(R, -1, -2)
    off = np.abs(gram - np.eye(3)).max(axis=(-2, -1)) > _ORTHONORMAL_TOL
    if np.any(off):
        u, _, vt = np.linalg.svd(R[off])
        R[off] = u @ vt
    trace = R[..., 0, 0] + R[..., 1, 1] + R[..., 2, 2]
    choice = np.argmax(np.stack([R[..., 0, 0], R[..., 1, 1], R[..., 2, 2], trace], -1), -1)
    q = np.empty(R.shape[:-2] + (4,))
    for i in range(3):  # x, y or z largest
        j, k = (i + 1) % 3, (i + 2) % 3
        m = choice == i
        qi = np.empty(R.shape[:-2] + (4,))
        qi[..., i] = 1.0 - trace + 2.0 * R[..., i, i]
        qi[..., j] = R[..., j, i] + R[..., i, j]
        qi[..., k] = R[..., k, i] + R[..., i, k]
        qi[..., 3] = R[..., k, j] - R[..., j, k]
        q[m] = qi[m]
    m = choice == 3  # w largest
    qw = np.stack(
        [
            R[..., 2, 1] - R[..., 1, 2],
            R[..., 0, 2] - R[..., 2, 0],
            R[..., 1, 0] - R[..., 0, 1],
            1.0 + trace,
        ],
        axis=-1,
    )
    q[m] = qw[m]
    return q / row_norm(q)[..., None]


def quat_angle_rad(q_a: ArrayLike, q_b: ArrayLike) -> NDArray[np.float64]:
    """Angle (rad, in ``[0, π]``) of the rotation between two attitudes, ``q_a* ⊗ q_b``.

    Insensitive to the sign of either quaternion. Accurate for tiny angles (uses ``atan2``,
    not ``acos``).
    """
    q_a = np.asarray(q_a, dtype=float)
    q_b = np.asarray(q_b, dtype=float)
    quat_checked_norm(q_a)  # the ratio below does not depend on the norms: only checked
    quat_checked_norm(q_b)
    x, y, z, w = product_planes(q_a, q_b, conj_p=True)
    return 2.0 * np.arctan2(np.sqrt(x * x + y * y + z * z), np.abs(w))


def angle_between_deg(q_a: ArrayLike, q_b: ArrayLike) -> NDArray[np.float64]:
    """Angle (deg, in ``[0, 180]``) of the rotation between two attitudes, ``q_a* ⊗ q_b``.

    Parameters
    ----------
    q_a, q_b : array_like, shape (..., 4)
        ``[x, y, z, w]`` quaternions (normalised here), broadcast against each other; the sign
        of either does not matter.

    Returns
    -------
    ndarray, shape (...)
        The attitude error, degrees; accurate for tiny angles (``atan2``, not ``acos``).
    """
    return np.degrees(quat_angle_rad(q_a, q_b))


def as_quat_xyzw(attitude: ArrayLike | Rotation, name: str = "q0") -> NDArray[np.float64]:
    """Coerce an attitude given as quaternion, matrix or ``Rotation`` to a unit ``[x, y, z, w]``.

    Parameters
    ----------
    attitude : array_like of shape (4,) or (3, 3), or scipy ``Rotation`` (single)
        ``[x, y, z, w]`` quaternion (normalised here), or a ``R_w_b`` matrix (must be a rotation
        to 1e-6), or a single scipy ``Rotation``.
    name : str
        Argument name used in error messages.

    Returns
    -------
    ndarray, shape (4,)

    Raises
    ------
    InputError
        For any other shape, non-finite values, a zero quaternion or a non-orthonormal matrix.
    """
    # scipy is imported lazily (it costs ~0.25 s): an object can only be a Rotation once
    # scipy.spatial.transform has been imported by someone.
    transform = sys.modules.get("scipy.spatial.transform")
    if transform is not None and isinstance(attitude, transform.Rotation):
        if not attitude.single:
            raise InputError(f"Expected `{name}` a single Rotation, got {len(attitude)} rotations")
        return attitude.as_quat()
    a = np.asarray(attitude, dtype=float)
    if not np.all(np.isfinite(a)):
        raise InputError(f"Expected `{name}` finite, got {a.tolist()}")
    if a.shape == (4,):
        if np.linalg.norm(a) < 1e-6:
            raise InputError(f"Expected `{name}` a unit quaternion [x, y, z, w], got zero norm")
        return quat_normalize(a)
    if a.shape == (3, 3):
        err = np.abs(a.T @ a - np.eye(3)).max()
        if err > 1e-6 or np.linalg.det(a) < 0:
            raise InputError(
                f"Expected `{name}` a rotation matrix (R^T R = I, det +1), "
                f"got max |R^T R - I| = {err:.3g}, det = {np.linalg.det(a):.3g}"
            )
        from scipy.spatial.transform import Rotation

        return Rotation.from_matrix(a).as_quat()
    raise InputError(
        f"Expected `{name}` an [x, y, z, w] quaternion (4,), a 3x3 R_w_b or a Rotation, "
        f"got shape {a.shape}"
    )

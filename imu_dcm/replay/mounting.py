"""The mounting: the constant rotation between the gyro's frame and the truth's body frame.

A gyro bolted to a body at a fixed rotation ``R_TG`` measures ``omega_G = R_TGᵀ omega_T``, where
``omega_T`` is the body rate in the truth's body frame. Over the steps of a time grid (at the
best time shift of the truth, :func:`imu_dcm.replay.rate_check.check_truth`), the gyro's rotation
vector ``a_k`` and the truth's body-frame rotation vector ``b_k`` satisfy ``b_k = R_TG a_k``:
Wahba's problem, solved by the SVD of ``H = Σ a_k b_kᵀ`` (Kabsch, with the sign fixed so that
``det R = +1``).

The singular values of ``H`` say how many axes the motion determines: an axis is determined when
its singular value is at least :data:`MIN_AXIS_SHARE` of the largest and the RMS rate about it
(``sqrt(s / steps) / step``) at least :data:`MIN_AXIS_RATE`. Two or three determined
axes fix the rotation; one (a robot that only yaws) fixes only where that axis goes, and the
smallest rotation that takes it there is reported (and applied: the motion is about that axis,
so the unknown turn about it hardly matters to the score). The nearest signed axis
permutation is named when it lies within :data:`PERMUTATION_DEG` ("gyro y = truth z").

Conventions: quaternions ``[x, y, z, w]``; ``q_t_g`` maps gyro-frame vectors into the truth's
body frame (``omega_T = R(q_t_g) omega_G``), so the gyro's attitude is ``q_w_t ⊗ q_t_g``.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imu_dcm.arrays import row_finite
from imu_dcm.replay.rate_check import rate_grid
from imu_dcm.so3 import exp_matrix, quat_angle_rad, quat_as_matrix, quat_from_matrix, quat_normalize

__all__ = ["APPLY_DEG", "Mounting", "axis_permutation", "estimate_mounting"]

#: An axis is determined when its singular value is at least this share of the largest.
MIN_AXIS_SHARE = 0.02
#: ... and the RMS rate about it at least this, rad/s (3 °/s: turning, not noise).
MIN_AXIS_RATE = 0.05
#: A signed axis permutation within this angle of the estimate is named, degrees.
PERMUTATION_DEG = 5.0
#: With ``--mounting auto``, a determined rotation larger than this is applied, degrees.
APPLY_DEG = 3.0
#: The fit must explain this share of the truth's rotation (1 - residual² / total²).
MIN_FIT = 0.9
_AXES = ("x", "y", "z")


@dataclass(frozen=True)
class Mounting:
    """An estimated (or given) mounting rotation and how well the motion determines it.

    Attributes
    ----------
    q_t_g : (x, y, z, w) — gyro frame into the truth's body frame.
    angle_deg : rotation angle, degrees.
    axis : unit rotation axis (gyro frame; (0, 0, 1) when the angle is 0).
    axes_determined : 0..3, from the singular values.
    singular_values : of ``H``, largest first, rad².
    fit : share of the truth's rotation the rotated gyro explains (1 is perfect).
    permutation : "gyro x = truth x, ..." when a signed axis permutation is within
        :data:`PERMUTATION_DEG`, else "".
    permutation_deg : angle between the estimate and the nearest permutation, degrees.
    source : "estimated", "given" or "tf" (declared in the log's ``/tf_static``).
    steps : grid steps used.
    turn_axis_g : unit gyro-frame direction of the strongest turn (the first singular vector
        of ``H``) for an estimate, else None. With one axis determined, only where this
        direction goes is known.
    """

    q_t_g: tuple[float, float, float, float]
    angle_deg: float
    axis: tuple[float, float, float]
    axes_determined: int
    singular_values: tuple[float, ...]
    fit: float
    permutation: str
    permutation_deg: float
    source: str = "estimated"
    steps: int = 0
    turn_axis_g: tuple[float, float, float] | None = None

    @property
    def determined(self) -> bool:
        """The motion determines at least one axis and the rotated gyro fits the truth.

        With one axis (a robot that only yaws) the rotation about it is unknown, but it hardly
        matters for scoring: the motion is about that axis.
        """
        return self.axes_determined >= 1 and self.fit >= MIN_FIT

    def describe(self) -> str:
        """One clause: angle, axis, permutation, axes determined, fit."""
        ax = ", ".join(f"{v:+.2f}" for v in self.axis)
        perm = (
            f", {self.permutation_deg:.1f}° from the axis permutation {self.permutation}"
            if self.permutation
            else ""
        )
        if self.source != "estimated":
            how = "as given" if self.source == "given" else "as declared"
            return f"{self.angle_deg:.1f}° about ({ax}) {how}{perm}"
        partly = (
            " (the rotation about it is unknown: the smallest one is used)"
            if self.axes_determined == 1
            else ""
        )
        return (
            f"{self.angle_deg:.1f}° about ({ax}){perm}; the motion determines "
            f"{self.axes_determined} of 3 axes{partly}, fit {self.fit:.3f}"
        )


def _permutations() -> list[NDArray[np.float64]]:
    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            m = np.zeros((3, 3))
            m[perm, range(3)] = signs
            if np.linalg.det(m) > 0:
                out.append(m)
    return out


_PERMS = _permutations()
_PERMS_T = np.stack([p.T for p in _PERMS])  # (24, 3, 3), each transposed
_IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])


def axis_permutation(r: NDArray[np.float64]) -> tuple[str, float]:
    """The signed axis permutation (proper rotation) nearest ``r`` and its angle, degrees.

    ``r`` maps gyro-frame vectors into the truth frame; column ``i`` is gyro axis ``i`` in truth
    axes, so the words read "gyro y = truth z" when column 1 is ``e_z``.
    """
    angles = np.degrees(quat_angle_rad(_IDENTITY, quat_from_matrix(_PERMS_T @ r)))
    k = int(np.argmin(angles))
    p = _PERMS[k]
    words = []
    for i in range(3):
        j = int(np.flatnonzero(p[:, i])[0])
        sign = "-" if p[j, i] < 0 else ""
        words.append(f"gyro {_AXES[i]} = truth {sign}{_AXES[j]}")
    return ", ".join(words), float(angles[k])


def _canonical(q: NDArray[np.float64]) -> NDArray[np.float64]:
    """``q`` or ``-q``: ``w > 0``, or at ``w == 0`` (half turns) the first non-zero component
    positive, so that a half turn's axis reads the same whichever sign it was given with."""
    first = q[np.flatnonzero(q)[0]] if q[3] == 0.0 and np.any(q) else q[3]
    return -q if first < 0.0 else q


def from_rotation(
    q_t_g: ArrayLike,
    source: str,
    svals=(),
    determined: int = 3,
    fit: float = 1.0,
    steps: int = 0,
    turn_axis_g=None,
) -> Mounting:
    """A :class:`Mounting` from a rotation ``q_t_g`` (gyro into truth frame, ``[x, y, z, w]``,
    normalised here; its sign is kept in :attr:`Mounting.q_t_g`)."""
    q = quat_normalize(q_t_g)
    c = _canonical(q)  # the angle in [0, π] and its axis, as scipy's rotation vector gives
    s = float(np.linalg.norm(c[:3]))
    angle = 2.0 * float(np.arctan2(s, c[3]))
    axis = tuple((c[:3] / s).tolist()) if angle > 1e-12 else (0.0, 0.0, 1.0)
    words, perm_deg = axis_permutation(quat_as_matrix(q))
    identity = words == "gyro x = truth x, gyro y = truth y, gyro z = truth z"
    named = perm_deg <= PERMUTATION_DEG and not identity
    return Mounting(
        tuple(float(x) for x in q),
        float(np.degrees(angle)),
        axis,
        determined,
        tuple(float(x) for x in svals),
        fit,
        words if named else "",
        perm_deg if named else float("nan"),
        source,
        steps,
        None if turn_axis_g is None else tuple(float(x) for x in turn_axis_g),
    )


def estimate_mounting(
    t_ns: NDArray[np.int64],
    omega_b: NDArray[np.float64],
    truth_t_ns: NDArray[np.int64],
    q_w_b: NDArray[np.float64],
    exclude_ns: tuple[tuple[int, int], ...] = (),
) -> Mounting | None:
    """Wahba/Kabsch estimate of the gyro-to-truth-body rotation (see the module docstring).

    Parameters
    ----------
    t_ns : int64 (N,) — gyro stamps, increasing.
    omega_b : float64 (N, 3) — gyro rates (bias removed), gyro axes, rad/s.
    truth_t_ns : int64 (M,) — truth stamps on the gyro's clock, already at the best shift.
    q_w_b : float64 (M, 4) — truth ``[x, y, z, w]``.
    exclude_ns : ``(start, end)`` stamp intervals left out (truth jumps).

    Returns
    -------
    Mounting, or None when gyro and truth share too few grid steps or the truth never turns.
    """
    grid = rate_grid(t_ns, omega_b, truth_t_ns, q_w_b)
    if grid is None:
        return None
    ok = row_finite(grid.truth_rotvec)
    for t0, t1 in exclude_ns:
        ok &= (grid.edges_ns[1:] <= t0) | (grid.edges_ns[:-1] >= t1)
    a, b = grid.gyro_rotvec[ok], grid.truth_rotvec[ok]
    if len(a) < 20:
        return None
    h = a.T @ b
    u, svals, vt = np.linalg.svd(h)
    if svals[0] <= 0.0:
        return None
    d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    r = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    # an axis is determined by motion about it: a share of the largest, and above noise
    axis_rate = np.sqrt(np.maximum(svals, 0.0) / len(a)) / grid.step_s
    determined = int(np.sum((svals >= MIN_AXIS_SHARE * svals[0]) & (axis_rate >= MIN_AXIS_RATE)))
    if determined == 1:  # only where the strongest axis goes: the smallest such rotation
        src = u[:, 0]
        r = _smallest(src, r @ src)
    total = float(np.sum(b * b))
    resid = float(np.sum((b - a @ r.T) ** 2))
    fit = 1.0 - resid / total if total > 0 else 0.0
    return from_rotation(quat_from_matrix(r), "estimated", svals, determined, fit, len(a), u[:, 0])


def _smallest(src: NDArray[np.float64], dst: NDArray[np.float64]) -> NDArray[np.float64]:
    """The smallest rotation taking unit vector ``src`` to ``dst``."""
    src, dst = src / np.linalg.norm(src), dst / np.linalg.norm(dst)
    axis = np.cross(src, dst)
    s, c = float(np.linalg.norm(axis)), float(np.dot(src, dst))
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        perp = np.cross(src, np.eye(3)[int(np.argmin(np.abs(src)))])
        return exp_matrix(np.pi * perp / np.linalg.norm(perp))
    return exp_matrix(axis / s * np.arctan2(s, c))

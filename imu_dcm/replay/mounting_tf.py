"""The mounting a log declares in ``/tf_static``, and which mounting a replay applies.

**Declared.** A tf transform ``parent -> child`` carries ``q_parent_child``, which maps
child-frame coordinates into the parent frame (``v_parent = R(q_parent_child) v_child``).
Composed along the static tree, ``q_a_c = q_a_b ⊗ q_b_c``; an edge walked from child to
parent contributes its inverse. The mounting of :mod:`imu_dcm.replay.mounting`, ``q_t_g``
(gyro frame into the truth's body frame, ``omega_T = R(q_t_g) omega_G``), is the composed
``q_body_imu``: the path runs from the truth's body frame to the IMU's ``frame_id`` through
their lowest common ancestor in the tree of ``/tf_static`` (frame ids compared with leading
'/' stripped).

**The truth's body frame.** A transform or odometry truth names it (``child_frame_id``). A
truth that names none (QuaternionStamped, PoseStamped, PoseWithCovarianceStamped) describes
the body the static tree hangs from: the root reached from the IMU's frame by following its
static parents (``base_link`` for ``base_link -> mount -> imu_link``), unless that root is the
truth's own parent frame (then nothing is declared). The IMU's own orientation describes the
IMU's frame itself: no mounting.

**Which one is applied** (``--mounting auto``). The declared mounting is applied, and compared
with the motion's estimate in the same line. Where the estimate is determined (the motion fixes
at least one axis and the rotated gyro fits the truth) and differs from the declared one by
more than :data:`TF_AGREE_DEG` - the full rotation when two or three axes are determined, where
the determined axis goes when one is - the two disagree: the declared transform is wrong or the
truth is not the attitude of the frame it names. The estimate is then applied, by its own rule
(over :data:`~imu_dcm.replay.mounting.APPLY_DEG`), because it is measured from this log's data
while the transform is only declared. ``--mounting none`` applies neither and reports both; a
given quaternion is applied and compared with both.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from imu_dcm.logio.types import StaticTransform, TruthSeries
from imu_dcm.replay.mounting import APPLY_DEG, Mounting, from_rotation
from imu_dcm.so3 import (
    angle_between_deg,
    quat_conjugate,
    quat_multiply,
    quat_normalize,
    quat_rotate,
)

if TYPE_CHECKING:
    from scipy.spatial.transform import Rotation

__all__ = ["TF_AGREE_DEG", "MountingChoice", "TfMounting", "choose_mounting", "tf_mounting"]

#: The declared and the estimated mounting disagree beyond this angle, degrees.
TF_AGREE_DEG = 5.0


def _bare(frame: str) -> str:
    return frame.strip().lstrip("/")


@dataclass(slots=True, frozen=True)
class TfMounting:
    """The mounting composed from ``/tf_static``.

    Attributes
    ----------
    mounting : Mounting — ``q_t_g`` = ``q_body_imu``, source "tf".
    imu_frame : the IMU's ``frame_id`` (the gyro frame).
    body_frame : the truth's body frame.
    body_frame_from : "child_frame_id" (the truth names it) or "static root" (the root of the
        static tree above the IMU's frame; the truth names no body frame).
    chain : frames from ``body_frame`` to ``imu_frame`` along the static tree.
    """

    mounting: Mounting
    imu_frame: str
    body_frame: str
    body_frame_from: str
    chain: tuple[str, ...]


def _parents(static: tuple[StaticTransform, ...]) -> dict[str, tuple[str, NDArray]]:
    """child -> (parent, q_parent_child ``[x, y, z, w]``, unit), frame ids bare."""
    return {_bare(s.child): (_bare(s.parent), quat_normalize(s.q_xyzw)) for s in static}


def _up(parents: dict, frame: str) -> list[str]:
    """``frame`` and its static ancestors, nearest first (a cycle stops the walk)."""
    out = [frame]
    while out[-1] in parents and parents[out[-1]][0] not in out:
        out.append(parents[out[-1]][0])
    return out


def _down(parents: dict, path: list[str]) -> NDArray:
    """``q_top_frame`` for ``path`` = [frame, its parent, ..., top]."""
    q = np.array([0.0, 0.0, 0.0, 1.0])
    for child in path[:-1]:
        q = quat_multiply(parents[child][1], q)
    return q


def static_rotation(
    static: tuple[StaticTransform, ...], a: str, b: str
) -> tuple[Rotation, tuple[str, ...]] | None:
    """``q_a_b`` (frame ``b`` into frame ``a``) as a scipy ``Rotation``, composed along the
    static tree, and the frames of the path from ``a`` to ``b``; None when the tree does not
    connect them. (:func:`static_quat` gives the quaternion without importing scipy.)"""
    found = static_quat(static, a, b)
    if found is None:
        return None
    from scipy.spatial.transform import Rotation

    return Rotation.from_quat(found[0]), found[1]


def static_quat(
    static: tuple[StaticTransform, ...], a: str, b: str
) -> tuple[NDArray[np.float64], tuple[str, ...]] | None:
    """``q_a_b`` ``[x, y, z, w]`` (frame ``b`` into frame ``a``) composed along the static
    tree, and the frames of the path from ``a`` to ``b``; None when the tree does not connect
    them."""
    parents = _parents(static)
    up_a, up_b = _up(parents, _bare(a)), _up(parents, _bare(b))
    common = next((f for f in up_b if f in up_a), None)
    if common is None:
        return None
    path_a = up_a[: up_a.index(common) + 1]
    path_b = up_b[: up_b.index(common) + 1]
    q_c_a, q_c_b = _down(parents, path_a), _down(parents, path_b)
    return quat_multiply(quat_conjugate(q_c_a), q_c_b), (*path_a, *reversed(path_b[:-1]))


def truth_body_frame(
    truth: TruthSeries, imu_topic: str, imu_frame: str, static: tuple[StaticTransform, ...]
) -> tuple[str, str]:
    """The frame whose attitude the truth gives, and how it was chosen (module docstring);
    ("", "") when it is the IMU's own frame or cannot be told."""
    if truth.topic == imu_topic:
        return "", ""  # the IMU's own orientation: its own frame
    if truth.child_frame_id:
        return _bare(truth.child_frame_id), "child_frame_id"
    root = _up(_parents(static), _bare(imu_frame))[-1]
    if root == _bare(imu_frame) or root == _bare(truth.frame_id):
        return "", ""
    return root, "static root"


def tf_mounting(
    static: tuple[StaticTransform, ...], imu_topic: str, imu_frame: str, truth: TruthSeries
) -> TfMounting | None:
    """The mounting ``/tf_static`` declares between the IMU's frame and the truth's body frame;
    None when the frames are the same, unknown or not connected by static transforms."""
    if not static or not _bare(imu_frame):
        return None
    body, how = truth_body_frame(truth, imu_topic, imu_frame, static)
    if not body or body == _bare(imu_frame):
        return None
    found = static_quat(static, body, imu_frame)
    if found is None:
        return None
    q_body_imu, chain = found
    mounting = from_rotation(q_body_imu, "tf", determined=0, fit=float("nan"))
    return TfMounting(mounting, _bare(imu_frame), body, how, chain)


def disagreement_deg(declared: Mounting, est: Mounting) -> tuple[float, str]:
    """How far the estimate is from ``declared``, degrees, on what the motion determines:
    the whole rotation ("rotation") with two or three axes, else where the determined turn
    axis goes ("axis")."""
    if est.axes_determined >= 2 or est.turn_axis_g is None:
        diff = angle_between_deg(np.asarray(declared.q_t_g), np.asarray(est.q_t_g))
        return float(diff), "rotation"
    u = np.asarray(est.turn_axis_g)
    a = quat_rotate(quat_normalize(declared.q_t_g), u)
    b = quat_rotate(quat_normalize(est.q_t_g), u)
    return float(np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b)), a @ b))), "axis"


@dataclass(slots=True, frozen=True)
class MountingChoice:
    """The mounting a replay applies, what its summary reports, and its one line.

    Attributes
    ----------
    applied : Mounting or None — the rotation applied to the gyro's rates (None: none).
    reported : Mounting or None — the summary's ``mounting``: the given one, else the estimate.
    used : "estimated", "given", "tf" or "" — where the applied rotation came from.
    tf : dict or None — the summary's ``mounting_tf`` (the declared mounting, its frames,
        its distance to the estimate and whether they agree).
    line : str — the one line to say ("" when there is nothing to say).
    """

    applied: Mounting | None
    reported: Mounting | None
    used: str
    tf: dict | None
    line: str


def _motion(est: Mounting) -> str:
    """The estimate in short: angle, axis, what the motion determines."""
    ax = ", ".join(f"{v:+.2f}" for v in est.axis)
    return (
        f"{est.angle_deg:.1f}° about ({ax}) (it determines {est.axes_determined} of 3 axes, "
        f"fit {est.fit:.3f})"
    )


def _tf_record(tf: TfMounting, est: Mounting | None) -> tuple[dict, str, bool | None]:
    """The summary's ``mounting_tf`` and the clause comparing it with the estimate."""
    record = {
        **asdict(tf.mounting),
        "imu_frame": tf.imu_frame,
        "body_frame": tf.body_frame,
        "body_frame_from": tf.body_frame_from,
        "chain": list(tf.chain),
        "angle_to_estimate_deg": None,
        "compared_on": "",
        "agrees": None,
    }
    if est is None or not est.determined:
        why = (
            "gyro and truth share too few turning steps"
            if est is None
            else f"it determines {est.axes_determined} of 3 axes, fit {est.fit:.3f}"
        )
        return record, f"the motion cannot check it ({why})", None
    diff, on = disagreement_deg(tf.mounting, est)
    agrees = diff <= TF_AGREE_DEG
    record.update(angle_to_estimate_deg=diff, compared_on=on, agrees=agrees)
    where = " on the axis the motion determines" if on == "axis" else ""
    verdict = (
        f"they agree ({diff:.1f}° apart{where})"
        if agrees
        else f"they DISAGREE by {diff:.1f}°{where}: the declared transform is wrong or the "
        f"truth is not the attitude of {tf.body_frame}"
    )
    return record, f"the motion says {_motion(est)}; {verdict}", agrees


def _choose_with_tf(mode, est: Mounting | None, tf: TfMounting) -> MountingChoice:
    """``auto`` or ``none`` with a declared mounting (module docstring)."""
    record, clause, agrees = _tf_record(tf, est)
    head = (
        f"mounting ({tf.imu_frame} -> {tf.body_frame}): /tf_static "
        f"({' -> '.join(tf.chain)}) gives {tf.mounting.describe()}; {clause}"
    )
    record["applied"] = False
    if mode == "none":
        return MountingChoice(None, est, "", record, f"{head}: neither applied (--mounting none)")
    if agrees is False:
        if est.angle_deg > APPLY_DEG:
            tail = "applied the motion's estimate (--mounting x,y,z,w to impose one)"
            return MountingChoice(est, est, "estimated", record, f"{head}; {tail}")
        tail = f"scored without a mounting (the motion's is under {APPLY_DEG:g}°)"
        return MountingChoice(None, est, "", record, f"{head}; {tail}")
    record["applied"] = True
    tail = "applied the /tf_static one (--mounting none to score without it)"
    return MountingChoice(tf.mounting, est, "tf", record, f"{head}: {tail}")


def _choose_given(given: Mounting, est, tf: TfMounting | None, frames: str) -> MountingChoice:
    compare = ""
    if est is not None and est.determined:
        diff = float(angle_between_deg(np.asarray(given.q_t_g), np.asarray(est.q_t_g)))
        compare = f"; the motion says {est.describe()}, {diff:.1f}° from the given one"
    record = None
    if tf is not None:
        record, _clause, _agrees = _tf_record(tf, est)
        record["applied"] = False
        diff = float(angle_between_deg(np.asarray(given.q_t_g), np.asarray(tf.mounting.q_t_g)))
        compare += (
            f"; /tf_static ({' -> '.join(tf.chain)}) gives {tf.mounting.describe()}, "
            f"{diff:.1f}° from the given one"
        )
    line = f"mounting ({frames}): {given.describe()}, applied{compare}"
    return MountingChoice(given, given, "given", record, line)


def choose_mounting(
    mode, est: Mounting | None, tf: TfMounting | None, given: Mounting | None, frames: str
) -> MountingChoice:
    """Which mounting to apply and the line that says so.

    Parameters
    ----------
    mode : "auto", "none" or a quaternion (then ``given`` is it as a :class:`Mounting`).
    est : the motion's estimate (:func:`imu_dcm.replay.mounting.estimate_mounting`) or None.
    tf : the declared mounting (:func:`tf_mounting`) or None.
    frames : "gyro frame -> truth body frame" as said in the line when ``tf`` is None.
    """
    if given is not None:
        return _choose_given(given, est, tf, frames)
    if tf is not None:
        return _choose_with_tf(mode, est, tf)
    if est is None or not est.determined or est.angle_deg <= APPLY_DEG:
        return MountingChoice(None, est, "", None, "")  # no turn to learn from, or no mounting
    if mode == "auto":
        line = (
            f"mounting ({frames}): the gyro frame is {est.describe()}: applied to the scoring "
            f"(--mounting none to score without it)"
        )
        return MountingChoice(est, est, "estimated", None, line)
    line = f"mounting ({frames}): the gyro frame is {est.describe()}: not applied (--mounting none)"
    return MountingChoice(None, est, "", None, line)

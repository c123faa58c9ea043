"""Which channel is the truth, and its attitude as a :class:`~imu_dcm.logio.types.TruthSeries`.

The truth topics (not under ``/estimate``) first, then each moving frame of ``/tf``, then the
Imu's own orientation; with none named, every other candidate is kept for the replay to judge
which one follows the gyro. Odometry and the Imu's orientation are marked as estimates
(``estimate_of``), as is a topic the bag's ``custom_data`` declares one (:data:`ESTIMATE_OF_KEY`).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from imu_dcm.errors import LogError
from imu_dcm.logio.ros.channels import ChannelDecoder, by_topic, describe, is_truth, merge
from imu_dcm.logio.ros.collect import Collected, Conn, Payloads
from imu_dcm.logio.ros.schema import norm_type
from imu_dcm.logio.ros.tf import TF_TYPE, moving_children, tf_truth
from imu_dcm.logio.types import ImuSeries, TruthSeries

__all__ = ["ESTIMATE_OF_KEY", "IMU_ESTIMATE", "declared_estimates", "imu_truth", "read_truths"]

#: Who estimated a truth of this type (its ``estimate_of``), when it is no independent reference.
_ESTIMATED_BY = {"nav_msgs/msg/Odometry": "odometry (an estimate, often wheels and the IMU)"}


IMU_ESTIMATE = "the IMU's own orientation"


#: A bag's ``custom_data`` key ``imu_dcm.estimate_of:<topic>`` says whose own estimate the truth
#: on ``<topic>`` is (convert-csv's ``--truth-estimate-of``); its value becomes ``estimate_of``.
ESTIMATE_OF_KEY = "imu_dcm.estimate_of:"


def _read_truth_topic(got: Collected, topic: str, conns: list[Conn], auto: bool) -> TruthSeries:
    rows, typ, frame, child = [], "", "", ""
    for c in conns:
        data = got.payloads.get(c.id)
        if data is None:
            data = ChannelDecoder(c, "truth")(Payloads.empty())
        if data.error is not None:
            raise data.error
        n = len(data)
        rows.append(
            (
                data.order,
                [
                    data.fields.get("t_ns", np.zeros(n, np.int64)),
                    data.log_time,
                    data.fields.get("q", np.zeros((n, 4))),
                    data.fields.get("p"),
                    data.fields.get("w"),
                ],
            )
        )
        typ = typ or data.frames.get("type") or norm_type(c.msgtype)
        frame = frame or data.frames.get("frame_id", "")
        child = child or data.frames.get("child_frame_id", "")
    t_ns, log_t, q, p_w, omega_b = merge(rows)
    return TruthSeries(
        t_ns.astype(np.int64, copy=False),
        log_t.astype(np.int64, copy=False),
        q,
        topic,
        typ,
        frame,
        child,
        auto,
        p_w=p_w,
        omega_b=omega_b,
    )


def imu_truth(imu: ImuSeries, required: bool) -> TruthSeries | None:
    """The Imu's own orientation as truth where it is given (covariance[0] != -1, unit norm)."""
    q = imu.orientation_xyzw
    if q is None:
        if required:
            raise LogError(
                f"Expected an orientation on {imu.topic} (orientation_covariance[0] "
                f"!= -1), got none"
            )
        return None
    norm = np.linalg.norm(q, axis=1)
    ok = np.isfinite(norm) & (np.abs(norm - 1.0) < 1e-3)  # all-zero quaternions are not truth
    if not ok.any():
        if required:
            raise LogError(f"Expected unit orientation quaternions on {imu.topic}, got none")
        return None
    if not required and ok.sum() > 1 and np.all(q[ok] == q[ok][0]):
        # A constant quaternion (typically the default 0,0,0,1 behind a garbage covariance
        # instead of the -1 flag) is no estimate; it is used only when asked for by topic.
        return None
    return TruthSeries(
        imu.t_ns[ok],
        imu.log_t_ns[ok],
        q[ok] / norm[ok, None],
        imu.topic,
        imu.type,
        imu.frame_id,
        "",
        not required,
    )


def declared_estimates(
    truths: tuple[TruthSeries | None, ...], custom_data: dict[str, str]
) -> tuple[TruthSeries | None, ...]:
    """``truths`` with ``estimate_of`` set where the bag's ``custom_data`` declares it for the
    truth's topic (:data:`ESTIMATE_OF_KEY`); a mark the reader already gave is kept."""
    return tuple(
        replace(t, estimate_of=custom_data[ESTIMATE_OF_KEY + t.topic])
        if t is not None and not t.estimate_of and custom_data.get(ESTIMATE_OF_KEY + t.topic)
        else t
        for t in truths
    )


def read_truths(
    got: Collected, imu: ImuSeries, truth_topic: str | None, truth_frame: str | None
) -> tuple[TruthSeries | None, tuple[TruthSeries, ...]]:
    """The truth and, when it was picked automatically, every other attitude candidate.

    Candidates, in the order of preference of the module docstring: the truth topics (not under
    ``/estimate``), each moving frame of ``/tf``, the Imu's own orientation. Odometry and the
    Imu's orientation carry ``estimate_of``. The replay judges which one follows the gyro.
    """
    if truth_topic == "none":
        return None, ()
    topics = by_topic(got)
    if truth_topic is not None:
        return _named_truth(got, imu, topics, truth_topic, truth_frame), ()
    tf = [c for c in got.conns if c.encoding in ("cdr", "ros1") and norm_type(c.msgtype) == TF_TYPE]
    if truth_frame is not None:  # a frame names a transform
        if not tf:
            raise LogError(
                f"Expected /tf or /tf_static for truth frame {truth_frame!r}, got "
                f"{describe(got.conns)}"
            )
        return tf_truth(got, tf, imu.frame_id, truth_frame, auto=False), ()
    found = [
        _marked(_read_truth_topic(got, t, cs, auto=True))
        for t, cs in sorted(topics.items())
        if not t.startswith("/estimate")
        and all(is_truth(c) and norm_type(c.msgtype) != TF_TYPE for c in cs)
    ]
    if tf:
        found += [tf_truth(got, tf, imu.frame_id, ch, auto=True) for ch in moving_children(got, tf)]
    own = imu_truth(imu, required=False)
    if own is not None:
        found.append(replace(own, estimate_of=IMU_ESTIMATE))
    if not found:
        return None, ()
    return found[0], tuple(found[1:])


def _marked(t: TruthSeries) -> TruthSeries:
    who = _ESTIMATED_BY.get(t.type, "")
    return replace(t, estimate_of=who) if who else t


def _named_truth(got, imu, topics, truth_topic: str, truth_frame: str | None):
    """The truth the caller named by topic (its type checked)."""
    if truth_topic == imu.topic:
        return replace(imu_truth(imu, required=True), estimate_of=IMU_ESTIMATE)
    conns = topics.get(truth_topic)
    if not conns:
        raise LogError(
            f"Expected truth topic {truth_topic!r} in the log, got {describe(got.conns)}"
        )
    for c in conns:
        if not is_truth(c):
            raise LogError(
                f"Expected truth messages on {truth_topic}, got "
                f"{c.msgtype or 'no schema'} ({c.encoding})"
            )
    if all(norm_type(c.msgtype) == TF_TYPE for c in conns):
        tf = tf_truth(got, conns, imu.frame_id, truth_frame, auto=False)
        if tf is None:
            raise LogError(f"Expected a moving transform in {truth_topic}, got none")
        return tf
    return _marked(_read_truth_topic(got, truth_topic, conns, auto=False))

"""Which channel is the gyro, and its samples as an :class:`~imu_dcm.logio.types.ImuSeries`.

By default the one IMU-typed channel (a gyro-named ``Vector3Stamped`` when there is none,
:mod:`imu_dcm.logio.ros.channels`); a candidate whose samples are no gyro's (all flagged
absent, or an accelerometer's norm) is refused with one line, as a note when another serves.
"""

from __future__ import annotations

import numpy as np

from imu_dcm.arrays import median, percentile, row_finite, row_norm
from imu_dcm.errors import LogError
from imu_dcm.gyro.rest_rule import GRAVITY_M_S2
from imu_dcm.logio.ros.channels import (
    KNOWN_ENCODINGS,
    NOT_GYRO,
    VEC3_TYPE,
    ChannelDecoder,
    by_topic,
    describe,
    gyro_name,
    imu_path,
    merge,
)
from imu_dcm.logio.ros.collect import Collected, Columns, Conn, Payloads
from imu_dcm.logio.ros.json_imu import is_json_imu, json_imu_columns, json_msg
from imu_dcm.logio.ros.schema import norm_type
from imu_dcm.logio.types import ImuSeries

__all__ = ["gyro_doubt", "pick_imu", "read_imu"]


def _imu_columns(c: Conn, data):
    """(order, t_ns, log_t_ns, omega, quat, accel, gyro_flagged, dropped, type, frame) of a
    channel.

    ``quat`` and ``accel`` are None where the channel has none; ``gyro_flagged`` (bool) marks
    messages whose ``angular_velocity_covariance[0]`` is -1 (an absent gyro).
    """
    if c.encoding == "json":
        t_ns, omega, _, good, typ, frame = json_imu_columns(c, data)
        n = int(good.sum())
        return (
            data.order[good],
            t_ns[good],
            data.log_time[good],
            omega[good],
            None,
            None,
            np.full(n, np.nan),
            int(len(data) - n),
            typ,
            frame,
        )
    if data.error is not None:
        raise data.error
    f = data.fields
    n = len(data)
    return (
        data.order,
        f.get("t_ns", np.zeros(n, np.int64)),
        data.log_time,
        f.get("omega", np.zeros((n, 3))),
        f.get("quat"),
        f.get("accel"),
        f.get("gyro_flagged", np.zeros(n, bool)),
        data.dropped,
        data.frames.get("type", ""),
        data.frames.get("frame_id", ""),
    )


#: Rows whose norms judge a gyro candidate (a long log is judged on every k-th row: the
#: quartiles of 131 072 norms are within ~0.5 % of the whole log's).
_DOUBT_ROWS = 1 << 17


def gyro_doubt(got: Collected, conns: list[tuple[Conn, str]]) -> str | None:
    """Why the decoded samples of a gyro candidate are no gyro's, or None when they may be.

    Refused: messages that all mark the angular velocity absent (Imu
    ``angular_velocity_covariance[0] = -1``), and rates whose norm stays at g (9.81, within 1)
    with a spread under 10 %: an accelerometer published as a Vector3Stamped.
    """
    omegas, covs = [], []
    for c, _path in conns:
        data = got.payloads.get(c.id)
        if not isinstance(data, Columns) or data.error is not None:
            continue
        omegas.append(data.fields.get("omega", np.zeros((0, 3))))
        covs.append(data.fields.get("gyro_flagged", np.zeros(len(data), bool)))
    flagged = np.concatenate(covs) if covs else np.zeros(0, bool)
    if len(flagged) and np.all(flagged == True):  # noqa: E712 (a NaN-filled join is not True)
        return "its messages mark the angular velocity absent (angular_velocity_covariance[0] = -1)"
    w = omegas[0] if len(omegas) == 1 else np.concatenate([np.zeros((0, 3)), *omegas])
    w = w[:: len(w) // _DOUBT_ROWS + 1]  # quartiles of norms: every k-th row tells them
    norm = row_norm(w)[row_finite(w)]
    if len(norm) < 10:
        return None
    med = median(norm)
    spread = percentile(norm, 75) - percentile(norm, 25)
    if abs(med - GRAVITY_M_S2) < 1.0 and spread < 0.1 * med:
        return (
            f"|omega| stays at {med:.2f} (interquartile {spread:.2f}), the 9.81 m/s² of gravity: "
            f"an accelerometer, not a gyro"
        )
    return None


def _alternatives(got: Collected, usable: list[str], refused: set[str]) -> str:
    """The channels that could be the gyro instead, for a refusal's line."""
    if usable:
        return f"; {', '.join(usable)} would work"
    vec = sorted(
        {c.topic for c in got.conns if norm_type(c.msgtype) == VEC3_TYPE and c.topic not in refused}
    )
    vec = [t for t in vec if not t.startswith(NOT_GYRO)]
    if vec:
        return f"; try {', '.join(vec)} with --imu-topic"
    return "; no other channel of the log holds angular rates"


def pick_imu(
    got: Collected, imu_topic: str | None
) -> tuple[str, list[tuple[Conn, str]], tuple[str, ...]]:
    """The IMU topic, its channels with their Imu field paths, and notes (LogError when unclear).

    Candidates that are no gyro (:func:`gyro_doubt`) are refused with one line each: returned
    as notes when another channel serves, a LogError otherwise.
    """
    if imu_topic is not None:
        out = _named_imu(got, imu_topic)
        doubt = gyro_doubt(got, out)
        if doubt:
            raise LogError(
                f"Expected a gyro on {imu_topic}, got {doubt}" + _alternatives(got, [], {imu_topic})
            )
        return imu_topic, out, ()
    found, gyro = _imu_candidates(got)
    refused = {t: d for t, cs in {**gyro, **found}.items() if (d := gyro_doubt(got, cs))}
    found = {t: cs for t, cs in found.items() if t not in refused}
    gyro = {t: cs for t, cs in gyro.items() if t not in refused}
    found = found or gyro
    if not found and refused:
        topic, why = next(iter(sorted(refused.items())))
        raise LogError(
            f"Expected a gyro channel, got {topic}: {why}" + _alternatives(got, [], set(refused))
        )
    if not found:
        unknown = [c for c in got.conns if c.encoding not in KNOWN_ENCODINGS]
        if unknown:
            raise LogError(
                f"Expected message encoding cdr or json, got {unknown[0].encoding!r} "
                f"on {unknown[0].topic}"
            )
        raise LogError(
            f"Expected an IMU channel (sensor_msgs/msg/Imu or a type with an Imu "
            f"field; a geometry_msgs/msg/Vector3Stamped gyro named with --imu-topic), "
            f"got {describe(got.conns)}"
        )
    if len(found) > 1:
        raise LogError(
            f"Expected one IMU channel, got {len(found)}: {', '.join(sorted(found))} "
            f"(choose with --imu-topic)"
        )
    topic = next(iter(found))
    notes = tuple(
        f"{t}: refused as the gyro: {d}; using {topic}" for t, d in sorted(refused.items())
    )
    return topic, found[topic], notes


def _named_imu(got: Collected, imu_topic: str) -> list[tuple[Conn, str]]:
    conns = by_topic(got).get(imu_topic)
    if not conns:
        raise LogError(f"Expected IMU topic {imu_topic!r} in the log, got {describe(got.conns)}")
    out = []
    for c in conns:
        if c.encoding not in KNOWN_ENCODINGS:
            raise LogError(
                f"Expected message encoding cdr, ros1 or json on {imu_topic}, got {c.encoding!r}"
            )
        path = "json" if c.encoding == "json" else imu_path(c)
        if path is None:
            raise LogError(
                f"Expected IMU messages on {imu_topic}, got "
                f"{c.msgtype or 'no schema'} ({c.encoding})"
            )
        out.append((c, path))
    return out


def _imu_candidates(got: Collected) -> tuple[dict, dict]:
    """IMU-typed channels and gyro-named Vector3Stamped channels, by topic."""
    found: dict[str, list[tuple[Conn, str]]] = {}
    gyro: dict[str, list[tuple[Conn, str]]] = {}
    for topic, conns in by_topic(got).items():
        for c in conns:
            if c.encoding == "json":
                p = got.payloads.get(c.id)
                if p is not None and len(p) and is_json_imu(json_msg(p.payload(0))):
                    found.setdefault(topic, []).append((c, "json"))
                continue
            path = imu_path(c)
            if path == "vec3":
                if gyro_name(topic):
                    gyro.setdefault(topic, []).append((c, path))
            elif path is not None:
                found.setdefault(topic, []).append((c, path))
    return found, gyro


def read_imu(got: Collected, topic: str, conns: list[tuple[Conn, str]]) -> tuple[ImuSeries, int]:
    """The IMU series of ``topic`` (its channels merged) and the count of undecodable ones."""
    rows, dropped, typ, frame = [], 0, "", ""
    for c, path in conns:
        data = got.payloads.get(c.id)
        if data is None:
            data = (
                Payloads.empty()
                if c.encoding == "json"
                else ChannelDecoder(c, "imu", path)(Payloads.empty())
            )
        order, t_ns, log_t, omega, quat, accel, flag, drop, typ_c, frame_c = _imu_columns(c, data)
        dropped += drop
        typ, frame = typ or typ_c, frame or frame_c
        if quat is None and len(conns) > 1:
            quat = np.full((len(t_ns), 4), np.nan)
        if accel is None and len(conns) > 1:
            accel = np.full((len(t_ns), 3), np.nan)
        rows.append((order, [t_ns, log_t, omega, quat, accel, flag]))
    t_ns, log_t, omega, quat, accel, flag = merge(rows)
    if quat is not None and not np.isfinite(quat).any():
        quat = None
    if accel is not None and not np.isfinite(accel).any():
        accel = None
    return ImuSeries(
        t_ns.astype(np.int64, copy=False),
        log_t.astype(np.int64, copy=False),
        omega,
        quat,
        topic,
        typ,
        frame,
        accel_b=accel,
        gyro_absent=bool(len(flag)) and bool(np.all(flag == True)),  # noqa: E712
    ), dropped

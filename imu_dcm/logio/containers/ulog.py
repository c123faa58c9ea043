"""PX4 ULog (``.ulg``) logs: gyro, accelerometer and attitude, in the toolkit's frames.

What is read
------------
* Gyro: ``sensor_combined.gyro_rad`` (the autopilot's selected IMU) by default, or the
  highest-rate ``sensor_gyro`` instance where it is more than 10 % faster. ``imu_topic``
  names one: ``sensor_combined``, ``sensor_gyro``, ``sensor_gyro_1`` or ``sensor_gyro[1]``.
  What each gyro topic held (samples, rate) is said in :attr:`LogData.notes`.
* Accelerometer: ``sensor_combined.accelerometer_m_s2`` (m/s²), on the gyro's rows
  (interpolated in time onto a ``sensor_gyro`` series); NaN where PX4 marks it invalid.
* Truth: ``vehicle_attitude_groundtruth`` where present (simulation), else
  ``vehicle_attitude``, which is PX4's own estimate and named as such
  (:attr:`TruthSeries.estimate_of`). ``truth_topic`` names either; ``"none"`` reads none.
* Vehicle state: ``vehicle_land_detected.landed`` and ``actuator_armed.armed`` where the log
  has them, as :attr:`LogData.vehicle_state` (evidence for the rest rule).
* Stamps: ULog stamps are µs since boot; ``t_ns`` is the sample time (``timestamp_sample``
  where the topic has it, else ``timestamp``), ``log_t_ns`` the publication time
  (``timestamp``), both int64 ns.
* The logger's dropouts, multi-instance sensors and estimator resets are listed in the notes.

Frames
------
PX4 states body vectors in FRD, the world in NED and ``q`` as ``[w, x, y, z]`` (FRD to NED).
The reader converts the gyro, the accelerometer and the truth into body FLU, world ENU and
``[x, y, z, w]`` (:mod:`imu_dcm.logio.ned`): a vehicle facing north is 90° about z in ENU.

How it is read
--------------
:mod:`imu_dcm.logio.containers.ulog_scan` walks the ULog message chain itself, in blocks, and
gathers the records of the wanted topics with numpy through the layouts the log's own format
messages declare. Any damaged message (a type the format does not define, a data message of an
unknown subscription or of another size than its format, a size past the end) costs only
itself, and the one before it when its size may be what was damaged: the walk resumes at the
next sound messages (:mod:`imu_dcm.logio.containers.ulog_resync`) and each damaged part is
listed in
:attr:`LogData.damage` with its byte offset. Appended data and incompatible flags hand the
file to ``pyulog`` (PX4's own parser); the notes say so. A log cut short costs its last
message and is listed too.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from imu_dcm.errors import LogError
from imu_dcm.logio.containers.ulog_scan import Scanned, Topic, scan
from imu_dcm.logio.damage import warn_damage
from imu_dcm.logio.ned import FLU_FROM_FRD, q_enu_flu
from imu_dcm.logio.paths import is_ulog as probe
from imu_dcm.logio.source import ProgressCallback, ReadRequest
from imu_dcm.logio.types import ChannelInfo, ImuSeries, LogData, TruthSeries, VehicleState

__all__ = [
    "GYRO_TOPICS",
    "KIND",
    "PX4_ESTIMATE",
    "STATE_TOPICS",
    "TRUTH_TOPICS",
    "UlogSource",
    "imu_series",
    "open_ulog",
    "probe",
    "truth_series",
]


KIND = "px4 ulog"
GYRO_TOPICS = ("sensor_combined", "sensor_gyro")
TRUTH_TOPICS = ("vehicle_attitude_groundtruth", "vehicle_attitude")
STATE_TOPICS = ("vehicle_land_detected", "actuator_armed")
PX4_ESTIMATE = "PX4's own estimate"
#: PX4's RELATIVE_TIMESTAMP_INVALID in ``sensor_combined.accelerometer_timestamp_relative``.
_ACCEL_INVALID = 0x7FFFFFFF


# ------------------------------------------------------------------------ the series
def _split_name(text: str) -> tuple[str, int | None]:
    """``sensor_gyro_1`` / ``sensor_gyro[1]`` -> ("sensor_gyro", 1); a bare name -> (name, None)."""
    m = re.fullmatch(r"(.+?)(?:_(\d+)|\[(\d+)\])", text)
    if m:
        return m.group(1), int(m.group(2) or m.group(3))
    return text, None


def _labeller(counts: dict[tuple[str, int, str], int]):
    """Labels as said to the user: ``name`` for a single instance, ``name_k`` for several."""
    multi = {n for n, i, _ in counts if i > 0}
    return lambda name, inst: f"{name}_{inst}" if name in multi else name


def _rate_hz(t_us: NDArray) -> float:
    """The median rate of the steps forward, Hz."""
    d = np.diff(np.asarray(t_us, dtype=np.int64))
    d = d[d > 0]
    return 1e6 / float(np.median(d)) if len(d) else 0.0


def _vec(t: Topic, names: tuple[str, ...]) -> NDArray[np.float64]:
    return np.stack([np.asarray(t.fields[n], dtype=np.float64) for n in names], axis=1)


def _sample_us(t: Topic) -> NDArray[np.int64]:
    """``timestamp_sample`` where the topic has it (and it is set), else ``timestamp``."""
    ts = t.fields["timestamp"].astype(np.int64)
    s = t.fields.get("timestamp_sample")
    if s is None:
        return ts
    s = s.astype(np.int64)
    return np.where(s > 0, s, ts)


def _omega_frd(t: Topic) -> NDArray[np.float64] | None:
    if t.name == "sensor_combined" and "gyro_rad[2]" in t.fields:
        return _vec(t, ("gyro_rad[0]", "gyro_rad[1]", "gyro_rad[2]"))
    if t.name == "sensor_gyro" and "z" in t.fields:
        return _vec(t, ("x", "y", "z"))
    return None


def _pick_gyro(topics: list[Topic], label, imu_topic: str | None) -> tuple[Topic, str]:
    """The gyro topic (see the module doc) and a note listing every gyro topic found."""
    gyros = [t for t in topics if t.name in GYRO_TOPICS and len(t) and _omega_frd(t) is not None]
    gyros.sort(key=lambda t: (t.name != "sensor_combined", t.multi_id))
    if not gyros:
        raise LogError(
            "Expected a gyro topic (sensor_combined or sensor_gyro) in the ULog, got none"
        )
    rates = {id(t): _rate_hz(_sample_us(t)) for t in gyros}
    if imu_topic is not None:
        name, inst = _split_name(imu_topic)
        found = [t for t in gyros if t.name == name and t.multi_id == (inst or 0)]
        if not found:
            have = ", ".join(label(t.name, t.multi_id) for t in gyros)
            raise LogError(f"Expected gyro topic {imu_topic!r} in the ULog, got {have}")
        chosen = found[0]
    else:
        chosen = gyros[0]
        fastest = max(gyros, key=lambda t: rates[id(t)])
        if fastest.name == "sensor_gyro" and rates[id(fastest)] > 1.1 * rates[id(chosen)]:
            chosen = fastest
    listed = "; ".join(
        f"{label(t.name, t.multi_id)}: {len(t)} samples at {rates[id(t)]:.3g} Hz" for t in gyros
    )
    used = f"used {label(chosen.name, chosen.multi_id)} at {rates[id(chosen)]:.3g} Hz"
    return chosen, f"{listed}; {used}" if len(gyros) > 1 else used


def _accel(gyro: Topic, topics: list[Topic], t_ns: NDArray[np.int64]) -> NDArray | None:
    """sensor_combined's accelerometer (m/s², FLU) on the gyro's rows, NaN where invalid."""
    comb = next((t for t in topics if t.name == "sensor_combined" and len(t)), None)
    if comb is None or "accelerometer_m_s2[2]" not in comb.fields:
        return None
    a = _vec(comb, tuple(f"accelerometer_m_s2[{i}]" for i in range(3))) * FLU_FROM_FRD
    rel = comb.fields.get("accelerometer_timestamp_relative")
    if rel is not None:
        a[rel.astype(np.int64) == _ACCEL_INVALID] = np.nan
    if gyro is comb:
        return a
    # PX4 stamps the accelerometer at timestamp + accelerometer_timestamp_relative (µs)
    t_us = comb.fields["timestamp"].astype(np.int64)
    if rel is not None:
        t_us = t_us + np.where(rel.astype(np.int64) == _ACCEL_INVALID, 0, rel.astype(np.int64))
    good = np.all(np.isfinite(a), axis=1)
    t_acc, a = t_us[good] * 1000, a[good]
    out = np.full((len(t_ns), 3), np.nan)
    if len(t_acc) < 2:
        return out
    order = np.argsort(t_acc, kind="stable")
    t_acc, a = t_acc[order], a[order]
    inside = (t_ns >= t_acc[0]) & (t_ns <= t_acc[-1])
    for i in range(3):
        out[inside, i] = np.interp(t_ns[inside], t_acc, a[:, i])
    return out


def _vehicle_state(topics: list[Topic]) -> VehicleState | None:
    """``vehicle_land_detected.landed`` and ``actuator_armed.armed`` (instance 0), or None."""

    def steps(name: str, field_name: str):
        t = next((t for t in topics if t.name == name and t.multi_id == 0 and len(t)), None)
        if t is None or field_name not in t.fields:
            return None
        return t.fields["timestamp"].astype(np.int64) * 1000, t.fields[field_name]

    landed, armed = steps(*STATE_TOPICS[:1], "landed"), steps(STATE_TOPICS[1], "armed")
    used = [n for n, x in zip(STATE_TOPICS, (landed, armed), strict=True) if x is not None]
    return VehicleState.of(", ".join(used), landed, armed)


def imu_series(gyro: Topic, topics: list[Topic], label) -> ImuSeries:
    """The gyro (rad/s) and accelerometer in body FLU, stamps in ns."""
    t_ns = _sample_us(gyro) * 1000
    omega_flu = _omega_frd(gyro) * FLU_FROM_FRD
    return ImuSeries(
        t_ns=t_ns,
        log_t_ns=gyro.fields["timestamp"].astype(np.int64) * 1000,
        omega_b=omega_flu,
        orientation_xyzw=None,
        topic=label(gyro.name, gyro.multi_id),
        type=gyro.name,
        frame_id="body",
        accel_b=_accel(gyro, topics, t_ns),
        log_axes="FRD",
    )


def truth_series(t: Topic, label, auto: bool) -> TruthSeries:
    estimate_of = "" if t.name == "vehicle_attitude_groundtruth" else PX4_ESTIMATE
    return TruthSeries(
        t_ns=_sample_us(t) * 1000,
        log_t_ns=t.fields["timestamp"].astype(np.int64) * 1000,
        q_w_b=q_enu_flu(_vec(t, tuple(f"q[{i}]" for i in range(4)))),
        topic=label(t.name, t.multi_id),
        type=t.name,
        frame_id="world",
        child_frame_id="body",
        auto=auto,
        estimate_of=estimate_of,
    )


def _pick_truth(topics: list[Topic], label, truth_topic: str | None) -> tuple[list[Topic], str]:
    """Attitude topics, the chosen one first (empty when none or ``"none"``), and a note."""
    att = [t for t in topics if t.name in TRUTH_TOPICS and len(t) and "q[3]" in t.fields]
    att.sort(key=lambda t: (TRUTH_TOPICS.index(t.name), t.multi_id))
    if truth_topic == "none":
        return [], ""
    if truth_topic is not None:
        name, inst = _split_name(truth_topic)
        found = [t for t in att if t.name == name and t.multi_id == (inst or 0)]
        if not found:
            have = ", ".join(label(t.name, t.multi_id) for t in att) or "no attitude topic"
            raise LogError(f"Expected truth topic {truth_topic!r} in the ULog, got {have}")
        att.remove(found[0])
        att.insert(0, found[0])
    if not att:
        return [], "no attitude in the log (vehicle_attitude_groundtruth, vehicle_attitude)"
    first = att[0]
    if first.name == "vehicle_attitude_groundtruth":
        return att, f"truth: {label(first.name, first.multi_id)} (the simulator's attitude)"
    why = "" if truth_topic else " (no vehicle_attitude_groundtruth in the log)"
    return att, f"truth: {label(first.name, first.multi_id)}, {PX4_ESTIMATE}{why}"


# --------------------------------------------------------------------------- notes
def _multi_note(counts: dict[tuple[str, int, str], int]) -> str | None:
    inst: dict[str, set[int]] = {}
    for name, i, _ in counts:
        if name.startswith("sensor_"):
            inst.setdefault(name, set()).add(i)
    multi = [f"{n} x{len(s)}" for n, s in sorted(inst.items()) if len(s) > 1]
    return f"multi-instance sensors: {', '.join(multi)}" if multi else None


def _dropout_note(s: Scanned) -> str | None:
    if not s.dropouts:
        return None
    ms = [d for _, d in s.dropouts]
    k = int(np.argmax(ms))
    at = (s.dropout_times_us[k] - s.start_us) * 1e-6 if k < len(s.dropout_times_us) else np.nan
    return (
        f"the logger dropped data {len(ms)} time{'s' if len(ms) > 1 else ''}: {sum(ms)} ms in "
        f"all, the longest {ms[k]} ms at {at:.3f} s into the log"
    )


def _reset_note(t: Topic, label, start_us: int) -> str | None:
    c = t.fields.get("quat_reset_counter")
    if c is None or len(c) < 2:
        return None
    steps = np.flatnonzero(np.diff(c.astype(np.int64)) != 0) + 1
    if not len(steps):
        return None
    at = ", ".join(f"{(x - start_us) * 1e-6:.3f}" for x in _sample_us(t)[steps[:5]])
    more = " ..." if len(steps) > 5 else ""
    return (
        f"{label(t.name, t.multi_id)}: the estimator reset its attitude {len(steps)} "
        f"time{'s' if len(steps) > 1 else ''} (quat_reset_counter) at {at}{more} s into the log"
    )


def _timed(topics: list[Topic], label) -> tuple[list[Topic], str | None]:
    """The topics whose format has a ``timestamp`` field, and a note naming the gyro and
    attitude topics without one (skipped). Refused in one line when no gyro topic is left."""
    bad = [t for t in topics if "timestamp" not in t.fields and len(t.positions)]
    if not bad:
        return topics, None
    good = [t for t in topics if "timestamp" in t.fields]
    names = ", ".join(label(t.name, t.multi_id) for t in bad)
    if not any(t.name in GYRO_TOPICS and _omega_frd(t) is not None for t in good):
        gyro = [label(t.name, t.multi_id) for t in bad if t.name in GYRO_TOPICS]
        if gyro:
            raise LogError(
                f"Expected a timestamp field in the format of {', '.join(gyro)} in the ULog, "
                "got none"
            )
    return good, f"skipped (their format has no timestamp field): {names}"


# --------------------------------------------------------------------------- source
class UlogSource:
    """One PX4 ULog file (see the module doc for what is read and how frames convert)."""

    kind = KIND

    def __init__(self, path: Path, progress: ProgressCallback | None = None):
        self.path = Path(path)
        self.progress = progress

    def read(self, request: ReadRequest) -> LogData:
        wanted = set(GYRO_TOPICS + TRUTH_TOPICS + STATE_TOPICS)
        for named in (request.imu_topic, request.truth_topic):
            if named and named != "none":
                wanted.add(_split_name(named)[0])
        progress = request.progress or self.progress
        s = scan(self.path, frozenset(wanted), progress)
        label = _labeller(s.counts)
        topics, untimed = _timed(s.topics, label)
        gyro, gyro_note = _pick_gyro(topics, label, request.imu_topic)
        imu = imu_series(gyro, topics, label)
        att, truth_note = _pick_truth(topics, label, request.truth_topic)
        auto = request.truth_topic is None
        series = [truth_series(t, label, auto) for t in att]
        notes = [untimed, gyro_note, truth_note, _multi_note(s.counts), _dropout_note(s)]
        notes += [_reset_note(t, label, s.start_us) for t in att] + s.notes
        channels = tuple(
            ChannelInfo(label(n, i), fmt, "ulog", c) for (n, i, fmt), c in sorted(s.counts.items())
        )
        # once the log is known to be usable
        stopped_at = warn_damage(self.path, s.damage, diagnostics=request.diagnostics)
        if progress is not None:
            progress(1.0)
        return LogData(
            path=self.path,
            imu=imu,
            truth=series[0] if series else None,
            channels=channels,
            custom_data={k: v for k, v in s.info.items() if len(v) < 200},
            container=KIND,
            damage=tuple(s.damage),
            stopped_at=stopped_at,
            truth_candidates=tuple(series[1:]),
            notes=tuple(n for n in notes if n),
            vehicle_state=_vehicle_state(topics),
        )


def open_ulog(path: Path, progress: ProgressCallback | None = None) -> UlogSource:
    return UlogSource(path, progress)

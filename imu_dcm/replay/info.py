"""``info``: what a log holds, read the way the replay reads it (``imu-dcm-replay info LOG``).

One reading serves both: :func:`log_info` opens the log through the container table and the
readers' own channel selection (:func:`imu_dcm.logio.read_log`), so the gyro and the truth it
names are the ones a replay would take. Only the channels that can be the gyro or a truth are
decoded; every other channel's count comes from the container's index or summary (MCAP
statistics, rosbag2 ``metadata.yaml``, sqlite3 rows, ROS 1 connection records, ULog and DataFlash
message tables), and its rate is the mean over the log's span (marked ``~``).

Times are seconds from the log's start: the first gyro header stamp (the origin of
``--score-window`` and of the replay's gap lines).

The autopilot's landed and armed state (:attr:`imu_dcm.logio.LogData.vehicle_state`: PX4's
``vehicle_land_detected`` and ``actuator_armed``, ArduPilot's arm and land events) is listed as
the spans where each held true: evidence the replay's rest rule uses (a window with the vehicle
airborne is no rest; landed and disarmed throughout supports one).
"""

from __future__ import annotations

import json
import re
import sys
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from imu_dcm.app.options import OneLineArgumentParser
from imu_dcm.integrator.batch import find_gaps, gap_message
from imu_dcm.logio import read_log
from imu_dcm.logio.intervals import declared_intervals
from imu_dcm.replay.kinds import ESTIMATE, POSITIONS, truth_kind

#: Channels that give a position and no attitude: by type, or the position estimates of PX4 and
#: ArduPilot by name (a truth candidate a user may look for, and that cannot score an attitude).
_POSITION_TYPES = ("geometry_msgs/msg/PointStamped", "asl data.csv (positions)")
_POSITION_NAME = re.compile(
    r"^(vehicle_(local|global|gps)_position|POS|GPS|/ground_truth/.*position.*)$"
)


@dataclass(frozen=True, slots=True)
class Channel:
    """One channel: ``count`` messages; ``rate_hz`` and ``duration_s`` exact (from its decoded
    stamps) when ``exact``, else the mean over the log's span (``duration_s`` None)."""

    topic: str
    type: str
    count: int
    rate_hz: float | None
    duration_s: float | None
    exact: bool
    role: str = ""


@dataclass(frozen=True, slots=True)
class Truth:
    """A truth candidate: ``kind`` (:func:`truth_kind` or :data:`POSITIONS`), who estimated it
    (``about``), whether the replay takes it (``picked``)."""

    topic: str
    type: str
    kind: str
    about: str
    picked: bool
    count: int


@dataclass(frozen=True, slots=True)
class Interval:
    """Intervals the metadata declares: ``spans_s`` seconds from the log's start."""

    name: str
    key: str
    spans_s: tuple[tuple[float, float], ...]


@dataclass(frozen=True, slots=True)
class Vehicle:
    """The autopilot's landed and armed state, evidence for rest: ``landed_s`` and ``armed_s``
    the spans (s from the log's start, the last to the log's end) where each held true;
    ``rows`` the state rows logged; ``source`` where they came from."""

    source: str
    rows: int
    landed_s: tuple[tuple[float, float], ...]
    armed_s: tuple[tuple[float, float], ...]


@dataclass(frozen=True, slots=True)
class LogInfo:
    """What :func:`log_info` found. ``gaps`` are (start s, length s) of the gyro's stamps."""

    path: str
    container: str
    span_s: float
    channels: tuple[Channel, ...]
    gyro: str
    gyro_frame: str
    gyro_count: int
    gyro_rate_hz: float | None
    gyro_duration_s: float | None
    gaps: tuple[tuple[float, float], ...]
    accel: str
    truths: tuple[Truth, ...]
    intervals: tuple[Interval, ...]
    notes: tuple[str, ...]
    damage: str | None
    vehicle: Vehicle | None = None


def _stats(t_ns: np.ndarray) -> tuple[float | None, float | None]:
    """(rate Hz, duration s) of sorted-or-not stamps, None when fewer than two."""
    if len(t_ns) < 2:
        return None, None
    span = (int(t_ns.max()) - int(t_ns.min())) * 1e-9
    return ((len(t_ns) - 1) / span if span > 0 else None), span


def _series(data) -> dict[str, np.ndarray]:
    """Decoded stamps by topic: the gyro's and every attitude candidate's."""
    out = {data.imu.topic: data.imu.t_ns}
    for t in (data.truth, *data.truth_candidates):
        if t is not None and t.topic not in out:
            out[t.topic] = t.t_ns
    return out


def _span_s(data) -> float:
    logs = [data.imu.log_t_ns] + [t.log_t_ns for t in (data.truth, *data.truth_candidates) if t]
    t = np.concatenate([x for x in logs if len(x)])
    return (int(t.max()) - int(t.min())) * 1e-9 if len(t) else 0.0


def _is_positions(topic: str, typ: str) -> bool:
    return typ in _POSITION_TYPES or bool(_POSITION_NAME.match(topic))


def _base(topic: str) -> str:
    """A DataFlash message of an instance (``IMU[0]``) lives in the channel ``IMU``."""
    return topic.split("[", 1)[0]


def _channels(data, span_s: float, roles: dict[str, str]) -> tuple[Channel, ...]:
    decoded = _series(data)
    rows = []
    for c in data.channels:
        role = roles.get(c.topic) or roles.get(_base(c.topic), "")
        role = role or ("positions" if _is_positions(c.topic, c.type) else "")
        if c.topic in decoded:
            rate, dur = _stats(decoded[c.topic])
            rows.append(Channel(c.topic, c.type, c.count, rate, dur, True, role))
        else:
            rate = c.count / span_s if span_s > 0 and c.count > 1 else None
            rows.append(Channel(c.topic, c.type, c.count, rate, None, False, role))
    return tuple(rows)


def _truths(data) -> tuple[Truth, ...]:
    out = []
    for k, t in enumerate(x for x in (data.truth, *data.truth_candidates) if x is not None):
        kind = truth_kind(t.estimate_of)
        out.append(Truth(t.topic, t.type, kind, t.estimate_of, k == 0, len(t.t_ns)))
    named = {t.topic for t in out}
    for c in data.channels:
        if c.topic not in named and _is_positions(c.topic, c.type):
            out.append(Truth(c.topic, c.type, POSITIONS, "", False, c.count))
    return tuple(out)


def _accel(imu) -> str:
    if imu.accel_b is None:
        return "none (rests are judged from the gyro alone)"
    n = int(np.isfinite(imu.accel_b).all(axis=1).sum())
    return f"{imu.topic}: {n} samples on the gyro's rows"


def _true_spans(t_s, held, end_s: float) -> tuple[tuple[float, float], ...]:
    """Where a held flag (1 true, 0 false, -1 unknown) is true: from the row it becomes 1 to the
    row it becomes 0, or to ``end_s``; within ``[0, end_s]``."""
    spans, start = [], None
    for ti, v in zip(t_s.tolist(), held.tolist(), strict=True):
        if v == 1 and start is None:
            start = ti
        elif v == 0 and start is not None:
            spans.append((start, ti))
            start = None
    if start is not None:
        spans.append((start, end_s))
    # the state may begin before the gyro: spans are kept to the log, [0, end_s]
    return tuple((max(a, 0.0), min(b, end_s)) for a, b in spans if b > 0.0 and a < end_s)


def _vehicle(state, t0_ns: int, end_ns: int) -> Vehicle | None:
    if state is None:
        return None
    landed, armed = state.at(state.t_ns)  # the state after each row
    t_s = (state.t_ns - t0_ns) * 1e-9
    end_s = (end_ns - t0_ns) * 1e-9
    spans = (_true_spans(t_s, x, end_s) for x in (landed, armed))
    return Vehicle(state.source, len(state.t_ns), *spans)


def _intervals(data, t0_ns: int) -> tuple[Interval, ...]:
    out = []
    for d in declared_intervals(data.custom_data):
        spans = tuple(((a - t0_ns) * 1e-9, (b - t0_ns) * 1e-9) for a, b in d.spans_ns)
        out.append(Interval(d.name, d.key, spans))
    return tuple(out)


def log_info(path: str | Path) -> LogInfo:
    """What ``path`` holds, read as the replay reads it (see the module docstring).

    Raises
    ------
    LogError
        What the replay would refuse (no gyro, an unreadable container), in one line.
    """
    data = read_log(path)
    imu = data.imu
    t0 = int(imu.t_ns.min()) if len(imu.t_ns) else 0
    t_s = np.sort(imu.t_ns - t0) * 1e-9
    roles = {imu.topic: "gyro"}
    for t in _truths(data):
        if t.kind != POSITIONS:
            roles.setdefault(t.topic, "truth" if t.picked else "truth candidate")
    roles.update({_base(k): f"{v} ({k})" for k, v in list(roles.items()) if _base(k) != k})
    span = _span_s(data)
    return LogInfo(
        str(data.path),
        data.container,
        span,
        _channels(data, span, roles),
        imu.topic,
        imu.frame_id,
        len(imu.t_ns),
        *_stats(imu.t_ns),
        find_gaps(t_s),
        _accel(imu),
        _truths(data),
        _intervals(data, t0),
        data.notes,
        data.stopped_at,
        _vehicle(data.vehicle_state, t0, int(imu.t_ns.max()) if len(imu.t_ns) else 0),
    )


# ------------------------------------------------------------------------------ showing
def _rate(c: Channel) -> str:
    if c.rate_hz is None:
        return "-"
    return f"{'' if c.exact else '~'}{c.rate_hz:.4g} Hz"


def _truth_line(t: Truth) -> str:
    about = f" ({t.about})" if t.about and t.kind == ESTIMATE else ""
    picked = ", the replay's truth" if t.picked else ""
    return f"{t.topic} [{t.type}]: {t.kind}{about}, {t.count} messages{picked}"


def _spans(spans) -> str:
    return ", ".join(f"{a:.2f}-{b:.2f} s" for a, b in spans) if spans else "never"


def _vehicle_line(v: Vehicle | None) -> str:
    if v is None:
        return "none (no landed or armed state: rests are judged without it)"
    return (
        f"{v.source}: landed {_spans(v.landed_s)}; armed {_spans(v.armed_s)} ({v.rows} rows; "
        "rest evidence: a window with the vehicle airborne is not rest)"
    )


def format_info(info: LogInfo) -> list[str]:
    """The lines ``info`` prints."""
    lines = [f"log        {info.path} ({info.container}), {info.span_s:.2f} s"]
    width = max((len(c.topic) for c in info.channels), default=5)
    tw = max((len(c.type) for c in info.channels), default=4)
    lines.append(f"channels   {len(info.channels)} (rate ~: mean over the log's span)")
    for c in info.channels:
        dur = f"{c.duration_s:.2f} s" if c.duration_s is not None else "-"
        role = f"  {c.role}" if c.role else ""
        lines.append(
            f"  {c.topic:<{width}}  {c.type:<{tw}}  {c.count:>8}  {_rate(c):>11}  {dur:>9}{role}"
        )
    frame = f", frame {info.gyro_frame}" if info.gyro_frame else ""
    rate = f", {info.gyro_rate_hz:.4g} Hz" if info.gyro_rate_hz else ""
    dur = f", {info.gyro_duration_s:.2f} s" if info.gyro_duration_s else ""
    lines.append(
        f"gyro       {info.gyro}{frame}: {info.gyro_count} samples{rate}{dur} (the replay's gyro)"
    )
    lines.append(f"gaps       {gap_message(info.gaps) if info.gaps else 'none'}")
    lines.append(f"accel      {info.accel}")
    lines.append(f"vehicle    {_vehicle_line(info.vehicle)}")
    if not info.truths:
        lines.append("truth      none")
    for k, t in enumerate(info.truths):
        lines.append(f"{'truth' if k == 0 else '':<10} {_truth_line(t)}")
    for iv in info.intervals:
        spans = ", ".join(f"{a:.2f}-{b:.2f} s" for a, b in iv.spans_s)
        lines.append(f"intervals  {iv.name}: {len(iv.spans_s)} ({spans}) [{iv.key}]")
    if info.damage:
        lines.append(f"damage     {info.damage}")
    for k, note in enumerate(info.notes):
        lines.append(f"{'notes' if k == 0 else '':<10} {note}")
    return lines


def info_main(argv: list[str], prog: str) -> int:
    """The ``info`` sub-command: prints :func:`format_info`, or the JSON with ``--json``."""

    p = OneLineArgumentParser(
        prog=f"{prog} info",
        description="Say what a log holds: every channel (type, count, rate, duration), the "
        "gyro the replay would take, its gaps, the accelerometer, the autopilot's landed and "
        "armed state, each truth candidate and what it is, and the intervals the metadata "
        "declares. Reads only the gyro and truth "
        "channels; the rest is counted from the container's index.",
    )
    p.add_argument("log", help="a log of any container the replay reads")
    p.add_argument("--json", action="store_true", help="print the same as JSON on stdout")
    a = p.parse_args(argv)
    info = log_info(a.log)
    if a.json:
        json.dump(asdict(info), sys.stdout, indent=1)
        sys.stdout.write("\n")
    else:
        print("\n".join(format_info(info)))
    return 0

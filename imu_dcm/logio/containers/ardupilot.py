"""ArduPilot DataFlash (``.bin``) logs: gyro, accelerometer and attitude, in the toolkit's frames.

What is read
------------
* Gyro: the ``IMU`` message's ``GyrX``, ``GyrY``, ``GyrZ`` (rad/s), first instance by default;
  ``imu_topic`` names another: ``IMU[1]`` (the ``I`` column of current logs, or the ``IMU2``
  message of older ones) or ``IMU2``. Every instance found is listed in :attr:`LogData.notes`.
* Accelerometer: ``AccX``, ``AccY``, ``AccZ`` (m/s²) of the same rows.
* Truth: ``SIM`` where present (the simulator's attitude in SITL logs), else ``ATT``: roll,
  pitch and yaw in degrees, ArduPilot's own estimate, named as such
  (:attr:`TruthSeries.estimate_of`); ``AHR2`` (its backup estimator) is kept as a candidate.
  ``truth_topic`` names one; ``"none"`` reads none.
* Vehicle state (:attr:`LogData.vehicle_state`, evidence for the rest rule): the ``EV``
  events ARMED (10), DISARMED (11), LAND_COMPLETE (18) and NOT_LANDED (28) (ArduPilot's
  ``LogEvent`` ids in ``AP_Logger.h``), ``ARM.ArmState``, and ``STAT.Armed`` and
  ``STAT.isFlying`` (landed is not flying) where the log has them.
* Stamps: ``TimeUS`` (µs since boot; logs since 2015) or ``TimeMS`` (ms; logs of 2013-2015)
  as int64 ns, for both ``t_ns`` and ``log_t_ns``. A message with neither is refused (IMU) or
  skipped with a note (truth), as is a column whose FMT types it a string.

Frames: body FRD, world NED, Euler angles in the 3-2-1 sequence; the gyro, accelerometer and
truth are converted to body FLU, world ENU, ``[x, y, z, w]`` (:mod:`imu_dcm.logio.ned`).

How it is read: :mod:`imu_dcm.logio.containers.dataflash` indexes the records of every message type,
resynchronising after a damaged record (each damaged part is counted and said once, with its
byte offset); the wanted types are then decoded in bulk with numpy through the layouts the
log's FMT records declare (no per-message Python objects). The format characters' sizes and
multipliers are pymavlink's (ArduPilot's own reader), an optional extra:
``pip install 'imu_dcm[mavlink]'``.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from imu_dcm.errors import LogError
from imu_dcm.logio.containers.dataflash import Format, Index, index_log
from imu_dcm.logio.damage import warn_damage
from imu_dcm.logio.ned import FLU_FROM_FRD, q_enu_flu, q_wxyz_from_euler_deg
from imu_dcm.logio.paths import DATAFLASH_MAGIC as MAGIC
from imu_dcm.logio.paths import is_dataflash as probe
from imu_dcm.logio.source import ProgressCallback, ReadRequest
from imu_dcm.logio.types import (
    ChannelInfo,
    Damage,
    ImuSeries,
    LogData,
    TruthSeries,
    VehicleState,
)

__all__ = [
    "ARDUPILOT_ESTIMATE",
    "EVENTS",
    "INSTALL",
    "KIND",
    "MAGIC",
    "TRUTHS",
    "DataFlashSource",
    "decode",
    "imu_series",
    "numbers",
    "open_dataflash",
    "probe",
    "stamps_ns",
    "truth_series",
]


KIND = "ardupilot dataflash"
#: Every binary DataFlash log opens with the FMT record describing FMT itself.
ARDUPILOT_ESTIMATE = "ArduPilot's own estimate"
TRUTHS = ("SIM", "ATT", "AHR2")
#: ArduPilot's LogEvent ids (AP_Logger.h) that set the armed or landed state: id -> (which, value)
EVENTS = {10: ("armed", 1), 11: ("armed", 0), 18: ("landed", 1), 28: ("landed", 0)}
INSTALL = "pip install 'imu_dcm[mavlink]'"
_NP = {  # struct codes of pymavlink's FORMAT_TO_STRUCT -> numpy
    "b": "i1",
    "B": "u1",
    "h": "<i2",
    "H": "<u2",
    "i": "<i4",
    "I": "<u4",
    "q": "<i8",
    "Q": "<u8",
    "f": "<f4",
    "d": "<f8",
    "e": "<f2",
    "4s": "S4",
    "16s": "S16",
    "64s": "S64",
}


def _dfreader():
    try:
        from pymavlink import DFReader  # lazy: the optional mavlink extra (93 MB installed)
    except ImportError:
        raise LogError(
            f"Expected pymavlink to read an ArduPilot DataFlash log, got none installed; {INSTALL}"
        ) from None
    return DFReader


# ----------------------------------------------------------------------------- decode
def _dtype(fmt: Format, struct_codes: dict) -> np.dtype:
    codes = [struct_codes[c][0] for c in fmt.format]
    return np.dtype([(n, _NP[c]) for n, c in zip(fmt.columns, codes, strict=True)])


def decode(index: Index, name: str, struct_codes: dict) -> tuple[dict[str, NDArray], int]:
    """Every record of message ``name`` as columns (the format characters' multipliers
    applied), and how many records were cut short by the end of the file."""
    type_id = index.name_to_id.get(name)
    if type_id is None:
        return {}, 0
    fmt = index.formats[type_id]
    dtype = _dtype(fmt, struct_codes)
    offs = index.offsets.get(type_id, np.zeros(0, np.int64))
    whole = offs + 3 + dtype.itemsize <= len(index.data)
    offs = offs[whole]
    rows = np.zeros((0, dtype.itemsize), np.uint8)
    if len(offs):  # whole records only, so the window fits the data
        rows = np.lib.stride_tricks.sliding_window_view(index.data, dtype.itemsize)[offs + 3]
    rec = np.ascontiguousarray(rows).view(dtype)[:, 0]
    cols = {}
    for col, mult in zip(dtype.names, fmt.mults, strict=True):
        cols[col] = rec[col] * mult if mult is not None else rec[col]
    return cols, int(np.count_nonzero(~whole))


def stamps_ns(cols: dict[str, NDArray], what: str) -> NDArray[np.int64]:
    """``TimeUS`` (µs, logs since 2015) or ``TimeMS`` (ms, 2013-2015 logs) as int64 ns."""
    for col, ns in (("TimeUS", 1000), ("TimeMS", 1_000_000)):
        if col in cols:
            return numbers(cols, col, what).astype(np.int64) * ns
    raise LogError(
        f"Expected a TimeUS or TimeMS column in {what} of the DataFlash log, got "
        f"{', '.join(cols) or 'no columns'}"
    )


def numbers(cols: dict[str, NDArray], col: str, what: str) -> NDArray:
    """Column ``col`` of message ``what``, refused in one line unless its FMT types it a number."""
    v = cols[col]
    if v.dtype.kind not in "iuf":
        raise LogError(
            f"Expected numbers in {what}.{col} of the DataFlash log, got its FMT typing it "
            f"{v.dtype.kind == 'S' and 'a string' or 'an array'}"
        )
    return v


# ------------------------------------------------------------------------ the series
def _instances(index: Index, struct_codes) -> tuple[dict[str, dict[str, NDArray]], int]:
    """IMU instances by label (``IMU[0]``, ``IMU[1]``, ...), from the ``I`` column or the
    ``IMU2``/``IMU3`` messages of older logs; and the IMU records cut short."""
    out: dict[str, dict[str, NDArray]] = {}
    cols, cut = decode(index, "IMU", struct_codes)
    if cols and "I" in cols:
        inst = cols["I"].astype(np.int64)
        for k in np.unique(inst).tolist():
            sel = inst == k
            out[f"IMU[{k}]"] = {c: v[sel] for c, v in cols.items()}
    elif cols:
        out["IMU[0]"] = cols
    for k in (2, 3):
        more, _ = decode(index, f"IMU{k}", struct_codes)
        if more:
            out[f"IMU[{k - 1}]"] = more
    return out, cut


def _rate_hz(t_ns: NDArray) -> float:
    """The median step between distinct stamps, as Hz (a sort: numpy's unique hashes, 3 s for
    2 M stamps)."""
    d = np.diff(np.sort(t_ns))
    d = d[d > 0]
    return 1e9 / float(np.median(d)) if len(d) else 0.0


def _pick_imu(imus: dict, imu_topic: str | None, names=()) -> tuple[str, str]:
    have = [k for k, v in imus.items() if "GyrZ" in v and len(v["GyrZ"])]
    if not have:
        listed = ", ".join(sorted(names)[:40]) or "no message declared"
        raise LogError(
            f"Expected IMU messages (GyrX, GyrY, GyrZ) in the DataFlash log, got none "
            f"(its messages: {listed})"
        )
    if imu_topic is None:
        chosen = "IMU[0]" if "IMU[0]" in have else have[0]
    else:
        m = re.fullmatch(r"IMU(\d)?(?:\[(\d+)\])?", imu_topic)
        chosen = ""
        if m and not (m.group(1) and m.group(2)):
            k = int(m.group(2)) if m.group(2) else max(int(m.group(1) or 1) - 1, 0)
            chosen = f"IMU[{k}]"
        if chosen not in have:
            raise LogError(
                f"Expected IMU topic {imu_topic!r} in the DataFlash log, got {', '.join(have)}"
            )
    t = {k: stamps_ns(imus[k], k) for k in have}
    listed = "; ".join(f"{k}: {len(t[k])} samples at {_rate_hz(t[k]):.3g} Hz" for k in have)
    return chosen, f"{listed}; used {chosen}" if len(have) > 1 else f"used {chosen}"


def _xyz(cols: dict[str, NDArray], names: tuple[str, str, str], what: str) -> NDArray:
    return np.stack([numbers(cols, c, what).astype(np.float64) for c in names], axis=1)


def imu_series(cols: dict[str, NDArray], label: str) -> ImuSeries:
    """The gyro (and accelerometer, where the FMT has it) of one IMU instance, FRD as FLU."""
    t_ns = stamps_ns(cols, label)
    omega = _xyz(cols, ("GyrX", "GyrY", "GyrZ"), label)
    accel = None
    if all(c in cols for c in ("AccX", "AccY", "AccZ")):
        accel = _xyz(cols, ("AccX", "AccY", "AccZ"), label) * FLU_FROM_FRD
    return ImuSeries(
        t_ns=t_ns,
        log_t_ns=t_ns.copy(),
        omega_b=omega * FLU_FROM_FRD,
        orientation_xyzw=None,
        topic=label,
        type="IMU",
        frame_id="body",
        accel_b=accel,
        log_axes="FRD",
    )


def truth_series(name: str, cols: dict[str, NDArray], auto: bool) -> TruthSeries:
    """Roll, pitch, yaw (degrees, FRD to NED) as ``q_w_b`` FLU to ENU."""
    rpy = _xyz(cols, ("Roll", "Pitch", "Yaw"), name)
    q = q_wxyz_from_euler_deg(rpy[:, 0], rpy[:, 1], rpy[:, 2])
    t_ns = stamps_ns(cols, name)
    estimate_of = "" if name == "SIM" else ARDUPILOT_ESTIMATE
    if name == "AHR2":
        estimate_of = f"{ARDUPILOT_ESTIMATE} (its backup estimator, AHR2)"
    return TruthSeries(
        t_ns=t_ns,
        log_t_ns=t_ns.copy(),
        q_w_b=q_enu_flu(q),
        topic=name,
        type=name,
        frame_id="world",
        child_frame_id="body",
        auto=auto,
        estimate_of=estimate_of,
    )


def _truths(index: Index, struct_codes, truth_topic: str | None) -> tuple[list[TruthSeries], list]:
    """The attitude messages found (the one named first), and notes: what was taken, and each
    one skipped with why."""
    if truth_topic == "none":
        return [], []
    names = list(TRUTHS)
    if truth_topic is not None:
        if truth_topic not in index.name_to_id:
            have = ", ".join(n for n in TRUTHS if n in index.name_to_id) or "no attitude message"
            raise LogError(f"Expected truth topic {truth_topic!r} in the DataFlash log, got {have}")
        names = [truth_topic] + [n for n in TRUTHS if n != truth_topic]
    found, notes = [], []
    for name in names:
        cols, _ = decode(index, name, struct_codes)
        if not cols or not all(c in cols for c in ("Roll", "Pitch", "Yaw")) or not len(cols["Yaw"]):
            continue
        try:
            found.append(truth_series(name, cols, truth_topic is None))
        except LogError as exc:
            if name == truth_topic:
                raise
            notes.append(f"{name} skipped as truth: {exc}")
    if truth_topic is not None and (not found or found[0].topic != truth_topic):
        raise LogError(
            f"Expected Roll, Pitch and Yaw in {truth_topic} of the DataFlash log, got none"
        )
    if not found:
        return [], [*notes, "no attitude in the log (SIM, ATT, AHR2)"]
    first = found[0]
    if not first.estimate_of:
        return found, [f"truth: {first.topic} (the simulator's attitude)", *notes]
    why = "" if truth_topic else " (no SIM in the log)"
    return found, [f"truth: {first.topic}, {first.estimate_of}{why}", *notes]


def _vehicle_state(index: Index, struct_codes) -> VehicleState | None:
    """The armed and landed state from ``EV``, ``ARM`` and ``STAT`` records (module doc)."""
    steps: dict[str, list[tuple[NDArray, NDArray]]] = {"landed": [], "armed": []}
    used = []
    for name, columns in (("EV", ("Id",)), ("ARM", ("ArmState",)), ("STAT", ("Armed", "isFlying"))):
        cols, _ = decode(index, name, struct_codes)
        if not cols or not all(c in cols for c in columns) or not len(cols[columns[0]]):
            continue
        try:
            t = stamps_ns(cols, name)
            values = [numbers(cols, c, name).astype(np.int64) for c in columns]
        except LogError:
            continue  # a state that cannot be read judges nothing
        if name == "EV":
            for ev, (which, value) in EVENTS.items():
                sel = values[0] == ev
                if sel.any():
                    steps[which].append((t[sel], np.full(int(sel.sum()), value)))
        else:
            steps["armed"].append((t, values[0] != 0))
            if name == "STAT":
                steps["landed"].append((t, values[1] == 0))
        used.append(name)
    merged = {}
    for which, parts in steps.items():
        if parts:
            t = np.concatenate([p[0] for p in parts])
            order = np.argsort(t, kind="stable")
            merged[which] = (t[order], np.concatenate([p[1] for p in parts]).astype(bool)[order])
    return VehicleState.of(", ".join(used), merged.get("landed"), merged.get("armed"))


# --------------------------------------------------------------------------- source
class DataFlashSource:
    """One ArduPilot DataFlash ``.bin`` log (see the module doc)."""

    kind = KIND

    def __init__(self, path: Path, progress: ProgressCallback | None = None):
        self.path = Path(path)
        self.progress = progress

    def read(self, request: ReadRequest) -> LogData:
        progress = request.progress or self.progress
        codes = _dfreader().FORMAT_TO_STRUCT
        try:
            index = index_log(self.path, codes)
        except OSError as exc:
            raise LogError(
                f"Expected a readable DataFlash log, got {exc.strerror or exc} in {self.path}"
            ) from None
        if progress is not None:
            progress(0.5)
        return self._read(index, codes, request, progress)

    def _read(self, index: Index, codes, request: ReadRequest, progress) -> LogData:
        imus, _ = _instances(index, codes)
        names = [f.name for t, f in index.formats.items() if len(index.offsets.get(t, ()))]
        label, imu_note = _pick_imu(imus, request.imu_topic, names)
        imu = imu_series(imus[label], label)
        truths, truth_notes = _truths(index, codes, request.truth_topic)
        damage = list(index.damage)
        cut = index.formats[int(index.data[index.cut_at + 2])].name if index.cut_at else ""
        if cut in {"IMU", "IMU2", "IMU3", *(t.topic for t in truths)}:  # read: its loss said
            damage.append(
                Damage(
                    index.cut_at,
                    f"DataFlash log cut short: its last record ({cut}) incomplete",
                    messages_lost=1,
                )
            )
        stopped_at = warn_damage(self.path, damage, diagnostics=request.diagnostics)
        channels = tuple(
            ChannelInfo(f.name, f.name, "dataflash", len(index.offsets[t]))
            for t, f in sorted(index.formats.items(), key=lambda kv: kv[1].name)
            if len(index.offsets.get(t, ()))
        )
        if progress is not None:
            progress(1.0)
        return LogData(
            path=self.path,
            imu=imu,
            truth=truths[0] if truths else None,
            channels=channels,
            container=KIND,
            damage=tuple(damage),
            stopped_at=stopped_at,
            truth_candidates=tuple(truths[1:]),
            notes=tuple(n for n in (imu_note, *truth_notes) if n),
            vehicle_state=_vehicle_state(index, codes),
        )


def open_dataflash(path: Path, progress: ProgressCallback | None = None) -> DataFlashSource:
    return DataFlashSource(path, progress)

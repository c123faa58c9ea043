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
* Stamps: ``TimeUS`` (µs since boot) as int64 ns, for both ``t_ns`` and ``log_t_ns``.

Frames: body FRD, world NED, Euler angles in the 3-2-1 sequence; the gyro, accelerometer and
truth are converted to body FLU, world ENU, ``[x, y, z, w]`` (:mod:`imu_dcm.logio.ned`).

How it is read: pymavlink's ``DFReader_binary`` (ArduPilot's own reader) indexes the records of
every message type; the wanted types are then decoded in bulk with numpy through the layouts
the log's FMT records declare (no per-message Python objects). pymavlink is an optional extra:
``pip install 'imu_dcm[mavlink]'``.
"""

from __future__ import annotations

import contextlib
import io
import re
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from imu_dcm.errors import LogError
from imu_dcm.logio.damage import warn_damage
from imu_dcm.logio.ned import FLU_FROM_FRD, q_enu_flu, q_wxyz_from_euler_deg
from imu_dcm.logio.paths import DATAFLASH_MAGIC as MAGIC  # noqa: F401 (tests write it)
from imu_dcm.logio.paths import is_dataflash as probe  # noqa: F401 (the reader's probe, here too)
from imu_dcm.logio.source import Progress, ReadRequest
from imu_dcm.logio.types import ChannelInfo, Damage, ImuSeries, LogData, TruthSeries

KIND = "ardupilot dataflash"
#: Every binary DataFlash log opens with the FMT record describing FMT itself.
ARDUPILOT_ESTIMATE = "ArduPilot's own estimate"
TRUTHS = ("SIM", "ATT", "AHR2")
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
        from pymavlink import DFReader
    except ImportError:
        raise LogError(
            f"Expected pymavlink to read an ArduPilot DataFlash log, got none installed; {INSTALL}"
        ) from None
    return DFReader


# ----------------------------------------------------------------------------- decode
def _dtype(fmt, struct_codes: dict) -> np.dtype:
    names = list(fmt.columns)
    codes = [struct_codes[c][0] for c in fmt.format]
    if len(names) != len(codes):
        raise LogError(
            f"Expected as many columns as format characters in {fmt.name}, got "
            f"{len(names)} and {len(codes)}"
        )
    return np.dtype([(n, _NP[c]) for n, c in zip(names, codes, strict=True)])


def decode(df, name: str, struct_codes: dict) -> tuple[dict[str, NDArray], int]:
    """Every record of message ``name`` as columns (pymavlink's multipliers applied), and how
    many records were cut short by the end of the file."""
    type_id = df.name_to_id.get(name)
    if type_id is None:
        return {}, 0
    fmt = df.formats[type_id]
    dtype = _dtype(fmt, struct_codes)
    offs = np.asarray(df.offsets[type_id], dtype=np.int64)
    whole = offs + 3 + dtype.itemsize <= df.data_len
    offs = offs[whole]
    rows = np.zeros((0, dtype.itemsize), np.uint8)
    if len(offs):  # whole records only, so the window fits the data
        b = np.frombuffer(df.data_map, np.uint8)
        try:  # a copy of the records' bytes only (no N x itemsize index matrix)
            rows = np.lib.stride_tricks.sliding_window_view(b, dtype.itemsize)[offs + 3]
        finally:
            del b  # the reader's mmap must have no exported buffer when it closes
    rec = np.ascontiguousarray(rows).view(dtype)[:, 0]
    cols = {}
    for col, mult in zip(dtype.names, fmt.msg_mults, strict=False):
        cols[col] = rec[col] * mult if mult is not None else rec[col]
    return cols, int(np.count_nonzero(~whole))


# ------------------------------------------------------------------------ the series
def _instances(df, struct_codes) -> tuple[dict[str, dict[str, NDArray]], int]:
    """IMU instances by label (``IMU[0]``, ``IMU[1]``, ...), from the ``I`` column or the
    ``IMU2``/``IMU3`` messages of older logs; and the IMU records cut short."""
    out: dict[str, dict[str, NDArray]] = {}
    cols, cut = decode(df, "IMU", struct_codes)
    if cols and "I" in cols:
        inst = cols["I"].astype(np.int64)
        for k in np.unique(inst).tolist():
            sel = inst == k
            out[f"IMU[{k}]"] = {c: v[sel] for c, v in cols.items()}
    elif cols:
        out["IMU[0]"] = cols
    for k in (2, 3):
        more, _ = decode(df, f"IMU{k}", struct_codes)
        if more:
            out[f"IMU[{k - 1}]"] = more
    return out, cut


def _rate_hz(t_us: NDArray) -> float:
    d = np.diff(np.unique(t_us.astype(np.int64)))
    return 1e6 / float(np.median(d)) if len(d) and np.median(d) > 0 else 0.0


def _pick_imu(imus: dict, imu_topic: str | None) -> tuple[str, str]:
    have = [k for k, v in imus.items() if "GyrZ" in v and len(v["GyrZ"])]
    if not have:
        raise LogError("Expected IMU messages (GyrX, GyrY, GyrZ) in the DataFlash log, got none")
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
    listed = "; ".join(
        f"{k}: {len(imus[k]['TimeUS'])} samples at {_rate_hz(imus[k]['TimeUS']):.3g} Hz"
        for k in have
    )
    return chosen, f"{listed}; used {chosen}" if len(have) > 1 else f"used {chosen}"


def imu_series(cols: dict[str, NDArray], label: str) -> ImuSeries:
    t_ns = cols["TimeUS"].astype(np.int64) * 1000
    omega = np.stack([cols[c].astype(np.float64) for c in ("GyrX", "GyrY", "GyrZ")], axis=1)
    accel = None
    if all(c in cols for c in ("AccX", "AccY", "AccZ")):
        accel = np.stack([cols[c].astype(np.float64) for c in ("AccX", "AccY", "AccZ")], axis=1)
        accel = accel * FLU_FROM_FRD
    return ImuSeries(
        t_ns=t_ns,
        log_t_ns=t_ns.copy(),
        omega_b=omega * FLU_FROM_FRD,
        orientation_xyzw=None,
        topic=label,
        type="IMU",
        frame_id="body",
        accel_b=accel,
    )


def truth_series(name: str, cols: dict[str, NDArray], auto: bool) -> TruthSeries:
    """Roll, pitch, yaw (degrees, FRD to NED) as ``q_w_b`` FLU to ENU."""
    q = q_wxyz_from_euler_deg(cols["Roll"], cols["Pitch"], cols["Yaw"])
    t_ns = cols["TimeUS"].astype(np.int64) * 1000
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


def _truths(df, struct_codes, truth_topic: str | None) -> tuple[list[TruthSeries], str]:
    if truth_topic == "none":
        return [], ""
    names = list(TRUTHS)
    if truth_topic is not None:
        if truth_topic not in df.name_to_id:
            have = ", ".join(n for n in TRUTHS if n in df.name_to_id) or "no attitude message"
            raise LogError(f"Expected truth topic {truth_topic!r} in the DataFlash log, got {have}")
        names = [truth_topic] + [n for n in TRUTHS if n != truth_topic]
    found = []
    for name in names:
        cols, _ = decode(df, name, struct_codes)
        if cols and all(c in cols for c in ("TimeUS", "Roll", "Pitch", "Yaw")) and len(cols["Yaw"]):
            found.append(truth_series(name, cols, truth_topic is None))
    if truth_topic is not None and (not found or found[0].topic != truth_topic):
        raise LogError(
            f"Expected TimeUS, Roll, Pitch and Yaw in {truth_topic} of the DataFlash log, got none"
        )
    if not found:
        return [], "no attitude in the log (SIM, ATT, AHR2)"
    first = found[0]
    if not first.estimate_of:
        return found, f"truth: {first.topic} (the simulator's attitude)"
    why = "" if truth_topic else " (no SIM in the log)"
    return found, f"truth: {first.topic}, {first.estimate_of}{why}"


# --------------------------------------------------------------------------- source
class DataFlashSource:
    """One ArduPilot DataFlash ``.bin`` log (see the module doc)."""

    kind = KIND

    def __init__(self, path: Path, progress: Progress | None = None):
        self.path = Path(path)
        self.progress = progress

    def _open(self, progress: Progress | None):
        dfr = _dfreader()

        class _Indexed(dfr.DFReader_binary):
            """pymavlink's reader without its clock search: in a log with no GPS week it
            parses every message once to find none; this reader uses TimeUS only."""

            def init_clock(self):
                self.init_clock_usec()
                self._rewind(keep_messages=True)

        report = (lambda pct: progress(min(pct / 100.0, 0.99))) if progress else None
        said = io.StringIO()
        try:
            with contextlib.redirect_stdout(said), contextlib.redirect_stderr(said):
                df = _Indexed(str(self.path), progress_callback=report)
        except Exception as exc:  # pymavlink raises anything on a damaged file
            raise LogError(
                f"Expected a readable DataFlash log, got {type(exc).__name__}: {exc} in {self.path}"
            ) from None
        return dfr, df, said.getvalue().strip()

    def read(self, request: ReadRequest) -> LogData:
        progress = request.progress or self.progress
        dfr, df, said = self._open(progress)
        try:
            return self._read(df, dfr.FORMAT_TO_STRUCT, said, request, progress)
        finally:
            df.close()

    def _read(self, df, codes, said: str, request: ReadRequest, progress) -> LogData:
        imus, cut = _instances(df, codes)
        label, imu_note = _pick_imu(imus, request.imu_topic)
        imu = imu_series(imus[label], label)
        truths, truth_note = _truths(df, codes, request.truth_topic)
        damage = []
        if cut:
            damage.append(Damage(-1, f"DataFlash log cut short: {cut} IMU record(s) incomplete"))
        if said:
            damage.append(Damage(-1, f"pymavlink skipped damaged bytes: {said.splitlines()[0]}"))
        stopped_at = warn_damage(self.path, damage)
        channels = tuple(
            ChannelInfo(name, name, "dataflash", len(df.offsets[tid]))
            for name, tid in sorted(df.name_to_id.items())
            if len(df.offsets[tid])
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
            notes=tuple(n for n in (imu_note, truth_note) if n),
        )


def open_dataflash(path: Path, progress: Progress | None = None) -> DataFlashSource:
    return DataFlashSource(path, progress)

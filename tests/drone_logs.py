"""Writers of small drone logs with known content, by the formats' documented layouts.

* :func:`write_ulog`: a PX4 ULog (file header, flag bits, format, info, subscription, data and
  dropout messages, as PX4's "ULog File Format" page lays them out). pyulog 1.3 can write a
  ULog only back from one it parsed (``ULog.write_ulog``), not from arrays, so the bytes are
  laid out here; the tests read every file written here with pyulog too.
* :func:`write_dataflash`: an ArduPilot DataFlash ``.bin`` (FMT records, then data records,
  as ArduPilot's "DataFlash log" format and pymavlink's DFReader read them).
* :func:`trial_arrays`: the shipped trial's gyro and truth, read from its MCAP.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from conftest import REPO_ROOT, STRANGERS, need_data

TRIAL = REPO_ROOT / "replay" / "broad_07_undisturbed_fast_rotation_B"

_NP = {
    "uint64_t": "<u8",
    "int64_t": "<i8",
    "uint32_t": "<u4",
    "int32_t": "<i4",
    "uint16_t": "<u2",
    "int16_t": "<i2",
    "uint8_t": "u1",
    "int8_t": "i1",
    "float": "<f4",
    "double": "<f8",
    "bool": "u1",
}


@dataclass
class UTopic:
    """One ULog topic instance: its format fields ``(ctype, array length or 0, name)`` and one
    array per field (``(N,)`` or ``(N, n)``); ``timestamp`` (µs) must be among the values (it
    orders the records), and is among the fields unless a test leaves it out."""

    name: str
    fields: list[tuple[str, int, str]]
    values: dict[str, np.ndarray]
    instance: int = 0
    trailing_padding: int = 0  # bytes of "_padding0" declared at the end but not logged

    def dtype(self) -> np.dtype:
        return np.dtype([(f, _NP[t], (n,)) if n else (f, _NP[t]) for t, n, f in self.fields])


@dataclass
class ULogSpec:
    topics: list[UTopic]
    start_us: int = 0
    info: dict[str, str] = field(default_factory=dict)
    dropouts: list[tuple[int, int]] = field(default_factory=list)  # (after data msg k, ms)


def _msg(typ: bytes, payload: bytes) -> bytes:
    return struct.pack("<HB", len(payload), typ[0]) + payload


def write_ulog(path: Path, spec: ULogSpec) -> Path:
    """Write ``spec`` as a ULog file; data messages interleaved by timestamp (stable)."""
    out = bytearray(b"ULog\x01\x12\x35\x01" + struct.pack("<Q", spec.start_us))
    out += _msg(b"B", bytes(16) + bytes(24))
    for key, value in spec.info.items():
        k = f"char[{len(value)}] {key}".encode()
        out += _msg(b"I", bytes([len(k)]) + k + value.encode())
    seen = set()
    for t in spec.topics:
        if t.name in seen:
            continue
        seen.add(t.name)
        text = "".join(f"{c}[{n}] {f};" if n else f"{c} {f};" for c, n, f in t.fields)
        pad = f"uint8_t[{t.trailing_padding}] _padding0;" if t.trailing_padding else ""
        out += _msg(b"F", f"{t.name}:{text}{pad}".encode())
    records = []
    for msg_id, t in enumerate(spec.topics):
        out += _msg(b"A", struct.pack("<BH", t.instance, msg_id) + t.name.encode())
        rec = np.zeros(len(t.values["timestamp"]), t.dtype())
        for f in rec.dtype.names:
            rec[f] = t.values[f]
        for i, r in enumerate(rec):  # ordered by values["timestamp"], a field or not
            stamp = int(t.values["timestamp"][i])
            records.append((stamp, msg_id, i, struct.pack("<H", msg_id) + r.tobytes()))
    records.sort(key=lambda x: (x[0], x[1], x[2]))
    drops = dict(spec.dropouts)
    for k, (_t, _m, _i, payload) in enumerate(records):
        out += _msg(b"D", payload)
        if k in drops:
            out += _msg(b"O", struct.pack("<H", drops[k]))
    path.write_bytes(bytes(out))
    return path


# ------------------------------------------------------------------------- the trial
@dataclass
class TrialArrays:
    t_ns: np.ndarray
    omega_b: np.ndarray  # FLU, rad/s
    truth_t_ns: np.ndarray
    q_w_b: np.ndarray  # [x, y, z, w], FLU -> ENU
    accel_b: np.ndarray  # FLU, m/s²


def trial_arrays() -> TrialArrays:
    from imu_dcm.logio import read_log

    log = read_log(TRIAL)
    assert log.imu.accel_b is not None, "the trial's Imu messages carry the accelerometer"
    return TrialArrays(
        log.imu.t_ns, log.imu.omega_b, log.truth.t_ns, log.truth.q_w_b, log.imu.accel_b
    )


def to_px4(q_w_b_xyzw: np.ndarray) -> np.ndarray:
    """q_w_b (FLU -> ENU, [x, y, z, w]) as PX4's q (FRD -> NED, [w, x, y, z]), by scipy."""
    from scipy.spatial.transform import Rotation

    m_ned_enu = np.array([[0.0, 1, 0], [1, 0, 0], [0, 0, -1]])
    m_flu_frd = np.diag([1.0, -1, -1])
    r = (
        Rotation.from_matrix(m_ned_enu)
        * Rotation.from_quat(q_w_b_xyzw)
        * Rotation.from_matrix(m_flu_frd)
    )
    q = r.as_quat()
    # keep the sign of the input's w-continuity: scipy may flip, which is the same rotation
    return np.concatenate([q[:, 3:], q[:, :3]], axis=1)


def trial_ulog(path: Path, ctype: str = "double") -> Path:
    """The trial as a ULog: sensor_combined (gyro, accelerometer) and
    vehicle_attitude_groundtruth."""
    a = trial_arrays()
    assert np.all(a.t_ns % 1000 == 0) and np.all(a.truth_t_ns % 1000 == 0), "µs stamps"
    gyro = UTopic(
        "sensor_combined",
        [
            ("uint64_t", 0, "timestamp"),
            (ctype, 3, "gyro_rad"),
            ("int32_t", 0, "accelerometer_timestamp_relative"),
            (ctype, 3, "accelerometer_m_s2"),
        ],
        {
            "timestamp": a.t_ns // 1000,
            "gyro_rad": a.omega_b * np.array([1.0, -1, -1]),
            "accelerometer_timestamp_relative": np.zeros(len(a.t_ns)),
            "accelerometer_m_s2": a.accel_b * np.array([1.0, -1, -1]),
        },
    )
    truth = UTopic(
        "vehicle_attitude_groundtruth",
        [("uint64_t", 0, "timestamp"), ("uint64_t", 0, "timestamp_sample"), (ctype, 4, "q")],
        {
            "timestamp": a.truth_t_ns // 1000,
            "timestamp_sample": a.truth_t_ns // 1000,
            "q": to_px4(a.q_w_b),
        },
    )
    return write_ulog(path, ULogSpec([gyro, truth], start_us=int(a.t_ns[0] // 1000)))


# ------------------------------------------------------------------------- DataFlash
@dataclass
class DFMessage:
    """One DataFlash message type: name, pymavlink format characters, columns, rows."""

    name: str
    format: str
    columns: list[str]
    rows: list[tuple]  # one tuple of values per record, in column order


def write_dataflash(path: Path, messages: list[DFMessage], order_by: str = "TimeUS") -> Path:
    """A binary DataFlash log written with pymavlink's own record builders
    (``DFReader_binary.make_format_msgbuf`` / ``make_msgbuf``): the FMT of FMT, one FMT per
    type, then the records of every type merged by ``TimeUS``."""
    from pymavlink.DFReader import DFFormat, DFReader_binary

    fmt_fmt = DFFormat(0x80, "FMT", 89, "BBnNZ", "Type,Length,Name,Format,Columns")

    class _Writer:  # what the two builders use of a reader: its FMT format
        formats = {0x80: fmt_fmt}

    w = _Writer()
    out = bytearray(DFReader_binary.make_format_msgbuf(w, fmt_fmt))
    recs = []
    for type_id, m in enumerate(messages, start=0x81):
        fmt = DFFormat(type_id, m.name, 0, m.format, ",".join(m.columns))
        out += DFReader_binary.make_format_msgbuf(w, fmt)
        col = m.columns.index(order_by)
        for i, row in enumerate(m.rows):
            recs.append((row[col], type_id, i, DFReader_binary.make_msgbuf(w, fmt, row)))
    recs.sort(key=lambda r: r[:3])
    for r in recs:
        out += r[3]
    path.write_bytes(bytes(out))
    return path


def to_ardupilot_euler_deg(q_w_b_xyzw: np.ndarray) -> np.ndarray:
    """q_w_b (FLU -> ENU) as ArduPilot's roll, pitch, yaw in degrees (FRD -> NED, 3-2-1), by
    scipy; yaw in [0, 360) as ArduPilot logs it."""
    from scipy.spatial.transform import Rotation

    m_ned_enu = np.array([[0.0, 1, 0], [1, 0, 0], [0, 0, -1]])
    m_flu_frd = np.diag([1.0, -1, -1])
    r = (
        Rotation.from_matrix(m_ned_enu)
        * Rotation.from_quat(q_w_b_xyzw)
        * Rotation.from_matrix(m_flu_frd)
    )
    yaw, pitch, roll = r.as_euler("ZYX", degrees=True).T
    return np.stack([roll, pitch, np.mod(yaw, 360.0)], axis=1)


def trial_dataflash(path: Path, real: str = "d") -> Path:
    """The trial as a DataFlash log: IMU (gyro, accelerometer) and ATT. ``real`` is the
    format character of the values: ``d`` (double) or ``f`` (float, as ArduPilot logs)."""
    a = trial_arrays()
    assert np.all(a.t_ns % 1000 == 0) and np.all(a.truth_t_ns % 1000 == 0), "µs stamps"
    w = a.omega_b * np.array([1.0, -1, -1])
    f = a.accel_b * np.array([1.0, -1, -1])
    imu_rows = [
        (int(t // 1000), 0, *map(float, wi), *map(float, fi))
        for t, wi, fi in zip(a.t_ns, w, f, strict=True)
    ]
    rpy = to_ardupilot_euler_deg(a.q_w_b)
    att_rows = [
        (int(t // 1000), float(r), float(p), float(y))
        for t, (r, p, y) in zip(a.truth_t_ns, rpy, strict=True)
    ]
    return write_dataflash(
        path,
        [
            DFMessage(
                "IMU",
                "QB" + real * 6,
                ["TimeUS", "I", "GyrX", "GyrY", "GyrZ", "AccX", "AccY", "AccZ"],
                imu_rows,
            ),
            DFMessage("ATT", "Q" + real * 3, ["TimeUS", "Roll", "Pitch", "Yaw"], att_rows),
        ],
    )


XIMU3_INERTIAL = STRANGERS / "ximu3_left_foot_inertial.csv"
XIMU3_QUATERNION = STRANGERS / "ximu3_left_foot_quaternion.csv"


def ximu3_convert_argv(out: Path) -> list[str]:
    """``convert-csv`` arguments joining the foot-worn x-IMU3's two CSVs (gyro deg/s, accel g,
    the device's W,X,Y,Z quaternion, sensor to earth) into ``out``; skips the calling test when
    the CSVs are absent."""
    need_data(XIMU3_INERTIAL, XIMU3_QUATERNION)
    axes = "XYZ"
    argv = ["convert-csv", str(XIMU3_INERTIAL), str(out), "--time-col", "Timestamp (us)"]
    argv += ["--time-units", "us", "--gyro-units", "deg/s", "--accel-units", "g"]
    argv += ["--gyro-cols", ",".join(f"Gyroscope {a} (deg/s)" for a in axes)]
    argv += ["--accel-cols", ",".join(f"Accelerometer {a} (g)" for a in axes)]
    argv += ["--truth-csv", str(XIMU3_QUATERNION), "--truth-cols", "W,X,Y,Z"]
    return [*argv, "--truth-order", "wxyz"]

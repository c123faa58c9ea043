"""Fuzz cases for the containers beside MCAP: a PX4 ULog, an ArduPilot DataFlash log, a EuRoC
dataset folder and a split bag whose metadata.yaml uses anchors and aliases.

Each base is small and valid (a constant turn about z with an exact truth); each case damages a
copy of one file of it: random byte flips (one byte xor a random non-zero value) and random
truncations. The rules are :func:`fuzzlib.judge`'s: no traceback, no hang, exit 0 or 2 with
one error line, input unchanged. Where the loss a damage may cost is known from the layout it
is the case's ``lost`` (so a reader that loses more, or loses any without a warning, fails):

* DataFlash: a flipped byte after the FMT records costs at most 2 IMU records (the record hit,
  and the one before it when its end can no longer be confirmed); a truncation costs the IMU
  records not wholly before the cut.
* ULog: a flipped byte after the definitions costs at most 2 data messages (the one hit, and
  the one before it when its size is what was damaged); a truncation costs the data messages
  not wholly before the cut.
* A flip in an FMT or ULog definition, a EuRoC CSV (refused whole by design: a line that is
  not numbers names its line) or a metadata.yaml may cost anything: only the rules above.
"""

from __future__ import annotations

import shutil
import struct
from pathlib import Path

import numpy as np
from fuzzlib import Base, Case

from imu_dcm.logio.writers import StampedSeries, write_bag
from tests.drone_logs import DFMessage, ULogSpec, UTopic, write_dataflash, write_ulog

N, RATE_HZ, OMEGA_Z = 2000, 400.0, 0.5  # samples, Hz, rad/s about z (FLU)
FLIPS, CUTS = 24, 8
KINDS = ("cli", "read_log")


def _truth_yaw_rad(t_s: np.ndarray) -> np.ndarray:
    return OMEGA_Z * t_s


# ------------------------------------------------------------------------------ the bases
def _dataflash(folder: Path) -> tuple[Path, int]:
    t_s = np.arange(N) / RATE_HZ
    imu = DFMessage(
        "IMU",
        "QBffffff",
        ["TimeUS", "I", "GyrX", "GyrY", "GyrZ", "AccX", "AccY", "AccZ"],
        [(int(1000 + t * 1e6), 0, 0.0, 0.0, -OMEGA_Z, 0.0, 0.0, -9.81) for t in t_s],
    )
    # ArduPilot's yaw is clockwise from north: an ENU turn of +OMEGA_Z decreases it.
    att = DFMessage(
        "ATT",
        "Qfff",
        ["TimeUS", "Roll", "Pitch", "Yaw"],
        [
            (int(1000 + t * 1e6), 0.0, 0.0, float(np.mod(90 - np.degrees(y), 360)))
            for t, y in zip(t_s[::8], _truth_yaw_rad(t_s[::8]), strict=True)
        ],
    )
    folder.mkdir(parents=True)
    return write_dataflash(folder / "log.bin", [imu, att]), 89 * 3


def _ulog(folder: Path) -> Path:
    t_us = (1_000_000 + np.arange(N) * 1e6 / RATE_HZ).astype(np.uint64)
    comb = UTopic(
        "sensor_combined",
        [
            ("uint64_t", 0, "timestamp"),
            ("float", 3, "gyro_rad"),
            ("float", 3, "accelerometer_m_s2"),
        ],
        {
            "timestamp": t_us,
            "gyro_rad": np.tile([0.0, 0.0, -OMEGA_Z], (N, 1)),
            "accelerometer_m_s2": np.tile([0.0, 0.0, -9.81], (N, 1)),
        },
    )
    yaw_ned = np.pi / 2 - _truth_yaw_rad((t_us[::8] - t_us[0]) * 1e-6)
    q = np.column_stack(
        [np.cos(yaw_ned / 2), np.zeros(len(yaw_ned)), np.zeros(len(yaw_ned)), np.sin(yaw_ned / 2)]
    )
    att = UTopic(
        "vehicle_attitude",
        [("uint64_t", 0, "timestamp"), ("float", 4, "q")],
        {"timestamp": t_us[::8], "q": q},
    )
    folder.mkdir(parents=True)
    return write_ulog(folder / "log.ulg", ULogSpec([comb, att], start_us=int(t_us[0])))


def _euroc(folder: Path) -> Path:
    t_ns = 1_000_000_000 + (np.arange(N) * 1e9 / RATE_HZ).astype(np.int64)
    mav = folder / "mav0"
    (mav / "imu0").mkdir(parents=True)
    (mav / "vicon0").mkdir()
    lines = ["#timestamp [ns],w_x,w_y,w_z,a_x,a_y,a_z"]
    lines += [f"{t},0.0,0.0,{OMEGA_Z!r},0.0,0.0,9.81" for t in t_ns]
    (mav / "imu0" / "data.csv").write_text("\n".join(lines) + "\n")
    yaw = _truth_yaw_rad((t_ns - t_ns[0]) * 1e-9)
    lines = ["#timestamp [ns],p_x,p_y,p_z,q_w,q_x,q_y,q_z"]
    lines += [
        f"{t},0,0,0,{float(np.cos(y / 2))!r},0,0,{float(np.sin(y / 2))!r}"
        for t, y in zip(t_ns[::8], yaw[::8], strict=True)
    ]
    (mav / "vicon0" / "data.csv").write_text("\n".join(lines) + "\n")
    return folder


def _split(folder: Path) -> Path:
    """Two MCAP halves under one metadata.yaml whose QoS and start time are YAML aliases."""
    import yaml

    t_ns = 1_700_000_000_000_000_000 + (np.arange(N) * 1e9 / RATE_HZ).astype(np.int64)
    yaw = _truth_yaw_rad((t_ns - t_ns[0]) * 1e-9)
    q = np.column_stack([np.zeros((N, 2)), np.sin(yaw / 2), np.cos(yaw / 2)])
    w = np.tile([0.0, 0.0, OMEGA_Z], (N, 1))
    folder.mkdir(parents=True)
    halves = (slice(0, N // 2), slice(N // 2, N))
    for k, s in enumerate(halves):
        part = write_bag(
            folder / f"part{k}",
            imu=StampedSeries(t_ns[s], w[s], "imu"),
            quaternions={"/truth": StampedSeries(t_ns[s], q[s], "world")},
        )
        (part / f"part{k}.mcap").rename(folder / f"split_{k}.mcap")
    info = yaml.safe_load((part / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    for k in range(2):
        shutil.rmtree(folder / f"part{k}")
    qos = info["topics_with_message_count"][0]["topic_metadata"]["offered_qos_profiles"]
    start = {"nanoseconds_since_epoch": int(t_ns[0])}
    for t in info["topics_with_message_count"]:
        t["topic_metadata"]["offered_qos_profiles"] = qos  # one object, twice: an alias
    info["relative_file_paths"] = ["split_0.mcap", "split_1.mcap"]
    info["files"] = [{"path": f"split_{k}.mcap", "starting_time": start} for k in range(2)]
    info["starting_time"] = start
    bag = folder / "bag"
    bag.mkdir()
    for k in range(2):
        (folder / f"split_{k}.mcap").rename(bag / f"split_{k}.mcap")
    text = yaml.dump({"rosbag2_bagfile_information": info})
    assert "*id" in text, "the metadata holds aliases"
    (bag / "metadata.yaml").write_text(text)
    return bag


def bases(tmp: Path) -> dict[str, Base]:
    """One valid log of each container (``Base.mcap`` is the file the cases damage)."""
    df, _ = _dataflash(tmp / "dataflash")
    ul = _ulog(tmp / "ulog")
    eu = _euroc(tmp / "euroc")
    sp = _split(tmp / "split")
    return {
        "dataflash": Base("dataflash", df.parent, df, -1, N, [], []),
        "ulog": Base("ulog", ul.parent, ul, -1, N, [], []),
        "euroc": Base("euroc", eu, eu / "mav0" / "imu0" / "data.csv", -1, N, [], []),
        "split": Base("split", sp, sp / "metadata.yaml", -1, N, [], []),
    }


# ------------------------------------------------------------------------------ the cases
def _copy_with(base: Base, raw: bytes, target: Path | None = None):
    """A case's ``make``: the base's folder copied under ``d/in``, one file replaced."""
    target = target or base.mcap

    def make(d: Path) -> tuple[Path, list[str]]:
        dst = d / "in" / base.folder.name
        shutil.copytree(base.folder, dst)
        (dst / target.relative_to(base.folder)).write_bytes(raw)
        log = (
            dst / base.mcap.relative_to(base.folder)
            if base.mcap.suffix in (".bin", ".ulg")
            else dst
        )
        return log, []

    return make


def _dataflash_imu_ends(raw: bytes, first: int) -> np.ndarray:
    """End offsets of the IMU records (type 0x81: 36 bytes; ATT 0x82: 23) of the base."""
    ends, ofs = [], first
    while ofs < len(raw):
        size = 36 if raw[ofs + 2] == 0x81 else 23
        if raw[ofs + 2] == 0x81:
            ends.append(ofs + size)
        ofs += size
    return np.asarray(ends)


def _ulog_data_ends(raw: bytes) -> np.ndarray:
    """End offsets of the ULog's sensor_combined data messages (msg_id 0)."""
    ends, ofs = [], 16
    while ofs + 3 <= len(raw):
        size, typ = struct.unpack_from("<HB", raw, ofs)
        if typ == ord("D") and struct.unpack_from("<H", raw, ofs + 3)[0] == 0:
            ends.append(ofs + 3 + size)
        ofs += 3 + size
    return np.asarray(ends)


def _flip(raw: bytes, at: int, rng) -> bytes:
    out = bytearray(raw)
    out[at] ^= int(rng.integers(1, 256))
    return bytes(out)


def container_cases(bases: dict[str, Base], rng: np.random.Generator) -> list[Case]:
    out = []
    for name, base in bases.items():
        raw = base.mcap.read_bytes()
        ends = None
        if name == "dataflash":
            ends = _dataflash_imu_ends(raw, 89 * 3)
        elif name == "ulog":
            ends = _ulog_data_ends(raw)
        for at in sorted({int(x) for x in rng.integers(0, len(raw), FLIPS)}):
            lost = 2 if name == "dataflash" and at >= 89 * 3 else None
            if name == "ulog" and at >= ends[0] - 40:  # after the definitions
                lost = 2
            out.append(
                Case(
                    "container_record",
                    f"flip{at}",
                    name,
                    _copy_with(base, _flip(raw, at, rng)),
                    lost=lost,
                    kinds=KINDS,
                    fix=f"{name} reader: a damaged record costs only itself",
                )
            )
        for cut in sorted({int(x) for x in rng.integers(1, len(raw), CUTS)}):
            lost = int(np.count_nonzero(ends > cut)) if ends is not None else None
            out.append(
                Case(
                    "container_record",
                    f"cut{cut}",
                    name,
                    _copy_with(base, raw[:cut]),
                    lost=lost,
                    kinds=KINDS,
                    fix=f"{name} reader: a truncated log keeps what is whole",
                )
            )
    split = bases["split"]
    mcap = split.folder / "split_1.mcap"
    raw = mcap.read_bytes()
    for at in sorted({int(x) for x in rng.integers(0, len(raw), FLIPS // 2)}):
        out.append(
            Case(
                "container_record",
                f"mcap1-flip{at}",
                "split",
                _copy_with(split, _flip(raw, at, rng), mcap),
                lost=None,
                kinds=KINDS,
                fix="split bag: a damaged second file",
            )
        )
    return out

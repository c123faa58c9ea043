"""Log reading speed and memory against plain per-message decode loops over the same bags.

``python -m benchmarks.replay_speed [--bag DIR] [--rounds N] [--camera-mb MB] [--hour]
[--ulog FILE]``

Speed, timed in interleaved rounds after a warm-up, one BLAS thread (:mod:`benchmarks.timing`).
Every reference decodes every message of the bag into one Python object each, as a user's
script would; rates are the bag's message count over the median time, so ratios are
speed-ups on the same bag:

* MCAP (the shipped trial): ``mcap`` + ``mcap_ros2`` ``iter_decoded_messages()`` against
  :func:`imu_dcm.logio.read_log`. Target >= 10x.
* sqlite3 and ROS 1 (the same trial written with rosbags' writers): ``rosbags`` ``AnyReader``
  + ``deserialize`` loop against ``read_log``. Target >= 5x.
* PX4 ULog (``--ulog``, default PX4's sample log beside the repository, skipped when absent):
  ``pyulog`` ``ULog()`` (its reader walks every message in Python; all topics, and only the
  gyro and attitude topics) against ``read_log``. Target >= 5x the full parse.
* EuRoC/ASL folder (the same trial's gyro and truth written as ``imu0`` and
  ``state_groundtruth_estimate0`` CSVs): a plain per-row ``csv.reader`` loop (``int`` stamps,
  ``float`` fields, rows stacked with numpy) against ``read_log``. Target >= 5x.
* In each group, a ``rosbags`` loop that only *iterates* the raw IMU and truth messages (no
  decoding at all): the best a source built on rosbags' message iterator could do, to show
  where our own container code (MCAP chunks, sqlite3 query, ROS 1 chunks) earns its place.
* ``replay`` (no viewer), when :mod:`imu_dcm.replay` imports; and the replay *command* end to end
  (``python -m imu_dcm.replay BAG --rerun off --quiet`` in a fresh process: start-up, imports
  and the kernel's cache load included), the figure a user sees. Target >= 10x the decode loop.

Memory, each in a fresh subprocess (peak RSS = VmHWM):

* the trial, and the trial with a camera topic of ``--camera-mb`` MB (incompressible 10 Hz
  frames mixed into the same chunks); target: the camera raises the peak <= 20 %;
* with ``--hour``, a one-hour 400 Hz bag (1.44 M IMU + 1.39 M truth messages); target: peak
  <= 3x the decoded arrays + 300 MB.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from benchmarks.timing import limit_threads_env

REPO = Path(__file__).resolve().parents[1]
DEFAULT_BAG = REPO / "replay" / "broad_07_undisturbed_fast_rotation_B"
DEFAULT_ULOG = REPO.parent / "shared" / "data" / "strangers" / "sample_px4_events.ulg"
TARGET_MCAP, TARGET_ROSBAGS = 10.0, 5.0


# ------------------------------------------------------------------------- references
def decode_loop(mcap_path: Path) -> int:
    """mcap + mcap_ros2: decode every message; returns the count."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    n = 0
    with open(mcap_path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _schema, _channel, _message, _decoded in reader.iter_decoded_messages():
            n += 1
    return n


def rosbags_loop(path: Path) -> int:
    """rosbags AnyReader: deserialize every message; returns the count."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    n = 0
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
        for conn, _t, raw in reader.messages():
            reader.deserialize(raw, conn.msgtype)
            n += 1
    return n


def rosbags_raw_iteration(path: Path, topics: tuple[str, ...]) -> int:
    """rosbags AnyReader: only iterate the raw messages of ``topics`` (no decoding)."""
    from rosbags.highlevel import AnyReader

    n = 0
    with AnyReader([path]) as reader:
        conns = [c for c in reader.connections if c.topic in topics]
        for _conn, _t, _raw in reader.messages(connections=conns):
            n += 1
    return n


def pyulog_loop(path: Path, topics: list[str] | None = None) -> int:
    """pyulog: parse the ULog (its reader walks every message in Python), or only ``topics``;
    returns the data messages kept."""
    from pyulog import ULog

    return sum(len(d.data["timestamp"]) for d in ULog(str(path), topics).data_list)


# --------------------------------------------------------------------------- variants
def _messages(mcap_path: Path):
    from mcap.reader import make_reader

    with open(mcap_path, "rb") as f:
        for schema, channel, m in make_reader(f).iter_messages():
            yield channel.topic, schema.name, m.log_time, m.data


def write_sqlite3(src: Path, dst: Path) -> Path:
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    with Writer(dst, version=9, storage_plugin=StoragePlugin.SQLITE3) as w:
        conns = {}
        for topic, typ, t, data in _messages(src):
            if topic not in conns:
                conns[topic] = w.add_connection(topic, typ, typestore=store)
            w.write(conns[topic], t, data)
    return dst


def write_ros1(src: Path, dst: Path) -> Path:
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ros2, ros1 = get_typestore(Stores.ROS2_HUMBLE), get_typestore(Stores.ROS1_NOETIC)
    with Writer(dst) as w:
        conns = {}
        for topic, typ, t, data in _messages(src):
            if topic not in conns:
                conns[topic] = w.add_connection(topic, typ, typestore=ros1)
            w.write(conns[topic], t, ros2.cdr_to_ros1(data, typ))
    return dst


def write_with_camera(src: Path, dst: Path, camera_mb: float) -> Path:
    """The trial plus a 10 Hz camera of incompressible frames totalling ``camera_mb`` MB."""
    import numpy as np
    from mcap.writer import Writer

    msgs = list(_messages(src))
    t0, t1 = msgs[0][2], msgs[-1][2]
    stamps = list(range(t0, t1, 100_000_000))
    frame_bytes = int(camera_mb * 1e6 / len(stamps))
    rng = np.random.default_rng(0)
    with open(src, "rb") as f:
        from mcap.reader import make_reader

        summary = make_reader(f).get_summary()
    schemas = {s.name: s for s in summary.schemas.values()}
    cam = iter(stamps)
    next_cam = next(cam, None)
    with open(dst, "wb") as f:
        w = Writer(f, chunk_size=768 * 1024)
        w.start("ros2", "bench")
        ids = {}
        img = w.register_schema("sensor_msgs/msg/Image", "ros2msg", b"uint8[] data\n")
        cam_id = w.register_channel("/camera/image_raw", "cdr", img)
        for topic, typ, t, data in msgs:
            while next_cam is not None and next_cam <= t:
                payload = b"\x00\x01\x00\x00" + rng.bytes(frame_bytes)
                w.add_message(cam_id, log_time=next_cam, data=payload, publish_time=next_cam)
                next_cam = next(cam, None)
            if topic not in ids:
                s = schemas[typ]
                ids[topic] = w.register_channel(
                    topic, "cdr", w.register_schema(s.name, s.encoding, s.data)
                )
            w.add_message(ids[topic], log_time=t, data=data, publish_time=t)
        w.finish()
    return dst


def write_hour(src: Path, dst: Path, rate_hz: float = 400.0, seconds: float = 3600.0) -> Path:
    """A one-hour bag: IMU at ``rate_hz``, truth at 96.5 % of those stamps (optical dropouts),
    payloads of the trial's first messages with patched stamps and rates."""
    import struct

    import numpy as np
    from mcap.reader import make_reader
    from mcap.writer import Writer

    with open(src, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        first = {}
        for schema, channel, m in reader.iter_messages():
            first.setdefault(channel.topic, (schema, m.data))
            if len(first) == len(summary.channels):
                break
    imu_schema, imu_raw = first["/imu/data"]
    tr_schema, tr_raw = first["/ground_truth/orientation"]
    n = int(rate_hz * seconds)
    rng = np.random.default_rng(1)
    has_truth = rng.random(n) < 0.965
    omega = rng.normal(0.0, 1.0, (n, 3))
    t0 = 1_700_000_000_000_000_000
    step = round(1e9 / rate_hz)
    with open(dst, "wb") as f:
        w = Writer(f, chunk_size=768 * 1024)
        w.start("ros2", "bench")
        imu = w.register_channel(
            "/imu/data",
            "cdr",
            w.register_schema(imu_schema.name, imu_schema.encoding, imu_schema.data),
        )
        tru = w.register_channel(
            "/ground_truth/orientation",
            "cdr",
            w.register_schema(tr_schema.name, tr_schema.encoding, tr_schema.data),
        )
        body = bytearray(imu_raw)
        tbody = bytearray(tr_raw)
        # angular_velocity sits after header (stamp 8 + frame_id "imu" 4+4 -> 20), orientation
        # (aligned to 24, 32 bytes) and orientation_covariance (72): at 128 after the 4-byte
        # encapsulation header.
        w_off = 4 + 24 + 32 + 72
        for i in range(n):
            t = t0 + i * step
            stamp = struct.pack("<iI", t // 1_000_000_000, t % 1_000_000_000)
            body[4:12] = stamp
            body[w_off : w_off + 24] = omega[i].tobytes()
            w.add_message(imu, log_time=t, data=bytes(body), publish_time=t)
            if has_truth[i]:
                tbody[4:12] = stamp
                w.add_message(tru, log_time=t, data=bytes(tbody), publish_time=t)
        w.finish()
    return dst


def write_euroc(src: Path, dst: Path) -> Path:
    """The trial as an ASL dataset: ``mav0/imu0`` (gyro, gravity as the accelerometer) and
    ``mav0/state_groundtruth_estimate0`` (quaternions w, x, y, z) CSVs."""
    import numpy as np

    from imu_dcm.logio import read_log

    log = read_log(src)
    gt = np.hstack([np.zeros((len(log.truth.t_ns), 3)), log.truth.q_w_b[:, [3, 0, 1, 2]]])
    imu = np.hstack([log.imu.omega_b, np.tile([0.0, 0.0, 9.81], (len(log.imu.t_ns), 1))])
    for name, t_ns, values in (
        ("imu0", log.imu.t_ns, imu),
        ("state_groundtruth_estimate0", log.truth.t_ns, gt),
    ):
        (dst / "mav0" / name).mkdir(parents=True)
        pairs = zip(t_ns.tolist(), values.tolist(), strict=True)
        rows = [f"{t}," + ",".join(map(repr, v)) for t, v in pairs]
        (dst / "mav0" / name / "data.csv").write_text("#timestamp [ns],...\n" + "\n".join(rows))
    return dst


def csv_loop(folder: Path) -> int:
    """csv.reader over every data.csv of an ASL dataset, one row at a time; returns the rows."""
    import csv

    import numpy as np

    n = 0
    for path in sorted(folder.glob("mav0/*/data.csv")):
        stamps, rows = [], []
        with open(path, newline="") as f:
            for row in csv.reader(f):
                if row and not row[0].startswith("#"):
                    stamps.append(int(row[0]))
                    rows.append([float(x) for x in row[1:]])
        np.array(stamps, np.int64), np.array(rows)
        n += len(stamps)
    return n


# ----------------------------------------------------------------------------- memory
_PEAK = """
import sys, warnings
warnings.simplefilter("ignore")
from imu_dcm.logio import read_log
log = read_log(sys.argv[1])
n_imu, n_truth = len(log.imu.t_ns), 0 if log.truth is None else len(log.truth.t_ns)
decoded = sum(a.nbytes for a in (log.imu.t_ns, log.imu.log_t_ns, log.imu.omega_b)
              if a is not None)
decoded += 0 if log.imu.orientation_xyzw is None else log.imu.orientation_xyzw.nbytes
if log.truth is not None:
    decoded += log.truth.t_ns.nbytes + log.truth.log_t_ns.nbytes + log.truth.q_w_b.nbytes
hwm = [ln for ln in open("/proc/self/status") if ln.startswith("VmHWM:")][0].split()[1]
print(n_imu, n_truth, decoded, int(hwm) * 1024)
"""


def peak(path: Path) -> tuple[int, int, int, int]:
    """(IMU samples, truth samples, decoded bytes, peak RSS bytes) of read_log in a subprocess."""
    env = dict(os.environ, PYTHONPATH=str(REPO))
    out = subprocess.run(
        [sys.executable, "-c", _PEAK, str(path)],
        capture_output=True,
        text=True,
        env=env,
        check=True,
    ).stdout.split()
    return tuple(int(x) for x in out)  # type: ignore[return-value]


# ------------------------------------------------------------------------------- main
def _quiet(fn):
    import warnings

    def run():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return fn()

    return run


def _replay_or_none(bag: Path):
    """imu_dcm.replay.replay where this checkout's replay runs on this reader, else None."""
    try:
        from imu_dcm.replay import replay

        _quiet(lambda: replay(bag))()
    except Exception as exc:
        print(f"(replay case skipped: {type(exc).__name__}: {exc})")
        return None
    return replay


def replay_command(bag: Path) -> None:
    """``python -m imu_dcm.replay BAG --rerun off --quiet`` in a fresh process (this checkout)."""
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]),
    }
    env.pop("PYTHONDONTWRITEBYTECODE", None)  # a user's install has its bytecode cached
    subprocess.run(
        [sys.executable, "-m", "imu_dcm.replay", str(bag), "--rerun", "off", "--quiet"],
        check=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env=env,
    )


def _groups(bag: Path, mcap_path: Path, db: Path, bag1: Path, n_msgs: int, replay) -> dict:
    """Each container's cases ``{name: (fn, items)}``, its reference case and its target."""
    from imu_dcm.logio import read_log

    topics = ("/imu/data", "/ground_truth/orientation")

    def rosbags_cases(path: Path) -> dict:
        return {
            "rosbags deserialize loop": (lambda: rosbags_loop(path), n_msgs),
            "rosbags raw iteration, IMU+truth": (
                lambda: rosbags_raw_iteration(path, topics),
                n_msgs,
            ),
            "read_log": (_quiet(lambda: read_log(path)), n_msgs),
        }

    mcap_cases = {
        "decode loop (mcap + mcap_ros2)": (lambda: decode_loop(mcap_path), n_msgs),
        "rosbags raw iteration, IMU+truth": (lambda: rosbags_raw_iteration(bag, topics), n_msgs),
        "read_log": (_quiet(lambda: read_log(bag)), n_msgs),
    }
    if replay is not None:
        mcap_cases["replay, no viewer"] = (_quiet(lambda: replay(bag)), n_msgs)
        mcap_cases["replay command, fresh process"] = (lambda: replay_command(bag), n_msgs)
    return {
        "MCAP": (mcap_cases, "decode loop (mcap + mcap_ros2)", TARGET_MCAP),
        "sqlite3": (rosbags_cases(db), "rosbags deserialize loop", TARGET_ROSBAGS),
        "ROS 1": (rosbags_cases(bag1), "rosbags deserialize loop", TARGET_ROSBAGS),
    }


def _speed(groups: dict, rounds: int) -> None:
    from benchmarks.timing import interleaved_medians, single_thread

    for group, (cases, ref, target) in groups.items():
        with single_thread():
            res = interleaved_medians(cases, rounds=rounds, warmup=1)
        base = res[ref]
        print(f"\n{group}\n{'case':<36} {'median s':>9} {'msgs/s':>12} {'vs ref':>8}")
        for name, t in res.items():
            print(
                f"{name:<36} {t.median_s:>9.3f} {t.items_per_s:>12,.0f} "
                f"{base.median_s / t.median_s:>7.1f}x"
            )
        ratio = base.median_s / res["read_log"].median_s
        verdict = "meets" if ratio >= target else "MISSES"
        print(f"read_log is {ratio:.1f}x the {ref} ({verdict} the >= {target:.0f}x target)")
        if "replay command, fresh process" in res:
            ratio = base.median_s / res["replay command, fresh process"].median_s
            verdict = "meets" if ratio >= TARGET_MCAP else "MISSES"
            print(
                f"the replay command end to end is {ratio:.1f}x the {ref} ({verdict} the "
                f">= {TARGET_MCAP:.0f}x target)"
            )


def _memory(mcap_path: Path, tmp: Path, camera_mb: float, hour: bool) -> None:
    print("\nmemory (read_log in a fresh process; peak RSS = VmHWM)")
    n_imu, n_truth, dec, pk0 = peak(mcap_path)
    print(f"trial:               {n_imu} IMU, {n_truth} truth, peak {pk0 / 1e6:.0f} MB")
    if camera_mb > 0:
        cam = write_with_camera(mcap_path, tmp / "camera.mcap", camera_mb)
        _, _, _, pk1 = peak(cam)
        rise = pk1 / pk0 - 1.0
        print(
            f"trial + {camera_mb:.0f} MB camera: file {cam.stat().st_size / 1e6:.0f}"
            f" MB, peak {pk1 / 1e6:.0f} MB ({100 * rise:+.1f} %; "
            f"{'meets' if rise <= 0.2 else 'MISSES'} the <= +20 % target)"
        )
        cam.unlink()
    if hour:
        path = write_hour(mcap_path, tmp / "hour.mcap")
        n_imu, n_truth, dec, pk = peak(path)
        bound = 3 * dec + 300e6
        print(
            f"one hour at 400 Hz:  {n_imu} IMU, {n_truth} truth, file "
            f"{path.stat().st_size / 1e6:.0f} MB, decoded arrays {dec / 1e6:.0f} MB, "
            f"peak {pk / 1e6:.0f} MB ({'meets' if pk <= bound else 'MISSES'} the "
            f"<= 3x arrays + 300 MB = {bound / 1e6:.0f} MB target)"
        )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m benchmarks.replay_speed",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--bag", type=Path, default=DEFAULT_BAG, help="bag folder or .mcap")
    p.add_argument("--rounds", type=int, default=3, help="timed rounds (default 3)")
    p.add_argument(
        "--camera-mb",
        type=float,
        default=566.0,
        help="size of the added camera topic, MB (default 566; 0 skips)",
    )
    p.add_argument("--hour", action="store_true", help="also the one-hour 400 Hz memory case")
    p.add_argument(
        "--ulog", type=Path, default=DEFAULT_ULOG, help="a PX4 ULog (default: PX4's sample)"
    )
    args = p.parse_args(argv)

    limit_threads_env()
    from imu_dcm.logio import read_log, resolve_mcap_path

    mcap_path = resolve_mcap_path(args.bag)
    n_msgs = decode_loop(mcap_path)
    replay = _replay_or_none(args.bag)
    with tempfile.TemporaryDirectory(prefix="replay_speed_") as tmp:
        tmp = Path(tmp)
        db = write_sqlite3(mcap_path, tmp / "sqlite3_bag")
        bag1 = write_ros1(mcap_path, tmp / "trial.bag")
        euroc = _quiet(lambda: write_euroc(args.bag, tmp / "euroc"))()
        n_rows = csv_loop(euroc)
        groups = _groups(args.bag, mcap_path, db, bag1, n_msgs, replay)
        groups["EuRoC/ASL folder"] = (
            {
                "per-row csv loop": (lambda: csv_loop(euroc), n_rows),
                "read_log": (_quiet(lambda: read_log(euroc)), n_rows),
            },
            "per-row csv loop",
            TARGET_ROSBAGS,
        )
        if args.ulog.is_file():  # PX4 ULog: pyulog's reader against read_log's scan
            n_ulog = pyulog_loop(args.ulog)
            groups["PX4 ULog " + args.ulog.name] = (
                {
                    "pyulog ULog(), every message": (lambda: pyulog_loop(args.ulog), n_ulog),
                    "pyulog ULog(), gyro+attitude topics": (
                        lambda: pyulog_loop(args.ulog, ["sensor_combined", "vehicle_attitude"]),
                        n_ulog,
                    ),
                    "read_log": (_quiet(lambda: read_log(args.ulog)), n_ulog),
                },
                "pyulog ULog(), every message",
                TARGET_ROSBAGS,
            )
        else:
            print(f"(PX4 ULog case skipped: no {args.ulog})")
        shown = args.bag.resolve()
        shown = shown.relative_to(REPO) if shown.is_relative_to(REPO) else args.bag
        print(
            f"bag: {shown} ({n_msgs} messages, {mcap_path.stat().st_size / 1e6:.1f} MB); "
            f"median of {args.rounds} interleaved rounds after a warm-up, 1 thread"
        )
        _speed(groups, args.rounds)
        if Path("/proc/self/status").is_file():
            _memory(mcap_path, tmp, args.camera_mb, args.hour)
    return 0


if __name__ == "__main__":
    sys.exit(main())

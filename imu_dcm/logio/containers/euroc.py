"""EuRoC / ASL dataset folders (EuRoC MAV, TUM-VI and the datasets that kept their layout).

Give the dataset folder or its ``mav0``; each sensor is a folder holding ``data.csv`` (one
header line starting with ``#``, then one sample a line, the first column a timestamp in ns)
and ``sensor.yaml``.

* **Gyro and accelerometer**: ``imu0/data.csv``, columns ``timestamp [ns], w_RS_S_x, w_RS_S_y,
  w_RS_S_z [rad/s], a_RS_S_x, a_RS_S_y, a_RS_S_z [m/s²]``: the angular rate and the specific
  force in the IMU's axes S. These axes are the body axes of everything read: ``omega_b``
  (rad/s) and ``accel_b`` (m/s²), as stored.
* **Truth**, the first present of (or the one named by ``truth_topic``):

  1. ``state_groundtruth_estimate0/data.csv``: ``timestamp, p_RS_R (x, y, z), q_RS (w, x, y,
     z), v_RS_R, b_w_RS_S, b_a_RS_S``. The dataset's ground-truth state, estimated offline
     from motion capture and the IMU, given for the IMU frame S: ``q_RS`` is ``q_w_b``.
  2. ``vicon0/data.csv`` (EuRoC) and 3. ``mocap0/data.csv`` (TUM-VI): ``timestamp, p_RS_R,
     q_RS (w, x, y, z)`` of the tracked marker body S. Its ``sensor.yaml`` ``T_BS`` places S
     in the body frame B, and ``imu0/sensor.yaml``'s ``T_BS`` places the IMU in B (the
     identity in EuRoC), so ``q_w_b = q_RS ⊗ q_BS⁻¹ ⊗ q_B,imu``: applied, and said in
     :attr:`LogData.notes`. A missing ``sensor.yaml`` is taken as the identity, and said.
  4. ``leica0/data.csv`` holds positions only (a laser tracker follows a prism): it gives no
     attitude and is never a truth; said in the notes.

* **Quaternions** are stored ``w, x, y, z``; they are returned ``[x, y, z, w]`` (Hamilton,
  body to world).
* **Frames** (assumed): the world R of EuRoC and TUM-VI is gravity-aligned with z up, like ENU,
  but its heading is the motion-capture room's, not east. Positions are not read.
* **Stamps**: int64 ns on the one clock of the dataset; header stamps and log times are the
  same (``t_ns == log_t_ns``).

Channels: ``imu_topic`` names the IMU folder (default ``imu0``), ``truth_topic`` a truth
folder or ``"none"``. The CSVs are read by Arrow's CSV reader (exact float parsing, many times
a per-row loop; see ``benchmarks.replay_speed``); a bad CSV (too few columns, a line of another
length than the first, a field that is not a number, stamps not increasing) raises
:class:`~imu_dcm.errors.LogError` naming the file and the line, as does a ``data.csv`` that is
missing, a folder or a special file (a truth's too, with the hint ``--truth-topic none``).
"""

from __future__ import annotations

import stat
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa  # ~130 ms at import: this module loads only when a EuRoC row opens a log
import pyarrow.csv as pcsv
from numpy.typing import NDArray

from imu_dcm.errors import LogError
from imu_dcm.logio.meta import load_yaml
from imu_dcm.logio.paths import check_regular, mav_folder
from imu_dcm.logio.source import ProgressCallback, ReadRequest
from imu_dcm.logio.types import ChannelInfo, ImuSeries, LogData, TruthSeries
from imu_dcm.outputs import file_kind
from imu_dcm.so3 import quat_conjugate, quat_from_matrix, quat_multiply

__all__ = [
    "CSV_TYPE",
    "IMU_COLUMNS",
    "KIND",
    "MAX_SENSOR_YAML",
    "POSITIONS_TYPE",
    "TRUTHS",
    "TRUTHS_BY_NAME",
    "EurocSource",
    "TruthFolder",
    "read_csv",
    "regular_csv",
    "sensor_rotation",
]


KIND = "euroc/asl folder"
CSV_TYPE = "asl data.csv"
#: The type of a truth folder holding positions only (``leica0``).
POSITIONS_TYPE = "asl data.csv (positions)"
#: Columns read from the IMU's data.csv: timestamp, 3 rates, 3 specific forces.
IMU_COLUMNS = 7
#: Largest sensor.yaml read (bytes); real ones are under 1 kB.
MAX_SENSOR_YAML = 1 << 20


@dataclass(frozen=True)
class TruthFolder:
    """A truth sensor of the layout: its folder, columns read, and what it is."""

    name: str
    columns: int  # timestamp + positions (+ quaternion w, x, y, z)
    attitude: bool
    in_imu_frame: bool
    about: str


#: The truth folders, in the order they are preferred.
TRUTHS = (
    TruthFolder(
        "state_groundtruth_estimate0",
        8,
        True,
        True,
        "the dataset's ground-truth estimate, from motion capture and the IMU, in the IMU frame",
    ),
    TruthFolder("vicon0", 8, True, False, "Vicon motion capture"),
    TruthFolder("mocap0", 8, True, False, "motion capture"),
    TruthFolder("leica0", 4, False, False, "Leica laser tracker, positions only"),
)


# ----------------------------------------------------------------------------- CSV
def _header_lines(path: Path) -> int:
    """How many lines at the top start with ``#`` (the column names)."""
    with open(path, "rb") as f:
        n = 0
        for line in f:
            if not line.lstrip().startswith(b"#"):
                return n
            n += 1
        return n


def _first_bad_line(path: Path, skip: int, n_columns: int) -> str | None:
    """What is wrong with the first bad data line, with its line number (None if none is): too
    few columns, another number of columns than the first data line, or not numbers."""
    width = None
    with open(path, encoding="utf-8", errors="replace") as f:
        for number, line in enumerate(f, start=1):
            if number <= skip or not line.strip():
                continue
            fields = line.rstrip("\r\n").split(",")
            width = width or len(fields)
            if len(fields) < n_columns or len(fields) != width:
                return f"{len(fields)} columns at line {number} (the first line: {width})"
            try:
                int(fields[0])
                [float(x) for x in fields[1:n_columns]]
            except ValueError:
                return f"{line.strip()[:60]!r} at line {number}"
    return None


def _read_arrow(path: Path, skip: int, n_columns: int) -> tuple[NDArray, NDArray]:
    names = [f"f{i}" for i in range(n_columns)]
    table = pcsv.read_csv(
        path,
        read_options=pcsv.ReadOptions(
            skip_rows=skip, autogenerate_column_names=True, use_threads=False
        ),
        convert_options=pcsv.ConvertOptions(
            column_types={"f0": pa.int64(), **{n: pa.float64() for n in names[1:]}},
            include_columns=names,
        ),
    )
    t_ns = table.column("f0").to_numpy().astype(np.int64, copy=False)
    values = np.column_stack([table.column(n).to_numpy() for n in names[1:]])
    return t_ns, values.astype(np.float64, copy=False)


def read_csv(path: Path, n_columns: int) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """The timestamps (int64 ns, strictly increasing) and the next ``n_columns - 1`` columns
    (float64, shape (N, n_columns - 1)) of an ASL ``data.csv``; further columns are ignored.

    Raises
    ------
    LogError
        Missing or special file, no samples, too few columns, a line of another length or
        holding something other than numbers, stamps not strictly increasing.
    """
    regular_csv(path)
    skip = _header_lines(path)
    where = f"{path.parent.name}/{path.name} ({path})"
    bad = None
    try:
        t_ns, values = _read_arrow(path, skip, n_columns)
    except (pa.ArrowInvalid, KeyError, ValueError):
        bad = _first_bad_line(path, skip, n_columns)
        if bad is not None:
            raise LogError(
                f"Expected {n_columns} numbers a line, the first an integer timestamp [ns], "
                f"in {where}, got {bad}"
            ) from None
        t_ns, values = _read_loadtxt(path, skip, n_columns, where)
    if len(t_ns) == 0:
        raise LogError(f"Expected samples in {where}, got none")
    back = np.flatnonzero(np.diff(t_ns) <= 0)
    if back.size:
        i = int(back[0]) + 1
        raise LogError(
            f"Expected timestamps strictly increasing in {where}, got {int(t_ns[i])} after "
            f"{int(t_ns[i - 1])} at line {skip + i + 1}"
        )
    return t_ns, values


def regular_csv(path: Path) -> None:
    """Refuse in one line a ``data.csv`` that is missing, a folder or a special file (only its
    status is read: a FIFO is never opened, which would wait for a writer)."""
    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        what = "none (no such file)"
    except OSError as exc:
        what = f"an unreadable path ({exc.strerror})"
    else:
        if stat.S_ISREG(mode):
            return
        what = "a folder" if stat.S_ISDIR(mode) else f"a {file_kind(mode)} (a special file)"
    raise LogError(f"Expected a regular file {path.parent.name}/{path.name}, got {what}: {path}")


def _read_loadtxt(path: Path, skip: int, n_columns: int, where: str) -> tuple[NDArray, NDArray]:
    """The slow path for what Arrow refuses but is numbers (spaces around fields)."""
    dtype = [("t", "<i8"), ("v", "<f8", (n_columns - 1,))]
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # "no data": said below, in one line
            rows = np.loadtxt(
                path, delimiter=",", skiprows=skip, usecols=range(n_columns), dtype=dtype, ndmin=1
            )
    except ValueError as exc:
        line = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise LogError(f"Expected a CSV of numbers in {where}, got {line}") from None
    return rows["t"].astype(np.int64), rows["v"].reshape(len(rows), n_columns - 1)


# ----------------------------------------------------------------------------- sensor.yaml
def sensor_rotation(folder: Path) -> NDArray[np.float64] | None:
    """The rotation part of ``T_BS`` in ``folder/sensor.yaml`` as ``q_BS`` ``[x, y, z, w]``
    (sensor S to body B); None when the file is absent.

    Raises
    ------
    LogError
        The file is unreadable, or its ``T_BS`` is not a 4x4 rigid transform.
    """
    path = folder / "sensor.yaml"
    if not path.is_file():
        return None
    check_regular(path)
    if path.stat().st_size > MAX_SENSOR_YAML:
        raise LogError(f"Expected a sensor.yaml of at most {MAX_SENSOR_YAML} bytes, got {path}")
    # OpenCV writes a "%YAML:1.0" first line, which is not YAML: dropped.
    text = "".join(
        ln
        for ln in path.read_text(encoding="utf-8", errors="replace").splitlines(True)
        if not ln.startswith("%YAML")
    )
    doc = load_yaml(text, path, "sensor.yaml")
    t_bs = doc.get("T_BS") if isinstance(doc, dict) else None
    data = t_bs.get("data") if isinstance(t_bs, dict) else t_bs
    try:
        m = np.asarray(data, dtype=np.float64).reshape(4, 4)
    except (TypeError, ValueError):
        raise LogError(f"Expected T_BS with 16 numbers (4x4) in {path}, got {data!r:.80}") from None
    r = m[:3, :3]
    if (
        not np.all(np.isfinite(m))
        or np.abs(r @ r.T - np.eye(3)).max() > 1e-4
        or (np.linalg.det(r) <= 0)
    ):
        raise LogError(f"Expected T_BS in {path} to hold a rotation, got {r.tolist()}")
    return quat_from_matrix(r)  # the nearest rotation; [x, y, z, w]


def _angle_deg(q: NDArray[np.float64]) -> float:
    return float(np.degrees(2.0 * np.arctan2(np.linalg.norm(q[:3]), abs(q[3]))))


# ----------------------------------------------------------------------------- the source
class EurocSource:
    """A EuRoC / ASL dataset (see the module doc); ``read`` returns its :class:`LogData`."""

    kind = KIND

    def __init__(self, path: Path, progress: ProgressCallback | None = None):
        mav = mav_folder(path)
        if mav is None:
            raise LogError(f"Expected a EuRoC/ASL dataset (mav0/imu0/data.csv), got {path}")
        self.path = path
        self.mav = mav
        self.progress = progress

    def _sensors(self) -> list[str]:
        return sorted(p.parent.name for p in self.mav.glob("*/data.csv"))

    def read(self, request: ReadRequest) -> LogData:
        progress = request.progress or self.progress
        if request.truth_frame is not None:
            raise LogError(
                f"Expected no truth frame for a EuRoC/ASL dataset (its truths are the folders "
                f"{', '.join(t.name for t in TRUTHS)}), got {request.truth_frame!r}"
            )
        imu = self._imu(request.imu_topic or "imu0")
        if imu.topic != "imu0" and request.truth_topic != "none":
            raise LogError(
                f"Expected imu0 with a truth (the dataset's truths are given in imu0's frame or "
                f"through it), got {imu.topic} in {self.mav}; add --truth-topic none to "
                f"integrate {imu.topic} without a truth"
            )
        channels = [ChannelInfo(imu.topic, CSV_TYPE, "csv", len(imu.t_ns))]
        if progress is not None:
            progress(0.5)
        notes: list[str] = []
        series = self._truths(request.truth_topic, notes)
        channels += [ChannelInfo(s.topic, CSV_TYPE, "csv", len(s.t_ns)) for s in series]
        channels += self._position_channels()
        truth = series[0] if series and request.truth_topic != "none" else None
        if progress is not None:
            progress(1.0)
        return LogData(
            self.path,
            imu,
            truth,
            tuple(channels),
            {},
            KIND,
            truth_candidates=tuple(series[1:]),
            notes=tuple(notes),
        )

    def _position_channels(self) -> list[ChannelInfo]:
        """The truth folders with positions only (``leica0``), their rows counted, not read."""
        out = []
        for t in TRUTHS:
            f = self.mav / t.name / "data.csv"
            if not t.attitude and f.is_file():
                with open(f, "rb") as lines:
                    rows = sum(1 for line in lines if line.strip() and not line.startswith(b"#"))
                out.append(ChannelInfo(t.name, POSITIONS_TYPE, "csv", rows))
        return out

    def _imu(self, name: str) -> ImuSeries:
        folder = self.mav / name
        if not folder.is_dir():
            raise LogError(
                f"Expected the IMU folder {name!r} (with data.csv) in {self.mav}, got "
                f"{', '.join(self._sensors()) or 'no sensor folders'}"
            )
        t_ns, v = read_csv(folder / "data.csv", IMU_COLUMNS)
        return ImuSeries(t_ns, t_ns, v[:, :3], None, name, CSV_TYPE, name, accel_b=v[:, 3:6])

    def _truths(self, named: str | None, notes: list[str]) -> list[TruthSeries]:
        """The truth series, the one to use first, then the other attitude candidates."""
        present = [t for t in TRUTHS if (self.mav / t.name).exists()]  # data.csv: checked
        for t in present:
            if not t.attitude:
                notes.append(f"{t.name}: {t.about}; no attitude, so not a truth")
        if named is not None and named != "none":
            chosen = next((t for t in present if t.name == named), None)
            if chosen is None or not chosen.attitude:
                what = "positions only" if chosen else ", ".join(t.name for t in present)
                raise LogError(
                    f"Expected an attitude truth {named!r} in {self.mav}, got "
                    f"{what or 'no truth folders'}"
                )
            present = [chosen] + [t for t in present if t is not chosen]
        out = []
        for k, t in enumerate(p for p in present if p.attitude):
            if named == "none":
                break
            try:
                out.append(self._truth(t, auto=named is None, notes=notes))
            except LogError as exc:
                if k == 0:
                    raise LogError(f"{exc}; --truth-topic none replays without a truth") from None
                notes.append(f"{t.name}: not read as a candidate truth: {exc}")
        if out:
            notes.insert(0, f"truth: {out[0].topic} ({TRUTHS_BY_NAME[out[0].topic].about})")
        return out

    def _truth(self, t: TruthFolder, auto: bool, notes: list[str]) -> TruthSeries:
        folder = self.mav / t.name
        t_ns, v = read_csv(folder / "data.csv", t.columns)
        q = v[:, [4, 5, 6, 3]]  # w, x, y, z -> x, y, z, w
        if not t.in_imu_frame:
            q = self._to_imu_frame(q, folder, notes)
        return TruthSeries(t_ns, t_ns, q, t.name, CSV_TYPE, "world", "imu0", auto)

    def _to_imu_frame(self, q_rs: NDArray, folder: Path, notes: list[str]) -> NDArray:
        """``q_RS ⊗ q_BS⁻¹ ⊗ q_B,imu``: the attitude of the IMU from that of the tracked body."""
        q_bs = sensor_rotation(folder)
        q_b_imu = sensor_rotation(self.mav / "imu0")
        if q_bs is None:
            notes.append(f"{folder.name}: no sensor.yaml; T_BS taken as the identity")
            q_bs = np.array([0.0, 0.0, 0.0, 1.0])
        else:
            notes.append(
                f"{folder.name}: T_BS of {folder.name}/sensor.yaml applied to the truth "
                f"(q_w_b = q_RS q_BS^-1 q_B,imu; a rotation of {_angle_deg(q_bs):.3f} deg)"
            )
        q = quat_multiply(q_rs, quat_conjugate(q_bs))
        if q_b_imu is not None and _angle_deg(q_b_imu) > 0.0:
            notes.append(
                f"imu0: T_BS of imu0/sensor.yaml applied to the truth "
                f"(a rotation of {_angle_deg(q_b_imu):.3f} deg)"
            )
            q = quat_multiply(q, q_b_imu)
        return q


TRUTHS_BY_NAME = {t.name: t for t in TRUTHS}

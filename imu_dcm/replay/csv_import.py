"""``convert-csv``: turn a CSV gyro log into a ROS 2 bag (MCAP) that the replay reads.

Every choice that a CSV leaves ambiguous is named on the command line: the columns, the time
unit (s, ms, us, ns), the gyro unit (rad/s, deg/s) and, for an optional truth quaternion, its
component order (``xyzw`` or ``wxyz``; no default, because a wrong order raises nothing).

Output topics: ``/imu/data`` (sensor_msgs/msg/Imu, rad/s, body axes) and, with truth,
``/ground_truth/orientation`` (geometry_msgs/msg/QuaternionStamped, ``q_w_b`` ``[x, y, z, w]``).
Rows with a non-finite quaternion get no truth message (as in the BROAD bags).
"""

from __future__ import annotations

import argparse
import csv
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from imu_dcm.cli import OneLineArgumentParser
from imu_dcm.errors import ImuDcmWarning, InputError, LogError
from imu_dcm.stamps import NS_PER_UNIT, timing_doubt

__all__ = ["TIME_UNITS_NS", "CsvColumns", "convert_csv", "convert_main", "read_csv_columns"]

#: Nanoseconds per unit of the time column.
TIME_UNITS_NS = NS_PER_UNIT


@dataclass(frozen=True)
class CsvColumns:
    """Columns read from the CSV: ``t_ns`` int64 (N,), ``omega_b`` rad/s (N, 3), truth or None."""

    t_ns: NDArray[np.int64]
    omega_b: NDArray[np.float64]
    q_w_b: NDArray[np.float64] | None


def _rows(reader, idx: list[int], width: int, name: str) -> NDArray[np.float64]:
    """The wanted columns of every data row as float64 (empty fields are NaN).

    Raises LogError naming the line of a ragged row or a field that is not a number.
    """
    out: list[list[float]] = []
    for row in reader:
        if not row or (len(row) == 1 and not row[0].strip()):
            continue  # blank line
        if len(row) != width:
            raise LogError(
                f"Expected {width} fields per row in {name} (as in the header), got "
                f"{len(row)} on line {reader.line_num}"
            )
        try:
            out.append([float(row[i]) if row[i].strip() else np.nan for i in idx])
        except ValueError:
            bad = next(row[i] for i in idx if row[i].strip() and not _is_float(row[i]))
            raise LogError(
                f"Expected numbers in {name}, got {bad[:40]!r} on line {reader.line_num}"
            ) from None
    return np.array(out, dtype=float).reshape(-1, len(idx))


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _split(names: str, n: int, what: str) -> list[str]:
    cols = [c.strip() for c in names.split(",")]
    if len(cols) != n or not all(cols):
        raise InputError(f"Expected {n} comma-separated column names for {what}, got {names!r}")
    return cols


def read_csv_columns(
    path: str | Path,
    *,
    time_col: str,
    time_unit: str,
    gyro_cols: str,
    gyro_units: str,
    truth_cols: str | None = None,
    truth_order: str | None = None,
    delimiter: str = ",",
) -> CsvColumns:
    """Read the named columns of a CSV with a header row, converting to ns and rad/s.

    Parameters
    ----------
    path : CSV file with a header row.
    time_col, time_unit : time column and its unit, one of ``s, ms, us, ns``.
    gyro_cols : "x,y,z" column names of the body rates; ``gyro_units`` "rad/s" or "deg/s".
    truth_cols, truth_order : four quaternion column names and their order, "xyzw" or "wxyz"
        (q_w_b, body to world). Both or neither.
    delimiter : field separator.
    """
    p = Path(path)
    if not p.is_file():
        raise LogError(f"Expected an existing CSV file, got {str(path)!r}")
    _check_options(time_unit, gyro_units, truth_cols, truth_order, delimiter)
    data = _read_table(p, time_col, gyro_cols, truth_cols, delimiter)
    t = data[:, 0]
    if not np.all(np.isfinite(t)):
        bad = int(np.flatnonzero(~np.isfinite(t))[0])
        raise InputError(
            f"Expected finite times in column {time_col!r}, got {t[bad]} in data row {bad}"
        )
    if np.any(t < 0):
        raise InputError(f"Expected times >= 0 in column {time_col!r}, got {t.min()}")
    if t.max() * TIME_UNITS_NS[time_unit] >= 2.0**63:
        fits = [u for u, f in TIME_UNITS_NS.items() if t.max() * f < 2.0**63]
        raise InputError(
            f"Expected times in {time_unit} in column {time_col!r}, got {t.max():.6g}, beyond "
            f"int64 nanoseconds (year 2262) in {time_unit}; the column's unit is likely "
            f"{fits[0] if fits else 'not a time'} (--time-units)"
        )
    t_ns = np.round(t * TIME_UNITS_NS[time_unit]).astype(np.int64)
    doubt = timing_doubt(np.sort(t_ns), time_unit)
    if doubt is not None:
        clause, fix = doubt
        hint = f"; pass --time-units {fix} if that is the column's unit" if fix else ""
        warnings.warn(
            f"{p.name}: column {time_col!r} in {time_unit} gives stamps no IMU produces: "
            f"{clause}{hint}",
            ImuDcmWarning,
            stacklevel=2,
        )
    omega = data[:, 1:4] * (np.pi / 180.0 if gyro_units == "deg/s" else 1.0)
    q = None
    if truth_cols is not None:
        q = data[:, 4:8]
        if truth_order == "wxyz":
            q = q[:, [1, 2, 3, 0]]
    return CsvColumns(t_ns, omega, q)


def _check_options(time_unit, gyro_units, truth_cols, truth_order, delimiter) -> None:
    if time_unit not in TIME_UNITS_NS:
        raise InputError(f"Expected time unit in {tuple(TIME_UNITS_NS)}, got {time_unit!r}")
    if gyro_units not in ("rad/s", "deg/s"):
        raise InputError(f"Expected gyro units 'rad/s' or 'deg/s', got {gyro_units!r}")
    if (truth_cols is None) != (truth_order is None):
        raise InputError(
            "Expected --truth-cols and --truth-order together (order xyzw or wxyz), "
            f"got cols={truth_cols!r}, order={truth_order!r}"
        )
    if truth_order is not None and truth_order not in ("xyzw", "wxyz"):
        raise InputError(f"Expected truth order 'xyzw' or 'wxyz', got {truth_order!r}")
    if not isinstance(delimiter, str) or len(delimiter) != 1 or delimiter in '\r\n"':
        raise InputError(
            f"Expected --delimiter to be one character (not a quote or newline), got {delimiter!r}"
        )


def _read_table(p: Path, time_col, gyro_cols, truth_cols, delimiter) -> NDArray[np.float64]:
    """The wanted columns (time, gyro x, y, z, truth) of every data row, float64."""
    try:
        with p.open(newline="", encoding="utf-8") as f:
            reader = csv.reader(f, delimiter=delimiter)
            header = next(reader, None)
            if not header:
                raise LogError(f"Expected a CSV header row in {p}, got an empty file")
            header = [h.strip() for h in header]
            wanted = [time_col, *_split(gyro_cols, 3, "--gyro-cols")]
            if truth_cols is not None:
                wanted += _split(truth_cols, 4, "--truth-cols")
            missing = [c for c in wanted if c not in header]
            if missing:
                shown = header if len(str(header)) < 300 else f"{len(header)} columns"
                raise InputError(f"Expected columns {missing} in {p.name}, got {shown}")
            idx = [header.index(c) for c in wanted]
            data = _rows(reader, idx, len(header), p.name)
    except UnicodeDecodeError as exc:
        raise LogError(
            f"Expected a UTF-8 text CSV in {p.name}, got the byte "
            f"0x{exc.object[exc.start]:02x} at offset {exc.start} of a read block"
        ) from None
    except csv.Error as exc:
        raise LogError(f"Expected a well-formed CSV in {p.name}, got {exc}") from None
    if data.size == 0:
        raise LogError(f"Expected data rows in {p.name}, got none")
    return data


def convert_csv(
    csv_path: str | Path,
    out_dir: str | Path,
    *,
    imu_topic: str = "/imu/data",
    truth_topic: str = "/ground_truth/orientation",
    frame_id: str = "imu",
    force: bool = False,
    **columns,
) -> Path:
    """Read a CSV (see :func:`read_csv_columns` for ``columns``) and write a ROS 2 bag.

    Returns the bag folder. The CSV is never modified; the bag appears whole or not at all. The
    output may not be or hold the CSV; ``force`` replaces only a bag this
    project wrote (:func:`imu_dcm.outputs.check_output_dir`).
    """
    from imu_dcm.logio.writer import StampedSeries, write_bag
    from imu_dcm.outputs import check_output_dir

    check_output_dir(out_dir, (csv_path,), force=force, what="output bag")
    cols = read_csv_columns(csv_path, **columns)
    quats = {}
    if cols.q_w_b is not None:
        q = cols.q_w_b
        norm = np.linalg.norm(q, axis=1)
        ok = np.isfinite(norm) & (norm > 0.5)
        quats[truth_topic] = StampedSeries(cols.t_ns[ok], q[ok] / norm[ok, None], "world")
    custom = {
        "imu_dcm.converted_from": Path(csv_path).name,
        "imu_dcm.columns": ", ".join(f"{k}={v}" for k, v in sorted(columns.items())),
    }
    return write_bag(
        out_dir,
        imu=StampedSeries(cols.t_ns, cols.omega_b, frame_id),
        quaternions=quats,
        imu_topic=imu_topic,
        custom_data=custom,
        force=force,
        inputs=(csv_path,),
    )


def build_parser() -> argparse.ArgumentParser:
    p = OneLineArgumentParser(
        prog="imu-dcm-replay convert-csv",
        description="Convert a CSV gyro log (with a header row) into a ROS 2 bag (MCAP).",
    )
    p.add_argument("csv", help="input CSV file (header row with column names)")
    p.add_argument("out", help="output bag folder")
    p.add_argument("--time-col", required=True, help="time column name")
    p.add_argument(
        "--time-units",
        "--time-unit",
        dest="time_unit",
        required=True,
        choices=tuple(TIME_UNITS_NS),
        help="unit of the time column (as live's --time-units; --time-unit is the same)",
    )
    p.add_argument(
        "--gyro-cols", required=True, metavar="X,Y,Z", help="body-rate column names, x,y,z"
    )
    p.add_argument("--gyro-units", required=True, choices=("rad/s", "deg/s"))
    p.add_argument("--truth-cols", metavar="A,B,C,D", help="truth quaternion column names")
    p.add_argument(
        "--truth-order",
        choices=("xyzw", "wxyz"),
        help="component order of --truth-cols (required with it)",
    )
    p.add_argument("--delimiter", default=",", help="field separator (default ,)")
    p.add_argument("--imu-topic", default="/imu/data")
    p.add_argument("--truth-topic", default="/ground_truth/orientation")
    p.add_argument("--frame-id", default="imu", help="IMU header.frame_id (default imu)")
    p.add_argument("--force", action="store_true", help="replace an existing output bag")
    return p


def convert_main(argv: list[str]) -> int:
    """The ``convert-csv`` sub-command; returns 0 (errors raise project errors)."""
    a = build_parser().parse_args(argv)
    out = convert_csv(
        a.csv,
        a.out,
        imu_topic=a.imu_topic,
        truth_topic=a.truth_topic,
        frame_id=a.frame_id,
        force=a.force,
        time_col=a.time_col,
        time_unit=a.time_unit,
        gyro_cols=a.gyro_cols,
        gyro_units=a.gyro_units,
        truth_cols=a.truth_cols,
        truth_order=a.truth_order,
        delimiter=a.delimiter,
    )
    print(f"wrote {out}")
    return 0

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
import shutil
import tempfile
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from imu_dcm.app.options import OneLineArgumentParser
from imu_dcm.errors import ImuDcmWarning, InputError, LogError
from imu_dcm.gyro.rest_rule import GRAVITY_M_S2
from imu_dcm.gyro.stamps import NS_PER_UNIT, timing_doubt
from imu_dcm.outputs import OutputError, check_output_dir, check_output_file, ensure_parent

__all__ = ["TIME_UNITS_NS", "CsvColumns", "convert_csv", "convert_main", "read_csv_columns"]

#: Nanoseconds per unit of the time column.
TIME_UNITS_NS = NS_PER_UNIT


#: Accelerometer units and their factor to m/s² (``g`` is the standard gravity).
ACCEL_UNITS = {"m/s^2": 1.0, "g": GRAVITY_M_S2}


@dataclass(frozen=True)
class CsvColumns:
    """Columns read from the CSV: ``t_ns`` int64 (N,), ``omega_b`` rad/s (N, 3), truth
    ``q_w_b`` ``[x, y, z, w]`` (N, 4) or None, specific force ``accel_b`` m/s² (N, 3) or None,
    all in body (sensor) axes."""

    t_ns: NDArray[np.int64]
    omega_b: NDArray[np.float64]
    q_w_b: NDArray[np.float64] | None
    accel_b: NDArray[np.float64] | None = None


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
    accel_cols: str | None = None,
    accel_units: str | None = None,
) -> CsvColumns:
    """Read the named columns of a CSV with a header row, converting to ns, rad/s and m/s².

    Parameters
    ----------
    path : CSV file with a header row.
    time_col, time_unit : time column and its unit, one of ``s, ms, us, ns``.
    gyro_cols : "x,y,z" column names of the body rates; ``gyro_units`` "rad/s" or "deg/s".
    truth_cols, truth_order : four quaternion column names and their order, "xyzw" or "wxyz"
        (q_w_b, body to world). Both or neither.
    delimiter : field separator.
    accel_cols, accel_units : "x,y,z" column names of the accelerometer (specific force, body
        axes) and their unit, "m/s^2" or "g" (standard gravity). Both or neither.
    """
    p = Path(path)
    if not p.is_file():
        raise LogError(f"Expected an existing CSV file, got {str(path)!r}")
    _check_options(time_unit, gyro_units, truth_cols, truth_order, delimiter)
    _check_accel(accel_cols, accel_units)
    wanted = [time_col, *_split(gyro_cols, 3, "--gyro-cols")]
    if truth_cols is not None:
        wanted += _split(truth_cols, 4, "--truth-cols")
    if accel_cols is not None:
        wanted += _split(accel_cols, 3, "--accel-cols")
    data = _read_table(p, wanted, delimiter)
    t_ns = _stamps(data[:, 0], time_col, time_unit, p.name)
    omega = data[:, 1:4] * (np.pi / 180.0 if gyro_units == "deg/s" else 1.0)
    q = None
    if truth_cols is not None:
        q = _order(data[:, 4:8], truth_order)
    accel = None
    if accel_cols is not None:
        accel = data[:, -3:] * ACCEL_UNITS[accel_units]
    return CsvColumns(t_ns, omega, q, accel)


def read_truth_csv(
    path: str | Path,
    *,
    time_col: str,
    time_unit: str,
    truth_cols: str,
    truth_order: str,
    delimiter: str = ",",
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """The truth of a second CSV: its stamps (int64 ns, its own time column, the same unit as
    the gyro's) and ``q_w_b`` ``[x, y, z, w]`` (M, 4), for loggers that write the gyro and the
    quaternion in two files (x-IMU3: ``Inertial.csv`` and ``Quaternion.csv``)."""
    p = Path(path)
    if not p.is_file():
        raise LogError(f"Expected an existing truth CSV file, got {str(path)!r}")
    data = _read_table(p, [time_col, *_split(truth_cols, 4, "--truth-cols")], delimiter)
    return _stamps(data[:, 0], time_col, time_unit, p.name), _order(data[:, 1:5], truth_order)


def _order(q: NDArray[np.float64], order: str | None) -> NDArray[np.float64]:
    """The quaternion columns as ``[x, y, z, w]``."""
    return q[:, [1, 2, 3, 0]] if order == "wxyz" else q


def _check_accel(accel_cols: str | None, accel_units: str | None) -> None:
    if (accel_cols is None) != (accel_units is None):
        raise InputError(
            "Expected --accel-cols and --accel-units together (units m/s^2 or g), got "
            f"cols={accel_cols!r}, units={accel_units!r}"
        )
    if accel_units is not None and accel_units not in ACCEL_UNITS:
        raise InputError(f"Expected accel units 'm/s^2' or 'g', got {accel_units!r}")


def _stamps(t: NDArray[np.float64], time_col: str, time_unit: str, name: str) -> NDArray:
    """The time column as int64 ns, checked (finite, >= 0, in int64), doubts warned."""
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
            f"{name}: column {time_col!r} in {time_unit} gives stamps no IMU produces: "
            f"{clause}{hint}",
            ImuDcmWarning,
            stacklevel=3,
        )
    return t_ns


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


def _read_table(p: Path, wanted: list[str], delimiter: str) -> NDArray[np.float64]:
    """The ``wanted`` columns (by header name, in that order) of every data row, float64."""
    try:
        with p.open(newline="", encoding="utf-8") as f:
            reader = csv.reader(f, delimiter=delimiter)
            header = next(reader, None)
            if not header:
                raise LogError(f"Expected a CSV header row in {p}, got an empty file")
            header = [h.strip() for h in header]
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
    truth_csv: str | Path | None = None,
    truth_time_col: str | None = None,
    truth_estimate_of: str | None = None,
    **columns,
) -> Path:
    """Read a CSV (see :func:`read_csv_columns` for ``columns``) and write a ROS 2 bag.

    Returns what was written: ``out_dir`` as the user named it. A path ending in ``.mcap`` is
    one MCAP file (no ``metadata.yaml``); any other path is a bag folder. The CSV is never
    modified; the output appears whole or not at all and may not be or hold an input;
    ``force`` replaces only what this project wrote (:func:`imu_dcm.outputs.check_output_dir`;
    for a ``.mcap``, a file whose header names the project's writer).

    ``truth_csv``: the truth quaternion (``truth_cols``, ``truth_order``) read from a second
    CSV with its own stamps (``truth_time_col``, default the gyro's ``time_col``; the same
    unit), as loggers that write the gyro and the quaternion in two files do. Each truth row
    becomes one message at its own stamp: the two files need not share their rows.

    ``truth_estimate_of``: who estimated the truth (``"the x-IMU3"``), when it is a device's
    own estimate rather than an independent reference. The bag's ``custom_data`` then holds
    ``imu_dcm.estimate_of:<truth_topic>`` = ``"<who>'s own estimate"``, which the reader gives
    as the truth's ``estimate_of`` (:data:`imu_dcm.logio.ros.truth.ESTIMATE_OF_KEY`).
    """
    inputs = tuple(x for x in (csv_path, truth_csv) if x is not None)
    single = str(out_dir).endswith(".mcap")
    if single:
        _check_mcap_output(Path(out_dir), inputs, force)
    else:
        check_output_dir(out_dir, inputs, force=force, what="output bag")
    gyro_columns = dict(columns)
    if truth_csv is not None:
        for k in ("truth_cols", "truth_order"):
            gyro_columns.pop(k, None)
        if columns.get("truth_cols") is None or columns.get("truth_order") is None:
            raise InputError(
                "Expected --truth-cols and --truth-order with --truth-csv (the quaternion "
                f"columns of {Path(truth_csv).name} and their order), got none"
            )
    if truth_estimate_of is not None and (
        columns.get("truth_cols") is None or not truth_estimate_of.strip()
    ):
        got = "no --truth-cols" if columns.get("truth_cols") is None else "an empty name"
        raise InputError(f"Expected --truth-estimate-of WHO with --truth-cols, got {got}")
    cols = read_csv_columns(csv_path, **gyro_columns)
    t_q, q = (
        (cols.t_ns, cols.q_w_b)
        if truth_csv is None
        else read_truth_csv(
            truth_csv,
            time_col=truth_time_col or columns["time_col"],
            time_unit=columns["time_unit"],
            truth_cols=columns["truth_cols"],
            truth_order=columns["truth_order"],
            delimiter=columns.get("delimiter", ","),
        )
    )
    custom = {
        "imu_dcm.converted_from": ", ".join(Path(x).name for x in inputs),
        "imu_dcm.columns": ", ".join(f"{k}={v}" for k, v in sorted(columns.items())),
    }
    if truth_estimate_of is not None:
        from imu_dcm.logio.ros.truth import ESTIMATE_OF_KEY

        custom[ESTIMATE_OF_KEY + truth_topic] = f"{truth_estimate_of.strip()}'s own estimate"
    write = _write_mcap_file if single else _write_folder
    return write(
        Path(out_dir), cols, t_q, q, custom, imu_topic, truth_topic, frame_id, force, inputs
    )


def _series(cols: CsvColumns, t_q, q, imu_topic: str, truth_topic: str, frame_id: str) -> dict:
    """The keywords of :func:`imu_dcm.logio.writers.write_bag` (rows without a finite, non-zero
    quaternion get no truth message)."""
    from imu_dcm.logio.writers import StampedSeries

    quats = {}
    if q is not None:
        norm = np.linalg.norm(q, axis=1)
        ok = np.isfinite(norm) & (norm > 0.5)
        quats[truth_topic] = StampedSeries(t_q[ok], q[ok] / norm[ok, None], "world")
    return {
        "imu": StampedSeries(cols.t_ns, cols.omega_b, frame_id),
        "quaternions": quats,
        "imu_topic": imu_topic,
        "imu_linear_acceleration": cols.accel_b,
    }


def _write_folder(out, cols, t_q, q, custom, imu_topic, truth_topic, frame_id, force, inputs):
    from imu_dcm.logio.writers import write_bag

    kw = _series(cols, t_q, q, imu_topic, truth_topic, frame_id)
    return write_bag(out, custom_data=custom, force=force, inputs=inputs, **kw)


def _check_mcap_output(out: Path, inputs: tuple, force: bool) -> None:
    """A ``.mcap`` output: a new file, or with ``force`` one this project's writer wrote."""
    from imu_dcm.logio.writers import OWN_LIBRARY

    check_output_file(out, inputs, what="output MCAP file")
    if out.exists():
        with open(out, "rb") as f:
            head = f.read(256)
        if not force or OWN_LIBRARY.encode() not in head:
            why = "add --force" if not force else "it is not one this tool wrote"
            raise OutputError(f"Expected a new output MCAP file, got an existing {out} ({why})")


def _write_mcap_file(out, cols, t_q, q, custom, imu_topic, truth_topic, frame_id, force, inputs):
    """The bag written into a temporary sibling folder, its ``.mcap`` renamed to ``out``."""

    from imu_dcm.logio.writers import write_bag

    ensure_parent(out, "output MCAP file")
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        kw = _series(cols, t_q, q, imu_topic, truth_topic, frame_id)
        bag = write_bag(tmp / out.stem, custom_data=custom, inputs=inputs, **kw)
        _check_mcap_output(out, inputs, force)  # unchanged meanwhile
        (bag / f"{out.stem}.mcap").replace(out)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return out


def build_parser() -> argparse.ArgumentParser:
    p = OneLineArgumentParser(
        prog="imu-dcm-replay convert-csv",
        description="Convert a CSV gyro log (with a header row) into a ROS 2 bag (MCAP): a "
        "folder, or one .mcap file when OUT ends in .mcap.",
    )
    p.add_argument("csv", help="input CSV file (header row with column names)")
    p.add_argument("out", help="output: a bag folder, or a single file when it ends in .mcap")
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
    p.add_argument(
        "--accel-cols", metavar="X,Y,Z", help="accelerometer column names (specific force)"
    )
    p.add_argument(
        "--accel-units", choices=tuple(ACCEL_UNITS), help="unit of --accel-cols: m/s^2 or g"
    )
    p.add_argument("--truth-cols", metavar="A,B,C,D", help="truth quaternion column names")
    p.add_argument(
        "--truth-order",
        choices=("xyzw", "wxyz"),
        help="component order of --truth-cols (required with it)",
    )
    p.add_argument(
        "--truth-csv",
        metavar="FILE",
        help="read --truth-cols from this second CSV, at its own stamps (same time unit)",
    )
    p.add_argument("--truth-time-col", help="time column of --truth-csv (default: --time-col)")
    p.add_argument(
        "--truth-estimate-of",
        metavar="WHO",
        help="the truth is WHO's own estimate (e.g. 'the x-IMU3': its AHRS output), not an "
        'independent reference; replay, batch and info then say "WHO\'s own estimate"',
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
    if a.truth_time_col is not None and a.truth_csv is None:
        raise InputError("Expected --truth-csv with --truth-time-col, got no --truth-csv")
    out = convert_csv(
        a.csv,
        a.out,
        imu_topic=a.imu_topic,
        truth_topic=a.truth_topic,
        frame_id=a.frame_id,
        force=a.force,
        truth_csv=a.truth_csv,
        truth_time_col=a.truth_time_col,
        truth_estimate_of=a.truth_estimate_of,
        time_col=a.time_col,
        time_unit=a.time_unit,
        gyro_cols=a.gyro_cols,
        gyro_units=a.gyro_units,
        truth_cols=a.truth_cols,
        truth_order=a.truth_order,
        delimiter=a.delimiter,
        accel_cols=a.accel_cols,
        accel_units=a.accel_units,
    )
    print(f"wrote {out}")
    return 0

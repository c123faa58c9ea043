"""The results table of a batch replay: one :class:`LogRow` per log, as CSV, markdown and curves.

Files written next to each other for a table ``OUT.csv``:

- ``OUT.csv``: one row per log, appended as each log finishes. Every append writes whole lines
  in one ``write`` on a file opened for appending, then ``fsync``, so a batch killed at any
  moment leaves complete rows only (a torn last line left by a crash of the machine is dropped
  when the table is read again). Numbers are written with ``repr``, which reads back to the
  same bits.
- ``OUT.curves.jsonl``: the error-over-time curve of each log (at most :data:`CURVE_POINTS`
  points, the largest error in each time bin), appended before the row, for the chart.
- ``OUT.md``: the table for people, with a summary line; rewritten (write, then rename) at the
  end of a batch. Its first line is an HTML comment ``<!-- imu_dcm ... -->`` (invisible when
  rendered): the signature by which a later batch recognises its own file.

Each file is replaced or appended to only when it is new or this tool's (its header row, its
JSON lines, its comment line: :mod:`imu_dcm.outputs.signatures`); appends never follow a symbolic
link.
"""

from __future__ import annotations

import csv
import io
import json
import os
import statistics
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from imu_dcm.app.run import one_line
from imu_dcm.errors import InputError
from imu_dcm.outputs import claim_output, write_atomic
from imu_dcm.outputs.signatures import signature
from imu_dcm.replay.kinds import KINDS

__all__ = [
    "COLUMNS",
    "COMPARE_COLUMNS",
    "CURVE_POINTS",
    "Curve",
    "LogRow",
    "append_curve",
    "append_rows",
    "curves_path",
    "decimate_curve",
    "markdown_path",
    "read_curves",
    "read_table",
    "row_key",
    "row_label",
    "summary_line",
    "table_methods",
    "write_curves",
    "write_markdown",
    "write_table",
]

#: Points kept of each log's error curve (the largest error in each of this many time bins).
CURVE_POINTS = 300
#: Separator of several warnings in one CSV cell.
WARNING_SEPARATOR = " | "


@dataclass(frozen=True)
class LogRow:
    """The outcome of replaying one log. Numbers are None when the log failed or has no truth.

    Attributes
    ----------
    path : str — the log (absolute path, as found).
    samples : int — gyro samples replayed (after cleaning).
    duration_s : float — first to last replayed sample, s.
    rate_hz : float — 1 / median sample step, Hz.
    imu_topic, truth_topic : str — channels used (truth None when the log has none).
    truth_kind : str — what the error is against (:mod:`imu_dcm.replay.kinds`): "independent
        reference", "the vehicle's own estimate" or "none"; None when the log failed.
    bias_x_rad_s, bias_y_rad_s, bias_z_rad_s : float — mean gyro bias removed, body axes, rad/s.
    rms_error_deg, max_error_deg : float — total attitude error against the truth, deg.
    rms_inclination_deg, max_inclination_deg : float — tilt part of the error, deg.
    rms_heading_deg, max_heading_deg : float — heading part of the error, deg.
    dropped : int — samples dropped while cleaning (NaN/Inf, duplicate, backward, ...).
    gaps : int — gaps over 5x the median step.
    warnings : tuple of str — one line per warning the replay gave.
    elapsed_s : float — wall time of this log's replay in its worker, s.
    error : str — one line ``Type: message`` when the log failed, else None.
    method : str — with ``--compare`` only: the method or peer of this row (the rows of a log
        share everything but the errors, ``method`` and ``ns_per_sample``); None otherwise.
    ns_per_sample : float — with ``--compare`` only: that method's integration cost, ns.
    """

    path: str
    samples: int | None = None
    duration_s: float | None = None
    rate_hz: float | None = None
    imu_topic: str | None = None
    truth_topic: str | None = None
    truth_kind: str | None = None
    bias_x_rad_s: float | None = None
    bias_y_rad_s: float | None = None
    bias_z_rad_s: float | None = None
    rms_error_deg: float | None = None
    max_error_deg: float | None = None
    rms_inclination_deg: float | None = None
    max_inclination_deg: float | None = None
    rms_heading_deg: float | None = None
    max_heading_deg: float | None = None
    dropped: int | None = None
    gaps: int | None = None
    warnings: tuple[str, ...] = ()
    elapsed_s: float | None = None
    error: str | None = None
    method: str | None = None
    ns_per_sample: float | None = None

    @property
    def failed(self) -> bool:
        return self.error is not None


#: The columns of a compared table (``--compare``) after :data:`COLUMNS`: its rows are keyed by
#: (path, method).
COMPARE_EXTRA = ("method", "ns_per_sample")
#: The table's columns (one row per log); a compared table adds :data:`COMPARE_EXTRA`.
COLUMNS = tuple(f.name for f in fields(LogRow) if f.name not in COMPARE_EXTRA)
COMPARE_COLUMNS = (*COLUMNS, *COMPARE_EXTRA)
_INT = {"samples", "dropped", "gaps"}
_FLOAT = {f.name for f in fields(LogRow) if f.name.endswith(("_s", "_hz", "_deg"))}
_FLOAT.add("ns_per_sample")


def row_key(row: LogRow) -> tuple[str, str | None]:
    """What identifies a row in its table: (path, method), the method None without compare."""
    return row.path, row.method


def row_label(row: LogRow) -> str:
    """The row's path, with `` [method]`` in a compared table (its curve's key, its name)."""
    return row.path if row.method is None else f"{row.path} [{row.method}]"


@dataclass(frozen=True)
class Curve:
    """A log's attitude error over time, decimated for a chart: ``t_s`` (K,) seconds since the
    log's first sample, ``error_deg`` (K,) total error, deg (NaN where there is none)."""

    path: str
    t_s: tuple[float, ...]
    error_deg: tuple[float, ...]


def decimate_curve(
    path: str, t_s: ArrayLike, error_deg: ArrayLike, points: int = CURVE_POINTS
) -> Curve:
    """Keep the largest error in each of ``points`` equal-count bins (peaks survive); 4 digits.

    ``t_s`` (N,) s and ``error_deg`` (N,) deg, NaN where no error was measured.
    """
    t = np.asarray(t_s, dtype=float)
    e = np.asarray(error_deg, dtype=float)
    if len(t) == 0:
        return Curve(path, (), ())
    edges = np.unique(np.linspace(0, len(t), min(points, len(t)) + 1).astype(int))[:-1]
    finite = np.where(np.isfinite(e), e, -np.inf)
    peak = np.maximum.reduceat(finite, edges)
    peak = np.where(np.isfinite(peak), peak, np.nan)
    return Curve(
        path, tuple(float(f"{x:.4g}") for x in t[edges]), tuple(float(f"{x:.4g}") for x in peak)
    )


# --------------------------------------------------------------------------- CSV cells
def _cell(name: str, value) -> str:
    if value is None:
        return ""
    if name == "warnings":
        return WARNING_SEPARATOR.join(one_line(w) for w in value)
    if isinstance(value, float):
        return repr(value)  # shortest text that reads back to the same bits
    return one_line(str(value))


def _parse(name: str, text: str):
    if name == "warnings":
        return tuple(text.split(WARNING_SEPARATOR)) if text else ()
    if text == "":
        return None
    if name in _INT:
        return int(text)
    if name in _FLOAT:
        return float(text)
    return text


def format_lines(rows: Sequence[LogRow], header: bool = False) -> str:
    """CSV text of ``rows`` (each ending in a newline), with the header line first if asked:
    :data:`COMPARE_COLUMNS` when the rows carry a method, else :data:`COLUMNS`."""
    columns = COMPARE_COLUMNS if any(r.method is not None for r in rows) else COLUMNS
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    if header:
        w.writerow(columns)
    for r in rows:
        w.writerow([_cell(n, getattr(r, n)) for n in columns])
    return buf.getvalue()


# ------------------------------------------------------------------------------- files
def markdown_path(table: str | Path) -> Path:
    return Path(table).with_suffix(".md")


def curves_path(table: str | Path) -> Path:
    return Path(table).with_suffix(".curves.jsonl")


def _append(path: Path, text: str) -> None:
    """Append whole lines with one ``write`` call (retried on a short write), then fsync."""
    data = memoryview(text.encode())
    flags = os.O_WRONLY | os.O_APPEND | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0)
    fd = os.open(path, flags, 0o644)
    try:
        while data:
            data = data[os.write(fd, data) :]
        os.fsync(fd)
    finally:
        os.close(fd)


def _replace(path: Path, text: str, kind: str) -> None:
    """Replace ``path`` with ``text`` whole, if it is new or this tool's file of ``kind``
    (:func:`imu_dcm.outputs.claim_output`, then :func:`~imu_dcm.outputs.write_atomic`)."""
    write_atomic(claim_output(path, kind, what=f"the batch {kind} file"), text)


def append_rows(table: str | Path, rows: Sequence[LogRow]) -> None:
    """Append ``rows`` to the CSV ``table`` (with the header when the file is new or empty)."""
    p = Path(table)
    new = not p.exists() or p.stat().st_size == 0
    _append(p, format_lines(rows, header=new))


def write_table(table: str | Path, rows: Sequence[LogRow]) -> None:
    """Replace the CSV ``table`` with ``rows`` (rename over the old file: never half written)."""
    _replace(Path(table), format_lines(rows, header=True), "table")


def read_table(table: str | Path) -> list[LogRow]:
    """The rows of a CSV table written by :func:`append_rows` (empty when it does not exist).

    A last line without its newline (the machine went down mid-write) is dropped and the file
    is rewritten without it. The rows of a compared table carry their ``method``.

    Raises
    ------
    InputError
        A header other than :data:`COLUMNS` or :data:`COMPARE_COLUMNS`, or a complete line with
        the wrong number of cells.
    """
    p = Path(table)
    if not p.exists():
        return []
    text = p.read_text()
    if text and not text.endswith("\n"):
        text = text[: text.rfind("\n") + 1]
        _replace(p, text, "table")
    lines = list(csv.reader(io.StringIO(text)))
    if not lines:
        return []
    columns = tuple(lines[0])
    if columns not in (COLUMNS, COMPARE_COLUMNS):
        raise InputError(
            f"Expected a batch table with columns {','.join(COLUMNS[:3])},..., got "
            f"{','.join(lines[0][:3])},... in {p}"
        )
    rows = []
    for k, cells in enumerate(lines[1:], start=2):
        if len(cells) != len(columns):
            raise InputError(f"Expected {len(columns)} cells on line {k} of {p}, got {len(cells)}")
        rows.append(LogRow(**{n: _parse(n, c) for n, c in zip(columns, cells, strict=True)}))
    return rows


def table_methods(table: str | Path) -> tuple[str, ...] | None:
    """The ``--compare`` methods a table was written with, in their order (None for a table
    without them, or one that does not exist or is empty)."""
    p = Path(table)
    if not p.exists():
        return None
    with p.open(newline="") as f:
        header = next(csv.reader(f), None)
    if header is None or tuple(header) != COMPARE_COLUMNS:
        return None
    return tuple(dict.fromkeys(r.method for r in read_table(p) if r.method is not None))


def append_curve(table: str | Path, curve: Curve) -> None:
    _append(curves_path(table), json.dumps(curve.__dict__, allow_nan=True) + "\n")


def read_curves(table: str | Path) -> dict[str, Curve]:
    """Curves by path (the last one of a path wins; a torn last line is skipped)."""
    p = curves_path(table)
    out: dict[str, Curve] = {}
    if not p.exists():
        return out
    for line in p.read_text().splitlines(keepends=True):
        if not line.endswith("\n"):
            break
        d = json.loads(line)
        out[d["path"]] = Curve(d["path"], tuple(d["t_s"]), tuple(d["error_deg"]))
    return out


def write_curves(table: str | Path, curves: Iterable[Curve]) -> None:
    text = "".join(json.dumps(c.__dict__, allow_nan=True) + "\n" for c in curves)
    _replace(curves_path(table), text, "curves")


# ---------------------------------------------------------------------------- markdown
def _num(x: float | None, digits: int = 3) -> str:
    return "" if x is None else f"{x:.{digits}g}"


def _stats(rms: list[float]) -> str:
    return f"mean {statistics.fmean(rms):.4g}°, median {statistics.median(rms):.4g}°"


def summary_line(rows: Sequence[LogRow]) -> str:
    """``N logs, F failed; RMS error over M logs with truth (KIND): mean X°, median Y°``, one
    mean per kind of truth (:mod:`imu_dcm.replay.kinds`) when the logs have several: an error
    against a vehicle's own estimate is never averaged with one against a reference. A
    compared table gives one such line per method, joined by `` | ``."""
    methods = list(dict.fromkeys(r.method for r in rows if r.method is not None))
    if methods:  # a compared table: one summary per method, never averaged across methods
        return " | ".join(f"{m}: {_summary([r for r in rows if r.method == m])}" for m in methods)
    return _summary(rows)


def _summary(rows: Sequence[LogRow]) -> str:
    """:func:`summary_line` of rows of one method (or of a table without methods)."""
    failed = sum(r.failed for r in rows)
    by_kind: dict[str, list[float]] = {}
    for r in rows:
        if r.rms_error_deg is not None:
            by_kind.setdefault(r.truth_kind or "kind not recorded", []).append(r.rms_error_deg)
    head = f"{len(rows)} log{'s' if len(rows) != 1 else ''}, {failed} failed"
    if not by_kind:
        return f"{head}; no log with truth, no RMS error"
    order = sorted(by_kind, key=lambda k: KINDS.index(k) if k in KINDS else len(KINDS))
    if len(order) == 1:
        rms = by_kind[order[0]]
        return (
            f"{head}; RMS error over {len(rms)} log{'s' if len(rms) != 1 else ''} with truth "
            f"({order[0]}): {_stats(rms)}"
        )
    parts = [
        f"{k}, {len(by_kind[k])} log{'s' if len(by_kind[k]) != 1 else ''}: {_stats(by_kind[k])}"
        for k in order
    ]
    return f"{head}; RMS error by kind of truth: " + "; ".join(parts)


def short_names(paths: Sequence[str]) -> list[str]:
    """The shortest tails of the paths (name, parent/name, ...) that tell the logs apart."""
    parts = [Path(p.rstrip("/")).parts for p in paths]
    depth = 1
    while True:
        names = ["/".join(q[-depth:]) for q in parts]
        if len(set(names)) == len(names) or depth >= max((len(q) for q in parts), default=1):
            return names
        depth += 1


def markdown(rows: Sequence[LogRow]) -> str:
    """The table for people: one line per log, errors in degrees, and the summary line."""
    head = (
        "| log | truth | samples | duration s | rate Hz | RMS ° | max ° | RMS incl. ° | "
        "RMS heading ° | dropped | gaps | warnings | elapsed s | error |"
    )
    lines = [head, "|" + "---|" * head.count(" | ") + "---|"]
    for name, r in zip(short_names([row_label(r) for r in rows]), rows, strict=False):
        cells = [
            name,
            r.truth_kind or "",
            "" if r.samples is None else str(r.samples),
            _num(r.duration_s, 4),
            _num(r.rate_hz, 4),
            _num(r.rms_error_deg),
            _num(r.max_error_deg),
            _num(r.rms_inclination_deg),
            _num(r.rms_heading_deg),
            "" if r.dropped is None else str(r.dropped),
            "" if r.gaps is None else str(r.gaps),
            str(len(r.warnings)),
            _num(r.elapsed_s, 2),
            r.error or "",
        ]
        lines.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
    sign = f"<!-- {signature('batch table: replay of many logs')} -->"
    return "\n".join([sign, "", *lines]) + "\n\n" + summary_line(rows) + "\n"


def write_markdown(table: str | Path, rows: Sequence[LogRow]) -> Path:
    p = markdown_path(table)
    _replace(p, markdown(rows), "markdown")
    return p

"""One log of a batch, replayed into table rows: :func:`replay_one` (one row) and
:func:`replay_compare` (one row per method), the functions every runner calls
(:mod:`imu_dcm.replay.runners`: in this process, in a pool worker, on a Dask worker). Neither
raises: a log that fails gives rows carrying its one-line error. The log's warnings travel with
its result (:class:`~imu_dcm.errors.Diagnostics`), so replays in threads of one process keep
theirs apart.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Iterable, Mapping
from typing import Any

from imu_dcm.errors import Diagnostics
from imu_dcm.replay.kinds import truth_kind
from imu_dcm.replay.table import Curve, LogRow, decimate_curve, one_line, row_label

__all__ = ["per_method", "replay_compare", "replay_one", "row_from_result"]


def row_from_result(path: str, result, warnings_seen: Iterable[str], elapsed_s: float) -> LogRow:
    """The table row of one replay result (the one place that reads a replay's summary).

    ``dropped`` sums every ``dropped_*`` count of the :class:`ReplaySummary`; warnings are the
    replay's own plus ``warnings_seen`` (its diagnostics: the reader's too), each once.
    """
    s = result.summary
    bx, by, bz = (float(b) for b in s.bias_rad_s)
    dropped = sum(v for k, v in vars(s).items() if k.startswith("dropped_"))
    said = dict.fromkeys(one_line(w) for w in (*s.warnings, *warnings_seen))
    return LogRow(
        path=path,
        samples=int(s.samples),
        duration_s=float(s.duration_s),
        rate_hz=float(s.rate_hz),
        imu_topic=s.imu_topic,
        truth_topic=s.truth_topic,
        truth_kind=truth_kind(s.truth_estimate_of if s.truth_topic else None),
        bias_x_rad_s=bx,
        bias_y_rad_s=by,
        bias_z_rad_s=bz,
        rms_error_deg=s.rms_error_deg,
        max_error_deg=s.max_error_deg,
        rms_inclination_deg=s.rms_inclination_deg,
        max_inclination_deg=s.max_inclination_deg,
        rms_heading_deg=s.rms_heading_deg,
        max_heading_deg=s.max_heading_deg,
        dropped=int(dropped),
        gaps=len(s.gaps),
        warnings=tuple(said),
        elapsed_s=float(elapsed_s),
    )


def replay_one(path: str, options: Mapping[str, Any]) -> tuple[LogRow, Curve | None]:
    """Replay one log with ``options`` (keywords of :func:`imu_dcm.replay.replay`); never raises
    an ``Exception``: a failure gives a row with ``error`` set and no curve.

    Returns the row and the log's total error over time, decimated (None without truth).
    """
    rows, curves = _replay_rows(path, options, None)
    return rows[0], (curves[0] if curves else None)


def replay_compare(
    path: str, options: Mapping[str, Any]
) -> tuple[tuple[LogRow, ...], tuple[Curve, ...]]:
    """:func:`replay_one` with ``options["compare"]``, a tuple of method names: the log is
    replayed once, then every method integrates the same rates from the same start
    (:func:`imu_dcm.replay.compare.compare_methods`, as the single-log ``--compare``).

    Returns one row per method, in the order given (``method`` and ``ns_per_sample`` set; the
    replay's own method's row is the replay's row), and their curves keyed by
    :func:`~imu_dcm.replay.table.row_label`. A failure gives every method a row with the error.
    """
    options = dict(options)
    names = tuple(options.pop("compare"))
    return _replay_rows(path, options, names)


def _replay_rows(path: str, options: Mapping[str, Any], names: tuple[str, ...] | None):
    """The rows and curves of one log: one row (names None) or one per method of ``names``."""
    t0 = time.perf_counter()
    # Lazy: the replay costs ~50 ms of CPU to import, which a Dask batch's driver never needs;
    # the comparison ~270 ms (its peers load scipy), which a batch without --compare never needs.
    from imu_dcm.replay.core import replay

    said = Diagnostics()  # the log's warnings travel with its result: no process-wide state
    try:
        result = replay(path, diagnostics=said, **options)
        compared = None
        if names is not None:
            from imu_dcm.replay.compare import compare_methods

            compared = compare_methods(result, names)
        row = row_from_result(path, result, said.lines(), time.perf_counter() - t0)
    except Exception as exc:
        seen = tuple(dict.fromkeys(one_line(m) for m in said.warned()))
        error = f"{type(exc).__name__}: {one_line(str(exc))}"
        failed = LogRow(path, warnings=seen, elapsed_s=time.perf_counter() - t0, error=error)
        return per_method(failed, names), ()
    if compared is None:
        curves = ()
        if row.rms_error_deg is not None:
            curves = (decimate_curve(path, result.t_s, result.error.total_deg),)
        return (row,), curves
    return _compared_rows(row, result, compared)


def per_method(row: LogRow, names: tuple[str, ...] | None) -> tuple[LogRow, ...]:
    """``row`` once (names None) or once per method of ``names``, each with its method set."""
    if names is None:
        return (row,)
    return tuple(dataclasses.replace(row, method=n) for n in names)


def _compared_rows(row: LogRow, result, compared) -> tuple[tuple[LogRow, ...], tuple[Curve, ...]]:
    """One row and curve per method: the replay's own method keeps the replay's figures, every
    other method gets its statistics from the comparison (the same the single-log
    ``--compare`` prints); heading-only truth scores the heading, as the replay does."""
    planar = result.summary.scored_on == "heading"
    rows, curves = [], []
    for c in compared:
        r = dataclasses.replace(row, method=c.name, ns_per_sample=float(c.ns_per_sample))
        if c.name != result.summary.method:
            ev = c.evaluation
            tot = None if ev is None else ev["heading_deg" if planar else "total_deg"]
            inc = None if ev is None or planar else ev["inclination_deg"]
            head = None if ev is None else ev["heading_deg"]
            r = dataclasses.replace(
                r,
                rms_error_deg=_stat(tot, "rms"),
                max_error_deg=_stat(tot, "max"),
                rms_inclination_deg=_stat(inc, "rms"),
                max_inclination_deg=_stat(inc, "max"),
                rms_heading_deg=_stat(head, "rms"),
                max_heading_deg=_stat(head, "max"),
            )
        rows.append(r)
        if r.rms_error_deg is not None:
            own = c.name == result.summary.method
            error = result.error.total_deg if own else c.error.total_deg
            curves.append(decimate_curve(row_label(r), result.t_s, error))
    return tuple(rows), tuple(curves)


def _stat(stats: dict | None, name: str) -> float | None:
    return None if stats is None else float(stats[name])

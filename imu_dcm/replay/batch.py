"""Replay many logs at once: on all cores of this machine, or on a Dask cluster.

``python -m imu_dcm.replay batch PATH... --table OUT.csv [--jobs N | --dask ADDRESS]`` or
:func:`replay_many`. Every log runs through :func:`imu_dcm.replay.batch_log.replay_one` (the
same function in a process pool, in a Dask worker, or in this process for ``jobs=1``), which
never raises: a log that fails gives a row carrying its one-line error. Rows are appended to
the table as they arrive (see :mod:`imu_dcm.replay.table`), so ``resume=True`` picks up a
batch that was killed.

Workers run one log at a time with one BLAS thread each, and send back only the row and a
decimated error curve, so a worker's memory is what that log's replay needs.
"""

from __future__ import annotations

import contextlib
import dataclasses
import importlib
import os
import warnings
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from imu_dcm._kernels import backend
from imu_dcm.errors import Diagnostics, ImuDcmWarning, InputError, say
from imu_dcm.logio import find_logs as find_logs_in
from imu_dcm.logio.registry import convert_hint, not_logs
from imu_dcm.outputs import OutputError, claim_output
from imu_dcm.replay.batch_chart import INSTALL_HINT, chart_available, write_chart
from imu_dcm.replay.batch_log import per_method, replay_compare, replay_one
from imu_dcm.replay.runners import LOST, run_dask, run_local
from imu_dcm.replay.table import (
    Curve,
    LogRow,
    append_curve,
    append_rows,
    curves_path,
    markdown_path,
    read_curves,
    read_table,
    row_key,
    row_label,
    summary_line,
    table_methods,
    write_curves,
    write_markdown,
    write_table,
)

__all__ = ["BatchResult", "claim_batch_outputs", "find_logs", "preload", "replay_many"]

#: Files read as lists of logs (one path a line, relative to the list; ``#`` comments).
LIST_SUFFIXES = (".txt", ".list", ".lst")


@dataclass(frozen=True)
class BatchResult:
    """What :func:`replay_many` produced.

    ``rows``: one :class:`LogRow` per input log, in input order (rows resumed from the table
    included); ``failed``: how many carry an error; ``resumed``: how many were already in the
    table; ``table``, ``markdown``, ``chart``: files written (None when not asked for or, for the
    chart, when matplotlib is missing); ``summary``: the summary line of the whole table (which
    also keeps rows of earlier runs over other logs).
    """

    rows: tuple[LogRow, ...]
    failed: int
    resumed: int
    table: Path | None
    markdown: Path | None
    chart: Path | None
    summary: str


# ------------------------------------------------------------------------------ inputs


def find_logs(paths: Iterable[str | Path], *, diagnostics: Diagnostics | None = None) -> list[str]:
    """The logs named by ``paths``, as absolute paths, each once, in the order found.

    A folder the reader takes as one log (a bag, a EuRoC dataset) is a log; another folder is
    searched (sorted, hidden entries skipped) by :func:`imu_dcm.logio.find_logs`; a ``.txt`` /
    ``.list`` file lists paths, one a line (relative to the list's folder; blank lines and
    ``#`` comments skipped); anything else, including a path that does not exist, is taken as a
    log (and gets an error row if it is not one). A searched folder's files that are not logs
    are warned (or added to ``diagnostics``), one line a folder.
    """
    out: dict[str, None] = {}

    def add(p: Path, from_list: bool) -> None:
        if p.is_dir():
            found = list(find_logs_in(p))
            said = _skipped(p, found)
            if said:
                say(diagnostics, said, ImuDcmWarning, stacklevel=3)
            out.update((os.path.abspath(f), None) for f in found)
        elif p.suffix in LIST_SUFFIXES and p.is_file() and not from_list:
            for line in p.read_text().splitlines():
                line = line.split("#", 1)[0].strip()
                if line:
                    add(p.parent / line, True)
        else:
            out[os.path.abspath(p)] = None

    for p in paths:
        add(Path(p), False)
    return list(out)


def _skipped(folder: Path, found: list) -> str:
    """One line naming the files under ``folder`` that are not logs (and which convert-csv
    converts), or "" when every file is a log."""
    skipped = not_logs(folder)
    if found and not skipped:
        return ""
    names = ", ".join(str(f.relative_to(folder)) for f in skipped[:6])
    more = f" and {len(skipped) - 6} more" if len(skipped) > 6 else ""
    files = (
        f"{len(skipped)} files that are not logs"
        if len(skipped) != 1
        else "1 file that is not a log"
    )
    head = f"no logs found under {folder}" if not found else f"skipped under {folder}"
    listed = f": {files} ({names}{more})" if skipped else ""
    return head + listed + convert_hint(skipped)


def _size(path: str) -> int:
    """Bytes of a log (a bag folder's files summed; 0 when unreadable)."""
    try:
        p = Path(path)
        return sum(f.stat().st_size for f in p.iterdir()) if p.is_dir() else p.stat().st_size
    except OSError:
        return 0


# --------------------------------------------------------------------------- one log


#: Modules the readers import on first use, when installed (preloaded with the replay).
_READER_MODULES = ("yaml", "zstandard")


def preload() -> None:
    """Import what every replay needs (the replay, the readers' lazy imports) and load the
    compiled kernel, once in this process, so that workers forked from it start with them
    instead of each paying the imports on its first log (about 0.3 s a worker, which on many
    small logs costs more than the logs)."""
    from imu_dcm.replay import core  # noqa: F401 (lazy: see batch_log._replay_rows)

    backend()
    for name in _READER_MODULES:
        with contextlib.suppress(ImportError):
            importlib.import_module(name)


# ---------------------------------------------------------------------------- driver


def replay_many(
    paths: Iterable[str | Path],
    table: str | Path | None = None,
    *,
    jobs: int | None = None,
    dask=None,
    resume: bool = False,
    overwrite: bool = False,
    chart: str | Path | None = "auto",
    progress: Callable[[int, int, LogRow], None] | None = None,
    compare: Sequence[str] | None = None,
    **replay_options,
) -> BatchResult:
    """Replay every log found under ``paths`` and tabulate one row per log.

    Parameters
    ----------
    paths : iterable of str or Path
        Logs, folders searched for logs, or list files (see :func:`find_logs`).
    table : str or Path, optional
        CSV table ``OUT.csv``; rows are appended as logs finish, then the table is rewritten in
        input order, with ``OUT.md`` (markdown and summary) and ``OUT.curves.jsonl`` beside it.
        None keeps the rows in memory only.
    jobs : int, optional
        Worker processes (default: the cores this process may use); 1 runs in this process.
    dask : distributed.Client or str, optional
        A Dask client or scheduler address (``"tcp://host:8786"``); replaces ``jobs``. The
        workers must see the logs at the same paths.
    resume : bool
        Skip logs that already have a row in ``table``, failed ones included, except rows whose
        worker process died (those logs are replayed again).
    overwrite : bool
        Start ``table`` afresh when it exists (otherwise an existing table needs ``resume``).
    chart : str, Path or None
        PNG of the RMS per log and the error curves; ``"auto"`` puts ``OUT.png`` beside the
        table when matplotlib is installed; None draws none.
    progress : callable(done, total, row), optional
        Called after each log (with its first row).
    compare : sequence of str, optional
        Method and peer names (those of the single-log ``--compare``): one row per log and
        method, keyed by (path, method), with the columns ``method`` and ``ns_per_sample``
        after the others. A table written with them resumes only with the same names.
    **replay_options
        Keywords of :func:`imu_dcm.replay.replay` (``method``, ``bias``, ...), the same for every
        log (``progress`` excluded).

    Returns
    -------
    BatchResult

    Raises
    ------
    InputError
        No logs found, a bad ``jobs``, an existing table without ``resume`` or ``overwrite``,
        an unreadable table, a table resumed with other ``compare`` names than it was written
        with, ``chart`` asked without matplotlib, ``dask`` without Dask.
    """
    paths = list(paths)
    logs, jobs = _check_batch(paths, jobs, replay_options)
    names = _compare_names(compare, replay_options)
    chart_path = _chart_path(chart, table)
    table = None if table is None else Path(table)
    claim_batch_outputs(table, chart_path, [*paths, *logs])
    old = _open_table(table, resume, overwrite, names)
    # A row whose worker died is not the log's verdict: replay that log again.
    done = {k: r for k, r in old.items() if not (r.error and f": {LOST}: " in r.error)}
    keys = [(p, m) for p in logs for m in (names or (None,))]
    todo = list(dict.fromkeys(p for p, m in keys if (p, m) not in done))
    resumed = len(logs) - len(todo)
    counts = (resumed, len(logs), progress)
    fresh, new_curves = _run_logs(todo, dict(replay_options), jobs, dask, table, counts)
    rows = [fresh.get(k) or done[k] for k in keys]
    listed = set(logs)
    others = [r for r in old.values() if r.path not in listed]  # earlier runs, other logs
    md, chart_path = _write_outputs(table, rows + others, new_curves, chart_path)
    failed = sum(r.failed for r in rows)
    return BatchResult(
        tuple(rows), failed, resumed, table, md, chart_path, summary_line(rows + others)
    )


def _check_batch(
    paths: Iterable[str | Path], jobs: int | None, replay_options: Mapping[str, Any]
) -> tuple[list[str], int]:
    """The logs of a batch (at least one) and the worker count (default: the usable cores)."""
    for p in paths:  # a path named that is not there is bad input, not a failed log
        if not os.path.lexists(p):
            raise InputError(
                f"Expected a log, a folder of logs or a list of logs, got no such path: {p}"
            )
    logs = find_logs(paths)
    if not logs:
        raise InputError("Expected at least one log in the batch, got none")
    if jobs is None:
        jobs = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    if not isinstance(jobs, int) or jobs < 1:
        raise InputError(f"Expected jobs >= 1, got {jobs!r}")
    if "progress" in replay_options:
        raise InputError("Expected no per-log progress callback in a batch, got progress=")
    return logs, jobs


def _compare_names(compare: Sequence[str] | None, options: dict) -> tuple[str, ...] | None:
    """The ``compare`` names checked as the single-log ``--compare`` checks them, put into the
    workers' ``options`` (None without them)."""
    if compare is None:
        return None
    from imu_dcm.replay.compare import parse_compare  # lazy: see batch_log._replay_rows

    options["compare"] = parse_compare(",".join(compare))
    return options["compare"]


def _chart_path(chart: str | Path | None, table: str | Path | None) -> Path | None:
    """Where the chart goes: ``"auto"`` beside the table when matplotlib is installed (a warning
    when it is not), a path as given (matplotlib required), or nowhere."""
    if chart == "auto":
        if table is not None and chart_available():
            return Path(table).with_suffix(".png")
        if table is not None:
            warnings.warn(
                f"no chart: matplotlib is not installed ({INSTALL_HINT})",
                ImuDcmWarning,
                stacklevel=3,
            )
        return None
    if chart is None:
        return None
    if Path(chart).suffix.lower() != ".png":  # the chart is signed in its PNG metadata
        raise InputError(f"Expected the chart to be a PATH.png, got {str(chart)!r}")
    if not chart_available():
        raise InputError(f"Expected matplotlib for the chart, got it not installed: {INSTALL_HINT}")
    return Path(chart)


def claim_batch_outputs(
    table: Path | None, chart: Path | None, inputs: Iterable[str | Path]
) -> None:
    """Check the table, the files beside it and the chart by :mod:`imu_dcm.outputs`' rule,
    before any log is read: each new or this tool's own file of its kind (header row, comment
    line, JSON lines, PNG metadata), never an input, inside an input folder or a symbolic link;
    the table, its markdown and its curves regular files (they are appended to and read)."""
    beside = []
    if table is not None:
        beside = [(table, "table", "--table"), (markdown_path(table), "markdown", None)]
        beside.append((curves_path(table), "curves", None))
    if chart is not None:
        beside.append((chart, "chart", "the chart"))
    for path, kind, what in beside:
        what = what or f"the {Path(path).name} beside --table"
        claim = claim_output(path, kind, inputs, what=what)
        if claim.stream != "file" and kind != "chart":
            raise OutputError(
                f"Expected {what} to be a regular file or new, got a stream {str(claim.path)!r}"
            )


def _open_table(
    table: Path | None, resume: bool, overwrite: bool, names: tuple[str, ...] | None
) -> dict[tuple[str, str | None], LogRow]:
    """Make the table ready to append to; its rows by (path, method) when resuming (the last
    row wins). An existing table needs ``resume`` or ``overwrite`` (which removes it and its
    curves); it resumes only with the ``compare`` names it was written with (or none)."""
    if table is None:
        return {}
    if table.exists() and table.stat().st_size and not (resume or overwrite):
        raise InputError(
            f"Expected a new table, got an existing {table}: add to it with resume=True "
            "(--resume), or start afresh with overwrite=True (--force)"
        )
    if overwrite and not resume:
        for p in (table, curves_path(table)):
            p.unlink(missing_ok=True)
    table.parent.mkdir(parents=True, exist_ok=True)
    if not resume:
        return {}
    rows = read_table(table)
    _check_resume_methods(table, rows, names)
    return {row_key(r): r for r in rows}


def _check_resume_methods(table: Path, rows: list[LogRow], names: tuple[str, ...] | None) -> None:
    """A compared table resumes with the same ``--compare`` names, a plain one without."""
    if not rows:
        return
    had = table_methods(table)
    if had == names:
        return
    said = "no --compare" if names is None else f"--compare {','.join(names)}"
    if had is None:
        raise InputError(
            f"Expected no --compare to resume {table} (written without it), got {said}"
        )
    raise InputError(
        f"Expected --compare {','.join(had)} to resume {table} (written with it), got {said}"
    )


def _run_logs(
    todo: list[str],
    options: dict[str, Any],
    jobs: int,
    dask,
    table: Path | None,
    counts: tuple[int, int, Callable[[int, int, LogRow], None] | None],
) -> tuple[dict[str, LogRow], dict[str, Curve]]:
    """Replay the logs ``todo`` (largest first when in parallel) and keep each result as it
    arrives: appended to the table (curve first, so a row always has its curve), or kept in
    memory without a table. ``counts``: logs already done, logs in all, the progress callback.
    Returns the new rows by (path, method) and, without a table, the new curves by label."""
    resumed, total, progress = counts
    fresh: dict[str, LogRow] = {}
    new_curves: dict[str, Curve] = {}
    if not todo:
        return fresh, new_curves
    if dask is not None or jobs > 1:  # largest first: no big log left alone at the end
        todo = sorted(todo, key=_size, reverse=True)
    names = options.get("compare")
    fn = replay_one if names is None else replay_compare
    if dask is not None:
        runs = run_dask(fn, todo, options, dask)
    else:
        if jobs > 1 and len(todo) > 1:
            preload()  # before the pool forks: its workers start with these
        runs = run_local(fn, todo, options, jobs)
    done = 0
    with contextlib.closing(runs):  # stops the workers if this loop is interrupted
        for got, curves in runs:
            rows = per_method(got, names) if isinstance(got, LogRow) else got  # a lost worker
            curves = () if curves is None else (curves,) if isinstance(curves, Curve) else curves
            if table is not None:
                for curve in curves:
                    append_curve(table, curve)
                append_rows(table, rows)  # a log's rows in one write: all of them or none
            else:
                new_curves.update((c.path, c) for c in curves)
            fresh.update((row_key(r), r) for r in rows)
            done += 1
            if progress is not None:
                progress(resumed + done, total, rows[0])
    return fresh, new_curves


def _write_outputs(
    table: Path | None, rows: list[LogRow], new_curves: dict[str, Curve], chart: Path | None
) -> tuple[Path | None, Path | None]:
    """Rewrite the table and its curves in input order, with the markdown beside them; draw the
    chart. Returns the markdown and the chart written (None when not asked for)."""
    md = None
    curves = new_curves
    if table is not None:
        write_table(table, rows)
        curves = read_curves(table)
        labels = [row_label(r) for r in rows]
        write_curves(table, [curves[k] for k in labels if k in curves])
        md = write_markdown(table, rows)
    if chart is not None:  # a compared table: one bar and curve per log and method
        labelled = [dataclasses.replace(r, path=row_label(r)) for r in rows]
        chart = write_chart(chart, labelled, curves)
    return md, chart

"""Batch ``--compare``: one row per log and method, keyed by (path, method), resumable.

Truth for every row is outside the batch: the replay's own method's row must be the plain batch
row of that log (which tests/test_batch.py holds to a bare replay), and every other method's row
the figures the single-log ``--compare`` writes to its summary JSON for that log, bit for bit.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import json
from pathlib import Path

import pytest
from conftest import assert_names, raises_naming

from data_synth.cli import main as synth_main
from imu_dcm.errors import InputError
from imu_dcm.replay import replay_many
from imu_dcm.replay.__main__ import main as replay_main
from imu_dcm.replay.batch_cli import main as batch_main
from imu_dcm.replay.table import COLUMNS, COMPARE_COLUMNS, read_table

# magnus4 is the replay's default method; a peer when one is installed, else the numpy loop
PEER = "vqf" if importlib.util.find_spec("vqf") else "reference"
NAMES = ("magnus4", "trapezoid", PEER)
SYNTH = {
    "coning": ["coning", "--rate", "200", "--duration", "2"],
    "top": ["heavy-top", "--motion", "wavy", "--rate", "200", "--duration", "3", "--seed", "3"],
}
_ERRORS = {  # row field -> (statistic group of the evaluation, statistic)
    "rms_error_deg": ("total_deg", "rms"),
    "max_error_deg": ("total_deg", "max"),
    "rms_inclination_deg": ("inclination_deg", "rms"),
    "max_inclination_deg": ("inclination_deg", "max"),
    "rms_heading_deg": ("heading_deg", "rms"),
    "max_heading_deg": ("heading_deg", "max"),
}


@pytest.fixture(scope="module")
def logs(tmp_path_factory) -> list[str]:
    root = tmp_path_factory.mktemp("synth")
    for name, argv in SYNTH.items():
        assert synth_main([*argv, "--out", str(root / name)]) == 0
    return [str(root / n) for n in SYNTH]


def _shared(row) -> dict:
    """What every row of a log shares whatever the method (no wall time, no cost)."""
    drop = {"elapsed_s", "method", "ns_per_sample", *_ERRORS}
    return {k: v for k, v in dataclasses.asdict(row).items() if k not in drop}


def _single_log_compare(log: str, tmp_path: Path) -> dict[str, dict]:
    """The single-log command's --compare figures, from its summary JSON, by method."""
    out = tmp_path / f"{Path(log).name}.json"
    argv = [log, "--compare", ",".join(NAMES), "--summary-json", str(out), "--rerun", "off"]
    assert replay_main([*argv, "--quiet"]) == 0
    return {c["method"]: c for c in json.loads(out.read_text())["compare"]}


def test_rows_per_log_and_method_equal_plain_rows_and_single_log_compare(logs, tmp_path):
    plain = replay_many(logs, tmp_path / "plain.csv", jobs=1, chart=None)
    res = replay_many(logs, tmp_path / "cmp.csv", jobs=1, chart=None, compare=NAMES)
    assert res.failed == 0 and len(res.rows) == len(logs) * len(NAMES)
    assert [(Path(r.path).name, r.method) for r in res.rows] == [
        (n, m) for n in SYNTH for m in NAMES
    ]
    for k, log in enumerate(logs):
        mine = res.rows[k * len(NAMES) : (k + 1) * len(NAMES)]
        # the replay's own method: the plain row, every field but the wall time
        own = dataclasses.replace(mine[0], method=None, ns_per_sample=None, elapsed_s=None)
        assert own == dataclasses.replace(plain.rows[k], elapsed_s=None)
        single = _single_log_compare(log, tmp_path)
        for row in mine:
            assert _shared(row) == _shared(plain.rows[k])
            assert row.ns_per_sample > 0
            if row.method == "magnus4":
                continue
            ev = single[row.method]["evaluation"]
            for field, (group, stat) in _ERRORS.items():
                assert getattr(row, field) == ev[group][stat], (log, row.method, field)
        # the methods really differ: trapezoid's error is not magnus4's
        assert mine[1].rms_error_deg != mine[0].rms_error_deg
    # the CSV keeps every bit, and the keys; the plain table's format is unchanged
    assert read_table(tmp_path / "cmp.csv") == list(res.rows)
    header = (tmp_path / "cmp.csv").read_text().splitlines()[0]
    assert tuple(header.split(",")) == COMPARE_COLUMNS == (*COLUMNS, "method", "ns_per_sample")
    assert tuple((tmp_path / "plain.csv").read_text().splitlines()[0].split(",")) == COLUMNS
    assert "method" not in COLUMNS
    # a pool gives the same rows (wall time and cost aside)
    pool = replay_many(logs, tmp_path / "pool.csv", jobs=2, chart=None, compare=NAMES)
    strip = {"elapsed_s": None, "ns_per_sample": None}
    assert [dataclasses.replace(r, **strip) for r in pool.rows] == [
        dataclasses.replace(r, **strip) for r in res.rows
    ]
    # one summary per method, never averaged across methods
    assert [part.split(":")[0] for part in res.summary.split(" | ")] == list(NAMES)


def test_resume_with_compare_completes_and_needs_the_same_names(logs, tmp_path):
    out = tmp_path / "t.csv"
    first = replay_many(logs[:1], out, jobs=1, chart=None, compare=NAMES)
    res = replay_many(logs, out, jobs=1, chart=None, compare=NAMES, resume=True)
    assert res.resumed == 1 and res.rows[: len(NAMES)] == first.rows
    assert [(Path(r.path).name, r.method) for r in read_table(out)] == [
        (n, m) for n in SYNTH for m in NAMES
    ]
    for other in (None, NAMES[:2], tuple(reversed(NAMES))):
        with raises_naming(InputError, f"--compare {','.join(NAMES)}", str(out)):
            replay_many(logs, out, jobs=1, chart=None, compare=other, resume=True)
    assert read_table(out) == list(res.rows)  # refused before anything was written


def test_resume_without_compare_keeps_the_plain_format(logs, tmp_path, capsys):
    out = tmp_path / "t.csv"
    first = replay_many(logs[:1], out, jobs=1, chart=None)
    res = replay_many(logs, out, jobs=1, chart=None, resume=True)
    assert res.resumed == 1 and res.rows[0] == first.rows[0]
    assert all(r.method is None for r in read_table(out))
    assert tuple(out.read_text().splitlines()[0].split(",")) == COLUMNS
    before = out.read_bytes()
    argv = [*logs, "--table", str(out), "--resume", "--no-chart", "--compare", "magnus4"]
    assert batch_main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("imu-dcm-replay batch: error: "), err
    assert_names(err[0], str(out), "without", "--compare magnus4")  # the table as written, asked
    assert out.read_bytes() == before


def test_cli_compare_rows_and_resume_line(logs, tmp_path, capsys):
    out = tmp_path / "t.csv"
    argv = [logs[0], "--table", str(out), "--no-chart", "--compare", ",".join(NAMES)]
    assert batch_main(argv) == 0
    argv[0:1] = logs
    assert batch_main([*argv, "--resume"]) == 0
    said = capsys.readouterr().out
    assert f"resumed    1 logs ({len(NAMES)} rows) already in the table" in said
    assert [r.method for r in read_table(out)] == [*NAMES, *NAMES]
    assert batch_main([*argv, "--resume", "--compare", "magnus4,nope"]) == 2
    assert_names(capsys.readouterr().err, "--compare", "'nope'", "coning")  # the names known

"""Batch replay: many logs, one row each, the same numbers wherever they run, resumable.

Truth for every row is a bare single-log :func:`imu_dcm.replay.replay` of the same log: the
batch must reproduce its numbers bit for bit in this process, in a process pool and on a Dask
cluster, and keep them through the CSV table (written with ``repr``, read back with ``float``).
"""

from __future__ import annotations

import csv
import dataclasses
import json
import os
import shutil
import signal
import statistics
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
from conftest import assert_names

from data_synth.cli import main as synth_main
from imu_dcm.errors import ImuDcmWarning
from imu_dcm.replay import replay, replay_many
from imu_dcm.replay.batch import find_logs
from imu_dcm.replay.batch_cli import main as batch_main
from imu_dcm.replay.batch_log import replay_one
from imu_dcm.replay.table import COLUMNS, LogRow, append_rows, read_table

REPO_ROOT = Path(__file__).resolve().parents[1]
SHIPPED = sorted(p for p in (REPO_ROOT / "replay").iterdir() if (p / "metadata.yaml").is_file())
SYNTH = {  # short logs: a closed-form coning, a noisy biased top, a delta-angle tumbling box
    "coning": ["coning", "--rate", "200", "--duration", "2"],
    "top_noisy": [
        "heavy-top",
        "--motion",
        "wavy",
        "--rate",
        "200",
        "--duration",
        "3",
        "--gyro-noise-density",
        "2e-4",
        "--gyro-bias",
        "0.002,-0.003,0.001",
        "--seed",
        "3",
    ],
    "box_delta": [
        "free-body",
        "--case",
        "intermediate",
        "--rate",
        "100",
        "--duration",
        "3",
        "--gyro-output",
        "delta-angle",
    ],
}
NUMBERS = [
    n
    for n in COLUMNS
    if n not in ("path", "imu_topic", "truth_topic", "warnings", "error", "elapsed_s")
]


@pytest.fixture(scope="module")
def synth_dir(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("synth")
    for name, argv in SYNTH.items():
        assert synth_main([*argv, "--out", str(root / name)]) == 0
    return root


@pytest.fixture(scope="module")
def logs(synth_dir) -> list[str]:
    return [str(p) for p in SHIPPED] + [str(synth_dir / n) for n in SYNTH]


def _numbers(row: LogRow) -> dict:
    """Every field but the wall time, which differs between runs."""
    return {k: v for k, v in dataclasses.asdict(row).items() if k != "elapsed_s"}


def test_rows_are_the_bare_replay_bit_for_bit_sequential_pool_and_dask(logs, tmp_path):
    seq = replay_many(logs, tmp_path / "seq.csv", jobs=1, chart=None)
    pool = replay_many(logs, tmp_path / "pool.csv", jobs=2, chart=None)
    assert [r.path for r in seq.rows] == [os.path.abspath(p) for p in logs]
    assert seq.failed == 0 and pool.failed == 0
    for path, row in zip(logs, seq.rows, strict=False):
        s = replay(path).summary  # independent of the batch machinery
        for key in NUMBERS:
            if key.startswith("bias_"):
                want = s.bias_rad_s["xyz".index(key[5])]
            elif key == "dropped":
                want = (
                    s.dropped_nonfinite
                    + s.dropped_implausible
                    + s.dropped_duplicate
                    + s.dropped_backward
                )
            elif key == "gaps":
                want = len(s.gaps)
            elif key == "truth_kind":  # data_synth's truth is exact: an independent reference
                want = "independent reference" if s.truth_topic else "none"
            else:
                want = getattr(s, key)
            got = getattr(row, key)
            assert got == want and type(got) is type(want), (path, key, got, want)
    assert [_numbers(r) for r in pool.rows] == [_numbers(r) for r in seq.rows]
    # The CSV keeps every bit, elapsed time included.
    assert read_table(tmp_path / "seq.csv") == list(seq.rows)
    assert read_table(tmp_path / "pool.csv") == list(pool.rows)

    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(
        n_workers=2,
        threads_per_worker=1,
        processes=True,
        host="127.0.0.1",
        dashboard_address="127.0.0.1:0",
    ) as cluster:
        on_dask = replay_many(
            logs, tmp_path / "dask.csv", dask=cluster.scheduler_address, chart=None
        )
    assert [_numbers(r) for r in on_dask.rows] == [_numbers(r) for r in seq.rows]
    assert read_table(tmp_path / "dask.csv") == list(on_dask.rows)


def test_bad_logs_get_error_rows_and_the_others_complete(logs, tmp_path):
    good = logs[-3:]
    whole = Path(SHIPPED[-1]) / f"{Path(SHIPPED[-1]).name}.mcap"
    data = whole.read_bytes()
    (tmp_path / "header_only.mcap").write_bytes(data[:3000])  # no complete message
    (tmp_path / "half.mcap").write_bytes(data[: len(data) // 2])  # readable up to the cut
    (tmp_path / "notes.csv").write_text("t,x\n0,1\n")
    bad = [tmp_path / "header_only.mcap", tmp_path / "notes.csv", tmp_path / "missing.mcap"]
    (tmp_path / "listed.txt").write_text("missing.mcap\n")  # a list naming a log that is gone
    named = [*bad[:2], tmp_path / "listed.txt"]  # (named itself, a missing path is bad input)
    res = replay_many(
        [good[0], *named, tmp_path / "half.mcap", *good[1:]], tmp_path / "t.csv", jobs=2, chart=None
    )
    by = {Path(r.path).name: r for r in res.rows}
    assert res.failed == 3 and len(res.rows) == 7
    for p in bad:
        row = by[p.name]
        assert row.error.startswith("LogError: Expected") and "\n" not in row.error
        assert row.samples is None and row.rms_error_deg is None
    full = replay(whole.parent).summary.samples
    half = by["half.mcap"]
    assert half.error is None and 0 < half.samples < full
    assert any("truncated" in w for w in half.warnings)
    for p in good:
        row = by[Path(p).name]
        assert row.error is None and row.samples > 0 and row.rms_error_deg is not None
    # The table says the same: three error rows, every other row complete.
    table = read_table(tmp_path / "t.csv")
    assert sorted(r.path for r in table) == sorted(r.path for r in res.rows)
    assert sum(r.failed for r in table) == 3


def test_replays_in_threads_keep_each_its_own_warnings(logs, tmp_path):
    # A replay's warnings travel with its result, not through the process-wide warnings state:
    # logs replayed in threads of one process (no lock) give the rows, warnings included, that
    # they give one at a time, and the truncated log's warning stays on its own row.
    whole = Path(SHIPPED[-1]) / f"{Path(SHIPPED[-1]).name}.mcap"
    data = whole.read_bytes()
    (tmp_path / "half.mcap").write_bytes(data[: len(data) // 2])
    paths = [str(tmp_path / "half.mcap"), *logs[-3:], str(tmp_path / "half.mcap")]

    def row(path):
        return dataclasses.replace(replay_one(path, {})[0], elapsed_s=0.0)

    alone = [row(p) for p in paths]
    with ThreadPoolExecutor(len(paths)) as pool:
        together = list(pool.map(row, paths))
    assert together == alone
    said = [any("truncated" in w for w in r.warnings) for r in together]
    assert said == [True, False, False, False, True]


def test_markdown_summary_and_chart(logs, tmp_path):
    pytest.importorskip("matplotlib")
    (tmp_path / "bad.mcap").write_bytes(b"\x89MCAP0\r\n")
    res = replay_many([*logs[-3:], tmp_path / "bad.mcap"], tmp_path / "out.csv", jobs=1)
    with open(tmp_path / "out.csv", newline="") as f:
        cells = list(csv.DictReader(f))
    rms = [float(c["rms_error_deg"]) for c in cells if c["rms_error_deg"]]
    assert len(cells) == 4 and len(rms) == 3
    want = (
        f"4 logs, 1 failed; RMS error over 3 logs with truth (independent reference): mean "
        f"{statistics.fmean(rms):.4g}°, median {statistics.median(rms):.4g}°"
    )
    assert res.summary == want
    md = (tmp_path / "out.md").read_text()
    table_lines = [line for line in md.splitlines() if line.startswith("|")]
    assert md.rstrip().endswith(want) and len(table_lines) == 2 + 4  # header, rule, 4 logs
    assert res.chart == tmp_path / "out.png"
    assert res.chart.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and res.chart.stat().st_size > 20_000


def test_find_logs_searches_folders_and_lists(synth_dir, tmp_path):
    root = tmp_path / "data"
    shutil.copytree(synth_dir / "coning", root / "a" / "bag")  # a bag folder: one log
    (root / "b").mkdir(parents=True)
    loose = root / "b" / "loose.mcap"
    shutil.copy(synth_dir / "coning" / "coning.mcap", loose)
    (root / "b" / "readme.md").write_text("not a log")
    (root / ".hidden").mkdir()
    shutil.copy(synth_dir / "coning" / "coning.mcap", root / ".hidden" / "x.mcap")
    listing = tmp_path / "logs.txt"
    listing.write_text(
        "# the same loose log again, and one more\n\ndata/b/loose.mcap\n"
        f"{synth_dir / 'top_noisy'}  # absolute\n"
    )
    with pytest.warns(ImuDcmWarning, match=r"1 file that is not a log \(b/readme.md\)"):
        found = find_logs([root, listing, root / "a" / "bag"])
    assert found == [str(root / "a" / "bag"), str(loose), str(synth_dir / "top_noisy")]


def _cli(*args: str, **kw) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(REPO_ROOT)}
    return subprocess.Popen(
        [sys.executable, "-m", "imu_dcm.replay", "batch", *args],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        **kw,
    )


def _lines(path: Path) -> list[str]:
    return path.read_text().splitlines(keepends=True) if path.exists() else []


@pytest.mark.parametrize("jobs", ["1", "2"])
def test_sigterm_halfway_then_resume_gives_the_complete_table(tmp_path, jobs):
    # 24 logs (links to one shipped bag) keep the batch busy for seconds after its first row.
    src = REPO_ROOT / "replay" / "heavy_top_wavy_noisy_400hz"
    for k in range(24):
        d = tmp_path / "logs" / f"log{k:02d}"
        d.mkdir(parents=True)
        for f in src.iterdir():
            (d / f.name).symlink_to(f)
    out = tmp_path / "t.csv"
    proc = _cli(str(tmp_path / "logs"), "--table", str(out), "--jobs", jobs, "--no-chart")
    deadline = time.monotonic() + 60
    while len(_lines(out)) < 4 and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.005)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 143, err
    assert "terminated" in err and "Traceback" not in err
    rows_at_kill = len(_lines(out)) - 1
    assert 3 <= rows_at_kill < 24  # really halfway
    assert all(line.endswith("\n") for line in _lines(out))  # no torn row

    again = _cli(
        str(tmp_path / "logs"), "--table", str(out), "--resume", "--jobs", "2", "--no-chart"
    )
    stdout, err = again.communicate(timeout=120)
    assert again.returncode == 0, err
    assert f"resumed    {rows_at_kill} rows" in stdout
    rows = read_table(out)
    assert sorted(Path(r.path).name for r in rows) == [f"log{k:02d}" for k in range(24)]
    assert all(r.error is None for r in rows)
    # Same log behind every link: every row has the same numbers, whichever run made it.
    assert all(_numbers(r) | {"path": ""} == _numbers(rows[0]) | {"path": ""} for r in rows)


def test_resume_drops_a_torn_last_line_and_completes(logs, tmp_path):
    out = tmp_path / "t.csv"
    first = replay_many(logs[-3:-1], out, jobs=1, chart=None)
    whole = out.read_text()
    torn = whole + whole.splitlines(keepends=True)[-1][:25]  # a row cut mid-way, no newline
    out.write_text(torn)
    res = replay_many(logs[-3:], out, jobs=1, resume=True, chart=None)
    assert res.resumed == 2 and res.rows[:2] == first.rows
    lines = _lines(out)
    assert len(lines) == 4 and all(line.endswith("\n") for line in lines)
    assert [r.path for r in read_table(out)] == [os.path.abspath(p) for p in logs[-3:]]


def test_cli_bad_input_is_one_line_and_exit_2(logs, tmp_path, capsys, monkeypatch):
    out = tmp_path / "t.csv"
    assert batch_main([logs[-1], "--table", str(out), "--no-chart", "--quiet"]) == 0
    assert batch_main([logs[-1], "--table", str(out), "--no-chart"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0
    assert_names(err, str(out), "--resume", "--force")  # the table, and the two ways on
    assert batch_main([logs[-1], "--table", str(tmp_path / "t.md")]) == 2
    assert "ending in .csv" in capsys.readouterr().err
    assert batch_main([logs[-1], "--table", str(out), "--jobs", "0", "--force"]) == 2
    assert "jobs >= 1" in capsys.readouterr().err
    monkeypatch.setitem(sys.modules, "distributed", None)  # as if Dask were not installed
    assert (
        batch_main([logs[-1], "--table", str(out), "--force", "--dask", "tcp://127.0.0.1:1"]) == 2
    )
    err = capsys.readouterr().err
    assert "pip install 'imu_dcm[dask]'" in err and err.count("\n") == 1


@pytest.mark.parametrize("flag", [[], ["--force"], ["--resume"]])
def test_a_curves_file_it_did_not_write_is_refused_and_kept(logs, tmp_path, capsys, flag):
    # the table's curves file is appended to, and removed by --force: a file of that name this
    # tool did not write stops the run before anything is read or written
    out = tmp_path / "t.csv"
    curves = tmp_path / "t.curves.jsonl"
    curves.write_text("my own notes\n")
    assert batch_main([logs[-1], "--table", str(out), "--no-chart", "--quiet", *flag]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "t.curves.jsonl beside --table" in err, err
    assert "not written by imu_dcm" in err, err
    assert curves.read_text() == "my own notes\n" and not out.exists()


def test_force_replaces_its_own_table_and_curves(logs, tmp_path):
    out = tmp_path / "t.csv"
    for extra in ([], ["--force"]):
        assert batch_main([logs[-1], "--table", str(out), "--no-chart", "--quiet", *extra]) == 0
    assert len(_lines(out)) == 2  # header and one row, not two
    curves = (tmp_path / "t.curves.jsonl").read_text().splitlines()
    assert len(curves) == 1 and json.loads(curves[0])["path"] == os.path.abspath(logs[-1])


def test_failed_logs_give_exit_code_1(logs, tmp_path, capsys):
    (tmp_path / "bad.mcap").write_bytes(b"nope")
    code = batch_main(
        [
            logs[-1],
            str(tmp_path / "bad.mcap"),
            "--table",
            str(tmp_path / "t.csv"),
            "--jobs",
            "1",
            "--no-chart",
        ]
    )
    out = capsys.readouterr().out
    assert code == 1 and "failed     " in out and "2 logs, 1 failed" in out
    assert np.isfinite(read_table(tmp_path / "t.csv")[0].rms_error_deg)


def test_resume_replays_a_log_whose_worker_died(logs, tmp_path):
    out = tmp_path / "t.csv"
    lost = LogRow(os.path.abspath(logs[-1]), error="BrokenProcessPool: worker lost: killed")
    failed = LogRow(os.path.abspath(logs[-2]), error="LogError: Expected an IMU channel, got none")
    append_rows(out, [lost, failed])
    res = replay_many(logs[-2:], out, jobs=1, resume=True, chart=None)
    assert res.resumed == 1 and res.rows[0] == failed  # the log's own failure stands
    assert res.rows[1].error is None and res.rows[1].samples > 0  # the lost one ran again
    assert read_table(out) == list(res.rows)


def test_preload_imports_what_each_worker_would_import_on_its_first_log():
    # A fresh interpreter, as the command is: the batch module alone imports no replay; the
    # preload (run before the pool forks) imports the replay and loads the compiled kernel.
    code = (
        "import sys\n"
        "from imu_dcm.replay import batch\n"
        "assert 'imu_dcm.replay.core' not in sys.modules\n"
        "batch.preload()\n"
        "from imu_dcm._kernels import loader\n"
        "assert 'imu_dcm.replay.core' in sys.modules and loader._AOT, sorted(sys.modules)\n"
    )
    env = {**os.environ, "PYTHONPATH": str(REPO_ROOT)}
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr

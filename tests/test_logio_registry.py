"""The container table: one row per container, the first probe that accepts a path reads it, a
new container is one class and one row, folders are searched for everything the table reads,
and logio's modules import one another without a circle."""

from __future__ import annotations

import ast
import gzip
import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import raises_naming

from imu_dcm.errors import LogError
from imu_dcm.logio import (
    READERS,
    ImuSeries,
    LogData,
    LogSource,
    ReadRequest,
    SourceEntry,
    find_logs,
    open_log,
    read_log,
    registry,
)

REPO = Path(__file__).resolve().parents[1]
SHIPPED = REPO / "replay" / "broad_07_undisturbed_fast_rotation_B"


def test_every_row_is_an_entry_and_every_source_the_interface():
    assert all(isinstance(e, SourceEntry) for e in READERS)
    assert len({e.name for e in READERS}) == len(READERS)
    folder = open_log(SHIPPED)
    single = open_log(next(SHIPPED.glob("*.mcap")))
    for src in (folder, single):
        assert isinstance(src, LogSource)
    assert folder.kind == "ros2 mcap"


class _Fake:
    """A container of one constant-rate series, to show what a new row takes."""

    kind = "fake"

    def __init__(self, path: Path, progress=None):
        self.path = path

    def read(self, request: ReadRequest) -> LogData:
        t = np.arange(5, dtype=np.int64) * 10_000_000
        imu = ImuSeries(t, t, np.ones((5, 3)), None, request.imu_topic or "gyro", "fake", "b")
        return LogData(self.path, imu, None, (), container=self.kind)


def test_a_new_container_is_a_class_and_a_row(tmp_path, monkeypatch):
    p = tmp_path / "x.fake"
    p.write_bytes(b"FAKE1 and some bytes")
    with raises_naming(LogError, str(p), "b'FAKE1 an'", ".mcap", ".ulg", ".bin"):
        read_log(p)
    row = SourceEntry("fake log", lambda path, head: head.startswith(b"FAKE1"), _Fake)
    monkeypatch.setattr(registry, "READERS", (row, *READERS))
    log = read_log(p, imu_topic="g")
    assert log.container == "fake" and log.imu.topic == "g" and len(log.imu.t_ns) == 5
    assert find_logs(tmp_path) == [p]


def test_foreign_formats_are_refused_naming_the_fix(tmp_path):
    gz = tmp_path / "log.mcap.gz"
    gz.write_bytes(gzip.compress(b"\x89MCAP0\r\n"))
    with raises_naming(LogError, "gzip", "`gunzip`", str(gz)):  # what it is, the fix
        read_log(gz)
    zipped = tmp_path / "log.zip"
    zipped.write_bytes(b"PK\x03\x04" + b"\0" * 40)
    with pytest.raises(LogError, match="got a zip archive"):
        read_log(zipped)


def test_find_logs_searches_for_every_container(tmp_path):
    root = tmp_path / "data"
    shutil.copytree(SHIPPED, root / "bags" / "trial")  # a bag folder: one log, not searched
    loose = root / "loose" / "renamed.bin"
    loose.parent.mkdir(parents=True)
    shutil.copy(next(SHIPPED.glob("*.mcap")), loose)  # an MCAP by its bytes, whatever its name
    (root / "loose" / "gyro.csv").write_text("t,x,y,z\n")  # refused rows are not logs
    (root / "loose" / "x.ulg").write_bytes(b"ULog\x01\x12" + b"\0" * 20)
    (root / "loose" / "notes.md").write_text("# not a log")
    imu = root / "euroc" / "MH_01" / "mav0" / "imu0"
    imu.mkdir(parents=True)
    (imu / "data.csv").write_text("#t\n1,0,0,0,0,0,9.8\n")
    (root / ".hidden").mkdir()
    shutil.copy(next(SHIPPED.glob("*.mcap")), root / ".hidden" / "x.mcap")
    assert find_logs(root) == [root / "bags" / "trial", root / "euroc" / "MH_01", loose]
    assert find_logs(root / "bags" / "trial") == [root / "bags" / "trial"]


def _imports(path: Path) -> set[str]:
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.module:
            found.add(node.module)
            found.update(f"{node.module}.{a.name}" for a in node.names)
        elif isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
    return found


def test_logio_has_no_import_circle():
    package = REPO / "imu_dcm" / "logio"
    mods = {
        "imu_dcm." + ".".join(p.relative_to(package.parent).with_suffix("").parts): p
        for p in package.rglob("*.py")
        if p.stem != "__init__"
    }
    graph = {m: {d for d in _imports(p) if d in mods and d != m} for m, p in mods.items()}
    state: dict[str, int] = {}

    def visit(m: str, path: list[str]) -> None:
        state[m] = 1
        for d in sorted(graph[m]):
            assert state.get(d) != 1, " -> ".join([*path, m, d])
            if d not in state:
                visit(d, [*path, m])
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m, [])

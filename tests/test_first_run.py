"""A newcomer's first ten minutes: outputs that never destroy what the tool did not write, modes
kept, no file left behind by a headless run, one exit-code convention, --version everywhere,
quiet broken pipes, and help that suggests the word meant.

Every command runs as a subprocess (a real exit code, a real stdout pipe) from the repository
root's package, in a temporary working folder.
"""

from __future__ import annotations

import os
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO_ROOT

from imu_dcm.logio.writer import StampedSeries, write_bag
from imu_dcm.outputs import OutputError, atomic_path, write_json, write_text_atomic

LINES = "".join(f"{k * 0.01:.2f},0.1,0,0\n" for k in range(50))  # 0.5 s at 100 Hz about x


def run(args: list[str], cwd: Path, stdin: str = "", timeout: float = 120.0):
    """``python -m ARGS`` in ``cwd`` with this checkout first on the path; CompletedProcess."""
    env = dict(os.environ, PYTHONPATH=str(REPO_ROOT), CI="true")
    env.pop("DISPLAY", None)
    env.pop("WAYLAND_DISPLAY", None)
    return subprocess.run(
        [sys.executable, "-m", *args],
        cwd=cwd,
        input=stdin,
        capture_output=True,
        text=True,
        env=env,
        timeout=timeout,
    )


def snapshot(folder: Path) -> dict:
    """Every entry under ``folder``: bytes (files) and modes, to prove nothing changed."""
    out = {}
    for p in sorted(folder.rglob("*")):
        st = p.lstat()
        out[str(p.relative_to(folder))] = (st.st_mode, p.read_bytes() if p.is_file() else None)
    return out


def _small_bag(path: Path) -> Path:
    t = np.arange(5, dtype=np.int64) * 10**7
    return write_bag(path, imu=StampedSeries(t, np.zeros((5, 3)), "imu"))


def _foreign(kind: str, tmp: Path) -> Path:
    """A folder this tool did not write: notes, a bag copy with its ATTRIBUTION.md, a shipped
    example with its COMMAND.txt."""
    d = tmp / kind
    if kind == "notes":
        d.mkdir()
        (d / "notes.txt").write_text("my notes\n")
    elif kind == "bag-copy":
        _small_bag(d)
        (d / "ATTRIBUTION.md").write_text("recorded by someone else\n")
    else:
        shutil.copytree(REPO_ROOT / "replay" / "heavy_top_cusp_2000hz", d)
    return d


# ---------------------------------------------------------------------------- outputs
@pytest.mark.parametrize("kind", ["notes", "bag-copy", "shipped-example"])
def test_live_record_force_refuses_a_folder_it_did_not_write(kind, tmp_path):
    d = _foreign(kind, tmp_path)
    before = snapshot(d)
    r = run(["imu_dcm.live", "-", "--record", str(d), "--force", "--rerun", "off"], tmp_path, LINES)
    assert r.returncode == 2, r.stderr
    err = r.stderr.strip().splitlines()
    assert err[-1].startswith("imu-dcm-live: error: Expected --force to replace only a bag"), err
    assert "Traceback" not in r.stderr
    assert snapshot(d) == before


def test_live_record_force_replaces_its_own_recording(tmp_path):
    bag = tmp_path / "rec"
    for extra in ([], ["--force"]):
        r = run(
            ["imu_dcm.live", "-", "--record", str(bag), "--rerun", "off", *extra], tmp_path, LINES
        )
        assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in bag.iterdir()) == ["metadata.yaml", "rec.mcap"]
    r = run(["imu_dcm.live", "-", "--record", str(bag), "--rerun", "off"], tmp_path, LINES)
    assert r.returncode == 2 and "use --force" in r.stderr


@pytest.mark.parametrize("mode", [0o644, 0o640, 0o600, 0o664])
def test_a_replaced_file_keeps_its_mode(mode, tmp_path):
    p = tmp_path / "s.json"
    p.write_text("old\n")
    os.chmod(p, mode)
    write_text_atomic(p, "new\n")
    assert p.read_text() == "new\n"
    assert stat.S_IMODE(p.stat().st_mode) == mode
    write_json(p, {"x": np.float64(1.5), "v": np.arange(2)})
    assert stat.S_IMODE(p.stat().st_mode) == mode
    assert p.read_text() == '{\n  "x": 1.5,\n  "v": [\n    0,\n    1\n  ]\n}\n'


@pytest.mark.parametrize("umask", [0o022, 0o027, 0o077])
def test_a_new_file_gets_the_umask_mode(umask, tmp_path):
    old = os.umask(umask)
    try:
        write_text_atomic(tmp_path / "a" / "b" / "new.txt", "x")  # parents created
        with atomic_path(tmp_path / "raw.bin") as tmp:
            tmp.write_bytes(b"\0")
    finally:
        os.umask(old)
    for p in (tmp_path / "a" / "b" / "new.txt", tmp_path / "raw.bin"):
        assert stat.S_IMODE(p.stat().st_mode) == 0o666 & ~umask
    assert [p.name for p in tmp_path.iterdir() if p.name.endswith(".tmp")] == []


def test_a_failed_write_leaves_the_target_and_no_temporary(tmp_path):
    p = tmp_path / "t.txt"
    p.write_text("kept")

    def write(exc: BaseException) -> None:
        with atomic_path(p) as tmp:
            tmp.write_text("half")
            raise exc

    with pytest.raises(RuntimeError):
        write(RuntimeError("boom"))
    with pytest.raises(OutputError, match="Expected to write"):
        write(OSError(28, "No space left on device"))
    assert p.read_text() == "kept"
    assert sorted(x.name for x in tmp_path.iterdir()) == ["t.txt"]


def test_replay_summary_json_keeps_the_mode_of_the_file_it_replaces(tmp_path):
    js = tmp_path / "s.json"
    js.write_text("{}\n")
    os.chmod(js, 0o644)
    log = REPO_ROOT / "replay" / "free_body_flip_100hz_delta"
    r = run(["imu_dcm.replay", str(log), "--rerun", "off", "--summary-json", str(js)], tmp_path)
    assert r.returncode == 0, r.stderr
    assert stat.S_IMODE(js.stat().st_mode) == 0o644
    assert js.read_text().startswith("{\n")


def test_data_synth_out_creates_its_parent_folders(tmp_path):
    r = run(
        ["data_synth", "coning", "--rate", "100", "--duration", "0.5", "--out", "out/top"],
        tmp_path,
    )
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in (tmp_path / "out" / "top").iterdir()) == [
        "metadata.yaml",
        "top.mcap",
    ]

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
from conftest import REPO_ROOT, assert_names, own_stderr, raises_naming
from loopback import free_udp_port, wait_bound

from imu_dcm.logio.writers import StampedSeries, write_bag
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
    assert err[-1].startswith("imu-dcm-live: error: "), err
    assert_names(err[-1], "--force", repr(str(d)))
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
    p = tmp_path / "metadata.yaml"  # the low-level write (a file inside a checked bag folder)
    p.write_text("old\n")
    os.chmod(p, mode)
    write_text_atomic(p, "new\n")
    assert p.read_text() == "new\n"
    assert stat.S_IMODE(p.stat().st_mode) == mode
    js = tmp_path / "s.json"  # a summary: replaced only when this tool wrote it
    write_json(js, {"x": 0})
    os.chmod(js, mode)
    write_json(js, {"x": np.float64(1.5), "v": np.arange(2)})
    assert stat.S_IMODE(js.stat().st_mode) == mode
    text = js.read_text()
    assert text.startswith('{\n  "written_by": "imu_dcm ')
    assert text.endswith('  "x": 1.5,\n  "v": [\n    0,\n    1\n  ]\n}\n')


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
    with raises_naming(OutputError, repr(str(p)), "OSError", "No space left on device"):
        write(OSError(28, "No space left on device"))
    assert p.read_text() == "kept"
    assert sorted(x.name for x in tmp_path.iterdir()) == ["t.txt"]


def test_replay_summary_json_keeps_the_mode_of_the_file_it_replaces(tmp_path):
    js = tmp_path / "s.json"
    log = REPO_ROOT / "replay" / "free_body_flip_100hz_delta"
    argv = ["imu_dcm.replay", str(log), "--rerun", "off", "--summary-json", str(js)]
    assert run(argv, tmp_path).returncode == 0  # its own summary, then replaced
    os.chmod(js, 0o644)
    r = run(argv, tmp_path)
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


# ---------------------------------------------------------------------------- exit codes, words
FLIP = REPO_ROOT / "replay" / "free_body_flip_100hz_delta"


def _one_error_line(r, prog: str) -> str:
    lines = [x for x in own_stderr(r.stderr).splitlines() if x.strip() and ": warning:" not in x]
    assert "Traceback" not in r.stderr
    assert len(lines) == 1 and lines[0].startswith(f"{prog}: error: "), r.stderr
    return lines[0]


def test_headless_replay_with_defaults_leaves_nothing_in_the_current_folder(tmp_path):
    r = run(["imu_dcm.replay", str(FLIP)], tmp_path)
    assert r.returncode == 0, r.stderr
    assert list(tmp_path.iterdir()) == []
    hint = [x for x in r.stdout.splitlines() if x.startswith("rerun:")]
    assert len(hint) == 1 and "--rerun serve" in hint[0] and "--rerun save:F.rrd" in hint[0]
    assert "127.0.0.1" in hint[0]


@pytest.mark.parametrize(
    "args,prog",
    [
        (["imu_dcm.replay"], "imu-dcm-replay"),
        (["imu_dcm.replay", "batch"], "imu-dcm-replay batch"),
        (["imu_dcm.replay", "convert-csv"], "imu-dcm-replay convert-csv"),
        (["imu_dcm.live"], "imu-dcm-live"),
        (["data_synth"], "python -m data_synth"),
        (["data_synth", "heavy-top"], "python -m data_synth heavy-top"),
    ],
)
def test_version_on_every_command(args, prog, tmp_path):
    from imu_dcm import __version__

    r = run([*args, "--version"], tmp_path)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == f"{prog} {__version__}"


def test_console_scripts_name_themselves_and_have_version(monkeypatch, capsys):
    from importlib import import_module

    import tomllib

    from imu_dcm import __version__

    scripts = tomllib.loads((REPO_ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    assert set(scripts) == {"imu-dcm-replay", "imu-dcm-live", "data-synth"}
    for name, target in scripts.items():
        module, func = target.split(":")
        if name == "data-synth":  # the program name is read when the module is imported
            monkeypatch.setattr(sys, "argv", [f"/venv/bin/{name}"])
            sys.modules.pop(module, None)
            sys.modules.pop("data_synth.cli", None)
        main = getattr(import_module(module), func)
        try:
            code = main(["--version"])
        except SystemExit as exc:
            code = exc.code
        assert code == 0
        assert capsys.readouterr().out.strip() == f"{name} {__version__}"
    sys.modules.pop("data_synth.cli", None)


def test_replay_exit_codes(tmp_path):
    assert run(["imu_dcm.replay", str(FLIP), "--rerun", "off"], tmp_path).returncode == 0
    r = run(["imu_dcm.replay", str(tmp_path / "missing"), "--rerun", "off"], tmp_path)
    assert r.returncode == 2
    _one_error_line(r, "imu-dcm-replay")
    r = run(["imu_dcm.replay", str(FLIP), "--method", "magnus5"], tmp_path)
    assert r.returncode == 2 and "did you mean 'magnus4'?" in _one_error_line(r, "imu-dcm-replay")


def test_batch_with_a_failed_log_exits_1(tmp_path):
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"not a log")
    table = tmp_path / "out" / "t.csv"  # parents created
    r = run(
        ["imu_dcm.replay", "batch", str(FLIP), str(bad), "--table", str(table), "--jobs", "1"],
        tmp_path,
    )
    assert r.returncode == 1, r.stderr
    assert "1 failed" in r.stdout and table.is_file()


def test_live_exit_codes(tmp_path):
    r = run(["imu_dcm.live", "-", "--rerun", "off"], tmp_path, "")  # no sample at all
    assert r.returncode == 1, r.stderr
    assert "None" not in r.stdout
    assert "no estimate (no sample was integrated)" in r.stdout
    r = run(["imu_dcm.live", "-", "--rerun", "off"], tmp_path, LINES)
    assert r.returncode == 0, r.stderr
    r = run(["imu_dcm.live", "ws://127.0.0.1:1", "--rerun", "off", "--give-up", "0.5"], tmp_path)
    assert r.returncode == 1, r.stderr  # never connected
    assert "None" not in r.stdout and "imu        no IMU channel" in r.stdout
    r = run(["imu_dcm.live", "-", "--time-units", "fortnights"], tmp_path)
    assert r.returncode == 2
    _one_error_line(r, "imu-dcm-live")


def test_live_sigint_and_sigterm_exit_130_and_143(tmp_path):
    import signal
    import time

    env = dict(os.environ, PYTHONPATH=str(REPO_ROOT), CI="true")
    for sig, code in ((signal.SIGINT, 130), (signal.SIGTERM, 143)):
        port = free_udp_port()
        proc = subprocess.Popen(
            [sys.executable, "-m", "imu_dcm.live", f"udp://127.0.0.1:{port}"]
            + ["--rerun", "off", "--no-status"],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            env=env,
            cwd=tmp_path,
        )
        try:
            assert wait_bound(port, proc, 60.0)  # the run is up (nothing is ever sent)
            time.sleep(1.0)
            proc.send_signal(sig)
            out, err = proc.communicate(timeout=30)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
        assert proc.returncode == code, err.decode()
        assert f"stopped    stopped by {sig.name}" in out.decode()


def test_a_closed_pipe_ends_quietly(tmp_path):
    env = dict(os.environ, PYTHONPATH=str(REPO_ROOT), CI="true")
    for args in (["imu_dcm.replay", str(FLIP), "--rerun", "off"], ["imu_dcm.live", "-"]):
        proc = subprocess.Popen(
            [sys.executable, "-m", *args],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            env=env,
            cwd=tmp_path,
        )
        proc.stdout.close()  # `| head` that has already read what it wanted
        _, err = proc.communicate(LINES.encode(), timeout=120)
        err = err.decode()
        assert "BrokenPipe" not in err and "Traceback" not in err and "error" not in err, err
        assert proc.returncode == 0, err


def test_near_miss_and_negative_numbers(tmp_path):
    r = run(["imu_dcm.replay", str(FLIP), "--rerun", "off", "--bias", "atuo"], tmp_path)
    assert r.returncode == 2
    assert "did you mean 'auto'?" in _one_error_line(r, "imu-dcm-replay")
    js = tmp_path / "s.json"
    r = run(
        ["imu_dcm.replay", str(FLIP), "--rerun", "off", "--bias", "-0.01,0,2.5e-3"]
        + ["--summary-json", str(js)],
        tmp_path,
    )
    assert r.returncode == 0, r.stderr
    import json

    # the mean of the bias applied at every sample: a few ulps from the value given
    assert json.loads(js.read_text())["bias_rad_s"] == pytest.approx([-0.01, 0, 0.0025], abs=1e-15)
    r = run(["imu_dcm.live", "-", "--rerun", "off", "--init-quat", "-0,0,-1,-1"], tmp_path, LINES)
    assert r.returncode == 0, r.stderr
    # q = -(0, 0, 1, 1)/sqrt(2) is 90 deg about z: the estimate starts there
    final = next(x for x in r.stdout.splitlines() if x.startswith("final"))
    assert "[+0.0" in final or "[-0.0" in final
    r = run(["imu_dcm.live", "-", "--bias", "-1,0", "--rerun", "off"], tmp_path, LINES)
    assert r.returncode == 2 and "--bias" in _one_error_line(r, "imu-dcm-live")


def test_a_folder_of_logs_points_to_batch(tmp_path):
    r = run(["imu_dcm.replay", str(REPO_ROOT / "replay"), "--rerun", "off"], tmp_path)
    assert r.returncode == 2
    line = _one_error_line(r, "imu-dcm-replay")
    assert "imu-dcm-replay batch" in line and "--table" in line


def test_help_names_every_container_batch_and_the_method_choices(tmp_path):
    import re

    from imu_dcm.integrator.methods import METHODS
    from imu_dcm.logio.containers.foreign import REFUSALS
    from imu_dcm.logio.registry import READERS

    text = " ".join(run(["imu_dcm.replay", "--help"], tmp_path).stdout.split())
    for word in ("metadata.yaml", ".mcap", ".db3", "ROS 1 .bag", "imu-dcm-replay batch"):
        assert word in text, word
    # every container of the reader table is named (by the first word in its parentheses)
    for entry in READERS:
        m = re.search(r"\(([^ ,)]+)", entry.name)
        if entry in REFUSALS or m is None:
            continue
        assert m.group(1) in text, entry.name
    assert "{" + ",".join(METHODS) + "}" in text
    csv_help = run(["imu_dcm.replay", "convert-csv", "--help"], tmp_path).stdout
    assert "--time-units" in csv_help and "--time-unit " in csv_help  # one spelling, old alias


def _port_closed(url: str) -> bool:
    import re
    import socket

    port = int(re.search(r"127\.0\.0\.1:(\d+)", url).group(1))
    with socket.socket() as s:
        return s.connect_ex(("127.0.0.1", port)) != 0


def test_replay_serve_stops_its_viewer_and_removes_its_file_at_ctrl_c(tmp_path):
    import signal
    import time

    tmp = tmp_path / "tmp"
    tmp.mkdir()
    env = dict(os.environ, PYTHONPATH=str(REPO_ROOT), CI="true", TMPDIR=str(tmp))
    proc = subprocess.Popen(
        [sys.executable, "-m", "imu_dcm.replay", str(FLIP), "--rerun", "serve"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        cwd=tmp_path,
    )
    try:
        deadline = time.monotonic() + 90
        line = ""
        while "web viewer at" not in line:
            assert time.monotonic() < deadline and proc.poll() is None, proc.stderr.read()
            line = proc.stdout.readline()
        assert any(p.name.startswith("imu_dcm_rerun_") for p in tmp.iterdir())
        assert not _port_closed(line)
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 130, err  # Ctrl-C is 130 on every path (the README's code)
    assert "rerun: web viewer stopped" in out
    assert _port_closed(line)
    assert not any(p.name.startswith("imu_dcm_rerun_") for p in tmp.iterdir())
    assert [p.name for p in tmp_path.iterdir()] == ["tmp"]


def test_live_idle_stop_leaves_no_web_viewer_running(tmp_path):
    r = run(
        ["imu_dcm.live", "-", "--rerun", "serve", "--idle-stop", "1", "--no-status"],
        tmp_path,
        LINES,
    )
    url = next(x for x in r.stderr.splitlines() if "rerun: open" in x)
    assert "web viewer stopped" in r.stderr
    assert _port_closed(url)

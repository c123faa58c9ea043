"""The one output rule, as a user meets it in replay, batch and live (:mod:`imu_dcm.outputs`).

Every output onto a file this tool did not write, a symbolic link, an input or standard input's
file is refused with one line and exit 2, the file unchanged (``--force`` too); this tool's own
files are written again; ``--summary-json -`` and pipes carry the JSON alone on stdout; the
environment's ``RERUN=off`` never empties a recording; bad input writes nothing.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import REPO_ROOT, assert_quiet

from imu_dcm.replay.__main__ import main

FLIP = REPO_ROOT / "replay" / "free_body_flip_100hz_delta"  # 3000 samples, with truth
FOREIGN = b"a user's own file\n"
LINES = "".join(f"{k * 0.01:.2f},0.1,0,0\n" for k in range(50))  # 0.5 s at 100 Hz about x


def _env(**extra: str) -> dict[str, str]:
    env = dict(os.environ, PYTHONPATH=str(REPO_ROOT), CI="true", **extra)
    for name in ("DISPLAY", "WAYLAND_DISPLAY"):
        env.pop(name, None)
    return env


def _run(args, cwd, stdin=None, **env) -> subprocess.CompletedProcess:
    """``python -m ARGS`` in ``cwd``; ``stdin``: text, or an open file."""
    kw = {"stdin": stdin} if hasattr(stdin, "fileno") else {"input": stdin or ""}
    return subprocess.run(
        [sys.executable, "-m", *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        env=_env(**env),
        timeout=180,
        **kw,
    )


def _refused(code: int, err: str, prog: str, pattern: str) -> None:
    lines = [x for x in err.splitlines() if x.strip()]
    assert code == 2, err
    assert "Traceback" not in err
    assert len(lines) == 1 and lines[0].startswith(f"{prog}: error: Expected"), lines
    assert pattern in lines[0], lines[0]


def _foreign(path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(FOREIGN)
    return path


# ------------------------------------------------------------------------------------ replay
REPLAY_OUTPUTS = {  # option -> (argv, the file it writes)
    "summary": (lambda d: ["--summary-json", str(d / "s.json")], "s.json"),
    "estimate.tum": (lambda d: ["--export-tum", str(d / "tum")], "tum/estimate.tum"),
    "truth.tum": (lambda d: ["--export-tum", str(d / "tum")], "tum/truth.tum"),
    "csv": (lambda d: ["--export-csv", str(d / "e.csv")], "e.csv"),
    "png": (lambda d: ["--plot", str(d / "p.png")], "p.png"),
    "svg": (lambda d: ["--plot", str(d / "p.svg")], "p.svg"),
}


@pytest.mark.parametrize("force", [[], ["--force"]])
@pytest.mark.parametrize("which", sorted(REPLAY_OUTPUTS))
def test_replay_never_replaces_a_file_it_did_not_write(which, force, tmp_path, capsys):
    argv, name = REPLAY_OUTPUTS[which]
    target = _foreign(tmp_path / name)
    code = main([str(FLIP), "--rerun", "off", *argv(tmp_path), *force])
    _refused(code, capsys.readouterr().err, "imu-dcm-replay", "not written by imu_dcm")
    assert target.read_bytes() == FOREIGN
    assert sorted(p.name for p in target.parent.iterdir()) == [target.name]  # nothing else


def test_replay_writes_its_own_files_again(tmp_path, capsys):
    argv = [str(FLIP), "--rerun", "off", "--quiet", "--summary-json", str(tmp_path / "s.json")]
    argv += ["--export-tum", str(tmp_path / "tum"), "--export-csv", str(tmp_path / "e.csv")]
    assert main(argv) == 0 and main(argv) == 0, capsys.readouterr().err
    for figure in ("p.png", "p.svg"):  # a figure of its own is signed, so written again
        pytest.importorskip("matplotlib")
        plot = [str(FLIP), "--rerun", "off", "--quiet", "--plot", str(tmp_path / figure)]
        assert main(plot) == 0 and main(plot) == 0, capsys.readouterr().err
    assert (tmp_path / "e.csv").read_text().startswith("# imu_dcm ")
    summary = json.loads((tmp_path / "s.json").read_text())
    assert summary["written_by"].startswith("imu_dcm ") and summary["samples"] == 3000
    for name in ("estimate.tum", "truth.tum"):
        first = (tmp_path / "tum" / name).read_text().splitlines()[0]
        assert first.startswith("# imu_dcm ") and "t x y z qx qy qz qw" in first


def test_a_rerun_recording_is_replaced_only_when_this_tool_wrote_it(tmp_path, capsys):
    pytest.importorskip("rerun")
    rrd = tmp_path / "v.rrd"
    argv = [str(FLIP), "--quiet", "--rerun", f"save:{rrd}"]
    assert main(argv) == 0, capsys.readouterr().err
    first = rrd.read_bytes()
    assert first[:3] == b"RRF" and len(first) > 10_000
    assert main(argv) == 0, capsys.readouterr().err  # its own recording: written again
    _foreign(rrd)
    _refused(main([*argv, "--force"]), capsys.readouterr().err, "imu-dcm-replay", "recording")
    assert rrd.read_bytes() == FOREIGN


@pytest.mark.parametrize("which", ["summary", "truth.tum"])
def test_replay_writes_nothing_through_a_symbolic_link(which, tmp_path, capsys):
    argv, name = REPLAY_OUTPUTS[which]
    user = _foreign(tmp_path / "mine" / "notes.txt")
    link = tmp_path / name
    link.parent.mkdir(exist_ok=True)
    link.symlink_to(user)
    code = main([str(FLIP), "--rerun", "off", *argv(tmp_path)])
    _refused(code, capsys.readouterr().err, "imu-dcm-replay", "symbolic link")
    assert user.read_bytes() == FOREIGN and link.is_symlink()


def test_replay_refuses_a_hard_link_to_its_input(tmp_path, capsys):
    log = tmp_path / "flip.mcap"
    log.write_bytes((FLIP / "free_body_flip_100hz_delta.mcap").read_bytes())
    before = log.read_bytes()
    os.link(log, tmp_path / "s.json")
    code = main([str(log), "--rerun", "off", "--summary-json", str(tmp_path / "s.json")])
    _refused(code, capsys.readouterr().err, "imu-dcm-replay", "other than the input")
    assert log.read_bytes() == before


def test_summary_json_dash_is_the_json_alone_on_stdout(capsys):
    assert main([str(FLIP), "--rerun", "off", "--summary-json", "-"]) == 0
    out, err = capsys.readouterr()
    summary = json.loads(out)  # nothing else on stdout
    assert summary["samples"] == 3000 and summary["written_by"].startswith("imu_dcm ")
    assert "samples" in err and "error      total RMS" in err  # the lines for people
    assert not Path("-").exists()


def test_summary_json_to_a_pipe_works_and_a_closed_pipe_ends_quietly(tmp_path):
    args = [sys.executable, "-m", "imu_dcm.replay", str(FLIP), "--rerun", "off"]
    r = subprocess.run(
        [*args, "--summary-json", "/dev/stdout"], capture_output=True, text=True, env=_env()
    )
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["samples"] == 3000  # the human lines went to stderr
    line = " ".join(f"'{a}'" for a in args)
    shell = f"set -o pipefail; {line} --summary-json /dev/stdout | head -1"
    r = subprocess.run(["bash", "-c", shell], capture_output=True, text=True, env=_env())
    assert r.returncode == 0 and r.stdout == "{\n", r.stderr
    assert "Traceback" not in r.stderr and "error:" not in r.stderr


def test_rerun_off_in_the_environment_never_empties_a_recording(tmp_path):
    pytest.importorskip("rerun")
    rrd = tmp_path / "v.rrd"
    argv = ["imu_dcm.replay", str(FLIP), "--quiet", "--rerun", f"save:{rrd}"]
    assert _run(argv, tmp_path).returncode == 0
    before = rrd.read_bytes()
    r = _run(argv, tmp_path, RERUN="off")  # rerun's own switch
    _refused(r.returncode, r.stderr, "imu-dcm-replay", "RERUN=off")
    assert rrd.read_bytes() == before and r.stdout == ""
    r = _run(["imu_dcm.replay", str(FLIP), "--quiet"], tmp_path, RERUN="off")
    assert r.returncode == 0, r.stderr
    assert_quiet(r.stderr)  # the default view: none, quietly


def test_rerun_switch_matches_rerun_itself():
    pytest.importorskip("rerun")
    from imu_dcm.app.rerun_mode import RERUN_OFF_VALUES

    probe = (
        "import uuid, rerun as rr; "
        "print(rr.RecordingStream('x', recording_id=uuid.uuid4()).is_enabled())"
    )
    for value in (*RERUN_OFF_VALUES, "OFF", "False", "1", "on", "no", ""):
        r = subprocess.run(
            [sys.executable, "-c", probe], capture_output=True, text=True, env=_env(RERUN=value)
        )
        off = value.lower() in RERUN_OFF_VALUES
        assert r.stdout.strip() == str(not off), (value, r.stdout, r.stderr)


def test_a_failed_run_creates_no_output_folder(tmp_path, capsys):
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"\x89MCAP0\r\n")
    code = main([str(bad), "--rerun", "off", "--summary-json", str(tmp_path / "new" / "s.json")])
    assert code == 2, capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.mcap"]


# ------------------------------------------------------------------------------------- batch
def test_batch_of_a_missing_path_exits_2_and_writes_nothing(tmp_path):
    r = _run(["imu_dcm.replay", "batch", str(tmp_path / "nonexist"), "--table", "t.csv"], tmp_path)
    _refused(r.returncode, r.stderr, "imu-dcm-replay batch", "no such path")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("beside", ["t.md", "t.png", "t.curves.jsonl"])
def test_a_new_table_never_replaces_the_users_files_beside_it(beside, tmp_path):
    pytest.importorskip("matplotlib")
    user = _foreign(tmp_path / "out" / beside)
    argv = ["imu_dcm.replay", "batch", str(FLIP), "--table", "out/t.csv", "--jobs", "1"]
    r = _run(argv, tmp_path)
    _refused(r.returncode, r.stderr, "imu-dcm-replay batch", "not written by imu_dcm")
    assert user.read_bytes() == FOREIGN
    assert sorted(p.name for p in user.parent.iterdir()) == [beside]
    user.unlink()  # then its own files, written again with --force
    assert _run(argv, tmp_path).returncode == 0
    r = _run([*argv, "--force"], tmp_path)
    assert r.returncode == 0, r.stderr
    md = (tmp_path / "out" / "t.md").read_text()
    assert md.startswith("<!-- imu_dcm ") and "| log |" in md
    png = (tmp_path / "out" / "t.png").read_bytes()
    assert png.startswith(b"\x89PNG") and b"Software\0imu_dcm " in png[:4096]


def test_batch_chart_and_table_refuse_symbolic_links(tmp_path):
    user = _foreign(tmp_path / "mine.csv")
    (tmp_path / "t.csv").symlink_to(user)
    argv = ["imu_dcm.replay", "batch", str(FLIP), "--jobs", "1"]
    r = _run([*argv, "--table", "t.csv", "--force"], tmp_path)
    _refused(r.returncode, r.stderr, "imu-dcm-replay batch", "symbolic link")
    r = _run([*argv, "--table", "u.csv", "--chart", "c.svg"], tmp_path)
    _refused(r.returncode, r.stderr, "imu-dcm-replay batch", "PATH.png")
    assert user.read_bytes() == FOREIGN
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine.csv", "t.csv"]


# -------------------------------------------------------------------------------------- live
def test_live_refuses_to_write_its_summary_over_its_own_stdin(tmp_path):
    feed = tmp_path / "feed.txt"
    feed.write_text(LINES)
    with open(feed) as stdin:
        r = _run(
            ["imu_dcm.live", "-", "--rerun", "off", "--summary-json", "feed.txt"],
            tmp_path,
            stdin=stdin,
        )
    _refused(r.returncode, r.stderr, "imu-dcm-live", "standard input")
    assert feed.read_text() == LINES


def test_live_summary_json_dash_is_the_json_alone_on_stdout(tmp_path):
    r = _run(["imu_dcm.live", "-", "--rerun", "off", "--summary-json", "-"], tmp_path, LINES)
    assert r.returncode == 0, r.stderr
    summary = json.loads(r.stdout)
    assert summary["samples"] == 50 and summary["written_by"].startswith("imu_dcm ")
    assert "final      q_w_b" in r.stderr
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("which", ["--summary-json s.json", "--rerun save:v.rrd"])
def test_live_never_replaces_a_file_it_did_not_write(which, tmp_path):
    flag, value = which.split(" ")
    name = value.removeprefix("save:")
    _foreign(tmp_path / name)
    rerun = [] if flag == "--rerun" else ["--rerun", "off"]
    r = _run(["imu_dcm.live", "-", *rerun, flag, value, "--force"], tmp_path, LINES)
    _refused(r.returncode, r.stderr, "imu-dcm-live", "not written by imu_dcm")
    assert (tmp_path / name).read_bytes() == FOREIGN


def test_live_recording_is_written_whole_and_again_and_never_emptied(tmp_path):
    pytest.importorskip("rerun")
    argv = ["imu_dcm.live", "-", "--rerun", "save:v.rrd", "--no-status"]
    for _ in range(2):  # new, then its own recording replaced
        r = _run(argv, tmp_path, LINES)
        assert r.returncode == 0, r.stderr
    rrd = (tmp_path / "v.rrd").read_bytes()
    assert rrd[:3] == b"RRF" and sorted(p.name for p in tmp_path.iterdir()) == ["v.rrd"]
    r = _run(argv, tmp_path, LINES, RERUN="off")
    _refused(r.returncode, r.stderr, "imu-dcm-live", "RERUN=off")
    assert (tmp_path / "v.rrd").read_bytes() == rrd


@pytest.mark.parametrize("signame,code", [("SIGINT", 130), ("SIGTERM", 143)])
def test_serve_stopped_by_a_signal_exits_128_plus_it(signame, code, monkeypatch, capsys):
    import signal
    import threading

    import imu_dcm.viz

    stopped = []

    class Served:  # the web viewer, as far as the command sees it: a running process
        line = "rerun: web viewer at http://127.0.0.1:1 (127.0.0.1 only)"
        viewer = type("V", (), {"process": type("P", (), {"poll": lambda self: None})()})()

        def stop(self):
            stopped.append(True)

    monkeypatch.setattr(imu_dcm.viz, "serve_replay", lambda view, realtime: Served())
    sig = getattr(signal, signame)
    threading.Timer(0.5, os.kill, (os.getpid(), sig)).start()
    assert main([str(FLIP), "--quiet", "--rerun", "serve"]) == code
    out = capsys.readouterr().out
    assert stopped == [True] and "web viewer stopped" in out

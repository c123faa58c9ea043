"""imu_dcm.outputs: the one output rule shared by replay, batch, live, convert-csv and data_synth.

Library level: each kind's own file is recognised (written by the project's writers) and a
foreign one refused; symbolic links, inputs (hard links and standard input included), streams,
missing folders and failed writes. The commands' side is in test_output_rule.py.
"""

from __future__ import annotations

import os
import socket
import threading

import numpy as np
import pytest
from fuzzlib import stdin_from  # fd 0 reads a file for a block, as `cmd < file`

from imu_dcm.logio.writers import StampedSeries, write_bag
from imu_dcm.outputs import (
    OutputError,
    PendingOutput,
    check_output_dir,
    check_output_file,
    claim_output,
    claimed_path,
    is_own_bag,
    write_atomic,
    write_json,
    write_text_atomic,
    writes_to_stdout,
)
from imu_dcm.outputs.signatures import KINDS, comment_line, is_own

FOREIGN = b"my own notes, not imu_dcm's\n"


def _bag(path):
    t = np.arange(3, dtype=np.int64) * 10**7
    return write_bag(path, imu=StampedSeries(t, np.zeros((3, 3)), "imu"))


def test_rules_for_files(tmp_path):
    log = tmp_path / "log"
    log.mkdir()
    (log / "metadata.yaml").write_text("x")
    with pytest.raises(OutputError, match="other than the input"):
        check_output_file(log, [log])
    with pytest.raises(OutputError, match="outside the input folder"):
        check_output_file(log / "s.json", [log])
    with pytest.raises(OutputError, match="does not contain the input"):
        check_output_file(tmp_path, [log / "metadata.yaml"])
    with pytest.raises(OutputError, match="a file, a stream or new, got a folder"):
        check_output_file(log, [])
    (tmp_path / "link.json").symlink_to(log / "metadata.yaml")  # resolved: the input itself
    with pytest.raises(OutputError, match="other than the input"):
        check_output_file(tmp_path / "link.json", [log / "metadata.yaml"])
    assert check_output_file(tmp_path / "new.json") == tmp_path / "new.json"
    with pytest.raises(ValueError, match="output kind"):
        claim_output(tmp_path / "x", "jsn")


def _own_files(tmp_path) -> dict[str, object]:
    """A file of each kind, written by the project's own writers."""
    from imu_dcm.replay.export import claim_export, export_tum
    from imu_dcm.replay.table import LogRow, append_curve, write_markdown, write_table

    own = {}
    own["json"] = write_json(tmp_path / "s.json", {"samples": 3})
    t = np.arange(3, dtype=np.int64)
    q = np.tile([0.0, 0.0, 0.0, 1.0], (3, 1))
    own["tum"] = export_tum(claim_export(tmp_path / "tum"), t, q, None)[0]
    own["csv"] = write_atomic(claim_output(tmp_path / "e.csv", "csv"), comment_line("x") + "1\n")
    y = claim_output(tmp_path / "n.yaml", "yaml")
    own["yaml"] = write_atomic(y, comment_line("noise yaml") + "update_rate: 200\n")
    table = tmp_path / "t.csv"
    write_table(table, [LogRow("a.mcap", samples=3)])
    own["table"] = table
    own["markdown"] = write_markdown(table, [LogRow("a.mcap", samples=3)])
    from imu_dcm.replay.table import Curve

    append_curve(table, Curve("a.mcap", (0.0,), (1.0,)))
    own["curves"] = table.with_suffix(".curves.jsonl")
    own["mcap"] = _bag(tmp_path / "bag") / "bag.mcap"
    return own


def test_each_kind_recognises_its_own_file_and_refuses_others(tmp_path):
    own = _own_files(tmp_path)
    # rrd, chart and figure (PNG/SVG from matplotlib): test_output_rule.py
    assert set(own) == set(KINDS) - {"rrd", "chart", "figure"}
    for kind, path in own.items():
        assert is_own(path, kind), kind
        assert is_own(path, "any"), kind
        assert claim_output(path, kind).stream == "file"
        commented = {"tum", "csv", "yaml"}  # all three start "# imu_dcm"
        same = {kind, *(commented if kind in commented else ())}
        for other in set(own) - same:  # a summary is no table, a table no TUM file, ...
            assert not is_own(path, other), (kind, other)
        foreign = tmp_path / "foreign" / path.name
        foreign.parent.mkdir(exist_ok=True)
        foreign.write_bytes(FOREIGN)
        with pytest.raises(OutputError, match="got an existing file not written by imu_dcm"):
            claim_output(foreign, kind, what="--x")
        assert foreign.read_bytes() == FOREIGN
    empty = tmp_path / "empty.json"
    empty.touch()
    assert claim_output(empty, "json").stream == "file"  # nothing to lose


def test_a_summary_is_signed_first_and_replaces_only_its_own(tmp_path):
    p = write_json(tmp_path / "s.json", {"x": np.float64(1.5), "v": np.arange(2)})
    text = p.read_text()
    assert text.startswith('{\n  "written_by": "imu_dcm ')
    import json

    assert json.loads(text)["x"] == 1.5 and json.loads(text)["v"] == [0, 1]
    write_json(p, {"x": 2})  # its own: replaced
    user = tmp_path / "user.json"
    user.write_text('{"x": 1}\n')
    with pytest.raises(OutputError, match="not written by imu_dcm"):
        write_json(user, {"x": 2})
    assert user.read_text() == '{"x": 1}\n'


@pytest.mark.parametrize("target", ["foreign", "own", "nothing", "folder"])
def test_a_symbolic_link_is_never_written_through_nor_replaced(tmp_path, target):
    dest = tmp_path / "dest.json"
    if target == "foreign":
        dest.write_bytes(FOREIGN)
    elif target == "own":
        write_json(dest, {"x": 1})
    elif target == "folder":
        dest.mkdir()
    link = tmp_path / "s.json"
    link.symlink_to(dest)
    before = dest.read_bytes() if dest.is_file() else None
    with pytest.raises(OutputError, match="not to be a symbolic link"):
        write_json(link, {"x": 2})
    assert link.is_symlink()
    assert (dest.read_bytes() if dest.is_file() else None) == before


def test_a_link_to_a_stream_is_written_through(tmp_path):
    link = tmp_path / "s.json"
    link.symlink_to(os.devnull)
    claim = claim_output(link, "json")
    assert claim.stream == "device"
    write_json(claim, {"x": 1})
    assert link.is_symlink() and os.path.realpath(link) == os.devnull


def test_a_hard_link_to_an_input_or_standard_input_is_refused(tmp_path):
    feed = tmp_path / "feed.txt"
    feed.write_text("0,0,0,1\n")
    twin = tmp_path / "twin.json"
    os.link(feed, twin)  # another name, same inode
    with pytest.raises(OutputError, match="other than the input"):
        claim_output(twin, "any", [feed])
    with stdin_from(feed), pytest.raises(OutputError, match="file on standard input"):
        claim_output(feed, "any")  # live - --summary-json feed.txt < feed.txt
    assert feed.read_text() == "0,0,0,1\n"
    with stdin_from(os.devnull):  # a device on stdin is no input file
        assert claim_output(tmp_path / "new.json", "json").stream == "file"


def test_dash_and_the_stdout_file_are_standard_output(tmp_path, capsys):
    claim = claim_output("-", "json")
    assert claim.stream == "stdout" and writes_to_stdout("-")
    write_json(claim, {"x": 1})
    out = capsys.readouterr().out
    assert out.startswith('{\n  "written_by": "imu_dcm ') and out.endswith("}\n")
    assert not writes_to_stdout(tmp_path / "s.json") and not writes_to_stdout(None)
    # a path that is fd 1's file (/dev/stdout, or the file the shell redirected stdout to)
    redirected = tmp_path / "stdout.txt"
    saved = os.dup(1)
    fd = os.open(redirected, os.O_WRONLY | os.O_CREAT, 0o644)
    try:
        os.dup2(fd, 1)
        assert claim_output(redirected, "json").stream == "stdout"
        assert writes_to_stdout(redirected)
    finally:
        os.dup2(saved, 1)
        os.close(saved)
        os.close(fd)


def test_a_fifo_is_written_directly_and_one_without_reader_is_refused(tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    with pytest.raises(OutputError, match="reader on the FIFO"):  # at the claim: never waits
        claim_output(fifo, "json")
    got = []

    def read():
        with open(fifo, "rb") as f:  # blocks until a writer opens
            got.append(f.read())

    reader = threading.Thread(target=read)
    reader.start()
    for _ in range(500):  # claim once the reader is in its open()
        try:
            claim = claim_output(fifo, "json")
            break
        except OutputError:
            threading.Event().wait(0.01)
    assert claim.stream == "device"
    threading.Event().wait(0.2)
    assert not got  # the reader waits for the output: the claim holds the write end
    write_json(claim, {"x": 1})
    reader.join(5)
    assert got and got[0].startswith(b'{\n  "written_by"') and got[0].endswith(b"}\n")
    assert os.path.exists(fifo) and not os.path.isfile(fifo)


def test_sockets_folders_and_block_devices_are_refused(tmp_path):
    sock_path = tmp_path / "s.sock"
    with socket.socket(socket.AF_UNIX) as s:
        s.bind(str(sock_path))
        with pytest.raises(OutputError, match="got a socket"):
            claim_output(sock_path, "json")
    with pytest.raises(OutputError, match="got a folder"):
        claim_output(tmp_path, "json")
    blocks = [p for p in ("/dev/loop0", "/dev/sda", "/dev/vda") if os.path.exists(p)]
    for dev in blocks:
        with pytest.raises(OutputError, match="block device"):
            claim_output(dev, "json")


def test_write_atomic_is_whole_or_absent(tmp_path, monkeypatch):
    target = tmp_path / "s.json"
    write_json(target, {"n": 1})
    before = target.read_bytes()
    from imu_dcm.outputs import write as outputs

    def fail(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(outputs.os, "replace", fail)
    with pytest.raises(OutputError, match="No space left"):
        write_json(target, {"n": 2})
    assert target.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.json"]  # no temporary left
    deep = tmp_path / "a" / "b" / "s.json"
    with pytest.raises(OutputError, match="No space left"):
        write_json(deep, {"n": 2})
    assert not (tmp_path / "a").exists()  # the folders made for it are gone again
    monkeypatch.undo()
    write_json(deep, {"n": 2})  # made when written
    assert deep.is_file()


def test_the_target_is_checked_again_just_before_it_is_replaced(tmp_path):
    target = tmp_path / "v.json"
    claim = claim_output(target, "json")  # new at the start of the work
    target.write_bytes(FOREIGN)  # ... and someone else's file by its end
    with pytest.raises(OutputError, match="not written by imu_dcm"):
        write_json(claim, {"x": 1})
    assert target.read_bytes() == FOREIGN
    pending = PendingOutput(claim_output(tmp_path / "w.json", "json"))
    pending.path.write_text('{"written_by": "imu_dcm test"}\n')
    (tmp_path / "w.json").symlink_to(target)
    with pytest.raises(OutputError, match="symbolic link"):
        pending.commit()
    assert target.read_bytes() == FOREIGN and not pending.path.exists()


def test_claimed_path_removes_its_temporary_on_an_exception(tmp_path):
    target = tmp_path / "c.json"

    def write_half():
        with claimed_path(claim_output(target, "json")) as tmp:
            tmp.write_text("half")
            raise RuntimeError("boom")

    with pytest.raises(RuntimeError):
        write_half()
    assert list(tmp_path.iterdir()) == []


def test_write_text_atomic_is_whole_or_absent(tmp_path, monkeypatch):
    target = tmp_path / "metadata.yaml"  # the low-level write, inside a checked folder
    write_text_atomic(target, "one\n")
    assert target.read_text() == "one\n"
    from imu_dcm.outputs import write as outputs

    def fail(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(outputs.os, "replace", fail)
    with pytest.raises(OutputError, match="No space left"):
        write_text_atomic(target, "two\n")
    assert target.read_text() == "one\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["metadata.yaml"]


def test_force_replaces_only_own_bags(tmp_path):
    own = _bag(tmp_path / "own")
    assert is_own_bag(own)
    assert check_output_dir(own, [], force=True) == own
    with pytest.raises(OutputError, match="not to exist"):
        check_output_dir(own, [])
    other = tmp_path / "other"
    other.mkdir()
    (other / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    (other / "other.mcap").write_bytes(b"\x89MCAP0\r\n" + b"\x01" * 64)  # someone else's
    assert not is_own_bag(other)
    with pytest.raises(OutputError, match="only a bag this tool wrote"):
        write_bag(other, imu=StampedSeries(np.arange(2), np.zeros((2, 3)), "imu"), force=True)
    assert (other / "other.mcap").exists()
    (tmp_path / "alias").symlink_to(own)
    with pytest.raises(OutputError, match="symbolic link"):
        check_output_dir(tmp_path / "alias", [], force=True)

"""imu_dcm.outputs: the output-path rules shared by replay, convert-csv and data_synth."""

from __future__ import annotations

import os

import numpy as np
import pytest

from imu_dcm.logio.writer import StampedSeries, write_bag
from imu_dcm.outputs import (
    OutputError,
    check_output_dir,
    check_output_file,
    is_own_bag,
    write_text_atomic,
)


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
    with pytest.raises(OutputError, match="regular file or new, got a folder"):
        check_output_file(log, [])
    os.mkfifo(tmp_path / "fifo")
    with pytest.raises(OutputError, match="got a FIFO"):
        check_output_file(tmp_path / "fifo")
    (tmp_path / "link.json").symlink_to(log / "metadata.yaml")  # resolved: the input itself
    with pytest.raises(OutputError, match="other than the input"):
        check_output_file(tmp_path / "link.json", [log / "metadata.yaml"])
    assert check_output_file(tmp_path / "new.json") == tmp_path / "new.json"


def test_write_text_atomic_is_whole_or_absent(tmp_path, monkeypatch):
    target = tmp_path / "s.json"
    write_text_atomic(target, "one\n")
    assert target.read_text() == "one\n"
    from imu_dcm import outputs

    def fail(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(outputs.os, "replace", fail)
    with pytest.raises(OutputError, match="No space left"):
        write_text_atomic(target, "two\n")
    assert target.read_text() == "one\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.json"]  # no temporary left


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

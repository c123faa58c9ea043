"""Files that are not logs are named: batch lists what it skipped and which convert-csv
converts; a folder of CSVs says so; a EuRoC CSV points to its dataset; a metadata.yaml reads its
bag. Driven through the commands as a user runs them."""

from __future__ import annotations

import numpy as np
import pytest

from imu_dcm.logio.writers import StampedSeries, write_bag
from imu_dcm.replay.__main__ import main


@pytest.fixture
def bag(tmp_path):
    t_ns = 10**9 + np.arange(300, dtype=np.int64) * 10_000_000
    w = np.tile([0.0, 0.0, 0.1], (300, 1))
    q = np.tile([0.0, 0.0, 0.0, 1.0], (300, 1))
    return write_bag(
        tmp_path / "logs" / "bag",
        imu=StampedSeries(t_ns, w, "imu"),
        quaternions={"/ground_truth/orientation": StampedSeries(t_ns, q, "world")},
    )


def _csv(path):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("t,wx,wy,wz\n0,0,0,0\n0.01,0,0,0\n")
    return path


def test_metadata_yaml_reads_its_bag(bag, capsys):
    assert main([str(bag), "--rerun", "off", "--bias", "none"]) == 0
    folder = capsys.readouterr().out
    assert main([str(bag / "metadata.yaml"), "--rerun", "off", "--bias", "none"]) == 0
    yaml = capsys.readouterr().out
    line = next(x for x in folder.splitlines() if x.startswith("error  "))
    assert line in yaml.splitlines()


def test_a_euroc_csv_points_to_its_dataset(tmp_path, capsys):
    csv = _csv(tmp_path / "MH_01" / "mav0" / "imu0" / "data.csv")
    assert main([str(csv), "--rerun", "off"]) == 2
    err = capsys.readouterr().err
    assert f"a file of the EuRoC/ASL dataset {tmp_path / 'MH_01'}" in err
    assert f"`python -m imu_dcm.replay {tmp_path / 'MH_01'}`" in err
    assert "convert-csv" not in err


def test_a_folder_of_csvs_says_so_and_names_convert_csv(tmp_path, capsys):
    for name in ("a.csv", "b.csv"):
        _csv(tmp_path / "csvs" / name)
    assert main([str(tmp_path / "csvs"), "--rerun", "off"]) == 2
    err = capsys.readouterr().err
    assert "holding a.csv, b.csv; 2 text tables" in err and "convert-csv FILE" in err
    table = tmp_path / "t.csv"
    assert main(["batch", str(tmp_path / "csvs"), "--table", str(table)]) == 2
    err = capsys.readouterr().err
    assert (
        f"no logs found under {tmp_path / 'csvs'}: 2 files that are not logs (a.csv, b.csv)" in err
    )
    assert "convert-csv FILE" in err and not table.exists()


def test_batch_names_the_files_it_skipped(bag, tmp_path, capsys):
    _csv(tmp_path / "logs" / "gyro.csv")
    (tmp_path / "logs" / "notes.md").write_text("not a log\n")
    table = tmp_path / "t.csv"
    assert main(["batch", str(tmp_path / "logs"), "--table", str(table), "--jobs", "1"]) == 0
    captured = capsys.readouterr()
    assert "1 log, 0 failed" in captured.out
    assert (
        f"skipped under {tmp_path / 'logs'}: 2 files that are not logs (gyro.csv, notes.md); "
        f"1 text table (gyro.csv): `python -m imu_dcm.replay convert-csv FILE OUT.mcap ...` "
        f"converts it into a bag"
    ) in captured.err

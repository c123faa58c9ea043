"""data_synth writes a log a block at a time: the same samples and bag at any block size, memory
that does not grow with the log, and a bag that appears whole or not at all."""

from __future__ import annotations

import os
import subprocess
import sys
from itertools import pairwise
from pathlib import Path

import numpy as np
import pytest
from conftest import small_blocks

import data_synth
from data_synth import budget
from data_synth.gyro import GyroModel, synthetic_gyro
from imu_dcm.errors import InputError
from imu_dcm.logio import read_log
from imu_dcm.logio.writers import BagBlock, StampedSeries, write_bag, write_bag_blocks

REPO = Path(__file__).resolve().parents[1]


def main(argv: list[str]) -> int:
    """data_synth's entry point, from the module as imported now (a test elsewhere re-imports
    it: patches go to the module in ``sys.modules``, which this calls)."""
    import data_synth.cli

    return data_synth.cli.main(argv)


EVERY_TERM = GyroModel(
    noise_density_rad_s_sqrt_hz=1e-3,
    bias_rad_s=(0.01, -0.02, 0.003),
    bias_walk_rad_s2_sqrt_hz=1e-3,
    quantization_rad_s=1e-3,
    range_rad_s=20.0,
    stamp_jitter_s=1e-5,
)
FIELDS = ("t_s", "t_ns", "values", "bias_b_rad_s")


@pytest.fixture(scope="module")
def scenes():
    return {
        "heavy-top": data_synth.simulate("heavy-top", duration_s=1.2, motion="looping"),
        "coning": data_synth.simulate("coning", duration_s=1.5),
    }


@pytest.mark.parametrize("rows", [1, 89, 1000])
@pytest.mark.parametrize("output", ["rate", "delta-angle"])
@pytest.mark.parametrize(
    "model",
    [EVERY_TERM, GyroModel(bias_walk_rad_s2_sqrt_hz=1e-3), GyroModel(quantization_rad_s=1e-3)],
    ids=["every-term", "walk", "quantized"],
)
def test_blocks_give_the_whole_record_bit_for_bit(scenes, monkeypatch, rows, output, model):
    # The random draws, the bias walk and the delta-angle quantization carry over from block to
    # block in the whole log's order: any block size gives the same bytes.
    for traj in scenes.values():
        whole = synthetic_gyro(traj, 1000.0, model=model, output=output, seed=3)
        with monkeypatch.context() as m:
            assert "data_synth.gyro" in small_blocks(m, rows)
            parts = synthetic_gyro(traj, 1000.0, model=model, output=output, seed=3)
        for name in FIELDS:
            assert getattr(parts, name).tobytes() == getattr(whole, name).tobytes(), name
        assert parts.rate_rad_s().tobytes() == whole.rate_rad_s(0.0).tobytes()


def test_the_shipped_noisy_log_is_made_in_blocks_of_89_rows(tmp_path, monkeypatch):
    # Its command draws noise and a bias walk from one seed and quantizes: made 89 rows at a
    # time, its bag holds what the whole-log run writes, value for value.
    shipped = REPO / "replay" / "heavy_top_wavy_noisy_400hz"
    argv = (shipped / "COMMAND.txt").read_text().split()[3:]
    at = argv.index("--out") + 1
    made = {}
    for rows in (None, 89):
        argv[at] = str(tmp_path / f"rows_{rows}")
        with monkeypatch.context() as m:
            if rows:
                small_blocks(m, rows)
            assert main(argv) == 0
        made[rows] = read_log(argv[at])
    whole, parts = made[None], made[89]
    for a, b in ((whole.imu, parts.imu), (whole.truth, parts.truth)):
        for name in ("t_ns", "omega_b", "q_w_b"):
            if hasattr(a, name):
                np.testing.assert_array_equal(getattr(a, name), getattr(b, name))


def _series(t_ns):
    n = len(t_ns)
    rng = np.random.default_rng(len(t_ns))
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return {
        "imu": StampedSeries(t_ns, rng.normal(size=(n, 3)), "imu"),
        "quaternions": {"/truth": StampedSeries(t_ns, q, "world")},
    }


def _cut(series, a, b):
    imu, q = series["imu"], series["quaternions"]["/truth"]
    return BagBlock(
        imu=StampedSeries(imu.t_ns[a:b], imu.values[a:b], "imu"),
        quaternions={"/truth": StampedSeries(q.t_ns[a:b], q.values[a:b], "world")},
    )


def test_a_bag_written_in_blocks_reads_as_the_bag_written_whole(tmp_path):
    t_ns = 1_700_000_000_000_000_000 + np.arange(5000) * 1_000_000
    series = _series(t_ns)
    write_bag(tmp_path / "whole", **series)
    cuts = [0, 1, 700, 701, 3000, 5000]
    write_bag_blocks(tmp_path / "blocks", (_cut(series, a, b) for a, b in pairwise(cuts)))
    whole, blocks = read_log(tmp_path / "whole"), read_log(tmp_path / "blocks")
    np.testing.assert_array_equal(whole.imu.t_ns, blocks.imu.t_ns)
    np.testing.assert_array_equal(whole.imu.omega_b, blocks.imu.omega_b)
    np.testing.assert_array_equal(whole.truth.q_w_b, blocks.truth.q_w_b)
    meta = (tmp_path / "blocks" / "metadata.yaml").read_text()
    assert "message_count: 10000" in meta and "message_count: 5000" in meta


@pytest.mark.parametrize("fault", ["back in time", "other topics", "bad value"])
def test_a_block_that_fails_leaves_no_bag(tmp_path, fault):
    t_ns = 1_700_000_000_000_000_000 + np.arange(400) * 1_000_000
    series = _series(t_ns)
    first, second = _cut(series, 0, 200), _cut(series, 200, 400)
    if fault == "back in time":
        second = _cut(series, 100, 300)
        match = "at or after the last log time"
    elif fault == "other topics":
        second = BagBlock(imu=second.imu)
        match = "to hold the channels"
    else:
        bad = second.imu.values.copy()
        bad[7] = np.nan
        second = BagBlock(StampedSeries(second.imu.t_ns, bad, "imu"), second.quaternions)
        match = "finite values"
    with pytest.raises(InputError, match=match):
        write_bag_blocks(tmp_path / "out", iter([first, second]))
    assert list(tmp_path.iterdir()) == []  # no bag, no temporary


def test_no_disk_room_is_refused_up_front(tmp_path, monkeypatch, capsys):
    # 1 h at 1 kHz: 3.6e6 samples at 160 B each on disk, with 1 MB free.
    monkeypatch.setattr(budget, "free_bytes", lambda out: 10**6)
    out = tmp_path / "never"
    assert main(["coning", "--rate", "1000", "--duration", "3600", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "room for the bag on disk" in err and "549 MiB" in err, err
    assert list(tmp_path.iterdir()) == []


def test_a_long_job_says_how_far_it_is(tmp_path, monkeypatch, capsys):
    import data_synth.cli as cli

    monkeypatch.setattr(cli, "PROGRESS_EVERY_S", 0.0)  # the module main() calls
    small_blocks(monkeypatch, 1000)
    argv = ["coning", "--rate", "1000", "--duration", "4.5", "--out", str(tmp_path / "b")]
    assert main(argv) == 0
    err = capsys.readouterr().err.splitlines()
    assert [line.split(": ")[1] for line in err] == [
        f"{p}% of 4501 samples written" for p in (22, 44, 67, 89)
    ]


def _peak_rss(minutes: float, out: Path) -> int:
    """Peak RSS of a data_synth coning job of ``minutes`` at 1 kHz, bytes (its own process)."""
    cmd = [sys.executable, "-m", "data_synth", "coning", "--rate", "1000"]
    cmd += ["--duration", str(60 * minutes), "--out", str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, cwd=REPO)
    _, status, ru = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)  # waited for: Popen need not
    assert proc.returncode == 0
    return ru.ru_maxrss * 1024


def test_memory_does_not_grow_with_the_log(tmp_path):
    # 5 min and 20 min at 1 kHz: 9e5 more samples, which held whole (~270 B a sample of gyro,
    # truth and their file order) would add ~240 MB. In blocks, both jobs hold one full block
    # (2^17 rows, both logs have more than two); what is left is the allocator's noise.
    short = _peak_rss(5, tmp_path / "short")
    long = _peak_rss(20, tmp_path / "long")
    assert long - short < 50e6, (short, long)

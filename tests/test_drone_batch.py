"""`replay batch` finds drone logs in folders by the container table's probes: PX4 ULogs and
ArduPilot DataFlash logs, whatever their names, beside files that are no logs."""

from __future__ import annotations

import os

import pytest

from imu_dcm.errors import ImuDcmWarning
from imu_dcm.logio import find_logs
from imu_dcm.replay.batch import find_logs as batch_find_logs
from tests.drone_logs import trial_dataflash, trial_ulog

pytest.importorskip("pymavlink")


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    root = tmp_path_factory.mktemp("fleet")
    (root / "px4").mkdir()
    (root / "ardupilot" / "2026-12-01").mkdir(parents=True)
    trial_ulog(root / "px4" / "flight.ulg")
    trial_dataflash(root / "ardupilot" / "2026-12-01" / "00000042.BIN")  # ArduPilot's naming
    trial_ulog(root / "px4" / "renamed.log")  # found by its bytes, not its name
    (root / "px4" / "notes.txt").write_text("not a log\n")
    (root / "ardupilot" / "params.parm").write_text("GYR_CAL 1\n")
    return root


def test_find_logs_takes_ulogs_and_dataflash_by_their_bytes(fleet):
    got = sorted(p.relative_to(fleet).as_posix() for p in find_logs(fleet))
    assert got == ["ardupilot/2026-12-01/00000042.BIN", "px4/flight.ulg", "px4/renamed.log"]


def test_replay_batch_searches_folders_for_them(fleet):
    with pytest.warns(
        ImuDcmWarning, match=r"2 files that are not logs \(ardupilot/params.parm, px4/notes.txt\)$"
    ):
        got = sorted(os.path.relpath(p, fleet) for p in batch_find_logs([fleet]))
    assert got == [
        os.path.join("ardupilot", "2026-12-01", "00000042.BIN"),
        os.path.join("px4", "flight.ulg"),
        os.path.join("px4", "renamed.log"),
    ]

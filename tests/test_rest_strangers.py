"""The rest rule on real logs of other projects, against figures computed without this
project's code (the data folder's README: scipy ``Rotation`` products from the truth's first
attitude). Skips with a reason when the logs are absent."""

from __future__ import annotations

import csv
import json
import warnings

import numpy as np
import pytest
from conftest import STRANGERS, need_data

from imu_dcm.logio import read_custom_data
from imu_dcm.logio.types import ImuSeries, LogData, TruthSeries
from imu_dcm.replay import replay

pytestmark = pytest.mark.slow


def _log(name: str):
    return need_data(STRANGERS / name)


def _rows(path) -> list[list[str]]:
    with open(path, newline="") as f:
        return list(csv.reader(f))[1:]


def _replay(path, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return replay(path, **kw)


def test_ardupilot_ground_log_is_one_rest():
    # 27 s that never move (|omega| < 0.0008 rad/s): the whole log is rest; 0.09° with it as
    # bias, 0.72° with none
    res = _replay(_log("ardupilot_sitl_plane_ground.BIN"))
    segs = res.bias.segments
    assert len(segs) == 1 and (segs[0].start, segs[0].stop) == (0, len(res.t_s))
    assert "accelerometer" in segs[0].evidence and res.summary.rest_conflict == ""
    # the README's whole-log figure, to within the scoring's start (the truth's first sample
    # here against the gyro's first) and print rounding: half the no-bias error is far off
    assert res.summary.rms_error_deg < 0.12 < 0.5 * 0.72
    # its simulated attitude is level to the last bit, but it never turns: scored whole
    assert res.summary.scored_on == "attitude"


def test_ardupilot_flight_rests_before_the_take_off_roll():
    # About 1 s at rest before the roll: 0.44° with the first 0.9 s as bias, 1.51° with none
    res = _replay(_log("ardupilot_sitl_plane_flight.BIN"))
    segs = res.bias.segments
    assert len(segs) == 1 and segs[0].start == 0 and 0.5 < segs[0].end_s < 1.5
    assert set(segs[0].evidence) == {"gyro floor", "accelerometer", "truth"}
    assert abs(res.summary.rms_error_deg - 0.44) < 0.02


def test_ximu3_foot_rests_at_start_and_end():
    # A walking foot, gyro in deg/s, its own AHRS as truth (W, X, Y, Z), no accelerometer in the
    # joined log: rest at the start and at the end (the README's 3.8° uses both). The AHRS
    # turns during the last rest where the gyro does not (its correction): that judges nothing.
    inertial = _rows(_log("ximu3_left_foot_inertial.csv"))
    quat = {r[0]: r[1:] for r in _rows(_log("ximu3_left_foot_quaternion.csv"))}
    rows = [(r, quat[r[0]]) for r in inertial if r[0] in quat]
    t_ns = np.array([int(r[0]) * 1000 for r, _q in rows], dtype=np.int64)
    w = np.radians(np.array([[float(x) for x in r[1:4]] for r, _q in rows]))
    q = np.array([[float(x) for x in qq] for _r, qq in rows])[:, [1, 2, 3, 0]]
    imu = ImuSeries(t_ns, t_ns, w, None, "inertial", "csv", "sensor")
    truth = TruthSeries(t_ns, t_ns, q, "quaternion", "csv", "earth", estimate_of="x-IMU3's AHRS")
    res = _replay(LogData("foot", imu, truth, ()))
    segs = res.bias.segments
    assert len(segs) == 2, segs
    assert segs[0].start == 0 and segs[0].end_s < 1.5
    assert segs[1].stop == len(res.t_s) and segs[1].start_s > 15.0
    assert all("truth" in s.evidence for s in segs)


@pytest.mark.broad
def test_broad_rests_with_breaks_lie_between_the_annotated_movements(broad_dir):
    # Trial 05 has four movement phases (BROAD's annotation, in the bag's custom_data): one rest
    # before, between and after them, each outside every movement phase
    bag = broad_dir / "05_undisturbed_slow_rotation_with_breaks_B"
    meta = read_custom_data(bag)
    moves = json.loads(meta["broad.movement_intervals_index"])
    res = _replay(bag)
    k = (res.t_ns - 1_700_000_000_000_000_000) // int(meta["broad.sample_period_ns"])
    segs = res.bias.segments
    assert len(segs) == len(moves) + 1
    for i, seg in enumerate(segs):
        first, last = k[seg.start], k[seg.stop - 1]
        assert (i == 0 or first > moves[i - 1][1]) and (i == len(moves) or last < moves[i][0])
        assert "accelerometer" in seg.evidence

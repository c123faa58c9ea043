"""Live from MAVLink: a pymavlink sender in a separate process on loopback streams HIGHRES_IMU
(or SCALED_IMU, RAW_IMU) and ATTITUDE_QUATERNION of a known motion; the live integration must
follow the sent truth."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from conftest import raises_naming
from scipy.spatial.transform import Rotation
from test_live_ws import live_thread

from imu_dcm.errors import InputError
from imu_dcm.live.sources import parse_source
from imu_dcm.live.sources.mavlink import parse_url
from imu_dcm.logio import ned
from imu_dcm.so3 import angle_between_deg

pytest.importorskip("pymavlink")

#: A constant body rate (FRD, rad/s) whose components float32 holds exactly, about a tilted
#: axis, from a start attitude; gyro at 250 Hz, truth at 50 Hz, for 3 s.
W_FRD = (0.25, -0.125, 0.5)
Q0_WXYZ = (0.9, 0.1, -0.3, 0.2)
SENDER = r"""
import sys, time
import numpy as np
from scipy.spatial.transform import Rotation
from pymavlink.dialects.v20 import common
host, port, kind, pause_s = sys.argv[1], int(sys.argv[2]), sys.argv[3], float(sys.argv[4])
w = np.array([0.25, -0.125, 0.5]); q0 = np.array([0.1, -0.3, 0.2, 0.9]); q0 /= np.linalg.norm(q0)
mav = common.MAVLink(None, srcSystem=1, srcComponent=1)
import socket
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
def att(t_ms):
    q = (Rotation.from_quat(q0) * Rotation.from_rotvec(w * t_ms * 1e-3)).as_quat()
    return mav.attitude_quaternion_encode(t_ms, q[3], q[0], q[1], q[2], 0, 0, 0).pack(mav)
T0_MS = 10_000
for k in range(751):                      # gyro every 4 ms from 10 s since boot
    t_us = (T0_MS + 4 * k) * 1000
    if kind == "highres":
        m = mav.highres_imu_encode(t_us, 0, 0, -9.8, *w, 0, 0, 0, 0, 0, 0, 0, 0x3F)
    elif kind == "hostile":               # 3e38 rad/s every 50th; one stamp of 2^64 - 1 us
        ww = (3e38, 0.0, 0.0) if k % 50 == 25 else w
        m = mav.highres_imu_encode(2**64 - 1 if k == 200 else t_us, 0, 0, -9.8, *ww, 0, 0, 0,
                                   0, 0, 0, 0, 0x3F)
    elif kind == "scaled":                # mrad/s as int16: 250, -125, 500 exactly
        m = mav.scaled_imu_encode(t_us // 1000, 0, 0, -1000, *(int(v * 1000) for v in w), 0, 0, 0)
    else:                                 # raw counts at 0.5 mrad/s per count
        m = mav.raw_imu_encode(t_us, 0, 0, -1000, *(int(v / 5e-4) for v in w), 0, 0, 0)
    s.sendto(m.pack(mav), (host, port))
    if k % 5 == 0:
        s.sendto(att(T0_MS + 4 * k), (host, port))
    if k == 100:
        s.sendto(b"\xfd\x09garbage-not-a-frame", (host, port))
    time.sleep(pause_s)
"""


def _run_with_sender(kind: str, source: str = "mavlink:udpin:127.0.0.1:0", **kw):
    live = live_thread(source, say=lambda _text: None, **kw)
    ready, stop, addr, out, th = live.ready, live.stop, live.addr, live.out, live.thread
    assert ready.wait(20)
    host, port = addr["address"]
    pause_s = "0.004" if kind == "raw" else "0.0008"  # RAW_IMU: past the 1 s wait
    subprocess.run(
        [sys.executable, "-c", SENDER, host, str(port), kind, pause_s], check=True, timeout=60
    )
    stop.wait(0.5)  # what is in flight on loopback arrives
    stop.set()
    th.join(60)
    assert not th.is_alive()
    return out["result"]


def _truth_at(t_ms: float) -> np.ndarray:
    q0 = np.array([*Q0_WXYZ[1:], Q0_WXYZ[0]])
    r = Rotation.from_quat(q0 / np.linalg.norm(q0)) * Rotation.from_rotvec(
        np.array(W_FRD) * t_ms * 1e-3
    )  # t_ms since boot, as the sender stamps it
    q = r.as_quat()
    return ned.q_enu_flu(np.array([q[3], *q[:3]]))


# The truth crosses the wire as float32: each component within 2^-24 of unit norm, so each
# attitude within 2 * 2^-24 rad = 6.8e-6 deg of the sent one; the estimate starts from one and
# is compared with another: 1.4e-5 deg. The rates are exact in float32 (and in mrad/s), and a
# constant rate about a fixed axis integrates exactly by every method.
TOL_DEG = 2 * 2 * 2.0**-24 * 180 / np.pi


@pytest.mark.parametrize("kind", ["highres", "scaled"])
def test_mavlink_gyro_follows_the_sent_truth(kind):
    res = _run_with_sender(kind, method="magnus4", bias="none")
    s = res.summary
    assert s["samples"] >= 750 and s["duration_s"] == pytest.approx(3.0)  # 751 stamps, 3 s
    assert s["malformed"] >= 1  # the garbage datagram
    assert s["truth_samples_used"] > 100
    t_ms = res.t_ns / 1e6
    assert t_ms == pytest.approx(10_000 + 3000)
    assert angle_between_deg(res.q_w_b, _truth_at(t_ms)) <= TOL_DEG
    assert s["rms_error_deg"] <= TOL_DEG


def test_raw_imu_with_a_scale():
    """RAW_IMU waits 1 s for a scaled message, then takes the counts times the scale."""
    res = _run_with_sender(
        "raw", "mavlink:udpin:127.0.0.1:0?raw_gyro_scale=0.0005", method="magnus4", bias="none"
    )
    s = res.summary
    assert 0 < s["samples"] < 751  # the first second of RAW_IMU went to waiting
    t_ms = res.t_ns / 1e6
    assert angle_between_deg(res.q_w_b, _truth_at(t_ms)) <= TOL_DEG


def test_raw_imu_without_a_scale_stops_with_one_line():
    res = _run_with_sender("raw", method="magnus4", bias="none")
    assert "raw_gyro_scale" in str(res.summary["stopped"])
    assert res.summary["samples"] == 0


def test_source_strings():
    assert parse_source("mavlink:udpin:127.0.0.1:14550").kind == "mavlink"
    assert parse_url("mavlink:udpin:127.0.0.1:14550") == ("udpin", "127.0.0.1", 14550, None)
    assert parse_url("mavlink:tcp:127.0.0.1:5760?raw_gyro_scale=1e-3")[3] == 1e-3
    for bad in (
        "mavlink:serial:/dev/ttyACM0:57600",
        "mavlink:udpin:127.0.0.1",
        "mavlink:udpin::1",
        "mavlink:udpin:127.0.0.1:1?scale=2",
    ):
        with raises_naming(InputError, repr(bad), "mavlink:udpin:HOST:PORT"):
            parse_url(bad)


def test_mavlink_survives_implausible_rates_and_an_overflowing_stamp():
    # HIGHRES_IMU with 3e38 rad/s in every 50th packet (15 of 751) and one time_usec of
    # 2^64 - 1: the rates are dropped and counted as replay drops them, the stamp is a
    # malformed message, and the stream goes on to the end on the exact attitude
    res = _run_with_sender("hostile", method="magnus4", bias="none")
    s = res.summary
    assert s["dropped_implausible"] == 15
    assert s["malformed"] >= 2  # the garbage datagram and the stamp
    assert "error" not in s["stopped"] and "Overflow" not in s["stopped"]
    assert s["samples"] >= 751 - 15 - 1 - 5  # the last few may be in flight at the stop
    t_ms = res.t_ns / 1e6
    # a constant rate about a fixed axis integrates exactly over any step, dropped ones too
    assert angle_between_deg(res.q_w_b, _truth_at(t_ms)) <= TOL_DEG


@pytest.mark.parametrize("scale", ["nan", "inf", "-inf", "0", "abc"])
def test_raw_gyro_scale_that_is_no_finite_number_is_refused(scale):
    with pytest.raises(InputError, match="a finite number other than 0"):
        parse_url(f"mavlink:udpin:127.0.0.1:14550?raw_gyro_scale={scale}")


def test_a_frame_cut_at_the_end_of_its_datagram_costs_only_itself():
    # over UDP a datagram holds whole frames: the next datagram is not the cut frame's rest
    from pymavlink.dialects.v20 import common

    from imu_dcm.live.events import Malformed, Received
    from imu_dcm.live.sources.mavlink import MavlinkSource

    mav = common.MAVLink(None, srcSystem=1, srcComponent=1)

    def frame(t_us):
        return mav.highres_imu_encode(t_us, 0, 0, -9.8, *W_FRD, 0, 0, 0, 0, 0, 0, 0, 0x3F).pack(mav)

    src = MavlinkSource("mavlink:udpin:127.0.0.1:0", truth_topic="none")
    try:
        src._handle([frame(1000), frame(2000)[:20], frame(3000), frame(4000)], 0, 0)
    finally:
        src._close()
    events = []
    while not src.events.empty():
        events.append(src.events.get())
    assert Malformed(1) in events
    (data,) = [e for e in events if isinstance(e, Received)]
    assert data.t_ns.tolist() == [1_000_000, 3_000_000, 4_000_000]


def _received_imu(kind: str, raw_gyro_scale: float | None = None):
    """The IMU batch a MavlinkSource makes of two messages of ``kind`` (no socket traffic)."""
    from pymavlink.dialects.v20 import common

    from imu_dcm.live.events import Received
    from imu_dcm.live.sources.mavlink import MavlinkSource

    mav = common.MAVLink(None, srcSystem=1, srcComponent=1)
    acc_frd = (0.5, -0.25, -9.75)  # m/s², FRD: the specific force of a level body is up (-z)
    if kind == "HIGHRES_IMU":
        msgs = [
            mav.highres_imu_encode(t, *acc_frd, *W_FRD, 0, 0, 0, 0, 0, 0, 0, 0x3F) for t in (1, 2)
        ]
    elif kind == "SCALED_IMU":  # mG as int16
        mg = [round(v / 9.80665e-3) for v in acc_frd]
        msgs = [mav.scaled_imu_encode(t, *mg, 250, -125, 500, 0, 0, 0) for t in (1, 2)]
    else:
        msgs = [mav.raw_imu_encode(t, 1, 2, 3, 500, -250, 1000, 0, 0, 0) for t in (1, 2)]
    url = "mavlink:udpin:127.0.0.1:0" + (
        f"?raw_gyro_scale={raw_gyro_scale}" if raw_gyro_scale else ""
    )
    src = MavlinkSource(url, imu_topic=kind)
    try:
        src._handle([b"".join(m.pack(mav) for m in msgs)], 0, 0)
    finally:
        src.sock.close()
    events = []
    while not src.events.empty():
        events.append(src.events.get())
    (rec,) = [e for e in events if isinstance(e, Received) and e.kind == "imu"]
    return rec, acc_frd


@pytest.mark.parametrize("kind", ["HIGHRES_IMU", "SCALED_IMU"])
def test_mavlink_accelerations_come_in_m_s2_in_the_gyros_axes(kind):
    rec, acc_frd = _received_imu(kind)
    want = np.array(acc_frd) * ned.FLU_FROM_FRD  # FLU, as the rates
    tol = 0.0 if kind == "HIGHRES_IMU" else 0.5 * 9.80665e-3  # float32 exact; mG rounding
    assert rec.accel.shape == (2, 3)
    np.testing.assert_allclose(rec.accel, np.tile(want, (2, 1)), rtol=1e-6, atol=tol)
    assert rec.accel[0, 2] > 9.0  # up in FLU: +z


def test_raw_imu_counts_carry_no_accelerometer():
    rec, _acc = _received_imu("RAW_IMU", raw_gyro_scale=0.001)
    assert rec.accel is None

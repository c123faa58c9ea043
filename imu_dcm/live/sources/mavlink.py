"""Live gyro and truth from MAVLink: what a PX4 or ArduPilot vehicle, or its simulator, streams
to a ground station.

SOURCE ``mavlink:udpin:HOST:PORT`` listens for datagrams on HOST:PORT (where a vehicle or a
ground station's forward sends them); ``mavlink:tcp:HOST:PORT`` connects to a TCP server (the
simulators' ``tcp:127.0.0.1:5760``). Messages are parsed with pymavlink (MAVLink 1 and 2, CRC
checked; frames that fail are counted as malformed). pymavlink is an optional extra:
``pip install 'imu_dcm[mavlink]'``.

Gyro, the first of these to arrive, or the one ``imu_topic`` names; said in one line:

* ``HIGHRES_IMU``: ``xgyro``, ``ygyro``, ``zgyro`` in rad/s, stamped ``time_usec``;
* ``SCALED_IMU`` (``SCALED_IMU2``, ``SCALED_IMU3``): mrad/s, stamped ``time_boot_ms``;
* ``RAW_IMU``: raw counts, stamped ``time_usec``. Their unit is the sensor's, so they are taken
  only when no scaled message arrives within 1 s, and only with a scale given in rad/s per
  count: ``mavlink:udpin:HOST:PORT?raw_gyro_scale=0.001``; without one the source stops with a
  line saying so.

Accelerometer, from the gyro's message, to the rest rule: ``HIGHRES_IMU``'s ``xacc..zacc`` in
m/s², ``SCALED_IMU``'s in mG (milli g: x 9.80665e-3 m/s²); ``RAW_IMU``'s counts have no known
unit and are not taken (the gyro judges rest alone).

Truth: ``ATTITUDE_QUATERNION`` (``q1..q4`` = w, x, y, z), stamped ``time_boot_ms``; the
autopilot's own estimate. Frames: MAVLink states body rates and accelerations in FRD and
attitude FRD to NED; all are converted to body FLU and world ENU, ``[x, y, z, w]``, as the log
readers do (:mod:`imu_dcm.logio.ned`).

One bad message costs itself: a frame pymavlink cannot take, a frame cut off at the end of
its datagram (over UDP a datagram holds whole frames: the next one starts afresh, never as the
cut frame's rest), or a stamp outside 0 to 2^63 ns,
is counted as malformed and the stream goes on. Rates go on to the pipeline, which drops and
counts non-finite and implausible ones (:func:`imu_dcm.gyro.rates.implausible_rates`).
"""

from __future__ import annotations

import math
import socket
import time
from urllib.parse import parse_qs

import numpy as np

try:  # an optional extra: this module is imported only when a mavlink: SOURCE opens
    from pymavlink.dialects.v20 import common
except ImportError:
    common = None

from imu_dcm.errors import InputError
from imu_dcm.live.events import Channel, End, Info, Malformed, Received
from imu_dcm.live.sources.base import Source
from imu_dcm.logio.ned import FLU_FROM_FRD, q_enu_flu

INSTALL = "pip install 'imu_dcm[mavlink]'"
#: gyro message -> (rad/s per unit or None for raw, stamp field, ns per stamp unit)
GYRO = {
    "HIGHRES_IMU": (1.0, "time_usec", 1000),
    "SCALED_IMU": (1e-3, "time_boot_ms", 1_000_000),
    "SCALED_IMU2": (1e-3, "time_boot_ms", 1_000_000),
    "SCALED_IMU3": (1e-3, "time_boot_ms", 1_000_000),
    "RAW_IMU": (None, "time_usec", 1000),
}
#: gyro message -> m/s² per unit of its accelerations (RAW_IMU's counts: no known unit)
ACCEL = {
    "HIGHRES_IMU": 1.0,
    "SCALED_IMU": 9.80665e-3,
    "SCALED_IMU2": 9.80665e-3,
    "SCALED_IMU3": 9.80665e-3,
}
TRUTH = "ATTITUDE_QUATERNION"
RAW_WAIT_S = 1.0
#: Stamps from 0 to here (ns, int64's end) are a clock's; a message stamped outside (a
#: ``time_usec`` of 2^64 - 1) is malformed: counted, never fatal.
_STAMP_END_NS = 2**63
BATCH_S = 0.005


def parse_url(url: str) -> tuple[str, str, int, float | None]:
    """``mavlink:udpin:HOST:PORT[?raw_gyro_scale=S]`` -> (mode, host, port, scale)."""
    body = url.removeprefix("mavlink:")
    body, _, query = body.partition("?")
    mode, _, where = body.partition(":")
    host, _, port = where.rpartition(":")
    try:
        port_n = int(port)
        opts = {k: float(v[-1]) for k, v in parse_qs(query, strict_parsing=bool(query)).items()}
    except ValueError:
        port_n, opts = -1, {}
    if (
        mode not in ("udpin", "tcp")
        or not host
        or not 0 <= port_n < 65536
        or set(opts) - {"raw_gyro_scale"}
        or not all(math.isfinite(v) and v != 0.0 for v in opts.values())
    ):
        raise InputError(
            f"Expected SOURCE mavlink:udpin:HOST:PORT or mavlink:tcp:HOST:PORT "
            f"(optionally ?raw_gyro_scale=RAD_S_PER_COUNT, a finite number other than 0), "
            f"got {url!r}"
        )
    return mode, host, port_n, opts.get("raw_gyro_scale")


def _dialect():
    if common is None:
        raise InputError(f"Expected pymavlink for a mavlink: SOURCE, got none installed; {INSTALL}")
    return common


class MavlinkSource(Source):
    """MAVLink over UDP (listening) or TCP (connecting); see the module doc."""

    converts_gyro_units = True
    announces_truth = True

    @classmethod
    def open(cls, spec, options) -> MavlinkSource:
        return cls(spec.url, options.imu_topic, options.truth_topic, options.batch_s)

    def __init__(
        self,
        url: str,
        imu_topic: str | None = None,
        truth_topic: str | None = None,
        batch_s: float = BATCH_S,
    ) -> None:
        super().__init__()
        self.mode, host, port, self.raw_scale = parse_url(url)
        if imu_topic is not None and imu_topic not in GYRO:
            raise InputError(f"Expected a MAVLink gyro message in {tuple(GYRO)}, got {imu_topic!r}")
        if truth_topic not in (None, "none", TRUTH):
            raise InputError(f"Expected MAVLink truth {TRUTH} or none, got {truth_topic!r}")
        if imu_topic == "RAW_IMU" and self.raw_scale is None:
            raise InputError(
                "Expected a scale for RAW_IMU (raw counts of an unknown unit), got none: "
                "mavlink:udpin:HOST:PORT?raw_gyro_scale=RAD_S_PER_COUNT"
            )
        self.imu_topic, self.truth = imu_topic, truth_topic != "none"
        self.batch_s = batch_s
        self._new_parser()
        self.gyro_type: str | None = imu_topic
        self._raw_since: float | None = None
        kind = socket.SOCK_DGRAM if self.mode == "udpin" else socket.SOCK_STREAM
        self.sock = socket.socket(socket.AF_INET, kind)
        try:
            if self.mode == "udpin":
                self.sock.bind((host, port))
            else:
                self.sock.settimeout(5.0)
                self.sock.connect((host, port))
        except OSError as exc:
            self.sock.close()
            verb = "bind" if self.mode == "udpin" else "connect to"
            raise InputError(f"Expected to {verb} {host}:{port}, got {exc}") from None
        self.address = self.sock.getsockname()
        self.sock.settimeout(0.2)

    def _new_parser(self) -> None:
        self.mav = _dialect().MAVLink(None)
        self.mav.robust_parsing = True

    def _close(self) -> None:
        self.sock.close()

    # ---------------------------------------------------------------------- receiving
    def _run(self) -> None:
        where = f"mavlink:{self.mode}:{self.address[0]}:{self.address[1]}"
        self.events.put(Info(f"listening on {where}" if self.mode == "udpin" else where))
        if self.truth:
            self.events.put(Channel("truth", TRUTH, "", "", "", "mavlink"))
        try:
            while not self._stop.is_set():
                data = self._receive()
                if data is None:
                    return
                if data:
                    self._handle(data, time.perf_counter_ns(), time.time_ns())
                    self._stop.wait(self.batch_s)  # let the batch arrive, then take all of it
        finally:
            self.sock.close()

    def _receive(self) -> list[bytes] | None:
        """Everything that has arrived (waiting up to 0.2 s for the first); None at the end."""
        try:
            first = self.sock.recv(65536)
        except TimeoutError:
            return []
        if not first and self.mode == "tcp":
            self.events.put(End("the MAVLink TCP server closed the connection"))
            return None
        chunks = [first]
        self.sock.setblocking(False)
        try:
            while len(chunks) < 4000:
                chunks.append(self.sock.recv(65536))
        except (BlockingIOError, InterruptedError):
            pass
        finally:
            self.sock.settimeout(0.2)
        return chunks

    def _handle(self, chunks: list[bytes], arrival: int, wall: int) -> None:
        gyro: list[tuple] = []
        truth: list[tuple] = []
        bad = 0
        for chunk in chunks:
            try:
                messages = self.mav.parse_buffer(chunk) or ()
            except Exception:  # pymavlink on a frame it cannot take: that datagram only
                bad += 1
                continue
            for m in messages:
                bad += not self._take(m, gyro, truth)
            if self.mode == "udpin" and self.mav.buf_len():
                bad += 1  # a datagram holds whole frames: its cut-off end is not the next's start
                self._new_parser()
        if bad:
            self.events.put(Malformed(bad))
        if truth:
            a = np.array(truth, dtype=np.float64)
            t = np.array([r[0] for r in truth], dtype=np.int64)
            self._put("truth", t, q_enu_flu(a[:, 1:5]), arrival, wall)
        if gyro:
            a = np.array(gyro, dtype=np.float64)
            t = np.array([r[0] for r in gyro], dtype=np.int64)
            unit = ACCEL.get(self.gyro_type or "")
            accel = None if unit is None else a[:, 4:7] * (unit * FLU_FROM_FRD)
            self._put("imu", t, a[:, 1:4] * FLU_FROM_FRD, arrival, wall, accel)

    def _take(self, m, gyro: list, truth: list) -> bool:
        """One parsed message into ``gyro`` or ``truth`` rows; False for a malformed one (a bad
        frame, or a stamp no clock gives: outside 0 to 2^63 ns)."""
        name = m.get_type()
        if name == "BAD_DATA":
            return False
        if name == TRUTH:
            if self.truth:
                t = m.time_boot_ms * 1_000_000
                if not 0 <= t < _STAMP_END_NS:
                    return False
                truth.append((t, m.q1, m.q2, m.q3, m.q4))
        elif name in GYRO and self._use(name):
            unit, stamp, ns = GYRO[name]
            scale = self.raw_scale if unit is None else unit
            t = getattr(m, stamp) * ns
            if not 0 <= t < _STAMP_END_NS:
                return False
            gyro.append(
                (t, m.xgyro * scale, m.ygyro * scale, m.zgyro * scale, m.xacc, m.yacc, m.zacc)
            )
        return True

    def _put(self, kind: str, t_ns, values, arrival: int, wall: int, accel=None) -> None:
        n = len(t_ns)
        arrival_ns, wall_ns = np.full(n, arrival, np.int64), np.full(n, wall, np.int64)
        self.events.put(Received(kind, t_ns, values, arrival_ns, wall_ns, accel=accel))

    def _use(self, name: str) -> bool:
        """Whether ``name`` is the gyro: the one named, else the first scaled message to
        arrive, else RAW_IMU after RAW_WAIT_S without a scaled one (with a scale given)."""
        if self.gyro_type is not None:
            if name == self.gyro_type and name == "RAW_IMU" and self.raw_scale is None:
                self._refuse_raw()
                return False
            return name == self.gyro_type
        if GYRO[name][0] is not None:
            self._lock(name)
            return True
        now = time.monotonic()
        if self._raw_since is None:
            self._raw_since = now
        if now - self._raw_since < RAW_WAIT_S:
            return False
        if self.raw_scale is None:
            self._refuse_raw()
            return False
        self._lock(name)
        return True

    def _lock(self, name: str) -> None:
        self.gyro_type = name
        unit = "raw counts x raw_gyro_scale" if GYRO[name][0] is None else "body FRD -> FLU"
        self.events.put(Channel("imu", name, "", "", "", "mavlink"))
        self.events.put(Info(f"gyro: {name} ({unit})"))

    def _refuse_raw(self) -> None:
        if not self._stop.is_set():
            why = (
                "Expected HIGHRES_IMU or SCALED_IMU (scaled gyro), got only RAW_IMU (raw counts "
                "of an unknown unit): give its scale, "
                "mavlink:udpin:HOST:PORT?raw_gyro_scale=RAD_S_PER_COUNT"
            )
            self.events.put(End(why))
            self._stop.set()

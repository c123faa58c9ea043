"""Live sources: a Foxglove WebSocket server, UDP lines and stdin lines, each in its own thread.

A source puts events on a queue for the pipeline, in arrival order:

* ``("data", Received)`` — a batch of decoded samples (IMU rates or truth quaternions) with
  their arrival times and, from a WebSocket, the raw CDR payloads (for ``--record``);
* ``("malformed", n)`` — lines or payloads that do not parse (counted, never fatal);
* ``("info", text)`` — something to tell the user (connected, lost, reconnecting);
* ``("channel", Channel)`` — a channel was picked (topic, type, schema, for the recorder);
* ``("end", reason)`` — the source is finished (end of input, source lost, a fatal error).

**WebSocket** (``ws://HOST:PORT``): the ``foxglove.websocket.v1`` protocol of ``foxglove_bridge``
(also offered as ``foxglove.sdk.v1``, the same messages, spoken by foxglove-sdk servers): the
server advertises channels (JSON ``advertise``); the IMU and truth channels are picked by schema
as replay picks them (or by ``imu_topic`` / ``truth_topic``) and subscribed (JSON
``subscribe``); messages arrive as binary frames ``0x01 | u32 subscription | u64 log time ns |
CDR payload``. Frames arriving within 2 ms of a batch's first are decoded together (one bulk
CDR decode per batch). When the connection drops, the source reconnects with back-off (0.2 s
doubling to 5 s), says so, and gives up after ``give_up_s`` without a connection.

**UDP** (``udp://HOST:PORT``): binds the address and reads datagrams of one or more lines.
**stdin** (``-``): reads lines until end of input. Line format: :mod:`imu_dcm.live.lines`.
"""

from __future__ import annotations

import json
import os
import queue
import select
import socket
import struct
import threading
import time
from dataclasses import dataclass
from urllib.parse import urlsplit

import numpy as np
from numpy.typing import NDArray

from imu_dcm.errors import InputError
from imu_dcm.live.lines import parse_lines
from imu_dcm.logio.batch import classify_schema, decode_cdr_batch

__all__ = ["Channel", "Received", "Source", "SourceSpec", "open_source", "parse_source"]

_SUBPROTOCOLS = ("foxglove.websocket.v1", "foxglove.sdk.v1")
_BIN_MESSAGE = 0x01
_MSG_HEAD = struct.Struct("<BIQ")  # opcode, subscription id, log time ns
_DRAIN_MAX = 4000  # frames (datagrams) per batch at most
#: A batch collects what arrives within this long after its first frame, s: per-batch costs
#: (one bulk decode, one queue event) are shared by several samples at the price of <= 2 ms.
_DRAIN_S = 0.002


@dataclass(frozen=True)
class SourceSpec:
    """A parsed SOURCE argument: ``kind`` ws / udp / stdin, ``host``, ``port``, ``url``."""

    kind: str
    host: str = ""
    port: int = 0
    url: str = "-"


def parse_source(text: str) -> SourceSpec:
    """``ws://HOST:PORT``, ``udp://HOST:PORT`` or ``-`` (stdin); raises InputError otherwise."""
    if text == "-":
        return SourceSpec("stdin")
    if text.startswith("mavlink:"):  # a pymavlink-style connection: imu_dcm.live.mavlink
        return SourceSpec("mavlink", url=text)
    parts = urlsplit(text)
    try:
        port = parts.port
    except ValueError:
        port = None
    if parts.scheme not in ("ws", "udp") or not parts.hostname or port is None:
        raise InputError(
            f"Expected SOURCE ws://HOST:PORT, udp://HOST:PORT, mavlink:udpin:HOST:PORT or -, "
            f"got {text!r}"
        )
    return SourceSpec(parts.scheme, parts.hostname, port, text)


@dataclass(frozen=True)
class Channel:
    """A picked channel: ``kind`` "imu" or "truth", ``topic``, schema ``name``, ``encoding``
    and ``text`` (``ros2msg``), ``message_encoding``; line sources give ``name=""``."""

    kind: str
    topic: str
    name: str = ""
    encoding: str = ""
    text: str = ""
    message_encoding: str = "cdr"


@dataclass(frozen=True)
class Received:
    """One batch of samples as received.

    Attributes
    ----------
    kind : "imu" or "truth"
    t_ns : int64 (n,) — source stamps (``header.stamp`` / the line's stamp), ns.
    values : float64 (n, 3) rates ``omega_b`` rad/s, or (n, 4) ``q_w_b`` ``[x, y, z, w]``.
    arrival_ns : int64 (n,) — ``time.perf_counter_ns()`` when each sample arrived.
    wall_ns : int64 (n,) — wall clock (Unix ns) at arrival (the recording's log time).
    raw : list of bytes or None — the CDR payloads as received (WebSocket), aligned with t_ns.
    """

    kind: str
    t_ns: NDArray[np.int64]
    values: NDArray[np.float64]
    arrival_ns: NDArray[np.int64]
    wall_ns: NDArray[np.int64]
    raw: list[bytes] | None = None


class Source:
    """Base: a daemon thread putting events on ``events``; :meth:`stop` ends it."""

    def __init__(self) -> None:
        self.events: queue.Queue = queue.Queue()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._guarded, name=type(self).__name__, daemon=True)

    def start(self) -> Source:
        self._thread.start()
        return self

    def stop(self, timeout_s: float = 5.0) -> None:
        self._stop.set()
        if self._thread.is_alive() and threading.current_thread() is not self._thread:
            self._thread.join(timeout_s)
        elif self._thread.ident is None:
            self._close()  # never started

    def _close(self) -> None:
        """Release what the constructor opened (for a source that never started)."""

    def _guarded(self) -> None:
        try:
            self._run()
        except Exception as exc:
            self.events.put(("end", f"source failed: {type(exc).__name__}: {exc}"))

    def _run(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError


class _LineSource(Source):
    def __init__(self, gyro_units: str, time_units: str) -> None:
        super().__init__()
        self.gyro_units = gyro_units
        self.time_units = time_units
        self._first = True

    def _emit_lines(self, lines: list[bytes], arrival_ns: int, wall_ns: int) -> None:
        t, w, tt, q, bad = parse_lines(
            lines, gyro_units=self.gyro_units, time_units=self.time_units, first=self._first
        )
        self._first = False
        if bad:
            self.events.put(("malformed", bad))
        if len(tt):
            m = len(tt)
            self.events.put(
                (
                    "data",
                    Received(
                        "truth",
                        tt,
                        q,
                        np.full(m, arrival_ns, np.int64),
                        np.full(m, wall_ns, np.int64),
                    ),
                )
            )
        if len(t):
            n = len(t)
            self.events.put(
                (
                    "data",
                    Received(
                        "imu", t, w, np.full(n, arrival_ns, np.int64), np.full(n, wall_ns, np.int64)
                    ),
                )
            )


class UdpSource(_LineSource):
    """Datagrams of sample lines on ``host:port`` (bound on start)."""

    def __init__(self, host: str, port: int, gyro_units: str, time_units: str) -> None:
        super().__init__(gyro_units, time_units)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
        try:
            self.sock.bind((host, port))
        except OSError as exc:
            self.sock.close()
            raise InputError(f"Expected to bind udp://{host}:{port}, got {exc}") from None
        self.address = self.sock.getsockname()
        self.sock.settimeout(0.2)

    def _close(self) -> None:
        self.sock.close()

    def _run(self) -> None:
        where = f"udp://{self.address[0]}:{self.address[1]}"
        self.events.put(("channel", Channel("imu", where, "", "", "", "lines")))
        self.events.put(("info", f"listening on {where}"))
        try:
            while not self._stop.is_set():
                try:
                    data = self.sock.recv(65536)
                except TimeoutError:
                    continue
                arrival, wall = time.perf_counter_ns(), time.time_ns()
                chunks = [data]
                t_end = time.perf_counter() + _DRAIN_S
                try:
                    while len(chunks) < _DRAIN_MAX:
                        left = t_end - time.perf_counter()
                        if left <= 0:
                            break
                        self.sock.settimeout(left)
                        chunks.append(self.sock.recv(65536))
                except (TimeoutError, BlockingIOError, InterruptedError):
                    pass
                finally:
                    self.sock.settimeout(0.2)
                self._emit_lines(b"\n".join(chunks).split(b"\n"), arrival, wall)
        finally:
            self.sock.close()


class StdinSource(_LineSource):
    """Sample lines from a file descriptor (stdin by default) until end of input."""

    def __init__(self, gyro_units: str, time_units: str, fd: int | None = None) -> None:
        super().__init__(gyro_units, time_units)
        self.fd = 0 if fd is None else fd

    def _run(self) -> None:
        self.events.put(("channel", Channel("imu", "stdin", "", "", "", "lines")))
        rest = b""
        while not self._stop.is_set():
            ready, _, _ = select.select([self.fd], [], [], 0.2)
            if not ready:
                continue
            data = os.read(self.fd, 1 << 16)
            arrival, wall = time.perf_counter_ns(), time.time_ns()
            if not data:
                if rest:
                    self._emit_lines([rest], arrival, wall)
                self.events.put(("end", "end of input"))
                return
            lines = (rest + data).split(b"\n")
            rest = lines.pop()
            if lines:
                self._emit_lines(lines, arrival, wall)


class WsSource(Source):
    """A Foxglove WebSocket client (see the module doc)."""

    def __init__(
        self,
        url: str,
        imu_topic: str | None,
        truth_topic: str | None,
        give_up_s: float | None = 30.0,
    ) -> None:
        super().__init__()
        self.url = url
        self.imu_topic = imu_topic
        self.truth_topic = truth_topic
        self.give_up_s = give_up_s
        self.reconnects = 0

    def _run(self) -> None:
        from websockets.exceptions import ConnectionClosed, InvalidHandshake, InvalidURI
        from websockets.sync.client import connect

        delay = 0.2
        lost_at = time.monotonic()
        ever = False
        while not self._stop.is_set():
            why = ""
            try:
                with connect(
                    self.url,
                    subprotocols=list(_SUBPROTOCOLS),
                    max_size=None,
                    compression=None,
                    proxy=None,
                    open_timeout=5,
                    close_timeout=1,
                ) as ws:
                    if ever:
                        self.reconnects += 1
                        self.events.put(("info", (f"reconnected to {self.url} ({ws.subprotocol})")))
                    else:
                        self.events.put(("info", f"connected to {self.url} ({ws.subprotocol})"))
                    ever = True
                    delay = 0.2
                    fatal = self._session(ws)
                    if fatal:
                        self.events.put(("end", fatal))
                        return
                    if self._stop.is_set():
                        return
                    why = "the server closed the connection"
            except InvalidURI as exc:
                self.events.put(("end", f"bad WebSocket URL: {exc}"))
                return
            except ConnectionClosed as exc:
                why = f"connection lost ({exc})"
            except (OSError, InvalidHandshake, TimeoutError) as exc:
                why = f"cannot connect ({type(exc).__name__}: {exc})"
            if self._stop.is_set():
                return
            if why.startswith(("connection lost", "the server")):
                lost_at = time.monotonic()
            waited = time.monotonic() - lost_at
            if self.give_up_s is not None and waited > self.give_up_s:
                self.events.put(
                    (
                        "end",
                        (f"source lost: no connection to {self.url} for {waited:.1f} s ({why})"),
                    )
                )
                return
            self.events.put(("info", f"{why}; reconnecting to {self.url} in {delay:.1f} s"))
            self._stop.wait(delay)
            delay = min(2 * delay, 5.0)

    def _pick(self, channels: dict[int, dict], kind: str, topic: str | None) -> list[int]:
        out = []
        for cid, ch in channels.items():
            if topic is not None:
                if ch["topic"] == topic:
                    out.append(cid)
                continue
            if ch["kind"] is not None and ch["kind"][0] == kind:
                if kind == "truth" and ch["topic"].startswith("/estimate"):
                    continue
                out.append(cid)
        return out

    def _session(self, ws) -> str | None:
        """One connection: subscribe, receive, decode. Returns a fatal reason or None."""
        channels: dict[int, dict] = {}
        subs: dict[int, tuple[str, dict]] = {}  # subscription id -> (kind, channel)
        picked: dict[str, int] = {}  # kind -> channel id
        pending: dict[int, list] = {}
        next_sub = 1
        while not self._stop.is_set():
            try:
                first = ws.recv(timeout=0.2)
            except TimeoutError:
                continue
            frames = [(first, time.perf_counter_ns(), time.time_ns())]
            t_end = time.perf_counter() + _DRAIN_S
            while len(frames) < _DRAIN_MAX:
                left = t_end - time.perf_counter()
                if left <= 0:
                    break
                try:
                    frames.append((ws.recv(timeout=left), time.perf_counter_ns(), time.time_ns()))
                except TimeoutError:
                    break
            for data, arrival, wall in frames:
                if isinstance(data, str):
                    msg = json.loads(data)
                    op = msg.get("op") if isinstance(msg, dict) else None
                    if op == "advertise":
                        for ch in msg.get("channels", []):
                            enc = ch.get("schemaEncoding", "")
                            text = ch.get("schema", "")
                            kind = (
                                classify_schema(ch.get("schemaName", ""), enc, text)
                                if ch.get("encoding") == "cdr"
                                else None
                            )
                            channels[int(ch["id"])] = {**ch, "kind": kind}
                        for kind, topic in (("imu", self.imu_topic), ("truth", self.truth_topic)):
                            if kind in picked or topic == "none":
                                continue
                            ids = self._pick(channels, kind, topic)
                            if topic is not None and ids:
                                ch = channels[ids[0]]
                                if ch["kind"] is None or ch["kind"][0] != kind:
                                    return (
                                        f"Expected {kind} messages (CDR) on {topic}, got "
                                        f"{ch.get('schemaName')} ({ch.get('encoding')})"
                                    )
                            if len(ids) > 1:
                                names = ", ".join(sorted(channels[i]["topic"] for i in ids))
                                flag = "--imu-topic" if kind == "imu" else "--truth-topic"
                                return (
                                    f"Expected one {kind} channel, got {len(ids)}: {names} "
                                    f"(choose with {flag})"
                                )
                            if ids:
                                cid = ids[0]
                                ch = channels[cid]
                                picked[kind] = cid
                                subs[next_sub] = (kind, ch)
                                ws.send(
                                    json.dumps(
                                        {
                                            "op": "subscribe",
                                            "subscriptions": [{"id": next_sub, "channelId": cid}],
                                        }
                                    )
                                )
                                next_sub += 1
                                self.events.put(
                                    (
                                        "channel",
                                        Channel(
                                            kind,
                                            ch["topic"],
                                            ch.get("schemaName", ""),
                                            ch.get("schemaEncoding", ""),
                                            ch.get("schema", ""),
                                            "cdr",
                                        ),
                                    )
                                )
                                self.events.put(
                                    (
                                        "info",
                                        (
                                            f"subscribed to {ch['topic']} "
                                            f"({ch.get('schemaName')}) as {kind}"
                                        ),
                                    )
                                )
                    elif op == "unadvertise":
                        gone = set(msg.get("channelIds", []))
                        for kind, cid in list(picked.items()):
                            if cid in gone:
                                del picked[kind]
                                self.events.put(
                                    ("info", (f"{channels[cid]['topic']} was unadvertised"))
                                )
                        for sid, (_, ch) in list(subs.items()):
                            if int(ch["id"]) in gone:
                                del subs[sid]
                elif len(data) >= _MSG_HEAD.size and data[0] == _BIN_MESSAGE:
                    _, sid, _ = _MSG_HEAD.unpack_from(data)
                    if sid in subs:
                        pending.setdefault(sid, []).append((data[_MSG_HEAD.size :], arrival, wall))
            for sid, items in pending.items():
                if items and sid in subs:
                    self._decode(subs[sid], items)
            pending.clear()
        return None

    def _decode(self, sub: tuple[str, dict], items: list) -> None:
        kind, ch = sub
        payloads = [p for p, _, _ in items]
        dec = decode_cdr_batch(
            ch["kind"],
            ch.get("schemaName", ""),
            ch.get("schemaEncoding", ""),
            ch.get("schema", ""),
            payloads,
            ch["topic"],
        )
        bad = int(len(payloads) - dec.good.sum())
        if bad:
            self.events.put(("malformed", bad))
        if len(dec.t_ns):
            g = np.flatnonzero(dec.good)
            arrival = np.fromiter((items[i][1] for i in g), np.int64, len(g))
            wall = np.fromiter((items[i][2] for i in g), np.int64, len(g))
            raw = [payloads[i] for i in g]
            self.events.put(("data", Received(kind, dec.t_ns, dec.values, arrival, wall, raw)))


def open_source(
    spec: SourceSpec,
    *,
    imu_topic: str | None = None,
    truth_topic: str | None = None,
    gyro_units: str = "rad/s",
    time_units: str = "s",
    give_up_s: float | None = 30.0,
    stdin_fd: int | None = None,
) -> Source:
    """Create (not start) the source for ``spec``."""
    if spec.kind == "ws":
        return WsSource(spec.url, imu_topic, truth_topic, give_up_s)
    if spec.kind == "udp":
        return UdpSource(spec.host, spec.port, gyro_units, time_units)
    if spec.kind == "mavlink":
        from imu_dcm.live.mavlink import MavlinkSource

        return MavlinkSource(spec.url, imu_topic, truth_topic)
    return StdinSource(gyro_units, time_units, stdin_fd)

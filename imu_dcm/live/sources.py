"""Live sources: a Foxglove WebSocket server, UDP lines and stdin lines, each in its own thread.

A source puts events on a queue for the pipeline, in arrival order:

* ``("raw", key, items)`` — what a wake-up read, not yet decoded (lines, CDR payloads) with
  its arrival time: the session's loop hands every item of a key queued since its last wake-up
  to :meth:`Source.decode` at once, which returns the events below;
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
CDR payload``. The client (:class:`WsConnection`) runs under the source thread's own socket
loop (websockets' Sans-I/O protocol for the handshake and the control frames; the data frames
split by the client); the messages queued between two wake-ups of the session's loop are
decoded together (one bulk CDR decode per channel). When the connection drops, the source
reconnects with back-off (0.2 s doubling to 5 s), says so, and gives up after ``give_up_s``
without a connection.

**UDP** (``udp://HOST:PORT``): binds the address and reads datagrams of one or more lines.
**stdin** (``-``): reads lines until end of input. Line format: :mod:`imu_dcm.live.lines`.

Each wake-up of a source takes everything that has arrived by then (the datagrams queued on the
socket, the bytes in the pipe, the frames received) and queues it raw: a source thread wakes at
most every ``batch_s`` (the session uses a quarter of the view interval, at most 20 ms) and only
reads; the parse or decode runs once per wake-up of the session's loop (once per view interval)
over everything queued, so its fixed cost is shared by all the samples in between. With a view
interval of 25 ms or more the session reads a pollable source (UDP, stdin, WebSocket:
:attr:`Source.pollable`) itself, once per wake-up of its loop (:meth:`Source.begin`,
:meth:`Source.poll`; a WebSocket source's thread then only connects and reconnects): one
thread wakes per interval, not two.

**A new source** is one :class:`Source` subclass and one row in :data:`SOURCES` (the URL scheme
and ``"module:Class"``, imported when a SOURCE of that scheme is opened).
"""

from __future__ import annotations

import importlib
import json
import os
import queue
import select
import socket
import struct
import sys
import threading
import time
from dataclasses import dataclass, field
from urllib.parse import urlsplit

import numpy as np
from numpy.typing import NDArray

from imu_dcm.errors import InputError
from imu_dcm.live.lines import parse_csv_blob, parse_lines
from imu_dcm.logio.ros.payload import classify_schema, decode_cdr_batch

__all__ = [
    "SOURCES",
    "Channel",
    "Received",
    "Source",
    "SourceOptions",
    "SourceSpec",
    "open_source",
    "parse_source",
]

_SUBPROTOCOLS = ("foxglove.websocket.v1", "foxglove.sdk.v1")
_BIN_MESSAGE = 0x01
#: The binary opcodes a Foxglove server sends: message data, time, service call response,
#: fetch asset response (any other is no message of the protocol).
_BIN_SERVER_OPS = frozenset({0x01, 0x02, 0x03, 0x04})
_MSG_HEAD = struct.Struct("<BIQ")  # opcode, subscription id, log time ns
_DRAIN_MAX = 4000  # frames (datagrams) per batch at most
#: A batch collects what arrives within this long after its first sample, s (default): per-batch
#: costs (one bulk parse or decode, one queue event) are shared by the samples of a few ms.
BATCH_S = 0.005
#: SOURCE URL scheme -> the Source class that reads it, as ``"module:Class"`` (imported on
#: open). ``-`` is stdin. A new source: one class and one row here.
SOURCES: dict[str, str] = {
    "ws": "imu_dcm.live.sources:WsSource",
    "udp": "imu_dcm.live.sources:UdpSource",
    "-": "imu_dcm.live.sources:StdinSource",
    "mavlink": "imu_dcm.live.mavlink:MavlinkSource",
}


@dataclass(frozen=True)
class SourceSpec:
    """A parsed SOURCE argument: ``kind`` (the :data:`SOURCES` scheme; ``stdin`` for ``-``),
    ``host``, ``port``, ``url``."""

    kind: str
    host: str = ""
    port: int = 0
    url: str = "-"


@dataclass(frozen=True)
class SourceOptions:
    """What a source may need besides its URL (each source reads the fields it uses).

    Attributes
    ----------
    imu_topic, truth_topic : str or None — channel choices (``truth_topic="none"``: no truth).
    gyro_units : "rad/s" or "deg/s" — unit of the rates the source delivers.
    time_units : "s", "ms", "us" or "ns" — unit of line stamps.
    give_up_s : float or None — stop after this long without a connection, s.
    stdin_fd : int or None — file descriptor of ``-`` (default 0).
    batch_s : float — a wake-up collects what arrives within this long, s.
    """

    imu_topic: str | None = None
    truth_topic: str | None = None
    gyro_units: str = "rad/s"
    time_units: str = "s"
    give_up_s: float | None = 30.0
    stdin_fd: int | None = None
    batch_s: float = BATCH_S


#: ``SO_RXQ_OVFL`` (Linux): each datagram read carries the socket's count of dropped datagrams.
_SO_RXQ_OVFL = getattr(socket, "SO_RXQ_OVFL", 40)
_OVFL_SPACE = socket.CMSG_SPACE(4) if hasattr(socket, "CMSG_SPACE") else 0


def _enable_drop_count(sock: socket.socket) -> bool:
    """Ask the system to tell the socket's drop count with each datagram (Linux); False where
    it cannot."""
    if not _OVFL_SPACE or not sys.platform.startswith("linux"):
        return False
    try:
        sock.setsockopt(socket.SOL_SOCKET, _SO_RXQ_OVFL, 1)
    except OSError:
        return False
    return True


#: A stdin line longer than this (bytes, no line end) is dropped as malformed, not kept whole.
MAX_LINE_BYTES = 1 << 16
#: The receive buffer a UDP source asks for, bytes (the system caps it at ``net.core.rmem_max``).
UDP_RCVBUF = 4 << 20


def _proc_udp_row(inode: int) -> list[str] | None:
    """The row of the UDP socket with ``inode`` in ``/proc/net/udp`` (or ``udp6``), as cells, or
    None where there is no such file or row (not Linux)."""
    key = f" {inode} "
    for name in ("/proc/net/udp", "/proc/net/udp6"):
        try:
            with open(name) as f:
                text = f.read()
        except OSError:
            continue
        at = text.find(key)
        while at >= 0:  # the inode's column (the 10th), not a number elsewhere in a row
            row = text[text.rfind("\n", 0, at) + 1 : text.find("\n", at)].split()
            if len(row) >= 13 and row[9] == str(inode):
                return row
            at = text.find(key, at + 1)
    return None


def _proc_udp_drops(inode: int) -> int | None:
    """The ``drops`` count of the UDP socket with ``inode`` (``/proc/net/udp``), or None."""
    row = _proc_udp_row(inode)
    return None if row is None else int(row[12])


def _proc_udp_queue(inode: int) -> int | None:
    """The bytes queued on the UDP socket with ``inode`` (``rx_queue``, the buffer's use as the
    system counts it against ``SO_RCVBUF``), or None."""
    row = _proc_udp_row(inode)
    return None if row is None else int(row[4].partition(":")[2], 16)


def _pipe_size(fd: int) -> int | None:
    """The bytes the pipe ``fd`` holds (Linux ``F_GETPIPE_SZ``; 64 KiB elsewhere), or None when
    ``fd`` is not a pipe."""
    import stat

    try:
        if not stat.S_ISFIFO(os.fstat(fd).st_mode):
            return None
    except OSError:
        return None
    try:
        import fcntl

        return int(fcntl.fcntl(fd, getattr(fcntl, "F_GETPIPE_SZ", 1032)))
    except (ImportError, OSError):
        return 65536


def _readable(fd, timeout_s: float) -> bool:
    """Whether ``fd`` (a socket or a file descriptor) has something to read within
    ``timeout_s``."""
    return bool(select.select([fd], [], [], timeout_s)[0])


def parse_source(text: str) -> SourceSpec:
    """``SCHEME://HOST:PORT`` for a scheme of :data:`SOURCES`, or ``-`` (stdin); raises
    InputError otherwise."""
    if text == "-":
        return SourceSpec("stdin")
    if text.startswith("mavlink:"):  # a pymavlink-style connection: imu_dcm.live.mavlink
        return SourceSpec("mavlink", url=text)
    parts = urlsplit(text)
    try:
        port = parts.port
    except ValueError:
        port = None
    if parts.scheme not in SOURCES or parts.scheme == "-" or not parts.hostname or port is None:
        forms = ", ".join(
            "mavlink:udpin:HOST:PORT" if k == "mavlink" else f"{k}://HOST:PORT"
            for k in SOURCES
            if k != "-"
        )
        raise InputError(f"Expected SOURCE {forms} or -, got {text!r}")
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
    """Base: a daemon thread putting events on ``events``; :meth:`stop` ends it.

    A subclass sets the class attributes below and implements :meth:`open` and :meth:`_run`.
    """

    #: The source converts rates to rad/s itself (else the session scales them by the units).
    converts_gyro_units: bool = False
    #: Truth arrives on a channel the source announces (``("channel", Channel("truth", ...))``):
    #: the pipeline may wait for it; else truth comes inline with the samples, or not at all.
    announces_truth: bool = False

    @classmethod
    def open(cls, spec: SourceSpec, options: SourceOptions) -> Source:
        """Create (not start) the source for ``spec``."""
        raise NotImplementedError

    def __init__(self) -> None:
        self.events: queue.Queue = queue.Queue()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._guarded, name=type(self).__name__, daemon=True)
        self._read_at: tuple[int, int] | None = None  # the last inline read (perf, wall ns)
        #: Set by a read that found the system's buffer filling (the reader should come
        #: sooner: a full buffer loses datagrams or blocks the writer).
        self.crowded = False
        #: How full the system's buffer was at the last read, 0 to 1 (None: not known), and
        #: whether a read has found anything yet: the session's loop sets its cadence from
        #: them (:meth:`imu_dcm.live.session._Loop._cadence`).
        self.fill: float | None = None
        self.flowing = False
        #: Datagrams the system dropped because its buffer was full (UDP, where it tells).
        self.lost = 0
        self._said: set[str] = set()

    def drop(self, what: str, text: str) -> None:
        """A bad message dropped: counted as malformed, said once per kind ``what``."""
        self.events.put(("malformed", 1))
        if what not in self._said:
            self._said.add(what)
            self.events.put(("info", f"dropped {text} (counted as malformed; said once)"))

    def _await(self, ready, batch_s: float) -> tuple[int, int] | None:
        """Wait for a batch to read: ``(arrival_ns, wall_ns)`` of its first bytes, or None when
        nothing came (within 0.2 s). ``ready(timeout_s)`` says whether there is something to
        read; the rest of the batch is given ``batch_s`` after its first bytes."""
        if not ready(0.2):
            return None
        got = time.perf_counter_ns(), time.time_ns()
        self._stop.wait(batch_s)
        return got

    #: The session's loop may watch the source for its first bytes (:meth:`ready`).
    watchable: bool = False

    #: The session's loop may read the source itself (:meth:`begin`, then :meth:`poll` once
    #: per wake-up) instead of its thread: one wake-up per interval, not two.
    pollable: bool = False

    def begin(self) -> None:
        """Read inline instead of in a thread: the events a thread puts before its first read."""
        raise NotImplementedError

    def poll(self) -> None:
        """Inline: read what has arrived by now, without waiting (the session's loop calls it
        once per wake-up). The bytes' arrival is taken as the previous poll's time, the
        earliest they can have come (a latency measured from it is an upper bound)."""
        since = self._read_at or (time.perf_counter_ns(), time.time_ns())
        self._read_at = time.perf_counter_ns(), time.time_ns()
        if self._ready(0.0):
            self._read(*since)

    def _ready(self, timeout_s: float) -> bool:
        """Whether there is something to read within ``timeout_s`` (a pollable source)."""
        raise NotImplementedError

    def _read(self, arrival_ns: int, wall_ns: int) -> bool:
        """Read what is there and queue it (a pollable source); False once the source ended."""
        raise NotImplementedError

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

    def decode(self, key, items: list) -> list[tuple]:
        """The ``data`` and ``malformed`` events of raw items the thread queued as
        ``("raw", key, items)``: called by the session's loop once per key and wake-up with every
        item of that key in arrival order, so the decode's fixed cost is shared by all of them."""
        raise NotImplementedError

    def _guarded(self) -> None:
        try:
            self._run()
        except Exception as exc:
            why = f"the source stopped on an error it cannot recover from ({type(exc).__name__})"
            self.events.put(("end", why))

    def _run(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError


class _LineSource(Source):
    converts_gyro_units = True
    #: The session's loop may watch it for its first bytes (:meth:`ready`).
    watchable = True

    def ready(self, timeout_s: float) -> bool:
        """Whether there is something to read within ``timeout_s``."""
        return self._ready(timeout_s)

    def __init__(self, gyro_units: str, time_units: str, batch_s: float = BATCH_S) -> None:
        super().__init__()
        self.gyro_units = gyro_units
        self.time_units = time_units
        self.batch_s = batch_s
        self._first = True

    pollable = True

    def _run(self) -> None:
        self.begin()
        try:
            while not self._stop.is_set():
                got = self._await(self._ready, self.batch_s)
                if got is not None and not self._read(*got):
                    return
        finally:
            self._close()

    def decode(self, key, items: list) -> list[tuple]:
        """Items ``(blob, arrival_ns, wall_ns)``, ``blob`` whole lines: plain CSV lines in one
        pass over each blob (:func:`parse_csv_blob`), else line by line (:func:`parse_lines`)."""
        out: list[tuple] = []
        for blob, arrival_ns, wall_ns in items:
            bulk = None
            if not self._first:
                bulk = parse_csv_blob(blob, gyro_units=self.gyro_units, time_units=self.time_units)
            if bulk is None:
                lines = [ln for ln in blob.split(b"\n") if ln.strip()]
                out.extend(self._each(lines, arrival_ns, wall_ns))
                continue
            t, w, bad = bulk
            if bad:
                out.append(("malformed", bad))
            if len(t):
                n = len(t)
                arrival, wall = np.full(n, arrival_ns, np.int64), np.full(n, wall_ns, np.int64)
                out.append(("data", Received("imu", t, w, arrival, wall)))
        return out

    def _each(self, lines: list[bytes], arrival_ns: int, wall_ns: int) -> list[tuple]:
        t, w, tt, q, bad = parse_lines(
            lines, gyro_units=self.gyro_units, time_units=self.time_units, first=self._first
        )
        self._first = self._first and not lines
        out: list[tuple] = [("malformed", bad)] if bad else []
        for kind, stamps, values in (("truth", tt, q), ("imu", t, w)):
            if len(stamps):
                n = len(stamps)
                arrival = np.full(n, arrival_ns, np.int64)
                wall = np.full(n, wall_ns, np.int64)
                out.append(("data", Received(kind, stamps, values, arrival, wall)))
        return out


class UdpSource(_LineSource):
    """Datagrams of sample lines on ``host:port`` (bound on open)."""

    @classmethod
    def open(cls, spec: SourceSpec, options: SourceOptions) -> UdpSource:
        return cls(spec.host, spec.port, options.gyro_units, options.time_units, options.batch_s)

    def __init__(
        self, host: str, port: int, gyro_units: str, time_units: str, batch_s: float = BATCH_S
    ) -> None:
        super().__init__(gyro_units, time_units, batch_s)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, UDP_RCVBUF)
        try:
            self.sock.bind((host, port))
        except OSError as exc:
            self.sock.close()
            raise InputError(f"Expected to bind udp://{host}:{port}, got {exc}") from None
        self.address = self.sock.getsockname()
        self._room = 4  # datagrams the receive buffer holds at least (set by begin)
        self._got = 0  # datagrams the last read took
        self._rcvbuf, self._inode = 1 << 20, 0  # set by begin
        self._measure = False  # read inline: measure the buffer's use at each read
        self._ovfl = _enable_drop_count(self.sock)

    def _close(self) -> None:
        """At the end: read what the socket still holds, take the system's final count of the
        datagrams it dropped (those after the last one read tell nobody else), then close."""
        try:
            self.sock.setblocking(False)
            at = self._read_at or (time.perf_counter_ns(), time.time_ns())
            while self._read(*at) and self._got >= _DRAIN_MAX:
                pass
            self._count_final_drops()
        except OSError:
            pass
        finally:
            self.sock.close()

    def _count_final_drops(self) -> None:
        """The socket's drop count from ``/proc/net/udp`` (Linux: the ``drops`` column of the
        row of this socket's inode), said as a rise is said."""
        drops = _proc_udp_drops(os.fstat(self.sock.fileno()).st_ino)
        if drops is not None and drops > self.lost:
            self._say_lost(drops)

    def begin(self) -> None:
        where = f"udp://{self.address[0]}:{self.address[1]}"
        self.events.put(("channel", Channel("imu", where, "", "", "", "lines")))
        self.events.put(("info", f"listening on {where}"))
        self.sock.setblocking(False)
        # a small datagram takes ~0.8 KB of the buffer (the system's bookkeeping with it)
        self._rcvbuf = self.sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
        self._room = max(4, self._rcvbuf // 1024)
        ino = os.fstat(self.sock.fileno()).st_ino
        self._inode = ino if _proc_udp_row(ino) is not None else 0

    def _ready(self, timeout_s: float) -> bool:
        return _readable(self.sock, timeout_s)

    def poll(self) -> None:
        """Inline (see :meth:`Source.poll`): each read also measures the buffer's use (the
        loop's cadence follows it; a thread's read, 2.5 ms after the first bytes, needs none)."""
        self._measure = True
        super().poll()

    def _read(self, arrival_ns: int, wall_ns: int) -> bool:
        queued = _proc_udp_queue(self._inode) if self._inode and self._measure else None
        chunks: list[bytes] = []
        last = None  # the last datagram's ancillary data: the system's drop count then
        most = max(_DRAIN_MAX, 2 * self._room)  # all the buffer can hold, and what came since
        try:
            while len(chunks) < most:
                if self._ovfl:
                    data, anc, _, _ = self.sock.recvmsg(65536, _OVFL_SPACE)
                    last = anc or last
                else:
                    data = self.sock.recv(65536)
                chunks.append(data)
        except (BlockingIOError, InterruptedError):
            pass
        if chunks:  # parsed by the session's loop (decode), with the other items
            self.events.put(("raw", "lines", [(b"\n".join(chunks), arrival_ns, wall_ns)]))
        self._got = len(chunks)
        self.flowing |= bool(chunks)
        # the buffer's use before the read (the system's own count, /proc/net/udp), or from
        # the datagrams read at a conservative ~1 KB each
        self.fill = queued / self._rcvbuf if queued is not None else len(chunks) / self._room
        self.crowded = self.fill >= 0.25
        if last:
            self._count_drops(last)
        return True

    def _count_drops(self, anc: list) -> None:
        """The system's count of datagrams dropped on this socket (``SO_RXQ_OVFL``): say each
        rise, once."""
        for level, kind, data in anc:
            if level == socket.SOL_SOCKET and kind == _SO_RXQ_OVFL and len(data) >= 4:
                lost = int.from_bytes(data[:4], sys.byteorder)
                if lost > self.lost:
                    self.crowded = True
                    self._say_lost(lost)

    def _say_lost(self, lost: int) -> None:
        why = (
            f"udp: the system dropped {lost - self.lost} datagram(s) (its receive "
            f"buffer was full; {lost} in all): samples were lost"
        )
        self.events.put(("info", why))
        self.lost = lost


class StdinSource(_LineSource):
    """Sample lines from a file descriptor (stdin by default) until end of input."""

    @classmethod
    def open(cls, spec: SourceSpec, options: SourceOptions) -> StdinSource:
        return cls(options.gyro_units, options.time_units, options.stdin_fd, options.batch_s)

    def __init__(
        self, gyro_units: str, time_units: str, fd: int | None = None, batch_s: float = BATCH_S
    ) -> None:
        super().__init__(gyro_units, time_units, batch_s)
        self.fd = 0 if fd is None else fd
        self._rest = b""  # a line not yet ended
        self._skipping = False  # the rest of a line too long to keep
        self._room = _pipe_size(self.fd)  # bytes a pipe holds (None: not a pipe)

    def begin(self) -> None:
        self.events.put(("channel", Channel("imu", "stdin", "", "", "", "lines")))

    def _ready(self, timeout_s: float) -> bool:
        return _readable(self.fd, timeout_s)

    def _read(self, arrival_ns: int, wall_ns: int) -> bool:
        data = os.read(self.fd, 1 << 20)
        # a pipe half full or more: its writer would soon block (a datagram socket, which
        # loses rather than blocks, asks for a reader sooner, at a quarter)
        self.fill = None if self._room is None else min(1.0, len(data) / self._room)
        self.flowing |= bool(data)
        self.crowded = self._room is not None and len(data) >= self._room // 2
        if not data:
            if self._rest:
                self.events.put(("raw", "lines", [(self._rest, arrival_ns, wall_ns)]))
                self._rest = b""
            self.events.put(("end", "end of input"))
            return False
        buf = self._rest + data
        if self._skipping:  # the rest of a line dropped as too long, up to its end
            _, end, buf = buf.partition(b"\n")
            self._skipping = not end
        whole, newline, self._rest = buf.rpartition(b"\n")
        if newline:  # parsed by the session's loop (decode), with the other items
            self.events.put(("raw", "lines", [(whole, arrival_ns, wall_ns)]))
        if len(self._rest) > MAX_LINE_BYTES:  # no line end in sight: memory stays bounded
            self._rest, self._skipping = b"", True
            self.drop("long-line", f"a line longer than {MAX_LINE_BYTES} bytes")
        return True


class WsConnection:
    """A WebSocket client connection under this thread's own socket loop (no second thread, no
    hand-over per frame): websockets' Sans-I/O protocol for the opening handshake, the control
    frames (pings answered, the close handshake completed) and what it sends; the server's data
    frames split here, a few bytes operations per frame instead of websockets' parser.

    :meth:`recv_messages` waits for the first bytes, then takes every frame that has arrived by
    then in one ``recv``: the framing costs per wake-up, not per message (measured against
    ``websockets.sync.client``, whose reader thread hands over every frame:
    ``python -m benchmarks.live_speed --ws-clients``). Fragmented messages are assembled; a frame
    that is not plain data from a server (masked, reserved bits or opcodes) goes to websockets,
    which fails the connection. Raises ``ConnectionClosed`` when the connection ends,
    ``InvalidHandshake`` / ``OSError`` / ``TimeoutError`` when it cannot open.
    """

    def __init__(self, url: str, subprotocols: tuple[str, ...], open_timeout_s: float = 5.0):
        from websockets.client import ClientProtocol
        from websockets.protocol import State
        from websockets.uri import parse_uri

        uri = parse_uri(url)
        if uri.secure:
            raise OSError("Expected ws:// (loopback, no TLS), got wss://")
        self._open = State.OPEN
        self._eof = False
        self._buf = b""  # the server's bytes after the handshake, not yet a whole frame
        self._parts: list[bytes] = []
        self._text = False
        self._proto = ClientProtocol(uri, subprotocols=list(subprotocols), max_size=None)
        self._sock = socket.create_connection((uri.host, uri.port), timeout=open_timeout_s)
        try:
            self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._proto.send_request(self._proto.connect())
            self._flush()
            self._handshake(time.monotonic() + open_timeout_s)
        except BaseException:
            self._sock.close()
            raise
        self._sock.setblocking(False)
        self.subprotocol = self._proto.subprotocol

    def _handshake(self, deadline: float) -> None:
        """Read the server's response into websockets up to its end; the frames that came
        with it stay in the buffer (split by :meth:`_messages`)."""
        buf = b""
        whole = False  # not a 101 response: websockets reads the rest (its body) itself
        while self._proto.state is not self._open:
            self._sock.settimeout(max(0.001, deadline - time.monotonic()))
            data = self._sock.recv(1 << 16)
            if not data or whole:
                self._feed(data)
            else:
                buf += data
                end = buf.find(b"\r\n\r\n")
                if end >= 0:
                    self._proto.receive_data(buf[: end + 4])
                    buf, whole = buf[end + 4 :], True
                    if self._proto.state is not self._open and buf:
                        self._proto.receive_data(buf)
            if self._proto.handshake_exc is not None:
                raise self._proto.handshake_exc
        self._buf = buf
        self._fresh = bool(buf)  # (later, the buffer holds at most part of a frame)

    def _flush(self) -> None:
        out = self._proto.data_to_send()
        if out:
            self._sock.setblocking(True)
            for chunk in out:
                if chunk:
                    self._sock.sendall(chunk)
                else:
                    self._sock.shutdown(socket.SHUT_WR)
            self._sock.setblocking(False)

    def _feed(self, data: bytes) -> None:
        if data:
            self._proto.receive_data(data)
        else:
            self._eof = True
            self._proto.receive_eof()

    def _read_all(self) -> None:
        """Everything the socket holds, into the buffer; ``_eof`` on EOF or reset (told to
        websockets once the frames before it are handled)."""
        chunks = [self._buf] if self._buf else []
        try:
            while not self._eof:
                data = self._sock.recv(1 << 20)
                if not data:
                    self._eof = True
                chunks.append(data)
        except (BlockingIOError, InterruptedError):
            pass
        except OSError:
            self._eof = True
        self._buf = chunks[0] if len(chunks) == 1 else b"".join(chunks)

    def _messages(self) -> list[str | bytes]:
        """The whole messages in the buffer; control frames (and anything but plain data)
        handed to websockets, whose answers :meth:`_flush` sends."""
        buf, pos, out, control = self._buf, 0, [], False
        n = len(buf)
        while n - pos >= 2:
            b0, b1 = buf[pos], buf[pos + 1]
            size, head = b1 & 0x7F, 2
            if size >= 126:
                head = 4 if size == 126 else 10
                if n - pos < head:
                    break
                size = int.from_bytes(buf[pos + 2 : pos + head], "big")
            head += 4 if b1 & 0x80 else 0  # masked: websockets refuses it
            end = pos + head + size
            if end > n:
                break
            op = b0 & 0x0F
            if op > 2 or b0 & 0x70 or b1 & 0x80 or (op == 0 and not self._parts):
                self._proto.receive_data(buf[pos:end])
                control = True
            else:
                if op:  # a new message: 1 text, 2 binary (0: its continuation)
                    self._text, self._parts = op == 1, []
                self._parts.append(buf[pos + head : end])
                if b0 & 0x80:  # FIN
                    parts, self._parts = self._parts, []
                    data = parts[0] if len(parts) == 1 else b"".join(parts)
                    out.append(data.decode() if self._text else data)
            pos = end
        self._buf = buf[pos:] if pos else buf
        if control:
            self._proto.events_received()  # handled by websockets; nothing for the caller
        return out

    def wait(self, timeout_s: float) -> bool:
        """Wait up to ``timeout_s`` for bytes to read (or the end of the connection, or frames
        already buffered); True when :meth:`recv_messages` has something to look at."""
        if self._fresh or self._eof:  # frames that came with the handshake's response
            self._fresh = False
            return True
        ready, _, _ = select.select([self._sock], [], [], timeout_s)
        return bool(ready)

    def recv_messages(self, timeout_s: float) -> list[str | bytes]:
        """Every message that has arrived, waiting up to ``timeout_s`` for the first bytes
        (an empty list when none came)."""
        out = self._messages() if self._buf else []  # came with the handshake's response
        if out:
            self._flush()  # a ping among them is answered now
            return out
        if self._eof:
            raise self._closed()
        if timeout_s > 0:
            ready, _, _ = select.select([self._sock], [], [], timeout_s)
            if not ready:
                if self._proto.state is not self._open:  # closing: nothing more to wait for
                    raise self._closed()
                return []
        self._read_all()
        out = self._messages()
        if self._eof:
            self._proto.receive_eof()  # after the frames that came before it
        self._flush()  # pongs, the close handshake
        if not out and self._proto.state is not self._open:
            raise self._closed()
        return out

    def _closed(self) -> Exception:
        """The ConnectionClosed to raise once the connection has ended (our side is done
        with it: the protocol is brought to CLOSED)."""
        self._proto.receive_eof()  # idempotent
        return self._proto.close_exc

    def send(self, text: str) -> None:
        self._proto.send_text(text.encode())
        self._flush()

    def close(self, timeout_s: float = 1.0) -> None:
        """The closing handshake (our close frame, then the server's frames up to its close
        frame and the end of its side, at most ``timeout_s``), then the socket: a socket closed
        with bytes unread resets the connection, and the server logs an error."""
        try:
            if self._proto.state is self._open:
                self._proto.send_close(1000)  # a normal closure
                self._flush()
                self._read_to_end(time.monotonic() + timeout_s)
        except OSError:
            pass
        finally:
            self._sock.close()

    def _read_to_end(self, deadline: float) -> None:
        """Read (and drop) what the server still sends until it ends the connection."""
        while not self._eof:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([self._sock], [], [], left)[0]:
                return
            self._read_all()
            self._messages()  # data dropped; the server's close frame goes to websockets
            self._flush()


def _import_websockets() -> None:
    """Import the parts of websockets the client uses (later imports are look-ups)."""
    import websockets.client
    import websockets.exceptions
    import websockets.frames
    import websockets.protocol
    import websockets.uri  # noqa: F401


@dataclass
class _WsSession:
    """What one WebSocket connection knows: advertised channels, subscriptions, picks."""

    channels: dict[int, dict] = field(default_factory=dict)
    subs: dict[int, tuple[str, dict]] = field(default_factory=dict)  # sub id -> (kind, channel)
    picked: dict[str, int] = field(default_factory=dict)  # kind -> channel id
    next_sub: int = 1


def _json_message(text: str, src: Source):
    """A server's JSON message, or None (dropped, counted and said once) when it is no JSON
    this client can read (not JSON, or nested deeper than Python's parser goes)."""
    try:
        return json.loads(text)
    except (ValueError, RecursionError):
        src.drop("json", "a text message that is not JSON (or nested too deep to read)")
        return None


def _channel(ch) -> dict | None:
    """An advertised channel as this client uses it (``id`` an int, ``topic``, ``encoding``,
    ``schemaName``, ``schemaEncoding`` and ``schema`` strings, ``kind`` as classified), or None
    when a field is missing or of another type."""
    if not isinstance(ch, dict) or not isinstance(ch.get("id"), int):
        return None
    fields = ("topic", "encoding", "schemaName", "schemaEncoding", "schema")
    out = {k: ch.get(k, "") for k in fields}
    if not out["topic"] or not all(isinstance(v, str) for v in out.values()):
        return None
    kind = None
    if out["encoding"] == "cdr":
        try:
            kind = classify_schema(out["schemaName"], out["schemaEncoding"], out["schema"])
        except (ValueError, KeyError, TypeError, IndexError, RecursionError):
            kind = None
    return {**out, "id": ch["id"], "kind": kind}


class WsSource(Source):
    """A Foxglove WebSocket client (see the module doc)."""

    announces_truth = True

    @classmethod
    def open(cls, spec: SourceSpec, options: SourceOptions) -> WsSource:
        return cls(
            spec.url, options.imu_topic, options.truth_topic, options.give_up_s, options.batch_s
        )

    def __init__(
        self,
        url: str,
        imu_topic: str | None,
        truth_topic: str | None,
        give_up_s: float | None = 30.0,
        batch_s: float = BATCH_S,
    ) -> None:
        super().__init__()
        self.url = url
        self.imu_topic = imu_topic
        self.truth_topic = truth_topic
        self.give_up_s = give_up_s
        self.batch_s = batch_s
        self.reconnects = 0
        self._connected_before = False
        # read inline (begin, poll): the thread connects, then hands the connection to poll
        # until poll sees it end (_lost): (ws, session) while handed over, and how it ended
        self._inline = False
        self._live: tuple[WsConnection, _WsSession] | None = None
        self._lost = threading.Event()
        self._ended: tuple[Exception | None, str | None] = (None, None)
        _import_websockets()  # at open, not in the receiving thread (~60 ms of CPU)

    pollable = True

    def begin(self) -> None:
        """Read inline: the thread only connects (and reconnects); :meth:`poll` reads."""
        self._inline = True
        self._thread.start()

    def poll(self) -> None:
        """Inline: every message that has arrived on the connection, if there is one. What
        ends the connection (closed, lost, a failure) goes to the thread, which handles it as
        its own reading would have (reconnect, or end the source)."""
        live = self._live
        since = self._read_at or (time.perf_counter_ns(), time.time_ns())
        self._read_at = time.perf_counter_ns(), time.time_ns()
        if live is None:
            return
        ws, st = live
        try:
            messages = ws.recv_messages(0.0) if ws.wait(0.0) else []
            fatal = self._handle(ws, st, [(m, *since) for m in messages])
        except Exception as exc:  # raised in the thread, as there (_run, _guarded)
            self._end_connection(exc, None)
            return
        if fatal:
            self._end_connection(None, fatal)

    def _end_connection(self, exc: Exception | None, fatal: str | None) -> None:
        self._live, self._ended = None, (exc, fatal)
        self._lost.set()

    def stop(self, timeout_s: float = 5.0) -> None:
        self._stop.set()
        self._lost.set()  # a thread waiting on a handed-over connection
        super().stop(timeout_s)

    def _run(self) -> None:
        from websockets.exceptions import ConnectionClosed, InvalidHandshake, InvalidURI

        delay = 0.2
        lost_at = time.monotonic()
        while not self._stop.is_set():
            try:
                why = self._connection()
                if why is None:
                    return
                delay = 0.2 if why == "the server closed the connection" else delay
            except InvalidURI as exc:
                self.events.put(("end", f"bad WebSocket URL: {exc}"))
                return
            except ConnectionClosed as exc:
                why = f"connection lost ({exc})"
                delay = 0.2
            except (OSError, InvalidHandshake, TimeoutError) as exc:
                why = f"cannot connect ({type(exc).__name__}: {exc})"
            except Exception:  # a message this client could not take: a new connection
                why = "connection lost (the server sent a message this client cannot read)"
                delay = 0.2
            if self._stop.is_set():
                return
            if why.startswith(("connection lost", "the server")):
                lost_at = time.monotonic()
            waited = time.monotonic() - lost_at
            if self.give_up_s is not None and waited > self.give_up_s:
                why = f"source lost: no connection to {self.url} for {waited:.1f} s ({why})"
                self.events.put(("end", why))
                return
            self.events.put(("info", f"{why}; reconnecting to {self.url} in {delay:.1f} s"))
            self._stop.wait(delay)
            delay = min(2 * delay, 5.0)

    def _connection(self) -> str | None:
        """Connect and receive until the connection ends: why it ended, or None when the
        source is finished (stopped, or a fatal reason already sent)."""
        ws = WsConnection(self.url, _SUBPROTOCOLS, open_timeout_s=5.0)
        try:
            again = "reconnected" if self._connected_before else "connected"
            self.reconnects += self._connected_before
            self._connected_before = True
            self.events.put(("info", f"{again} to {self.url} ({ws.subprotocol})"))
            fatal = self._handed_over(ws) if self._inline else self._session(ws)
            if fatal:
                self.events.put(("end", fatal))
                return None
            if self._stop.is_set():
                return None
            return "the server closed the connection"
        finally:
            ws.close()

    def _frames(self, ws: WsConnection) -> list[tuple]:
        """Every message of one read in the thread: ``(data, arrival, wall)`` (the arrival of
        the batch's first bytes, for each)."""
        got = self._await(ws.wait, self.batch_s)
        if got is None:
            return []
        arrival, wall = got
        return [(m, arrival, wall) for m in ws.recv_messages(0.0)]

    def _session(self, ws: WsConnection) -> str | None:
        """One connection: subscribe, receive, decode. Returns a fatal reason or None."""
        st = _WsSession()
        while not self._stop.is_set():
            fatal = self._handle(ws, st, self._frames(ws))
            if fatal:
                return fatal
        return None

    def _handed_over(self, ws: WsConnection) -> str | None:
        """Inline: one connection, read by :meth:`poll` until it ends (or the source stops).
        Returns a fatal reason or None; raises how the connection was lost."""
        self._lost.clear()
        self._ended = (None, None)
        self._live = (ws, _WsSession())
        if self._stop.is_set():  # stopped before the hand-over: poll will not end it
            self._live = None
            return None
        self._lost.wait()
        self._live = None
        exc, fatal = self._ended
        if exc is not None:
            raise exc
        return fatal

    def _handle(self, ws: WsConnection, st: _WsSession, frames: list[tuple]) -> str | None:
        """The messages of one read, ``(data, arrival, wall)``: JSON ones acted on (channels
        picked and subscribed), the binary ones of a subscription queued raw (decoded by the
        session's loop). Returns a fatal reason or None."""
        pending: dict[int, list] = {}
        for data, arrival, wall in frames:
            if isinstance(data, str):
                fatal = self._on_text(ws, st, _json_message(data, self))
                if fatal:
                    return fatal
            elif len(data) >= _MSG_HEAD.size and data[0] == _BIN_MESSAGE:
                _, sid, _ = _MSG_HEAD.unpack_from(data)
                if sid in st.subs:  # else a subscription just ended: the protocol's race
                    pending.setdefault(sid, []).append((data[_MSG_HEAD.size :], arrival, wall))
            elif not data or data[0] == _BIN_MESSAGE:
                self.drop("short", f"a binary message shorter than its {_MSG_HEAD.size}-byte head")
            elif data[0] not in _BIN_SERVER_OPS:
                self.drop("binary op", "a binary frame of an opcode the protocol has not")
        for sid, items in pending.items():  # decoded by the session's loop (decode)
            if sid in st.subs:
                self.events.put(("raw", st.subs[sid], items))
        return None

    def _on_text(self, ws, st: _WsSession, msg) -> str | None:
        """A JSON message: channels advertised (pick and subscribe) or withdrawn."""
        op = msg.get("op") if isinstance(msg, dict) else None
        if op == "advertise":
            channels = msg.get("channels")
            if not isinstance(channels, list):
                channels = []
                self.drop("advertise", "an advertise whose channels are not a list")
            for ch in channels:
                checked = _channel(ch)
                if checked is None:
                    self.drop(
                        "channel",
                        "an advertised channel without an integer id, a topic "
                        "or text schema fields",
                    )
                    continue
                st.channels[checked["id"]] = checked
            for kind, topic in (("imu", self.imu_topic), ("truth", self.truth_topic)):
                if kind not in st.picked and topic != "none":
                    fatal = self._pick_and_subscribe(ws, st, kind, topic)
                    if fatal:
                        return fatal
        elif op == "unadvertise":
            ids = msg.get("channelIds")
            if not isinstance(ids, list) or not all(isinstance(i, int) for i in ids):
                self.drop("unadvertise", "an unadvertise whose channelIds are not integers")
                return None
            gone = set(ids)
            for kind, cid in list(st.picked.items()):
                if cid in gone:
                    del st.picked[kind]
                    self.events.put(("info", f"{st.channels[cid]['topic']} was unadvertised"))
            for sid, (_, ch) in list(st.subs.items()):
                if int(ch["id"]) in gone:
                    del st.subs[sid]
        return None

    def _pick_and_subscribe(self, ws, st: _WsSession, kind: str, topic: str | None) -> str | None:
        channels = st.channels
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
            return f"Expected one {kind} channel, got {len(ids)}: {names} (choose with {flag})"
        if not ids:
            return None
        cid = ids[0]
        ch = channels[cid]
        st.picked[kind] = cid
        st.subs[st.next_sub] = (kind, ch)
        sub = {"op": "subscribe", "subscriptions": [{"id": st.next_sub, "channelId": cid}]}
        ws.send(json.dumps(sub))
        st.next_sub += 1
        name, enc, text = (
            ch.get("schemaName", ""),
            ch.get("schemaEncoding", ""),
            ch.get("schema", ""),
        )
        self.events.put(("channel", Channel(kind, ch["topic"], name, enc, text, "cdr")))
        self.events.put(("info", f"subscribed to {ch['topic']} ({name}) as {kind}"))
        return None

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

    def decode(self, key, items: list) -> list[tuple]:
        """The messages of one subscription (``key``: its ``(kind, channel)``): every item
        ``(payload, arrival_ns, wall_ns)`` of the wake-up in one bulk CDR decode."""
        kind, ch = key
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
        out: list[tuple] = [("malformed", bad)] if bad else []
        if len(dec.t_ns):
            g = np.flatnonzero(dec.good)
            arrival = np.fromiter((items[i][1] for i in g), np.int64, len(g))
            wall = np.fromiter((items[i][2] for i in g), np.int64, len(g))
            raw = [payloads[i] for i in g]
            out.append(("data", Received(kind, dec.t_ns, dec.values, arrival, wall, raw)))
        return out


def open_source(
    spec: SourceSpec,
    *,
    imu_topic: str | None = None,
    truth_topic: str | None = None,
    gyro_units: str = "rad/s",
    time_units: str = "s",
    give_up_s: float | None = 30.0,
    stdin_fd: int | None = None,
    batch_s: float = BATCH_S,
) -> Source:
    """Create (not start) the source for ``spec``: the :data:`SOURCES` class of its scheme."""
    options = SourceOptions(
        imu_topic, truth_topic, gyro_units, time_units, give_up_s, stdin_fd, batch_s
    )
    module, _, name = SOURCES["-" if spec.kind == "stdin" else spec.kind].partition(":")
    cls = getattr(importlib.import_module(module), name)
    return cls.open(spec, options)

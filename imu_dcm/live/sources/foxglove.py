"""``ws://HOST:PORT``: a Foxglove WebSocket server, such as ``foxglove_bridge``.

The ``foxglove.websocket.v1`` protocol of ``foxglove_bridge`` (also offered as
``foxglove.sdk.v1``, the same messages, spoken by foxglove-sdk servers): the server advertises
channels (JSON ``advertise``); the IMU and truth channels are picked by schema as replay picks
them (or by ``imu_topic`` / ``truth_topic``) and subscribed (JSON ``subscribe``); messages
arrive as binary frames ``0x01 | u32 subscription | u64 log time ns | CDR payload``. The client
(:class:`~imu_dcm.live.sources.websocket.WsConnection`) runs under the source thread's own
socket loop; the messages queued between two wake-ups of the session's loop are decoded
together (one bulk CDR decode per channel). When the connection drops, the source reconnects
with back-off (0.2 s doubling to 5 s), says so, and gives up after ``give_up_s`` without a
connection.
"""

from __future__ import annotations

import json
import struct
import threading
import time
from dataclasses import dataclass, field

import numpy as np
from websockets.exceptions import ConnectionClosed, InvalidHandshake, InvalidURI

from imu_dcm.live.events import Channel, End, Event, Info, Malformed, Raw, Received
from imu_dcm.live.sources.base import Source
from imu_dcm.live.sources.spec import BATCH_S, SourceOptions, SourceSpec
from imu_dcm.live.sources.websocket import WsConnection
from imu_dcm.logio.ros.payload import classify_schema, decode_cdr_batch

__all__ = ["BIN_MESSAGE", "BIN_SERVER_OPS", "MSG_HEAD", "SUBPROTOCOLS", "WsSource"]

#: The subprotocols offered, in order of preference (the same messages).
SUBPROTOCOLS = ("foxglove.websocket.v1", "foxglove.sdk.v1")
BIN_MESSAGE = 0x01
#: The binary opcodes a Foxglove server sends: message data, time, service call response,
#: fetch asset response (any other is no message of the protocol).
BIN_SERVER_OPS = frozenset({0x01, 0x02, 0x03, 0x04})
MSG_HEAD = struct.Struct("<BIQ")  # opcode, subscription id, log time ns


@dataclass(slots=True)
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
        delay = 0.2
        lost_at = time.monotonic()
        while not self._stop.is_set():
            try:
                why = self._connection()
                if why is None:
                    return
                delay = 0.2 if why == "the server closed the connection" else delay
            except InvalidURI as exc:
                self.events.put(End(f"bad WebSocket URL: {exc}"))
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
                self.events.put(End(why))
                return
            self.events.put(Info(f"{why}; reconnecting to {self.url} in {delay:.1f} s"))
            self._stop.wait(delay)
            delay = min(2 * delay, 5.0)

    def _connection(self) -> str | None:
        """Connect and receive until the connection ends: why it ended, or None when the
        source is finished (stopped, or a fatal reason already sent)."""
        ws = WsConnection(self.url, SUBPROTOCOLS, open_timeout_s=5.0)
        try:
            again = "reconnected" if self._connected_before else "connected"
            self.reconnects += self._connected_before
            self._connected_before = True
            self.events.put(Info(f"{again} to {self.url} ({ws.subprotocol})"))
            fatal = self._handed_over(ws) if self._inline else self._session(ws)
            if fatal:
                self.events.put(End(fatal))
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
            elif len(data) >= MSG_HEAD.size and data[0] == BIN_MESSAGE:
                _, sid, _ = MSG_HEAD.unpack_from(data)
                if sid in st.subs:  # else a subscription just ended: the protocol's race
                    pending.setdefault(sid, []).append((data[MSG_HEAD.size :], arrival, wall))
            elif not data or data[0] == BIN_MESSAGE:
                self.drop("short", f"a binary message shorter than its {MSG_HEAD.size}-byte head")
            elif data[0] not in BIN_SERVER_OPS:
                self.drop("binary op", "a binary frame of an opcode the protocol has not")
        for sid, items in pending.items():  # decoded by the session's loop (decode)
            if sid in st.subs:
                self.events.put(Raw(st.subs[sid], items))
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
                    self.events.put(Info(f"{st.channels[cid]['topic']} was unadvertised"))
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
        self.events.put(Channel(kind, ch["topic"], name, enc, text, "cdr"))
        self.events.put(Info(f"subscribed to {ch['topic']} ({name}) as {kind}"))
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

    def decode(self, key, items: list) -> list[Event]:
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
        out: list[Event] = [Malformed(bad)] if bad else []
        if len(dec.t_ns):
            g = np.flatnonzero(dec.good)
            arrival = np.fromiter((items[i][1] for i in g), np.int64, len(g))
            wall = np.fromiter((items[i][2] for i in g), np.int64, len(g))
            raw = [payloads[i] for i in g]
            out.append(Received(kind, dec.t_ns, dec.values, arrival, wall, raw, dec.accel))
        return out

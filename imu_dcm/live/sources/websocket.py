"""A WebSocket client connection under the reading thread's own socket loop (no second thread).

websockets (its Sans-I/O protocol) makes the opening handshake, the control frames and what the
client sends; the server's data frames are split here (see :class:`WsConnection`). Imported
when a ``ws://`` source opens (websockets costs ~30 ms of CPU to import, measured), never by the
receiving thread.
"""

from __future__ import annotations

import select
import socket
import time

from websockets.client import ClientProtocol
from websockets.protocol import State
from websockets.uri import parse_uri

__all__ = ["WsConnection"]


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
        uri = parse_uri(url)
        if uri.secure:
            raise OSError("Expected ws:// (loopback, no TLS), got wss://")
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
        while self._proto.state is not State.OPEN:
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
                    if self._proto.state is not State.OPEN and buf:
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
                if self._proto.state is not State.OPEN:  # closing: nothing more to wait for
                    raise self._closed()
                return []
        self._read_all()
        out = self._messages()
        if self._eof:
            self._proto.receive_eof()  # after the frames that came before it
        self._flush()  # pongs, the close handshake
        if not out and self._proto.state is not State.OPEN:
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
            if self._proto.state is State.OPEN:
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

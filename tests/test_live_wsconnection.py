"""The live WebSocket client (websockets' Sans-I/O protocol under the source's own loop) against
websockets' own server on 127.0.0.1: the subprotocol is negotiated, a fragmented message is
assembled, a ping is answered, text and binary messages arrive in order, and a close from the
server ends in ConnectionClosed."""

from __future__ import annotations

import contextlib
import threading
import time

import pytest

from imu_dcm.live.sources.websocket import WsConnection

server_mod = pytest.importorskip("websockets.sync.server")


@contextlib.contextmanager
def connected(handler):
    """websockets' server on 127.0.0.1 serving ``handler``, and a client connected to it."""
    with server_mod.serve(
        handler, "127.0.0.1", 0, subprotocols=["foxglove.websocket.v1"], compression=None
    ) as server:
        threading.Thread(target=server.serve_forever, daemon=True).start()
        port = server.socket.getsockname()[1]
        yield server, WsConnection(f"ws://127.0.0.1:{port}", ("foxglove.websocket.v1",))


def test_ws_connection_assembles_answers_pings_and_sees_the_close():
    got_pong = threading.Event()

    def handler(conn):
        conn.send('{"op": "serverInfo"}')
        conn.send([b"ab", b"cd", b"ef"])  # one binary message in three frames
        pong = conn.ping(b"p")
        got_pong.set() if pong.wait(5) else None
        conn.send(b"\x01" * 70000)  # longer than one frame header's short lengths
        assert conn.recv(timeout=5) == "hello"
        conn.close()

    with connected(handler) as (server, ws):
        assert ws.subprotocol == "foxglove.websocket.v1"
        messages: list = []
        deadline = time.monotonic() + 10
        while len(messages) < 3 and time.monotonic() < deadline:
            messages += ws.recv_messages(0.2)
        assert messages == ['{"op": "serverInfo"}', b"abcdef", b"\x01" * 70000]
        assert got_pong.wait(5)  # answered from inside recv_messages
        ws.send("hello")
        from websockets.exceptions import ConnectionClosed

        def until_closed():
            while time.monotonic() < deadline:
                assert ws.recv_messages(0.2) == []

        with pytest.raises(ConnectionClosed):
            until_closed()
        ws.close()
        server.shutdown()


def _raw_server(frames: list[bytes], got: list[bytes]):
    """A bare TCP server on 127.0.0.1: answers the opening handshake by hand, sends ``frames``
    as given (bytes on the wire), then records what the client sends until it closes."""
    import base64
    import hashlib
    import socket

    srv = socket.create_server(("127.0.0.1", 0))

    def serve():
        conn, _ = srv.accept()
        with conn:
            req = b""
            while b"\r\n\r\n" not in req:
                req += conn.recv(4096)
            key = next(
                ln.split(b":", 1)[1].strip()
                for ln in req.split(b"\r\n")
                if ln.lower().startswith(b"sec-websocket-key:")
            )
            magic = b"258EAFA5-E914-47DA-95CA-C5AB0DC85B11"
            accept = base64.b64encode(hashlib.sha1(key + magic).digest())
            conn.sendall(
                b"HTTP/1.1 101 Switching Protocols\r\nUpgrade: websocket\r\n"
                b"Connection: Upgrade\r\nSec-WebSocket-Accept: " + accept + b"\r\n"
                b"Sec-WebSocket-Protocol: foxglove.websocket.v1\r\n\r\n" + b"".join(frames)
            )
            conn.settimeout(5)
            try:
                while data := conn.recv(4096):
                    got.append(data)
            except OSError:
                pass
        srv.close()

    threading.Thread(target=serve, daemon=True).start()
    return srv.getsockname()[1]


def test_ws_connection_frames_split_by_hand_control_frames_to_websockets():
    """Frames sent with the handshake's response, a ping between two fragments of a message
    (allowed), then a masked frame (a server must not mask): the messages come whole and in
    order, the ping is answered, the masked frame fails the connection (close code 1002)."""
    from websockets.exceptions import ConnectionClosed

    frames = [
        b"\x81\x02hi",  # text, FIN
        b"\x02\x03abc",  # binary, first fragment
        b"\x89\x01p",  # ping between the fragments
        b"\x80\x02de",  # continuation, FIN
        b"\x82\x7e\x01\x00" + bytes(256),  # binary, 16-bit length
        b"\x82\x81\x00\x00\x00\x00x",  # masked: a protocol error from a server
    ]
    got: list[bytes] = []
    port = _raw_server(frames, got)
    ws = WsConnection(f"ws://127.0.0.1:{port}", ("foxglove.websocket.v1",))
    messages: list = []

    def until_closed():
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            messages.extend(ws.recv_messages(0.2))

    with pytest.raises(ConnectionClosed) as closed:
        until_closed()
    assert messages == ["hi", b"abcde", bytes(256)]
    assert closed.value.sent is not None and closed.value.sent.code == 1002
    ws.close()
    sent = b"".join(got)
    assert sent[:1] == b"\x8a"  # the pong, first (client frames are masked: payload not plain)


def test_client_close_completes_the_handshake_while_the_server_streams():
    # the server sends data frames until the client closes: the client answers with the
    # closing handshake (the server's close frame read, its end of the connection awaited),
    # so the server sees a clean close (code 1000), not a reset with bytes unread.
    from websockets.exceptions import ConnectionClosed

    seen: dict = {}

    def handler(conn):
        try:
            while True:
                conn.send(b"\x02" * 200)
                time.sleep(0.0005)
        except ConnectionClosed as exc:
            seen["rcvd"] = exc.rcvd

    with connected(handler) as (server, ws):
        deadline = time.monotonic() + 10
        while not ws.recv_messages(0.2) and time.monotonic() < deadline:
            pass
        time.sleep(0.05)  # frames pile up unread in the socket
        ws.close()
        deadline = time.monotonic() + 5
        while "rcvd" not in seen and time.monotonic() < deadline:
            time.sleep(0.01)
        server.shutdown()
    assert seen["rcvd"] is not None and seen["rcvd"].code == 1000

"""The live WebSocket client (websockets' Sans-I/O protocol under the source's own loop) against
websockets' own server on 127.0.0.1: the subprotocol is negotiated, a fragmented message is
assembled, a ping is answered, text and binary messages arrive in order, and a close from the
server ends in ConnectionClosed."""

from __future__ import annotations

import threading
import time

import pytest

from imu_dcm.live.sources import WsConnection

server_mod = pytest.importorskip("websockets.sync.server")


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

    with server_mod.serve(
        handler, "127.0.0.1", 0, subprotocols=["foxglove.websocket.v1"], compression=None
    ) as server:
        threading.Thread(target=server.serve_forever, daemon=True).start()
        port = server.socket.getsockname()[1]
        ws = WsConnection(f"ws://127.0.0.1:{port}", ("foxglove.websocket.v1",))
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

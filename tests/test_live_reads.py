"""How the live sources are read: by the session's loop at each wake-up (inline: UDP, stdin and
the WebSocket source, with a wake-up interval of 25 ms or more), or by the source's thread a
batch after the first bytes (a shorter interval); the inline read's arrival is the previous
read's time (the earliest the bytes can have come); every line sent over UDP arrives, in order."""

from __future__ import annotations

import contextlib
import gc
import itertools
import os
import socket
import threading
import time

import pytest

from imu_dcm.live.events import Channel, Info, Raw, Received
from imu_dcm.live.sources import Source, udp
from imu_dcm.live.sources.udp import UdpSource


def _recording_waits(src: Source) -> list[float]:
    waits: list[float] = []
    src._stop.wait = lambda t: waits.append(t) or False  # type: ignore[method-assign]
    return waits


def test_thread_read_waits_batch_s_after_the_first_bytes():
    src = Source()
    waits = _recording_waits(src)
    assert src._await(lambda t: True, 0.007) is not None
    assert waits == [0.007]


def test_inline_arrival_is_the_previous_read():
    src = UdpSource("127.0.0.1", 0, "rad/s", "s")
    src.begin()
    src.poll()  # nothing yet
    read_at = src._read_at
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
        tx.sendto(b"1,0,0,0", src.address)
    time.sleep(0.05)
    src.poll()
    items = [ev for ev in list(src.events.queue) if isinstance(ev, Raw)]
    src.stop()
    assert [item[1:] for item in items[0].items] == [read_at]
    assert src._read_at[0] > read_at[0]


def test_inline_udp_source_reads_in_the_callers_thread_every_line_in_order():
    src = UdpSource("127.0.0.1", 0, "rad/s", "s")
    assert src.pollable
    src.begin()  # no thread: the session's loop reads it (poll) once per wake-up
    n = 300
    sent = [f"{1700000000 + k / 1000:.3f},0,0,{k}".encode() for k in range(n)]
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
        for k, line in enumerate(sent):
            tx.sendto(line, src.address)
            if k % 50 == 49:
                src.poll()
    deadline = time.monotonic() + 5.0
    got: list[float] = []
    infos = []
    while len(got) < n and time.monotonic() < deadline:
        src.poll()
        while not src.events.empty():
            ev = src.events.get_nowait()
            if isinstance(ev, Raw):
                for e in src.decode(ev.key, ev.items):
                    got.extend(e.values[:, 2].tolist())
            else:
                infos.append(type(ev))
        time.sleep(0.005)
    assert src._thread.ident is None  # never started
    src.stop()
    assert got == [float(k) for k in range(n)]
    assert infos == [Channel, Info]


def _count_polls(monkeypatch) -> list[float]:
    from imu_dcm.live import sources

    polls: list[float] = []
    poll = sources.Source.poll

    def counted(self):
        polls.append(time.monotonic())
        return poll(self)

    monkeypatch.setattr(sources.Source, "poll", counted)
    return polls


def _record_wakeups(monkeypatch) -> list[tuple[float, bool, bool]]:
    """The loop's waits: for each, the time it was set to end (the loop's own schedule, not
    the clock's reading), whether the source was flowing (its first bytes read) when it
    began, and whether it woke to read (not stopped)."""
    from imu_dcm.live.loop import Loop

    waits: list[tuple[float, bool, bool]] = []
    wait = Loop._wait

    def recorded(self, timeout_s):
        deadline, flowing = self.next_flush, self.src.flowing
        stopped = wait(self, timeout_s)
        waits.append((deadline, flowing, not stopped))
        return stopped

    monkeypatch.setattr(Loop, "_wait", recorded)
    return waits


@pytest.mark.parametrize(("view_interval_s", "every_s"), [(None, 0.25), (0.05, 0.05)])
def test_loop_reads_a_line_source_inline_on_its_cadence(monkeypatch, view_interval_s, every_s):
    # without a view the loop wakes every 0.25 s by default (nothing needs it sooner); a view
    # interval given is kept. Polls: one per wake-up and none besides; the wake-ups, after the
    # read at the first bytes and the probe after it, are an interval apart (a steady cadence):
    # facts of the loop's schedule, whatever the machine's load.
    from imu_dcm.live import run

    polls = _count_polls(monkeypatch)
    waits = _record_wakeups(monkeypatch)
    r, w = os.pipe()

    def feed():
        with os.fdopen(w, "wb") as f:
            for k in range(80):
                f.write(f"{k / 100},0,0,1\n".encode())
                f.flush()
                time.sleep(0.01)

    feeder = threading.Thread(target=feed)
    feeder.start()
    try:
        res = run(
            "-",
            stdin_fd=r,
            rerun="off",
            status=False,
            bias="none",
            say=lambda s: None,
            view_interval_s=view_interval_s,
        )
    finally:
        feeder.join()
        os.close(r)
    assert res.summary["samples"] == 80 and res.summary["stopped"] == "end of input"
    assert res.summary["read_interval_s"] == every_s
    assert len(polls) >= 2 and len(polls) == sum(woke for *_, woke in waits)
    steady = [deadline for deadline, flowing, _ in waits if flowing]  # the probe's on
    assert all(b - a >= every_s - 1e-9 for a, b in itertools.pairwise(steady)), steady


def test_udp_datagrams_the_system_drops_are_counted_and_said():
    # a receive buffer far too small for what is sent between two reads: the system drops
    # datagrams, and the source says how many (the kernel's own count, SO_RXQ_OVFL)
    import sys

    if not sys.platform.startswith("linux"):
        pytest.skip("the drop count is Linux's SO_RXQ_OVFL")
    src = UdpSource("127.0.0.1", 0, "rad/s", "s")
    src.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    src.begin()
    n = 2000
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx, contextlib.closing(src.sock):
        for k in range(n):
            tx.sendto(f"{k / 1000:.3f},0,0,1".encode(), src.address)
        time.sleep(0.05)
        src.poll()
        assert src.crowded
        got, said = _drain_events(src)
        assert 0 < got < n
        # the count comes with the datagrams queued after the drops: the stream goes on
        tx.sendto(f"{n / 1000:.3f},0,0,1".encode(), src.address)
        time.sleep(0.05)
        src.poll()
    more, said2 = _drain_events(src)
    src.stop()
    assert more == 1
    assert src.lost == n - got  # every datagram not read was dropped, and counted
    assert any(f"dropped {n - got} datagram(s)" in line for line in said + said2), said2


def _drain_events(src) -> tuple[int, list[str]]:
    """Samples decoded and lines said from the source's queued events."""
    got, said = 0, []
    while not src.events.empty():
        ev = src.events.get_nowait()
        if isinstance(ev, Raw):
            got += sum(len(e.t_ns) for e in src.decode(ev.key, ev.items) if type(e) is Received)
        elif isinstance(ev, Info):
            said.append(ev.text)
    return got, said


def test_a_filling_pipe_sets_the_cadence_its_rate_needs_and_says_it_once(monkeypatch):
    # without a view the loop wakes every 0.25 s; a writer that would fill the pipe in ~0.4 s
    # makes it read as often as that rate needs (a full pipe would block the writer): the
    # cadence is set from the first reads, and said once, at the end, with its value
    from imu_dcm.live import run

    polls = _count_polls(monkeypatch)
    r, w = os.pipe()
    n, per = 8000, 40  # 18-byte lines, 40 every 2 ms: ~360 kB/s, a 64 KiB pipe in ~0.2 s

    def feed():
        with os.fdopen(w, "wb") as f:
            for k in range(0, n, per):
                f.write(b"".join(f"{j / 1000:.3f},0,0,1\n".encode() for j in range(k, k + per)))
                f.flush()
                time.sleep(0.002)

    said: list[str] = []
    feeder = threading.Thread(target=feed)
    feeder.start()
    try:
        res = run("-", stdin_fd=r, rerun="off", status=False, bias="none", say=said.append)
    finally:
        feeder.join()
        os.close(r)
    s = res.summary
    assert s["samples"] == n and s["stopped"] == "end of input"
    lines = [line for line in said if line.startswith("read every")]
    assert len(lines) == 1 and lines[0].endswith("the source's rate filled its buffer sooner")
    assert s["read_interval_s"] < 0.25 and f"{s['read_interval_s'] * 1e3:.0f} ms" in lines[0]
    assert len(polls) >= 4


def test_every_datagram_the_system_drops_is_counted_at_stop(monkeypatch):
    # a 4 KiB receive buffer flooded, then nothing more: the datagrams dropped after the last
    # one read are counted at stop (the socket's own count, /proc/net/udp), so the summary's
    # lost_by_system is exactly what was sent and not integrated
    import sys

    if not sys.platform.startswith("linux"):
        pytest.skip("the drop count is Linux's")
    from test_live_ws import live_thread

    monkeypatch.setattr(udp, "UDP_RCVBUF", 4096)
    live = live_thread("udp://127.0.0.1:0", bias="none", idle_stop_s=1.0)
    assert live.ready.wait(20)
    n = 3000
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
        for k in range(n):
            tx.sendto(f"{k / 1000:.3f},0,0,1".encode(), live.addr["address"])
    live.thread.join(30)
    assert not live.thread.is_alive()
    s = live.out["result"].summary
    assert s["malformed"] == s["dropped_duplicate"] == s["dropped_backward"] == 0
    assert 0 < s["lost_by_system"] < n
    assert s["lost_by_system"] == n - s["samples"]


def _fast_udp_attempt(rate: float, n: int) -> tuple[dict, list[str]]:
    """One live run fed ``n`` one-line datagrams at ``rate`` a second; its summary and lines."""
    from test_live_ws import live_thread

    live = live_thread("udp://127.0.0.1:0", bias="none", idle_stop_s=0.75)
    assert live.ready.wait(20)
    lines = [f"{k * 1e-5:.5f},0,0,1".encode() for k in range(n)]
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
        start = time.perf_counter()
        for k in range(0, n, 100):
            while time.perf_counter() - start < k / rate:
                time.sleep(0.0002)
            for line in lines[k : k + 100]:
                tx.sendto(line, live.addr["address"])
    live.thread.join(30)
    assert not live.thread.is_alive()
    return live.out["result"].summary, live.said


def test_a_fast_udp_stream_is_read_at_its_cadence_from_the_first_datagram():
    # one sample a datagram at the rate that fills the socket's buffer in 0.2 s, whatever the
    # machine gives it (with the default 0.25 s cadence the first wake-up would come too late):
    # the loop reads at the first datagram, measures the rate on the next read, and reads as
    # often as the rate needs; no datagram is lost.
    # Up to three runs, one of which must lose nothing. A loop that reads too seldom loses in
    # every run (the buffer overflows at each slow wake-up), and every run must set the fast
    # cadence and count each lost datagram. What a retry forgives is a stall the loop cannot
    # help (the machine's other work on a shared core): 0.2 s of it overflows the buffer. The
    # heap the suite has built is frozen first, so a full collection does not walk it mid-run.
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, udp.UDP_RCVBUF)
        rcvbuf = probe.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
    rate = rcvbuf / 832 / 0.2  # a one-line datagram takes 832 bytes of it (Linux, loopback)
    n = int(rate)  # one second
    runs = []
    gc.collect()
    gc.freeze()
    try:
        for _ in range(3):
            s, said = _fast_udp_attempt(rate, n)
            runs.append((s["samples"], s["lost_by_system"], s["read_interval_s"]))
            assert s["lost_by_system"] == n - s["samples"], runs  # every loss counted
            assert s["read_interval_s"] <= 0.06, runs  # a quarter of the 0.2 s, and rounding
            # 100 kHz stamps: no line says they are past an IMU's range (1 Hz to 100 kHz)
            assert not [line for line in said if "100 kHz" in line]
            if s["samples"] == n:
                break
    finally:
        gc.unfreeze()
    assert runs[-1][:2] == (n, 0), f"every run lost datagrams (samples, lost, interval): {runs}"

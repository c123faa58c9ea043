"""A paced source (:meth:`Source.pace`) reads once per wake-up of the session's loop, a lead
before it; the batch's arrival is the previous read's time (the earliest its bytes can have
come); every line sent over UDP arrives, in order, through paced reads."""

from __future__ import annotations

import os
import socket
import threading
import time

import numpy as np
import pytest

from imu_dcm.live.sources import Source, UdpSource

EVERY_S, LEAD_S = 0.05, 0.0125


def _recording_waits(src: Source) -> list[float]:
    waits: list[float] = []
    src._stop.wait = lambda t: waits.append(t) or False  # type: ignore[method-assign]
    return waits


def test_paced_wait_ends_a_lead_before_the_next_wake_up():
    src = Source()
    waits = _recording_waits(src)
    take = time.monotonic() + 0.03
    src.pace(lambda: take, EVERY_S, LEAD_S)
    before = time.monotonic()
    src._settle()
    after = time.monotonic()
    # the wait ends at take - lead, whenever within [before, after] it was computed
    assert take - LEAD_S - after <= waits[0] <= take - LEAD_S - before


def test_paced_wait_skips_a_wake_up_already_under_way():
    src = Source()
    waits = _recording_waits(src)
    take = time.monotonic() - 0.001  # the loop is waking now: its queue is being taken
    src.pace(lambda: take, EVERY_S, LEAD_S)
    before = time.monotonic()
    src._settle()
    after = time.monotonic()
    at = take + EVERY_S - LEAD_S  # the read before the wake-up after it
    assert at - after <= waits[0] <= at - before


def test_unpaced_wait_is_batch_s():
    src = Source()
    waits = _recording_waits(src)
    assert src._await(lambda t: True, 0.007) is not None
    assert waits == [0.007]


def test_paced_arrival_is_the_previous_read():
    src = Source()
    _recording_waits(src)
    src.pace(lambda: time.monotonic() + 0.02, EVERY_S, LEAD_S)
    assert src._await(lambda t: False, 0.005) is None  # nothing to read
    read_at = src._read_at
    got = src._await(lambda t: True, 0.005)
    assert got == read_at
    assert src._read_at[0] >= read_at[0]


def test_paced_udp_source_delivers_every_line_in_order():
    src = UdpSource("127.0.0.1", 0, "rad/s", "s", batch_s=LEAD_S)
    start = time.monotonic()
    src.pace(lambda: start + EVERY_S * (1 + (time.monotonic() - start) // EVERY_S), EVERY_S, LEAD_S)
    src.start()
    n = 300
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for i in range(n):
            s.sendto(f"{i * 1e-3:.3f},0.1,0.2,0.3\n".encode(), src.address)
            time.sleep(5e-4)
    stamps, reads = [], 0
    deadline = time.monotonic() + 10
    while len(stamps) < n and time.monotonic() < deadline:
        try:
            ev = src.events.get(timeout=0.5)
        except Exception:
            continue
        if ev[0] == "raw":
            reads += 1
            for dec in src.decode(ev[1], ev[2]):
                if dec[0] == "data":
                    stamps.extend(dec[1].t_ns.tolist())
    src.stop()
    np.testing.assert_array_equal(stamps, np.arange(n) * 1_000_000)
    # ~0.3 s of sending over 50 ms reads: a handful of reads, not one per 5 ms batch
    assert reads <= 2 + (time.monotonic() - start) / EVERY_S


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
            if ev[0] == "raw":
                for e in src.decode(ev[1], ev[2]):
                    got.extend(e[1].values[:, 2].tolist())
            else:
                infos.append(ev[0])
        time.sleep(0.005)
    assert src._thread.ident is None  # never started
    src.stop()
    assert got == [float(k) for k in range(n)]
    assert infos == ["channel", "info"]


def _count_polls(monkeypatch) -> list[float]:
    from imu_dcm.live import sources

    polls: list[float] = []
    poll = sources.Source.poll

    def counted(self):
        polls.append(time.monotonic())
        return poll(self)

    monkeypatch.setattr(sources.Source, "poll", counted)
    return polls


@pytest.mark.parametrize(("view_interval_s", "every_s"), [(None, 0.25), (0.05, 0.05)])
def test_loop_reads_a_line_source_inline_on_its_cadence(monkeypatch, view_interval_s, every_s):
    # without a view the loop wakes every 0.25 s by default (nothing needs it sooner); a view
    # interval given is kept. Polls: one per wake-up (at most one per interval, a steady
    # cadence), plus the last one at the end.
    from imu_dcm.live import run

    polls = _count_polls(monkeypatch)
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
    span = polls[-1] - polls[0]
    assert len(polls) >= 2
    assert len(polls) <= span / every_s + 2

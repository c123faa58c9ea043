"""A paced source (:meth:`Source.pace`) reads once per wake-up of the session's loop, a lead
before it; the batch's arrival is the previous read's time (the earliest its bytes can have
come); every line sent over UDP arrives, in order, through paced reads."""

from __future__ import annotations

import socket
import time

import numpy as np

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

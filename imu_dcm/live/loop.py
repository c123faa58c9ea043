"""The session's loop: events from the source to the pipeline, the view at display rate.

:class:`Loop` wakes once per interval (not per event), takes every event the source has queued
(:mod:`imu_dcm.live.events`, dispatched on their type), hands the samples on as one batch per
kind, sends the view batch and prints the status line. With a pollable source and an interval
of :data:`INLINE_MIN_S` or more it reads the source itself at each wake-up, at the cadence the
source's rate needs (:meth:`Loop._cadence`).
"""

from __future__ import annotations

import dataclasses
import queue
import signal
import sys
import threading
import time
import warnings

import numpy as np

from imu_dcm.errors import GapWarning
from imu_dcm.live.events import Channel, End, Info, Malformed, Raw, Received
from imu_dcm.live.pipeline import DEG, Pipeline
from imu_dcm.live.sources import Source

__all__ = ["INLINE_MIN_S", "NO_VIEW_INTERVAL_S", "VIEW_INTERVAL_S", "Loop"]

#: From this view interval on, the loop reads a pollable source itself at each wake-up (one
#: thread wakes per interval, not two). Shorter intervals ask for latency: the source's thread
#: reads each sample a batch_s after its first bytes, not held for the next wake-up's read (worth
#: a 10 ms interval's p99).
INLINE_MIN_S = 0.025
#: The shortest cadence the loop takes when a source's rate needs it, s.
CADENCE_MIN_S = 0.01
#: The loop reads a source whose buffer fills this much between two reads at most (a quarter:
#: a rate that doubles, or a read that comes late, still finds room).
FILL_TARGET = 0.25
#: After the first bytes of a source, the next read comes this soon, to measure the rate, s.
PROBE_S = 0.01
#: The loop's wake-up interval by default: the view's display rate, or, without a view, four
#: times a second (the status line, the recording and the reorder window's release need no
#: more; each wake-up costs CPU of its own, most of it in caches gone cold while asleep).
VIEW_INTERVAL_S = 0.05
NO_VIEW_INTERVAL_S = 0.25


def _scaled(rec: Received, gyro_scale: float) -> Received:
    """The IMU sample with its rates converted to rad/s (``gyro_scale`` rad/s per unit)."""
    if gyro_scale == 1.0:
        return rec
    return dataclasses.replace(rec, values=rec.values * gyro_scale)


def _joined(recs: list[Received]) -> Received:
    """Batches of one kind, in arrival order, as one."""
    if len(recs) == 1:
        return recs[0]
    raw = None if any(r.raw is None for r in recs) else [p for r in recs for p in r.raw]
    accel = None
    if any(r.accel is not None for r in recs):  # batches without one: NaN rows
        accel = np.concatenate(
            [np.full((len(r.t_ns), 3), np.nan) if r.accel is None else r.accel for r in recs]
        )
    return Received(
        recs[0].kind,
        np.concatenate([r.t_ns for r in recs]),
        np.concatenate([r.values for r in recs]),
        np.concatenate([r.arrival_ns for r in recs]),
        np.concatenate([r.wall_ns for r in recs]),
        raw,
        accel,
    )


class Loop:
    """Receive until stopped: events from the source to the pipeline, the view at display
    rate, the status line; :meth:`run` returns why it stopped."""

    def __init__(
        self,
        src: Source,
        pipe: Pipeline,
        stop: threading.Event,
        say,
        on_ready,
        *,
        view_interval_s: float | None,
        idle_stop_s: float | None,
        gyro_units: str,
        status: bool | None,
    ) -> None:
        self.src, self.pipe, self.stop, self.say, self.on_ready = src, pipe, stop, say, on_ready
        self.recorder = pipe.recorder
        self.interval_s = view_interval_s or (
            VIEW_INTERVAL_S if pipe.view is not None else NO_VIEW_INTERVAL_S
        )
        self.idle_stop_s = idle_stop_s
        scale = gyro_units == "deg/s" and not src.converts_gyro_units
        self.gyro_scale = DEG if scale else 1.0
        self.tty = sys.stderr.isatty()
        self.status = True if status is None else status
        self.status_every = 0.5 if self.tty else 5.0
        self.reason, self.ended = "stopped", False  # ended: the source said it ended
        self.idle_since = time.monotonic()
        self.next_flush = self.idle_since + self.interval_s  # the next wake-up of _receive
        self.inline = src.pollable and self.interval_s >= INLINE_MIN_S  # read in the loop
        self.default_interval_s = self.interval_s
        self._last_read: float | None = None  # when the previous inline read began
        self._probed = False  # the read after the first bytes is set (_cadence)
        self._pending_next: float | None = None

    def _on_signal(self, signum, frame) -> None:
        self.reason = f"stopped by {signal.Signals(signum).name}"
        self.stop.set()

    def run(self) -> str:
        handlers = {}
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                handlers[sig] = signal.signal(sig, self._on_signal)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", GapWarning)  # gaps are reported once, here
                cpu_start = time.process_time()
                self.src.begin() if self.inline else self.src.start()
                if self.on_ready is not None:
                    self.on_ready({"address": getattr(self.src, "address", None)})
                self._receive()
                self._drain()
                if self.interval_s < self.default_interval_s:
                    self.say(
                        f"read every {self.interval_s * 1e3:.0f} ms (not "
                        f"{self.default_interval_s * 1e3:.0f}): the source's rate filled its "
                        f"buffer sooner"
                    )
                self.pipe.read_interval_s = self.interval_s
                self.pipe.finish()
                self.pipe.flush(final=True)
                self.pipe.cpu_s = time.process_time() - cpu_start
                if self.tty and self.status:
                    sys.stderr.write("\r" + " " * 100 + "\r")
        finally:
            for sig, h in handlers.items():
                signal.signal(sig, h)
        return self.reason

    def _receive(self) -> None:
        """Wake once per view interval (not per event): take every event the source has
        queued, hand the samples on as one batch per kind, send the view batch."""
        pipe = self.pipe
        now = time.monotonic()
        self.next_flush, next_status = now + self.interval_s, now + self.status_every
        window_s = pipe.reorder.window_ns * 1e-9
        while not self._wait(max(0.0, self.next_flush - time.monotonic())):
            if self.inline:
                before = time.monotonic()
                self.src.poll()
                self._cadence(before)
            if self._take():
                return
            now = time.monotonic()
            if len(pipe.reorder) and now - self.idle_since > window_s:
                pipe.release_held()  # the source went quiet: a sample waits <= the window
            pipe.flush()
            if self.recorder is not None:
                self.recorder.maybe_flush()
            if self._pending_next is not None:  # the probe read after the first bytes
                self.next_flush, self._pending_next = self._pending_next, None
            else:
                self.next_flush = max(self.next_flush + self.interval_s, now)  # steady cadence
            if self.status and now >= next_status:
                _status(pipe, self.tty)
                next_status = now + self.status_every
            if self.idle_stop_s is not None and now - self.idle_since > self.idle_stop_s:
                self.reason = f"no sample for {self.idle_stop_s:g} s"
                return

    def _wait(self, timeout_s: float) -> bool:
        """Sleep until the next read; True when stopped. A line source that has sent nothing yet
        is watched meanwhile, and read at its first bytes: the cadence its rate needs is set
        from the first reads, before its buffer can fill (:meth:`_cadence`). ``stop`` is seen
        at the end of the interval, as when sleeping (no more wake-ups than the cadence's)."""
        if not (self.inline and self.src.watchable and not self.src.flowing):
            return self.stop.wait(timeout_s)
        end = time.monotonic() + timeout_s
        while not self.stop.is_set():
            left = end - time.monotonic()
            if left <= 0:
                return False
            if self.src.ready(left):
                self.next_flush = time.monotonic()
                return self.stop.is_set()
        return True

    def _cadence(self, read_at: float) -> None:
        """The interval the source's rate needs, from the read that just ran: the buffer filled
        ``fill`` in the time since the previous read, so a read every ``dt * target / fill``
        finds it at most a quarter full (down to :data:`CADENCE_MIN_S`; never longer than the
        interval set). The first read with data is followed by one after :data:`PROBE_S`,
        which measures the rate."""
        src, prev = self.src, self._last_read
        self._last_read = read_at
        if not src.flowing:
            return
        if not self._probed:
            self._probed = True
            self._pending_next = read_at + PROBE_S
            return
        fill = src.fill
        if fill is None or prev is None or fill <= 0:
            return
        need = max(CADENCE_MIN_S, (read_at - prev) * FILL_TARGET / fill)
        if need < 0.9 * self.interval_s:
            self.interval_s = need  # from the next wake-up on

    def _take(self, data_only: bool = False) -> bool:
        """Every event queued by now, in order; raw items decoded once per key (the source's
        :meth:`~imu_dcm.live.sources.Source.decode`); the samples of each kind go to the
        pipeline as one batch (the truth first: it may start the estimate). True when the
        source ended."""
        events = self.src.events
        raw: dict[int, tuple] = {}  # id(key) -> (key, items), in first-seen order
        data: list[Received | Malformed] = []
        ended = False
        while not ended:
            try:
                ev = events.get_nowait()
            except queue.Empty:
                break
            if type(ev) is Raw:
                raw.setdefault(id(ev.key), (ev.key, []))[1].extend(ev.items)
            elif type(ev) is Received or type(ev) is Malformed:
                data.append(ev)
            elif not data_only:
                ended = self._handle(ev)
        for key, items in raw.values():
            data.extend(self.src.decode(key, items))
        got: dict[str, list[Received]] = {"truth": [], "imu": []}
        for ev in data:
            if type(ev) is Malformed:
                self.pipe.malformed += ev.count
                continue
            got[ev.kind].append(ev)
            if self.recorder is not None:
                self.recorder.add_received(ev)
        if got["truth"]:
            self.pipe.on_truth(_joined(got["truth"]))
        if got["imu"]:
            self.pipe.on_imu(_scaled(_joined(got["imu"]), self.gyro_scale))
            self.idle_since = time.monotonic()
        return ended

    def _handle(self, ev: Channel | Info | End) -> bool:
        """One event from the source other than samples; True when it ends the run."""
        match ev:
            case Channel(kind=kind):
                self.pipe.channels[kind] = ev
                self.pipe.truth_channel |= kind == "truth"
                if self.recorder is not None:
                    self.recorder.add_channel(ev)
            case Info(text=text):
                self.say(text)
            case End(reason=reason):
                self.reason, self.ended = reason, True
                return True
        return False

    def _drain(self) -> None:
        """What the source already delivered, once it has stopped."""
        if self.inline and not self.ended:
            self.src.poll()  # what came since the last wake-up
        self.src.stop()
        self._take(data_only=True)


def _status(pipe: Pipeline, tty: bool) -> None:
    r = pipe.reorder
    dropped = (
        r.dropped_duplicate
        + r.dropped_backward
        + r.dropped_nonfinite
        + r.dropped_implausible
        + pipe.malformed
    )
    step = pipe.median_step_s
    rate = 1.0 / step if step else 0.0
    lat = pipe.latency.last
    p50 = f"{np.median(lat):.1f}" if len(lat) else "-"
    b = pipe.rest.bias_rad_s if pipe.rest is not None else pipe.fixed_bias
    rest = " (at rest)" if pipe.rest is not None and pipe.rest.at_rest else ""
    line = (
        f"{rate:7.1f} Hz  {pipe.n} samples  {dropped} dropped  latency {p50} ms  "
        f"bias ({b[0]:+.4f}, {b[1]:+.4f}, {b[2]:+.4f}) rad/s{rest}"
    )
    sys.stderr.write(("\r" + line) if tty else (line + "\n"))
    sys.stderr.flush()

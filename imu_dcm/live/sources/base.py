"""The base of every live source: a daemon thread (or the session's loop) putting events on a queue.

A source puts :mod:`imu_dcm.live.events` on :attr:`Source.events`, in arrival order. Each
wake-up takes everything that has arrived by then (the datagrams queued on the socket, the bytes
in the pipe, the frames received) and queues it raw (:class:`~imu_dcm.live.events.Raw`): a
source thread wakes at most every ``batch_s`` and only reads; the parse or decode
(:meth:`Source.decode`) runs once per wake-up of the session's loop over everything queued, so
its fixed cost is shared by all the samples in between. A pollable source
(:attr:`Source.pollable`) may instead be read by the session's loop itself, once per wake-up
(:meth:`Source.begin`, :meth:`Source.poll`): one thread wakes per interval, not two.
"""

from __future__ import annotations

import queue
import threading
import time

from imu_dcm.live.events import End, Event, Info, Malformed
from imu_dcm.live.sources.spec import SourceOptions, SourceSpec

__all__ = ["Source"]


class Source:
    """Base: a daemon thread putting events on ``events``; :meth:`stop` ends it.

    A subclass sets the class attributes below and implements :meth:`open` and :meth:`_run`.
    """

    #: The source converts rates to rad/s itself (else the session scales them by the units).
    converts_gyro_units: bool = False
    #: Truth arrives on a channel the source announces (``Channel("truth", ...)``):
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
        #: them (:meth:`imu_dcm.live.loop.Loop._cadence`).
        self.fill: float | None = None
        self.flowing = False
        #: Datagrams the system dropped because its buffer was full (UDP, where it tells).
        self.lost = 0
        self._said: set[str] = set()

    def drop(self, what: str, text: str) -> None:
        """A bad message dropped: counted as malformed, said once per kind ``what``."""
        self.events.put(Malformed(1))
        if what not in self._said:
            self._said.add(what)
            self.events.put(Info(f"dropped {text} (counted as malformed; said once)"))

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

    def decode(self, key, items: list) -> list[Event]:
        """The :class:`~imu_dcm.live.events.Received` and
        :class:`~imu_dcm.live.events.Malformed` events of raw items queued as
        ``Raw(key, items)``: called by the session's loop once per key and wake-up with every
        item of that key in arrival order, so the decode's fixed cost is shared by all of them."""
        raise NotImplementedError

    def _guarded(self) -> None:
        try:
            self._run()
        except Exception as exc:
            why = f"the source stopped on an error it cannot recover from ({type(exc).__name__})"
            self.events.put(End(why))

    def _run(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

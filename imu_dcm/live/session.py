"""A live run: open the source, feed the pipeline, batch the view, stop cleanly, summarise.

:func:`run` is ``imu_dcm.live.run``: it checks the options, opens the source (and the view and
the recording), then loops, waking every ``view_interval_s`` (0.05 s with a view, 0.25 s
without, by default): the source is read (a pollable one by the loop itself, else by its thread
before), its events go to the :class:`imu_dcm.live.pipeline.Pipeline`, the pipeline sends its
batch, a status line goes to stderr. SIGINT / SIGTERM (in the main thread), ``stop``, the end
of input, a lost source or ``idle_stop_s`` end the loop; what the source already delivered is still
processed, the integrator closes its last step, the recording is finished and the summary made.
"""

from __future__ import annotations

import dataclasses
import gc
import queue
import signal
import sys
import threading
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from imu_dcm.app.checks import check_bias, check_init_q_w_b
from imu_dcm.app.rerun_mode import check_rerun_mode, rerun_save_path
from imu_dcm.app.summary import RunFigures, json_ready
from imu_dcm.errors import GapWarning, InputError
from imu_dcm.integrate import METHODS
from imu_dcm.live.lines import TIME_UNITS
from imu_dcm.live.pipeline import DEG, LiveResult, Pipeline
from imu_dcm.live.sources import Received, Source, open_source, parse_source

__all__ = ["LiveOptions", "run"]


def _warm_up(method: str) -> None:
    """Load numba and the compiled kernel before the source opens, so the first samples do not
    wait for them (about 0.7 s with a warm cache, measured as the first second's latency)."""
    from imu_dcm.integrate import integrate_quat
    from imu_dcm.resample import slerp_truth  # noqa: F401 - the truth slerp's modules
    from imu_dcm.streaming import DcmIntegrator

    q0, w, t = [0.0, 0.0, 0.0, 1.0], np.zeros((5, 3)), 0.001 * np.arange(5)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # rotvec_sum's warning belongs to the real run
        integrate_quat(w, t, q0, method)  # the pipeline's start-up uses the batch form
        integ = DcmIntegrator(q0, method)
        integ.update_many_quat(w, t)  # the pipeline feeds arrays (the kernel's feed)
        integ.finish()


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
    return Received(
        recs[0].kind,
        np.concatenate([r.t_ns for r in recs]),
        np.concatenate([r.values for r in recs]),
        np.concatenate([r.arrival_ns for r in recs]),
        np.concatenate([r.wall_ns for r in recs]),
        raw,
    )


#: A source wakes at most every quarter view interval, and at least every 20 ms: a sample
#: waits for its batch and then for the view's, so the batch adds <= 1/4 to the latency.
_BATCH_MAX_S = 0.02
#: From this view interval on, the loop reads a pollable source itself at each wake-up (one
#: thread wakes per interval, not two). Shorter intervals ask for latency: the source's thread
#: reads each sample a batch_s after its first bytes, not held for the next wake-up's read (worth
#: a 10 ms interval's p99).
_INLINE_MIN_S = 0.025
#: The shortest cadence the loop takes when a source's rate needs it, s.
_CADENCE_MIN_S = 0.01
#: The loop reads a source whose buffer fills this much between two reads at most (a quarter:
#: a rate that doubles, or a read that comes late, still finds room).
_FILL_TARGET = 0.25
#: After the first bytes of a source, the next read comes this soon, to measure the rate, s.
_PROBE_S = 0.01
#: The loop's wake-up interval by default: the view's display rate, or, without a view, four
#: times a second (the status line, the recording and the reorder window's release need no
#: more; each wake-up costs CPU of its own, most of it in caches gone cold while asleep).
_VIEW_INTERVAL_S = 0.05
_NO_VIEW_INTERVAL_S = 0.25


def _has_display() -> bool:
    from imu_dcm.viz import has_display

    return has_display()


def _check_outputs(record, force: bool, summary_json, rerun) -> None:
    """The view's mode and the output paths, before the source is opened (imu_dcm.outputs'
    rule)."""
    from imu_dcm.outputs import OutputError, check_output_dir, check_output_file

    check_rerun_mode(rerun, "rerun mode")
    files = []
    if summary_json is not None:
        path = check_output_file(summary_json, (), "--summary-json", kind="json")
        files.append((path, "--summary-json"))
    if rerun_save_path(rerun) is not None:
        path = check_output_file(rerun_save_path(rerun), (), "--rerun save:", kind="rrd")
        files.append((path, "--rerun save:"))
    if record is not None:  # the other outputs must not land in (or be) the bag folder
        bag = check_output_dir(record, force=force, what="--record bag")
        for path, what in files:
            if path.is_relative_to(bag):
                raise OutputError(
                    f"Expected {what} outside the --record bag {str(bag)!r}, got {str(path)!r}"
                )


@dataclass(frozen=True)
class LiveOptions:
    """Options of a live run (the keyword arguments of :func:`run`).

    Attributes
    ----------
    imu_topic, truth_topic : str, optional — WebSocket channel choices (default: by schema, as
        replay); ``truth_topic="none"`` ignores any truth.
    method : str — integrator method (:data:`imu_dcm.integrate.METHODS`), default ``magnus4``.
    bias : "auto", "none" or array_like (3,) — ``auto``: from rest as it happens
        (replay's rest rule, causal); a vector: rad/s.
    gyro_units : "rad/s" or "deg/s" — unit of the rates (line sources and WebSocket alike).
    time_units : "s", "ms", "us" or "ns" — unit of CSV stamps.
    init_q_w_b : array_like (4,), optional — start attitude ``q_w_b``
        ``[x, y, z, w]`` at the first sample (instead of the truth; :mod:`imu_dcm.app.checks`).
    reorder_window_s : float — reorder window in source time, s (default 0.05).
    view_interval_s : float, optional — the loop's wake-up interval: the batches of the view
        and the recording (display rate), s; default 0.05 with a view, 0.25 without.
    rerun : None, "spawn", "serve", "save:PATH.rrd" or "off" — ``None``: spawn with a display,
        else no view (one line names ``serve`` and ``save:``).
    keep_viewer : bool — ``serve``: leave the web viewer running after the run (default True;
        the command line stops it unless ``--keep-viewer``).
    record : path, optional — ROS 2 bag folder written as it goes (received messages +
        ``/estimate/orientation``); ``force`` replaces an existing one.
    summary_json : path, optional — summary written at stop.
    truth_wait_s : float — a source with a truth channel: source time to wait for the truth's
        first sample before starting from the identity (re-anchored when the truth comes), s.
    give_up_s : float or None — WebSocket: stop after this long without a connection, s.
    idle_stop_s : float or None — stop after this long without a sample (None: never), s.
    status : bool, optional — status line on stderr (default: every 0.5 s on a terminal, else
        every 5 s).
    stdin_fd : int, optional — file descriptor of the ``-`` source (default 0).
    """

    imu_topic: str | None = None
    truth_topic: str | None = None
    method: str = "magnus4"
    bias: str | ArrayLike = "auto"
    gyro_units: str = "rad/s"
    time_units: str = "s"
    init_q_w_b: ArrayLike | None = None
    reorder_window_s: float = 0.05
    view_interval_s: float | None = None
    rerun: str | None = None
    keep_viewer: bool = True
    record: str | Path | None = None
    force: bool = False
    summary_json: str | Path | None = None
    truth_wait_s: float = 1.0
    give_up_s: float | None = 30.0
    idle_stop_s: float | None = None
    status: bool | None = None
    stdin_fd: int | None = None


def _checked(source: str, o: LiveOptions) -> tuple:
    """The options checked before any I/O: ``(spec, bias, init_q_w_b)``; raises InputError."""
    spec = parse_source(source)
    if o.method not in METHODS:
        raise InputError(f"Expected method in {METHODS}, got {o.method!r}")
    if o.gyro_units not in ("rad/s", "deg/s"):
        raise InputError(f"Expected gyro units 'rad/s' or 'deg/s', got {o.gyro_units!r}")
    if o.time_units not in TIME_UNITS:
        raise InputError(f"Expected time units in {tuple(TIME_UNITS)}, got {o.time_units!r}")
    if not o.reorder_window_s >= 0 or not (o.view_interval_s is None or o.view_interval_s > 0):
        raise InputError(
            f"Expected reorder window >= 0 s and view interval > 0 s, got "
            f"{o.reorder_window_s!r} and {o.view_interval_s!r}"
        )
    return spec, check_bias(o.bias), check_init_q_w_b(o.init_q_w_b)


def _say_stderr(text: str) -> None:
    print(f"imu-dcm-live: {text}", file=sys.stderr, flush=True)


def run(
    source: str,
    *,
    stop: threading.Event | None = None,
    say=None,
    on_ready=None,
    **options,
) -> LiveResult:
    """Integrate a live gyro stream as it arrives; show, record and summarise it.

    Parameters
    ----------
    source : str
        ``ws://HOST:PORT`` (Foxglove WebSocket), ``udp://HOST:PORT`` (lines), ``-`` (stdin), or
        another scheme of :data:`imu_dcm.live.sources.SOURCES`.
    stop : threading.Event, optional
        Set it to stop (in addition to SIGINT/SIGTERM in the main thread).
    say : callable(str), optional
        Where one-line messages go (default: stderr, prefixed ``imu-dcm-live:``).
    on_ready : callable(info dict), optional
        Called once the source is open (``udp``: ``{"address": (host, port)}``).
    **options
        The fields of :class:`LiveOptions`.

    Returns
    -------
    LiveResult
        Summary keys: ``source, imu_topic, imu_type, truth_topic, truth_type, samples,
        duration_s, rate_hz, dropped_nonfinite, dropped_implausible (a rate over
        :data:`imu_dcm.rates.MAX_RATE_RAD_S`, replay's rule), dropped_duplicate, dropped_backward,
        reordered, malformed, gaps (the first 1000), gap_count, reconnects, lost_by_system (UDP
        datagrams the system dropped, its buffer full, counted to the stop), gyro_units,
        units_evidence (why the rates look like deg/s, or None), bias_mode, bias_rad_s,
        bias_segments, method, start_time_s, unscored_before_s, initial_q_w_b,
        final_q_w_b, final_t_s, truth_samples_used, rms/max error/inclination/heading (deg,
        None without truth), latency_p50_ms, latency_p99_ms, stopped, record, cpu_s (process
        CPU time while receiving, all threads), read_interval_s (the loop's final cadence),
        elapsed_s``; no value is NaN or Inf (None where it cannot be measured).
    """
    started = time.perf_counter()
    o = LiveOptions(**options)
    spec, bias_v, init_q_w_b = _checked(source, o)
    say = say or _say_stderr
    _check_outputs(o.record, o.force, o.summary_json, o.rerun)
    _warm_up(o.method)
    src = _open_source(spec, o)
    recorder = view = None
    try:
        recorder = _open_recorder(source, o, bias_v)
        view = _open_view(o.rerun, source, say)
        pipe = Pipeline(
            method=o.method,
            bias=bias_v,
            init_q_w_b=init_q_w_b,
            window_ns=round(o.reorder_window_s * 1e9),
            truth_wait_s=o.truth_wait_s,
            lines=not src.announces_truth,
            view=view,
            recorder=recorder,
            say=say,
            time_units=o.time_units if src.converts_gyro_units else None,
            check_units=o.gyro_units == "rad/s",
        )
        gc.freeze()  # the start-up's objects: not traversed by every collection while live
        reason = _Loop(src, pipe, o, stop or threading.Event(), say, on_ready).run()
    finally:
        gc.unfreeze()
        _close(src, view, recorder, say, o.keep_viewer)
    summary = json_ready(_summary(pipe, src, source, o, reason, recorder, started))
    if o.summary_json is not None:
        from imu_dcm.outputs import write_json

        write_json(o.summary_json, summary, what="--summary-json file")
    q = None if pipe.q_last is None else np.asarray(pipe.q_last, dtype=float)
    return LiveResult(summary, q, pipe.t_last_ns, pipe.latency.recent())


def _batch_s(o: LiveOptions) -> float:
    """How long a source's wake-up waits for the rest of a batch after its first bytes, s."""
    return min(_BATCH_MAX_S, (o.view_interval_s or _VIEW_INTERVAL_S) / 4)


def _open_source(spec, o: LiveOptions) -> Source:
    """The source of ``spec``, created with the options it reads (not started)."""
    return open_source(
        spec,
        imu_topic=o.imu_topic,
        truth_topic=o.truth_topic,
        gyro_units=o.gyro_units,
        time_units=o.time_units,
        give_up_s=o.give_up_s,
        stdin_fd=o.stdin_fd,
        batch_s=_batch_s(o),
    )


def _open_view(rerun: str | None, source: str, say):
    """The live view, or None: ``off``, or no mode given and no display (one line says how to
    ask for one)."""
    from imu_dcm.live.view import LiveView

    if rerun is None and not _has_display():
        from imu_dcm.viz import HEADLESS_HINT

        say(HEADLESS_HINT)
        return None
    return None if rerun == "off" else LiveView(rerun, title=f"live {source}", say=say)


def _open_recorder(source: str, o: LiveOptions, bias_v):
    if o.record is None:
        return None
    from imu_dcm.live.recorder import LiveRecorder

    return LiveRecorder(
        o.record,
        force=o.force,
        custom_data={
            "imu_dcm.live.source": source,
            "imu_dcm.method": o.method,
            "imu_dcm.bias_mode": bias_v if isinstance(bias_v, str) else "fixed",
        },
    )


def _close(src: Source, view, recorder, say, keep_viewer: bool = True) -> None:
    src.stop()
    if view is not None:
        try:
            line = view.close()
            if view.served is not None and not keep_viewer:
                view.served.stop()
                line = "rerun: web viewer stopped (--keep-viewer leaves it running)"
            if line:
                say(line)
        except Exception as exc:
            say(f"rerun view failed: {type(exc).__name__}: {exc}")
    if recorder is not None:
        recorder.close()


class _Loop:
    """Receive until stopped: events from the source to the pipeline, the view at display
    rate, the status line; :meth:`run` returns why it stopped."""

    def __init__(self, src: Source, pipe: Pipeline, o: LiveOptions, stop, say, on_ready) -> None:
        self.src, self.pipe, self.stop, self.say, self.on_ready = src, pipe, stop, say, on_ready
        self.recorder = pipe.recorder
        self.interval_s = o.view_interval_s or (
            _VIEW_INTERVAL_S if pipe.view is not None else _NO_VIEW_INTERVAL_S
        )
        self.idle_stop_s = o.idle_stop_s
        scale = o.gyro_units == "deg/s" and not src.converts_gyro_units
        self.gyro_scale = DEG if scale else 1.0
        self.tty = sys.stderr.isatty()
        self.status = True if o.status is None else o.status
        self.status_every = 0.5 if self.tty else 5.0
        self.reason, self.ended = "stopped", False  # ended: the source said it ended
        self.idle_since = time.monotonic()
        self.next_flush = self.idle_since + self.interval_s  # the next wake-up of _receive
        self.inline = src.pollable and self.interval_s >= _INLINE_MIN_S  # read in the loop
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
        finds it at most a quarter full (down to :data:`_CADENCE_MIN_S`; never longer than the
        interval set). The first read with data is followed by one after :data:`_PROBE_S`,
        which measures the rate."""
        src, prev = self.src, self._last_read
        self._last_read = read_at
        if not src.flowing:
            return
        if not self._probed:
            self._probed = True
            self._pending_next = read_at + _PROBE_S
            return
        fill = src.fill
        if fill is None or prev is None or fill <= 0:
            return
        need = max(_CADENCE_MIN_S, (read_at - prev) * _FILL_TARGET / fill)
        if need < 0.9 * self.interval_s:
            self.interval_s = need  # from the next wake-up on

    def _take(self, data_only: bool = False) -> bool:
        """Every event queued by now, in order; raw items decoded once per key (the source's
        :meth:`~imu_dcm.live.sources.Source.decode`); the samples of each kind go to the
        pipeline as one batch (the truth first: it may start the estimate). True when the
        source ended."""
        events = self.src.events
        raw: dict[int, tuple] = {}  # id(key) -> (key, items), in first-seen order
        data: list[tuple] = []
        ended = False
        while not ended:
            try:
                ev = events.get_nowait()
            except queue.Empty:
                break
            if ev[0] == "raw":
                raw.setdefault(id(ev[1]), (ev[1], []))[1].extend(ev[2])
            elif ev[0] == "data" or ev[0] == "malformed":
                data.append(ev)
            elif not data_only:
                ended = self._handle(ev)
        for key, items in raw.values():
            data.extend(self.src.decode(key, items))
        got: dict[str, list[Received]] = {"truth": [], "imu": []}
        for ev in data:
            if ev[0] == "malformed":
                self.pipe.malformed += ev[1]
                continue
            got[ev[1].kind].append(ev[1])
            if self.recorder is not None:
                self.recorder.add_received(ev[1])
        if got["truth"]:
            self.pipe.on_truth(_joined(got["truth"]))
        if got["imu"]:
            self.pipe.on_imu(_scaled(_joined(got["imu"]), self.gyro_scale))
            self.idle_since = time.monotonic()
        return ended

    def _handle(self, ev: tuple) -> bool:
        """One event from the source other than samples; True when it ends the run."""
        kind, pipe = ev[0], self.pipe
        if kind == "channel":
            ch = ev[1]
            pipe.channels[ch.kind] = ch
            pipe.truth_channel |= ch.kind == "truth"
            if self.recorder is not None:
                self.recorder.add_channel(ch)
        elif kind == "info":
            self.say(ev[1])
        elif kind == "end":
            self.reason, self.ended = ev[1], True
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


def _summary(
    pipe: Pipeline,
    src: Source,
    source: str,
    o: LiveOptions,
    reason: str,
    recorder,
    started: float,
) -> dict:
    r = pipe.reorder
    imu_ch, truth_ch = pipe.channels.get("imu"), pipe.channels.get("truth")
    dur = float(pipe.recent_t_s[-1]) if len(pipe.recent_t_s) else 0.0
    step = pipe.median_step_s
    st = pipe.stats
    have = st.n > 0
    rms_v = np.sqrt(st.sq / st.n) if have else [None] * 3
    segs = [x.as_dict() for x in pipe.rest.segments] if pipe.rest is not None else []
    bias_mean = (pipe.bias_sum / pipe.bias_n).tolist() if pipe.bias_n else [0.0, 0.0, 0.0]
    figures = RunFigures(
        samples=int(pipe.n),
        samples_estimated=int(pipe.n - pipe.samples_before_start) if pipe.integ else 0,
        duration_s=float(dur),
        rate_hz=1.0 / step if step else None,
        imu_topic=imu_ch.topic if imu_ch else None,
        imu_type=(imu_ch.name or imu_ch.message_encoding) if imu_ch else None,
        truth_topic=truth_ch.topic if truth_ch else ("lines (q_w_b)" if pipe.truth_count else None),
        truth_type=truth_ch.name if truth_ch else None,
        method=o.method,
        gyro_units=o.gyro_units,
        bias_mode=pipe.bias_mode,
        bias_rad_s=tuple(bias_mean),
        bias_segments=tuple(segs),
        start_time_s=pipe.start_t_s,
        initial_q_w_b=None if pipe.q0 is None else tuple(float(v) for v in pipe.q0),
        final_q_w_b=None if pipe.q_last is None else tuple(float(v) for v in pipe.q_last),
        truth_samples_used=int(pipe.truth_used),
        rms_error_deg=float(rms_v[0]) if have else None,
        max_error_deg=float(st.max[0]) if have else None,
        rms_inclination_deg=float(rms_v[1]) if have else None,
        max_inclination_deg=float(st.max[1]) if have else None,
        rms_heading_deg=float(rms_v[2]) if have else None,
        max_heading_deg=float(st.max[2]) if have else None,
        dropped_nonfinite=r.dropped_nonfinite,
        dropped_implausible=r.dropped_implausible,
        dropped_duplicate=r.dropped_duplicate,
        dropped_backward=r.dropped_backward,
        gaps=tuple(pipe.gaps),
        elapsed_s=time.perf_counter() - started,
    )
    return {
        "source": source,
        **figures.to_dict(),
        "reordered": r.reordered,
        "malformed": int(pipe.malformed),
        "gap_count": pipe.gap_count,
        "reconnects": int(getattr(src, "reconnects", 0)),
        "lost_by_system": int(src.lost),
        "units_evidence": pipe.units_evidence,
        "bias_final_rad_s": list(pipe.rest.bias_rad_s) if pipe.rest else list(pipe.fixed_bias),
        "reorder_window_s": r.window_ns * 1e-9,
        "unscored_before_s": pipe.unscored_before_s,
        "final_t_s": None
        if pipe.t_last_ns is None or pipe.t0_ns is None
        else (pipe.t_last_ns - pipe.t0_ns) * 1e-9,
        "latency_p50_ms": pipe.latency.percentile(50),
        "latency_p99_ms": pipe.latency.percentile(99),
        "stopped": reason,
        "record": str(recorder.path) if recorder is not None else None,
        "cpu_s": pipe.cpu_s,
        "read_interval_s": pipe.read_interval_s,
    }

"""The live pipeline: source -> reorder window -> bias -> DcmIntegrator -> view, recording, summary.

:func:`run` connects to the source and, until stopped (SIGINT/SIGTERM, end of input, a lost
source, ``stop`` set, ``idle_stop_s`` without samples), for every sample in stamp order:

1. puts it in order within the reorder window (:mod:`imu_dcm.live.reorder`); later samples,
   duplicate stamps and non-finite rates are dropped and counted;
2. reports a gap when the step exceeds ``GAP_FACTOR`` times the median of the recent steps
   (replay's rule, on the steps seen so far);
3. subtracts the bias (``auto``: :class:`imu_dcm.live.rest.CausalRestBias`; ``none``; a vector);
4. integrates it with :class:`imu_dcm.DcmIntegrator`, starting — as replay does — at the first
   sample inside the truth's coverage, from the truth slerped there (or from ``init_quat`` /
   identity when there is no truth).

Every ``view_interval_s`` (display rate) the new rows go to the rerun view in one batch of
``send_columns`` calls and to the recording; the estimate is compared with the truth where the
truth covers it. Times: ``t_s`` = seconds since the first sample, computed from the source's
int64 ns stamps exactly as replay computes them, so the same messages give the same attitude.
"""

from __future__ import annotations

import math
import signal
import sys
import threading
import time
import warnings
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imu_dcm.errors import GapWarning, InputError
from imu_dcm.integrate import GAP_FACTOR, METHODS, integrate
from imu_dcm.live.reorder import ReorderBuffer
from imu_dcm.live.rest import CausalRestBias
from imu_dcm.live.sources import Received, Source, open_source, parse_source
from imu_dcm.metrics import attitude_error_deg
from imu_dcm.so3 import as_quat_xyzw
from imu_dcm.streaming import DcmIntegrator

__all__ = ["LiveResult", "run"]

DEG = math.pi / 180.0
_TRUTH_KEEP_NS = 5_000_000_000  # truth kept for slerp, ns behind the newest
_ERROR_GIVE_UP_NS = 2_000_000_000  # an estimate uncovered by truth this long: no error


@dataclass(frozen=True)
class LiveResult:
    """What a live run produced.

    Attributes
    ----------
    summary : dict — JSON-ready summary (keys as replay's where they apply; see :func:`run`).
    q_w_b : float64 (4,) or None — final attitude ``[x, y, z, w]`` at ``t_ns`` (None if the
        estimate never started).
    t_ns : int or None — source stamp of the final attitude, ns.
    latency_ms : float64 (n,) — receive -> view log call, per sample logged, ms.
    """

    summary: dict
    q_w_b: NDArray[np.float64] | None
    t_ns: int | None
    latency_ms: NDArray[np.float64] = field(repr=False)


def _slerp(truth_t: NDArray, truth_q: NDArray, t_ns: NDArray) -> NDArray:
    from imu_dcm.replay.core import slerp_truth

    return slerp_truth(truth_t, truth_q, t_ns)


class _Stats:
    """Running error statistics (RMS and max of total, inclination, heading)."""

    def __init__(self) -> None:
        self.n = 0
        self.sq = np.zeros(3)
        self.max = np.zeros(3)

    def add(self, err: NDArray) -> None:
        if len(err):
            self.n += len(err)
            self.sq += (err * err).sum(axis=0)
            self.max = np.maximum(self.max, err.max(axis=0))


class _Pipeline:
    def __init__(self, *, method: str, bias, init_q: NDArray | None, window_ns: int,
                 truth_wait_s: float, lines: bool, view, recorder, say) -> None:
        self.method = method
        self.bias_mode = "auto" if isinstance(bias, str) and bias == "auto" else (
            "none" if isinstance(bias, str) else "fixed")
        self.fixed_bias = (tuple(float(v) for v in bias) if self.bias_mode == "fixed"
                           else (0.0, 0.0, 0.0))  # fmt: skip
        self.rest = CausalRestBias() if self.bias_mode == "auto" else None
        self.init_q = init_q
        self.reorder = ReorderBuffer(window_ns)
        self.truth_wait_ns = int(truth_wait_s * 1e9)
        self.lines = lines
        self.view = view
        self.recorder = recorder
        self.say = say
        self.t0_ns: int | None = None
        self.n = 0
        self.malformed = 0
        self.gaps: list[tuple[float, float]] = []
        self._steps: deque = deque(maxlen=64)
        self._median = math.inf
        self._since_median = 0
        self._prev_t_s: float | None = None
        self.integ: DcmIntegrator | None = None
        self._warm: list | None = None
        self.q0: NDArray | None = None
        self.start_t_s: float | None = None
        self.waiting: list[tuple[int, float, tuple]] = []
        self.truth_channel = False
        self.truth_t: deque = deque()  # arrays of truth stamps / quats, oldest first
        self.truth_q: deque = deque()
        self.truth_max_ns: int | None = None
        self.truth_count = 0
        self._recent_ns: deque = deque(maxlen=4)  # (t_s, t_ns) of the newest samples
        self.last_est_t_s = -math.inf
        self.q_last: NDArray | None = None
        self.t_last_ns: int | None = None
        self.bias_sum = np.zeros(3)
        self.bias_n = 0
        self.stats = _Stats()
        self.truth_used = 0
        # rows since the last flush
        self.g_t: list[float] = []
        self.g_w: list[tuple] = []
        self.g_arr: list[int] = []
        self.e_rows: list[tuple[int, float, tuple]] = []  # estimate (t_ns, t_s, q)
        self.err_pending: list[tuple[int, float, tuple]] = []
        self.tr_rows_t: list[int] = []
        self.tr_rows_q: list[NDArray] = []
        self.latency: list[NDArray] = []
        self.last_arrival_wall = time.monotonic()
        self.samples_before_start = 0

    # -- input -----------------------------------------------------------------------------
    def on_imu(self, rec: Received) -> None:
        out: list = []
        push = self.reorder.push
        for t, w, a in zip(rec.t_ns.tolist(), rec.values.tolist(), rec.arrival_ns.tolist()):
            push(t, w, a, out)
        if out:
            self._process(out)
        self.last_arrival_wall = time.monotonic()

    def on_truth(self, rec: Received) -> None:
        ok = np.all(np.isfinite(rec.values), axis=1)
        if not ok.any():
            return
        t, q = rec.t_ns[ok], rec.values[ok]
        self.truth_t.append(t)
        self.truth_q.append(q)
        self.truth_count += len(t)
        m = int(t.max())
        self.truth_max_ns = m if self.truth_max_ns is None else max(self.truth_max_ns, m)
        while len(self.truth_t) > 1 and int(self.truth_t[0].max()) < m - _TRUTH_KEEP_NS:
            self.truth_t.popleft()
            self.truth_q.popleft()
        self.tr_rows_t.extend(t.tolist())
        self.tr_rows_q.append(q)
        if self.integ is None and self.waiting:
            self._try_start()

    def _truth_arrays(self) -> tuple[NDArray, NDArray]:
        return np.concatenate(list(self.truth_t)), np.concatenate(list(self.truth_q))

    # -- per sample ------------------------------------------------------------------------
    def _process(self, released: list) -> None:
        rest = self.rest
        fixed = self.fixed_bias
        for t_ns, w, arrival in released:
            if self.t0_ns is None:
                self.t0_ns = t_ns
            t_s = (t_ns - self.t0_ns) * 1e-9
            prev = self._prev_t_s
            if prev is not None:
                h = t_s - prev
                if h > GAP_FACTOR * self._median and len(self._steps) >= 3:
                    self.gaps.append((prev, h))
                    self.say(f"gap of {h:.3f} s after t = {prev:.3f} s "
                             f"(> {GAP_FACTOR:g}x the median step {self._median * 1e3:.3f} ms)")
                self._steps.append(h)
                self._since_median += 1
                if self._since_median >= 16 or len(self._steps) < 16:
                    self._since_median = 0
                    s = sorted(self._steps)
                    self._median = s[len(s) // 2]
            self._prev_t_s = t_s
            b = rest.update(w, t_s) if rest is not None else fixed
            wc = (w[0] - b[0], w[1] - b[1], w[2] - b[2])
            self.n += 1
            self.g_t.append(t_s)
            self.g_w.append(wc)
            self.g_arr.append(arrival)
            self._recent_ns.append((t_s, t_ns))
            if self.integ is None:
                self.waiting.append((t_ns, t_s, wc))
                self._try_start()
            else:
                self._step(t_ns, t_s, wc)
            if self.integ is not None:
                self.bias_sum += b
                self.bias_n += 1

    def _start(self, i: int, q0: NDArray, why: str | None) -> None:
        waiting = self.waiting
        self.samples_before_start += i
        self.q0 = np.asarray(q0, dtype=float)
        t_ns, t_s, _ = waiting[i]
        self.start_t_s = t_s
        self.integ = DcmIntegrator(self.q0, self.method)
        self._warm = [] if self.method == "magnus4" else None
        if why:
            self.say(why)
        self.waiting = []
        for t_ns, t_s, wc in waiting[i:]:
            self._step(t_ns, t_s, wc)

    def _try_start(self) -> None:
        waiting = self.waiting
        if self.init_q is not None:
            self._start(0, self.init_q, None)
            return
        if self.truth_max_ns is not None:
            tt, tq = self._truth_arrays()
            stamps = np.array([w[0] for w in waiting], dtype=np.int64)
            covered = stamps <= self.truth_max_ns
            if not covered.any():
                if stamps[-1] - stamps[0] >= 10 * self.truth_wait_ns:  # the truth stalled
                    self._start(0, np.array([0.0, 0.0, 0.0, 1.0]),
                                f"the truth stopped {(stamps[-1] - self.truth_max_ns) * 1e-9:.3f} s "
                                f"before the gyro: starting from the identity attitude")
                return
            q = _slerp(tt, tq, stamps[covered])
            ok = np.flatnonzero(np.all(np.isfinite(q), axis=1))
            if len(ok):
                self._start(int(ok[0]), q[ok[0]], None)
            else:
                k = int(covered.sum())  # covered but outside the truth: never estimated
                self.samples_before_start += k
                del waiting[:k]
            return
        if self.lines and not self.truth_channel:
            self._start(0, np.array([0.0, 0.0, 0.0, 1.0]), None)
            return
        if waiting[-1][0] - waiting[0][0] >= self.truth_wait_ns:
            self._start(0, np.array([0.0, 0.0, 0.0, 1.0]),
                        f"no truth within {self.truth_wait_ns * 1e-9:g} s of source time: "
                        f"starting from the identity attitude")  # fmt: skip

    def _ns_of(self, t_s: float) -> int:
        for ts, tn in reversed(self._recent_ns):
            if ts == t_s:
                return tn
        return round(t_s * 1e9) + (self.t0_ns or 0)

    def _step(self, t_ns: int, t_s: float, wc: tuple) -> None:
        q = self.integ.update(wc, t_s)
        te = self.integ.t_s
        warm = self._warm
        if warm is not None:
            warm.append((t_ns, t_s, wc))
            if len(warm) == 4:
                # magnus4 commits its first two steps at once (the start stencil needs four
                # samples): the attitude at the second stamp comes from the batch integrator on
                # the same four samples, which is what the streaming one computes inside.
                self._warm = None
                W = np.array([r[2] for r in warm])
                T = np.array([r[1] for r in warm])
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", GapWarning)
                    q1 = integrate(W, T, self.q0, self.method).as_quat()[1]
                self.e_rows.append((warm[1][0], warm[1][1], tuple(q1.tolist())))
                self.last_est_t_s = warm[1][1]
        if te is not None and te > self.last_est_t_s:
            self.last_est_t_s = te
            tn = t_ns if te == t_s else self._ns_of(te)
            row = (tn, te, tuple(q.tolist()))
            self.e_rows.append(row)
            self.q_last, self.t_last_ns = q, tn

    def finish(self) -> None:
        out: list = []
        self.reorder.flush(out)
        if out:
            self._process(out)
        if self.integ is None and self.waiting:
            q0 = self.init_q if self.init_q is not None else np.array([0.0, 0.0, 0.0, 1.0])
            if self.truth_max_ns is not None:
                tt, tq = self._truth_arrays()
                q = _slerp(tt, tq, np.array([w[0] for w in self.waiting], np.int64))
                ok = np.flatnonzero(np.all(np.isfinite(q), axis=1))
                if len(ok):
                    self._start(int(ok[0]), q[ok[0]], None)
            if self.integ is None:
                self._start(0, q0, None)
        if self.integ is not None:
            q = self.integ.finish()
            te = self.integ.t_s
            if te is not None and te > self.last_est_t_s:
                self.last_est_t_s = te
                tn = self._ns_of(te)
                self.e_rows.append((tn, te, tuple(q.tolist())))
                self.q_last, self.t_last_ns = q, tn
            elif te is not None:
                self.q_last = q
        if self.rest is not None:
            self.rest.finish()

    # -- display rate ----------------------------------------------------------------------
    def flush(self, final: bool = False) -> None:
        """Errors for covered estimates, one batch to the view and the recording, latency."""
        est = self.e_rows
        self.e_rows = []
        err_t: list[float] = []
        err: NDArray = np.zeros((0, 3))
        if self.truth_count:
            pend = self.err_pending + est
            if pend:
                stamps = np.array([r[0] for r in pend], np.int64)
                cover = self.truth_max_ns if self.truth_max_ns is not None else -1
                ready = stamps <= cover
                newest = stamps[-1]
                give_up = ~ready & (final | (stamps < newest - _ERROR_GIVE_UP_NS))
                idx = np.flatnonzero(ready)
                if len(idx):
                    tt, tq = self._truth_arrays()
                    qt = _slerp(tt, tq, stamps[idx])
                    qe = np.array([pend[i][2] for i in idx])
                    ok = np.all(np.isfinite(qt), axis=1)
                    if ok.any():
                        e = attitude_error_deg(qe[ok], qt[ok])
                        err = np.stack([e.total_deg, e.inclination_deg, e.heading_deg], axis=1)
                        err_t = [pend[i][1] for i in idx[ok]]
                        self.stats.add(err)
                        self.truth_used += int(ok.sum())
                self.err_pending = [pend[i] for i in np.flatnonzero(~ready & ~give_up)]
        tr_t = self.tr_rows_t
        tr_q = np.concatenate(self.tr_rows_q) if self.tr_rows_q else np.zeros((0, 4))
        self.tr_rows_t, self.tr_rows_q = [], []
        g_t, g_w, g_arr = self.g_t, self.g_w, self.g_arr
        self.g_t, self.g_w, self.g_arr = [], [], []
        t0 = self.t0_ns
        if self.view is not None and t0 is not None:
            tr_s = (np.array(tr_t, np.int64) - t0) * 1e-9 if tr_t else np.zeros(0)
            self.view.log(
                gyro_t_s=np.array(g_t), omega_b=np.array(g_w).reshape(-1, 3),
                est_t_s=np.array([r[1] for r in est]),
                q_est=np.array([r[2] for r in est]).reshape(-1, 4),
                truth_t_s=tr_s, q_truth=tr_q,
                err_t_s=np.array(err_t), err_deg=err,
            )  # fmt: skip
        elif t0 is None and tr_t:  # no gyro sample yet: keep the truth rows for later
            self.tr_rows_t, self.tr_rows_q = tr_t, [tr_q]
        if g_arr:
            now = time.perf_counter_ns()
            self.latency.append((now - np.array(g_arr, np.int64)) * 1e-6)
        if self.recorder is not None and est:
            self.recorder.add_estimate(np.array([r[0] for r in est], np.int64),
                                       np.array([r[2] for r in est]))  # fmt: skip


def _parse_bias(bias) -> str | tuple:
    if isinstance(bias, str):
        if bias in ("auto", "none"):
            return bias
        try:
            bias = [float(v) for v in bias.split(",")]
        except ValueError:
            raise InputError(f"Expected bias auto, none or x,y,z in rad/s, got {bias!r}") from None
    b = np.asarray(bias, dtype=float)
    if b.shape != (3,) or not np.all(np.isfinite(b)):
        raise InputError(f"Expected bias auto, none or 3 finite numbers (rad/s), got {bias!r}")
    return tuple(b.tolist())


def _pct(a: NDArray, p: float) -> float | None:
    return float(np.percentile(a, p)) if len(a) else None


def run(
    source: str,
    *,
    imu_topic: str | None = None,
    truth_topic: str | None = None,
    method: str = "magnus4",
    bias: str | ArrayLike = "auto",
    gyro_units: str = "rad/s",
    time_units: str = "s",
    init_quat: ArrayLike | None = None,
    reorder_window_s: float = 0.05,
    view_interval_s: float = 0.05,
    rerun: str | None = None,
    record: str | Path | None = None,
    force: bool = False,
    summary_json: str | Path | None = None,
    truth_wait_s: float = 1.0,
    give_up_s: float | None = 30.0,
    idle_stop_s: float | None = None,
    stop: threading.Event | None = None,
    status: bool | None = None,
    say=None,
    stdin_fd: int | None = None,
    on_ready=None,
) -> LiveResult:
    """Integrate a live gyro stream as it arrives; show, record and summarise it.

    Parameters
    ----------
    source : str
        ``ws://HOST:PORT`` (Foxglove WebSocket), ``udp://HOST:PORT`` (lines) or ``-`` (stdin).
    imu_topic, truth_topic : str, optional
        WebSocket channel choices (default: by schema, as replay); ``truth_topic="none"``
        ignores any truth.
    method : str
        Integrator method (:data:`imu_dcm.integrate.METHODS`), default ``magnus4``.
    bias : "auto", "none", "x,y,z" or array_like (3,)
        ``auto``: from rest as it happens (replay's rest rule, causal); a vector: rad/s.
    gyro_units : {"rad/s", "deg/s"}
        Unit of the rates (line sources and WebSocket alike).
    time_units : {"s", "ms", "us", "ns"}
        Unit of CSV stamps.
    init_quat : array_like (4,) or "x,y,z,w", optional
        Start attitude ``q_w_b`` ``[x, y, z, w]`` at the first sample (instead of the truth).
    reorder_window_s : float
        Reorder window in source time, s (default 0.05).
    view_interval_s : float
        Batching interval of the view and the recording (display rate), s.
    rerun : {None, "spawn", "serve", "save:PATH.rrd", "off"}
        ``None``: spawn with a display, else serve the web viewer on 127.0.0.1.
    record : path, optional
        ROS 2 bag folder to write as it goes (received messages + ``/estimate/orientation``).
    force : bool
        Replace an existing ``record`` folder.
    summary_json : path, optional
        Summary written at stop.
    truth_wait_s : float
        WebSocket without a truth channel: source time to wait for one before starting from the
        identity, s.
    give_up_s : float or None
        WebSocket: stop after this long without a connection (None: never), s.
    idle_stop_s : float or None
        Stop after this long without a sample (None: never), s.
    stop : threading.Event, optional
        Set it to stop (in addition to SIGINT/SIGTERM in the main thread).
    status : bool, optional
        Status line on stderr (default: when stderr is a terminal, every 0.5 s; else every 5 s).
    say : callable(str), optional
        Where one-line messages go (default: stderr, prefixed ``imu-dcm-live:``).
    stdin_fd : int, optional
        File descriptor of the ``-`` source (default 0).
    on_ready : callable(info dict), optional
        Called once the source is open (``udp``: ``{"address": (host, port)}``).

    Returns
    -------
    LiveResult
        Summary keys: ``source, imu_topic, imu_type, truth_topic, truth_type, samples,
        duration_s, rate_hz, dropped_nonfinite, dropped_duplicate, dropped_backward,
        reordered, malformed, gaps, reconnects, gyro_units, bias_mode, bias_rad_s,
        bias_segments, method, start_time_s, initial_quat_xyzw, final_quat_xyzw, final_t_s,
        truth_samples_used, rms/max error/inclination/heading (deg, None without truth),
        latency_p50_ms, latency_p99_ms, stopped, record, cpu_s (process CPU time while
        receiving, all threads), elapsed_s``.
    """
    started = time.perf_counter()
    spec = parse_source(source)
    if method not in METHODS:
        raise InputError(f"Expected method in {METHODS}, got {method!r}")
    if gyro_units not in ("rad/s", "deg/s"):
        raise InputError(f"Expected gyro units 'rad/s' or 'deg/s', got {gyro_units!r}")
    from imu_dcm.live.lines import TIME_UNITS

    if time_units not in TIME_UNITS:
        raise InputError(f"Expected time units in {tuple(TIME_UNITS)}, got {time_units!r}")
    if not reorder_window_s >= 0 or not view_interval_s > 0:
        raise InputError(f"Expected reorder window >= 0 s and view interval > 0 s, got "
                         f"{reorder_window_s!r} and {view_interval_s!r}")  # fmt: skip
    bias_v = _parse_bias(bias)
    init_q = None
    if init_quat is not None:
        if isinstance(init_quat, str):
            try:
                init_quat = [float(v) for v in init_quat.split(",")]
            except ValueError:
                raise InputError(f"Expected init quaternion x,y,z,w, got {init_quat!r}") from None
        init_q = as_quat_xyzw(np.asarray(init_quat, dtype=float), "init_quat")
    if say is None:
        def say(text: str) -> None:
            print(f"imu-dcm-live: {text}", file=sys.stderr, flush=True)
    from imu_dcm.live.view import LiveView, check_mode

    check_mode(rerun)
    src: Source = open_source(spec, imu_topic=imu_topic, truth_topic=truth_topic,
                              gyro_units=gyro_units, time_units=time_units, give_up_s=give_up_s,
                              stdin_fd=stdin_fd)  # fmt: skip
    recorder = view = None
    try:
        if record is not None:
            from imu_dcm.live.recorder import LiveRecorder

            recorder = LiveRecorder(record, force=force, custom_data={
                "imu_dcm.live.source": source, "imu_dcm.method": method,
                "imu_dcm.bias_mode": bias_v if isinstance(bias_v, str) else "fixed"})
        if rerun != "off":
            view = LiveView(rerun, title=f"live {source}", say=say)
        pipe = _Pipeline(method=method, bias=bias_v, init_q=init_q,
                         window_ns=round(reorder_window_s * 1e9), truth_wait_s=truth_wait_s,
                         lines=spec.kind != "ws", view=view, recorder=recorder, say=say)
        gyro_scale = DEG if (gyro_units == "deg/s" and spec.kind == "ws") else 1.0
        stop_event = stop or threading.Event()
        reason = _loop(src, pipe, stop_event, gyro_scale, view_interval_s, status, say,
                       idle_stop_s, recorder, on_ready, spec)  # fmt: skip
    finally:
        src.stop()
        if view is not None:
            try:
                line = view.close()
                if line:
                    say(line)
            except Exception as exc:  # noqa: BLE001 - the view never loses the run
                say(f"rerun view failed: {type(exc).__name__}: {exc}")
        if recorder is not None:
            recorder.close()
    lat = np.concatenate(pipe.latency) if pipe.latency else np.zeros(0)
    summary = _summary(pipe, src, spec, source, method, bias_v, gyro_units, reason, lat,
                       recorder, started)  # fmt: skip
    if summary_json is not None:
        from imu_dcm.live.__main__ import write_json

        write_json(Path(summary_json), summary)
    q = None if pipe.q_last is None else np.asarray(pipe.q_last, dtype=float)
    return LiveResult(summary, q, pipe.t_last_ns, lat)


def _loop(src: Source, pipe: _Pipeline, stop: threading.Event, gyro_scale: float,
          interval_s: float, status: bool | None, say, idle_stop_s, recorder, on_ready,
          spec) -> str:
    """Receive until stopped; returns why it stopped."""
    import queue

    handlers = {}
    reason = ["stopped"]

    def on_signal(signum, frame):
        reason[0] = f"stopped by {signal.Signals(signum).name}"
        stop.set()

    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            handlers[sig] = signal.signal(sig, on_signal)
    tty = sys.stderr.isatty()
    if status is None:
        status = True
    status_every = 0.5 if tty else 5.0
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", GapWarning)  # gaps are reported once, here
            pipe.cpu_start = time.process_time()
            src.start()
            if on_ready is not None:
                info = {"address": getattr(src, "address", None)}
                on_ready(info)
            events = src.events
            next_flush = time.monotonic() + interval_s
            next_status = time.monotonic() + status_every
            idle_since = time.monotonic()
            while not stop.is_set():
                timeout = max(0.0, next_flush - time.monotonic())
                try:
                    ev = events.get(timeout=timeout)
                except queue.Empty:
                    ev = None
                if ev is not None:
                    kind = ev[0]
                    if kind == "data":
                        rec: Received = ev[1]
                        if rec.kind == "imu":
                            if gyro_scale != 1.0:
                                rec = Received(rec.kind, rec.t_ns, rec.values * gyro_scale,
                                               rec.arrival_ns, rec.wall_ns, rec.raw)  # fmt: skip
                            pipe.on_imu(rec)
                            idle_since = time.monotonic()
                        else:
                            pipe.on_truth(rec)
                        if recorder is not None:
                            recorder.add_received(rec)
                    elif kind == "malformed":
                        pipe.malformed += ev[1]
                    elif kind == "channel":
                        ch = ev[1]
                        pipe.channels = getattr(pipe, "channels", {})
                        pipe.channels[ch.kind] = ch
                        if ch.kind == "truth":
                            pipe.truth_channel = True
                        if recorder is not None:
                            recorder.add_channel(ch)
                    elif kind == "info":
                        say(ev[1])
                    elif kind == "end":
                        reason[0] = ev[1]
                        break
                now = time.monotonic()
                if now >= next_flush:
                    pipe.flush()
                    if recorder is not None:
                        recorder.maybe_flush()
                    next_flush = now + interval_s
                if status and now >= next_status:
                    _status(pipe, src, tty)
                    next_status = now + status_every
                if idle_stop_s is not None and now - idle_since > idle_stop_s:
                    reason[0] = f"no sample for {idle_stop_s:g} s"
                    break
            # drain what the source already delivered
            src.stop()
            while True:
                try:
                    ev = src.events.get_nowait()
                except queue.Empty:
                    break
                if ev[0] == "data":
                    rec = ev[1]
                    if rec.kind == "imu":
                        if gyro_scale != 1.0:
                            rec = Received(rec.kind, rec.t_ns, rec.values * gyro_scale,
                                           rec.arrival_ns, rec.wall_ns, rec.raw)  # fmt: skip
                        pipe.on_imu(rec)
                    else:
                        pipe.on_truth(rec)
                    if recorder is not None:
                        recorder.add_received(rec)
                elif ev[0] == "malformed":
                    pipe.malformed += ev[1]
            pipe.finish()
            pipe.flush(final=True)
            pipe.cpu_s = time.process_time() - pipe.cpu_start
            if tty and status:
                sys.stderr.write("\r" + " " * 100 + "\r")
    finally:
        for sig, h in handlers.items():
            signal.signal(sig, h)
    return reason[0]


def _status(pipe: _Pipeline, src: Source, tty: bool) -> None:
    r = pipe.reorder
    dropped = r.dropped_duplicate + r.dropped_backward + r.dropped_nonfinite + pipe.malformed
    rate = 1.0 / pipe._median if pipe._median not in (0.0, math.inf) else 0.0
    lat = pipe.latency[-1] if pipe.latency else np.zeros(0)
    p50 = f"{np.median(lat):.1f}" if len(lat) else "-"
    b = pipe.rest.bias_rad_s if pipe.rest is not None else pipe.fixed_bias
    rest = " (at rest)" if pipe.rest is not None and pipe.rest.at_rest else ""
    line = (f"{rate:7.1f} Hz  {pipe.n} samples  {dropped} dropped  latency {p50} ms  "
            f"bias ({b[0]:+.4f}, {b[1]:+.4f}, {b[2]:+.4f}) rad/s{rest}")
    sys.stderr.write(("\r" + line) if tty else (line + "\n"))
    sys.stderr.flush()


def _summary(pipe: _Pipeline, src: Source, spec, source: str, method: str, bias_v, gyro_units,
             reason: str, lat: NDArray, recorder, started: float) -> dict:
    r = pipe.reorder
    chans = getattr(pipe, "channels", {})
    imu_ch, truth_ch = chans.get("imu"), chans.get("truth")
    dur = pipe._prev_t_s or 0.0
    steps = sorted(pipe._steps)
    st = pipe.stats
    have = st.n > 0
    rms_v = np.sqrt(st.sq / st.n) if have else [None] * 3
    if pipe.rest is not None:
        segs = list(pipe.rest.segments)
    else:
        segs = []
    bias_mean = (pipe.bias_sum / pipe.bias_n).tolist() if pipe.bias_n else [0.0, 0.0, 0.0]
    return {
        "source": source,
        "imu_topic": imu_ch.topic if imu_ch else None,
        "imu_type": (imu_ch.name or imu_ch.message_encoding) if imu_ch else None,
        "truth_topic": truth_ch.topic if truth_ch else ("lines (q_w_b)" if pipe.truth_count
                                                       else None),
        "truth_type": truth_ch.name if truth_ch else None,
        "samples": int(pipe.n),
        "samples_estimated": int(pipe.n - pipe.samples_before_start) if pipe.integ else 0,
        "duration_s": float(dur),
        "rate_hz": float(1.0 / steps[len(steps) // 2]) if steps else None,
        "dropped_nonfinite": r.dropped_nonfinite,
        "dropped_duplicate": r.dropped_duplicate,
        "dropped_backward": r.dropped_backward,
        "reordered": r.reordered,
        "malformed": int(pipe.malformed),
        "gaps": [{"t_s": a, "length_s": d} for a, d in pipe.gaps],
        "reconnects": int(getattr(src, "reconnects", 0)),
        "gyro_units": gyro_units,
        "bias_mode": pipe.bias_mode,
        "bias_rad_s": bias_mean,
        "bias_final_rad_s": list(pipe.rest.bias_rad_s) if pipe.rest else list(pipe.fixed_bias),
        "bias_segments": segs,
        "method": method,
        "reorder_window_s": r.window_ns * 1e-9,
        "start_time_s": pipe.start_t_s,
        "initial_quat_xyzw": None if pipe.q0 is None else [float(v) for v in pipe.q0],
        "final_quat_xyzw": None if pipe.q_last is None else [float(v) for v in pipe.q_last],
        "final_t_s": None if pipe.t_last_ns is None or pipe.t0_ns is None
        else (pipe.t_last_ns - pipe.t0_ns) * 1e-9,
        "truth_samples_used": int(pipe.truth_used),
        "rms_error_deg": float(rms_v[0]) if have else None,
        "max_error_deg": float(st.max[0]) if have else None,
        "rms_inclination_deg": float(rms_v[1]) if have else None,
        "max_inclination_deg": float(st.max[1]) if have else None,
        "rms_heading_deg": float(rms_v[2]) if have else None,
        "max_heading_deg": float(st.max[2]) if have else None,
        "latency_p50_ms": _pct(lat, 50),
        "latency_p99_ms": _pct(lat, 99),
        "stopped": reason,
        "record": str(recorder.path) if recorder is not None else None,
        "cpu_s": getattr(pipe, "cpu_s", None),
        "elapsed_s": time.perf_counter() - started,
    }

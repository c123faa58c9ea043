"""A live run: open the source, feed the pipeline, batch the view, stop cleanly, summarise.

:func:`run` is ``imu_dcm.live.run``: it checks the options, opens the source (and the view and
the recording), then loops: events from the source thread go to the
:class:`imu_dcm.live.pipeline.Pipeline`; every ``view_interval_s`` the pipeline sends its batch;
a status line goes to stderr. SIGINT / SIGTERM (in the main thread), ``stop``, the end of input,
a lost source or ``idle_stop_s`` end the loop; what the source already delivered is still
processed, the integrator closes its last step, the recording is finished and the summary made.
"""

from __future__ import annotations

import dataclasses
import math
import signal
import sys
import threading
import time
import warnings
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imu_dcm.errors import GapWarning, InputError
from imu_dcm.integrate import METHODS
from imu_dcm.live.pipeline import DEG, LiveResult, Pipeline
from imu_dcm.live.sources import Received, Source, open_source, parse_source
from imu_dcm.so3 import as_quat_xyzw

__all__ = ["run"]


def _warm_up(method: str) -> None:
    """Load numba and the compiled kernel before the source opens, so the first samples do not
    wait for them (about 0.7 s with a warm cache, measured as the first second's latency)."""
    from imu_dcm.integrate import integrate
    from imu_dcm.replay.core import slerp_truth  # noqa: F401 - the truth slerp's modules
    from imu_dcm.streaming import DcmIntegrator

    q0, w, t = [0.0, 0.0, 0.0, 1.0], np.zeros((5, 3)), 0.001 * np.arange(5)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # rotvec_sum's warning belongs to the real run
        integrate(w, t, q0, method)  # the pipeline's start-up uses the batch form (and scipy)
        integ = DcmIntegrator(q0, method)
        for wk, tk in zip(w, t, strict=True):
            integ.update(wk, float(tk))
        integ.finish()


def _scaled(rec: Received, gyro_scale: float) -> Received:
    """The IMU sample with its rates converted to rad/s (``gyro_scale`` rad/s per unit)."""
    if gyro_scale == 1.0:
        return rec
    return dataclasses.replace(rec, values=rec.values * gyro_scale)


def _check_bias(bias) -> str | tuple:
    """``"auto"``, ``"none"`` or 3 finite numbers (rad/s); text is parsed by the command line
    (:func:`imu_dcm.cli.parse_bias`)."""
    if isinstance(bias, str):
        if bias in ("auto", "none"):
            return bias
        raise InputError(f"Expected bias 'auto', 'none' or 3 numbers (rad/s), got {bias!r}")
    try:
        b = np.asarray(bias, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"Expected bias as 3 finite numbers (rad/s), got {bias!r}") from None
    if b.shape != (3,) or not np.all(np.isfinite(b)):
        raise InputError(f"Expected bias auto, none or 3 finite numbers (rad/s), got {bias!r}")
    return tuple(b.tolist())


def _has_display() -> bool:
    from imu_dcm.viz import has_display

    return has_display()


def _check_outputs(record, force: bool, summary_json, rerun) -> None:
    """The output paths, before the source is opened (imu_dcm.outputs' rule)."""
    from imu_dcm.outputs import check_output_dir, check_output_file

    if record is not None:
        check_output_dir(record, force=force, what="--record bag")
    if summary_json is not None:
        check_output_file(summary_json, (), "--summary-json file")
    if isinstance(rerun, str) and rerun.startswith("save:"):
        check_output_file(rerun[len("save:") :], (), "--rerun save: file")


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
    keep_viewer: bool = True,
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
    bias : "auto", "none" or array_like (3,)
        ``auto``: from rest as it happens (replay's rest rule, causal); a vector: rad/s.
    gyro_units : {"rad/s", "deg/s"}
        Unit of the rates (line sources and WebSocket alike).
    time_units : {"s", "ms", "us", "ns"}
        Unit of CSV stamps.
    init_quat : array_like (4,), optional
        Start attitude ``q_w_b`` ``[x, y, z, w]`` at the first sample (instead of the truth).
    reorder_window_s : float
        Reorder window in source time, s (default 0.05).
    view_interval_s : float
        Batching interval of the view and the recording (display rate), s.
    rerun : {None, "spawn", "serve", "save:PATH.rrd", "off"}
        ``None``: spawn with a display, else no view (one line names ``serve`` and ``save:``).
    keep_viewer : bool
        ``serve``: leave the web viewer running after the run (default True; the command line
        stops it unless ``--keep-viewer``).
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
        raise InputError(
            f"Expected reorder window >= 0 s and view interval > 0 s, got "
            f"{reorder_window_s!r} and {view_interval_s!r}"
        )
    bias_v = _check_bias(bias)
    init_q = None
    if init_quat is not None:
        init_q = as_quat_xyzw(np.asarray(init_quat, dtype=float), "init_quat")
    if say is None:

        def say(text: str) -> None:
            print(f"imu-dcm-live: {text}", file=sys.stderr, flush=True)

    from imu_dcm.live.view import LiveView, check_mode

    check_mode(rerun)
    _check_outputs(record, force, summary_json, rerun)
    _warm_up(method)
    src: Source = open_source(
        spec,
        imu_topic=imu_topic,
        truth_topic=truth_topic,
        gyro_units=gyro_units,
        time_units=time_units,
        give_up_s=give_up_s,
        stdin_fd=stdin_fd,
    )
    recorder = view = None
    try:
        if record is not None:
            from imu_dcm.live.recorder import LiveRecorder

            recorder = LiveRecorder(
                record,
                force=force,
                custom_data={
                    "imu_dcm.live.source": source,
                    "imu_dcm.method": method,
                    "imu_dcm.bias_mode": bias_v if isinstance(bias_v, str) else "fixed",
                },
            )
        if rerun is None and not _has_display():
            from imu_dcm.viz import HEADLESS_HINT

            say(HEADLESS_HINT)
            rerun = "off"
        if rerun != "off":
            view = LiveView(rerun, title=f"live {source}", say=say)
        pipe = Pipeline(
            method=method,
            bias=bias_v,
            init_q=init_q,
            window_ns=round(reorder_window_s * 1e9),
            truth_wait_s=truth_wait_s,
            lines=spec.kind != "ws",
            view=view,
            recorder=recorder,
            say=say,
        )
        gyro_scale = DEG if (gyro_units == "deg/s" and spec.kind == "ws") else 1.0
        stop_event = stop or threading.Event()
        reason = _loop(
            src,
            pipe,
            stop_event,
            gyro_scale,
            view_interval_s,
            status,
            say,
            idle_stop_s,
            recorder,
            on_ready,
            spec,
        )
    finally:
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
    lat = np.concatenate(pipe.latency) if pipe.latency else np.zeros(0)
    summary = _summary(
        pipe, src, spec, source, method, bias_v, gyro_units, reason, lat, recorder, started
    )
    if summary_json is not None:
        from imu_dcm.outputs import write_json

        write_json(summary_json, summary, what="--summary-json file")
    q = None if pipe.q_last is None else np.asarray(pipe.q_last, dtype=float)
    return LiveResult(summary, q, pipe.t_last_ns, lat)


def _loop(
    src: Source,
    pipe: Pipeline,
    stop: threading.Event,
    gyro_scale: float,
    interval_s: float,
    status: bool | None,
    say,
    idle_stop_s,
    recorder,
    on_ready,
    spec,
) -> str:
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
            window_s = pipe.reorder.window_ns * 1e-9
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
                            pipe.on_imu(_scaled(rec, gyro_scale))
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
                if len(pipe.reorder) and now - idle_since > window_s:
                    pipe.release_held()  # the source went quiet: a sample waits <= the window
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
                        pipe.on_imu(_scaled(rec, gyro_scale))
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


def _status(pipe: Pipeline, src: Source, tty: bool) -> None:
    r = pipe.reorder
    dropped = r.dropped_duplicate + r.dropped_backward + r.dropped_nonfinite + pipe.malformed
    rate = 1.0 / pipe._median if pipe._median not in (0.0, math.inf) else 0.0
    lat = pipe.latency[-1] if pipe.latency else np.zeros(0)
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
    spec,
    source: str,
    method: str,
    bias_v,
    gyro_units,
    reason: str,
    lat: NDArray,
    recorder,
    started: float,
) -> dict:
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
        "truth_topic": truth_ch.topic
        if truth_ch
        else ("lines (q_w_b)" if pipe.truth_count else None),
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
        "final_t_s": None
        if pipe.t_last_ns is None or pipe.t0_ns is None
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

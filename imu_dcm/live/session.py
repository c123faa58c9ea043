"""A live run: open the source, feed the pipeline, batch the view, stop cleanly, summarise.

:func:`run` is ``imu_dcm.live.run``: it checks the options, opens the source (and the view and
the recording), then loops, waking every ``view_interval_s`` (0.05 s with a view, 0.25 s
without, by default): the source is read (a pollable one by the loop itself, else by its thread
before), its events go to the :class:`imu_dcm.live.pipeline.Pipeline`, the pipeline sends its
batch, a status line goes to stderr. SIGINT / SIGTERM (in the main thread), ``stop``, the end
of input, a lost source or ``idle_stop_s`` end the loop; what the source already delivered is still
processed, the integrator closes its last step, the recording is finished and the summary made.

The loop is :mod:`imu_dcm.live.loop`, the summary :mod:`imu_dcm.live.summary`, the view
:mod:`imu_dcm.viz.live`.
"""

from __future__ import annotations

import gc
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
from imu_dcm.errors import InputError
from imu_dcm.integrator.batch import METHODS, integrate_quat
from imu_dcm.integrator.streaming import DcmIntegrator
from imu_dcm.live.lines import TIME_UNITS
from imu_dcm.live.loop import VIEW_INTERVAL_S, Loop
from imu_dcm.live.pipeline import Pipeline
from imu_dcm.live.recorder import LiveRecorder
from imu_dcm.live.sources import Source, open_source, parse_source
from imu_dcm.live.summary import LiveResult, summary
from imu_dcm.outputs import OutputError, check_output_dir, check_output_file, write_json
from imu_dcm.viz import HEADLESS_HINT, has_display
from imu_dcm.viz.live import LiveView

__all__ = ["LiveOptions", "run"]


def _warm_up(method: str) -> None:
    """Run the integrators once before the source opens (numba and the compiled kernel load and
    dispatch on their first call), so the first samples do not wait for them (about 0.7 s with a
    warm cache, measured as the first second's latency)."""
    q0, w, t = [0.0, 0.0, 0.0, 1.0], np.zeros((5, 3)), 0.001 * np.arange(5)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # rotvec_sum's warning belongs to the real run
        integrate_quat(w, t, q0, method)  # the pipeline's start-up uses the batch form
        integ = DcmIntegrator(q0, method)
        integ.update_many_quat(w, t)  # the pipeline feeds arrays (the kernel's feed)
        integ.finish()


#: A source wakes at most every quarter view interval, and at least every 20 ms: a sample
#: waits for its batch and then for the view's, so the batch adds <= 1/4 to the latency.
_BATCH_MAX_S = 0.02


def _check_outputs(record, force: bool, summary_json, rerun) -> None:
    """The view's mode and the output paths, before the source is opened (imu_dcm.outputs'
    rule)."""
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


@dataclass(slots=True, frozen=True)
class LiveOptions:
    """Options of a live run (the keyword arguments of :func:`run`).

    Attributes
    ----------
    imu_topic, truth_topic : str, optional — WebSocket channel choices (default: by schema, as
        replay); ``truth_topic="none"`` ignores any truth.
    method : str — integrator method (:data:`imu_dcm.integrator.batch.METHODS`), default
    ``magnus4``.
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
        another scheme of :data:`imu_dcm.live.sources.SCHEMES`.
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
        :data:`imu_dcm.gyro.rates.MAX_RATE_RAD_S`, replay's rule), dropped_duplicate,
        dropped_backward,
        reordered, malformed, gaps (the first 1000), gap_count, reconnects, lost_by_system (UDP
        datagrams the system dropped, its buffer full, counted to the stop), gyro_units,
        units_evidence (why the rates look like deg/s, or None), bias_mode, bias_rad_s,
        bias_segments (each with ``used``, and a ``reason`` when not), rest_agreement (replay's:
        how the rests' biases agree, None with fewer than two), method, start_time_s,
        unscored_before_s, initial_q_w_b, final_q_w_b, final_t_s, truth_samples_used, rms/max
        error/inclination/heading (deg, None without truth), latency_p50_ms, latency_p99_ms,
        stopped, record, cpu_s (process CPU time while receiving, all threads), read_interval_s
        (the loop's final cadence), elapsed_s``; no value is NaN or Inf (None where it cannot be
        measured).
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
        reason = _loop(src, pipe, o, stop or threading.Event(), say, on_ready).run()
    finally:
        gc.unfreeze()
        _close(src, view, recorder, say, o.keep_viewer)
    return _result(pipe, src, source, o, reason, recorder, started)


def _result(pipe, src, source, o: LiveOptions, reason, recorder, started) -> LiveResult:
    """The run's result; its summary written to ``o.summary_json`` when one is asked for."""
    made = summary(
        pipe,
        src,
        source,
        gyro_units=o.gyro_units,
        method=o.method,
        reason=reason,
        recorder=recorder,
        started=started,
    )
    if o.summary_json is not None:
        write_json(o.summary_json, made, what="--summary-json file")
    q = None if pipe.q_last is None else np.asarray(pipe.q_last, dtype=float)
    return LiveResult(made, q, pipe.t_last_ns, pipe.latency.recent())


def _loop(src: Source, pipe: Pipeline, o: LiveOptions, stop, say, on_ready) -> Loop:
    """The session's loop over ``src``, with the options it reads."""
    return Loop(
        src,
        pipe,
        stop,
        say,
        on_ready,
        view_interval_s=o.view_interval_s,
        idle_stop_s=o.idle_stop_s,
        gyro_units=o.gyro_units,
        status=o.status,
    )


def _batch_s(o: LiveOptions) -> float:
    """How long a source's wake-up waits for the rest of a batch after its first bytes, s."""
    return min(_BATCH_MAX_S, (o.view_interval_s or VIEW_INTERVAL_S) / 4)


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
    if rerun is None and not has_display():
        say(HEADLESS_HINT)
        return None
    return None if rerun == "off" else LiveView(rerun, title=f"live {source}", say=say)


def _open_recorder(source: str, o: LiveOptions, bias_v):
    if o.record is None:
        return None
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

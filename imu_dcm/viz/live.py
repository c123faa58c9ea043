"""Live's rerun view: replay's entities and blueprint, fed in batches at display rate.

The same entity paths (``imu_dcm.viz.ENTITY``), timeline and blueprint as replay's view
(:func:`imu_dcm.viz.make_blueprint`), so a live view reads like a replayed one: estimated and
true body axes in 3D with the z-tip trail of the last ``TRAIL_S`` s, the attitude error and the
gyro rates over time (replay's colours and radii, :mod:`imu_dcm.viz.log`). Each
:meth:`LiveView.log` call sends what arrived since the previous one with one ``send_columns``
per entity (never one log call per sample); the 3D axes are thinned to the first row of each
1/``AXES_HZ`` s of source time (the scalars keep every sample). Each call costs rerun about
0.2-0.4 ms of CPU whatever its rows, so the live view keeps the calls few: the three gyro rates
go out as three series of one entity (``ENTITY["gyro"]``, replay's colours and names; replay's
view has one entity per axis), the arrow columns are made directly, and the axes' and trails'
colours, radii and labels are sent once, statically.

Modes: ``spawn`` starts the native viewer (:func:`imu_dcm.viz.viewer.start_viewer`: the
``rerun`` binary, listening on 127.0.0.1 only) — it needs a display; ``serve`` runs ``rerun
--serve-web --bind 127.0.0.1`` (via :func:`imu_dcm.viz.serve_rrd`) and streams to it, the
server staying up after the run so the recording can still be looked at; ``save:PATH.rrd``
streams into a file; ``None`` spawns with a display and serves without one.

rerun and pyarrow are imported when a view opens (:class:`LiveView`), not with this module: a
run without a view, which still checks its mode here, does not pay the ~0.5 s of CPU they take
to import (measured: rerun 458 ms, pyarrow 30 ms).
"""

from __future__ import annotations

import math
import uuid
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from imu_dcm.app.rerun_mode import check_rerun_mode, rerun_save_path
from imu_dcm.errors import InputError
from imu_dcm.outputs import PendingOutput, claim_output
from imu_dcm.viz.log import (
    AXES_RADIUS,
    ENTITY,
    EST_RGB,
    EST_TRAIL_RGB,
    TIMELINE,
    TRAIL_RADIUS,
    TRUTH_RGB,
    TRUTH_TRAIL_RGB,
    make_blueprint,
    send_styles,
)
from imu_dcm.viz.view_data import AXES_HZ, TRAIL_POINTS, TRAIL_S, ViewData, body_axes_w
from imu_dcm.viz.viewer import has_display, serve_rrd, start_viewer

__all__ = ["LiveView"]

_FLUSH_TIMEOUT_S = 10.0
#: Source time between two sends of the 3D axes and trails, s (10 a second, each holding every
#: row of 1/AXES_HZ s: each send costs two rerun calls, ~0.5 ms of CPU, so sending them with
#: every 50 ms batch cost 1.5-2 % of a core at 1 kHz, measured).
_3D_EVERY_S = 0.1


_AXES_STYLE = {  # arrows of the body axes: colours, radius, labels (replay's view's)
    "estimate": (EST_RGB, AXES_RADIUS["estimate"], None),
    "truth": (TRUTH_RGB, AXES_RADIUS["truth"], ["x", "y", "z"]),
}
TRAIL_STYLE = {  # the z-tip trails: colour, radius (replay's view's)
    "estimate": (EST_TRAIL_RGB, TRAIL_RADIUS["estimate"]),
    "truth": (TRUTH_TRAIL_RGB, TRAIL_RADIUS["truth"]),
}
_ONE_ROW = np.array([0, 1], dtype=np.int32)


@dataclass(slots=True, frozen=True)
class _Batch:
    """A ready arrow array as a rerun component batch (``ComponentBatchLike``)."""

    array: object

    def as_arrow_array(self):
        return self.array


@dataclass(slots=True, frozen=True)
class _Times:
    """The ``time`` timeline of rows, an arrow duration array in ns (``TimeColumnLike``)."""

    timeline: str
    array: object

    def timeline_name(self) -> str:
        return self.timeline

    def as_arrow_array(self):
        return self.array


def _arrow(pa, values, dtype):
    """``values`` as an arrow array of ``dtype`` (``pa`` is pyarrow): float64 scalars,
    fixed-size lists of 3 (vectors, from an (n, 3) array) or lists of them (strips, from a list
    of (k, 3) arrays)."""
    if pa.types.is_fixed_size_list(dtype):
        flat = np.ascontiguousarray(values, dtype=np.float32).reshape(-1)
        return pa.FixedSizeListArray.from_arrays(pa.array(flat, dtype.value_type), type=dtype)
    if pa.types.is_list(dtype):
        sizes = np.array([len(v) for v in values], dtype=np.int32)
        offsets = pa.array(np.concatenate([[0], np.cumsum(sizes)]).astype(np.int32))
        inner = _arrow(
            pa, np.concatenate(values) if len(values) else np.zeros((0, 3)), dtype.value_type
        )
        return pa.ListArray.from_arrays(offsets, inner, type=dtype)
    return pa.array(np.ascontiguousarray(values, dtype=np.float64), dtype)


def _save(rec, target: str, blueprint):
    """Stream the recording into a temporary sibling of ``target`` (.rrd; new or a recording
    this tool wrote, :func:`imu_dcm.outputs.claim_output`); the returned
    :class:`~imu_dcm.outputs.PendingOutput` makes it ``target`` whole at :meth:`LiveView.close`
    (the target is never emptied, and never half written)."""
    pending = PendingOutput(claim_output(target, "rrd", what="--rerun save:"))
    try:
        rec.save(pending.path, default_blueprint=blueprint)
    except BaseException:
        pending.abort()
        raise
    return pending


class LiveView:
    """A rerun recording fed as the live run goes (see the module doc)."""

    def __init__(self, mode: str | None, title: str, say=print) -> None:
        import pyarrow as pa  # here, not with the module (see the module doc)
        import rerun as rr

        check_rerun_mode(mode, "rerun mode")
        if mode is None:
            mode = "spawn" if has_display() else "serve"
        self.mode = mode
        self.say = say
        self.served = None
        self.viewer_pid = None
        self._pending = None
        self.rr, self.pa = rr, pa
        self.entity = ENTITY
        self.timeline = TIMELINE
        nan4 = np.full((1, 4), np.nan)
        self._blank = ViewData(
            t_s=np.zeros(1),
            q_est=nan4,
            q_truth=nan4,
            omega_b=np.zeros((1, 3)),
            error_total_deg=np.full(1, np.nan),
            error_inclination_deg=np.full(1, np.nan),
            error_heading_deg=np.full(1, np.nan),
            title=title,
        )
        blueprint = make_blueprint(self._blank)
        rec = rr.RecordingStream("imu_dcm", recording_id=uuid.uuid4())
        if mode == "spawn":
            if not has_display():
                raise InputError(
                    "Expected a display (DISPLAY or WAYLAND_DISPLAY) for rerun mode "
                    "'spawn', got none; use 'serve' or 'save:PATH.rrd'"
                )
            proc, port = start_viewer()
            self.viewer_pid = proc.pid
            rec.connect_grpc(f"rerun+http://127.0.0.1:{port}/proxy", default_blueprint=blueprint)
            say(f"rerun: viewer started (pid {proc.pid}, listening on 127.0.0.1:{port})")
        elif mode == "serve":
            self.served = serve_rrd(None)
            try:
                rec.connect_grpc(self.served.grpc_url, default_blueprint=blueprint)
            except BaseException:
                self.served.stop()
                raise
            say(f"rerun: open {self.served.url} (web viewer, 127.0.0.1 only)")
        else:
            self._pending = _save(rec, rerun_save_path(mode), blueprint)
        rec.send_recording_name(title)
        self.rec = rec
        self._static()
        self._last_axes = {"est": -math.inf, "truth": -math.inf}
        self._held = {"est": [], "truth": []}  # rows waiting for the next 3D send
        self._sent_3d = {"est": -math.inf, "truth": -math.inf}
        self._tips = {k: (np.zeros(0), np.zeros((0, 3))) for k in ("est", "truth")}
        self.log_calls = 0

    def _static(self) -> None:
        rr = self.rr
        # replay's styles (colours, names, widths); the rates as one entity of three series
        send_styles(self._blank, self.rec, gyro_one_entity=True)
        # the axes' and trails' colours, radii and labels: static, once (replay's values), so
        # each send carries the vectors and the strip alone
        for key, (rgb, radius, labels) in _AXES_STYLE.items():
            style = rr.Arrows3D.from_fields(colors=rgb, radii=[radius], labels=labels)
            self.rec.log(self.entity[f"{key}_axes"], style, static=True)
        for key, (color, radius) in TRAIL_STYLE.items():
            style = rr.LineStrips3D.from_fields(colors=[color], radii=[radius])
            self.rec.log(self.entity[f"{key}_trail"], style, static=True)
        # arrow types and descriptors of the columns, from rerun's own builders
        vec = rr.Arrows3D.columns(vectors=np.zeros((1, 3)))
        strip = rr.LineStrips3D.columns(strips=[np.zeros((2, 3))])
        scalar = rr.Scalars.columns(scalars=np.zeros(1))
        self._kinds = {
            name: (col.component_descriptor(), col.as_arrow_array().type.value_type)
            for name, cols in (("vectors", vec), ("strips", strip), ("scalars", scalar))
            for col in cols
        }

    def _time(self, t_s: NDArray) -> _Times:
        """The rows' times as the timeline's column (a duration, rounded to the ns)."""
        pa = self.pa
        ns = pa.array(np.rint(t_s * 1e9).astype(np.int64), pa.duration("ns"))
        return _Times(self.timeline, ns)

    def _column(self, kind: str, values, offsets: NDArray):
        """One component column (``vectors``, ``strips`` or ``scalars``) of rows
        ``values[offsets[i]:offsets[i + 1]]``, made directly as the arrow array rerun's builder
        makes (its type taken from that builder at start)."""
        desc, dtype = self._kinds[kind]
        batch = _Batch(_arrow(self.pa, values, dtype))
        return self.rr.ComponentColumn(desc, batch, offsets=offsets)

    def _send(self, path: str, times, column) -> None:
        self.rec.send_columns(path, indexes=[times], columns=[column])
        self.log_calls += 1

    def _thin(self, key: str, t_s: NDArray) -> NDArray:
        """Indices of the rows to draw: the first of each new 1/AXES_HZ slot of source time,
        and always the newest (at most AXES_HZ + one row per call per second)."""
        slot = np.floor(t_s * AXES_HZ)
        first = np.concatenate([[slot[0] > self._last_axes[key]], slot[1:] > slot[:-1]])
        first[-1] = True
        self._last_axes[key] = slot[-1]
        return np.flatnonzero(first)

    def axes_rows(self, key: str, t_s: NDArray, q: NDArray, final: bool = False) -> None:
        """The 3D axes and the z-tip trail of new rows: at most every ``_3D_EVERY_S`` of source
        time (the rows in between are held and go with the next send): two ``send_columns``
        calls per send, whatever the view interval."""
        ok = np.all(np.isfinite(q), axis=1)
        held = self._held[key]
        if ok.any():
            held.append((t_s[ok], q[ok]))
        if not held or (not final and held[-1][0][-1] - self._sent_3d[key] < _3D_EVERY_S):
            return
        t_s = np.concatenate([h[0] for h in held])
        q = np.concatenate([h[1] for h in held])
        held.clear()
        self._sent_3d[key] = t_s[-1]
        idx = self._thin(key, t_s)
        ax = body_axes_w(q[idx])[0]  # (n, 3 axes, 3), the rows finite
        n = len(idx)
        path = self.entity["estimate_axes" if key == "est" else "truth_axes"]
        vectors = self._column("vectors", ax.reshape(-1, 3), np.arange(0, 3 * n + 1, 3, np.int32))
        self._send(path, self._time(t_s[idx]), vectors)
        # z-tip trail of the drawn rows: the last TRAIL_S seconds, one strip per call
        tip_t, tip_z = self._tips[key]
        tip_t, tip_z = np.concatenate([tip_t, t_s[idx]]), np.concatenate([tip_z, ax[:, 2]])
        keep = tip_t >= t_s[-1] - TRAIL_S
        self._tips[key] = tip_t, tip_z = tip_t[keep], tip_z[keep]
        pts = tip_z
        if len(pts) > TRAIL_POINTS:
            pts = pts[np.linspace(0, len(pts) - 1, TRAIL_POINTS).round().astype(int)]
        strip = self._column("strips", [pts], _ONE_ROW)
        self._send(
            self.entity["estimate_trail" if key == "est" else "truth_trail"],
            self._time(t_s[-1:]),
            strip,
        )

    def log(
        self,
        *,
        gyro_t_s: NDArray,
        omega_b: NDArray,
        est_t_s: NDArray,
        q_est: NDArray,
        truth_t_s: NDArray,
        q_truth: NDArray,
        err_t_s: NDArray,
        err_deg: NDArray,
    ) -> None:
        """Send one batch: times in s since the first sample; rates (n, 3) rad/s body axes;
        ``q_*`` (n, 4) ``[x, y, z, w]`` body to world; errors (n, 3) deg (total, incl., head)."""
        if len(gyro_t_s):  # x, y, z: three series of one entity, one send_columns
            rows = np.arange(0, 3 * len(gyro_t_s) + 1, 3, dtype=np.int32)
            gyro = self._column("scalars", omega_b.reshape(-1), rows)
            self._send(self.entity["gyro"], self._time(gyro_t_s), gyro)
        if len(est_t_s):
            self.axes_rows("est", est_t_s, q_est)
        if len(truth_t_s):
            order = np.argsort(truth_t_s, kind="stable")
            self.axes_rows("truth", truth_t_s[order], q_truth[order])
        if len(err_t_s):
            rows = np.arange(0, 3 * len(err_t_s) + 1, 3, dtype=np.int32)  # total, incl., heading
            self._send(
                self.entity["errors"],
                self._time(err_t_s),
                self._column("scalars", err_deg.reshape(-1), rows),
            )

    def close(self) -> str:
        """Flush and disconnect; return the line to print about the viewer."""
        try:
            for key in ("est", "truth"):  # the rows held for the next 3D send
                self.axes_rows(key, np.zeros(0), np.zeros((0, 4)), final=True)
            self.rec.flush(timeout_sec=_FLUSH_TIMEOUT_S)
            self.rec.disconnect()
        except BaseException:
            if self._pending is not None:
                self._pending.abort()
            raise
        if self._pending is not None:
            return f"rerun: saved {self._pending.commit()}"
        if self.served is not None:
            return (
                f"rerun: the web viewer stays at {self.served.url} (127.0.0.1 only; stop it "
                f"with: kill {self.served.process.pid})"
            )
        if self.viewer_pid is not None:
            return f"rerun: viewer running (pid {self.viewer_pid})"
        return ""

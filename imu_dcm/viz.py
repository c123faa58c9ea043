"""Rerun view of a replay: the true and estimated body axes in 3D, attitude error and gyro over time.

Conventions (see README "Frames and units"): quaternions are Hamilton ``[x, y, z, w]`` (scalar
last, the order rerun uses), ``q_w_b`` maps body to world, so the body axes drawn in the world are
the columns of ``R_w_b`` (``quat_rotate(q_w_b, e_k)``); world is ENU, z up; ``omega_b`` is the body
rate relative to the world in body axes, rad/s; time ``t_s`` in seconds, shown on the rerun
timeline ``"time"`` (a duration timeline).

What is sent (every time-varying entity in ONE ``send_columns`` call, one row per sample unless
stated):

=====================================  ==========================================================
entity                                 content
=====================================  ==========================================================
``/world/truth/axes``                  Arrows3D, true body x/y/z axes, solid red/green/blue;
                                       an empty row where there is no truth
``/world/estimate/axes``               Arrows3D, estimated body axes, light red/green/blue;
                                       an empty row where there is no estimate
``/world/truth/z_trail``               LineStrips3D, tip of the body z axis over the last
``/world/estimate/z_trail``            ``TRAIL_S`` seconds (truth purple, estimate amber), one
                                       row per frame at ``TRAIL_FPS`` frames per second of log
                                       time (not per sample)
``/world/truth/z_trace``               static LineStrips3D, the whole z-tip trace, thin and faint
``/world/estimate/z_trace``            (at most ``TRACE_MAX_POINTS`` points, evenly decimated;
                                       only for logs up to ``TRACE_MAX_S`` = 30 s)
``/errors_deg``                        Scalars (3 per row): total, inclination, heading error, deg
``/gyro/{x,y,z}/omega_b``              Scalars: each channel of the rate integrated, rad/s
``/gyro/{x,y,z}/measured_omega_raw_b`` Scalars: the raw gyro (only when a pre-filter ran), rad/s
                                       (named to sort, and so be drawn, before ``omega_b``)
=====================================  ==========================================================

The tip trace: a strip per sample holding the whole history would make the data quadratic in
the log length. The view instead sends a trailing window of the last 2 s (``TRAIL_S``) resampled
to ``TRAIL_POINTS`` points, one strip per frame at 30 frames per second of log time: linear in the
log duration (30 · 120 points per second of log per trace), and, for short logs, a static
decimated full trace as context (on long logs it would be a tangle).

The layout (blueprint) is declared in :func:`make_blueprint`: the 3D view on the left, the error
and gyro time series stacked on the right.

Viewer modes of :func:`show_replay`: ``"spawn"`` starts the native viewer (the ``rerun`` binary
shipped in the rerun-sdk wheel, listening on 127.0.0.1 only) and streams to it; ``"serve"``
saves a temporary ``.rrd`` and serves it with the ``rerun`` binary's web viewer bound to
127.0.0.1 (the SDK's own servers bind every interface, so they are not used); ``"save:PATH.rrd"``
writes a file; ``"off"`` does nothing; ``None`` spawns when a display exists, else saves to
``save_dir/<title>.rrd``.
"""

from __future__ import annotations

import math
import os
import re
import signal
import socket
import subprocess
import sys
import tempfile
import time
import uuid
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from imu_dcm.errors import ImuDcmError, InputError
from imu_dcm.so3 import quat_rotate

__all__ = [
    "ENTITY",
    "TIMELINE",
    "ServedViewer",
    "ViewData",
    "gyro_needs_split",
    "has_display",
    "make_blueprint",
    "rerun_binary",
    "save_rrd",
    "send_view",
    "serve_rrd",
    "show_replay",
]

TIMELINE = "time"
"""Name of the rerun timeline (a duration in seconds from the log's time origin)."""

ENTITY = {
    "truth_axes": "/world/truth/axes",
    "estimate_axes": "/world/estimate/axes",
    "truth_trail": "/world/truth/z_trail",
    "estimate_trail": "/world/estimate/z_trail",
    "truth_trace": "/world/truth/z_trace",
    "estimate_trace": "/world/estimate/z_trace",
    "errors": "/errors_deg",
    "gyro_x": "/gyro/x/omega_b",
    "gyro_y": "/gyro/y/omega_b",
    "gyro_z": "/gyro/z/omega_b",
    "gyro_raw_x": "/gyro/x/measured_omega_raw_b",
    "gyro_raw_y": "/gyro/y/measured_omega_raw_b",
    "gyro_raw_z": "/gyro/z/measured_omega_raw_b",
}
"""Entity paths of the view (see the module docstring)."""

TRAIL_S = 2.0
"""Length of the trailing z-tip window, s."""
TRAIL_FPS = 30.0
"""Frames per second of log time at which the trailing window is sent."""
TRAIL_POINTS = 120
"""Points per trailing-window strip (the window is resampled to this many samples)."""
TRACE_MAX_POINTS = 20_000
"""Upper bound on the points of the static full z-tip trace."""
TRACE_MAX_S = 30.0
"""Logs longer than this (s) get no static full trace: it would be an unreadable tangle."""

# Truth: saturated RGB; estimate: the same hues, light.
_TRUTH_RGB = np.array([[220, 40, 40], [30, 170, 50], [40, 90, 235]], dtype=np.uint8)
_EST_RGB = np.array([[255, 165, 150], [150, 235, 140], [150, 195, 255]], dtype=np.uint8)
# Colours readable on the viewer's light and dark themes.
_TRUTH_TRAIL_RGB = (150, 70, 220)
_EST_TRAIL_RGB = (240, 150, 0)
_ERROR_RGB = [(190, 50, 190), (255, 140, 40), (40, 160, 230)]
_GYRO_RGB = [(230, 70, 70), (70, 200, 90), (80, 130, 255)]
_GYRO_RAW_RGB = [(140, 110, 110), (110, 140, 115), (110, 120, 150)]
_AXES = "xyz"

_MODES = ("spawn", "serve", "save:PATH.rrd", "off", None)
_FLUSH_TIMEOUT_S = 60.0  # a viewer that went away must not hang the replay


def _as_array(name: str, x: object, shape_tail: tuple[int, ...], n: int | None) -> NDArray:
    """``x`` as float64 of shape ``(n, *shape_tail)`` (any length when ``n`` is None)."""
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"Expected `{name}` a numeric array, got {type(x).__name__}") from None
    if (
        a.ndim != 1 + len(shape_tail)
        or a.shape[1:] != shape_tail
        or (n is not None and len(a) != n)
    ):
        want = ("N" if n is None else str(n),) + tuple(str(k) for k in shape_tail)
        raise InputError(f"Expected `{name}` of shape ({', '.join(want)}), got {a.shape}")
    return a


@dataclass(frozen=True)
class ViewData:
    """Everything the view shows, as whole arrays (one row per gyro sample).

    Attributes
    ----------
    t_s : ndarray, shape (N,)
        Sample times, s, strictly increasing (shown on the timeline relative to ``t_s[0]``).
    q_est : ndarray, shape (N, 4)
        Estimated attitude ``q_w_b`` (body to world), Hamilton ``[x, y, z, w]``; rows of NaN
        where there is no estimate (e.g. before the estimate starts at the first truth sample).
    q_truth : ndarray, shape (N, 4)
        True attitude ``q_w_b``, ``[x, y, z, w]``; rows of NaN where there is no truth.
    omega_b : ndarray, shape (N, 3)
        Body rate used for the integration (after any pre-filter), body axes, rad/s.
    error_total_deg, error_inclination_deg, error_heading_deg : ndarray, shape (N,)
        Attitude error of the estimate against the truth, deg (see ``imu_dcm.metrics``); NaN where
        there is no truth.
    title : str
        Recording name; also the file stem of the default ``.rrd``.
    omega_raw_b : ndarray, shape (N, 3), or None
        The raw gyro, body axes, rad/s, when a pre-filter ran (``None``: not shown).

    Raises
    ------
    InputError
        On construction, when a shape disagrees with ``N = len(t_s)``, ``N < 1``, or ``t_s`` is
        not finite and strictly increasing.
    """

    t_s: NDArray[np.float64]
    q_est: NDArray[np.float64]
    q_truth: NDArray[np.float64]
    omega_b: NDArray[np.float64]
    error_total_deg: NDArray[np.float64]
    error_inclination_deg: NDArray[np.float64]
    error_heading_deg: NDArray[np.float64]
    title: str
    omega_raw_b: NDArray[np.float64] | None = None

    def __post_init__(self) -> None:
        t = _as_array("t_s", self.t_s, (), None)
        n = len(t)
        if n < 1:
            raise InputError("Expected `t_s` with at least 1 sample, got 0")
        if not np.all(np.isfinite(t)):
            k = int(np.flatnonzero(~np.isfinite(t))[0])
            raise InputError(f"Expected `t_s` finite, got t_s[{k}] = {t[k]}")
        bad = np.flatnonzero(np.diff(t) <= 0)
        if bad.size:
            k = int(bad[0])
            raise InputError(
                f"Expected `t_s` strictly increasing, got t_s[{k + 1}] = {t[k + 1]!r} "
                f"<= t_s[{k}] = {t[k]!r}"
            )
        fields = {
            "t_s": t,
            "q_est": _as_array("q_est", self.q_est, (4,), n),
            "q_truth": _as_array("q_truth", self.q_truth, (4,), n),
            "omega_b": _as_array("omega_b", self.omega_b, (3,), n),
            "error_total_deg": _as_array("error_total_deg", self.error_total_deg, (), n),
            "error_inclination_deg": _as_array(
                "error_inclination_deg", self.error_inclination_deg, (), n
            ),
            "error_heading_deg": _as_array("error_heading_deg", self.error_heading_deg, (), n),
        }
        if self.omega_raw_b is not None:
            fields["omega_raw_b"] = _as_array("omega_raw_b", self.omega_raw_b, (3,), n)
        if not isinstance(self.title, str) or not self.title:
            raise InputError(f"Expected `title` a non-empty str, got {self.title!r}")
        for name, value in fields.items():
            object.__setattr__(self, name, value)


# ------------------------------------------------------------------------------------------------
# geometry of the 3D view


def _body_axes_w(q_w_b: NDArray) -> tuple[NDArray, NDArray[np.bool_]]:
    """Body x, y, z axes in world coordinates (the columns of ``R_w_b``) and the valid rows.

    Returns
    -------
    axes_w : ndarray, shape (N, 3, 3)
        ``axes_w[n, k]`` = body axis k in world coordinates; NaN rows where ``q_w_b`` is not
        finite or zero.
    valid : ndarray of bool, shape (N,)
    """
    norm = np.linalg.norm(q_w_b, axis=1)
    valid = np.isfinite(norm) & (norm > 1e-9)
    q = np.where(valid[:, None], q_w_b, [0.0, 0.0, 0.0, 1.0]) / np.where(valid, norm, 1.0)[:, None]
    axes = quat_rotate(q[:, None, :], np.eye(3)[None, :, :])
    return np.where(valid[:, None, None], axes, np.nan), valid


def _trail_frames(t_s: NDArray) -> NDArray[np.intp]:
    """Sample index of each trailing-window frame: the last sample at or before k / TRAIL_FPS."""
    rel = t_s - t_s[0]
    n_frames = math.floor(rel[-1] * TRAIL_FPS) + 1
    idx = np.searchsorted(rel, np.arange(n_frames) / TRAIL_FPS, side="right") - 1
    return np.unique(np.clip(idx, 0, len(t_s) - 1))


def _trail_strips(t_s: NDArray, tip_w: NDArray, frames: NDArray[np.intp]) -> list[NDArray]:
    """Per frame, the tip positions over the last TRAIL_S seconds (NaN points dropped)."""
    start = np.searchsorted(t_s, t_s[frames] - TRAIL_S, side="left")
    j = np.linspace(0.0, 1.0, TRAIL_POINTS)
    idx = np.rint(start[:, None] + (frames - start)[:, None] * j[None, :]).astype(np.intp)
    pts = tip_w[idx]  # (F, TRAIL_POINTS, 3)
    ok = np.all(np.isfinite(pts), axis=2)
    if ok.all():
        return list(pts)
    return [p[m] for p, m in zip(pts, ok)]


def _trace_segments(tip_w: NDArray) -> list[NDArray]:
    """The whole tip trace, decimated to <= TRACE_MAX_POINTS, split where it is NaN."""
    step = max(1, math.ceil(len(tip_w) / TRACE_MAX_POINTS))
    pts = tip_w[::step]
    ok = np.all(np.isfinite(pts), axis=1)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], ok.astype(np.int8), [0]])))
    return [pts[a:b] for a, b in zip(edges[0::2], edges[1::2]) if b - a >= 2]


# ------------------------------------------------------------------------------------------------
# rerun


def gyro_needs_split(omega_b: NDArray) -> bool:
    """True when one shared axis would squash a gyro channel (one plot per channel instead).

    A channel is squashed when its own span (0.5 to 99.5 percentile) is under a quarter of the
    span of all three channels together (e.g. a spinning top: ω_z ≈ 125 rad/s, ω_x,y ≈ ±7 rad/s).
    """
    w = omega_b[np.all(np.isfinite(omega_b), axis=1)]
    if len(w) < 2:
        return False
    lo, hi = np.percentile(w, [0.5, 99.5], axis=0)
    overall = float(hi.max() - lo.min())
    return overall > 0 and bool(np.any(hi - lo < 0.25 * overall))


def make_blueprint(view: ViewData):
    """The layout: 3D body axes on the left; attitude error and gyro time series on the right.

    The gyro channels share one plot unless that would squash one of them
    (:func:`gyro_needs_split`); then each channel gets its own plot.

    Returns
    -------
    rerun.blueprint.Blueprint
    """
    import rerun.blueprint as rrb

    raw_note = " (grey: raw)" if view.omega_raw_b is not None else ""
    legend = rrb.PlotLegend(corner=rrb.Corner2D.LeftTop)
    # Every plot shows the whole log (rerun would otherwise zoom long logs around the cursor).
    whole = rrb.TimeRangeBoundary.infinite()
    axis_x = rrb.TimeAxis(view_range=rrb.TimeRange(start=whole, end=whole))
    if gyro_needs_split(view.omega_b):
        gyro_views = [
            rrb.TimeSeriesView(
                origin=f"/gyro/{axis}",
                name=f"gyro ω_{axis} [rad/s]{raw_note}",
                plot_legend=legend,
                axis_x=axis_x,
            )
            for axis in _AXES
        ]
        right = rrb.Vertical(
            rrb.TimeSeriesView(
                origin=ENTITY["errors"],
                name="attitude error [deg]",
                plot_legend=legend,
                axis_x=axis_x,
            ),
            *gyro_views,
            row_shares=[2.0, 1.0, 1.0, 1.0],
        )
    else:
        right = rrb.Vertical(
            rrb.TimeSeriesView(
                origin=ENTITY["errors"],
                name="attitude error [deg]",
                plot_legend=legend,
                axis_x=axis_x,
            ),
            rrb.TimeSeriesView(
                origin="/gyro",
                name=f"gyro ω_b [rad/s]{raw_note}",
                plot_legend=legend,
                axis_x=axis_x,
            ),
        )
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(
                origin="/world",
                name="body axes: truth solid, estimate light; z-axis tip: truth purple, estimate amber",
                eye_controls=rrb.EyeControls3D(
                    kind=rrb.Eye3DKind.Orbital,
                    position=(1.55, -1.9, 1.3),
                    look_target=(0.0, 0.0, 0.0),
                    eye_up=(0.0, 0.0, 1.0),
                ),
            ),
            right,
            column_shares=[1.0, 1.0],
        ),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(state="collapsed", timeline=TIMELINE),
        collapse_panels=False,
    )


@dataclass(frozen=True)
class _Entity:
    """One time-varying entity as whole arrays, sliceable by rows for the realtime mode.

    ``fields`` hold one element per instance (flattened over rows); ``lengths`` gives the number
    of instances per row (``None``: one row per first-axis element, as for ``Scalars`` of shape
    (N, 3) or one strip per row).
    """

    path: str
    t_rel_s: NDArray[np.float64]
    archetype: type
    fields: dict
    lengths: NDArray[np.intp] | None = None

    def columns(self, a: int = 0, b: int | None = None):
        """Rerun columns of rows ``[a, b)``."""
        b = len(self.t_rel_s) if b is None else b
        if self.lengths is None:
            cols = self.archetype.columns(**{k: v[a:b] for k, v in self.fields.items()})
            return cols
        offsets = np.concatenate([[0], np.cumsum(self.lengths)])
        lo, hi = offsets[a], offsets[b]
        cols = self.archetype.columns(**{k: v[lo:hi] for k, v in self.fields.items()})
        return cols.partition(self.lengths[a:b])


def _entities(view: ViewData) -> list[_Entity]:
    """Every time-varying entity of the view."""
    import rerun as rr

    t_rel = view.t_s - view.t_s[0]
    est_axes, has_est = _body_axes_w(view.q_est)  # (N, 3 axes, 3)
    true_axes, has_truth = _body_axes_w(view.q_truth)
    n_est, m = int(has_est.sum()), int(has_truth.sum())
    # Rows without an attitude hold no arrows (an empty row clears the previous axes).
    out = [
        _Entity(
            ENTITY["estimate_axes"],
            t_rel,
            rr.Arrows3D,
            {
                "vectors": est_axes[has_est].reshape(-1, 3),
                "colors": np.tile(_EST_RGB, (n_est, 1)),
                "radii": np.full(3 * n_est, 0.018, dtype=np.float32),
            },
            np.where(has_est, 3, 0).astype(np.intp),
        ),
        _Entity(
            ENTITY["truth_axes"],
            t_rel,
            rr.Arrows3D,
            {
                "vectors": true_axes[has_truth].reshape(-1, 3),
                "colors": np.tile(_TRUTH_RGB, (m, 1)),
                "radii": np.full(3 * m, 0.035, dtype=np.float32),
                "labels": np.tile(np.array(["x", "y", "z"]), m),
            },
            np.where(has_truth, 3, 0).astype(np.intp),
        ),
    ]
    frames = _trail_frames(view.t_s)
    tips = {
        "truth_trail": true_axes[:, 2],
        "estimate_trail": est_axes[:, 2],
    }
    for key, tip in tips.items():
        strips = _trail_strips(view.t_s, tip, frames)
        color = _EST_TRAIL_RGB if key == "estimate_trail" else _TRUTH_TRAIL_RGB
        radius = 0.004 if key == "estimate_trail" else 0.007
        out.append(
            _Entity(
                ENTITY[key],
                t_rel[frames],
                rr.LineStrips3D,
                {
                    "strips": strips,
                    "colors": np.tile(np.array(color, dtype=np.uint8), (len(frames), 1)),
                    "radii": np.full(len(frames), radius, dtype=np.float32),
                },
            )
        )
    errors = np.stack(
        [view.error_total_deg, view.error_inclination_deg, view.error_heading_deg], axis=1
    )
    out.append(_Entity(ENTITY["errors"], t_rel, rr.Scalars, {"scalars": errors}))
    for k, axis in enumerate(_AXES):
        out.append(
            _Entity(ENTITY[f"gyro_{axis}"], t_rel, rr.Scalars, {"scalars": view.omega_b[:, k]})
        )
    if view.omega_raw_b is not None:
        for k, axis in enumerate(_AXES):
            out.append(
                _Entity(
                    ENTITY[f"gyro_raw_{axis}"],
                    t_rel,
                    rr.Scalars,
                    {"scalars": view.omega_raw_b[:, k]},
                )
            )
    return out


def _send_static(view: ViewData, rec) -> None:
    """View coordinates, series styles and the faint full z-tip traces (static, sent once)."""
    import rerun as rr

    rec.log("/world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    rec.log(
        ENTITY["errors"],
        rr.SeriesLines(
            names=["total", "inclination", "heading"], colors=_ERROR_RGB, widths=[3.5, 1.5, 1.5]
        ),
        static=True,
    )
    for k, axis in enumerate(_AXES):
        rec.log(
            ENTITY[f"gyro_{axis}"],
            rr.SeriesLines(names=[f"ω_{axis}"], colors=[_GYRO_RGB[k]], widths=[1.5]),
            static=True,
        )
        if view.omega_raw_b is not None:
            rec.log(
                ENTITY[f"gyro_raw_{axis}"],
                rr.SeriesLines(names=[f"raw ω_{axis}"], colors=[_GYRO_RAW_RGB[k]], widths=[1.0]),
                static=True,
            )
    if view.t_s[-1] - view.t_s[0] > TRACE_MAX_S:
        return
    tips = {
        "estimate_trace": _body_axes_w(view.q_est)[0][:, 2],
        "truth_trace": _body_axes_w(view.q_truth)[0][:, 2],
    }
    for key, tip in tips.items():
        segments = _trace_segments(tip)
        if segments:
            color = (*_EST_TRAIL_RGB, 110) if key == "estimate_trace" else (*_TRUTH_TRAIL_RGB, 90)
            rec.log(
                ENTITY[key],
                rr.LineStrips3D(segments, colors=[color], radii=[0.003]),
                static=True,
            )


def _time_column(t_rel_s: NDArray):
    """The ``"time"`` timeline as a duration column, rounded to the nearest ns."""
    import rerun as rr

    return rr.TimeColumn(TIMELINE, duration=np.rint(t_rel_s * 1e9).astype("timedelta64[ns]"))


def send_view(view: ViewData, rec, *, realtime: bool = False, chunk_s: float = 0.1) -> None:
    """Send the whole view to a rerun recording stream.

    Parameters
    ----------
    view : ViewData
    rec : rerun.RecordingStream
        The stream to send to (its sinks are already set).
    realtime : bool
        False: each entity in one ``send_columns`` call. True: pace the replay at the recorded
        speed, sending every entity's rows in chunks of ``chunk_s`` seconds of log time
        (``send_columns`` per chunk) and sleeping to the wall clock in between.
    chunk_s : float
        Chunk length for ``realtime``, s.
    """
    if realtime and not chunk_s > 0:
        raise InputError(f"Expected `chunk_s` > 0, got {chunk_s!r}")
    _send_static(view, rec)
    entities = _entities(view)
    if not realtime:
        for e in entities:
            rec.send_columns(e.path, indexes=[_time_column(e.t_rel_s)], columns=e.columns())
        return
    # Rows of each entity per chunk of log time; one send_columns per entity and chunk.
    span = view.t_s[-1] - view.t_s[0]
    ends = np.arange(1, math.floor(span / chunk_s) + 2) * chunk_s
    cuts = [np.searchsorted(e.t_rel_s, ends, side="left") for e in entities]
    start_wall = time.monotonic()
    prev = [0] * len(entities)
    for c, end_s in enumerate(ends):
        for k, e in enumerate(entities):
            b = len(e.t_rel_s) if c == len(ends) - 1 else int(cuts[k][c])
            if b > prev[k]:
                rec.send_columns(
                    e.path,
                    indexes=[_time_column(e.t_rel_s[prev[k] : b])],
                    columns=e.columns(prev[k], b),
                )
                prev[k] = b
        delay = start_wall + end_s - time.monotonic()
        if delay > 0:
            time.sleep(delay)


def _new_recording(view: ViewData):
    import rerun as rr

    rec = rr.RecordingStream("imu_dcm", recording_id=uuid.uuid4())
    return rec


def save_rrd(view: ViewData, path: str | os.PathLike) -> Path:
    """Write the view (data and blueprint) to an ``.rrd`` file, atomically.

    Parameters
    ----------
    view : ViewData
    path : path-like
        Destination; must end in ``.rrd``. Parent folders are created.

    Returns
    -------
    Path
        The file written.
    """
    path = Path(path)
    if path.suffix != ".rrd":
        raise InputError(f"Expected an .rrd path, got {str(path)!r}")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    rec = _new_recording(view)
    try:
        rec.save(tmp, default_blueprint=make_blueprint(view))
        rec.send_recording_name(view.title)
        send_view(view, rec)
        rec.flush()
        rec.disconnect()
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


# ------------------------------------------------------------------------------------------------
# the rerun binary (viewer / web server), always bound to 127.0.0.1


def rerun_binary() -> Path:
    """Path of the ``rerun`` executable shipped in the rerun-sdk wheel (package ``rerun_cli``)."""
    override = os.environ.get("RERUN_CLI_PATH")
    if override:
        return Path(override)
    import rerun_cli

    exe = Path(rerun_cli.__file__).with_name("rerun.exe" if sys.platform == "win32" else "rerun")
    if not exe.is_file():
        raise ImuDcmError(f"Expected the rerun binary at {exe}, got no such file")
    return exe


def _rerun_env() -> dict[str, str]:
    """Environment for the rerun binary: analytics and telemetry off (rerun skips them under CI)."""
    env = dict(os.environ)
    env.update({"CI": "1", "TELEMETRY_ENABLED": "false", "RUST_LOG": env.get("RUST_LOG", "warn")})
    return env


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class _Child:
    """A process started with ``os.posix_spawn`` in a new session: ``pid``, ``poll``, ``wait``.

    Unlike ``subprocess.Popen`` it does not warn when dropped while running, which is what a
    server left running for the user (``serve``/``spawn``) does on purpose.
    """

    def __init__(self, cmd: list[str], log_path: str | os.PathLike | None) -> None:
        out = str(log_path) if log_path is not None else os.devnull
        actions = [
            (os.POSIX_SPAWN_OPEN, 0, os.devnull, os.O_RDONLY, 0),
            (os.POSIX_SPAWN_OPEN, 1, out, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644),
            (os.POSIX_SPAWN_DUP2, 1, 2),
        ]
        self.pid = os.posix_spawn(cmd[0], cmd, _rerun_env(), file_actions=actions, setsid=True)
        self.returncode: int | None = None

    def poll(self) -> int | None:
        if self.returncode is None:
            try:
                pid, status = os.waitpid(self.pid, os.WNOHANG)
            except ChildProcessError:  # reaped elsewhere
                self.returncode = -1
            else:
                if pid:
                    self.returncode = os.waitstatus_to_exitcode(status)
        return self.returncode

    def wait(self, timeout: float) -> int:
        deadline = time.monotonic() + timeout
        while self.poll() is None:
            if time.monotonic() > deadline:
                raise subprocess.TimeoutExpired(str(self.pid), timeout)
            time.sleep(0.02)
        return self.returncode


def _start(cmd: list[str], log_path: str | os.PathLike | None):
    """Start the rerun binary in its own session, output to ``log_path`` (or discarded)."""
    if hasattr(os, "posix_spawn"):
        return _Child(cmd, log_path)
    with open(log_path or os.devnull, "ab") as log:  # pragma: no cover - Windows
        return subprocess.Popen(
            cmd, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, env=_rerun_env()
        )


def _wait_for_port(
    port: int, proc, timeout_s: float, log_path: str | os.PathLike | None = None
) -> None:
    """Wait until 127.0.0.1:port accepts connections; raise if the process exits first."""
    deadline = time.monotonic() + timeout_s
    see = f" (its output: {log_path})" if log_path else ""
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(
                f"Expected rerun to listen on 127.0.0.1:{port}, got exit code {proc.returncode}{see}"
            )
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=0.2):
                return
        except OSError:
            time.sleep(0.05)
    raise TimeoutError(f"Expected rerun to listen on 127.0.0.1:{port} within {timeout_s} s{see}")


@dataclass(frozen=True)
class ServedViewer:
    """A ``rerun`` web-viewer server bound to 127.0.0.1.

    Attributes
    ----------
    process
        The server process (leader of its own session): ``pid``, ``poll()``, ``wait(timeout)``.
    url : str
        The web viewer, already pointed at the recording.
    grpc_url : str
        The gRPC proxy (``rerun+http://127.0.0.1:PORT/proxy``) a native viewer or SDK can use.
    grpc_port, web_port : int
        The two ports, both on 127.0.0.1.
    """

    process: object
    url: str
    grpc_url: str
    grpc_port: int
    web_port: int

    def stop(self, timeout_s: float = 5.0) -> None:
        """Terminate the server (and its process group) and wait for it."""
        if self.process.poll() is None:
            _signal_group(self.process.pid, signal.SIGTERM)
            try:
                self.process.wait(timeout_s)
            except subprocess.TimeoutExpired:
                _signal_group(self.process.pid, signal.SIGKILL)
                self.process.wait(timeout_s)


def _signal_group(pid: int, sig: int) -> None:
    """Signal the process group led by ``pid`` (POSIX), or the process itself."""
    try:
        if hasattr(os, "killpg"):
            os.killpg(pid, sig)
        else:  # pragma: no cover - Windows
            os.kill(pid, sig)
    except ProcessLookupError:
        pass


def serve_rrd(
    path: str | os.PathLike | None,
    *,
    grpc_port: int | None = None,
    web_port: int | None = None,
    timeout_s: float = 20.0,
    log_path: str | os.PathLike | None = None,
) -> ServedViewer:
    """Serve an ``.rrd`` (or, with ``path=None``, a live gRPC proxy) in rerun's web viewer.

    Runs ``rerun --serve-web --bind 127.0.0.1`` (never all interfaces) in its own process group
    and returns once both ports accept connections. Stop it with :meth:`ServedViewer.stop`.

    Parameters
    ----------
    path : path-like or None
        Recording to serve; ``None`` serves an empty proxy an SDK can stream to.
    grpc_port, web_port : int, optional
        Ports on 127.0.0.1; free ports are chosen when omitted.
    timeout_s : float
        How long to wait for the ports, s.
    log_path : path-like, optional
        File receiving the server's stdout/stderr (default: discarded).
    """
    if path is not None and not Path(path).is_file():
        raise InputError(f"Expected an existing .rrd file, got {str(path)!r}")
    grpc_port = grpc_port or _free_port()
    web_port = web_port or _free_port()
    cmd = [
        str(rerun_binary()),
        "--serve-web",
        "--bind",
        "127.0.0.1",
        "--port",
        str(grpc_port),
        "--web-viewer-port",
        str(web_port),
    ]
    if path is not None:
        cmd.append(str(path))
    proc = _start(cmd, log_path)
    grpc_url = f"rerun+http://127.0.0.1:{grpc_port}/proxy"
    served = ServedViewer(
        proc,
        f"http://127.0.0.1:{web_port}/?url={_quote(grpc_url)}",
        grpc_url,
        grpc_port,
        web_port,
    )
    try:
        _wait_for_port(grpc_port, proc, timeout_s, log_path)
        _wait_for_port(web_port, proc, timeout_s, log_path)
    except BaseException:
        served.stop()
        raise
    return served


def _quote(s: str) -> str:
    from urllib.parse import quote

    return quote(s, safe="")


def has_display() -> bool:
    """True when a graphical display is available (Linux: DISPLAY or WAYLAND_DISPLAY set)."""
    if sys.platform.startswith("linux"):
        return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    return True  # macOS and Windows always have a desktop session for a local user


def _spawn_viewer(view: ViewData, realtime: bool) -> str:
    """Start the native viewer on 127.0.0.1 (detached) and stream the view to it."""
    port = _free_port()
    log_path = Path(tempfile.gettempdir()) / f"imu_dcm_rerun_viewer_{port}.log"
    cmd = [str(rerun_binary()), "--bind", "127.0.0.1", "--port", str(port), "--expect-data-soon"]
    proc = _start(cmd, log_path)
    _wait_for_port(port, proc, 20.0, log_path)
    rec = _new_recording(view)
    rec.connect_grpc(f"rerun+http://127.0.0.1:{port}/proxy", default_blueprint=make_blueprint(view))
    rec.send_recording_name(view.title)
    send_view(view, rec, realtime=realtime)
    rec.flush(timeout_sec=_FLUSH_TIMEOUT_S)
    rec.disconnect()
    return f"rerun: viewer started (pid {proc.pid}, listening on 127.0.0.1:{port})"


def _safe_stem(title: str) -> str:
    stem = re.sub(r"[^A-Za-z0-9._-]+", "_", title).strip("._")
    return stem or "replay"


def show_replay(
    view: ViewData, mode: str | None, save_dir: str | os.PathLike, realtime: bool = False
) -> str:
    """Show a replay in rerun and return the one line to print about it.

    Parameters
    ----------
    view : ViewData
        The arrays to show.
    mode : {"spawn", "serve", "save:PATH.rrd", "off", None}
        ``"spawn"``: start the native viewer (listening on 127.0.0.1) and stream to it; needs a
        display. ``"serve"``: save to a temporary ``.rrd`` and serve it with the ``rerun``
        binary's web viewer bound to 127.0.0.1; the server keeps running after return (the line
        gives the URL and the pid to stop). ``"save:PATH.rrd"``: write the file. ``"off"``:
        nothing. ``None``: ``"spawn"`` when a display exists, else save to
        ``save_dir/<title>.rrd``.
    save_dir : path-like
        Folder of the default ``.rrd`` (``mode=None`` without a display).
    realtime : bool
        Pace the data at the recorded speed in small chunks (for live viewing with ``"spawn"``
        and ``"serve"``; with ``"serve"`` the URL is printed before streaming). Files are
        written at full speed.

    Returns
    -------
    str
        The line to print (how to open the view); empty for ``"off"``.

    Raises
    ------
    InputError
        For an unknown mode, a ``save:`` path not ending in ``.rrd``, or ``"spawn"`` without a
        display.
    """
    if mode is None:
        mode = (
            "spawn"
            if has_display()
            else f"save:{Path(save_dir) / (_safe_stem(view.title) + '.rrd')}"
        )
    if not isinstance(mode, str):
        raise InputError(f"Expected rerun mode one of {_MODES}, got {mode!r}")
    if mode == "off":
        return ""
    if mode.startswith("save:"):
        target = mode[len("save:") :]
        if not target.endswith(".rrd") or len(target) <= len(".rrd"):
            raise InputError(f"Expected rerun mode save:PATH.rrd, got {mode!r}")
        path = save_rrd(view, target)
        return f"rerun: saved {path}; open it with: rerun {path}"
    if mode == "serve":
        if realtime:
            served = serve_rrd(None)
            print(f"rerun: open {served.url} (streaming at recorded speed)", flush=True)
            rec = _new_recording(view)
            rec.connect_grpc(served.grpc_url, default_blueprint=make_blueprint(view))
            rec.send_recording_name(view.title)
            send_view(view, rec, realtime=True)
            rec.flush(timeout_sec=_FLUSH_TIMEOUT_S)
            rec.disconnect()
        else:
            folder = Path(tempfile.mkdtemp(prefix="imu_dcm_rerun_"))
            served = serve_rrd(save_rrd(view, folder / (_safe_stem(view.title) + ".rrd")))
        return (
            f"rerun: web viewer at {served.url} (127.0.0.1 only; "
            f"stop it with: kill {served.process.pid})"
        )
    if mode == "spawn":
        if not has_display():
            raise InputError(
                "Expected a display (DISPLAY or WAYLAND_DISPLAY) for rerun mode 'spawn', got none; "
                "use 'serve' or 'save:PATH.rrd'"
            )
        return _spawn_viewer(view, realtime)
    raise InputError(f"Expected rerun mode one of {_MODES}, got {mode!r}")

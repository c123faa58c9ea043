"""What is logged to rerun: the entities, their colours, the blueprint, and sending a view.

See :mod:`imu_dcm.viz` for the table of entities. Every time-varying entity goes out in
``send_columns`` calls of at most ``_BLOCK_ROWS`` rows (never one log call per sample; the block
bounds the memory a long log's view needs), or in chunks of ``chunk_s`` seconds when paced at
the recorded speed.
"""

from __future__ import annotations

import math
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from imu_dcm.errors import InputError
from imu_dcm.viz.view_data import (
    TRACE_MAX_S,
    ViewData,
    axes_rows,
    body_axes_w,
    gyro_needs_split,
    trace_segments,
    trail_frames,
    trail_strips,
)

_BLOCK_ROWS = 2_000  # rows per send_columns call when the whole view is sent at once

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
    "gyro": "/gyro/omega_b",  # the live view's: the three rates as three series of one entity
}
"""Entity paths of the view (see the module docstring)."""

# Truth: saturated RGB; estimate: the same hues, light.
TRUTH_RGB = np.array([[220, 40, 40], [30, 170, 50], [40, 90, 235]], dtype=np.uint8)
EST_RGB = np.array([[255, 165, 150], [150, 235, 140], [150, 195, 255]], dtype=np.uint8)
# Colours readable on the viewer's light and dark themes.
TRUTH_TRAIL_RGB = (150, 70, 220)
EST_TRAIL_RGB = (240, 150, 0)
#: Radii of the body axes' arrows and of the z-tip trails, by entity ("estimate", "truth").
AXES_RADIUS = {"estimate": 0.018, "truth": 0.035}
TRAIL_RADIUS = {"estimate": 0.004, "truth": 0.007}
_ERROR_RGB = [(190, 50, 190), (255, 140, 40), (40, 160, 230)]
_GYRO_RGB = [(230, 70, 70), (70, 200, 90), (80, 130, 255)]
_GYRO_RAW_RGB = [(140, 110, 110), (110, 140, 115), (110, 120, 150)]
_AXES = "xyz"


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
                name=(
                    "body axes: truth solid, estimate light; "
                    "z-axis tip: truth purple, estimate amber"
                ),
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
    fields: dict | Callable[[int, int], dict]
    lengths: NDArray[np.intp] | None = None

    def columns(self, a: int = 0, b: int | None = None):
        """Rerun columns of rows ``[a, b)``."""
        b = len(self.t_rel_s) if b is None else b
        if callable(self.fields):  # made per slice (the trails: bounded memory)
            return self.archetype.columns(**self.fields(a, b))
        if self.lengths is None:
            cols = self.archetype.columns(**{k: v[a:b] for k, v in self.fields.items()})
            return cols
        offsets = np.concatenate([[0], np.cumsum(self.lengths)])
        lo, hi = offsets[a], offsets[b]
        cols = self.archetype.columns(**{k: v[lo:hi] for k, v in self.fields.items()})
        return cols.partition(self.lengths[a:b])


def _axes_entity(
    path: str,
    t_rel: NDArray,
    axes: NDArray,
    has: NDArray,
    rgb: NDArray,
    radius: float,
    labelled: bool = False,
) -> _Entity:
    """Body axes as Arrows3D, three per row that has an attitude; rows without one hold no
    arrows (an empty row clears the previous axes)."""
    import rerun as rr

    n = int(has.sum())
    fields = {
        "vectors": axes[has].reshape(-1, 3),
        "colors": np.tile(rgb, (n, 1)),
        "radii": np.full(3 * n, radius, dtype=np.float32),
    }
    if labelled:
        fields["labels"] = np.tile(np.array(["x", "y", "z"]), n)
    return _Entity(path, t_rel, rr.Arrows3D, fields, np.where(has, 3, 0).astype(np.intp))


def _trail_fields(t_s: NDArray, tip: NDArray, frames: NDArray, color, radius: float):
    """The trail's strips for frames ``[a, b)``, made when sent (120 points per frame: a
    25-minute log's strips made at once would hold ~130 MB per trail)."""

    def fields(a: int, b: int) -> dict:
        n = b - a
        return {
            "strips": trail_strips(t_s, tip, frames[a:b]),
            "colors": np.tile(np.array(color, dtype=np.uint8), (n, 1)),
            "radii": np.full(n, radius, dtype=np.float32),
        }

    return fields


def _entities(view: ViewData) -> list[_Entity]:
    """Every time-varying entity of the view."""
    import rerun as rr

    t_rel = view.t_s - view.t_s[0]
    est_axes, has_est = body_axes_w(view.q_est)  # (N, 3 axes, 3)
    true_axes, has_truth = body_axes_w(view.q_truth)
    rows = axes_rows(view.t_s)  # thinned to AXES_HZ: memory bounded on long logs
    out = [
        _axes_entity(
            ENTITY["estimate_axes"],
            t_rel[rows],
            est_axes[rows],
            has_est[rows],
            EST_RGB,
            AXES_RADIUS["estimate"],
        ),
        _axes_entity(
            ENTITY["truth_axes"],
            t_rel[rows],
            true_axes[rows],
            has_truth[rows],
            TRUTH_RGB,
            AXES_RADIUS["truth"],
            True,
        ),
    ]
    frames = trail_frames(view.t_s)
    tips = {
        "truth_trail": true_axes[:, 2],
        "estimate_trail": est_axes[:, 2],
    }
    for key, tip in tips.items():
        color = EST_TRAIL_RGB if key == "estimate_trail" else TRUTH_TRAIL_RGB
        radius = TRAIL_RADIUS["estimate" if key == "estimate_trail" else "truth"]
        out.append(
            _Entity(
                ENTITY[key],
                t_rel[frames],
                rr.LineStrips3D,
                _trail_fields(view.t_s, tip, frames, color, radius),
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


def send_styles(view: ViewData, rec, *, gyro_one_entity: bool = False) -> None:
    """View coordinates, series styles and the faint full z-tip traces (static, sent once).

    ``gyro_one_entity``: the rates go to ``ENTITY["gyro"]`` as three series of one entity (the
    live view: one ``send_columns`` per batch instead of three), styled as the three entities.
    """
    import rerun as rr

    rec.log("/world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    rec.log(
        ENTITY["errors"],
        rr.SeriesLines(
            names=["total", "inclination", "heading"], colors=_ERROR_RGB, widths=[3.5, 1.5, 1.5]
        ),
        static=True,
    )
    if gyro_one_entity:
        names = [f"ω_{axis}" for axis in _AXES]
        rec.log(
            ENTITY["gyro"], rr.SeriesLines(names=names, colors=_GYRO_RGB, widths=[1.5]), static=True
        )
    for k, axis in enumerate(_AXES if not gyro_one_entity else ()):
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
        "estimate_trace": body_axes_w(view.q_est)[0][:, 2],
        "truth_trace": body_axes_w(view.q_truth)[0][:, 2],
    }
    for key, tip in tips.items():
        segments = trace_segments(tip)
        if segments:
            color = (*EST_TRAIL_RGB, 110) if key == "estimate_trace" else (*TRUTH_TRAIL_RGB, 90)
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
        False: each entity in ``send_columns`` calls of ``_BLOCK_ROWS`` rows. True: pace the
        replay at the recorded speed, sending every entity's rows in chunks of ``chunk_s``
        seconds of log time (``send_columns`` per chunk) and sleeping to the wall clock in
        between.
    chunk_s : float
        Chunk length for ``realtime``, s.
    """
    if realtime and not chunk_s > 0:
        raise InputError(f"Expected `chunk_s` > 0, got {chunk_s!r}")
    send_styles(view, rec)
    entities = _entities(view)
    if not realtime:
        for e in entities:  # in blocks of rows: what is made at once stays bounded
            for a in range(0, len(e.t_rel_s), _BLOCK_ROWS):
                b = min(a + _BLOCK_ROWS, len(e.t_rel_s))
                rec.send_columns(
                    e.path, indexes=[_time_column(e.t_rel_s[a:b])], columns=e.columns(a, b)
                )
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


def new_recording(view: ViewData):
    import rerun as rr

    rec = rr.RecordingStream("imu_dcm", recording_id=uuid.uuid4())
    return rec

"""Rerun view of a replay: true and estimated body axes in 3D, attitude error and gyro over time.

Conventions (see README "Frames and units"): quaternions are Hamilton ``[x, y, z, w]`` (scalar
last, the order rerun uses), ``q_w_b`` maps body to world, so the body axes drawn in the world are
the columns of ``R_w_b`` (``quat_rotate(q_w_b, e_k)``); world is ENU, z up; ``omega_b`` is the body
rate relative to the world in body axes, rad/s; time ``t_s`` in seconds, shown on the rerun
timeline ``"time"`` (a duration timeline).

What is sent (every time-varying entity in ``send_columns`` calls of a few thousand rows, one
row per sample unless stated):

=====================================  ==========================================================
entity                                 content
=====================================  ==========================================================
``/world/truth/axes``                  Arrows3D, true body x/y/z axes, solid red/green/blue;
                                       an empty row where there is no truth; one row per
                                       ``1 / AXES_HZ`` s of log time and the last sample
``/world/estimate/axes``               Arrows3D, estimated body axes, light red/green/blue;
                                       an empty row where there is no estimate (thinned too)
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
127.0.0.1 (the SDK's own servers bind every interface, so they are not used); the command line
keeps it up until Ctrl-C, then stops the server and removes the file (:func:`serve_replay`);
``"save:PATH.rrd"`` writes a file; ``"off"`` does nothing; ``None`` spawns when a display
exists, else shows nothing and writes nothing (one line, :data:`HEADLESS_HINT`, names the
other modes).

Modules: ``view_data`` (:class:`ViewData` and the geometry drawn from it), ``log`` (what is
logged: entities, colours, blueprint, :func:`send_view`), ``viewer`` (how it is shown:
:func:`save_rrd`, :func:`serve_rrd`, the native viewer, :func:`show_replay`) and ``live``
(live's view, :class:`imu_dcm.viz.live.LiveView`: the same entities fed in batches as a live run
goes; imported by live, not here, so that importing viz loads no rerun).
"""

from __future__ import annotations

from imu_dcm.viz.log import ENTITY, TIMELINE, make_blueprint, send_styles, send_view
from imu_dcm.viz.view_data import (
    AXES_HZ,
    TRACE_MAX_POINTS,
    TRACE_MAX_S,
    TRAIL_FPS,
    TRAIL_POINTS,
    TRAIL_S,
    ViewData,
    gyro_needs_split,
)
from imu_dcm.viz.viewer import (
    HEADLESS_HINT,
    ServedReplay,
    ServedViewer,
    has_display,
    rerun_binary,
    save_rrd,
    saved_line,
    serve_replay,
    serve_rrd,
    show_replay,
)

__all__ = [
    "AXES_HZ",
    "HEADLESS_HINT",
    "ServedReplay",
    "serve_replay",
    "ENTITY",
    "TIMELINE",
    "TRACE_MAX_POINTS",
    "TRACE_MAX_S",
    "TRAIL_FPS",
    "TRAIL_POINTS",
    "TRAIL_S",
    "ServedViewer",
    "ViewData",
    "gyro_needs_split",
    "has_display",
    "make_blueprint",
    "rerun_binary",
    "save_rrd",
    "saved_line",
    "send_styles",
    "send_view",
    "serve_rrd",
    "show_replay",
]

"""What a view holds: :class:`ViewData` (whole arrays, one row per gyro sample) and the geometry
drawn from it (body axes in the world, the trailing and full traces of the body z tip).

Conventions: quaternions Hamilton ``[x, y, z, w]``, ``q_w_b`` body to world, so the body axes
drawn in the world are the columns of ``R_w_b``; world ENU, z up; ``omega_b`` body rate in body
axes, rad/s; ``t_s`` seconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from imu_dcm.errors import InputError
from imu_dcm.so3 import quat_rotate

TRAIL_S = 2.0
"""Length of the trailing z-tip window, s."""
TRAIL_FPS = 30.0
"""Frames per second of log time at which the trailing window is sent."""
TRAIL_POINTS = 120
"""Points per trailing-window strip (the window is resampled to this many samples)."""
AXES_HZ = 60.0
"""Rows of 3D body axes per second of log time (the viewer draws the latest row anyway; the
scalars keep every sample). Bounds the view's memory on long logs, as live's view does."""
"""Points per trailing-window strip (the window is resampled to this many samples)."""
TRACE_MAX_POINTS = 20_000
"""Upper bound on the points of the static full z-tip trace."""
TRACE_MAX_S = 30.0
"""Logs longer than this (s) get no static full trace: it would be an unreadable tangle."""


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


def body_axes_w(q_w_b: NDArray) -> tuple[NDArray, NDArray[np.bool_]]:
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


def trail_frames(t_s: NDArray, fps: float = TRAIL_FPS) -> NDArray[np.intp]:
    """Sample index of each frame: the last sample at or before k / fps."""
    rel = t_s - t_s[0]
    n_frames = math.floor(rel[-1] * fps) + 1
    idx = np.searchsorted(rel, np.arange(n_frames) / fps, side="right") - 1
    return np.unique(np.clip(idx, 0, len(t_s) - 1))


def axes_rows(t_s: NDArray) -> NDArray[np.intp]:
    """Samples whose body axes are drawn: one per 1 / AXES_HZ of log time, and the last."""
    return np.union1d(trail_frames(t_s, AXES_HZ), [len(t_s) - 1])


def trail_strips(t_s: NDArray, tip_w: NDArray, frames: NDArray[np.intp]) -> list[NDArray]:
    """Per frame, the tip positions over the last TRAIL_S seconds (NaN points dropped)."""
    start = np.searchsorted(t_s, t_s[frames] - TRAIL_S, side="left")
    j = np.linspace(0.0, 1.0, TRAIL_POINTS)
    idx = np.rint(start[:, None] + (frames - start)[:, None] * j[None, :]).astype(np.intp)
    pts = tip_w[idx]  # (F, TRAIL_POINTS, 3)
    ok = np.all(np.isfinite(pts), axis=2)
    if ok.all():
        return list(pts)
    return [p[m] for p, m in zip(pts, ok, strict=True)]


def trace_segments(tip_w: NDArray) -> list[NDArray]:
    """The whole tip trace, decimated to <= TRACE_MAX_POINTS, split where it is NaN."""
    step = max(1, math.ceil(len(tip_w) / TRACE_MAX_POINTS))
    pts = tip_w[::step]
    ok = np.all(np.isfinite(pts), axis=1)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], ok.astype(np.int8), [0]])))
    return [pts[a:b] for a, b in zip(edges[0::2], edges[1::2], strict=True) if b - a >= 2]


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

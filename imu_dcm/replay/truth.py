"""The truth side of a replay: which time base to trust, truth attitudes at the gyro stamps, and
whether the truth is the IMU's attitude at all.

* :func:`choose_time` — ``"auto"`` uses the header stamps unless they are all equal, fall in
  file order at more than 10 % of the steps, or miss the truth while the log times overlap it;
  then the log (receive) times, with the reason in one line.
* :func:`slerp_truth` — truth ``q_w_b`` at the gyro stamps, never bridged across long gaps
  (from :mod:`imu_dcm.gyro.resample`, the core, where live uses it too).
* :func:`align_truth` — all of it for a replay: offset, check, slerp, and the decision to drop
  an automatically picked truth that does not follow the gyro.
* :func:`check_truth` — the body rate implied by the truth against the gyro: the rate norms
  (frame-free, so a constant mounting rotation does not matter) are correlated over time shifts
  of up to ±0.5 s; the best shift, its correlation and the residual rate error are returned.
  A truth that does not follow the gyro (correlation below :data:`MIN_CORRELATION`, or, when a
  rate norm hardly varies and cannot be correlated, a still truth under a clearly turning
  gyro) is not the IMU's attitude: wheel odometry in ``base_link`` under
  an IMU that also tilts, or another body's pose.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from imu_dcm.arrays import median, row_finite, row_norm
from imu_dcm.errors import LogError
from imu_dcm.gyro.resample import TRUTH_BRIDGE_STEPS, slerp_truth
from imu_dcm.so3 import log_quat, quat_angle_rad, quat_conjugate, quat_multiply

__all__ = [
    "MIN_CORRELATION",
    "TRUTH_BRIDGE_STEPS",
    "AlignedTruth",
    "RateGrid",
    "TruthCheck",
    "TruthJump",
    "align_truth",
    "check_truth",
    "choose_time",
    "find_jumps",
    "rate_grid",
    "slerp_truth",
]

#: A truth whose rate norm correlates less than this with the gyro's does not follow it.
MIN_CORRELATION = 0.6
#: Time shifts searched between truth and gyro, s (each way).
MAX_SHIFT_S = 0.5
#: Below this spread of the rate norm (rad/s) a series is taken as still.
STILL_RAD_S = 0.05
#: Header stamps falling at more than this fraction of file-order steps are "not increasing".
MAX_BACKWARD_FRACTION = 0.1


@dataclass(frozen=True)
class TruthCheck:
    """How well the truth's rotation rate follows the gyro's.

    Attributes
    ----------
    checked : bool — False when there was too little overlap or motion to tell.
    follows : bool — the truth moves with the gyro (True when unchecked: no evidence against).
    shift_s : float or None — time shift to add to the truth stamps that best aligns the rates.
    correlation : float or None — Pearson correlation of the rate norms at ``shift_s``.
    residual_rad_s : float or None — RMS of (gyro − truth) rate norm at ``shift_s``, rad/s.
    gyro_rms_rad_s : float or None — RMS of the gyro rate norm over the same samples, rad/s.
    """

    checked: bool
    follows: bool
    shift_s: float | None = None
    correlation: float | None = None
    residual_rad_s: float | None = None
    gyro_rms_rad_s: float | None = None

    def describe(self) -> str:
        """One clause for a person: shift, correlation and residual."""
        if not self.checked:
            return "too little overlap or motion to compare the rates"
        if self.correlation is None:
            return (
                f"rate norms nearly constant: residual {self.residual_rad_s:.3f} rad/s "
                f"(gyro RMS {self.gyro_rms_rad_s:.3f} rad/s)"
            )
        return (
            f"rate-norm correlation {self.correlation:.2f} at a shift of "
            f"{self.shift_s * 1e3:+.1f} ms, residual {self.residual_rad_s:.3f} rad/s "
            f"(gyro RMS {self.gyro_rms_rad_s:.3f} rad/s)"
        )


def _span(t: NDArray[np.int64]) -> tuple[int, int]:
    return int(t.min()), int(t.max())


def _overlap(a: NDArray[np.int64], b: NDArray[np.int64]) -> bool:
    (a0, a1), (b0, b1) = _span(a), _span(b)
    return a0 <= b1 and b0 <= a1


def _backward_fraction(t: NDArray[np.int64]) -> float:
    return float(np.mean(np.diff(t) < 0)) if len(t) > 1 else 0.0


def choose_time(
    mode: str,
    imu_t_ns: NDArray[np.int64],
    imu_log_t_ns: NDArray[np.int64],
    truth_t_ns: NDArray[np.int64] | None,
    truth_log_t_ns: NDArray[np.int64] | None,
) -> tuple[str, str | None]:
    """The time base to use, ``"header"`` or ``"log"``, and why log time was chosen (or None).

    ``mode`` is ``"header"``, ``"log"`` (used as given) or ``"auto"`` (the rule of this module).
    All stamps int64 ns in file order; the truth arguments are None without truth.
    """
    if mode != "auto":
        return mode, None
    h, lg = imu_t_ns, imu_log_t_ns
    if len(h) > 1 and np.all(h == h[0]):
        return "log", f"the IMU header stamps are all equal ({int(h[0])} ns)"
    back_h, back_l = _backward_fraction(h), _backward_fraction(lg)
    if back_h > MAX_BACKWARD_FRACTION and back_l < back_h / 2:
        return "log", (
            f"the IMU header stamps fall at {100 * back_h:.0f} % of the steps in file "
            f"order (log times at {100 * back_l:.0f} %)"
        )
    if (
        truth_t_ns is not None
        and truth_log_t_ns is not None
        and len(truth_t_ns)
        and len(h)
        and not _overlap(h, truth_t_ns)
        and _overlap(lg, truth_log_t_ns)
    ):
        return "log", (
            "the header stamps of the IMU and the truth never overlap while their log times do"
        )
    return "header", None


def lagged_correlation(
    g: NDArray[np.float64], h: NDArray[np.float64], valid: NDArray[np.bool_], lags: int
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Pearson correlation of ``g[i + k]`` with ``h[i]`` over the valid ``i``, k = -lags..lags.

    The six pair sums of a lag (count, Σa, Σa², Σb, Σb², Σab) are one 3x3 product of the
    series ``[1, g, g²]`` (at ``i + k``) with ``[valid, h, h²]`` (at ``i``, zero where not
    valid): ``2 lags + 1`` small matrix products, cheaper than FFTs for the few lags searched.
    Returns (correlation (2 lags + 1,), 0 where a series is constant; the number of pairs per
    lag).
    """
    n = len(g)
    hv = np.where(valid, h, 0.0)
    x = np.stack([np.ones(n), g, g * g])
    y = np.stack([valid.astype(float), hv, hv * hv])
    sums = np.zeros((2 * lags + 1, 3, 3))
    for j, k in enumerate(range(-lags, lags + 1)):
        if abs(k) < n:
            sums[j] = x[:, max(k, 0) : n + min(k, 0)] @ y[:, max(-k, 0) : n - max(k, 0)].T
    cnt, sa, saa = sums[:, 0, 0], sums[:, 1, 0], sums[:, 2, 0]
    sb, sbb, sab = sums[:, 0, 1], sums[:, 0, 2], sums[:, 1, 1]
    count = np.rint(cnt).astype(np.int64)
    safe = np.maximum(cnt, 1.0)
    cov = sab - sa * sb / safe
    var = np.maximum(saa - sa * sa / safe, 0.0) * np.maximum(sbb - sb * sb / safe, 0.0)
    scale = np.sqrt(var)
    tiny = scale <= 1e-12 * np.maximum(np.sqrt(saa * sbb), 1e-300)
    corr = np.where(tiny, 0.0, cov / np.where(tiny, 1.0, scale))
    return corr, count


def integrated_rate(
    t_ns: NDArray[np.int64], omega_b: NDArray[np.float64], at_ns: NDArray[np.int64]
) -> NDArray[np.float64]:
    """The trapezoid integral of the rate from the first gyro sample to each of ``at_ns``
    (linear between samples), rad (K, 3); differences give the turn over short intervals.
    Any number of columns: ``omega_b`` (N, C) gives (K, C)."""
    ts = (t_ns - t_ns[0]) * 1e-9
    cum = np.concatenate(
        [
            np.zeros((1, omega_b.shape[1])),
            np.cumsum(0.5 * (omega_b[1:] + omega_b[:-1]) * np.diff(ts)[:, None], axis=0),
        ]
    )
    te = (np.asarray(at_ns) - t_ns[0]) * 1e-9
    return np.stack([np.interp(te, ts, cum[:, k]) for k in range(cum.shape[1])], axis=1)


class RateGrid:
    """Gyro and truth rotations over the steps of one time grid (truth stamps as given).

    ``edges_ns`` int64 (K + 1,) grid edges; ``dt_s`` float (K,) step lengths; ``gyro_rotvec``
    (K, 3) the gyro's rotation over each step (trapezoid integral of the rate, gyro axes, rad);
    ``truth_rotvec`` (K, 3) the truth's body-frame rotation over each step (truth body axes,
    rad), NaN where the truth does not cover the step; ``step_s`` the grid step.
    """

    __slots__ = ("edges_ns", "dt_s", "gyro_rotvec", "truth_rotvec", "step_s")

    def __init__(
        self,
        edges_ns: NDArray[np.int64],
        dt_s: NDArray[np.float64],
        gyro_rotvec: NDArray[np.float64],
        truth_rotvec: NDArray[np.float64],
        step_s: float,
    ) -> None:
        self.edges_ns, self.dt_s, self.step_s = edges_ns, dt_s, step_s
        self.gyro_rotvec, self.truth_rotvec = gyro_rotvec, truth_rotvec


def rate_grid(
    t_ns: NDArray[np.int64],
    omega_b: NDArray[np.float64],
    truth_t_ns: NDArray[np.int64],
    q_w_b: NDArray[np.float64],
    min_step_s: float = 0.01,
) -> RateGrid | None:
    """Gyro and truth rotations on a grid of steps of ``max(min_step_s, 2 truth steps, gyro
    step)`` over their overlap; None when they overlap in fewer than 24 steps."""
    tt = np.asarray(truth_t_ns, dtype=np.int64)
    if len(t_ns) < 4 or len(tt) < 4:
        return None
    lo, hi = max(int(t_ns[0]), int(tt.min())), min(int(t_ns[-1]), int(tt.max()))
    if hi <= lo:
        return None
    dt_g = median(np.diff(t_ns)) * 1e-9
    dt_t = median(np.diff(tt if np.all(tt[1:] >= tt[:-1]) else np.sort(tt))) * 1e-9
    span_s = (hi - lo) * 1e-9
    dt = max(min_step_s, 2 * dt_t, dt_g, span_s / 100_000)
    edges = lo + np.round(np.arange(0.0, span_s, dt) * 1e9).astype(np.int64)
    if len(edges) < 24:
        return None
    te = (edges - t_ns[0]) * 1e-9
    angle = integrated_rate(t_ns, omega_b, edges)
    q = slerp_truth(tt, q_w_b, edges)
    has = row_finite(q)
    both = has[:-1] & has[1:]
    rot = np.full((len(q) - 1, 3), np.nan)
    rel = quat_multiply(quat_conjugate(q[:-1][both]), q[1:][both])
    rel = np.where(rel[:, 3:4] < 0, -rel, rel)  # shortest arc
    rot[both] = log_quat(rel)
    return RateGrid(edges, np.diff(te), np.diff(angle, axis=0), rot, dt)


def check_truth(
    t_ns: NDArray[np.int64],
    omega_b: NDArray[np.float64],
    truth_t_ns: NDArray[np.int64],
    q_w_b: NDArray[np.float64],
) -> TruthCheck:
    """Compare the truth's rotation-rate norm with the gyro's over time shifts.

    Parameters
    ----------
    t_ns : int64 (N,), strictly increasing — gyro stamps.
    omega_b : float64 (N, 3) — gyro rates, rad/s, body axes (bias left in: it is small).
    truth_t_ns : int64 (M,) — truth stamps on the same clock.
    q_w_b : float64 (M, 4) — truth ``[x, y, z, w]``.

    Returns
    -------
    TruthCheck
        On the grid of :func:`rate_grid` (mean rates over steps of at least 10 ms).
    """
    grid = rate_grid(t_ns, omega_b, truth_t_ns, q_w_b)
    if grid is None:
        return TruthCheck(False, True)
    dt = grid.step_s
    g = row_norm(grid.gyro_rotvec) / grid.dt_s
    h = row_norm(grid.truth_rotvec) / grid.dt_s  # NaN where uncovered
    valid = np.isfinite(h)
    if valid.sum() < 20:
        return TruthCheck(False, True)
    g0, h0 = g[valid], h[valid]
    resid0 = float(np.sqrt(np.mean((g0 - h0) ** 2)))
    g_rms0 = float(np.sqrt(np.mean(g0**2)))
    if np.std(g0) < STILL_RAD_S or np.std(h0) < STILL_RAD_S:
        # A norm that hardly varies (a still body, a steady spin) has no shape to correlate:
        # only one still under the other clearly turning is evidence against it (either way:
        # an all-zero gyro under a turning truth is no gyro of that body)
        still_truth, still_gyro = float(np.mean(h0)) < STILL_RAD_S, float(np.mean(g0)) < STILL_RAD_S
        turning_g, turning_t = (
            float(np.mean(g0)) > 10 * STILL_RAD_S,
            float(np.mean(h0)) > 10 * STILL_RAD_S,
        )
        against = (still_truth and turning_g) or (still_gyro and turning_t)
        return TruthCheck(True, not against, None, None, resid0, g_rms0)
    span_s = (grid.edges_ns[-1] - grid.edges_ns[0]) * 1e-9
    lags = int(min(MAX_SHIFT_S, span_s / 4) / dt)
    corr, count = lagged_correlation(g, h, valid, lags)
    ok = count >= 20
    if not ok.any():
        return TruthCheck(False, True)
    j = int(np.argmax(np.where(ok, corr, -np.inf)))
    k, c = j - lags, float(corr[j])
    n = len(g)
    m = valid[max(-k, 0) : n - max(k, 0)]
    a = g[max(k, 0) : n + min(k, 0)][m]  # g[i + k] against h[i]
    b = h[max(-k, 0) : n - max(k, 0)][m]
    resid, g_rms = float(np.sqrt(np.mean((a - b) ** 2))), float(np.sqrt(np.mean(a**2)))
    shift = k * dt
    if 0 < j < len(corr) - 1 and ok[j - 1] and ok[j + 1]:  # parabola through the peak
        y0, y2 = float(corr[j - 1]), float(corr[j + 1])
        den = y0 - 2 * c + y2
        if den < 0:
            shift += 0.5 * (y0 - y2) / den * dt
    return TruthCheck(True, c >= MIN_CORRELATION, shift, c, resid, g_rms)


class AlignedTruth:
    """The truth at the gyro stamps, after the offset and the rate check.

    ``q_truth`` (N, 4) ``[x, y, z, w]``, NaN where there is none (all NaN when rejected);
    ``truth`` the series used, or None; ``check`` the rate comparison; ``offset_s`` the shift
    applied to the truth stamps; ``rejected`` the topic of an auto-picked truth that did not
    follow the gyro.
    """

    __slots__ = ("q_truth", "truth", "check", "offset_s", "rejected")

    def __init__(
        self,
        q_truth: NDArray[np.float64],
        truth: object | None,
        check: TruthCheck | None,
        offset_s: float,
        rejected: str | None,
    ) -> None:
        self.q_truth, self.truth, self.check = q_truth, truth, check
        self.offset_s, self.rejected = offset_s, rejected


def _spans_overlap(a: NDArray[np.int64], b: NDArray[np.int64]) -> bool:
    return bool(len(a) and len(b) and a.min() <= b.max() and b.min() <= a.max())


def align_truth(
    truth,
    base: str,
    t_ns: NDArray[np.int64],
    omega_b: NDArray[np.float64],
    offset: float | str,
    imu_log_t_ns: NDArray[np.int64],
    warn: Callable[[str], None],
) -> AlignedTruth:
    """Shift, check and slerp the truth at the gyro stamps.

    Parameters
    ----------
    truth : TruthSeries or None
        From the reader (``t_ns``, ``log_t_ns``, ``q_w_b``, ``topic``, ``type``, frame ids,
        ``auto``).
    base : {"header", "log"}
        The time base chosen for the gyro, used for the truth too.
    t_ns, omega_b : the cleaned gyro stamps (N,) and rates (N, 3), rad/s.
    offset : float or "auto"
        Seconds added to the truth stamps; "auto": the best shift of :func:`check_truth`.
    imu_log_t_ns : the gyro's log times, for the hint when header stamps never overlap.
    warn : callable(str)
        Receives the one-line warnings.

    Raises
    ------
    LogError
        The truth never overlaps the gyro.
    """
    n = len(t_ns)
    none = np.full((n, 4), np.nan)
    if truth is None:
        return AlignedTruth(none, None, None, 0.0, None)
    applied = 0.0 if offset == "auto" else float(offset)
    tt = (truth.t_ns if base == "header" else truth.log_t_ns) + np.int64(round(applied * 1e9))
    q_truth = slerp_truth(tt, truth.q_w_b, t_ns)
    if not np.isfinite(q_truth[:, 3]).any():
        t0 = t_ns[0]
        span = (
            f"{(tt.min() - t0) * 1e-9:.3f}..{(tt.max() - t0) * 1e-9:.3f} s"
            if len(tt)
            else "no samples"
        )
        hint = ""
        if base == "header" and _spans_overlap(imu_log_t_ns, truth.log_t_ns):
            hint = "; their log times overlap: try --time log"
        raise LogError(
            f"Expected the truth {truth.topic} to overlap the gyro "
            f"(0..{(t_ns[-1] - t0) * 1e-9:.3f} s), got {span}{hint}"
        )
    check = check_truth(t_ns, omega_b, tt, truth.q_w_b)
    if offset == "auto" and check.shift_s is not None:
        applied = float(check.shift_s)
        tt = tt + np.int64(round(applied * 1e9))
        q_truth = slerp_truth(tt, truth.q_w_b, t_ns)
    frame = truth.child_frame_id or truth.frame_id
    what = f"truth {truth.topic} ({truth.type}{f', frame {frame}' if frame else ''})"
    if not check.follows:
        part = _following_part(t_ns, omega_b, tt, truth)
        if part is not None:
            kept, line = part
            warn(f"{what} does not follow the gyro as a whole ({check.describe()}); {line}")
            q_truth = slerp_truth(tt[kept], truth.q_w_b[kept], t_ns)
            sub = dataclasses.replace(
                truth, t_ns=truth.t_ns[kept], log_t_ns=truth.log_t_ns[kept],
                q_w_b=truth.q_w_b[kept],
                p_w=None if getattr(truth, "p_w", None) is None else truth.p_w[kept],
                omega_b=None if getattr(truth, "omega_b", None) is None else truth.omega_b[kept],
            )  # fmt: skip
            return AlignedTruth(q_truth, sub, check, applied, None)
    if not check.follows and truth.auto:
        warn(
            f"{what} does not follow the gyro ({check.describe()}): replaying without truth; "
            f"name it with --truth-topic to score it anyway"
        )
        return AlignedTruth(none, None, check, applied, truth.topic)
    if not check.follows:
        warn(f"{what} does not follow the gyro ({check.describe()}); scored anyway, as asked")
    return AlignedTruth(q_truth, truth, check, applied, None)


def _following_part(t_ns, omega_b, tt, truth):
    """The truth samples of the stretches between its jumps that follow the gyro, and one line
    naming them and the others with their times; None when no stretch, or every one, does.

    A stretch follows when :func:`check_truth` correlates its rates with the gyro's (enough
    overlap and motion) and finds it follows: a truth good for a while (until a crash flips the
    pose) is scored there. A stretch too still to correlate shows nothing and is left out.
    """
    jumps = find_jumps(t_ns, omega_b, tt, truth.q_w_b)
    if not jumps:
        return None
    t0 = int(t_ns[0])
    cuts = [(-np.inf, jumps[0].t0_s)]
    cuts += [(a.t1_s, b.t0_s) for a, b in zip(jumps[:-1], jumps[1:], strict=True)]
    cuts.append((jumps[-1].t1_s, np.inf))
    te = (tt - t0) * 1e-9
    kept = np.zeros(len(tt), dtype=bool)
    good: list[str] = []
    bad: list[tuple[float, float, int]] = []
    last_good = False
    for a, b in cuts:
        sel = (te >= a) & (te <= b)
        lo, hi = max(a, 0.0), min(b, (t_ns[-1] - t0) * 1e-9)
        g = (t_ns >= t0 + a * 1e9) & (t_ns <= t0 + b * 1e9)
        chk = check_truth(t_ns[g], omega_b[g], tt[sel], truth.q_w_b[sel]) if g.sum() > 3 else None
        if chk is not None and chk.correlation is not None and chk.follows:
            kept |= sel
            good.append(f"{lo:.2f}-{hi:.2f} s ({chk.describe()})")
            last_good = True
        elif hi > lo:
            if bad and not last_good:  # stretches apart only by a jump: one span
                bad[-1] = (bad[-1][0], hi, bad[-1][2] + 1)
            else:
                bad.append((lo, hi, 1))
            last_good = False
    if not good or not bad:
        return None
    shown = ", ".join(f"{a:.2f}-{b:.2f} s ({n} stretch{'es' if n > 1 else ''})" for a, b, n in bad)
    line = (
        f"between its {len(jumps)} jumps it follows in {'; '.join(good)}: scored there only; "
        f"not in {shown}"
    )
    return kept, line


#: A truth step that turns this much more than the gyro over the same interval is a jump, deg.
JUMP_DEG = 5.0
#: ... and at least this many times the gyro's turn (a fast turn's noise is not a jump).
JUMP_RATIO = 3.0


@dataclass(frozen=True)
class TruthJump:
    """A truth step the gyro does not show: from ``t0_s`` to ``t1_s`` (s since the first gyro
    sample) the truth turns ``truth_deg`` while the gyro turns ``gyro_deg``."""

    t0_s: float
    t1_s: float
    truth_deg: float
    gyro_deg: float

    def describe(self) -> str:
        return (
            f"{self.truth_deg:.1f}° at {self.t0_s:.3f} s in {1e3 * (self.t1_s - self.t0_s):.0f} ms "
            f"(gyro {self.gyro_deg:.1f}°)"
        )


def find_jumps(
    t_ns: NDArray[np.int64],
    omega_b: NDArray[np.float64],
    truth_t_ns: NDArray[np.int64],
    q_w_b: NDArray[np.float64],
) -> tuple[TruthJump, ...]:
    """Truth steps that turn more than the gyro over the same interval (see :data:`JUMP_DEG`).

    Every step between consecutive truth samples inside the gyro's span is compared: the
    truth's angle against the gyro's path length over the same interval (the integral of
    ``|omega|``, which no rotation over the interval can exceed, whatever its axes; frame-free,
    so the mounting does not matter).

    Parameters
    ----------
    t_ns : int64 (N,) — gyro stamps, increasing; ``omega_b`` (N, 3) rad/s.
    truth_t_ns : int64 (M,) — truth stamps on the gyro's clock; ``q_w_b`` (M, 4).
    """
    tt = np.asarray(truth_t_ns, dtype=np.int64)
    q = np.asarray(q_w_b, dtype=float)
    norm = row_norm(q)
    ok = np.isfinite(norm) & (norm > 0.5)
    tt, q = tt[ok], q[ok] / norm[ok, None]
    if not np.all(tt[1:] >= tt[:-1]):  # a stable sort leaves sorted stamps as they are
        order = np.argsort(tt, kind="stable")
        tt, q = tt[order], q[order]
    inside = (tt >= t_ns[0]) & (tt <= t_ns[-1])
    tt, q = tt[inside], q[inside]
    if len(tt) < 2 or len(t_ns) < 2:
        return ()
    # Only a step turning more than JUMP_DEG can be one: |q_i · q_i+1| = cos(θ/2) screens the
    # steps at 0.9 JUMP_DEG (its rounding moves θ by ~1e-14 rad there, far inside the margin);
    # the exact angles and the gyro's path are computed for the few steps left, the same
    # numbers as over every step.
    cos_half = np.abs(np.einsum("ij,ij->i", q[:-1], q[1:]))
    i = np.flatnonzero(cos_half < np.cos(np.radians(0.9 * JUMP_DEG) / 2))
    if not len(i):
        return ()
    truth_deg = np.degrees(quat_angle_rad(q[i], q[i + 1]))
    # the gyro's path length over each truth step bounds any rotation it can have made
    speed = row_norm(omega_b)[:, None]
    path = integrated_rate(t_ns, speed, np.stack([tt[i], tt[i + 1]], axis=1).ravel())
    gyro_deg = np.degrees(np.diff(path[:, 0].reshape(-1, 2), axis=1)[:, 0])
    te = (tt - t_ns[0]) * 1e-9
    jump = (truth_deg - gyro_deg > JUMP_DEG) & (truth_deg > JUMP_RATIO * gyro_deg)
    return tuple(
        TruthJump(float(te[k]), float(te[k + 1]), float(truth_deg[m]), float(gyro_deg[m]))
        for m, k in zip(np.flatnonzero(jump).tolist(), i[jump].tolist(), strict=True)
    )

"""The truth side of a replay: which time base to trust, truth attitudes at the gyro stamps, and
whether the truth is the IMU's attitude at all.

* :func:`choose_time` — ``"auto"`` uses the header stamps unless they are all equal, fall in
  file order at more than 10 % of the steps, or miss the truth while the log times overlap it;
  then the log (receive) times, with the reason in one line.
* :func:`slerp_truth` — truth ``q_w_b`` at the gyro stamps, never bridged across long gaps
  (from :mod:`imu_dcm.gyro.resample`, the core, where live uses it too).
* :func:`align_truth` — all of it for a replay: offset, the rate check
  (:func:`imu_dcm.replay.rate_check.check_truth`), slerp, and the decision to drop an
  automatically picked truth that does not follow the gyro (or to keep the stretches between
  its jumps that do).
* :func:`find_jumps` — truth steps that turn more than the gyro could have over the same
  interval (:class:`TruthJump`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from imu_dcm.arrays import BLOCK_ROWS, row_norm
from imu_dcm.errors import LogError
from imu_dcm.gyro.resample import TRUTH_BRIDGE_STEPS, slerp_truth
from imu_dcm.replay.rate_check import TruthCheck, check_truth, integrated_rate
from imu_dcm.so3 import quat_angle_rad

__all__ = [
    "JUMP_DEG",
    "JUMP_RATIO",
    "TRUTH_BRIDGE_STEPS",
    "AlignedTruth",
    "TruthJump",
    "align_truth",
    "choose_time",
    "find_jumps",
    "slerp_truth",
]

#: Header stamps falling at more than this fraction of file-order steps are "not increasing".
MAX_BACKWARD_FRACTION = 0.1


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


@dataclass(slots=True, frozen=True)
class AlignedTruth:
    """The truth at the gyro stamps, after the offset and the rate check.

    ``q_truth`` (N, 4) ``[x, y, z, w]``, NaN where there is none (all NaN when rejected);
    ``truth`` the series used, or None; ``check`` the rate comparison; ``offset_s`` the shift
    applied to the truth stamps; ``rejected`` the topic of an auto-picked truth that did not
    follow the gyro.
    """

    q_truth: NDArray[np.float64]
    truth: object | None
    check: TruthCheck | None
    offset_s: float
    rejected: str | None


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
    if truth is None:
        return AlignedTruth(np.full((len(t_ns), 4), np.nan), None, None, 0.0, None)
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
        q_truth[...] = np.nan  # refused: no row has a truth
        return AlignedTruth(q_truth, None, check, applied, truth.topic)
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
    used = np.isfinite(norm) & (norm > 0.5)
    if len(t_ns) and used.all() and np.all(tt[1:] >= tt[:-1]):
        # the usual truth, every row used in file order: those inside the gyro's span are one
        # run of rows, taken in place (no index of them, no gathered stamps)
        lo = int(np.searchsorted(tt, t_ns[0], side="left"))
        hi = int(np.searchsorted(tt, t_ns[-1], side="right"))
        tt, rows, r0 = tt[lo:hi], None, lo
    else:
        rows = np.flatnonzero(used)  # the truth's rows used, in order
        tt = tt[rows]
        in_order = bool(np.all(tt[1:] >= tt[:-1]))
        if not in_order:  # a stable sort leaves sorted stamps as they are
            order = np.argsort(tt, kind="stable")
            tt, rows = tt[order], rows[order]
        inside = (tt >= t_ns[0]) & (tt <= t_ns[-1])
        tt, rows = tt[inside], rows[inside]
        contiguous = in_order and len(rows) > 0 and rows[-1] - rows[0] == len(rows) - 1
        r0 = int(rows[0]) if contiguous else -1
    if len(tt) < 2 or len(t_ns) < 2:
        return ()

    def row(k):  # the truth's rows of steps k (their first rows)
        return r0 + k if rows is None else rows[k]

    def unit(r):  # the truth's rows r, normalised (gathered a block at a time: no copy of all)
        return q[r] / norm[r, None]

    # Only a step turning more than JUMP_DEG can be one: |q_i · q_i+1| = cos(θ/2) screens the
    # steps at 0.9 JUMP_DEG (its rounding moves θ by ~1e-14 rad there, far inside the margin);
    # the exact angles and the gyro's path are computed for the few steps left, the same
    # numbers as over every step.
    # the usual truth, every row used in file order, is read in place (no gathered copy)
    cos_half = np.empty(len(tt) - 1)
    for a in range(0, len(cos_half), BLOCK_ROWS):
        if r0 >= 0:
            k = slice(r0 + a, r0 + min(a + BLOCK_ROWS, len(cos_half)) + 1)
            qb, nb = q[k], norm[k]
            dot = np.einsum("ij,ij->i", qb[:-1], qb[1:]) / (nb[:-1] * nb[1:])
        else:
            qb = unit(rows[a : a + BLOCK_ROWS + 1])
            dot = np.einsum("ij,ij->i", qb[:-1], qb[1:])
        cos_half[a : a + BLOCK_ROWS] = np.abs(dot)
    i = np.flatnonzero(cos_half < np.cos(np.radians(0.9 * JUMP_DEG) / 2))
    if not len(i):
        return ()
    truth_deg = np.degrees(quat_angle_rad(unit(row(i)), unit(row(i + 1))))
    # the gyro's path length over each truth step bounds any rotation it can have made
    speed = row_norm(omega_b)[:, None]
    path = integrated_rate(t_ns, speed, np.stack([tt[i], tt[i + 1]], axis=1).ravel())
    gyro_deg = np.degrees(np.diff(path[:, 0].reshape(-1, 2), axis=1)[:, 0])
    jump = (truth_deg - gyro_deg > JUMP_DEG) & (truth_deg > JUMP_RATIO * gyro_deg)

    def te(k):  # s since the first gyro sample
        return float((tt[k] - t_ns[0]) * 1e-9)

    return tuple(
        TruthJump(te(k), te(k + 1), float(truth_deg[m]), float(gyro_deg[m]))
        for m, k in zip(np.flatnonzero(jump).tolist(), i[jump].tolist(), strict=True)
    )

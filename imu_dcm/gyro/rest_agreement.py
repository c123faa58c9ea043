"""Rests that disagree beyond their noise: the bias of every rest against its neighbours' (offline).

Each rest's bias is the mean of ``n = hi - lo`` samples with per-axis sample standard deviation
``s``: its noise is the standard error ``s / √n`` per axis (white noise; its own samples, no
constant of a sensor; ``s²`` at least the output's quantisation, step²/12). Two rests *disagree*
where, on some axis, their biases differ by more than ``z √(s_i²/n_i + s_j²/n_j)`` (``z`` =
``floor_spreads``, the spreads the rest rule allows its windows: 4).

A rest is an *outlier* when it disagrees with both of its neighbours in time (at the first or
the last rest: the two nearest on its one side) while those two agree with each other: a hover,
a slow steady turn or a drive the windows took for rest gives a bias off by its motion, where
the rests around it give the same one. An outlier is not used. A change that the neighbours
share (a bias that drifts with temperature, rests on two sides of a change) is no outlier: the
rests are all used, and the line says that they disagree. With two rests nothing tells which
is wrong, so both are used and the line says so.

Conventions: ``omega_b`` (N, 3) body rate in body axes, rad/s; segments as
:class:`imu_dcm.gyro.rest_rule.RestSegment`, in time order.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from imu_dcm.gyro.rest_rule import RestSegment
from imu_dcm.gyro.windows import min_steps, step_var

__all__ = ["Agreement", "rests_agree"]

#: The evidence the judgement rests on, named in its line and its JSON.
EVIDENCE = "the rests' own sample std and lengths"


@dataclass(frozen=True, slots=True)
class Agreement:
    """How the biases of a log's rests agree.

    Attributes
    ----------
    kept : the rests whose bias is used (all but the outliers), in time order.
    outliers : the rests not used, each with how many noises it lies from its neighbours.
    disagree : each pair of rests next to each other in time that disagree, as
        ``(i, j, ratio)``: indices into the rests given, and the largest per-axis difference
        over its noise.
    line : one line when any disagree ("" when all agree).
    """

    kept: tuple[RestSegment, ...]
    outliers: tuple[tuple[RestSegment, float], ...] = ()
    disagree: tuple[tuple[int, int, float], ...] = ()
    line: str = ""

    def as_dict(self, segs: list[RestSegment] | tuple[RestSegment, ...]) -> dict:
        """The judgement for a summary (``segs``: the rests it judged, for their times)."""
        return {
            "evidence": EVIDENCE,
            "outliers": [{**s.as_dict(), "noises": r} for s, r in self.outliers],
            "disagree": [
                {"first_s": _times(segs[i]), "second_s": _times(segs[j]), "noises": r}
                for i, j, r in self.disagree
            ],
            "line": self.line,
        }


def _times(s: RestSegment) -> list[float]:
    return [s.start_s, s.end_s]


def _noise(w: NDArray, s: RestSegment, quantum_var: float) -> NDArray:
    """Per-axis standard error of a rest's bias, rad/s: sample std / √n over ``[lo, hi)``, the
    variance at least the output's quantisation ``quantum_var`` (step²/12, as for the floor)."""
    x = w[s.lo : s.hi]
    if len(x) < 2:
        return np.full(3, np.inf)
    return np.sqrt(np.maximum(x.var(axis=0, ddof=1), quantum_var) / len(x))


def rests_agree(omega_b: NDArray, segs: list[RestSegment], spreads: float = 4.0) -> Agreement:
    """Judge the rests' biases against each other (the module docstring's rule).

    Parameters
    ----------
    omega_b : ndarray, shape (N, 3)
        The gyro's rates, rad/s, on the rows the segments index.
    segs : list of RestSegment
        The rests found, in time order.
    spreads : float
        ``z``: how many noises two biases may differ by on an axis.
    """
    n = len(segs)
    if n < 2:
        return Agreement(tuple(segs))
    w = np.asarray(omega_b, dtype=float)
    b = np.array([s.bias_rad_s for s in segs])
    quantum = step_var(min_steps(w))
    se = np.array([_noise(w, s, quantum) for s in segs])

    def ratio(i: int, j: int) -> float:
        with np.errstate(invalid="ignore", divide="ignore"):
            r = np.abs(b[i] - b[j]) / np.sqrt(se[i] ** 2 + se[j] ** 2)
        return float(np.nan_to_num(r, nan=0.0).max())

    disagree = tuple((i, i + 1, r) for i in range(n - 1) if (r := ratio(i, i + 1)) > spreads)
    outliers = []
    for i in range(n if n >= 3 else 0):
        j, k = (i - 1, i + 1) if 0 < i < n - 1 else ((1, 2) if i == 0 else (n - 2, n - 3))
        rj, rk = ratio(i, j), ratio(i, k)
        if rj > spreads and rk > spreads and ratio(j, k) <= spreads:
            outliers.append((i, min(rj, rk)))
    out_idx = {i for i, _r in outliers}
    kept = tuple(s for i, s in enumerate(segs) if i not in out_idx)
    return Agreement(
        kept,
        tuple((segs[i], r) for i, r in outliers),
        disagree,
        _line(segs, outliers, disagree, spreads),
    )


def _span(s: RestSegment) -> str:
    return f"{s.start_s:.2f}-{s.end_s:.2f} s"


def _line(segs, outliers, disagree, spreads: float) -> str:
    """One line: the outliers not used, or the rests that disagree and are all used."""
    if outliers:
        each = "; ".join(
            f"{_span(segs[i])} (bias {_deg(segs[i].bias_rad_s)} °/s, {r:.1f}x its noise from "
            "its two neighbours, which agree)"
            for i, r in outliers
        )
        n = len(outliers)
        return (
            f"biases disagree beyond their noise ({EVIDENCE}, z = {spreads:g}): {each}; "
            f"{'it is' if n == 1 else 'they are'} not used"
        )
    if not disagree:
        return ""
    i, j, r = max(disagree, key=lambda d: d[2])
    diff = np.degrees(np.abs(np.subtract(segs[i].bias_rad_s, segs[j].bias_rad_s))).max()
    more = f" (and {len(disagree) - 1} more pairs)" if len(disagree) > 1 else ""
    return (
        f"biases disagree beyond their noise ({EVIDENCE}, z = {spreads:g}): {_span(segs[i])} and "
        f"{_span(segs[j])} differ by {diff:.4f} °/s, {r:.1f}x their noise{more}; all used (a "
        "bias that changed between them, or one that is no rest: nothing here tells which)"
    )


def _deg(v) -> str:
    return "(" + ", ".join(f"{x:+.3f}" for x in np.degrees(v)) + ")"

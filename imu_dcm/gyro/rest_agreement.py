"""Rests that disagree beyond their noise: the bias of every rest against its neighbours'
(offline, :func:`rests_agree`; live, :class:`CausalAgreement`), by one pairwise rule
(:func:`apart`, :func:`agree`, :func:`outlier`).

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
is wrong, so both are used and the line says so. Live judges each rest as it closes, as the
last rest of the log so far (against the two before it).

Conventions: ``omega_b`` (N, 3) body rate in body axes, rad/s; segments as
:class:`imu_dcm.gyro.rest_rule.RestSegment`, in time order.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from imu_dcm.gyro.rest_rule import RestSegment
from imu_dcm.gyro.windows import min_steps, step_var

__all__ = [
    "Agreement",
    "CausalAgreement",
    "RestBias",
    "agree",
    "apart",
    "outlier",
    "rest_bias",
    "rests_agree",
    "standard_error",
]

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


class RestBias(NamedTuple):
    """A rest's bias and its noise, per axis, rad/s (what the pairwise rule compares)."""

    bias: NDArray
    se: NDArray


def standard_error(var: NDArray, n: int, quantum_var: float) -> NDArray:
    """Per-axis standard error of a mean of ``n`` samples of sample variance ``var``, rad/s: the
    variance at least the output's quantisation ``quantum_var`` (step²/12, as for the floor)."""
    if n < 2:
        return np.full(3, np.inf)
    return np.sqrt(np.maximum(var, quantum_var) / n)


def rest_bias(w: NDArray, s: RestSegment, quantum_var: float) -> RestBias:
    """A rest's bias and noise from its samples ``[lo, hi)`` of ``w``."""
    x = w[s.lo : s.hi]
    var = x.var(axis=0, ddof=1) if len(x) >= 2 else np.zeros(3)
    return RestBias(np.asarray(s.bias_rad_s, dtype=float), standard_error(var, len(x), quantum_var))


def apart(x: RestBias, y: RestBias) -> float:
    """How far two rests' biases lie apart: the largest per-axis difference over its noise
    ``√(se_x² + se_y²)``."""
    with np.errstate(invalid="ignore", divide="ignore"):
        r = np.abs(x.bias - y.bias) / np.sqrt(x.se**2 + y.se**2)
    return float(np.nan_to_num(r, nan=0.0).max())


def agree(x: RestBias, y: RestBias, spreads: float = 4.0) -> bool:
    """Do two rests agree: their biases within ``spreads`` noises on every axis."""
    return apart(x, y) <= spreads


def neighbours(i: int, n: int) -> tuple[int, int]:
    """The two rests rest ``i`` of ``n`` (n >= 3) is judged against: the one before and the one
    after; at the first or the last, the two nearest on its one side."""
    if 0 < i < n - 1:
        return i - 1, i + 1
    return (1, 2) if i == 0 else (n - 2, n - 3)


def outlier(x: RestBias, j: RestBias, k: RestBias, spreads: float = 4.0) -> float | None:
    """Rest ``x`` against its two neighbours ``j``, ``k``: how many noises it lies from the
    nearer when it disagrees with both while they agree with each other, else None."""
    rj, rk = apart(x, j), apart(x, k)
    if rj > spreads and rk > spreads and agree(j, k, spreads):
        return min(rj, rk)
    return None


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
    quantum = step_var(min_steps(w))
    rb = [rest_bias(w, s, quantum) for s in segs]
    disagree = tuple(
        (i, i + 1, r) for i in range(n - 1) if (r := apart(rb[i], rb[i + 1])) > spreads
    )
    outliers = []
    for i in range(n if n >= 3 else 0):
        j, k = neighbours(i, n)
        if (r := outlier(rb[i], rb[j], rb[k], spreads)) is not None:
            outliers.append((i, r))
    return judged(segs, outliers, disagree, spreads)


def judged(segs, outliers, disagree, spreads: float) -> Agreement:
    """The :class:`Agreement` of rests ``segs`` with ``outliers`` ``(index, noises)`` and the
    ``disagree`` pairs ``(i, j, noises)``."""
    out_idx = {i for i, _r in outliers}
    return Agreement(
        tuple(s for i, s in enumerate(segs) if i not in out_idx),
        tuple((segs[i], r) for i, r in outliers),
        tuple(disagree),
        _line(segs, outliers, disagree, spreads),
    )


class CausalAgreement:
    """The rule run causally (live): each rest as it closes, against the rests before it.

    A new rest is judged as the last rest of the log so far: against the two before it (all
    rests seen, used or not, as offline), it is not used when it disagrees with both while they
    agree with each other (:func:`outlier`). With fewer than two before it, it is used. A rest
    used is never judged again (live cannot take back a bias it applied).

    Attributes
    ----------
    rests : the rests judged, in time order; ``used`` : whether each is used.
    outliers, disagree : as :func:`rests_agree`'s (indices into ``rests``).
    """

    def __init__(self, spreads: float = 4.0) -> None:
        self.spreads = spreads
        self.rests: list[RestSegment] = []
        self.used: list[bool] = []
        self.outliers: list[tuple[int, float]] = []
        self.disagree: list[tuple[int, int, float]] = []
        self._rb: list[RestBias] = []

    def add(self, seg: RestSegment, var: NDArray, n: int, quantum_var: float) -> float | None:
        """Judge a rest that closed (``var``: per-axis sample variance of its ``n`` bias
        samples); return how many noises it lies from the two before it when it is not used,
        else None."""
        x = RestBias(np.asarray(seg.bias_rad_s, dtype=float), standard_error(var, n, quantum_var))
        i = len(self.rests)
        if i and (r := apart(self._rb[-1], x)) > self.spreads:
            self.disagree.append((i - 1, i, r))
        r = outlier(x, self._rb[-1], self._rb[-2], self.spreads) if i >= 2 else None
        if r is not None:
            self.outliers.append((i, r))
        self.rests.append(seg)
        self._rb.append(x)
        self.used.append(r is None)
        return r

    def result(self) -> Agreement:
        """The judgement so far, as :func:`rests_agree` gives it."""
        return judged(self.rests, self.outliers, self.disagree, self.spreads)


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

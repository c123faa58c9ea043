"""The truth's quaternion convention, judged by how its body-rate vectors fit the gyro's.

A truth may come in another convention than ``q_w_b`` ``[x, y, z, w]``, body to world:

* ``"conjugate"``: world to body (a sensor's own "earth to sensor" output). Its rate norms are
  those of ``q_w_b``, so a check of norms passes it; its body-rate vectors are the gyro's turned
  by the attitude itself, which no constant mounting fits.
* ``"w-first"``: the components were ``[w, x, y, z]`` read as ``[x, y, z, w]`` (a wxyz column
  order declared xyzw); ``"w-last"`` the reverse.

The fit is the share of the truth's body-frame rotation, over 10 ms steps, that the gyro's
explains through the best constant mounting (:func:`imu_dcm.replay.mounting.estimate_mounting`,
``fit``; 1 is perfect). When the truth as read fits less than a good mounting must
(:data:`imu_dcm.replay.mounting.MIN_FIT`), the others are tried. One that fits as a good
mounting must, leaving :data:`CLEAR_RATIO` times less unexplained than the truth as read, is
determined clearly: named and applied; a smaller gain is only named. The three others differ
from each other by constant rotations on the world and body sides (a component permutation
of a quaternion is a conjugation between constant ones), which rates cannot tell apart: among
those that fit as well, the one needing the smallest mounting is taken, and the line names the
others. ``truth_convention`` other than ``"auto"`` applies the one stated.

A world in NED rather than ENU turns every attitude by one constant rotation on the left: the
body rates, and so the fit, do not see it (the heading and inclination split does). Only a
log's gravity could tell, and that is not judged here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from imu_dcm.errors import InputError
from imu_dcm.replay.mounting import MIN_FIT, estimate_mounting
from imu_dcm.so3 import quat_conjugate

__all__ = [
    "CONVENTIONS",
    "CLEAR_RATIO",
    "ConventionChoice",
    "check_convention",
    "choose_convention",
    "convert",
]

#: What ``--truth-convention`` accepts ("auto": judged by the fit).
CONVENTIONS = ("auto", "as-is", "conjugate", "w-first", "w-last")
#: Another convention is clear when the share its fit leaves unexplained is this many times
#: smaller than the truth's as read (an order of magnitude).
CLEAR_RATIO = 10.0


@dataclass(frozen=True, slots=True)
class ConventionChoice:
    """The convention applied to the truth and why.

    Attributes
    ----------
    used : "as-is", "conjugate", "w-first" or "w-last".
    how : "given" (stated by the user), "fit" (determined by the fit) or "" (as read).
    fits : each convention tried and its fit (empty when none was tried).
    line : one line for the user ("" when there is nothing to say).
    """

    used: str = "as-is"
    how: str = ""
    fits: tuple[tuple[str, float], ...] = ()
    line: str = ""


def check_convention(convention: str) -> str:
    """``convention`` when it is one of :data:`CONVENTIONS`; InputError otherwise."""
    if convention not in CONVENTIONS:
        raise InputError(f"Expected a truth convention in {CONVENTIONS}, got {convention!r}")
    return convention


def convert(q_w_b: NDArray[np.float64], convention: str) -> NDArray[np.float64]:
    """The truth ``[x, y, z, w]`` body to world, from components in ``convention`` (M, 4)."""
    q = np.asarray(q_w_b, dtype=float)
    if convention == "as-is":
        return q
    if convention == "conjugate":
        return quat_conjugate(q)
    if convention == "w-first":  # [w, x, y, z] read as [x, y, z, w]
        return q[:, [1, 2, 3, 0]]
    if convention == "w-last":  # [x, y, z, w] read as [w, x, y, z]
        return q[:, [3, 0, 1, 2]]
    raise InputError(f"Expected a truth convention in {CONVENTIONS}, got {convention!r}")


def _fit(t_ns, omega_b, truth_t_ns, q) -> tuple[float, float]:
    """The fit and the angle (deg) of the best constant mounting; NaN when too little motion."""
    est = estimate_mounting(t_ns, omega_b, truth_t_ns, q)
    return (float(est.fit), float(est.angle_deg)) if est is not None else (np.nan, np.nan)


def choose_convention(
    t_ns: NDArray[np.int64],
    omega_b: NDArray[np.float64],
    truth_t_ns: NDArray[np.int64],
    q_w_b: NDArray[np.float64],
    given: str = "auto",
    topic: str = "truth",
) -> ConventionChoice:
    """The convention to read the truth in (see the module docstring).

    Parameters
    ----------
    t_ns, omega_b : int64 (N,), float64 (N, 3) — gyro stamps and rates (rad/s, gyro axes).
    truth_t_ns, q_w_b : int64 (M,), float64 (M, 4) — truth stamps (gyro's clock) and quaternions.
    given : one of :data:`CONVENTIONS`.
    topic : the truth's name, for the line.
    """
    if check_convention(given) != "auto":
        line = f"truth {topic}: read as {given}, as given" if given != "as-is" else ""
        return ConventionChoice(given, "given", (), line)
    as_is, _angle = _fit(t_ns, omega_b, truth_t_ns, q_w_b)
    if not as_is < MIN_FIT:  # a good fit, or too little motion to tell (NaN)
        return ConventionChoice()
    tried = {c: _fit(t_ns, omega_b, truth_t_ns, convert(q_w_b, c)) for c in CONVENTIONS[2:]}
    fits = (("as-is", as_is), *((c, f) for c, (f, _a) in tried.items()))
    best_fit = max((f for _c, f in fits[1:] if np.isfinite(f)), default=np.nan)
    if not best_fit >= MIN_FIT:
        return ConventionChoice("as-is", "", fits, "")
    # the rates cannot tell conventions that differ by constant rotations on either side (the
    # conjugate and the two reorders): among those that fit as well, the one that needs the
    # smallest mounting
    equal = [c for c, (f, _a) in tried.items() if f >= best_fit - (1.0 - best_fit)]
    best = min(equal, key=lambda c: tried[c][1])
    shown = ", ".join(f"{c} {f:.3f}" for c, f in fits if np.isfinite(f))
    same = (
        f"; {', '.join(c for c in equal if c != best)} fit as well with a larger mounting"
        if len(equal) > 1
        else ""
    )
    if (1.0 - best_fit) * CLEAR_RATIO <= 1.0 - as_is:
        line = (
            f"truth {topic}: its body rates fit the gyro read as {best} (fits: {shown}{same}): "
            f"applied (--truth-convention as-is keeps it as read)"
        )
        return ConventionChoice(best, "fit", fits, line)
    line = (
        f"truth {topic}: its body rates fit the gyro better read as {best} (fits: {shown}"
        f"{same}): not applied (--truth-convention {best} applies it)"
    )
    return ConventionChoice("as-is", "", fits, line)

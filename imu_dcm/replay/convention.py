"""The truth's quaternion convention, judged by how its body-rate vectors fit the gyro's.

A truth may come in another convention than ``q_w_b`` ``[x, y, z, w]``, body to world:

* ``"conjugate"``: world to body (a sensor's own "earth to sensor" output). Its rate norms are
  those of ``q_w_b``, so a check of norms passes it; its body-rate vectors are the gyro's turned
  by the attitude itself, which no constant mounting fits.
* ``"w-first"``: the components were ``[w, x, y, z]`` read as ``[x, y, z, w]`` (a wxyz column
  order declared xyzw); ``"w-last"`` the reverse.
* ``"ned"``: body to a NED world (north, east, down) rather than our ENU: ``q_enu_b =
  q_enu_ned ⊗ q_ned_b``, ``q_enu_ned`` the half turn about ``(1, 1, 0)/√2`` (x and y swap, z
  flips).

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
body rates, and so the fit, do not see it. The log's gravity does: where the IMU has an
accelerometer and the truth as read fits, its specific force, turned through the mounting and
the truth into the truth's world and averaged over the log, is the reaction to gravity, up
(a body that ends where it started has no mean acceleration). Where that mean lies within
:data:`GRAVITY_ERROR_M_S2` (0.05 g, the scale and bias error of MEMS accelerometers, as the
rest rule's) of ``(0, 0, -g)``, the world is NED: named and applied (the scores do not change:
the error of a constant rotation on the world side is the same; the estimate and truth are
then in ENU).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from imu_dcm.arrays import row_finite
from imu_dcm.errors import InputError
from imu_dcm.gyro.rest_rule import GRAVITY_M_S2, RestConfig
from imu_dcm.replay.mounting import MIN_FIT, estimate_mounting
from imu_dcm.so3 import quat_as_matrix, quat_conjugate, quat_multiply, quat_rotate

__all__ = [
    "CONVENTIONS",
    "CLEAR_RATIO",
    "GRAVITY_ERROR_M_S2",
    "Q_ENU_NED",
    "ConventionChoice",
    "check_convention",
    "choose_convention",
    "convert",
]

#: What ``--truth-convention`` accepts ("auto": judged by the fit).
CONVENTIONS = ("auto", "as-is", "conjugate", "w-first", "w-last", "ned")
#: the conventions the body rates can tell from the truth as read (a NED world they cannot)
RATE_CONVENTIONS = ("conjugate", "w-first", "w-last")
#: Another convention is clear when the share its fit leaves unexplained is this many times
#: smaller than the truth's as read (an order of magnitude).
CLEAR_RATIO = 10.0
#: How far the accelerometer's mean specific force may lie from g (m/s²): the rest rule's bound,
#: 0.05 g, the scale and bias error of MEMS accelerometers.
GRAVITY_ERROR_M_S2 = RestConfig().max_gravity_error_m_s2
#: ENU from NED, ``[x, y, z, w]``: the half turn about (1, 1, 0)/√2 (x and y swap, z flips).
Q_ENU_NED = np.array([np.sqrt(0.5), np.sqrt(0.5), 0.0, 0.0])


@dataclass(frozen=True, slots=True)
class ConventionChoice:
    """The convention applied to the truth and why.

    Attributes
    ----------
    used : "as-is", "conjugate", "w-first", "w-last" or "ned".
    how : "given" (stated by the user), "fit" (determined by the fit or, for "ned", by the
        gravity) or "" (as read).
    fits : each convention tried and its fit (empty when none was tried).
    line : one line for the user ("" when there is nothing to say).
    gravity_w_m_s2 : the accelerometer's mean specific force in the truth's world as read,
        m/s², where it found the world NED (None otherwise).
    """

    used: str = "as-is"
    how: str = ""
    fits: tuple[tuple[str, float], ...] = ()
    line: str = ""
    gravity_w_m_s2: tuple[float, float, float] | None = None

    def as_dict(self) -> dict:
        """The choice for the summary JSON."""
        out = {"used": self.used, "how": self.how, "fits": [list(f) for f in self.fits]}
        out["line"] = self.line
        if self.gravity_w_m_s2 is not None:  # the evidence of a NED world
            out["gravity_w_m_s2"] = list(self.gravity_w_m_s2)
        return out


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
    if convention == "ned":  # body to NED: q_enu_b = q_enu_ned q_ned_b
        return quat_multiply(Q_ENU_NED, q)
    raise InputError(f"Expected a truth convention in {CONVENTIONS}, got {convention!r}")


def _fit(t_ns, omega_b, truth_t_ns, q) -> tuple[float, float]:
    """The fit and the angle (deg) of the best constant mounting; NaN when too little motion."""
    est = estimate_mounting(t_ns, omega_b, truth_t_ns, q)
    return (float(est.fit), float(est.angle_deg)) if est is not None else (np.nan, np.nan)


def gravity_in_world(t_ns, accel_b, truth_t_ns, q_w_b, q_t_g=None) -> NDArray | None:
    """The accelerometer's mean specific force in the truth's world, m/s² (3,), or None.

    Each accelerometer row (gyro axes, m/s²) is turned through the mounting ``q_t_g`` (gyro to
    truth body; identity when None) and the truth sample nearest in time into the truth's
    world; rows outside the truth's span, or without a finite truth, count for nothing.
    """
    if accel_b is None or len(truth_t_ns) < 2:
        return None
    inside = (t_ns >= truth_t_ns[0]) & (t_ns <= truth_t_ns[-1]) & row_finite(accel_b)
    if not inside.any():
        return None
    k = np.clip(np.searchsorted(truth_t_ns, t_ns[inside]), 1, len(truth_t_ns) - 1)
    k -= (t_ns[inside] - truth_t_ns[k - 1]) < (truth_t_ns[k] - t_ns[inside])
    q = q_w_b[k]
    ok = row_finite(q)
    if not ok.any():
        return None
    f_t = accel_b[inside][ok] @ (np.eye(3) if q_t_g is None else quat_as_matrix(q_t_g)).T
    return quat_rotate(q[ok], f_t).mean(axis=0)


def _world(t_ns, truth_t_ns, q_w_b, accel_b, q_t_g, topic: str) -> ConventionChoice:
    """The truth as read fits the rates: is its world NED (see the module docstring)?"""
    f = gravity_in_world(t_ns, accel_b, truth_t_ns, q_w_b, q_t_g)
    if f is None or np.linalg.norm(f - [0.0, 0.0, -GRAVITY_M_S2]) > GRAVITY_ERROR_M_S2:
        return ConventionChoice()
    line = (
        f"truth {topic}: its world is NED, not ENU: the accelerometer's mean specific force in "
        f"it is ({f[0]:+.2f}, {f[1]:+.2f}, {f[2]:+.2f}) m/s², gravity's reaction pointing down "
        f"(within {GRAVITY_ERROR_M_S2:g} m/s² of g): applied (--truth-convention as-is keeps "
        "it as read)"
    )
    return ConventionChoice("ned", "fit", (), line, tuple(float(x) for x in f))


def choose_convention(
    t_ns: NDArray[np.int64],
    omega_b: NDArray[np.float64],
    truth_t_ns: NDArray[np.int64],
    q_w_b: NDArray[np.float64],
    given: str = "auto",
    topic: str = "truth",
    accel_b: NDArray[np.float64] | None = None,
) -> ConventionChoice:
    """The convention to read the truth in (see the module docstring).

    Parameters
    ----------
    t_ns, omega_b : int64 (N,), float64 (N, 3) — gyro stamps and rates (rad/s, gyro axes).
    truth_t_ns, q_w_b : int64 (M,), float64 (M, 4) — truth stamps (gyro's clock) and quaternions.
    given : one of :data:`CONVENTIONS`.
    topic : the truth's name, for the line.
    accel_b : float64 (N, 3), optional — the accelerometer on the gyro's rows, m/s² (judges a
        NED world).
    """
    if check_convention(given) != "auto":
        line = f"truth {topic}: read as {given}, as given" if given != "as-is" else ""
        return ConventionChoice(given, "given", (), line)
    mount = estimate_mounting(t_ns, omega_b, truth_t_ns, q_w_b)
    if mount is None:  # too little motion to tell
        return ConventionChoice()
    as_is = float(mount.fit)
    if as_is >= MIN_FIT:  # the rates fit as read: the world's vertical, by the gravity
        return _world(t_ns, truth_t_ns, q_w_b, accel_b, mount.q_t_g, topic)
    tried = {c: _fit(t_ns, omega_b, truth_t_ns, convert(q_w_b, c)) for c in RATE_CONVENTIONS}
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

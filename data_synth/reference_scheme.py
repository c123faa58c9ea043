"""The heavy-top simulator of Xiaoliang (2014), as it describes it, and its comparison.

The heavy-top derivation of Xiaoliang (2014) (its program ``RGCoordTrans``; docs/design.md,
"Source derivations") simulates the top with a *coupled* fixed-step scheme, its "five lines"
(eq. 19):

1. ``τ_b`` = gravity torque in body axes from the tracked DCM ``R_i`` (``Tau_body_temp``),
2. ``ω_{i+1}`` = one classical RK4 step of Euler's equations (its eq. 17) from ``ω_i`` with that
   torque held fixed over the step (``topRK(w[i-1], Tau_body_temp)``),
3. ``R_{i+1} = R_i · CK(ω_{i+1} h)`` (the DCM is updated with the rate at the *end* of the step),

starting from ``R_0 = Rx(tilt)``, ``h = 1 / samplerate``. It checks itself against an Euler-angle
solution (Hasbun's, "absolutely correct while it does not diverge"): the angle between the two
symmetry axes stays below 0.1° over 1.2 s under its Figure 11 conditions (M = 1, arm = 0.04,
I = 0.002, I_s = 0.0008, g = 9.8, 20 Hz spin, 54.57° tilt; sampling 2500 Hz in the caption,
``samplerate = 2000`` in the listed code).

:func:`compare_reference` reproduces that comparison with an independent Euler-angle solution
(z-x-z angles, first integrals ``L_z`` and ``ω3``, DOP853 at 1e-12) and also measures the scheme
against the exact truth (:func:`data_synth.scenes.heavy_top`), in symmetry axis and in full
attitude. Run ``python -m data_synth.reference_scheme`` to print both.

Conventions: ``R_w_b`` maps body to world (columns = body axes in world, Xiaoliang's
``cordvec``); ``omega_b`` body rate in body axes, rad/s; world z up.
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.integrate import solve_ivp
from scipy.spatial.transform import Rotation

from data_synth.rigid_body import Trajectory
from data_synth.scenes import (
    HeavyTopParams,
    heavy_top,
    heavy_top_initial_rates,
    heavy_top_initial_state,
)
from imu_dcm.errors import InputError
from imu_dcm.so3 import exp_matrix, quat_angle_rad

__all__ = [
    "ReferenceComparison",
    "ReferenceRun",
    "SampledTrajectory",
    "compare_reference",
    "euler_angle_top",
    "reference_top",
]


@dataclass(frozen=True)
class ReferenceRun:
    """Output of the coupled scheme of Xiaoliang (2014).

    Attributes
    ----------
    t_s : ndarray, shape (N+1,)
        ``i h``, s.
    R_w_b : ndarray, shape (N+1, 3, 3)
        Tracked DCM (``TrackMat``), body to world.
    omega_b : ndarray, shape (N+1, 3)
        RK4 body rates, rad/s.
    params : dict
        The top's parameters and initial state (as ``heavy_top(...).params``) and the scheme.
    """

    t_s: NDArray[np.float64]
    R_w_b: NDArray[np.float64]
    omega_b: NDArray[np.float64]
    params: dict


def reference_top(
    duration_s: float,
    rate_hz: float,
    motion: str = "cusp",
    *,
    branch: str = "slow",
    params: HeavyTopParams | None = None,
    tilt_deg: float | None = None,
    spin_hz: float | None = None,
) -> ReferenceRun:
    """Run the coupled RK4 + DCM scheme of Xiaoliang (2014) for the heavy top.

    Parameters
    ----------
    duration_s : float
        Length, s (``N = round(duration_s · rate_hz)`` steps).
    rate_hz : float
        ``samplerate``, Hz; ``h = 1 / rate_hz``.
    motion, branch, params, tilt_deg, spin_hz
        As :func:`data_synth.scenes.heavy_top` (same initial state).

    Returns
    -------
    ReferenceRun
    """
    p, q0, omega0, record = heavy_top_initial_state(
        motion, branch=branch, params=params, tilt_deg=tilt_deg, spin_hz=spin_hz
    )
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise InputError(f"Expected `rate_hz` > 0, got {rate_hz!r}")
    if not (math.isfinite(duration_s) and duration_s > 0):
        raise InputError(f"Expected `duration_s` > 0, got {duration_s!r}")
    n = round(duration_s * rate_hz)
    if n < 1:
        raise InputError(f"Expected at least one step, got {duration_s} s at {rate_hz} Hz")
    h = 1.0 / rate_hz
    i1 = i2 = p.i1_kg_m2
    i3 = p.i3_kg_m2
    k1, k2, k3 = (i2 - i3) / i1, (i3 - i1) / i2, (i1 - i2) / i3
    mg, arm = p.mass_kg * p.g_m_s2, p.arm_m

    def f(w1: float, w2: float, w3: float, t1: float, t2: float, t3: float):
        # Euler's equations (Xiaoliang 2014, eq. 17) with a fixed body torque.
        return k1 * w2 * w3 + t1 / i1, k2 * w3 * w1 + t2 / i2, k3 * w1 * w2 + t3 / i3

    R = np.empty((n + 1, 3, 3))
    W = np.empty((n + 1, 3))
    R[0] = Rotation.from_quat(q0).as_matrix()  # Rx(tilt), Xiaoliang's CK(Ω0)
    W[0] = omega0
    w1, w2, w3 = W[0]
    track = R[0].copy()
    for i in range(1, n + 1):
        # Torque about the pivot in body axes from the tracked DCM: r_cm × (Rᵀ (0, 0, −M g)).
        gx, gy = -mg * track[2, 0], -mg * track[2, 1]
        t1, t2, t3 = -arm * gy, arm * gx, 0.0
        a = f(w1, w2, w3, t1, t2, t3)
        b = f(w1 + 0.5 * h * a[0], w2 + 0.5 * h * a[1], w3 + 0.5 * h * a[2], t1, t2, t3)
        cc = f(w1 + 0.5 * h * b[0], w2 + 0.5 * h * b[1], w3 + 0.5 * h * b[2], t1, t2, t3)
        d = f(w1 + h * cc[0], w2 + h * cc[1], w3 + h * cc[2], t1, t2, t3)
        w1 += h / 6.0 * (a[0] + 2.0 * b[0] + 2.0 * cc[0] + d[0])
        w2 += h / 6.0 * (a[1] + 2.0 * b[1] + 2.0 * cc[1] + d[1])
        w3 += h / 6.0 * (a[2] + 2.0 * b[2] + 2.0 * cc[2] + d[2])
        track = track @ exp_matrix((w1 * h, w2 * h, w3 * h))  # CK(ω(t_{i+1}) h), eq. 19
        R[i] = track
        W[i] = (w1, w2, w3)
    return ReferenceRun(
        np.arange(n + 1) * h,
        R,
        W,
        {**record, "scheme": "reference", "scheme_rate_hz": float(rate_hz)},
    )


def euler_angle_top(
    t_s: ArrayLike,
    motion: str = "cusp",
    *,
    branch: str = "slow",
    params: HeavyTopParams | None = None,
) -> NDArray[np.float64]:
    """Symmetry axis of the heavy top from its Euler-angle equations (Xiaoliang's check).

    z-x-z angles, ``R_w_b = Rz(φ) Rx(θ) Rz(ψ)``; with the first integrals ``ω3`` and
    ``L_z = I1 φ̇ sin²θ + I3 ω3 cos θ``: ``φ̇ = (L_z − I3 ω3 cos θ)/(I1 sin²θ)``,
    ``I1 θ̈ = I1 φ̇² sin θ cos θ − I3 ω3 φ̇ sin θ + M g l sin θ``. Solved by DOP853 at 1e-12;
    singular when ``sin θ = 0`` (the divergence Xiaoliang (2014) mentions).

    Returns
    -------
    ndarray, shape (N, 3)
        Body z axis in world, ``(sin φ sin θ, −cos φ sin θ, cos θ)``.
    """
    p = params or HeavyTopParams()
    p.validate()
    precession0, tilt = heavy_top_initial_rates(p, motion, branch)
    if math.sin(tilt) == 0.0:
        raise InputError("Expected a tilted top for the Euler-angle solution, got tilt 0")
    i1, i3, mgl, w3 = p.i1_kg_m2, p.i3_kg_m2, p.mgl_n_m, p.omega3_rad_s
    lz = i1 * precession0 * math.sin(tilt) ** 2 + i3 * w3 * math.cos(tilt)

    def rhs(t: float, y: NDArray) -> list[float]:
        th, thd, _ = y.tolist()
        st, ct = math.sin(th), math.cos(th)
        phid = (lz - i3 * w3 * ct) / (i1 * st * st)
        thdd = (i1 * phid * phid * st * ct - i3 * w3 * phid * st + mgl * st) / i1
        return [thd, thdd, phid]

    t = np.asarray(t_s, dtype=float)
    sol = solve_ivp(
        rhs,
        (0.0, float(t.max())),
        [tilt, 0.0, 0.0],
        method="DOP853",
        rtol=1e-12,
        atol=1e-12,
        t_eval=t,
    )
    th, ph = sol.y[0], sol.y[2]
    return np.stack([np.sin(ph) * np.sin(th), -np.cos(ph) * np.sin(th), np.cos(th)], axis=-1)


@dataclass(frozen=True)
class ReferenceComparison:
    """The reference scheme's two figures of merit (max over the run), degrees.

    Attributes
    ----------
    rate_hz, duration_s : float
        Step rate and length.
    axis_vs_euler_deg : float
        Angle between the scheme's symmetry axis and the Euler-angle solution's (the
        document's own check, reported < 0.1°).
    axis_vs_truth_deg : float
        The same against the exact truth (DOP853 1e-12 on the coupled quaternion ODE).
    attitude_vs_truth_deg : float
        Full attitude error against the exact truth (includes the spin phase about the axis).
    euler_vs_truth_axis_deg : float
        Euler-angle solution against the exact truth (two independent exact solutions agree).
    strapdown_axis_deg, strapdown_attitude_deg : float
        Pure strapdown with Xiaoliang's update ``R_{i+1} = R_i CK(ω(t_{i+1}) h)`` fed the
        exact rates ``ω(t_i)`` (what a gyro would give it), against the exact truth: symmetry
        axis and full attitude.
    """

    rate_hz: float
    duration_s: float
    axis_vs_euler_deg: float
    axis_vs_truth_deg: float
    attitude_vs_truth_deg: float
    euler_vs_truth_axis_deg: float
    strapdown_axis_deg: float
    strapdown_attitude_deg: float


def _axis_angle_deg(a: NDArray, b: NDArray) -> NDArray:
    """Angle between unit vectors, deg (atan2 form, accurate for small angles)."""
    return np.degrees(
        np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.einsum("...i,...i->...", a, b))
    )


def compare_reference(
    rate_hz: float = 2500.0, duration_s: float = 1.2, motion: str = "cusp"
) -> ReferenceComparison:
    """Reproduce Xiaoliang's (2014) comparison and measure the scheme against the exact truth."""
    run = reference_top(duration_s, rate_hz, motion)
    axis_ref = run.R_w_b[:, :, 2]
    axis_euler = euler_angle_top(run.t_s, motion)
    truth = heavy_top(duration_s, motion)
    q_true, w_true = truth.at(run.t_s)
    R_true = Rotation.from_quat(q_true).as_matrix()
    axis_true = R_true[:, :, 2]
    q_ref = Rotation.from_matrix(run.R_w_b).as_quat()
    # The five lines as a strapdown integrator on exact samples: R_{i+1} = R_i CK(ω_{i+1} h).
    ck = exp_matrix(w_true[1:] * np.diff(run.t_s)[:, None])
    R_sd = np.empty_like(R_true)
    R_sd[0] = R_true[0]
    for i in range(len(ck)):
        R_sd[i + 1] = R_sd[i] @ ck[i]
    q_sd = Rotation.from_matrix(R_sd).as_quat()
    return ReferenceComparison(
        rate_hz=float(rate_hz),
        duration_s=float(duration_s),
        axis_vs_euler_deg=float(_axis_angle_deg(axis_ref, axis_euler).max()),
        axis_vs_truth_deg=float(_axis_angle_deg(axis_ref, axis_true).max()),
        attitude_vs_truth_deg=float(np.degrees(quat_angle_rad(q_ref, q_true)).max()),
        euler_vs_truth_axis_deg=float(_axis_angle_deg(axis_euler, axis_true).max()),
        strapdown_axis_deg=float(_axis_angle_deg(R_sd[:, :, 2], axis_true).max()),
        strapdown_attitude_deg=float(np.degrees(quat_angle_rad(q_sd, q_true)).max()),
    )


class SampledTrajectory(Trajectory):
    """A trajectory known only at grid times ``k / rate_hz`` (the reference scheme's output).

    ``at`` accepts only times on the grid (to 1 ns); ``delta_angles`` is not available (the
    scheme has no dense solution).
    """

    def __init__(
        self,
        run: ReferenceRun,
        rate_hz: float,
        scene: str = "heavy-top",
        params: dict | None = None,
    ) -> None:
        self._run = run
        self._q = Rotation.from_matrix(run.R_w_b).as_quat()
        self.rate_hz = float(rate_hz)
        self.duration_s = float(run.t_s[-1])
        self.scene = scene
        self.params = dict(run.params if params is None else params)

    def at(self, t_s: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        t = self._check_times(t_s)
        k = np.round(t * self.rate_hz).astype(np.int64)
        off = np.abs(k / self.rate_hz - t)
        if np.any(off > 1e-9):
            i = int(np.argmax(off))
            raise InputError(
                f"Expected times on the {self.rate_hz} Hz grid of the reference "
                f"scheme, got t_s[{i}] = {float(t[i])!r}"
            )
        return self._q[k].copy(), self._run.omega_b[k].copy()

    def delta_angles(self, t_s: ArrayLike) -> NDArray[np.float64]:
        raise InputError(
            "Expected the exact scheme for delta angles, got the reference scheme "
            "(it has no dense solution)"
        )


def main(argv: list[str] | None = None) -> int:
    """Print the comparison numbers: ``python -m data_synth.reference_scheme``."""
    ap = argparse.ArgumentParser(
        prog="python -m data_synth.reference_scheme", description=__doc__.splitlines()[0]
    )
    ap.add_argument(
        "--rate",
        type=float,
        nargs="+",
        default=[2500.0, 2000.0],
        help="step rates, Hz (default: 2500 = its Figure 11, 2000 = its listed code)",
    )
    ap.add_argument("--duration", type=float, default=1.2, help="length, s (default 1.2)")
    args = ap.parse_args(argv)
    print("heavy top, cusp, Xiaoliang (2014) Figure 11 parameters; max over the run, degrees")
    print(
        "coupled scheme (RK4 + CK(w(t_i+1) h)):  axis vs Euler-angle | axis vs exact | "
        "attitude vs exact"
    )
    print("strapdown on exact samples (same CK):    axis vs exact | attitude vs exact")
    print("Euler-angle solution vs exact:           axis")
    for r in args.rate:
        c = compare_reference(r, args.duration)
        print(
            f"{c.rate_hz:6.0f} Hz  coupled {c.axis_vs_euler_deg:.4f} | "
            f"{c.axis_vs_truth_deg:.4f} | {c.attitude_vs_truth_deg:.4f}   "
            f"strapdown {c.strapdown_axis_deg:.4f} | {c.strapdown_attitude_deg:.4f}   "
            f"Euler-angle {c.euler_vs_truth_axis_deg:.1e}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())

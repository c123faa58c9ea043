"""Measure how exact the ground truth is: ``python -m data_synth.checks [--duration S]``.

Prints, for each scene, the largest relative drift of the conserved quantities, the largest
attitude change when the ODE is re-solved at 10x tighter tolerance, and the largest distance to
the independent closed-form solutions (:mod:`data_synth.analytic`). The tests assert bounds on
the same quantities; this prints the measured values.

Conventions as everywhere: ``q_w_b`` ``[x, y, z, w]`` body to world, ``omega_b`` rad/s in body
axes, world z up.
"""

from __future__ import annotations

import argparse
import math
import sys

import numpy as np
from scipy.spatial.transform import Rotation

from data_synth.analytic import (
    box_attitude_elliptic,
    box_omega_elliptic,
    heavy_top_cos_theta,
    heavy_top_invariants,
)
from data_synth.scenes import HeavyTopParams, free_body, heavy_top, heavy_top_initial_rates
from imu_dcm.so3 import quat_angle_rad

__all__ = ["free_body_checks", "heavy_top_checks", "main"]


def heavy_top_checks(motion: str, duration_s: float, n: int = 20001) -> dict[str, float]:
    """Conservation, re-solve and elliptic cos θ figures of one heavy-top motion."""
    p = HeavyTopParams()
    inertia = np.array([p.i1_kg_m2, p.i1_kg_m2, p.i3_kg_m2])
    t = np.linspace(0.0, duration_s, n)
    traj = heavy_top(duration_s, motion)
    q, w = traj.at(t)
    R = Rotation.from_quat(q).as_matrix()
    energy = 0.5 * np.sum(inertia * w * w, axis=1) + p.mgl_n_m * R[:, 2, 2]
    lz = np.einsum("nij,nj->ni", R, inertia * w)[:, 2]
    out = {
        "energy": float(np.ptp(energy) / abs(energy[0])),
        "L_z/|L|": float(np.ptp(lz) / np.linalg.norm(inertia * w[0])),
        "L_3": float(np.ptp(w[:, 2]) / abs(w[0, 2])),
    }
    q13, _ = heavy_top(duration_s, motion, rtol=1e-13, atol=1e-13).at(t)
    out["resolve_deg"] = float(np.degrees(quat_angle_rad(q, q13)).max())
    if motion in ("cusp", "wavy", "looping"):
        precession0, tilt = heavy_top_initial_rates(p, motion)
        inv = heavy_top_invariants(
            p.i1_kg_m2, p.i3_kg_m2, p.mgl_n_m, tilt, p.omega3_rad_s, precession0
        )
        out["cos_theta_vs_elliptic"] = float(np.abs(R[:, 2, 2] - heavy_top_cos_theta(t, inv)).max())
    if motion == "steady":
        out["cos_theta_vs_steady"] = float(
            np.abs(R[:, 2, 2] - math.cos(math.radians(p.tilt_deg))).max()
        )
    return out


def free_body_checks(case: str, duration_s: float, n: int = 20001) -> dict[str, float]:
    """Conservation, re-solve and elliptic figures of the free box."""
    t = np.linspace(0.0, duration_s, n)
    traj = free_body(duration_s, case)
    q, w = traj.at(t)
    inertia = traj.inertia_kg_m2
    energy = 0.5 * np.sum(inertia * w * w, axis=1)
    l_w = np.einsum("nij,nj->ni", Rotation.from_quat(q).as_matrix(), inertia * w)
    w0 = traj.params["omega0_b_rad_s"]
    q13, _ = free_body(duration_s, case, rtol=1e-13, atol=1e-13).at(t)
    return {
        "energy": float(np.ptp(energy) / energy[0]),
        "L_world/|L|": float(np.abs(l_w - l_w[0]).max() / np.linalg.norm(l_w[0])),
        "resolve_deg": float(np.degrees(quat_angle_rad(q, q13)).max()),
        "omega_vs_jacobi_rad_s": float(np.abs(w - box_omega_elliptic(t, inertia, w0)).max()),
        "attitude_vs_elliptic_deg": float(
            np.degrees(
                quat_angle_rad(q, box_attitude_elliptic(t, inertia, w0, [0.0, 0.0, 0.0, 1.0]))
            ).max()
        ),
    }


def main(argv: list[str] | None = None) -> int:
    """Print the figures (max over the run) for every heavy-top motion and both boxes."""
    ap = argparse.ArgumentParser(
        prog="python -m data_synth.checks", description=__doc__.splitlines()[0]
    )
    ap.add_argument("--duration", type=float, default=10.0, help="length, s (default 10)")
    args = ap.parse_args(argv)
    print(f"max over {args.duration:g} s (20001 instants); drifts relative; angles in degrees")
    for motion in ("cusp", "wavy", "looping", "steady", "sleeping"):
        figs = heavy_top_checks(motion, args.duration)
        print(f"heavy-top {motion:9s} " + "  ".join(f"{k} {v:.1e}" for k, v in figs.items()))
    for case in ("diagonal", "intermediate"):
        figs = free_body_checks(case, args.duration)
        print(f"free-body {case:12s} " + "  ".join(f"{k} {v:.1e}" for k, v in figs.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())

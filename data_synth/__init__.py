"""data_synth: rigid-body ground truth (Euler's equations), a synthetic gyro and a ROS 2 log writer.

Conventions (docs/design.md): ``q_w_b`` Hamilton ``[x, y, z, w]`` (scalar last), body to world;
``omega_b`` the body rate relative to the world in body axes, rad/s; ``t_s`` seconds; world ENU,
z up, gravity ``(0, 0, −g)``.

>>> import data_synth
>>> traj = data_synth.simulate("heavy-top", duration_s=1.2, motion="cusp")
>>> q_w_b, omega_b = traj.at([0.0, 0.6, 1.2])      # (3, 4) xyzw, (3, 3) rad/s body
>>> dtheta_b = traj.delta_angles([0.0, 0.6, 1.2])   # (2, 3) exact ∫ omega_b dt, rad

Modules: ``rigid_body`` (Euler's equations + attitude, DOP853 1e-12, dense), ``scenes`` (heavy
top, free box, coning), ``analytic`` (closed forms used as independent checks), ``gyro`` (the
synthetic gyro), ``reference_scheme`` (the coupled RK4 + DCM top of Xiaoliang (2014) and its
comparison), ``checks`` (measured exactness of the truth), ``cli`` (``python -m data_synth``).
"""

from data_synth.gyro import GyroModel, GyroRecord, synthetic_gyro
from data_synth.rigid_body import SolvedTrajectory, Trajectory, solve_rigid_body
from data_synth.scenes import (
    BRANCHES,
    FREE_BODY_CASES,
    MOTIONS,
    SCENES,
    HeavyTopParams,
    coning,
    free_body,
    heavy_top,
    simulate,
)

__all__ = [
    "BRANCHES",
    "FREE_BODY_CASES",
    "MOTIONS",
    "SCENES",
    "GyroModel",
    "GyroRecord",
    "HeavyTopParams",
    "SolvedTrajectory",
    "Trajectory",
    "coning",
    "free_body",
    "heavy_top",
    "simulate",
    "solve_rigid_body",
    "synthetic_gyro",
]

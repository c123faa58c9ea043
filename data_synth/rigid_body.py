"""Rigid-body ground truth: Euler's equations coupled with the attitude, solved to 1e-12.

Conventions (docs/design.md): ``q_w_b`` is the Hamilton quaternion ``[x, y, z, w]`` (scalar last)
that maps body coordinates to world (active), so ``R_w_b`` has the body axes as its columns;
``omega_b`` is the angular velocity of the body relative to the world in body axes, rad/s;
time ``t_s`` in seconds from the start of the trajectory.

The state ``y = (q_w_b, omega_b, theta_b)`` obeys

* ``dq/dt = ½ q ⊗ [omega_b, 0]`` (increments on the right, ``dR/dt = R [omega_b×]``),
* ``I domega/dt = tau_b − omega_b × (I omega_b)`` (Euler's equations, principal body axes),
* ``dtheta/dt = omega_b`` (the running integral of the rate, for exact delta angles),

integrated by scipy ``solve_ivp`` DOP853 with ``rtol = atol = 1e-12`` and dense output, so the
truth can be sampled at any time. The quaternion is renormalised only on output.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.integrate import solve_ivp

from imu_dcm.errors import InputError
from imu_dcm.so3 import quat_normalize

__all__ = ["DEFAULT_TOL", "SolvedTrajectory", "TorqueFn", "Trajectory", "solve_rigid_body"]

DEFAULT_TOL = 1e-12

#: Torque on the body about its reference point, in body axes (N·m), as a function of time (s),
#: the (possibly unnormalised) ``q_w_b`` and ``omega_b``. Plain floats in and out (speed).
TorqueFn = Callable[[float, tuple, tuple], tuple]


class Trajectory:
    """A rigid-body motion that can be sampled at any time in ``[0, duration_s]``.

    Attributes
    ----------
    scene : str
        Scene name, as the CLI's sub-command (``"heavy-top"``, ``"free-body"``, ``"coning"``).
    params : dict
        Every parameter that defines the motion (for log metadata); JSON-serialisable values.
    duration_s : float
        Length of the trajectory, s.
    """

    scene: str
    params: dict[str, Any]
    duration_s: float

    def at(self, t_s: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """True attitude and rate at the times ``t_s``.

        Parameters
        ----------
        t_s : array_like, shape (N,)
            Times, s, within ``[0, duration_s]`` (any order).

        Returns
        -------
        q_w_b : ndarray, shape (N, 4)
            Unit quaternions ``[x, y, z, w]``, body to world.
        omega_b : ndarray, shape (N, 3)
            Body rate relative to the world in body axes, rad/s.
        """
        raise NotImplementedError

    def delta_angles(self, t_s: ArrayLike) -> NDArray[np.float64]:
        """Exact integral of ``omega_b`` over each interval ``[t_s[k], t_s[k+1]]``.

        Parameters
        ----------
        t_s : array_like, shape (N,)
            Increasing times, s, within ``[0, duration_s]``.

        Returns
        -------
        ndarray, shape (N-1, 3)
            ``∫ omega_b dt`` over each interval, rad, body axes (what a delta-angle IMU outputs;
            not a rotation vector when the axis moves).
        """
        raise NotImplementedError

    def _check_times(self, t_s: ArrayLike, increasing: bool = False) -> NDArray[np.float64]:
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        if t.ndim != 1:
            raise InputError(f"Expected `t_s` of shape (N,), got shape {t.shape}")
        if not np.all(np.isfinite(t)):
            i = int(np.argmin(np.isfinite(t)))
            raise InputError(f"Expected finite `t_s`, got t_s[{i}] = {float(t[i])!r}")
        # A few ulps of slack so that stamps rounded to integer nanoseconds still fit.
        slack = 1e-9
        bad = np.flatnonzero((t < -slack) | (t > self.duration_s + slack))
        if bad.size:
            raise InputError(
                f"Expected `t_s` within [0, {self.duration_s}] s, "
                f"got t_s[{bad[0]}] = {float(t[bad[0]])!r}"
            )
        if increasing and t.size > 1:
            d = np.diff(t)
            bad = np.flatnonzero(d <= 0)
            if bad.size:
                i = bad[0]
                raise InputError(
                    f"Expected `t_s` strictly increasing, got t_s[{i + 1}] = {float(t[i + 1])!r} "
                    f"<= t_s[{i}] = {float(t[i])!r}"
                )
        return np.clip(t, 0.0, self.duration_s)


class SolvedTrajectory(Trajectory):
    """Dense solution of Euler's equations coupled with the attitude (see module docstring).

    Build with :func:`solve_rigid_body`. ``inertia_kg_m2`` holds the principal moments
    ``(I1, I2, I3)`` about the body axes through the reference point (the pivot for a top, the
    centre of mass for a free body).
    """

    def __init__(
        self,
        sol,
        scene: str,
        params: dict[str, Any],
        duration_s: float,
        inertia_kg_m2: NDArray[np.float64],
        nfev: int,
    ) -> None:
        self._sol = sol
        self.scene = scene
        self.params = params
        self.duration_s = float(duration_s)
        self.inertia_kg_m2 = inertia_kg_m2
        self.nfev = nfev

    def state(self, t_s: ArrayLike) -> NDArray[np.float64]:
        """Raw ODE state ``(q_w_b unnormalised, omega_b, theta_b)`` at ``t_s``, shape (N, 10)."""
        t = self._check_times(t_s)
        return np.asarray(self._sol(t)).T.reshape(t.size, 10)

    def at(self, t_s: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        y = self.state(t_s)
        return quat_normalize(y[:, 0:4]), y[:, 4:7].copy()

    def delta_angles(self, t_s: ArrayLike) -> NDArray[np.float64]:
        t = self._check_times(t_s, increasing=True)
        theta = np.asarray(self._sol(t)).T.reshape(t.size, 10)[:, 7:10]
        return np.diff(theta, axis=0)


def _rhs_factory(inertia: tuple[float, float, float], torque: TorqueFn | None):
    i1, i2, i3 = inertia
    k1, k2, k3 = (i2 - i3) / i1, (i3 - i1) / i2, (i1 - i2) / i3

    def rhs(t: float, y: NDArray) -> list[float]:
        qx, qy, qz, qw, w1, w2, w3, _, _, _ = y.tolist()
        # dq/dt = 1/2 q ⊗ [w, 0]
        dqx = 0.5 * (qw * w1 + qy * w3 - qz * w2)
        dqy = 0.5 * (qw * w2 - qx * w3 + qz * w1)
        dqz = 0.5 * (qw * w3 + qx * w2 - qy * w1)
        dqw = -0.5 * (qx * w1 + qy * w2 + qz * w3)
        dw1 = k1 * w2 * w3
        dw2 = k2 * w3 * w1
        dw3 = k3 * w1 * w2
        if torque is not None:
            t1, t2, t3 = torque(t, (qx, qy, qz, qw), (w1, w2, w3))
            dw1 += t1 / i1
            dw2 += t2 / i2
            dw3 += t3 / i3
        return [dqx, dqy, dqz, dqw, dw1, dw2, dw3, w1, w2, w3]

    return rhs


def solve_rigid_body(
    inertia_kg_m2: ArrayLike,
    q0_w_b: ArrayLike,
    omega0_b: ArrayLike,
    duration_s: float,
    *,
    torque: TorqueFn | None = None,
    scene: str = "rigid-body",
    params: dict[str, Any] | None = None,
    rtol: float = DEFAULT_TOL,
    atol: float = DEFAULT_TOL,
    max_steps: float | None = None,
) -> SolvedTrajectory:
    """Solve Euler's equations coupled with the attitude (DOP853, dense output).

    Parameters
    ----------
    inertia_kg_m2 : array_like, shape (3,)
        Principal moments of inertia ``(I1, I2, I3)`` about the body axes, kg·m², all > 0.
    q0_w_b : array_like, shape (4,)
        Initial attitude ``[x, y, z, w]``, body to world (normalised here).
    omega0_b : array_like, shape (3,)
        Initial body rate, rad/s, body axes.
    duration_s : float
        End time, s (> 0).
    torque : callable, optional
        ``torque(t_s, q_w_b, omega_b) -> (tau1, tau2, tau3)``: external torque about the
        reference point in body axes, N·m; ``q_w_b`` may be slightly unnormalised. ``None``:
        torque-free.
    scene, params : str, dict
        Recorded on the result.
    rtol, atol : float
        Tolerances of ``solve_ivp``.
    max_steps : float, optional
        Refuse (:class:`data_synth.budget.JobTooLarge`, before solving) when the solve is
        estimated to take more steps than this; its ``steps`` attribute holds the estimate.
        ``None``: no limit.

    Returns
    -------
    SolvedTrajectory
    """
    inertia = np.asarray(inertia_kg_m2, dtype=float)
    if inertia.shape != (3,) or not np.all(np.isfinite(inertia)) or np.any(inertia <= 0):
        raise InputError(f"Expected `inertia_kg_m2` three positive moments, got {inertia.tolist()}")
    q0 = np.asarray(q0_w_b, dtype=float)
    if q0.shape != (4,):
        raise InputError(f"Expected `q0_w_b` of shape (4,) [x, y, z, w], got shape {q0.shape}")
    q0 = quat_normalize(q0)
    w0 = np.asarray(omega0_b, dtype=float)
    if w0.shape != (3,) or not np.all(np.isfinite(w0)):
        raise InputError(f"Expected `omega0_b` three finite rates (rad/s), got {w0.tolist()}")
    if not (math.isfinite(duration_s) and duration_s > 0):
        raise InputError(f"Expected `duration_s` > 0, got {duration_s!r}")
    y0 = np.concatenate([q0, w0, np.zeros(3)])
    rhs = _rhs_factory(tuple(float(v) for v in inertia), torque)
    if max_steps is not None:
        from data_synth.budget import BYTES_PER_STEP, JobTooLarge, estimate_ode_steps, format_bytes

        steps = estimate_ode_steps(rhs, y0, duration_s, rtol, atol)
        if steps > max_steps:
            exc = JobTooLarge(
                f"Expected at most {max_steps:.3g} ODE steps, got an estimated "
                f"{steps:.3g} (~{format_bytes(steps * BYTES_PER_STEP)}) over "
                f"{duration_s:g} s from |omega_b(0)| = "
                f"{float(np.linalg.norm(w0)):.3g} rad/s"
            )
            exc.steps = steps
            raise exc
    sol = solve_ivp(
        rhs, (0.0, float(duration_s)), y0, method="DOP853", rtol=rtol, atol=atol, dense_output=True
    )
    if not sol.success:
        raise InputError(f"Expected the rigid-body ODE to solve, got: {sol.message}")
    return SolvedTrajectory(sol.sol, scene, dict(params or {}), duration_s, inertia, sol.nfev)

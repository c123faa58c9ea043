"""The scenes of the simulator (also the CLI's sub-commands): heavy top, free body, coning.

Conventions (docs/design.md): ``q_w_b`` Hamilton ``[x, y, z, w]`` body to world; ``omega_b`` body
rate relative to the world in body axes, rad/s; world ENU with gravity ``(0, 0, −g)``.

* ``heavy-top``: the top of Xiaoliang (2014) (docs/design.md, "Ground truth"): pivot at the
  world origin, symmetry axis = body z, centre of mass at ``arm_m · z_b``, ``R_w_b(0) = Rx(+tilt)``,
  ``ω3 = 2π spin_hz`` (conserved), ``θ̇(0) = 0``. The motion is set by the initial precession
  rate ``φ̇(0)``, i.e. ``omega_b(0) = (0, φ̇(0) sin θ0, ω3)`` (Goldstein 4-125 with ψ = 0):

  ==========  ===============================================================================
  cusp        ``φ̇(0) = 0``: the top starts at rest in the precession and falls, cusps on top
  wavy        ``φ̇(0) = +½ φ̇_slow``: same sense as the mean precession, ``φ̇`` never changes
              sign (``b/a`` lies above the upper turning point ``u2 = cos θ0``)
  looping     ``φ̇(0) = −½ φ̇_slow``: against it, ``φ̇`` changes sign twice per nutation
              (``f(b/a) > 0``, so ``b/a`` lies strictly between the turning points)
  steady      ``φ̇(0) = φ̇_slow`` or ``φ̇_fast`` (``branch``): θ stays at the tilt
  sleeping    tilt 0: spins upright (stable: ``ω3² > 4 I1 M g l / I3²``)
  ==========  ===============================================================================

  with ``φ̇_slow, φ̇_fast`` the roots of ``I1 cosθ0 φ̇² − I3 ω3 φ̇ + M g l = 0``.
* ``free-body``: the box of Shuijing (n.d.) (edges 2.0 × 1.5 × 1.0 m along body x, y, z,
  1 kg, about its centre of mass), ``R_w_b(0) = I``; ``case="diagonal"``:
  ``omega_b(0) = (1, 1, 1)/√3`` rad/s; ``case="intermediate"``: ``(0.05, 3, 0.05)`` rad/s, which
  flips about the intermediate axis (Dzhanibekov).
* ``coning``: pure coning, closed form (:class:`data_synth.analytic.ConingTrajectory`).
"""

from __future__ import annotations

import inspect
import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from data_synth.analytic import ConingTrajectory, steady_precession_rates
from data_synth.rigid_body import SolvedTrajectory, TorqueFn, Trajectory, solve_rigid_body
from imu_dcm.errors import InputError

__all__ = [
    "BRANCHES",
    "FREE_BODY_CASES",
    "MOTIONS",
    "SCENES",
    "HeavyTopParams",
    "box_inertia",
    "coning",
    "free_body",
    "heavy_top",
    "heavy_top_initial_rates",
    "heavy_top_initial_state",
    "heavy_top_torque",
    "simulate",
]

SCENES = ("heavy-top", "free-body", "coning")
MOTIONS = ("cusp", "wavy", "looping", "steady", "sleeping")
BRANCHES = ("slow", "fast")
FREE_BODY_CASES = ("diagonal", "intermediate")

#: Fraction of the slow steady-precession rate used as ``φ̇(0)`` for wavy (+) and looping (−).
WAVY_LOOPING_FRACTION = 0.5


@dataclass(frozen=True)
class HeavyTopParams:
    """Physical parameters of the heavy symmetric top (Xiaoliang 2014, Figure 11).

    Attributes
    ----------
    mass_kg : float
        Mass ``M``, kg.
    arm_m : float
        Pivot to centre of mass ``l``, m, along body z.
    i1_kg_m2 : float
        Transverse moment about the pivot, ``I1 = I2``, kg·m².
    i3_kg_m2 : float
        Axial moment ``I3``, kg·m².
    g_m_s2 : float
        Gravity, m/s², along world −z.
    spin_hz : float
        ``ω3 / 2π``, Hz: the body-z rate (conserved).
    tilt_deg : float
        Initial angle of the symmetry axis from the vertical, deg (``R_w_b(0) = Rx(tilt)``).
    """

    mass_kg: float = 1.0
    arm_m: float = 0.04
    i1_kg_m2: float = 0.002
    i3_kg_m2: float = 0.0008
    g_m_s2: float = 9.8
    spin_hz: float = 20.0
    tilt_deg: float = 54.57

    @property
    def mgl_n_m(self) -> float:
        """``M g l``, N·m."""
        return self.mass_kg * self.g_m_s2 * self.arm_m

    @property
    def omega3_rad_s(self) -> float:
        """``ω3 = 2π spin_hz``, rad/s."""
        return 2.0 * math.pi * self.spin_hz

    def validate(self) -> None:
        """Raise :class:`InputError` for a non-physical parameter."""
        for name, v in asdict(self).items():
            if not math.isfinite(v):
                raise InputError(f"Expected finite `{name}`, got {v!r}")
        for name in ("mass_kg", "arm_m", "i1_kg_m2", "i3_kg_m2", "g_m_s2"):
            if getattr(self, name) <= 0:
                raise InputError(f"Expected `{name}` > 0, got {getattr(self, name)!r}")
        if not 0.0 <= self.tilt_deg < 180.0:
            raise InputError(f"Expected `tilt_deg` in [0, 180), got {self.tilt_deg!r}")


def heavy_top_initial_rates(
    p: HeavyTopParams, motion: str, branch: str = "slow"
) -> tuple[float, float]:
    """Initial precession rate ``φ̇(0)`` (rad/s) and tilt (rad) for a motion of the top.

    See the module docstring for the table of motions. ``sleeping`` forces the tilt to 0.
    """
    if motion not in MOTIONS:
        raise InputError(f"Expected motion in {MOTIONS}, got {motion!r}")
    if branch not in BRANCHES:
        raise InputError(f"Expected branch in {BRANCHES}, got {branch!r}")
    tilt = math.radians(p.tilt_deg)
    if motion == "sleeping":
        return 0.0, 0.0
    if motion == "cusp":
        return 0.0, tilt
    slow, fast = steady_precession_rates(p.i1_kg_m2, p.i3_kg_m2, p.omega3_rad_s, p.mgl_n_m, tilt)
    if motion == "steady":
        return (slow if branch == "slow" else fast), tilt
    sign = 1.0 if motion == "wavy" else -1.0
    return sign * WAVY_LOOPING_FRACTION * slow, tilt


def heavy_top_torque(p: HeavyTopParams) -> TorqueFn:
    """Gravity torque about the pivot in body axes: ``τ_b = l z_b × (R_w_bᵀ (0, 0, −M g))``.

    With ``(R20, R21, R22)`` the body components of world z (third row of ``R_w_b``), this is
    ``M g l (R21, −R20, 0)``. Works for an unnormalised quaternion (divides by ``|q|²``).
    """
    mgl = p.mgl_n_m

    def torque(t: float, q: tuple, w: tuple) -> tuple:
        x, y, z, s = q
        k = 2.0 * mgl / (x * x + y * y + z * z + s * s)
        return (k * (y * z + s * x), -k * (x * z - s * y), 0.0)

    return torque


def heavy_top_initial_state(
    motion: str = "cusp",
    *,
    branch: str = "slow",
    params: HeavyTopParams | None = None,
    tilt_deg: float | None = None,
    spin_hz: float | None = None,
) -> tuple[HeavyTopParams, np.ndarray, np.ndarray, dict[str, Any]]:
    """Parameters, initial ``q_w_b`` (4,), initial ``omega_b`` (3,, rad/s) and the metadata
    record of a heavy-top motion (arguments as :func:`heavy_top`)."""
    p = params or HeavyTopParams()
    if motion == "sleeping":
        if tilt_deg not in (None, 0.0):
            raise InputError(f"Expected no tilt for a sleeping top, got tilt_deg = {tilt_deg!r}")
        tilt_deg = 0.0
    if tilt_deg is not None:
        p = HeavyTopParams(**{**asdict(p), "tilt_deg": float(tilt_deg)})
    if spin_hz is not None:
        p = HeavyTopParams(**{**asdict(p), "spin_hz": float(spin_hz)})
    p.validate()
    precession0, tilt = heavy_top_initial_rates(p, motion, branch)
    q0 = np.array([math.sin(0.5 * tilt), 0.0, 0.0, math.cos(0.5 * tilt)])
    omega0 = np.array([0.0, precession0 * math.sin(tilt), p.omega3_rad_s])
    record: dict[str, Any] = {
        **asdict(p),
        "tilt_deg": math.degrees(tilt),
        "motion": motion,
        "precession0_rad_s": precession0,
        "q0_w_b": q0.tolist(),
        "omega0_b_rad_s": omega0.tolist(),
    }
    if motion == "steady":
        record["branch"] = branch
    return p, q0, omega0, record


def heavy_top(
    duration_s: float,
    motion: str = "cusp",
    *,
    branch: str = "slow",
    params: HeavyTopParams | None = None,
    tilt_deg: float | None = None,
    spin_hz: float | None = None,
    rtol: float = 1e-12,
    atol: float = 1e-12,
    max_steps: float | None = None,
) -> SolvedTrajectory:
    """Simulate the heavy symmetric top (see the module docstring).

    Parameters
    ----------
    duration_s : float
        Length, s.
    motion : {"cusp", "wavy", "looping", "steady", "sleeping"}
    branch : {"slow", "fast"}
        Root used for ``motion="steady"``.
    params : HeavyTopParams, optional
        Physical parameters; default those of Xiaoliang (2014), Figure 11.
    tilt_deg, spin_hz : float, optional
        Override ``params``. A non-zero tilt is refused for ``sleeping``.
    rtol, atol : float
        ODE tolerances (default 1e-12).
    max_steps : float, optional
        Refuse a solve estimated to need more ODE steps (see :func:`solve_rigid_body`).

    Returns
    -------
    SolvedTrajectory
        ``scene = "heavy-top"``; ``params`` holds every physical parameter, the motion and the
        initial state.
    """
    p, q0, omega0, record = heavy_top_initial_state(
        motion, branch=branch, params=params, tilt_deg=tilt_deg, spin_hz=spin_hz
    )
    inertia = (p.i1_kg_m2, p.i1_kg_m2, p.i3_kg_m2)
    return solve_rigid_body(
        inertia,
        q0,
        omega0,
        duration_s,
        torque=heavy_top_torque(p),
        scene="heavy-top",
        params=record,
        rtol=rtol,
        atol=atol,
        max_steps=max_steps,
    )


def box_inertia(edges_m: ArrayLike, mass_kg: float) -> np.ndarray:
    """Principal moments of a uniform box about its centre, ``I1 = m (b² + c²)/12`` etc., kg·m²."""
    a, b, c = (float(v) for v in np.asarray(edges_m, dtype=float))
    return mass_kg / 12.0 * np.array([b * b + c * c, c * c + a * a, a * a + b * b])


def free_body(
    duration_s: float,
    case: str = "diagonal",
    *,
    omega0_b: ArrayLike | None = None,
    edges_m: tuple[float, float, float] = (2.0, 1.5, 1.0),
    mass_kg: float = 1.0,
    rtol: float = 1e-12,
    atol: float = 1e-12,
    max_steps: float | None = None,
) -> SolvedTrajectory:
    """Simulate the torque-free box of Shuijing (n.d.).

    Parameters
    ----------
    duration_s : float
        Length, s.
    case : {"diagonal", "intermediate"}
        ``omega_b(0) = (1, 1, 1)/√3`` rad/s, or ``(0.05, 3, 0.05)`` rad/s (intermediate-axis
        flips).
    omega0_b : array_like, shape (3,), optional
        Overrides the case's initial body rate, rad/s.
    edges_m : tuple of 3 float
        Box edges along body x, y, z, m.
    mass_kg : float
        Mass, kg.
    rtol, atol : float
        ODE tolerances (default 1e-12).
    max_steps : float, optional
        Refuse a solve estimated to need more ODE steps (see :func:`solve_rigid_body`).
    """
    if case not in FREE_BODY_CASES:
        raise InputError(f"Expected case in {FREE_BODY_CASES}, got {case!r}")
    edges = np.asarray(edges_m, dtype=float)
    if edges.shape != (3,) or not np.all(np.isfinite(edges)) or np.any(edges <= 0):
        raise InputError(f"Expected `edges_m` three positive lengths, got {edges.tolist()}")
    if not (math.isfinite(mass_kg) and mass_kg > 0):
        raise InputError(f"Expected `mass_kg` > 0, got {mass_kg!r}")
    if omega0_b is None:
        w0 = np.ones(3) / math.sqrt(3.0) if case == "diagonal" else np.array([0.05, 3.0, 0.05])
    else:
        w0 = np.asarray(omega0_b, dtype=float)
    inertia = box_inertia(edges, mass_kg)
    q0 = np.array([0.0, 0.0, 0.0, 1.0])
    record = {
        "case": case,
        "edges_m": edges.tolist(),
        "mass_kg": float(mass_kg),
        "inertia_kg_m2": inertia.tolist(),
        "q0_w_b": q0.tolist(),
        "omega0_b_rad_s": np.asarray(w0, dtype=float).tolist(),
    }
    return solve_rigid_body(
        inertia,
        q0,
        w0,
        duration_s,
        scene="free-body",
        params=record,
        rtol=rtol,
        atol=atol,
        max_steps=max_steps,
    )


def coning(
    duration_s: float, half_angle_deg: float = 10.0, freq_hz: float = 5.0
) -> ConingTrajectory:
    """Pure coning, ``R_w_b(t) = Rz(Ωt) Rx(β) Rz(−Ωt)`` (closed form; docs/design.md, coning)."""
    return ConingTrajectory(duration_s, half_angle_deg=half_angle_deg, freq_hz=freq_hz)


def simulate(scene: str, duration_s: float, **params: Any) -> Trajectory:
    """Make the ground truth of a scene, by the CLI's scene name.

    Parameters
    ----------
    scene : {"heavy-top", "free-body", "coning"}
    duration_s : float
        Length, s.
    **params
        Keyword arguments of :func:`heavy_top` (``motion``, ``branch``, ``tilt_deg``,
        ``spin_hz``, ``params``), :func:`free_body` (``case``, ``omega0_b``, ``edges_m``,
        ``mass_kg``) or :func:`coning` (``half_angle_deg``, ``freq_hz``).

    Returns
    -------
    Trajectory
        ``q_w_b, omega_b = traj.at(t_s)``; ``traj.delta_angles(t_s)``; ``traj.scene``,
        ``traj.params``.

    Examples
    --------
    >>> traj = simulate("heavy-top", duration_s=1.2, motion="cusp")
    >>> q_w_b, omega_b = traj.at([0.0, 0.5])
    """
    makers = {"heavy-top": heavy_top, "free-body": free_body, "coning": coning}
    key = scene.replace("_", "-")
    if key not in makers:
        raise InputError(f"Expected scene in {SCENES}, got {scene!r}")
    allowed = [n for n in inspect.signature(makers[key]).parameters if n != "duration_s"]
    unknown = sorted(set(params) - set(allowed))
    if unknown:
        raise InputError(f"Expected parameters of scene {key!r} among {allowed}, got {unknown}")
    return makers[key](duration_s, **params)

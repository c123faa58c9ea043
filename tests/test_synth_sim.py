"""The rigid-body ground truth: conservation laws, convergence, and independent analytic solutions
(torque-free symmetric top, Jacobi-elliptic box rates and elliptic-integral box attitude, the heavy
top's elliptic cos θ(t), steady precession, coning)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.spatial.transform import Rotation

import data_synth
from data_synth.analytic import (
    box_attitude_elliptic,
    box_omega_elliptic,
    coning_attitude,
    coning_rates,
    heavy_top_cos_theta,
    heavy_top_invariants,
    steady_precession_rates,
    symmetric_free_top,
)
from data_synth.scenes import HeavyTopParams, heavy_top_initial_rates
from imu_dcm.errors import InputError
from imu_dcm.so3 import quat_angle_rad

EPS = np.finfo(float).eps  # 2.2e-16: unit round-off bounds below are multiples of it

P = HeavyTopParams()
I_TOP = np.array([P.i1_kg_m2, P.i1_kg_m2, P.i3_kg_m2])


def _deg(q_a, q_b) -> np.ndarray:
    return np.degrees(quat_angle_rad(q_a, q_b))


def _top_invariants(q, w):
    """Energy, world-vertical and body-axial angular momentum of the heavy top, from its state."""
    R = Rotation.from_quat(q).as_matrix()
    energy = 0.5 * np.sum(I_TOP * w * w, axis=1) + P.mgl_n_m * R[:, 2, 2]
    l_world = np.einsum("nij,nj->ni", R, I_TOP * w)
    return energy, l_world[:, 2], I_TOP[2] * w[:, 2]


@pytest.mark.parametrize("motion", ["cusp", "wavy", "looping", "steady", "sleeping"])
def test_heavy_top_conserves_energy_lz_l3(motion):
    traj = data_synth.simulate("heavy-top", duration_s=2.0, motion=motion)
    q, w = traj.at(np.linspace(0.0, 2.0, 4001))
    energy, lz, l3 = _top_invariants(q, w)
    # Bound of docs/design.md, "Ground truth": relative drift <= 1e-10 (measured ~1e-12 at
    # rtol = atol = 1e-12).
    assert np.ptp(energy) / abs(energy[0]) <= 1e-10
    scale_l = np.linalg.norm(I_TOP * w[0])  # |L|: L_z may be near zero, so scale by |L|
    assert np.ptp(lz) / scale_l <= 1e-10
    assert np.ptp(l3) / abs(l3[0]) <= 1e-10


@pytest.mark.parametrize("case", ["diagonal", "intermediate"])
def test_free_body_conserves_energy_and_world_angular_momentum(case):
    traj = data_synth.simulate("free-body", duration_s=20.0, case=case)
    q, w = traj.at(np.linspace(0.0, 20.0, 2001))
    inertia = traj.inertia_kg_m2
    energy = 0.5 * np.sum(inertia * w * w, axis=1)
    l_world = np.einsum("nij,nj->ni", Rotation.from_quat(q).as_matrix(), inertia * w)
    assert np.ptp(energy) / energy[0] <= 1e-10
    assert np.abs(l_world - l_world[0]).max() / np.linalg.norm(l_world[0]) <= 1e-10


def test_resolving_tighter_moves_attitude_below_1e_8_deg():
    t = np.linspace(0.0, 1.2, 2401)
    q12, _ = data_synth.heavy_top(1.2, "cusp").at(t)
    q13, _ = data_synth.heavy_top(1.2, "cusp", rtol=1e-13, atol=1e-13).at(t)
    # The truth is converged: a 10x tighter tolerance changes it by < 1e-8 deg
    # (docs/design.md, "Ground truth").
    assert _deg(q12, q13).max() < 1e-8


def test_quaternion_order_90_deg_about_z():
    # Spin about the major axis at π/2 rad/s for 1 s: exactly 90° about z = [0, 0, √½, √½].
    traj = data_synth.free_body(1.0, omega0_b=(0.0, 0.0, math.pi / 2))
    q, w = traj.at([1.0])
    assert np.allclose(q[0], [0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)], atol=1e-11)
    assert np.allclose(w[0], [0.0, 0.0, math.pi / 2], atol=1e-14)


def test_initial_state_is_rx_tilt_and_spin():
    traj = data_synth.simulate("heavy-top", duration_s=0.1, motion="cusp")
    q, w = traj.at([0.0])
    # R_w_b(0) = Rx(+54.57°): the body z axis leans towards world -y.
    R = Rotation.from_quat(q[0]).as_matrix()
    tilt = math.radians(54.57)
    assert np.allclose(R[:, 2], [0.0, -math.sin(tilt), math.cos(tilt)], atol=1e-15)
    assert np.allclose(w[0], [0.0, 0.0, 2 * math.pi * 20.0], atol=0)


def test_torque_free_symmetric_top_matches_closed_form():
    q0 = Rotation.from_euler("xyz", [0.3, -0.2, 0.5]).as_quat()
    w0 = np.array([2.0, -1.0, 60.0])
    traj = data_synth.solve_rigid_body(I_TOP, q0, w0, 3.0)
    t = np.linspace(0.0, 3.0, 3001)
    q, w = traj.at(t)
    q_cf, w_cf = symmetric_free_top(t, I_TOP[0], I_TOP[2], w0, q0)
    # Closed form vs DOP853 at 1e-12: both exact; ~ 1e-9 deg after 3 s and 180 rad of spin.
    assert _deg(q, q_cf).max() < 1e-7
    assert np.abs(w - w_cf).max() < 1e-9


@pytest.mark.parametrize("case", ["diagonal", "intermediate"])
def test_box_rates_match_jacobi_elliptic_solution(case):
    traj = data_synth.free_body(20.0, case)
    t = np.linspace(0.0, 20.0, 2001)
    _, w = traj.at(t)
    w_el = box_omega_elliptic(t, traj.inertia_kg_m2, traj.params["omega0_b_rad_s"])
    # scipy's ellipj is accurate to ~1e-13; the near-separatrix (intermediate) case loses a
    # few digits in the phase, both are far inside 1e-8 rad/s.
    assert np.abs(w - w_el).max() < 1e-8


@pytest.mark.parametrize("case", ["diagonal", "intermediate"])
def test_box_attitude_matches_elliptic_integral_solution(case):
    traj = data_synth.free_body(20.0, case)
    t = np.linspace(0.0, 20.0, 2001)
    q, _ = traj.at(t)
    q_el = box_attitude_elliptic(
        t, traj.inertia_kg_m2, traj.params["omega0_b_rad_s"], [0.0, 0.0, 0.0, 1.0]
    )
    # Carlson-form Π vs the ODE: measured ~1e-9 deg over 20 s; 1e-6 deg leaves room for the
    # conditioning of the phase near the separatrix.
    assert _deg(q, q_el).max() < 1e-6


@pytest.mark.parametrize(
    "omega0_b",
    [
        (-0.3, 0.5, -1.0),
        (-1.0, -1.0, 1.5),  # M² > 2EI2
        (0.4, -2.0, 0.3),
        (2.0, 0.1, 0.1),
        (-2.0, 0.5, -0.3),
    ],
)
def test_box_elliptic_solution_from_a_general_state(omega0_b):
    # Any signs of the rates, any initial attitude (the phase τ0 and the frame of L), and both
    # sides of the separatrix (the last three turn about the minor axis: M² < 2 E I2).
    inertia = np.array([0.27, 0.42, 0.52])
    q0 = Rotation.from_euler("xyz", [0.3, 1.0, -2.0]).as_quat()
    traj = data_synth.solve_rigid_body(inertia, q0, omega0_b, 15.0)
    t = np.linspace(0.0, 15.0, 1501)
    q, w = traj.at(t)
    assert np.abs(box_omega_elliptic(t, inertia, omega0_b) - w).max() < 1e-8
    assert _deg(box_attitude_elliptic(t, inertia, omega0_b, q0), q).max() < 1e-6


def test_box_elliptic_refuses_the_separatrix_and_bad_inertia():
    inertia = np.array([1.0, 2.0, 3.0])
    # ω = (√3, 0, 1): 2E = 3 + 3 = 6 and M² = 3 + 9 = 12 = 2 E I2, exactly on the separatrix.
    with pytest.raises(InputError, match="separatrix"):
        box_omega_elliptic([0.0], inertia, (math.sqrt(3.0), 0.0, 1.0))
    with pytest.raises(InputError, match="I1 < I2 < I3"):
        box_attitude_elliptic([0.0], (3.0, 2.0, 1.0), (0.0, 0.0, 1.0), (0.0, 0.0, 0.0, 1.0))


def test_intermediate_axis_flips():
    traj = data_synth.free_body(30.0, "intermediate")
    _, w = traj.at(np.linspace(0.0, 30.0, 3001))
    # Dzhanibekov: ω2 reverses sign (the body flips), which the diagonal case never does.
    assert w[:, 1].max() > 2.5 and w[:, 1].min() < -2.5


@pytest.mark.parametrize("motion", ["cusp", "wavy", "looping"])
def test_heavy_top_cos_theta_matches_elliptic_solution(motion):
    precession0, tilt = heavy_top_initial_rates(P, motion)
    inv = heavy_top_invariants(P.i1_kg_m2, P.i3_kg_m2, P.mgl_n_m, tilt, P.omega3_rad_s, precession0)
    # The top starts at rest in θ at its upper turning point (it falls): u2 = cos θ0.
    assert abs(inv.roots[1] - math.cos(tilt)) < 1e-9
    traj = data_synth.heavy_top(2.0, motion)
    t = np.linspace(0.0, 2.0, 4001)
    q, _ = traj.at(t)
    u_sim = Rotation.from_quat(q).as_matrix()[:, 2, 2]
    u_el = heavy_top_cos_theta(t, inv, start_at_upper=True)
    # Two exact solutions: agreement ~1e-11; the bound allows root-finding round-off.
    assert np.abs(u_sim - u_el).max() < 1e-8


def _precession_rate(traj, t):
    """φ̇ of the simulated top from the azimuth of its symmetry axis (z-x-z: z_b =
    (sin φ sin θ, −cos φ sin θ, cos θ))."""
    q, _ = traj.at(t)
    z = Rotation.from_quat(q).as_matrix()[:, :, 2]
    phi = np.unwrap(np.arctan2(z[:, 0], -z[:, 1]))
    return np.diff(phi) / np.diff(t)


def test_wavy_and_looping_are_what_their_names_say():
    t = np.linspace(0.0, 2.0, 20001)
    for motion in ("wavy", "looping"):
        precession0, tilt = heavy_top_initial_rates(P, motion)
        inv = heavy_top_invariants(
            P.i1_kg_m2, P.i3_kg_m2, P.mgl_n_m, tilt, P.omega3_rad_s, precession0
        )
        u1, u2, _ = inv.roots
        ustar = inv.b / inv.a  # where φ̇ = (b − a u)/(1 − u²) changes sign
        rate = _precession_rate(data_synth.heavy_top(2.0, motion), t)
        if motion == "wavy":  # b/a above the motion: φ̇ keeps the sign of the mean precession
            assert ustar > u2 and rate.min() > 0
        else:  # b/a between the turning points: φ̇ reverses, the axis loops
            assert u1 < ustar < u2 and rate.min() < 0 < rate.max()
    cusp = _precession_rate(data_synth.heavy_top(2.0, "cusp"), t)
    # Cusp: φ̇ >= 0, touching 0 at the top of each nutation (finite-difference resolution).
    assert cusp.min() > -1e-3 and abs(cusp.min()) < 0.05 * cusp.max()


@pytest.mark.parametrize("branch", ["slow", "fast"])
def test_steady_precession_keeps_theta(branch):
    traj = data_synth.heavy_top(2.0, "steady", branch=branch)
    q, _ = traj.at(np.linspace(0.0, 2.0, 4001))
    u = Rotation.from_quat(q).as_matrix()[:, 2, 2]
    # Any nutation would swing cos θ by ~0.1 (the cusp's amplitude); steady: round-off only.
    assert np.abs(u - math.cos(math.radians(54.57))).max() < 1e-8
    slow, fast = steady_precession_rates(
        P.i1_kg_m2, P.i3_kg_m2, P.omega3_rad_s, P.mgl_n_m, math.radians(54.57)
    )
    expected = slow if branch == "slow" else fast
    rate = _precession_rate(traj, np.linspace(0.0, 2.0, 40001))
    assert np.abs(rate / expected - 1.0).max() < 1e-6
    # Roots of I1 cosθ φ̇² − I3 ω3 φ̇ + M g l = 0, checked by substitution.
    c = math.cos(math.radians(54.57))
    # Three terms of up to ~8 (fast branch) cancel: the residual is round-off of the terms and
    # of the root, a few eps of their magnitudes (16 eps margin), not a fixed 1e-12.
    terms = (P.i1_kg_m2 * c * expected**2, -P.i3_kg_m2 * P.omega3_rad_s * expected, P.mgl_n_m)
    assert abs(sum(terms)) < 16 * EPS * sum(abs(x) for x in terms)


def test_sleeping_top_stays_upright():
    q, w = data_synth.heavy_top(2.0, "sleeping").at(np.linspace(0.0, 2.0, 201))
    assert np.abs(Rotation.from_quat(q).as_matrix()[:, 2, 2] - 1.0).max() < 1e-12
    assert np.abs(w[:, :2]).max() < 1e-12


def test_steady_refused_for_too_slow_top():
    with pytest.raises(InputError, match="steady precession"):
        data_synth.heavy_top(1.0, "steady", spin_hz=1.0)


def test_coning_closed_form_against_scipy_and_kinematics():
    beta, f = 10.0, 5.0
    traj = data_synth.simulate("coning", duration_s=1.0, half_angle_deg=beta, freq_hz=f)
    t = np.linspace(0.0, 1.0, 501)
    q, w = traj.at(t)
    om = 2 * math.pi * f
    ref = (
        Rotation.from_rotvec(np.outer(om * t, [0, 0, 1]))
        * Rotation.from_rotvec([math.radians(beta), 0, 0])
        * Rotation.from_rotvec(np.outer(-om * t, [0, 0, 1]))
    )
    # Both evaluate sin/cos of Ωt (up to 31 rad here): rounding the argument costs eps·Ωt rad,
    # twice (Rz(Ωt), Rz(-Ωt)), plus a few eps for products and conversions (measured 1 eps).
    bound_rad = 8 * EPS * (1.0 + om * t.max())
    assert _deg(q, ref.as_quat()).max() < math.degrees(bound_rad)

    # The closed-form rate integrates (dq/dt = ½ q ⊗ ω) to the closed-form attitude.
    def rhs(tt, y):
        wx, wy, wz = coning_rates(np.array([tt]), math.radians(beta), f)[0]
        x, yy, z, s = y
        return 0.5 * np.array(
            [
                s * wx + yy * wz - z * wy,
                s * wy - x * wz + z * wx,
                s * wz + x * wy - yy * wx,
                -x * wx - yy * wy - z * wz,
            ]
        )

    sol = solve_ivp(rhs, (0, 1.0), q[0], method="DOP853", rtol=1e-12, atol=1e-12, t_eval=t)
    assert _deg(sol.y.T, coning_attitude(t, math.radians(beta), f)).max() < 1e-8
    assert np.allclose(w, coning_rates(t, math.radians(beta), f), rtol=0, atol=0)


@pytest.mark.parametrize(
    "scene, kw",
    [
        ("heavy-top", {"motion": "looping"}),
        ("free-body", {"case": "intermediate"}),
        ("coning", {"half_angle_deg": 30.0, "freq_hz": 7.0}),
    ],
)
def test_delta_angles_are_the_integral_of_the_rate(scene, kw):
    traj = data_synth.simulate(scene, duration_s=1.0, **kw)
    t = np.linspace(0.0, 1.0, 201)
    d = traj.delta_angles(t)
    assert d.shape == (200, 3)
    # 8-point Gauss–Legendre on each 5 ms interval of the dense rate: exact to ~1e-13 here.
    x, wts = np.polynomial.legendre.leggauss(8)
    a, b = t[:-1, None], t[1:, None]
    nodes = (0.5 * (b - a) * x[None, :] + 0.5 * (a + b)).ravel()
    _, w = traj.at(nodes)
    quad = 0.5 * (b - a) * np.einsum("k,nkj->nj", wts, w.reshape(200, 8, 3))
    scale = np.abs(d).max()
    assert np.abs(d - quad).max() < 1e-9 * max(scale, 1.0)


def test_trajectory_rejects_bad_times_and_scene_parameters():
    traj = data_synth.simulate("coning", duration_s=1.0)
    with pytest.raises(InputError, match=r"t_s\[1\] = 1.5"):
        traj.at([0.0, 1.5])
    with pytest.raises(InputError, match="strictly increasing"):
        traj.delta_angles([0.0, 0.5, 0.5])
    with pytest.raises(InputError, match="scene"):
        data_synth.simulate("spinning-plate", duration_s=1.0)
    with pytest.raises(InputError, match="motion"):
        data_synth.simulate("heavy-top", duration_s=1.0, mode="cusp")
    with pytest.raises(InputError, match="motion in"):
        data_synth.simulate("heavy-top", duration_s=1.0, motion="wobbly")
    with pytest.raises(InputError, match="duration_s"):
        data_synth.simulate("free-body", duration_s=-1.0)
    with pytest.raises(InputError, match="sleeping"):
        data_synth.heavy_top(1.0, "sleeping", tilt_deg=10.0)


def test_params_record_the_scene():
    traj = data_synth.simulate("heavy-top", duration_s=1.2, motion="cusp")
    assert traj.scene == "heavy-top"
    p = traj.params
    assert p["motion"] == "cusp" and p["tilt_deg"] == 54.57 and p["spin_hz"] == 20.0
    assert p["mass_kg"] == 1.0 and p["arm_m"] == 0.04 and p["precession0_rad_s"] == 0.0


def test_checks_command_reports_figures_within_the_bounds(capsys):
    from data_synth.checks import free_body_checks, heavy_top_checks, main

    assert main(["--duration", "0.3"]) == 0
    assert capsys.readouterr().out.count("\n") == 8  # header, five motions, two boxes
    figs = heavy_top_checks("looping", 0.5, n=501)
    # The same bounds as the tests above (conservation 1e-10, re-solve 1e-8°, elliptic 1e-8).
    assert figs["energy"] < 1e-10 and figs["L_z/|L|"] < 1e-10 and figs["resolve_deg"] < 1e-8
    assert figs["cos_theta_vs_elliptic"] < 1e-8
    box = free_body_checks("intermediate", 2.0, n=201)
    assert box["attitude_vs_elliptic_deg"] < 1e-6 and box["omega_vs_jacobi_rad_s"] < 1e-8

"""Stability scenes: small motions where attitude integration methods fail, and where they do not.

Eight scenes, each a pure function returning a frozen result that both the charts
(``python -m benchmarks``, ``benchmarks/stability.py``) and ``tests/test_stability.py`` use:

1. :func:`gimbal_lock` — integrating ZXZ Euler angles (a common textbook
   comparison) past ``θ = 0`` against the DCM recursion, as the body's z axis passes the vertical.
2. :func:`rotvec_sum_shortcut` — the rotation-vector-sum shortcut ``R0 · exp(Σ ω dt)``
   (exact only when the rotations commute) under coning, against its analytic error
   ``(1 − cos β) Ω t``.
3. :func:`large_steps` — steps with ``|ω| dt`` from 0.01 to 3 rad.
4. :func:`long_run` and :func:`naive_dcm_drift` — 10⁷ steps: error against truth, and how far the
   plain, never re-orthonormalised 3x3 product ``R ← R · CK(ω dt)`` leaves SO(3).
5. :func:`free_box` — flips about the free box's intermediate axis (Dzhanibekov), checked by
   conservation of the world angular momentum.
6. :func:`steady_top` — the sleeping top and the fast top at high spin (closed-form steady
   precession).
7. :func:`noise_growth` — attitude-error growth under white rate noise (``√T``) and bias (``T``).
8. :func:`truncated_update` — the first-order truncated quaternion step
   ``q ← normalise(q + ½ q ⊗ [ω dt, 0])`` against the exact exponential.

Conventions (docs/design.md): quaternions Hamilton ``[x, y, z, w]``; ``q_w_b`` maps body to world;
``omega_b`` is the body rate relative to the world in body axes, rad/s; increments multiply on
the right, ``q_{i+1} = q_i ⊗ exp(φ_i)``; world ENU, z up; times ``t_s`` in seconds. ZXZ Euler
angles ``(φ, θ, ψ)`` are intrinsic: ``R_w_b = Rz(φ) · Rx(θ) · Rz(ψ)``.

The truths here are closed forms (coning, steady precession, composed fixed-axis rotations) or
conservation laws (the free box), never an integrator of the kind being judged.
"""

from data_synth.stability.bodies import (
    FREE_BOX_OMEGA0,
    FreeBoxResult,
    NoiseGrowthResult,
    SteadyTopResult,
    free_box,
    noise_growth,
    steady_top,
)
from data_synth.stability.common import (
    BOX_INERTIA,
    DCM_METHODS,
    TOP,
    coning_truth,
    zxz_truth,
)
from data_synth.stability.steps import (
    GIMBAL_DURATION_S,
    GIMBAL_SPIN_RATE,
    GIMBAL_TILT_RATE,
    LARGE_DURATION_S,
    LARGE_PHI_RATE,
    LARGE_PSI_RATE,
    LARGE_TILT,
    LONG_BETA,
    LONG_OMEGA,
    GimbalLockResult,
    LargeStepsResult,
    LongRunResult,
    NaiveDcmResult,
    RotvecSumResult,
    TruncatedResult,
    gimbal_lock,
    gimbal_motion,
    large_steps,
    long_run,
    naive_dcm_drift,
    rotvec_sum_shortcut,
    truncated_update,
)

__all__ = [
    "BOX_INERTIA",
    "DCM_METHODS",
    "FREE_BOX_OMEGA0",
    "GIMBAL_DURATION_S",
    "GIMBAL_SPIN_RATE",
    "GIMBAL_TILT_RATE",
    "LARGE_DURATION_S",
    "LARGE_PHI_RATE",
    "LARGE_PSI_RATE",
    "LARGE_TILT",
    "LONG_BETA",
    "LONG_OMEGA",
    "TOP",
    "FreeBoxResult",
    "GimbalLockResult",
    "LargeStepsResult",
    "LongRunResult",
    "NaiveDcmResult",
    "NoiseGrowthResult",
    "RotvecSumResult",
    "SteadyTopResult",
    "TruncatedResult",
    "coning_truth",
    "free_box",
    "gimbal_lock",
    "gimbal_motion",
    "large_steps",
    "long_run",
    "naive_dcm_drift",
    "noise_growth",
    "rotvec_sum_shortcut",
    "steady_top",
    "truncated_update",
    "zxz_truth",
]

"""Peer integrators: other people's gyro-only attitude updates behind one signature.

Every peer is a function

    name(omega_b, t_s, q0) -> q_w_b

* ``omega_b`` : (N, 3) body rate relative to the world, in body axes, rad/s (what a gyro reads).
* ``t_s`` : (N,) sample times, s, strictly increasing.
* ``q0`` : (4,) attitude ``q_w_b`` at ``t_s[0]``, Hamilton ``[x, y, z, w]``.
* returns ``q_w_b`` : (N, 4) ``[x, y, z, w]``, body to world at every sample time; row 0 is ``q0``.

Conventions are this project's (docs/design.md): increments multiply on the **right**,
``q_{i+1} = q_i ⊗ exp(φ_i)``. Scalar-first libraries (ahrs, imufusion, vqf) are converted only at
the edge, here. Libraries that start from the identity (vqf) are brought to ``q0`` by a constant
left product ``q0 ⊗ q_rel(t)``, which is exact for right-multiplied body increments.

**Which sample each peer uses.** Every peer applies the *newest* sample over the step that ends at
it: ``q_{i+1} = q_i ⊗ step(ω_{i+1}, dt)`` — the plain DCM loop's rule and how a streaming
filter is naturally fed (sample ``i+1`` arrives at ``t_{i+1}`` and is applied over the elapsed
interval). All peers are first order; none corrects coning.

**Uneven sampling.** ``reference_loop``, ``scipy_loop`` and ``ahrs_angular_rate`` use each real
``dt``. ``imufusion_gain0`` sets its sample period once when the stamps are uniform (to 1e-9
relative) and before every sample otherwise. vqf takes one fixed ``gyrTs``: ``vqf_batch`` and
``vqf_update_gyr`` use the **median** ``dt`` (uneven stamps are not honoured).

``reference_loop`` and ``scipy_loop`` live in :mod:`imu_dcm.integrator.reference`; the library peers
import their library when called (``pip install imu_dcm[bench]``). ``PEERS`` maps each name to
a :class:`Peer` (function, short description, order).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from imu_dcm.integrator.reference import reference_ck, reference_loop, scipy_loop
from imu_dcm.so3 import quat_multiply

__all__ = [
    "PEERS",
    "Peer",
    "ahrs_angular_rate",
    "imufusion_gain0",
    "reference_ck",
    "reference_loop",
    "scipy_loop",
    "vqf_batch",
    "vqf_update_gyr",
]

# Uniform stamps: max |dt - median| below this fraction of the median.
_UNIFORM_REL = 1e-9


def _wxyz_to_xyzw(q: NDArray) -> NDArray:
    return np.asarray(q, dtype=float)[..., [1, 2, 3, 0]]


def _xyzw_to_wxyz(q: NDArray) -> NDArray:
    return np.asarray(q, dtype=float)[..., [3, 0, 1, 2]]


def _median_dt(t_s: NDArray) -> float:
    return float(np.median(np.diff(t_s)))


def _is_uniform(t_s: NDArray) -> bool:
    dt = np.diff(t_s)
    med = np.median(dt)
    return bool(np.max(np.abs(dt - med)) <= _UNIFORM_REL * med)


# ----------------------------------------------------------------------------------------------
# Library peers
# ----------------------------------------------------------------------------------------------


def ahrs_angular_rate(omega_b: NDArray, t_s: NDArray, q0: NDArray) -> NDArray:
    """ahrs ``AngularRate.update`` per sample, closed form (exact exponential of ``ω_{i+1} dt``).

    ahrs is scalar-first ``[w, x, y, z]`` and right-multiplies (its Ω(ω) matrix is ``q ⊗ [0, ω]``).
    The real ``dt`` of each step is passed (``dt=`` argument).
    """
    from ahrs.filters import AngularRate

    omega_b = np.asarray(omega_b, dtype=float)
    dt = np.diff(np.asarray(t_s, dtype=float))
    ar = AngularRate()
    out = np.empty((len(omega_b), 4))
    q = _xyzw_to_wxyz(q0)
    out[0] = q
    for i in range(1, len(omega_b)):
        q = ar.update(q, omega_b[i], method="closed", dt=dt[i - 1])
        out[i] = q
    return _wxyz_to_xyzw(out)


def imufusion_gain0(omega_b: NDArray, t_s: NDArray, q0: NDArray) -> NDArray:
    """imufusion (x-io Fusion) ``Ahrs`` with gain 0: gyro only, first-order ``q̇`` step, float32.

    Settings: ``gain = 0`` (no accelerometer correction), accelerometer fed zeros,
    ``gyroscope_range = 0`` (disables Fusion's over-range reset, which a fast top would trip),
    ``skip_startup()`` (the start-up phase otherwise holds the attitude), initial quaternion set to
    ``q0``. Fusion takes deg/s and ``[w, x, y, z]``. Sample period: set once when the stamps are
    uniform, else before every sample.
    """
    import imufusion

    omega_b = np.asarray(omega_b, dtype=float)
    t_s = np.asarray(t_s, dtype=float)
    dt = np.diff(t_s)
    gyr_dps = np.degrees(omega_b)
    zeros = np.zeros(3)
    ahrs = imufusion.Ahrs()
    ahrs.set_settings(
        imufusion.AhrsSettings(sample_rate=1.0 / _median_dt(t_s), gain=0.0, gyroscope_range=0.0)
    )
    ahrs.set_sample_period(_median_dt(t_s))
    ahrs.skip_startup()
    ahrs.set_quaternion(_xyzw_to_wxyz(q0))
    out = np.empty((len(omega_b), 4))
    out[0] = _xyzw_to_wxyz(q0)
    if _is_uniform(t_s):
        for i in range(1, len(omega_b)):
            ahrs.update_no_magnetometer(gyr_dps[i], zeros)
            out[i] = ahrs.get_quaternion()
    else:
        for i in range(1, len(omega_b)):
            ahrs.set_sample_period(dt[i - 1])
            ahrs.update_no_magnetometer(gyr_dps[i], zeros)
            out[i] = ahrs.get_quaternion()
    return _wxyz_to_xyzw(out)


def _gyro_only_vqf(ts_s: float):
    import vqf

    # Bias estimation and magnetic rejection off; zero accelerometer samples are ignored by
    # vqf's updateAcc, so only the gyro strapdown quaternion (exact step of ω Ts) acts.
    return vqf.VQF(
        ts_s, restBiasEstEnabled=False, motionBiasEstEnabled=False, magDistRejectionEnabled=False
    )


def vqf_batch(omega_b: NDArray, t_s: NDArray, q0: NDArray) -> NDArray:
    """vqf ``VQF.updateBatch`` (C++ loop), gyro only, fixed ``gyrTs`` = median ``dt``.

    Accelerometer rows are zero, which vqf skips, so ``quat6D`` is the pure gyro strapdown
    quaternion from the identity; the result is ``q0 ⊗ quat6D`` (scalar-first converted).
    """
    omega_b = np.asarray(omega_b, dtype=float)
    gyr = np.ascontiguousarray(omega_b[1:])
    v = _gyro_only_vqf(_median_dt(np.asarray(t_s, dtype=float)))
    q_rel = _wxyz_to_xyzw(v.updateBatch(gyr, np.zeros_like(gyr))["quat6D"])
    out = np.empty((len(omega_b), 4))
    out[0] = q0
    out[1:] = quat_multiply(q0, q_rel)
    return out


def vqf_update_gyr(omega_b: NDArray, t_s: NDArray, q0: NDArray) -> NDArray:
    """vqf ``VQF.updateGyr`` called per sample (Python loop over C++), fixed ``gyrTs`` = median dt.

    ``getQuat3D()`` (the gyro-only quaternion from the identity) is read after every sample; the
    result is ``q0 ⊗ quat3D``.
    """
    omega_b = np.ascontiguousarray(omega_b, dtype=float)
    v = _gyro_only_vqf(_median_dt(np.asarray(t_s, dtype=float)))
    q_rel = np.empty((len(omega_b), 4))
    q_rel[0] = (1.0, 0.0, 0.0, 0.0)
    for i in range(1, len(omega_b)):
        v.updateGyr(omega_b[i])
        q_rel[i] = v.getQuat3D()
    return quat_multiply(q0, _wxyz_to_xyzw(q_rel))


class Peer(NamedTuple):
    """A peer integrator: its function, a short description and its order of accuracy."""

    fn: Callable[[NDArray, NDArray, NDArray], NDArray]
    description: str
    order: str


PEERS: dict[str, Peer] = {
    "reference_loop": Peer(
        reference_loop, "plain DCM loop, numpy 3x3 CK per step, end-of-step rate", "first"
    ),
    "scipy_loop": Peer(scipy_loop, "scipy Rotation composed per sample", "first"),
    "ahrs_angular_rate": Peer(ahrs_angular_rate, "ahrs AngularRate.update, closed form", "first"),
    "imufusion_gain0": Peer(imufusion_gain0, "imufusion Ahrs, gain 0, float32 q-dot step", "first"),
    "vqf_batch": Peer(vqf_batch, "vqf updateBatch (C++), gyro only, median Ts", "first"),
    "vqf_update_gyr": Peer(vqf_update_gyr, "vqf updateGyr per sample, median Ts", "first"),
}

"""Batch DCM integration of body rates: ``R_{i+1} = R_i · exp([φ_i×])``.

Conventions (README, "Frames and units"): ``q_w_b`` / ``R_w_b`` map body to world (active
rotations, columns of ``R_w_b`` are the body axes in world); quaternions are Hamilton,
scalar-last ``[x, y, z, w]``; ``omega_b`` is the body rate relative to the world in body axes,
rad/s; increments multiply on the **right**, ``q_{i+1} = q_i ⊗ exp(φ_i)``; time ``t_s`` in
seconds, each step uses its own ``dt_i = t_{i+1} - t_i``.

Increment rules ``φ_i`` over step ``[t_i, t_{i+1}]`` (``h = dt_i``):

=============  ===================================================================  =====
method         ``φ_i``                                                              order
=============  ===================================================================  =====
``start``      ``h ω_i``                                                            1
``end``        ``h ω_{i+1}`` (the classic DCM recursion ``R_{i+1} = R_i CK(ω_{i+1} h)``) 1
``trapezoid``  ``h (ω_i + ω_{i+1}) / 2``                                            2
``coning``     trapezoid ``+ h²/12 ω_i × ω_{i+1}``                                  2
``magnus4``    ``h/6 (ω_i + 4 ω_m + ω_{i+1}) + h²/12 ω_i × ω_{i+1}``                4
``rotvec_sum`` ``q_i = q_0 ⊗ exp(Σ_{j<i} h_j ω_j)``: wrong unless rotations commute;
               kept to show the failure, warns                                      —
=============  ===================================================================  =====

``ω_m`` is the rate at mid-step from the cubic through ``ω_{i-1..i+2}`` at their real stamps
(one sample of look-ahead). At the ends of the record the missing neighbour is a *ghost* sample
extrapolated from the cubic through the first (last) four samples, so the end steps use the
one-sided cubic; with 2 or 3 samples the polynomial degree drops to 1 or 2.

The exponential is exact: ``exp(φ) = [φ sin(θ/2)/θ, cos(θ/2)]``, ``θ = |φ|``, by four terms of
its Taylor series below 0.05 rad and by ``sin``/``cos`` above. The recursion itself runs in the
compiled kernel :mod:`imu_dcm._kernels`, shared with the streaming integrator; numba and scipy are
imported on the first call, so importing this module is cheap.
"""

from __future__ import annotations

import math
import warnings
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imu_dcm.arrays import median
from imu_dcm.errors import Diagnostics, GapWarning, ImuDcmWarning, InputError, say
from imu_dcm.integrator.methods import DELTA_METHODS, GAP_FACTOR, METHODS, DeltaMethod, Method
from imu_dcm.so3 import as_quat_xyzw

if TYPE_CHECKING:
    from scipy.spatial.transform import Rotation

__all__ = [
    "DELTA_METHODS",
    "GAP_FACTOR",
    "METHODS",
    "check_samples",
    "find_gaps",
    "gap_message",
    "increments",
    "integrate",
    "integrate_delta",
    "integrate_quat",
]


# ----------------------------------------------------------------------------------------------
# Input checks
# ----------------------------------------------------------------------------------------------


def as_float_array(a: ArrayLike, name: str) -> NDArray[np.float64]:
    arr = np.asarray(a)
    if arr.dtype.kind not in "iuf":
        raise InputError(f"Expected `{name}` real numbers (int or float), got dtype {arr.dtype}")
    return np.asarray(arr, dtype=np.float64)


def check_samples(
    values: ArrayLike,
    t_s: ArrayLike,
    name: str = "omega_b",
    n_extra_stamps: int = 0,
    *,
    stacklevel: int = 3,
    diagnostics: Diagnostics | None = None,
) -> tuple[NDArray, NDArray, NDArray]:
    """Validate ``(N, 3)`` samples and their stamps; return float64 arrays and the steps.

    Parameters
    ----------
    values : array_like, shape (N, 3)
        Samples (rates in rad/s or delta angles in rad), body frame.
    t_s : array_like, shape (N + n_extra_stamps,)
        Stamps, s, strictly increasing.
    name : str
        Name of ``values`` in messages.
    n_extra_stamps : int
        0 for rates (one stamp per sample), 1 for delta angles (stamps bound the intervals).
    stacklevel : int
        The GapWarning's stack level, counted from this function (3: its caller's caller).
    diagnostics : Diagnostics, optional
        Where the GapWarning goes instead of being warned (the caller's result carries it).

    Returns
    -------
    values : ndarray (N, 3), t_s : ndarray (N + n_extra_stamps,), dt_s : ndarray (len(t_s) - 1,)

    Raises
    ------
    InputError
        Wrong shape or dtype, fewer than two stamps, a non-finite value (first index named),
        stamps not strictly increasing (index and values named).

    Notes
    -----
    The checks run in one compiled pass (:func:`imu_dcm._kernels.check_record`): importing numba
    on the first call.

    Warns
    -----
    GapWarning
        A step longer than ``GAP_FACTOR`` times the median step (the first gap's time named).
    """
    v = as_float_array(values, name)
    t = as_float_array(t_s, "t_s")
    if v.ndim != 2 or v.shape[1] != 3:
        raise InputError(f"Expected `{name}` of shape (N, 3), got {v.shape}")
    if t.ndim != 1:
        raise InputError(f"Expected `t_s` of shape (N,), got {t.shape}")
    if len(t) != len(v) + n_extra_stamps:
        want = "N" if n_extra_stamps == 0 else f"N + {n_extra_stamps}"
        raise InputError(
            f"Expected `t_s` of length {want} = {len(v) + n_extra_stamps} "
            f"for `{name}` of shape {v.shape}, got {len(t)}"
        )
    if len(t) < 2 or len(v) < 1:
        raise InputError(f"Expected at least 2 stamps, got {len(t)}")
    from imu_dcm import _kernels as kernel

    v = np.ascontiguousarray(v)
    t = np.ascontiguousarray(t)
    row, stamp, order, dt_min, dt_max = kernel.check_record(v, t, -math.inf)
    if row >= 0:
        raise InputError(f"Expected finite `{name}`, got {v[row].tolist()} at row {row}")
    if stamp >= 0:
        raise InputError(f"Expected finite `t_s`, got t_s[{stamp}] = {float(t[stamp])}")
    if order >= 0:
        raise InputError(
            f"Expected `t_s` strictly increasing, got t_s[{order}] = "
            f"{float(t[order])!r} s after t_s[{order - 1}] = "
            f"{float(t[order - 1])!r} s"
        )
    if dt_max > GAP_FACTOR * dt_min:  # else no step can exceed GAP_FACTOR x the median
        _warn_gaps(t, stacklevel, diagnostics)
    return v, t, np.diff(t)


def find_gaps(t_s: ArrayLike, factor: float = GAP_FACTOR) -> tuple[tuple[float, float], ...]:
    """The gap rule: every step longer than ``factor`` times the median step.

    Parameters
    ----------
    t_s : array_like, shape (N,)
        Stamps, s, increasing.
    factor : float
        A step longer than ``factor`` x the median step is a gap.

    Returns
    -------
    tuple of (t_start_s, length_s)
        Each gap's first stamp (a value of ``t_s``) and its length, s, in stamp order; empty when
        there is none (always with fewer than 3 steps: one gap cannot exceed 5x a median it
        is half of).
    """
    t = np.asarray(t_s, dtype=float)
    dt = np.diff(t)
    # Cheap test first: no step exceeds factor x the median if none exceeds factor x the min.
    if len(dt) < 2 or dt.max() <= factor * dt.min():
        return ()
    big = np.flatnonzero(dt > factor * median(dt))
    return tuple((float(t[i]), float(dt[i])) for i in big)


def gap_message(gaps: tuple[tuple[float, float], ...], factor: float = GAP_FACTOR) -> str:
    """The one-line description of :func:`find_gaps`' result (used by every caller): how many,
    and the first five as ``start s (+length s)``."""
    listed = ", ".join(f"{t0:.3f} s (+{length:.3f} s)" for t0, length in gaps[:5])
    more = f" and {len(gaps) - 5} more" if len(gaps) > 5 else ""
    return f"{len(gaps)} gap(s) longer than {factor:g}x the median step at {listed}{more}"


def _warn_gaps(t: NDArray, stacklevel: int = 3, diagnostics: Diagnostics | None = None) -> None:
    gaps = find_gaps(t)
    if gaps:
        say(diagnostics, gap_message(gaps), GapWarning, stacklevel=stacklevel + 1)


def check_method(method: str, allowed: tuple[str, ...]) -> None:
    if method not in allowed:
        raise InputError(f"Expected method in {allowed}, got {method!r}")


def warn_rotvec_sum(stacklevel: int = 3, diagnostics: Diagnostics | None = None) -> None:
    say(
        diagnostics,
        "method 'rotvec_sum' adds rotation vectors (q_0 ⊗ exp(Σ dt ω)); it is wrong "
        "whenever the rotation axis moves in the body",
        ImuDcmWarning,
        stacklevel=stacklevel,
    )


def to_rotation(q: NDArray) -> Rotation:
    """``Rotation`` of quaternions the kernel keeps unit to rounding (no second normalisation,
    no copy: scipy's would cost ~13 ns/sample at N = 10^6)."""
    from scipy.spatial.transform import Rotation

    return Rotation(q, normalize=False, copy=False)


def _rate_run(
    omega: NDArray, t: NDArray, q_first: NDArray, method: str, emit_phi: bool = False
) -> NDArray:
    """Feed a checked record through the kernel and close it: ``N`` rows (``q0`` first), or
    the ``N - 1`` increments when ``emit_phi``."""
    from imu_dcm import _kernels as kernel

    state = kernel.new_state(q_first, int(Method[method.upper()]))
    out = np.empty((len(t), 4))
    out[0] = q_first
    rows = out[1:]
    k = kernel.feed(state, omega, t, rows, emit_phi)
    rows[k:] = state[kernel.ROWS : kernel.ROWS + 4 * kernel.close(state, emit_phi)].reshape(-1, 4)
    return rows[:, :3] if emit_phi else out


def integrate(
    omega_b: ArrayLike, t_s: ArrayLike, q0: ArrayLike | Rotation, method: str = "magnus4"
) -> Rotation:
    """Attitude ``q_w_b`` at every sample time from body angular rates (batch).

    Parameters
    ----------
    omega_b : array_like, shape (N, 3)
        Angular velocity of the body relative to the world, in body axes, rad/s (a strapdown
        gyro's output), sampled at ``t_s``.
    t_s : array_like, shape (N,)
        Sample times, s, strictly increasing; the spacing may be uneven (each real step is used).
    q0 : array_like (4,) or (3, 3), or scipy ``Rotation``
        Attitude at ``t_s[0]``: ``[x, y, z, w]`` quaternion ``q_w_b``, ``R_w_b`` matrix, or a
        single ``Rotation``.
    method : str
        ``magnus4`` (default, 4th order), ``coning``, ``trapezoid``, ``start``, ``end``
        (the classic DCM recursion) or ``rotvec_sum`` (warns). See the module doc.

    Returns
    -------
    scipy.spatial.transform.Rotation, length N
        Body-to-world attitude at every ``t_s``; element 0 is ``q0``. ``.as_matrix()`` gives the
        DCMs ``R_w_b`` (columns = body axes in world), ``.as_quat()`` the ``[x, y, z, w]``.

    Raises
    ------
    InputError
        Bad shape, dtype, non-finite sample, non-increasing stamps, fewer than 2 samples,
        unknown method, bad ``q0``.

    Warns
    -----
    GapWarning
        A step longer than 5x the median step (:func:`find_gaps`).
    ImuDcmWarning
        ``method="rotvec_sum"``.

    Examples
    --------
    >>> import numpy as np
    >>> t = np.linspace(0.0, 1.0, 101)
    >>> w = np.tile([0.0, 0.0, np.pi / 2], (101, 1))     # 90 deg/s about body z
    >>> integrate(w, t, [0, 0, 0, 1]).as_quat()[-1].round(6)
    array([0.      , 0.      , 0.707107, 0.707107])
    """
    return to_rotation(_integrate_rows(omega_b, t_s, q0, method))


def integrate_quat(
    omega_b: ArrayLike,
    t_s: ArrayLike,
    q0: ArrayLike | Rotation,
    method: str = "magnus4",
    *,
    diagnostics: Diagnostics | None = None,
) -> NDArray[np.float64]:
    """:func:`integrate` as an ``(N, 4)`` array of ``[x, y, z, w]`` quaternions ``q_w_b``
    (unit to rounding, row 0 is ``q0``), without building a scipy ``Rotation``: the replay and
    live commands take this path and never import scipy's rotations. Same arguments, checks and
    warnings as :func:`integrate`; with ``diagnostics`` the warnings go there instead."""
    return _integrate_rows(omega_b, t_s, q0, method, diagnostics)


def _integrate_rows(omega_b, t_s, q0, method: str, diagnostics=None) -> NDArray[np.float64]:
    """Check, then run the kernel: the body of :func:`integrate` and :func:`integrate_quat`
    (their warnings name their caller: three frames up from here)."""
    check_method(method, METHODS)
    omega, t, dt = check_samples(omega_b, t_s, stacklevel=4, diagnostics=diagnostics)
    del dt  # the steps are the checks', not the kernel's: their memory goes before its output's
    q_first = as_quat_xyzw(q0)
    if method == "rotvec_sum":
        warn_rotvec_sum(stacklevel=4, diagnostics=diagnostics)
    return _rate_run(omega, t, q_first, method)


def increments(omega_b: ArrayLike, t_s: ArrayLike, method: str = "magnus4") -> NDArray:
    """Rotation-vector increments ``φ_i`` (rad, body frame) of every step, shape (N - 1, 3).

    The same rules as :func:`integrate` (ghost samples at the ends for ``magnus4``); for
    inspection and tests. ``rotvec_sum`` is not a per-step rule and is refused.
    """
    check_method(method, METHODS[:-1])
    omega, t, _dt = check_samples(omega_b, t_s)
    return np.ascontiguousarray(
        _rate_run(omega, t, np.array([0.0, 0.0, 0.0, 1.0]), method, emit_phi=True)
    )


def integrate_delta(
    dtheta_b: ArrayLike, t_s: ArrayLike, q0: ArrayLike | Rotation, method: str = "one_plus_previous"
) -> Rotation:
    """Attitude from delta angles (integrated gyro increments), as many IMUs output.

    Parameters
    ----------
    dtheta_b : array_like, shape (N, 3)
        ``Δθ_k = ∫ ω_b dt`` over interval ``k = [t_s[k], t_s[k+1]]``, rad, body axes.
    t_s : array_like, shape (N + 1,)
        The ``N + 1`` stamps bounding the ``N`` intervals, s, strictly increasing (uneven allowed).
    q0 : array_like (4,) or (3, 3), or scipy ``Rotation``
        Attitude ``q_w_b`` at ``t_s[0]``.
    method : str
        ``plain`` (``φ_k = Δθ_k``), ``one_plus_previous`` (default, ``φ_k = Δθ_k +
        Δθ_{k-1} × Δθ_k / 12``; the first interval is plain), ``two_sample`` (``φ = Δθ1 + Δθ2 +
        (2/3) Δθ1 × Δθ2`` per pair) or ``three_sample`` (``φ = ΣΔθ + (9/20) Δθ1 × Δθ3 +
        (27/40) Δθ2 × (Δθ3 − Δθ1)`` per triple, equal intervals assumed). For uneven intervals
        the one-plus-previous and two-sample coefficients use the real interval lengths (the
        second Magnus term for a rate linear over the intervals involved).

    Returns
    -------
    scipy.spatial.transform.Rotation
        ``plain`` / ``one_plus_previous``: N + 1 attitudes, at every stamp. ``two_sample`` /
        ``three_sample``: ``N / m + 1`` attitudes at ``t_s[::m]`` (m = 2 or 3), the stamps
        ending each set. Element 0 is ``q0``.

    Raises
    ------
    InputError
        As :func:`integrate`; also ``N`` not a multiple of the set size m.
    """
    check_method(method, DELTA_METHODS)
    dtheta, _t, dt = check_samples(dtheta_b, t_s, name="dtheta_b", n_extra_stamps=1)
    m = {"two_sample": 2, "three_sample": 3}.get(method, 1)
    if len(dtheta) % m:
        raise InputError(
            f"Expected the number of intervals to be a multiple of {m} for "
            f"method {method!r}, got {len(dtheta)}"
        )
    if method == "three_sample":
        sets = dt.reshape(-1, 3)
        spread = float(np.max(np.ptp(sets, axis=1) / sets.mean(axis=1)))
        if spread > 0.01:
            warnings.warn(
                f"method 'three_sample' assumes equal intervals within a set; they "
                f"differ by up to {100 * spread:.3g} % here",
                ImuDcmWarning,
                stacklevel=2,
            )
    from imu_dcm import _kernels as kernel

    out = np.empty((len(dtheta) // m + 1, 4))
    q_first = np.ascontiguousarray(as_quat_xyzw(q0), dtype=np.float64)
    kernel.feed_delta(q_first, dtheta, dt, int(DeltaMethod[method.upper()]), out)
    return to_rotation(out)

"""Batch DCM integration of body rates: ``R_{i+1} = R_i · exp([φ_i×])`` (DESIGN.md §4).

Conventions (DESIGN.md §3): ``q_w_b`` / ``R_w_b`` map body to world (active rotations, columns of
``R_w_b`` are the body axes in world); quaternions are Hamilton, scalar-last ``[x, y, z, w]``;
``omega_b`` is the body rate relative to the world in body axes, rad/s; increments multiply on the
**right**, ``q_{i+1} = q_i ⊗ exp(φ_i)``; time ``t_s`` in seconds, each step uses its own
``dt_i = t_{i+1} - t_i``.

Increment rules ``φ_i`` over step ``[t_i, t_{i+1}]`` (``h = dt_i``):

=============  ===================================================================  =====
method         ``φ_i``                                                              order
=============  ===================================================================  =====
``start``      ``h ω_i``                                                            1
``end``        ``h ω_{i+1}`` (the reference document's rule, its eq. 19)            1
``trapezoid``  ``h (ω_i + ω_{i+1}) / 2``                                            2
``coning``     trapezoid ``+ h²/12 ω_i × ω_{i+1}``                                  2
``magnus4``    ``h/6 (ω_i + 4 ω_m + ω_{i+1}) + h²/12 ω_i × ω_{i+1}``                4
``rotvec_sum`` ``q_i = q_0 ⊗ exp(Σ_{j<i} h_j ω_j)`` (eq. 13; wrong unless rotations
               commute — kept to show the failure, warns)                          —
=============  ===================================================================  =====

``ω_m`` is the rate at mid-step from the cubic through ``ω_{i-1..i+2}`` at their real stamps
(one sample of look-ahead). At the ends of the record the missing neighbour is a *ghost* sample
extrapolated from the cubic through the first (last) four samples, so the end steps use the
one-sided cubic; with 2 or 3 samples the polynomial degree drops to 1 or 2.

The exponential is exact: ``exp(φ) = [φ sin(θ/2)/θ, cos(θ/2)]``, ``θ = |φ|``, evaluated by its
Taylor series to full double precision for ``θ <= 0.5`` rad and by ``sin``/``cos`` above. The
products run as a blocked prefix product (:mod:`imu_dcm.scan`), then every quaternion is
normalised once.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
from numpy.lib.stride_tricks import as_strided
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from imu_dcm.errors import GapWarning, ImuDcmWarning, InputError
from imu_dcm.scan import (
    BLOCK,
    CHUNK_SAMPLES,
    blocked_prefix_product,
    prefix_product,
    prefix_product_parts,
    quat_mul_parts,
)
from imu_dcm.so3 import as_quat_xyzw

__all__ = [
    "DELTA_METHODS",
    "GAP_FACTOR",
    "METHODS",
    "increments",
    "integrate",
    "integrate_delta",
]

#: Rate-input methods, in order of increasing accuracy (``rotvec_sum`` last: a counter-example).
METHODS = ("start", "end", "trapezoid", "coning", "magnus4", "rotvec_sum")
#: Delta-angle methods of :func:`integrate_delta`.
DELTA_METHODS = ("plain", "one_plus_previous", "two_sample", "three_sample")
#: A step longer than this many median steps is reported as a gap (GapWarning).
GAP_FACTOR = 5.0

# exp(φ) by the series of sin(θ/2)/θ in θ² = |φ|² up to this bound (θ <= 0.5 rad), where seven
# terms leave out θ¹⁴/(2 4⁷ 15!) < 3e-21, far below double precision.
_POLY_THETA2_MAX = 0.25
_SINC_HALF = tuple((-1) ** k / (2 * 4 ** k * math.factorial(2 * k + 1)) for k in range(7))
# Below this θ² (θ < 0.05 rad) the float (streaming) path uses four series terms instead of
# sqrt/sin/cos: the first terms left out, θ⁸/(4⁴ 8!) < 4e-18 and θ⁸/(2 4⁴ 9!), are below rounding.
_SERIES_THETA2_FLOAT = 2.5e-3


# ----------------------------------------------------------------------------------------------
# Input checks
# ----------------------------------------------------------------------------------------------

def _as_float_array(a: ArrayLike, name: str) -> NDArray[np.float64]:
    arr = np.asarray(a)
    if arr.dtype.kind not in "iuf":
        raise InputError(f"Expected `{name}` real numbers (int or float), got dtype {arr.dtype}")
    return np.asarray(arr, dtype=np.float64)


def _first_bad_row(ok_rows: NDArray[np.bool_]) -> int:
    return int(np.flatnonzero(~ok_rows)[0])


def check_samples(values: ArrayLike, t_s: ArrayLike, name: str = "omega_b",
                  n_extra_stamps: int = 0) -> tuple[NDArray, NDArray, NDArray]:
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

    Returns
    -------
    values : ndarray (N, 3), t_s : ndarray (N + n_extra_stamps,), dt_s : ndarray (len(t_s) - 1,)

    Raises
    ------
    InputError
        Wrong shape or dtype, fewer than two stamps, a non-finite value (first index named),
        stamps not strictly increasing (index and values named).

    Warns
    -----
    GapWarning
        A step longer than ``GAP_FACTOR`` times the median step (the first gap's time named).
    """
    v = _as_float_array(values, name)
    t = _as_float_array(t_s, "t_s")
    if v.ndim != 2 or v.shape[1] != 3:
        raise InputError(f"Expected `{name}` of shape (N, 3), got {v.shape}")
    if t.ndim != 1:
        raise InputError(f"Expected `t_s` of shape (N,), got {t.shape}")
    if len(t) != len(v) + n_extra_stamps:
        want = "N" if n_extra_stamps == 0 else f"N + {n_extra_stamps}"
        raise InputError(f"Expected `t_s` of length {want} = {len(v) + n_extra_stamps} "
                         f"for `{name}` of shape {v.shape}, got {len(t)}")
    if len(t) < 2 or len(v) < 1:
        raise InputError(f"Expected at least 2 stamps, got {len(t)}")
    if not np.isfinite(v).all():
        i = _first_bad_row(np.isfinite(v).all(axis=1))
        raise InputError(f"Expected finite `{name}`, got {v[i].tolist()} at row {i}")
    if not np.isfinite(t).all():
        i = _first_bad_row(np.isfinite(t))
        raise InputError(f"Expected finite `t_s`, got t_s[{i}] = {float(t[i])}")
    dt = np.diff(t)
    if not (dt > 0.0).all():
        i = int(np.flatnonzero(~(dt > 0.0))[0]) + 1
        raise InputError(f"Expected `t_s` strictly increasing, got t_s[{i}] = {float(t[i])!r} s "
                         f"after t_s[{i - 1}] = {float(t[i - 1])!r} s")
    _warn_gaps(t, dt)
    return np.ascontiguousarray(v), t, dt


def _warn_gaps(t: NDArray, dt: NDArray) -> None:
    # Cheap test first: no step exceeds GAP_FACTOR x the median if it does not exceed it x the min.
    if dt.max() <= GAP_FACTOR * dt.min():
        return
    med = float(np.median(dt))
    gaps = np.flatnonzero(dt > GAP_FACTOR * med)
    if len(gaps):
        i = int(gaps[0])
        warnings.warn(
            f"Found {len(gaps)} gap(s) longer than {GAP_FACTOR:g}x the median step {med:.6g} s; "
            f"the first after t_s = {t[i]:.6f} s lasts {dt[i]:.6g} s",
            GapWarning, stacklevel=3)


def _check_method(method: str, allowed: tuple[str, ...]) -> None:
    if method not in allowed:
        raise InputError(f"Expected method in {allowed}, got {method!r}")


# ----------------------------------------------------------------------------------------------
# The formulas (shape-agnostic: floats for streaming, arrays for batch)
# ----------------------------------------------------------------------------------------------

def phi_parts(method: str, w_m: tuple, w_0: tuple, w_1: tuple, w_2: tuple,
              h_m, h_0, h_p) -> tuple:
    """Rotation-vector increment ``φ_i`` (rad, body frame) of one step, component-wise.

    Shape-agnostic (floats or equal-shape arrays): the one place the increment formulas live
    (with ``magnus4_weights`` and ``magnus4_phi`` next to it), used by the batch integrator and
    by :class:`imu_dcm.streaming.DcmIntegrator`.

    Parameters
    ----------
    method : str
        One of ``start``, ``end``, ``trapezoid``, ``coning``, ``magnus4``.
    w_m, w_0, w_1, w_2 : tuple of 3
        Rates ``ω_{i-1}, ω_i, ω_{i+1}, ω_{i+2}`` (rad/s, body); only ``magnus4`` reads
        ``w_m`` and ``w_2``.
    h_m, h_0, h_p : float or array
        Step lengths ``dt_{i-1}, dt_i, dt_{i+1}`` (s); only ``magnus4`` reads ``h_m``, ``h_p``.

    Returns
    -------
    tuple of 3
        ``φ_i`` components, rad.
    """
    # Dispatch in order of use (magnus4 is the default); products written out: the streaming
    # integrator calls this with floats once per sample (magnus4: its two halves, below).
    if method == "magnus4":
        return magnus4_phi(magnus4_weights(h_m, h_0, h_p), w_m, w_0, w_1, w_2)
    x0, y0, z0 = w_0
    x1, y1, z1 = w_1
    if method == "trapezoid":
        half = 0.5 * h_0
        return (half * (x0 + x1), half * (y0 + y1), half * (z0 + z1))
    if method == "coning":
        # Trapezoid plus the second Magnus term for rates linear over the step.
        half = 0.5 * h_0
        k = h_0 * h_0 * (1.0 / 12.0)
        kx, ky, kz = k * x0, k * y0, k * z0
        return (half * (x0 + x1) + (ky * z1 - kz * y1),
                half * (y0 + y1) + (kz * x1 - kx * z1),
                half * (z0 + z1) + (kx * y1 - ky * x1))
    if method == "start":
        return (h_0 * x0, h_0 * y0, h_0 * z0)
    if method == "end":
        return (h_0 * x1, h_0 * y1, h_0 * z1)
    raise InputError(f"Expected method in {METHODS[:-1]}, got {method!r}")


# magnus4 in two halves, so the streaming integrator can memoise the weights (they depend on
# the three step lengths only, and float stamps from a uniform clock repeat a few triples).
# Simpson with the cubic mid-step rate, written as weights on the four samples:
# φ = -c_m ω_{i-1} + c_0 ω_i + c_1 ω_{i+1} - c_2 ω_{i+2} + k ω_i × ω_{i+1},  k = h²/12.
# Uniform steps give (-1, 13, 13, -1) h / 24; the weights sum to h.

def magnus4_weights(h_m, h_0, h_p) -> tuple:
    """Weights ``(c_m, c_0, c_1, c_2, k)`` of the ``magnus4`` increment for the steps
    ``dt_{i-1}, dt_i, dt_{i+1}`` (floats or arrays); see :func:`magnus4_phi`."""
    u = 0.5 * h_0
    a_m = u + h_m
    a_p = u + h_p
    s_m0 = h_m + h_0
    s_0p = h_0 + h_p
    s_all = s_m0 + h_p
    h2 = h_0 * h_0
    h6 = h_0 * (1.0 / 6.0)
    g = h2 * h6
    c_m = g * a_p / (h_m * s_m0 * s_all)
    c_2 = g * a_m / (h_p * s_0p * s_all)
    p = h_0 * a_m * a_p * (1.0 / 3.0)
    c_0 = h6 + p / (h_m * s_0p)
    c_1 = h6 + p / (h_p * s_m0)
    return (c_m, c_0, c_1, c_2, h2 * (1.0 / 12.0))


def magnus4_phi(weights: tuple, w_m: tuple, w_0: tuple, w_1: tuple, w_2: tuple) -> tuple:
    """``magnus4`` increment ``φ_i`` from :func:`magnus4_weights` and the rates
    ``ω_{i-1}, ω_i, ω_{i+1}, ω_{i+2}`` (component tuples of floats or arrays)."""
    c_m, c_0, c_1, c_2, k = weights
    xm, ym, zm = w_m
    x0, y0, z0 = w_0
    x1, y1, z1 = w_1
    x2, y2, z2 = w_2
    kx, ky, kz = k * x0, k * y0, k * z0
    return (c_0 * x0 + c_1 * x1 - c_m * xm - c_2 * x2 + (ky * z1 - kz * y1),
            c_0 * y0 + c_1 * y1 - c_m * ym - c_2 * y2 + (kz * x1 - kx * z1),
            c_0 * z0 + c_1 * z1 - c_m * zm - c_2 * z2 + (kx * y1 - ky * x1))


def _horner(t2, coefs: tuple):
    acc = coefs[-1]
    for c in coefs[-2::-1]:
        acc = acc * t2 + c
    return acc


def exp_parts(px, py, pz) -> tuple:
    """Quaternion ``exp(φ) = [φ sin(θ/2)/θ, cos(θ/2)]`` component-wise, exact.

    Floats use ``math.sin``/``math.cos`` (series below 0.05 rad); arrays use the Taylor series
    to full precision when every ``θ <= 0.5`` rad and ``np.sin``/``np.cos`` otherwise.

    Parameters
    ----------
    px, py, pz : float or array
        Rotation vector components, rad.

    Returns
    -------
    tuple (x, y, z, w)
    """
    t2 = px * px + py * py + pz * pz
    if type(t2) is float or isinstance(t2, float):  # the first test: fast path for streaming
        if t2 < _SERIES_THETA2_FLOAT:
            s = 0.5 + t2 * (-1.0 / 48.0 + t2 * (1.0 / 3840.0 + t2 * (-1.0 / 645120.0)))
            c = 1.0 + t2 * (-0.125 + t2 * (1.0 / 384.0 + t2 * (-1.0 / 46080.0)))
        else:
            theta = math.sqrt(t2)
            s = math.sin(0.5 * theta) / theta
            c = math.cos(0.5 * theta)
        return (px * s, py * s, pz * s, c)
    t2 = np.asarray(t2)
    t2_max = float(t2.max()) if t2.size else 0.0
    big = None
    if t2_max > _POLY_THETA2_MAX:  # some steps above 0.5 rad: series on the others only
        big = t2 > _POLY_THETA2_MAX
        t2 = np.where(big, 0.0, t2)
        t2_max = _POLY_THETA2_MAX
    # As many series terms as the largest angle needs: the first one left out is < 1e-17.
    n_terms = next((n for n in range(1, len(_SINC_HALF))
                    if abs(_SINC_HALF[n]) * t2_max ** n < 1e-17), len(_SINC_HALF))
    s = _horner(t2, _SINC_HALF[:n_terms])
    # cos(θ/2) = sqrt(1 - sin²(θ/2)) for θ <= 0.5: exact to rounding, and makes |q| = 1.
    c = np.sqrt(1.0 - t2 * s * s)
    if big is not None:
        theta = np.sqrt(px[big] ** 2 + py[big] ** 2 + pz[big] ** 2)
        s[big] = np.sin(0.5 * theta) / theta
        c[big] = np.cos(0.5 * theta)
    return (px * s, py * s, pz * s, c)


# ----------------------------------------------------------------------------------------------
# Rates -> attitudes
# ----------------------------------------------------------------------------------------------

def _extrapolate(t_nodes: NDArray, w_nodes: NDArray, t: float) -> NDArray:
    """Value at ``t`` of the polynomial through ``(t_nodes, w_nodes)`` (Lagrange form)."""
    tn = t_nodes.tolist()
    weights = []
    for j, tj in enumerate(tn):
        lj = 1.0
        for i, ti in enumerate(tn):
            if i != j:
                lj *= (t - ti) / (tj - ti)
        weights.append(lj)
    return np.asarray(weights) @ w_nodes


def ghost_start(omega: NDArray, t: NDArray) -> tuple[NDArray, float]:
    """Ghost sample before the record: (rate at ``t_0 - dt_0`` on the cubic through the first
    four samples, the ghost step ``dt_0``)."""
    h = float(t[1] - t[0])
    n = min(len(t), 4)
    return _extrapolate(t[:n], omega[:n], float(t[0]) - h), h


def ghost_end(omega: NDArray, t: NDArray) -> tuple[NDArray, float]:
    """Ghost sample after the record, mirrored: rate at ``t_{N-1} + dt_{N-2}``, step
    ``dt_{N-2}``."""
    h = float(t[-1] - t[-2])
    n = min(len(t), 4)
    return _extrapolate(t[-n:], omega[-n:], float(t[-1]) + h), h


def rate_quats(omega: NDArray, t: NDArray, dt: NDArray, q_first: NDArray, method: str,
               lo: int = 0, hi: int | None = None, block: int = BLOCK) -> NDArray[np.float64]:
    """Attitudes at samples ``lo..hi`` from validated rates (internal, vectorised).

    Step ``i`` (``lo <= i < hi``) uses samples ``i-1..i+2``; sample ``-1`` (when ``lo == 0``)
    and sample ``N`` (when ``hi == N - 1``) are the ghost samples.

    Parameters
    ----------
    omega : ndarray (N, 3), t : ndarray (N,), dt : ndarray (N - 1,)
        Validated rates (rad/s, body), stamps (s) and steps (s).
    q_first : ndarray (4,)
        Attitude ``[x, y, z, w]`` at sample ``lo``.
    method : str
        A method of ``METHODS`` except ``rotvec_sum``.
    lo, hi : int
        First and last sample of the output (``hi`` defaults to ``N - 1``).

    Returns
    -------
    ndarray, shape (hi - lo + 1, 4)
    """
    n = len(t)
    hi = n - 1 if hi is None else hi
    m = hi - lo
    if m <= 0:
        return np.asarray(q_first, dtype=float)[None, :].copy()
    K = int(block)
    small = m <= CHUNK_SAMPLES  # fits in cache: natural order, no block layout needed
    nb = -(-m // K)
    length = m if small else nb * K  # steps in the padded layout
    # Padded stencil arrays, struct-of-arrays: wpad[:, j] = ω_{lo-1+j}, hpad[j] = dt_{lo-1+j}.
    wpad = np.empty((3, length + 3))
    hpad = np.empty(length + 2)
    j0 = max(lo - 1, 0)
    j1 = min(hi + 2, n)  # samples lo-1 .. hi+1 that exist
    off = j0 - (lo - 1)
    wpad[:, off:off + j1 - j0] = omega[j0:j1].T
    hj1 = min(hi + 1, n - 1)
    hpad[off:off + hj1 - j0] = dt[j0:hj1]
    ghosts = method == "magnus4"  # only its stencil reaches beyond the step
    if lo == 0:
        wpad[:, 0], hpad[0] = ghost_start(omega, t) if ghosts else (omega[0], dt[0])
    tail_w = off + j1 - j0
    tail_h = off + hj1 - j0
    if hi == n - 1 and ghosts:
        wpad[:, tail_w], hpad[tail_h] = ghost_end(omega, t)
        tail_w += 1
        tail_h += 1
    # Padding of the last block (its steps are replaced by the identity): any finite value.
    wpad[:, tail_w:] = wpad[:, tail_w - 1:tail_w]
    hpad[tail_h:] = hpad[tail_h - 1]
    if small:
        rows = [tuple(wpad[c, r:r + m] for c in range(3)) for r in range(4)]
        phi = phi_parts(method, *rows, hpad[0:m], hpad[1:m + 1], hpad[2:m + 2])
        return prefix_product_parts(q_first, exp_parts(*phi))

    def fill(b0: int, b1: int) -> tuple:
        # Gather blocks b0..b1 with their stencil halo: W[c, r, b] = wpad[c, b K + r].
        nbc = b1 - b0
        W = np.array(as_strided(wpad[:, b0 * K:], shape=(3, K + 3, nbc),
                                strides=(wpad.strides[0], 8, 8 * K), writeable=False))
        H = np.array(as_strided(hpad[b0 * K:], shape=(K + 2, nbc), strides=(8, 8 * K),
                                writeable=False))
        rows = [(W[0, r:r + K], W[1, r:r + K], W[2, r:r + K]) for r in range(4)]
        phi = phi_parts(method, *rows, H[0:K], H[1:K + 1], H[2:K + 2])
        return exp_parts(*phi)

    return blocked_prefix_product(q_first, m, fill, block=K)


def _rotvec_sum_quats(omega: NDArray, dt: NDArray, q0: NDArray) -> NDArray:
    """Eq. 13 of the reference document: ``q_i = q_0 ⊗ exp(Σ_{j<i} dt_j ω_j)``."""
    phi = np.zeros((len(omega), 3))
    np.cumsum(omega[:-1] * dt[:, None], axis=0, out=phi[1:])
    e = exp_parts(phi[:, 0], phi[:, 1], phi[:, 2])
    q = quat_mul_parts(tuple(q0), e)
    return np.stack(q, axis=-1)


def _warn_rotvec_sum() -> None:
    warnings.warn("method 'rotvec_sum' (the reference document's eq. 13) adds rotation vectors; "
                  "it is wrong whenever the rotation axis moves in the body", ImuDcmWarning,
                  stacklevel=3)


def _to_rotation(q: NDArray) -> Rotation:
    # The quaternions are unit to ~1e-16 already (normalised at the end of the scan): skip
    # scipy's second normalisation and copy (it costs ~13 ns/sample at N = 10^6).
    return Rotation(q, normalize=False, copy=False)


def integrate(omega_b: ArrayLike, t_s: ArrayLike, q0: ArrayLike | Rotation,
              method: str = "magnus4") -> Rotation:
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
        (the reference document's eq. 19) or ``rotvec_sum`` (eq. 13, warns). See the module doc.

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
        A step longer than 5x the median step.
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
    _check_method(method, METHODS)
    omega, t, dt = check_samples(omega_b, t_s)
    q_first = as_quat_xyzw(q0)
    if method == "rotvec_sum":
        _warn_rotvec_sum()
        return _to_rotation(_rotvec_sum_quats(omega, dt, q_first))
    return _to_rotation(rate_quats(omega, t, dt, q_first, method))


def increments(omega_b: ArrayLike, t_s: ArrayLike, method: str = "magnus4") -> NDArray:
    """Rotation-vector increments ``φ_i`` (rad, body frame) of every step, shape (N - 1, 3).

    The same rules as :func:`integrate` (ghost samples at the ends for ``magnus4``); for
    inspection and tests. ``rotvec_sum`` is not a per-step rule and is refused.
    """
    _check_method(method, METHODS[:-1])
    omega, t, dt = check_samples(omega_b, t_s)
    n = len(t)
    gs, hs = ghost_start(omega, t)
    ge, he = ghost_end(omega, t)
    w = np.vstack([gs, omega, ge])
    h = np.concatenate([[hs], dt, [he]])
    cols = [tuple(w[r:r + n - 1, c] for c in range(3)) for r in range(4)]
    phi = phi_parts(method, *cols, h[0:n - 1], h[1:n], h[2:n + 1])
    return np.stack(phi, axis=-1)


# ----------------------------------------------------------------------------------------------
# Delta angles
# ----------------------------------------------------------------------------------------------

def delta_rotvecs(dtheta: NDArray, dt: NDArray, method: str) -> NDArray:
    """Rotation vectors of the attitude updates from delta angles (internal, vectorised).

    ``plain`` and ``one_plus_previous`` give one update per interval; ``two_sample`` and
    ``three_sample`` one per set of 2 or 3 intervals. Coefficients for uneven intervals assume
    the rate is linear over the intervals involved (exact coefficients derived in the module
    tests reduce to 1/12 and 2/3 for equal intervals).
    """
    if method == "plain":
        return dtheta.copy()
    if method == "one_plus_previous":
        # φ_k = Δθ_k + c_k Δθ_{k-1} × Δθ_k, c_k = b²/(6 a (a + b)), a = dt_{k-1}, b = dt_k:
        # the second Magnus term for a rate linear over both intervals (1/12 when a = b).
        phi = dtheta.copy()
        if len(dtheta) > 1:
            a, b = dt[:-1], dt[1:]
            c = (b * b / (6.0 * a * (a + b)))[:, None]
            phi[1:] += c * np.cross(dtheta[:-1], dtheta[1:])
        return phi
    if method == "two_sample":
        d1, d2 = dtheta[0::2], dtheta[1::2]
        a, b = dt[0::2], dt[1::2]
        T = a + b
        # (2/3) for equal intervals: T²/(6 a b) Δθ1 × Δθ2 (rate linear over the set).
        return d1 + d2 + (T * T / (6.0 * a * b))[:, None] * np.cross(d1, d2)
    if method == "three_sample":
        d1, d2, d3 = dtheta[0::3], dtheta[1::3], dtheta[2::3]
        return (d1 + d2 + d3 + (9.0 / 20.0) * np.cross(d1, d3)
                + (27.0 / 40.0) * np.cross(d2, d3 - d1))
    raise InputError(f"Expected method in {DELTA_METHODS}, got {method!r}")


def integrate_delta(dtheta_b: ArrayLike, t_s: ArrayLike, q0: ArrayLike | Rotation,
                    method: str = "one_plus_previous") -> Rotation:
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
        the one-plus-previous and two-sample coefficients use the real interval lengths.

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
    _check_method(method, DELTA_METHODS)
    dtheta, _t, dt = check_samples(dtheta_b, t_s, name="dtheta_b", n_extra_stamps=1)
    m = {"two_sample": 2, "three_sample": 3}.get(method, 1)
    if len(dtheta) % m:
        raise InputError(f"Expected the number of intervals to be a multiple of {m} for "
                         f"method {method!r}, got {len(dtheta)}")
    if method == "three_sample":
        sets = dt.reshape(-1, 3)
        spread = float(np.max(np.ptp(sets, axis=1) / sets.mean(axis=1)))
        if spread > 0.01:
            warnings.warn(f"method 'three_sample' assumes equal intervals within a set; they "
                          f"differ by up to {100 * spread:.3g} % here", ImuDcmWarning,
                          stacklevel=2)
    phi = delta_rotvecs(dtheta, dt, method)
    dq = np.stack(exp_parts(phi[:, 0], phi[:, 1], phi[:, 2]), axis=-1)
    return _to_rotation(prefix_product(as_quat_xyzw(q0), dq))

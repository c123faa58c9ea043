"""Blocked prefix product of quaternions: ``q_{i+1} = q_i ⊗ dq_i`` for all ``i`` without a
per-sample Python loop (DESIGN.md §4, "Speed").

The product is sequential, so it is reorganised for numpy:

1. The ``M`` increments are laid out as ``nb`` blocks of ``K`` consecutive steps, in
   struct-of-arrays form: component arrays of shape ``(K, nb)``, row ``k`` holding step
   ``i = b K + k`` of every block ``b``. Inside, a quaternion is a pair of complex numbers
   ``a = w + 1j z``, ``b = x + 1j y`` (its SU(2) form), which halves the arithmetic calls.
2. **Local scan**: ``K - 1`` vectorised products along the rows give every block's inclusive
   prefix ``R[k, b] = dq_{bK} ⊗ … ⊗ dq_{bK+k}`` (all blocks side by side).
3. **Recursion** on the block totals ``R[K-1, :]`` gives the attitude ``E[b]`` at the start of each
   block (the same algorithm on ``nb`` elements, down to a short input, below).
4. **Apply**: ``q_{bK+k+1} = E[b] ⊗ R[k, b]`` in one vectorised product, written as
   ``[x, y, z, w]`` rows, then every quaternion is normalised once.

Short inputs (up to 8192 steps: streaming chunks, the recursion's last level) skip the blocks:
in pair form the recursion is a unit lower-triangular banded linear system, solved by LAPACK's
banded forward substitution (``ztbtrs``), which runs the plain loop's products in compiled code
(1000 steps: 25 µs, against 65 µs blocked and 200 µs as a Python loop); up to 16 steps, the
Python loop. Steps 1-2 and 4 run over chunks of blocks whose arrays fit in the CPU cache. Every product is the
Hamilton product of scalar-last ``[x, y, z, w]`` quaternions; increments multiply on the right.
The result agrees with the sequential loop to rounding (1e-14 over 5000 steps, tested).

Importing this module raises glibc's malloc trim threshold (see ``_keep_freed_heap``; opt out
with ``IMU_DCM_KEEP_MALLOC=1``).
"""

from __future__ import annotations

import ctypes
import os
import sys
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.linalg.lapack import ztbtrs as _ztbtrs

from imu_dcm.errors import InputError


def _keep_freed_heap() -> bool:
    """Raise glibc's malloc trim and mmap thresholds (Linux/glibc only; a no-op elsewhere).

    The vectorised formulas create many short-lived arrays of 64-512 kB per chunk. With glibc's
    defaults every chunk's temporaries are handed back to the kernel when freed (heap trimming
    above 128 kB) and faulted in again, zeroed, by the next chunk: measured here, the magnus4
    increments ran at 83 ns/sample instead of 13 and a 10^6-sample batch 30 % slower. Keeping up
    to 64 MB of freed heap in the process avoids that. Set ``IMU_DCM_KEEP_MALLOC=1`` in the
    environment to leave malloc untouched.
    """
    if os.environ.get("IMU_DCM_KEEP_MALLOC") or not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    m_trim_threshold, m_mmap_threshold = -1, -3
    return bool(mallopt(m_trim_threshold, 64 << 20) and mallopt(m_mmap_threshold, 32 << 20))


MALLOC_TUNED = _keep_freed_heap()

__all__ = [
    "BLOCK",
    "CHUNK_SAMPLES",
    "blocked_prefix_product",
    "prefix_product",
    "prefix_product_parts",
    "quat_mul_parts",
]

#: Default block length K (steps per block). Measured on 10^6 steps (benchmarks/core_speed.py):
#: short blocks keep the rows long, the number of numpy calls per sample low.
BLOCK = 8
#: Samples per cache chunk of blocks (complex arrays of 256 kB); shorter inputs are not split
#: into chunks.
CHUNK_SAMPLES = 1 << 14
# Prefix products of at most this many steps: a plain loop over Python complex numbers (~0.2 µs
# per step); up to _BANDED steps: banded forward substitution in LAPACK (~5 µs + 23 ns per step);
# longer: the blocked scan. Crossovers measured (25 µs for 1000 steps: 200 µs loop, 65 µs blocked).
_SEQUENTIAL = 16
_BANDED = 8192

_ONES4 = np.ones(4)

Parts = tuple  # 4 component arrays (or floats) x, y, z, w
FillFn = Callable[[int, int], Parts]


def quat_mul_parts(a: Parts, b: Parts) -> Parts:
    """Hamilton product ``a ⊗ b`` of quaternions given as component tuples ``(x, y, z, w)``.

    Shape-agnostic: the components may be floats or broadcastable arrays. ``a ⊗ b`` applies ``b``
    first, then ``a``; for ``q_w_b ⊗ dq`` the increment ``dq`` is a body-frame rotation.

    Parameters
    ----------
    a, b : tuple of 4 floats or arrays
        ``(x, y, z, w)`` components.

    Returns
    -------
    tuple of 4 floats or arrays
    """
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz)


# Internally a quaternion is a pair of complex numbers (Cayley-Dickson form with k as the
# imaginary unit): q = (w + z k) + (x + y k) i  ->  a = w + 1j z, b = x + 1j y, and
#     (a1, b1) ⊗ (a2, b2) = (a1 a2 - b1 conj(b2),  a1 b2 + b1 conj(a2)),
# six complex operations instead of 28 real ones (fewer numpy calls, less memory traffic).

def _to_pair(x, y, z, w) -> tuple[NDArray, NDArray]:
    a = np.empty(np.shape(w), dtype=complex)
    b = np.empty(np.shape(x), dtype=complex)
    a.real, a.imag = w, z
    b.real, b.imag = x, y
    return a, b


def _mul_into(a1, b1, a2, b2, ca2, cb2, out_a, out_b, tmp) -> None:
    """``(out_a, out_b) = (a1, b1) ⊗ (a2, b2)``; ``ca2, cb2`` are ``conj(a2), conj(b2)``."""
    np.multiply(a1, a2, out=out_a)
    np.multiply(b1, cb2, out=tmp)
    np.subtract(out_a, tmp, out=out_a)
    np.multiply(a1, b2, out=out_b)
    np.multiply(b1, ca2, out=tmp)
    np.add(out_b, tmp, out=out_b)


def _sequential_pair(a0: complex, b0: complex, da: NDArray, db: NDArray):
    """Plain loop over Python complex numbers (short inputs); returns (M + 1,) arrays."""
    a, b = complex(a0), complex(b0)
    out_a = [a]
    out_b = [b]
    for x, y in zip(da.tolist(), db.tolist()):
        a, b = a * x - b * y.conjugate(), a * y + b * x.conjugate()
        out_a.append(a)
        out_b.append(b)
    return np.array(out_a), np.array(out_b)


def _local_scan(da: NDArray, db: NDArray, r: NDArray) -> None:
    """In-block inclusive prefix ``r[k] = d[0] ⊗ ... ⊗ d[k]`` along rows of (K, nb) arrays.

    ``r`` has shape (K, 2, nb): ``r[k, 0]`` = a, ``r[k, 1]`` = b. Each step is the row vector
    ``(a, b)`` of the running product times the SU(2) matrix ``[[a2, b2], [-conj(b2), conj(a2)]]``
    of the increment: two numpy calls (a broadcast product and a sum) per step.
    """
    K, nb = da.shape
    m = np.empty((K, 2, 2, nb), dtype=complex)
    m[:, 0, 0] = da
    m[:, 0, 1] = db
    np.negative(db.conj(), out=m[:, 1, 0])
    np.conjugate(da, out=m[:, 1, 1])
    r[0, 0] = da[0]
    r[0, 1] = db[0]
    prod = np.empty((2, 2, nb), dtype=complex)
    for k in range(1, K):
        np.multiply(r[k - 1][:, None, :], m[k], out=prod)
        np.add(prod[0], prod[1], out=r[k])


def _banded_pair(a0: complex, b0: complex, da: NDArray, db: NDArray):
    """The prefix product solved as the linear system it is (short inputs); returns (M + 1,).

    With the unknowns ``u = [a_0, b_0, a_1, b_1, ..., a_M, b_M]`` the recursion
    ``a_{i+1} = a_i da_i - b_i conj(db_i)``, ``b_{i+1} = a_i db_i + b_i conj(da_i)`` is
    ``L u = [a0, b0, 0, ...]`` with ``L`` unit lower triangular of bandwidth 3. LAPACK's banded
    forward substitution (``ztbtrs``) runs the same products in the same order as the plain loop
    (bit for bit here), in compiled code: ~6 ns per unknown plus ~10 numpy calls to build ``L``.
    """
    M = len(da)
    # LAPACK band storage ab[d, j] = L[j + d, j], in Fortran order: ab = abt.reshape(-1, 4).T,
    # abt[i, c, d] = L[2 i + c + d, 2 i + c] (column of a_i: c = 0, of b_i: c = 1).
    abt = np.empty((M + 1, 2, 4), dtype=complex)
    abt[:, :, 0] = 1.0  # the unit diagonal (not read: diag="U")
    abt[:, 0, 1] = 0.0  # b_i does not depend on a_i
    np.negative(da, out=abt[:M, 0, 2])  # a_{i+1} -= a_i da_i
    np.negative(db, out=abt[:M, 0, 3])  # b_{i+1} -= a_i db_i
    np.conjugate(db, out=abt[:M, 1, 1])  # a_{i+1} -= b_i (-conj(db_i))
    np.conjugate(da, out=abt[:M, 1, 2])
    np.negative(abt[:M, 1, 2], out=abt[:M, 1, 2])  # b_{i+1} -= b_i conj(da_i)
    abt[:, 1, 3] = 0.0  # a_{i+2} does not depend on b_i
    abt[M, 0, 2:] = 0.0  # outside the matrix (not read)
    rhs = np.zeros(2 * M + 2, dtype=complex)
    rhs[0], rhs[1] = a0, b0
    u = _ztbtrs(abt.reshape(2 * M + 2, 4).T, rhs, uplo="L", trans="N", diag="U",
                overwrite_b=1)[0]
    return u[0::2], u[1::2]


def _prefix_pair(a0: complex, b0: complex, da: NDArray, db: NDArray, K: int):
    """Prefix product in pair form, natural order: (M,) increments -> (M + 1,) attitudes."""
    M = len(da)
    if M <= _SEQUENTIAL:
        return _sequential_pair(a0, b0, da, db)
    if M <= _BANDED:
        return _banded_pair(a0, b0, da, db)
    nb = -(-M // K)
    pa = np.ones(nb * K, dtype=complex)
    pb = np.zeros(nb * K, dtype=complex)
    pa[:M] = da
    pb[:M] = db
    bda = np.ascontiguousarray(pa.reshape(nb, K).T)
    bdb = np.ascontiguousarray(pb.reshape(nb, K).T)
    r = np.empty((K, 2, nb), dtype=complex)
    _local_scan(bda, bdb, r)
    ra, rb = r[:, 0], r[:, 1]
    ea, eb = _prefix_pair(a0, b0, ra[K - 1], rb[K - 1], K)  # (nb + 1,): start of each block
    out_a = np.empty(nb * K + 1, dtype=complex)
    out_b = np.empty(nb * K + 1, dtype=complex)
    out_a[0], out_b[0] = a0, b0
    # Written straight into natural order through transposed (K, nb) views.
    _mul_into(ea[:nb], eb[:nb], ra, rb, np.conjugate(ra), np.conjugate(rb),
              out_a[1:].reshape(nb, K).T, out_b[1:].reshape(nb, K).T,
              np.empty((K, nb), dtype=complex))
    return out_a[:M + 1], out_b[:M + 1]


def _write_xyzw(dst: NDArray, a: NDArray, b: NDArray, normalize: bool) -> None:
    """Write pairs into ``[x, y, z, w]`` rows: dst[..., :] from ``a = w + 1j z, b = x + 1j y``."""
    dst.view(complex)[..., 0] = b  # x + 1j y
    dst[..., 2] = a.imag
    dst[..., 3] = a.real
    if normalize:
        # Squared norms as a product with ones: fewer passes than einsum (2.5 vs 6.5 µs per
        # 1000 rows).
        dst /= np.sqrt(np.square(dst) @ _ONES4)[..., None]


def blocked_prefix_product(q0: ArrayLike, n_steps: int, fill: FillFn, block: int = BLOCK,
                           normalize: bool = True) -> NDArray[np.float64]:
    """Attitudes ``q_0 = q0``, ``q_{i+1} = q_i ⊗ dq_i`` for increments produced block-wise.

    Parameters
    ----------
    q0 : array_like, shape (4,)
        Initial unit quaternion ``[x, y, z, w]``.
    n_steps : int
        Number ``M`` of increments (>= 1).
    fill : callable ``(b0, b1) -> (x, y, z, w)``
        Returns the increments of blocks ``b0 <= b < b1`` as 4 arrays of shape ``(K, b1 - b0)``,
        element ``[k, b - b0]`` being step ``i = b K + k``. Entries for ``i >= n_steps`` (padding
        of the last block) may hold anything finite; they are replaced by the identity.
    block : int
        Block length ``K`` (>= 2).
    normalize : bool
        Normalise every output quaternion (default). Off only for testing the raw product.

    Returns
    -------
    ndarray, shape (n_steps + 1, 4)
        ``[x, y, z, w]`` attitudes, row 0 = ``q0``; C-contiguous.
    """
    K = int(block)
    if K < 2:
        raise InputError(f"Expected block >= 2, got {block}")
    M = int(n_steps)
    q0 = np.asarray(q0, dtype=float)
    a0 = complex(q0[3], q0[2])
    b0 = complex(q0[0], q0[1])
    nb = -(-M // K)
    cb = max(1, CHUNK_SAMPLES // K)  # blocks per cache chunk
    r = np.empty((K, 2, nb), dtype=complex)
    ra, rb = r[:, 0], r[:, 1]
    # Pass 1: increments and local (in-block) inclusive prefix, chunk by chunk.
    for b0_ in range(0, nb, cb):
        b1_ = min(nb, b0_ + cb)
        da, db = _to_pair(*fill(b0_, b1_))
        if b1_ == nb and nb * K > M:  # identity padding after the last real step
            pad = M - (nb - 1) * K
            da[pad:, -1] = 1.0
            db[pad:, -1] = 0.0
        _local_scan(da, db, r[:, :, b0_:b1_])
    # Recursion: attitude at the start of every block.
    ea, eb = _prefix_pair(a0, b0, ra[K - 1], rb[K - 1], K)
    # Pass 2: apply each block's start attitude, normalise, write [x, y, z, w] rows.
    out = np.empty((nb * K + 1, 4))
    out[0] = q0
    body = out[1:].reshape(nb, K, 4)
    for b0_ in range(0, nb, cb):
        b1_ = min(nb, b0_ + cb)
        sa, sb = ra[:, b0_:b1_], rb[:, b0_:b1_]
        oa = np.empty(sa.shape, dtype=complex)
        ob = np.empty(sa.shape, dtype=complex)
        _mul_into(ea[b0_:b1_], eb[b0_:b1_], sa, sb, np.conjugate(sa), np.conjugate(sb), oa, ob,
                  np.empty(sa.shape, dtype=complex))
        _write_xyzw(body[b0_:b1_].transpose(1, 0, 2), oa, ob, normalize)
    if normalize:
        out[0] = q0 / np.linalg.norm(q0)
    return out[:M + 1]


def prefix_product_parts(q0: ArrayLike, dq: Parts, block: int = BLOCK,
                         normalize: bool = True) -> NDArray[np.float64]:
    """As :func:`prefix_product` with the increments as 4 component arrays ``(x, y, z, w)``,
    each of shape (M,) (natural order); returns (M + 1, 4)."""
    q0 = np.asarray(q0, dtype=float)
    da, db = _to_pair(*dq)
    a, b = _prefix_pair(complex(q0[3], q0[2]), complex(q0[0], q0[1]), da, db, int(block))
    out = np.empty((len(da) + 1, 4))
    _write_xyzw(out, a, b, normalize)
    return out


def prefix_product(q0: ArrayLike, dq: ArrayLike, block: int = BLOCK,
                   normalize: bool = True) -> NDArray[np.float64]:
    """Attitudes ``q_0 = q0``, ``q_{i+1} = q_i ⊗ dq_i`` (body increments on the right).

    Parameters
    ----------
    q0 : array_like, shape (4,)
        Initial quaternion ``[x, y, z, w]``.
    dq : array_like, shape (M, 4)
        Increments ``[x, y, z, w]``, M >= 0.
    block : int
        Block length K of the blocked scan.
    normalize : bool
        Normalise the output quaternions (default).

    Returns
    -------
    ndarray, shape (M + 1, 4)
        Row 0 is ``q0``.
    """
    q0 = np.asarray(q0, dtype=float)
    dq = np.asarray(dq, dtype=float)
    if dq.ndim != 2 or dq.shape[1] != 4:
        raise InputError(f"Expected `dq` of shape (M, 4), got {dq.shape}")
    return prefix_product_parts(q0, (dq[:, 0], dq[:, 1], dq[:, 2], dq[:, 3]), block, normalize)

"""Blocked prefix product of quaternions: ``q_{i+1} = q_i ⊗ dq_i`` for all ``i`` without a
per-sample Python loop (DESIGN.md §4, "Speed").

The product is sequential, so it is reorganised for numpy:

1. The ``M`` increments are laid out as ``nb`` blocks of ``K`` consecutive steps, in
   struct-of-arrays form: 4 component arrays of shape ``(K, nb)``, row ``k`` holding step
   ``b K + k`` of every block ``b``. Step ``i = b K + k``.
2. **Local scan**: ``K - 1`` vectorised products along the rows give every block's inclusive
   prefix ``R[k, b] = dq_{bK} ⊗ … ⊗ dq_{bK+k}`` (all blocks side by side).
3. **Recursion** on the block totals ``R[K-1, :]`` gives the attitude ``E[b]`` at the start of each
   block (the same algorithm on ``nb`` elements, down to a short plain loop).
4. **Apply**: ``q_{bK+k+1} = E[b] ⊗ R[k, b]`` in one vectorised product, then every quaternion is
   normalised once.

Steps 1-2 and 4 run over chunks of blocks whose arrays fit in the CPU cache. Every product is the
Hamilton product of scalar-last ``[x, y, z, w]`` quaternions; increments multiply on the right.
The result agrees with the sequential loop to rounding (~1e-15 per element, tested).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imu_dcm.errors import InputError

__all__ = ["BLOCK", "blocked_prefix_product", "prefix_product", "quat_mul_parts"]

#: Default block length K (steps per block). Measured on 10^6 steps (benchmarks/core_speed.py):
#: short blocks keep the rows long, the number of numpy calls per sample low.
BLOCK = 8
# Target number of samples per cache chunk of blocks (arrays of ~256 kB).
_CHUNK_SAMPLES = 1 << 15
# Below this many steps the product is a plain loop over Python floats.
_SMALL = 64

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


def _sequential(q0: NDArray, dq: NDArray) -> NDArray:
    """Plain loop over Python floats; ``dq`` (M, 4) -> (M + 1, 4)."""
    out = np.empty((len(dq) + 1, 4))
    q = tuple(float(v) for v in q0)
    out[0] = q
    for i, d in enumerate(dq.tolist(), start=1):
        q = quat_mul_parts(q, d)
        out[i] = q
    return out


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
    nb = -(-M // K)
    cb = max(1, _CHUNK_SAMPLES // K)  # blocks per cache chunk
    R = np.empty((4, K, nb))
    # Pass 1: increments and local (in-block) inclusive prefix, chunk by chunk.
    for b0 in range(0, nb, cb):
        b1 = min(nb, b0 + cb)
        d = fill(b0, b1)
        if b1 == nb and nb * K > M:  # identity padding after the last real step
            pad = M - (nb - 1) * K
            d = [np.array(c, dtype=float, copy=True) for c in d]
            for c in range(3):
                d[c][pad:, -1] = 0.0
            d[3][pad:, -1] = 1.0
        Rc = R[:, :, b0:b1]
        for c in range(4):
            Rc[c, 0] = d[c][0]
        for k in range(1, K):
            x, y, z, w = quat_mul_parts((Rc[0, k - 1], Rc[1, k - 1], Rc[2, k - 1], Rc[3, k - 1]),
                                        (d[0][k], d[1][k], d[2][k], d[3][k]))
            Rc[0, k], Rc[1, k], Rc[2, k], Rc[3, k] = x, y, z, w
    # Recursion: attitude at the start of every block.
    totals = R[:, K - 1, :]  # (4, nb), block b's total product
    E = prefix_product(q0, totals.T, block=K, normalize=False)  # (nb + 1, 4)
    # Pass 2: apply each block's start attitude, normalise, write [x, y, z, w] rows.
    out = np.empty((nb * K + 1, 4))
    out[0] = q0
    body = out[1:].reshape(nb, K, 4)
    for b0 in range(0, nb, cb):
        b1 = min(nb, b0 + cb)
        e = tuple(np.ascontiguousarray(E[b0:b1, c]) for c in range(4))  # contiguous: faster broadcast
        r = R[:, :, b0:b1]
        x, y, z, w = quat_mul_parts(e, (r[0], r[1], r[2], r[3]))
        if normalize:
            inv = 1.0 / np.sqrt(x * x + y * y + z * z + w * w)
            x, y, z, w = x * inv, y * inv, z * inv, w * inv
        dst = body[b0:b1]
        dst[:, :, 0], dst[:, :, 1], dst[:, :, 2], dst[:, :, 3] = x.T, y.T, z.T, w.T
    if normalize:
        out[0] = q0 / np.linalg.norm(q0)
    return out[:M + 1]


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
    M = len(dq)
    if M <= max(_SMALL, block):
        out = _sequential(q0, dq)
        if normalize:
            out /= np.linalg.norm(out, axis=1, keepdims=True)
        return out
    K = int(block)
    nb = -(-M // K)
    padded = np.empty((nb * K, 4))
    padded[:M] = dq
    padded[M:] = (0.0, 0.0, 0.0, 1.0)
    blocks = padded.reshape(nb, K, 4)

    def fill(b0: int, b1: int) -> Parts:
        v = blocks[b0:b1]
        return tuple(np.ascontiguousarray(v[:, :, c].T) for c in range(4))

    return blocked_prefix_product(q0, M, fill, block=K, normalize=normalize)

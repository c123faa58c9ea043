"""The ULog byte walker, written for numba: the chain of ``[uint16 size][uint8 type]`` record
headers of a PX4 ULog file (:mod:`imu_dcm.logio.containers.ulog` reads the records it finds), and
its entry
point (:data:`ENTRIES`).

Imported only to compile, like :mod:`imu_dcm._kernels.integrator`.
"""

from __future__ import annotations

import numpy as np

__all__ = ["ENTRIES", "SIGNATURE", "record_chain"]

SIGNATURE = "Tuple((int64[::1], uint8[::1], int64))(uint8[::1], int64)"


def record_chain(b, pos: int):
    """Follow the ``[uint16 size][uint8 type]`` chain of little-endian record headers of ``b``
    from ``pos`` (PX4 ULog's message framing): the position and type of every whole record,
    and where the first incomplete one starts. Compiled with the integrator so that a ULog
    replay needs no numba either (:func:`imu_dcm._kernels.calls.record_chain` checks the
    bytes)."""
    n = len(b)
    at = np.empty(n // 3 + 1, np.int64)
    typ = np.empty(n // 3 + 1, np.uint8)
    k = 0
    while pos + 3 <= n:
        end = pos + 3 + (np.int64(b[pos]) | (np.int64(b[pos + 1]) << 8))
        if end > n:
            break
        at[k] = pos
        typ[k] = b[pos + 2]
        k += 1
        pos = end
    return at[:k], typ[:k], pos


#: ``name -> (function, signature)`` of this kernel's entry point.
ENTRIES = {"record_chain": (record_chain, SIGNATURE)}

"""The steps of a message layout as the compiled field walk reads them
(:mod:`imu_dcm._kernels.ros_fields`): one int64 row per step. No numba here: the decoder that
builds the table (:mod:`imu_dcm.logio.ros.cdr`) and the compiled walk read the same columns.
"""

from __future__ import annotations

__all__ = ["COL", "COUNT", "KIND", "KIND_PRIM", "KIND_SEQ", "KIND_STRING", "N", "SIGNED", "SIZE"]

#: Step kinds: ``n`` primitives; a u4 count, then that many primitives; a u4 length, then the
#: bytes of a string.
KIND_PRIM, KIND_SEQ, KIND_STRING = 0, 1, 2
#: A row's columns: its kind, the size of one value (bytes: 1, 2, 4 or 8), how many values a
#: primitive step holds, whether they are signed integers (1) or not (0), the first output
#: word of a wanted step (-1: not wanted) and how many of its values are wanted (its first ones).
KIND, SIZE, N, SIGNED, COL, COUNT = range(6)

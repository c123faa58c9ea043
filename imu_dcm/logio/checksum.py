"""The CRC-32 of MCAP chunks and summaries (the zlib polynomial), read and written.

zlib-ng computes it with carry-less multiplication where the CPU has it: about 12x the speed of
the system zlib that Python's :mod:`zlib` links (23 against 1.9 GB/s on one core of the
development machine), which matters because every decompressed byte of a log is checked. Both
release the GIL on large buffers, so the decompression workers check chunks side by side. The
value is the same either way; without zlib-ng (a platform with no wheel) the standard library's
is used.
"""

from __future__ import annotations

try:
    from zlib_ng.zlib_ng import crc32
except ImportError:  # pragma: no cover - zlib-ng is a dependency; a missing wheel only costs speed
    from zlib import crc32

__all__ = ["crc32"]

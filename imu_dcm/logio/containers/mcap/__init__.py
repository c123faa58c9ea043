"""MCAP, read our own way: only the chunks that hold kept channels, each bounded and checked.

Laid out as mcap's own reader is: the record layouts and their parsing (``records``), what
both readers share (``reader``: the channels, the messages of one chunk located), the indexed
reader that follows the summary (``indexed``), the streaming one that walks a file without a
usable summary (``streaming``), and the factory choosing between them (``source``:
:func:`make_reader`, :class:`McapSource`).

With a summary (the normal case) the chunk indexes say which channels every chunk holds, so
chunks of other channels (a camera) are never read; the others are read in batches and the
messages of a whole batch located and checked at once from their message indexes. Without one
(a truncated file) the file is walked forward record by record, one chunk in memory at a time.
Each chunk is refused when its declared size is beyond :func:`size_bound`, and never
decompresses past its declared size. A damaged chunk costs only itself: it becomes a
:class:`~imu_dcm.logio.types.Damage` (file offset, time range, messages lost) and reading goes
on with the next chunk (from the index, or a scan for the next valid chunk).
"""

from imu_dcm.logio.containers.mcap.records import MAGIC, compact, size_bound
from imu_dcm.logio.containers.mcap.source import McapSource, make_reader

__all__ = ["MAGIC", "McapSource", "compact", "make_reader", "size_bound"]

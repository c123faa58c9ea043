"""One MCAP file as a log source: the factory choosing its reader, and what the read found.

:func:`make_reader` gives the indexed reader (:mod:`.indexed`) when the file's summary is
usable, else the streaming one (:mod:`.streaming`), as mcap's own ``make_reader`` does;
:class:`McapSource` is the container the registry opens.
"""

from __future__ import annotations

from pathlib import Path

from imu_dcm.errors import LogError
from imu_dcm.logio.containers.mcap.indexed import IndexedReader, read_summary
from imu_dcm.logio.containers.mcap.reader import McapReader
from imu_dcm.logio.containers.mcap.records import MAGIC, header_profile
from imu_dcm.logio.containers.mcap.streaming import StreamingReader
from imu_dcm.logio.ros.collect import Collected, Sink
from imu_dcm.logio.ros.read import RosSource
from imu_dcm.logio.source import ProgressCallback

__all__ = ["McapSource", "make_reader"]


def make_reader(
    f,
    path: Path,
    sink: Sink,
    progress: ProgressCallback | None = None,
    custom_data: dict[str, str] | None = None,
) -> McapReader:
    """The reader of the open MCAP file ``f``: indexed when its summary is usable, else
    streaming."""
    size = f.seek(0, 2)
    summary = read_summary(f, size)
    if summary is not None:
        return IndexedReader(summary, path, size, sink, progress, custom_data)
    return StreamingReader(path, size, sink, progress, custom_data)


def _open(path: Path):
    try:
        return open(path, "rb")
    except OSError as exc:
        raise LogError(f"Expected a readable MCAP file, got {path} ({exc.strerror})") from None


class McapSource(RosSource):
    """One MCAP file. ``collect(sink)`` returns every channel and the data of kept ones.

    Only the chunks that hold kept channels are read, each bounded (its declared size within
    :func:`~imu_dcm.logio.containers.mcap.records.size_bound`, never decompressed past it) and
    checked; a damaged chunk costs only itself.
    """

    kind = "mcap"

    def __init__(self, path: Path, progress: ProgressCallback | None = None):
        self.path = path
        self.progress = progress

    def collect(self, sink: Sink) -> Collected:
        with _open(self.path) as f:
            head = f.read(len(MAGIC))
            if not head:
                raise LogError(f"Expected an MCAP file, got an empty file: {self.path}")
            if head != MAGIC:
                raise LogError(
                    f"Expected an MCAP file (magic \\x89MCAP0), got {head!r} in {self.path}"
                )
            profile = header_profile(f)
            reader = make_reader(f, self.path, sink, self.progress, self.custom_data)
            reader.read(f)
        self.custom_data = reader.custom_data
        if self.kind == "mcap" and profile in ("ros1", "ros2"):
            self.kind = f"{profile} mcap"
        conns = [reader.conn(c) for c in sorted(reader.channels)]
        damage = reader.damage + reader.unknown_channel_damage()
        return Collected(self.kind, conns, sink.finish(), damage)

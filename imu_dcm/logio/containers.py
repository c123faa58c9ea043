"""Which container a path is, and the source that reads it (one interface for all).

Accepted: a regular file (``.mcap``, ``.mcap.zstd``, ``.db3``, ROS 1 ``.bag``) or a folder (a
rosbag2 bag with ``metadata.yaml``, or a folder holding one such file). Anything else - a FIFO,
a device such as ``/dev/zero``, a socket - is refused before a byte is read. A format that
cannot be read raises :class:`~imu_dcm.errors.LogError` saying what it is and the one command
that converts it.

Every source has ``kind`` and ``read(sink) -> Collected``: all channels, the data of the
channels the :class:`~imu_dcm.logio.types.Sink` wants (decoded batch by batch), and the damaged
parts skipped.
"""

from __future__ import annotations

import stat
import tempfile
from pathlib import Path

from imu_dcm.errors import LogError
from imu_dcm.logio import meta
from imu_dcm.logio.lfs import lfs_pointer
from imu_dcm.logio.mcap import MAGIC as MCAP_MAGIC
from imu_dcm.logio.mcap import McapSource
from imu_dcm.logio.ros1 import MAGIC as ROS1_MAGIC
from imu_dcm.logio.ros1 import Ros1Source
from imu_dcm.logio.rosbag2 import Rosbag2Folder, SqliteSource, decompress_file
from imu_dcm.logio.types import Collected, Sink
from imu_dcm.outputs import file_kind

SQLITE_MAGIC = b"SQLite format 3\x00"
ZSTD_MAGIC = b"\x28\xb5\x2f\xfd"
STORAGES = ("mcap", "sqlite3")
_FOREIGN = {  # magic -> (what it is, how to convert it)
    b"\x89HDF": (
        "an HDF5 file",
        ("export the gyro as CSV and run `python -m imu_dcm.replay convert-csv gyro.csv`"),
    ),
    b"ULog": (
        "a PX4 ULog",
        ("`ulog2csv x.ulg` then `python -m imu_dcm.replay convert-csv x_sensor_gyro_0.csv`"),
    ),
    b"\x1f\x8b": ("a gzip file", "`gunzip` it first"),
    b"BZh": ("a bzip2 file", "`bunzip2` it first"),
    b"PK\x03\x04": ("a zip archive", "`unzip` it first"),
}


def check_regular(p: Path) -> bool:
    """True for a folder, False for a regular file; LogError for anything else or missing."""
    try:
        st = p.stat()
    except FileNotFoundError:
        raise LogError(
            f"Expected an existing log path, got {str(p)!r} (no such file or folder)"
        ) from None
    except OSError as exc:
        raise LogError(f"Expected a readable log path, got {p} ({exc.strerror})") from None
    if stat.S_ISDIR(st.st_mode):
        return True
    if not stat.S_ISREG(st.st_mode):
        raise LogError(
            f"Expected a regular file or a folder, got a {file_kind(st.st_mode)} (a special "
            f"file): {p}"
        )
    return False


class _ZstdFile:
    """A single ``.zstd``-compressed storage file, decompressed into a temporary folder."""

    def __init__(self, path: Path, progress):
        self.path = path
        self.progress = progress
        self.kind = "zstd-compressed file"

    def read(self, sink: Sink) -> Collected:
        with tempfile.TemporaryDirectory(prefix="imu_dcm_bag_") as tmp:
            inner = decompress_file(self.path, Path(tmp))
            src = source_for_file(inner, "", self.progress)
            got = src.read(sink)
            self.kind = f"{getattr(src, 'kind', 'log')}, file-compressed"
            got.kind = self.kind
            return got


def _head(p: Path) -> bytes:
    try:
        with open(p, "rb") as f:
            return f.read(16)
    except OSError as exc:
        raise LogError(f"Expected a readable log file, got {p} ({exc.strerror})") from None


def source_for_file(p: Path, storage: str = "", progress=None):
    """The source reading the regular file ``p`` (by its first bytes, then its name)."""
    if check_regular(p):
        raise LogError(f"Expected a bag file, got a folder: {p}")
    head = _head(p)
    if head.startswith(MCAP_MAGIC):
        return McapSource(p, progress)
    if head.startswith(SQLITE_MAGIC):
        return SqliteSource(p, progress)
    if head.startswith(ZSTD_MAGIC):
        return _ZstdFile(p, progress)
    if head.startswith(ROS1_MAGIC):
        if head.startswith(b"#ROSBAG V2.0"):
            return Ros1Source(p, progress)
        version = head[9:12].decode("ascii", "replace")
        raise LogError(
            f"Expected a ROS 1 bag of version 2.0, got version {version} in {p}; "
            f"`rosbag fix {p.name} out.bag` rewrites it as 2.0"
        )
    if not head:
        what = "an MCAP file" if p.suffix == ".mcap" else "a log file"
        raise LogError(f"Expected {what}, got an empty file: {p}")
    if lfs := lfs_pointer(p, head):
        raise LogError(lfs)
    for magic, (what, fix) in _FOREIGN.items():
        if head.startswith(magic):
            raise LogError(f"Expected a ROS bag or an MCAP file, got {what}: {p}; {fix}")
    if p.suffix == ".mcap" or storage == "mcap":
        raise LogError(f"Expected an MCAP file (magic \\x89MCAP0), got {head[:8]!r} in {p}")
    if p.suffix in (".csv", ".txt", ".tsv"):
        raise LogError(
            f"Expected a ROS bag or an MCAP file, got a text table: {p}; "
            f"`python -m imu_dcm.replay convert-csv {p.name}` converts it"
        )
    raise LogError(
        f"Expected a ROS 2 bag (MCAP or sqlite3), a ROS 1 bag (.bag v2.0) or an MCAP "
        f"file, got a file starting {head[:8]!r}: {p}"
    )


def open_source(path: str | Path, progress=None):
    """(source, the file or folder shown to the user, custom_data) for ``path``.

    Raises
    ------
    LogError
        Missing path, not a regular file or folder, a folder without a readable bag, a format
        that cannot be read (saying how to convert it).
    """
    p = Path(path)
    if not check_regular(p):
        custom = meta.read_custom_data(p) if (p.parent / "metadata.yaml").is_file() else {}
        return source_for_file(p, "", progress), p, custom
    if (p / "metadata.yaml").is_file():
        info = meta.load_metadata(p)
        storage = str(info.get("storage_identifier") or "")
        if storage not in STORAGES:
            raise LogError(
                f"Expected rosbag2 storage mcap or sqlite3, got {storage!r} in "
                f"{p / 'metadata.yaml'}; `ros2 bag convert -i {p.name} -o out.yaml` "
                f"with storage_id mcap rewrites it"
            )
        files = meta.file_list(info, p)
        for f in files:
            check_regular(f)
        custom = meta.custom_data(info)
        mode = str(info.get("compression_mode") or "").lower()
        if len(files) == 1 and mode in ("", "none"):
            src = source_for_file(files[0], storage, progress)
            if isinstance(src, McapSource | SqliteSource):
                src.kind = f"ros2 {storage}"
            if isinstance(src, SqliteSource):
                src.counts = meta.topic_counts(info)
            return src, files[0], custom
        return Rosbag2Folder(p, info, files, progress), p, custom
    found = [x for pat in ("*.mcap", "*.db3", "*.bag", "*.mcap.zstd") for x in sorted(p.glob(pat))]
    if not found:
        names = ", ".join(sorted(x.name for x in p.iterdir())[:8]) or "nothing"
        raise LogError(f"Expected a bag folder with a .mcap file, got {p} holding {names}")
    if len(found) > 1:
        raise LogError(
            f"Expected one .mcap file in {p}, got {len(found)}: " + ", ".join(f.name for f in found)
        )
    return source_for_file(found[0], "", progress), found[0], {}


def resolve_mcap_path(path: str | Path) -> Path:
    """The storage file of a bag folder holding exactly one (or a file path itself)."""
    _src, shown, _ = open_source(path)
    return shown

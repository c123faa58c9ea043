"""The container table: which reader takes a path, by a file's first bytes or a folder's layout.

:data:`READERS` has one :class:`~imu_dcm.logio.source.SourceEntry` per container; the first
whose ``probe`` accepts a path reads it. Adding a container is one module holding a
:class:`~imu_dcm.logio.source.LogSource`, plus one row here. Rows that only
recognise a format to refuse it (saying how to convert it) come last
(:mod:`imu_dcm.logio.containers.foreign`).

Accepted paths are regular files and folders; a FIFO, a device such as ``/dev/zero`` or a
socket is refused before a byte is read.

Readers of containers other than ROS are imported only when their row opens a log
(:func:`_later`), so that a replay of a ROS bag does not load them.
"""

from __future__ import annotations

from importlib import import_module
from pathlib import Path

from imu_dcm.errors import LogError
from imu_dcm.logio import meta
from imu_dcm.logio.containers.foreign import REFUSALS, TEXT_SUFFIXES
from imu_dcm.logio.containers.mcap import McapSource
from imu_dcm.logio.containers.ros1 import MAGIC as ROS1_MAGIC
from imu_dcm.logio.containers.ros1 import open_bag
from imu_dcm.logio.containers.rosbag2 import (
    SQLITE_MAGIC,
    ZSTD_MAGIC,
    SqliteSource,
    ZstdFile,
    is_bag_folder,
    open_folder,
)
from imu_dcm.logio.paths import (
    MCAP_MAGIC,
    check_regular,
    is_dataflash,
    is_euroc,
    is_ulog,
    read_head,
)
from imu_dcm.logio.ros.read import RosSource
from imu_dcm.logio.source import LogSource, ProgressCallback, SourceEntry

__all__ = [
    "READERS",
    "convert_hint",
    "find_logs",
    "not_logs",
    "open_log",
    "pick",
    "resolve_mcap_path",
]


#: File names taken as a folder's one log even when their bytes are not recognised (so that
#: a damaged one is reported, not passed over).
_LOG_NAMES = ("*.mcap", "*.db3", "*.bag", "*.mcap.zstd")


def _magic(magic: bytes):
    return lambda _path, head: head.startswith(magic)


def _in_bag(open_file):
    """``open_file``, and the ``custom_data`` of the bag folder the file lies in (if any)."""

    def opened(path: Path, progress: ProgressCallback | None) -> RosSource:
        src = open_file(path, progress)
        if (path.parent / "metadata.yaml").is_file():
            src.custom_data = meta.read_custom_data(path)
        return src

    return opened


def _later(module: str, opener: str):
    """The opener ``opener`` of ``imu_dcm.logio.containers.<module>``, that module imported
    at the call."""

    def opened(path: Path, progress: ProgressCallback | None) -> LogSource:
        return getattr(import_module(f"imu_dcm.logio.containers.{module}"), opener)(path, progress)

    return opened


def _is_folder(path: Path, head: bytes) -> bool:
    return not head and path.is_dir()


def _is_metadata(path: Path, head: bytes) -> bool:
    return path.name == "metadata.yaml" and bool(head) and is_bag_folder(path.parent, b"")


def _open_metadata(path: Path, progress: ProgressCallback | None) -> LogSource:
    """A bag's ``metadata.yaml``: the bag folder it describes."""
    return open_folder(path.parent, progress)


def _is_table(path: Path) -> bool:
    """A text file (by suffix) whose first two lines have at least 4 fields alike (a time and
    three rates, what convert-csv needs), split by comma, semicolon or tab."""
    if path.suffix.lower() not in TEXT_SUFFIXES:
        return False
    try:
        with open(path, encoding="utf-8", errors="replace") as f:
            lines = [f.readline() for _ in range(2)]
    except OSError:
        return False
    return any(
        len(lines[0].split(sep)) >= 4 and len(lines[1].split(sep)) == len(lines[0].split(sep))
        for sep in (",", ";", "\t")
    )


def convert_hint(files: list[Path]) -> str:
    """``; N text tables (a.csv, ...): `python -m imu_dcm.replay convert-csv FILE ...`
    converts each`` for the files that look like tables (or "")."""
    csvs = [f for f in files if _is_table(f)]
    if not csvs:
        return ""
    n = len(csvs)
    return (
        f"; {n} text table{'s' if n != 1 else ''} ({csvs[0].name}"
        f"{', ...' if n > 1 else ''}): `python -m imu_dcm.replay convert-csv FILE OUT.mcap "
        f"...` converts {'each' if n > 1 else 'it'} into a bag"
    )


def _open_inside(folder: Path, progress: ProgressCallback | None) -> LogSource:
    """A folder holding exactly one log file (not a bag folder): that file's source."""
    found = _logs_inside(folder)
    if not found:
        entries = sorted(folder.iterdir())
        names = ", ".join(x.name for x in entries[:8]) or "nothing"
        raise LogError(
            f"Expected a bag folder with a .mcap file, got {folder} holding {names}"
            + convert_hint([x for x in entries if x.is_file()])
        )
    if len(found) > 1:
        raise LogError(
            f"Expected one .mcap file in {folder}, got {len(found)}: "
            + ", ".join(f.name for f in found)
        )
    return open_log(found[0], progress)


READERS: tuple[SourceEntry, ...] = (
    SourceEntry("rosbag2 folder (metadata.yaml + storage files)", is_bag_folder, open_folder),
    SourceEntry(
        "a bag's own file (metadata.yaml, read as its folder)", _is_metadata, _open_metadata, False
    ),
    SourceEntry(
        "EuRoC / ASL dataset folder (mav0/imu0/data.csv)", is_euroc, _later("euroc", "EurocSource")
    ),
    SourceEntry("MCAP file (.mcap)", _magic(MCAP_MAGIC), _in_bag(McapSource)),
    SourceEntry("rosbag2 sqlite3 file (.db3)", _magic(SQLITE_MAGIC), _in_bag(SqliteSource)),
    SourceEntry(
        "zstd-compressed storage file (.mcap.zstd, .db3.zstd)",
        _magic(ZSTD_MAGIC),
        _in_bag(ZstdFile),
    ),
    SourceEntry("ROS 1 bag (.bag, v2.0)", _magic(ROS1_MAGIC), open_bag),
    SourceEntry("PX4 ULog (.ulg)", is_ulog, _later("ulog", "open_ulog")),
    SourceEntry(
        "ArduPilot DataFlash log (.bin)", is_dataflash, _later("ardupilot", "open_dataflash")
    ),
    SourceEntry("folder holding one log file", _is_folder, _open_inside, search=False),
    *REFUSALS,
)


def pick(path: Path) -> SourceEntry:
    """The first row of :data:`READERS` accepting ``path`` (a regular file or a folder).

    Raises
    ------
    LogError
        Missing path, a special file, or a file no row recognises.
    """
    head = b"" if check_regular(path) else read_head(path)
    for entry in READERS:
        if entry.probe(path, head):
            return entry
    readable = "; ".join(e.name for e in READERS if e.search)
    raise LogError(
        f"Expected a log of a known container ({readable}), got a file starting "
        f"{head[:8]!r}: {path}"
    )


def open_log(path: str | Path, progress: ProgressCallback | None = None) -> LogSource:
    """The opened source of ``path`` (no samples read yet); see :func:`pick`."""
    p = Path(path)
    return pick(p).open(p, progress)


def _accepts(path: Path) -> bool:
    """A row that :func:`find_logs` follows accepts ``path`` (a file or folder)."""
    try:
        head = b"" if path.is_dir() else read_head(path)
    except LogError:
        return False
    return any(e.search and e.probe(path, head) for e in READERS)


def _is_log_file(path: Path) -> bool:
    """A regular, not hidden file with a ROS log's name or bytes a row recognises."""
    if path.name.startswith(".") or not path.is_file():
        return False
    return any(path.match(pat) for pat in _LOG_NAMES) or _accepts(path)


def _logs_inside(folder: Path) -> list[Path]:
    """The log files directly in ``folder``."""
    return [x for x in sorted(folder.iterdir()) if _is_log_file(x)]


def find_logs(folder: str | Path) -> list[Path]:
    """Every log under ``folder`` that the table reads, in sorted order, hidden entries skipped.

    A folder a row accepts (a rosbag2 folder, a EuRoC dataset) is one log and is not searched
    further; other folders are searched; a file is a log when a row accepts its first bytes or
    its name is a ROS log's (``.mcap``, ``.db3``, ``.bag``, ``.mcap.zstd``).
    """
    p = Path(folder)
    if not p.is_dir():
        return []
    if _accepts(p):
        return [p]
    out: list[Path] = []
    for x in sorted(p.iterdir()):
        if x.is_dir() and not x.name.startswith("."):
            out.extend(find_logs(x))
        elif _is_log_file(x):
            out.append(x)
    return out


def not_logs(folder: str | Path) -> list[Path]:
    """The regular, not hidden files under ``folder`` that :func:`find_logs` does not take
    (nor any log folder holds), sorted: what a batch over ``folder`` skips."""
    p = Path(folder)
    if not p.is_dir() or _accepts(p):
        return []
    out: list[Path] = []
    for x in sorted(p.iterdir()):
        if x.name.startswith("."):
            continue
        if x.is_dir():
            out.extend(not_logs(x))
        elif x.is_file() and not _is_log_file(x):
            out.append(x)
    return out


def resolve_mcap_path(path: str | Path) -> Path:
    """The storage file of a bag folder holding exactly one (or a file path itself)."""
    src = open_log(path)
    return getattr(src, "path", Path(path))

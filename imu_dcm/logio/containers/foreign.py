"""The rows of the container table that recognise a file only to refuse it, saying how to
convert it: compressed archives, HDF5, text tables, empty files, a ``.mcap`` that is not MCAP.

Each is a :class:`~imu_dcm.logio.source.SourceEntry` with ``search=False`` whose ``open``
raises :class:`~imu_dcm.errors.LogError` in one line.
"""

from __future__ import annotations

from pathlib import Path

from imu_dcm.errors import LogError
from imu_dcm.logio.containers.lfs import is_lfs_pointer, refuse_lfs_pointer
from imu_dcm.logio.paths import mav_folder, read_head
from imu_dcm.logio.source import LogSource, ProgressCallback, SourceEntry

__all__ = ["REFUSALS", "TEXT_SUFFIXES", "euroc_root"]


#: Text tables: convert-csv turns them into a bag.
TEXT_SUFFIXES = (".csv", ".txt", ".tsv")


def _refusal(name: str, magic: bytes, fix: str) -> SourceEntry:
    def refuse(path: Path, _progress: ProgressCallback | None) -> LogSource:
        raise LogError(f"Expected a ROS bag or an MCAP file, got {name}: {path}; {fix}")

    return SourceEntry(name, lambda _p, head: head.startswith(magic), refuse, search=False)


def _is_empty_file(path: Path, head: bytes) -> bool:
    return not head and not path.is_dir()


def _refuse_empty(path: Path, _progress: ProgressCallback | None) -> LogSource:
    what = "an MCAP file" if path.suffix == ".mcap" else "a log file"
    raise LogError(f"Expected {what}, got an empty file: {path}")


def _refuse_not_mcap(path: Path, _progress: ProgressCallback | None) -> LogSource:
    head = read_head(path)[:8]
    raise LogError(f"Expected an MCAP file (magic \\x89MCAP0), got {head!r} in {path}")


def _refuse_text(path: Path, _progress: ProgressCallback | None) -> LogSource:
    raise LogError(
        f"Expected a ROS bag or an MCAP file, got a text table: {path}; "
        f"`python -m imu_dcm.replay convert-csv {path.name}` converts it"
    )


def euroc_root(path: Path) -> Path | None:
    """The EuRoC/ASL dataset folder a ``<sensor>/data.csv`` lies in (``mav0``'s parent, or
    ``mav0`` itself when it has no parent dataset folder), or None."""
    if path.name != "data.csv":
        return None
    mav = path.parent.parent
    if mav_folder(mav) is None:
        return None
    return mav.parent if mav.name == "mav0" else mav


def _refuse_euroc_file(path: Path, _progress: ProgressCallback | None) -> LogSource:
    root = euroc_root(path)
    raise LogError(
        f"Expected a log, got a file of the EuRoC/ASL dataset {root}: {path}; give the dataset "
        f"folder: `python -m imu_dcm.replay {root}`"
    )


REFUSALS: tuple[SourceEntry, ...] = (
    SourceEntry("an empty file", _is_empty_file, _refuse_empty, search=False),
    SourceEntry("a Git LFS pointer", is_lfs_pointer, refuse_lfs_pointer, search=False),
    _refusal(
        "an HDF5 file",
        b"\x89HDF",
        "export the gyro as CSV and run `python -m imu_dcm.replay convert-csv gyro.csv`",
    ),
    _refusal("a gzip file", b"\x1f\x8b", "`gunzip` it first"),
    _refusal("a bzip2 file", b"BZh", "`bunzip2` it first"),
    _refusal("a zip archive", b"PK\x03\x04", "`unzip` it first"),
    SourceEntry(
        "a .mcap file that is not MCAP",
        lambda p, head: p.suffix == ".mcap" and bool(head),
        _refuse_not_mcap,
        search=False,
    ),
    SourceEntry(
        "a CSV file of a EuRoC/ASL dataset",
        lambda p, head: bool(head) and euroc_root(p) is not None,
        _refuse_euroc_file,
        search=False,
    ),
    SourceEntry(
        "a text table (.csv, .txt, .tsv)",
        lambda p, head: bool(head) and p.suffix in TEXT_SUFFIXES,
        _refuse_text,
        search=False,
    ),
)

"""Output-path safety shared by every command that writes files (replay, convert-csv, data_synth).

Rules, checked before any work is done and again just before a file is replaced:

* An output is never an input, never contains an input (a folder holding the log) and never lies
  inside an input folder (a bag folder is an input as a whole).
* An existing output must be a regular file (or, for folder outputs, a folder): devices, FIFOs
  and sockets are refused (``/dev/full`` stays a device).
* ``force`` replaces only what this project wrote: a bag folder made by
  :func:`imu_dcm.logio.writer.write_bag` (``metadata.yaml`` plus one ``<name>.mcap`` whose MCAP
  header names ``imu_dcm.bag_writer``). Anything else is refused even with ``force``.
* Files are written atomically: a temporary sibling, then ``os.replace``; on any error the
  temporary file is removed and the target is untouched.

Errors are :class:`imu_dcm.errors.OutputError` with one line "Expected ..., got ...".
"""

from __future__ import annotations

import os
import stat
import tempfile
from collections.abc import Iterable
from pathlib import Path

from imu_dcm.errors import LogError

__all__ = [
    "OutputError",
    "check_not_input",
    "check_output_dir",
    "file_kind",
    "check_output_file",
    "is_own_bag",
    "write_text_atomic",
]

_MCAP_MAGIC = b"\x89MCAP0\r\n"
_OWN_LIBRARY = b"imu_dcm.bag_writer"


class OutputError(LogError):
    """An output path that would destroy an input, a special file or something not ours (also a
    :class:`~imu_dcm.errors.LogError` and a ``ValueError``)."""


def _resolved(path: str | os.PathLike) -> Path:
    return Path(os.path.abspath(os.path.realpath(os.fspath(path))))


def _stat(out: Path, what: str) -> os.stat_result | None:
    """``os.stat(out)``, None when nothing is there; any other failure is one OutputError line."""
    try:
        return os.stat(out)
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise OutputError(
            f"Expected a usable path for {what}, got {exc.strerror}: {str(out)!r}"
        ) from None


def check_not_input(out: Path, inputs: Iterable[str | os.PathLike], what: str) -> None:
    """Refuse ``out`` (resolved) when it is an input, holds one, or lies inside an input folder."""
    for item in inputs:
        src = _resolved(item)
        if out == src:
            raise OutputError(f"Expected {what} other than the input, got {str(out)!r}")
        if src.is_relative_to(out):
            raise OutputError(
                f"Expected {what} that does not contain the input {str(src)!r}, got {str(out)!r}"
            )
        if src.is_dir() and out.is_relative_to(src):
            raise OutputError(
                f"Expected {what} outside the input folder {str(src)!r}, got {str(out)!r}"
            )


def file_kind(mode: int) -> str:
    """What a ``st_mode`` is, in words: "FIFO", "character device", "folder", ..."""
    for test, name in (
        (stat.S_ISCHR, "character device"),
        (stat.S_ISBLK, "block device"),
        (stat.S_ISFIFO, "FIFO"),
        (stat.S_ISSOCK, "socket"),
        (stat.S_ISDIR, "folder"),
        (stat.S_ISREG, "regular file"),
    ):
        if test(mode):
            return name
    return "special file"


def _parent_writable(out: Path, what: str) -> None:
    parent = out.parent
    if not parent.is_dir():
        raise OutputError(f"Expected an existing folder for {what}, got no folder {str(parent)!r}")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise OutputError(f"Expected a writable folder for {what}, got read-only {str(parent)!r}")


def check_output_file(
    path: str | os.PathLike, inputs: Iterable[str | os.PathLike] = (), what: str = "output file"
) -> Path:
    """Check a file output before anything is written; returns the resolved path.

    An existing regular file may be replaced (it is only swapped in whole); a folder, device,
    FIFO or socket is refused, as is any path that is, holds or lies inside an input.
    """
    out = _resolved(path)
    check_not_input(out, inputs, what)
    st = _stat(out, what)
    if st is not None and not stat.S_ISREG(st.st_mode):
        raise OutputError(
            f"Expected {what} to be a regular file or new, got a {file_kind(st.st_mode)} "
            f"{str(out)!r}"
        )
    _parent_writable(out, what)
    return out


def is_own_bag(path: str | os.PathLike) -> bool:
    """True for a bag folder written by :func:`imu_dcm.logio.writer.write_bag` and nothing else.

    The folder holds exactly ``metadata.yaml`` and ``<folder name>.mcap``, and the MCAP header
    record names the library ``imu_dcm.bag_writer``.
    """
    p = Path(path)
    if p.is_symlink() or not p.is_dir():
        return False
    names = {c.name for c in p.iterdir()}
    mcap = p / f"{p.name}.mcap"
    if names != {"metadata.yaml", mcap.name} or not mcap.is_file() or mcap.is_symlink():
        return False
    with open(mcap, "rb") as f:
        head = f.read(256)
    return head.startswith(_MCAP_MAGIC) and _OWN_LIBRARY in head


def check_output_dir(
    path: str | os.PathLike,
    inputs: Iterable[str | os.PathLike] = (),
    *,
    force: bool = False,
    what: str = "output folder",
    writer: str = "imu_dcm",
) -> Path:
    """Check a bag-folder output before anything is written; returns the resolved path.

    A missing path is fine (its parent must be a writable folder). An existing one needs
    ``force`` and must be a bag folder this project wrote (:func:`is_own_bag`); ``writer``
    names the command in the refusal.
    """
    out = _resolved(path)
    check_not_input(out, inputs, what)
    raw = Path(os.path.abspath(os.fspath(path)))
    if raw.is_symlink():
        raise OutputError(f"Expected {what} that is not a symbolic link, got {str(raw)!r}")
    st = _stat(out, what)
    if st is not None:
        if not force:
            raise OutputError(
                f"Expected {what} {str(out)!r} not to exist (use --force), got an "
                f"existing {file_kind(st.st_mode)}"
            )
        if not is_own_bag(out):
            raise OutputError(
                f"Expected --force to replace only a bag this tool wrote (written by "
                f"{writer}), got {file_kind(st.st_mode)} {str(out)!r} (remove it yourself)"
            )
    _parent_writable(out, what)
    return out


def write_text_atomic(
    path: str | os.PathLike, text: str, inputs: Iterable[str | os.PathLike] = ()
) -> Path:
    """Write ``text`` to ``path`` whole or not at all (temporary sibling, then ``os.replace``).

    Re-checks the target with :func:`check_output_file` first. Raises :class:`OutputError` for
    an unsafe target or a write that fails (permission, disk full), leaving no temporary file.
    """
    out = check_output_file(path, inputs)
    fd, tmp = tempfile.mkstemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
        os.replace(tmp, out)
    except OSError as exc:
        Path(tmp).unlink(missing_ok=True)
        raise OutputError(
            f"Expected to write {str(out)!r}, got {type(exc).__name__}: {exc.strerror or exc}"
        ) from None
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return out

"""Output-path safety shared by every command that writes files (replay, convert-csv, data_synth).

Rules, checked before any work is done and again just before a file is replaced:

* An output is never an input, never contains an input (a folder holding the log) and never lies
  inside an input folder (a bag folder is an input as a whole).
* An existing output must be a regular file (or, for folder outputs, a folder): devices, FIFOs
  and sockets are refused (``/dev/full`` stays a device).
* ``force`` replaces only what this project wrote: a bag folder made by
  :func:`imu_dcm.logio.writer.write_bag` (``metadata.yaml`` plus one ``<name>.mcap`` whose MCAP
  header names ``imu_dcm.bag_writer``). Anything else is refused even with ``force``.
* Missing parent folders of an output are created when it is written (``--out out/top``); the
  nearest existing one must be a writable folder.
* Files are written atomically by one helper, :func:`atomic_path`: a temporary sibling, then
  ``os.replace``; on any error the temporary file is removed and the target is untouched. A
  replaced file keeps its mode; a new one gets the umask's (``0o666 & ~umask``), not the
  temporary file's 0o600.

Errors are :class:`imu_dcm.errors.OutputError` with one line "Expected ..., got ...".
"""

from __future__ import annotations

import contextlib
import os
import stat
import tempfile
import threading
from collections.abc import Iterable, Iterator
from pathlib import Path

from imu_dcm.errors import LogError

__all__ = [
    "OutputError",
    "atomic_path",
    "ensure_parent",
    "check_not_input",
    "check_output_dir",
    "file_kind",
    "check_output_file",
    "is_own_bag",
    "check_output_folder",
    "save_figure",
    "write_json",
    "write_text_atomic",
]

_MCAP_MAGIC = b"\x89MCAP0\r\n"
#: MCAP header ``library`` values of the project's bag writers (replay/convert-csv/data_synth,
#: and live's recorder).
_OWN_LIBRARIES = (b"imu_dcm.bag_writer", b"imu_dcm.live")


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
    """The nearest existing ancestor of ``out`` is a writable folder (missing ones are created
    when the output is written, by :func:`ensure_parent`)."""
    parent = out.parent
    while not parent.exists() and not parent.is_symlink() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        raise OutputError(f"Expected a folder for {what}, got no folder {str(parent)!r}")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise OutputError(f"Expected a writable folder for {what}, got read-only {str(parent)!r}")


def ensure_parent(path: str | os.PathLike, what: str = "output") -> Path:
    """Create the missing parent folders of ``path`` (umask modes); returns the parent."""
    parent = Path(path).parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(
            f"Expected to create the folder {str(parent)!r} for {what}, got "
            f"{type(exc).__name__}: {exc.strerror or exc}"
        ) from None
    return parent


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
    return head.startswith(_MCAP_MAGIC) and any(lib in head for lib in _OWN_LIBRARIES)


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


_UMASK_LOCK = threading.Lock()


def _umask() -> int:
    """The process umask (read from /proc on Linux; else set and restored under a lock)."""
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    with _UMASK_LOCK:
        mask = os.umask(0o022)
        os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, what: str = "output") -> Iterator[Path]:
    """Yield a temporary sibling of ``path`` to write; on success it replaces ``path`` whole.

    The one atomic write of the project (text, JSON, tables, ``.rrd`` files, ``metadata.yaml``).
    Missing parent folders are created. The result keeps the mode of the file it replaces, or
    gets ``0o666 & ~umask`` when new. On any error (or an exception in the ``with`` body) the
    temporary file is removed, ``path`` is untouched and an ``OSError`` becomes one
    :class:`OutputError` line. Checks of the target (:func:`check_output_file`) are the
    caller's.
    """
    out = Path(path)
    ensure_parent(out, what)
    tmp = None
    try:
        fd, name = tempfile.mkstemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent)
        os.close(fd)
        tmp = Path(name)
        yield tmp
        try:
            mode = stat.S_IMODE(os.stat(out).st_mode)
        except FileNotFoundError:
            mode = 0o666 & ~_umask()
        os.chmod(tmp, mode)
        with open(tmp, "rb") as f:
            os.fsync(f.fileno())
        os.replace(tmp, out)
    except OSError as exc:
        if tmp is not None:
            tmp.unlink(missing_ok=True)
        raise OutputError(
            f"Expected to write {str(out)!r}, got {type(exc).__name__}: {exc.strerror or exc}"
        ) from None
    except BaseException:
        if tmp is not None:
            tmp.unlink(missing_ok=True)
        raise


def write_text_atomic(
    path: str | os.PathLike,
    text: str,
    inputs: Iterable[str | os.PathLike] = (),
    what: str = "output file",
) -> Path:
    """Write ``text`` to ``path`` whole or not at all (:func:`atomic_path`).

    Re-checks the target with :func:`check_output_file` first. Raises :class:`OutputError` for
    an unsafe target or a write that fails (permission, disk full), leaving no temporary file;
    the mode of a replaced file is kept.
    """
    out = check_output_file(path, inputs, what)
    with atomic_path(out, what) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return out


def _json_default(o):
    """numpy arrays and scalars as lists and numbers (duck-typed: numpy is not imported here)."""
    if hasattr(o, "tolist"):
        return o.tolist()
    if hasattr(o, "item"):
        return o.item()
    return str(o)


def write_json(
    path: str | os.PathLike,
    data,
    inputs: Iterable[str | os.PathLike] = (),
    what: str = "JSON file",
) -> Path:
    """Write ``data`` as indented JSON (numpy values as numbers; NaN refused) with
    :func:`write_text_atomic`."""
    import json

    text = json.dumps(data, indent=2, default=_json_default, allow_nan=False) + "\n"
    return write_text_atomic(path, text, inputs, what)


def check_output_folder(
    path: str | os.PathLike, inputs: Iterable[str | os.PathLike] = (), what: str = "--out folder"
) -> Path:
    """Check a folder that files are written into (benchmarks' ``--out``): an existing folder or
    a new path whose nearest existing ancestor is a writable folder; never an input, holding
    one or inside one. Returns the resolved path (created later, by the writes)."""
    out = _resolved(path)
    check_not_input(out, inputs, what)
    st = _stat(out, what)
    if st is not None and not stat.S_ISDIR(st.st_mode):
        raise OutputError(f"Expected {what} to be a folder, got a {file_kind(st.st_mode)} {out!s}")
    if st is None:
        _parent_writable(out, what)
    elif not os.access(out, os.W_OK | os.X_OK):
        raise OutputError(f"Expected a writable folder for {what}, got read-only {str(out)!r}")
    return out


def save_figure(fig, path: str | os.PathLike, **savefig_kwargs) -> Path:
    """``fig.savefig`` (matplotlib) whole or not at all, through :func:`atomic_path`."""
    out = check_output_file(path, (), "figure")
    fmt = savefig_kwargs.pop("format", None) or out.suffix.lstrip(".") or "png"
    with atomic_path(out, "figure") as tmp:
        fig.savefig(tmp, format=fmt, **savefig_kwargs)
    return out

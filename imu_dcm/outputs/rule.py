"""The checks of :mod:`imu_dcm.outputs`' rule: which paths a command may write, and how.

:func:`claim_output` checks a file a user named (ours or new, never an input, no symbolic link
to a file, streams written directly); :func:`check_output_dir` a bag folder;
:func:`check_output_folder` a folder files are written into. The writes are in
:mod:`imu_dcm.outputs`, which re-exports every name here; import them from there.
"""

from __future__ import annotations

import contextlib
import os
import stat
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from imu_dcm.errors import LogError
from imu_dcm.outputs.signatures import KINDS, is_own

__all__ = [
    "Claim",
    "OutputError",
    "check_not_input",
    "check_output_dir",
    "check_output_file",
    "check_output_folder",
    "claim_output",
    "ensure_parent",
    "file_kind",
    "is_own_bag",
    "open_stream",
    "writes_to_stdout",
]


class OutputError(LogError):
    """An output path that would destroy an input, a special file or something not ours (also a
    :class:`~imu_dcm.errors.LogError` and a ``ValueError``)."""


def _resolved(path: str | os.PathLike) -> Path:
    return Path(os.path.abspath(os.path.realpath(os.fspath(path))))


def _stat(out: Path, what: str, follow: bool = True) -> os.stat_result | None:
    """``os.stat(out)`` (``lstat`` unless ``follow``), None when nothing is there (or a link
    leads nowhere); any other failure is one OutputError line."""
    try:
        return os.stat(out) if follow else os.lstat(out)
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise OutputError(
            f"Expected a usable path for {what}, got {exc.strerror}: {str(out)!r}"
        ) from None


def _fd_identity(fd: int) -> tuple[int, int] | None:
    try:
        st = os.fstat(fd)
    except OSError:
        return None
    return st.st_dev, st.st_ino


def _input_identities(inputs: Iterable[str | os.PathLike]) -> dict[tuple[int, int], str]:
    """(st_dev, st_ino) of every input that exists, and of standard input's file when it is a
    regular file (``live - < feed.txt`` reads it)."""
    ids = {}
    for item in inputs:
        with contextlib.suppress(OSError):
            st = os.stat(item)
            ids[(st.st_dev, st.st_ino)] = os.fspath(item)
    with contextlib.suppress(OSError):
        st = os.fstat(0)
        if stat.S_ISREG(st.st_mode):
            ids.setdefault((st.st_dev, st.st_ino), "the file on standard input")
    return ids


def check_not_input(out: Path, inputs: Iterable[str | os.PathLike], what: str) -> None:
    """Refuse ``out`` when it is an input (same path once links are resolved, or same device and
    inode: a hard link, the file on standard input), holds one, or lies inside an input folder."""
    inputs = tuple(inputs)
    full = _resolved(out)
    with contextlib.suppress(OSError):
        st = os.stat(full)
        name = _input_identities(inputs).get((st.st_dev, st.st_ino))
        if name is not None:
            got = name if name.startswith("the file") else "the input"
            raise OutputError(f"Expected {what} other than the input, got {got}: {str(out)!r}")
    for item in inputs:
        src = _resolved(item)
        if full == src:
            raise OutputError(f"Expected {what} other than the input, got {str(full)!r}")
        if src.is_relative_to(full):
            raise OutputError(
                f"Expected {what} that does not contain the input {str(src)!r}, got {str(full)!r}"
            )
        if src.is_dir() and full.is_relative_to(src):
            raise OutputError(
                f"Expected {what} outside the input folder {str(src)!r}, got {str(full)!r}"
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
        (stat.S_ISLNK, "symbolic link"),
    ):
        if test(mode):
            return name
    return "special file"


def _parent_writable(out: Path, what: str) -> None:
    """The nearest existing ancestor of ``out`` is a writable folder (missing ones are created
    when the output is written)."""
    parent = out.parent
    while not parent.exists() and not parent.is_symlink() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        raise OutputError(f"Expected a folder for {what}, got no folder {str(parent)!r}")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise OutputError(f"Expected a writable folder for {what}, got read-only {str(parent)!r}")


def make_parents(path: str | os.PathLike, what: str) -> list[Path]:
    """Create the missing parent folders of ``path`` (umask modes); the folders made, deepest
    last (for :func:`remove_made`)."""
    parent = Path(path).parent
    missing = []
    while not parent.exists() and parent != parent.parent:
        missing.append(parent)
        parent = parent.parent
    try:
        for folder in reversed(missing):
            folder.mkdir(exist_ok=True)
    except OSError as exc:
        remove_made(missing[::-1])
        raise OutputError(
            f"Expected to create the folder {str(Path(path).parent)!r} for {what}, got "
            f"{type(exc).__name__}: {exc.strerror or exc}"
        ) from None
    return missing[::-1]


def remove_made(folders: list[Path]) -> None:
    """Remove the folders :func:`make_parents` made, deepest first, if they are still empty."""
    for folder in reversed(folders):
        with contextlib.suppress(OSError):
            folder.rmdir()


def ensure_parent(path: str | os.PathLike, what: str = "output") -> Path:
    """Create the missing parent folders of ``path`` (umask modes); returns the parent."""
    make_parents(path, what)
    return Path(path).parent


# ------------------------------------------------------------------------------ the claim
@dataclass(frozen=True, slots=True)
class Claim:
    """An output checked by :func:`claim_output`.

    Attributes
    ----------
    path : Path
        Where it goes: absolute, its folder's links resolved, its last component as named
        (``Path("-")`` for standard output).
    kind : str
        Its kind (:data:`imu_dcm.outputs.signatures.KINDS`, or ``"any"``).
    what : str
        How messages name it (``"--summary-json"``).
    inputs : tuple of str
        What it must not be.
    stream : {"file", "stdout", "stderr", "device"}
        ``file``: a regular file (new or this tool's), replaced atomically. ``stdout`` /
        ``stderr``: the process's own stream. ``device``: a FIFO, pipe or character device,
        opened and written directly.
    """

    path: Path
    kind: str
    what: str
    inputs: tuple[str, ...] = ()
    stream: str = "file"


def _std_stream(st: os.stat_result | None) -> str | None:
    """``"stdout"`` / ``"stderr"`` when ``st`` is the file behind fd 1 / fd 2."""
    if st is None:
        return None
    for fd, name in ((1, "stdout"), (2, "stderr")):
        if _fd_identity(fd) == (st.st_dev, st.st_ino):
            return name
    return None


#: FIFOs claimed, by (st_dev, st_ino): their write end, opened at the claim (so a missing reader
#: is refused before the work, and the reader waits for the output instead of seeing an end).
_HELD_FIFOS: dict[tuple[int, int], int] = {}


def open_stream(path: Path, what: str) -> int:
    """A write descriptor of the FIFO, pipe or character device ``path``: the one held since its
    claim, or opened now without waiting; a FIFO nobody reads is one OutputError line."""
    with contextlib.suppress(OSError):
        st = os.stat(path)
        fd = _HELD_FIFOS.pop((st.st_dev, st.st_ino), None)
        if fd is not None:
            return fd
    try:
        fd = os.open(path, os.O_WRONLY | os.O_NONBLOCK | getattr(os, "O_NOCTTY", 0))
    except OSError as exc:
        if exc.errno == 6:  # ENXIO: a FIFO that nobody reads
            raise OutputError(
                f"Expected a reader on the FIFO {what} {str(path)!r}, got none (start the "
                "reader first)"
            ) from None
        raise
    os.set_blocking(fd, True)
    return fd


def _hold_fifo(path: Path, what: str, st: os.stat_result) -> None:
    if (st.st_dev, st.st_ino) not in _HELD_FIFOS:
        _HELD_FIFOS[(st.st_dev, st.st_ino)] = open_stream(path, what)


def _check_owner(out: Path, kind: str, what: str) -> None:
    """Refuse an existing regular file this tool did not write
    (:mod:`imu_dcm.outputs.signatures`)."""

    if is_own(out, kind):
        return
    words = "a file of its own" if kind == "any" else KINDS[kind].words
    raise OutputError(
        f"Expected {what} to be new or {words} (written by imu_dcm), got an existing file not "
        f"written by imu_dcm: {str(out)!r}"
    )


def claim_output(
    path: str | os.PathLike, kind: str, inputs: Iterable[str | os.PathLike] = (), *, what=None
) -> Claim:
    """Check an output file by the module's rule before any work; returns how it is written.

    Parameters
    ----------
    path : path-like
        The output as the user named it; ``"-"`` is standard output.
    kind : str
        A kind of :data:`imu_dcm.outputs.signatures.KINDS` (``"json"``, ``"rrd"``, ``"tum"``,
        ``"csv"``,
        ``"table"``, ``"markdown"``, ``"chart"``, ``"curves"``, ``"mcap"``) or ``"any"``: an
        existing regular file must carry that kind's signature (or be empty).
    inputs : iterable of path-like
        The command's inputs (logs, folders); the file on standard input is always one.
    what : str, optional
        How messages name the output (default ``"output file"``).

    Returns
    -------
    Claim
        Pass it to :func:`write_atomic`, :func:`claimed_path` or :class:`PendingOutput`, which
        check it again just before the output is replaced.

    Raises
    ------
    OutputError
        One line "Expected ..., got ...": an input, a foreign file, a symbolic link to a file,
        a folder, a block device or socket, a path under a file or in a read-only folder.
    """

    if kind != "any" and kind not in KINDS:
        raise ValueError(f"Expected an output kind of {sorted(KINDS)} or 'any', got {kind!r}")
    what = what or "output file"
    inputs = tuple(os.fspath(i) for i in inputs)
    if os.fspath(path) == "-":
        return Claim(Path("-"), kind, what, inputs, "stdout")
    raw = Path(os.path.abspath(os.fspath(path)))
    out = _resolved(raw.parent) / raw.name
    st, lst = _stat(out, what), _stat(out, what, follow=False)
    std = _std_stream(st)
    if std is not None:
        return Claim(out, kind, what, inputs, std)
    check_not_input(out, inputs, what)
    streams = (stat.S_ISFIFO, stat.S_ISCHR)
    to_stream = st is not None and any(is_(st.st_mode) for is_ in streams)
    if lst is not None and stat.S_ISLNK(lst.st_mode) and not to_stream:
        got = "nothing" if st is None else f"a {file_kind(st.st_mode)}"
        raise OutputError(
            f"Expected {what} not to be a symbolic link, got a link to {got} "
            f"({os.readlink(out)!r}): {str(out)!r}"
        )
    if st is None:
        _parent_writable(out, what)
        return Claim(out, kind, what, inputs, "file")
    if to_stream:
        if stat.S_ISFIFO(st.st_mode):
            _hold_fifo(out, what, st)  # a reader now, or a refusal now: never a wait at the end
        return Claim(out, kind, what, inputs, "device")
    if not stat.S_ISREG(st.st_mode):
        raise OutputError(
            f"Expected {what} to be a file, a stream or new, got a {file_kind(st.st_mode)} "
            f"{str(out)!r}"
        )
    _check_owner(out, kind, what)
    _parent_writable(out, what)
    return Claim(out, kind, what, inputs, "file")


def writes_to_stdout(path: str | os.PathLike | None) -> bool:
    """True when an output named ``path`` goes to standard output (``-``, ``/dev/stdout``, the
    file stdout is redirected to): the command's lines for people then go to stderr."""
    if path is None:
        return False
    if os.fspath(path) == "-":
        return True
    try:
        return _std_stream(os.stat(path)) == "stdout"
    except OSError:
        return False


def check_output_file(
    path: str | os.PathLike,
    inputs: Iterable[str | os.PathLike] = (),
    what: str = "output file",
    kind: str = "any",
) -> Path:
    """:func:`claim_output` for callers that only need the check; returns the claim's path."""
    return claim_output(path, kind, inputs, what=what).path


def plain_file(path: str | os.PathLike, inputs: Iterable[str | os.PathLike], what: str) -> Path:
    """The low-level check of :func:`write_text_atomic`: not an input, regular or new."""
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
    """True for a bag folder written by :func:`imu_dcm.logio.writers.write_bag` and nothing else.

    The folder holds exactly ``metadata.yaml`` and ``<folder name>.mcap``, and the MCAP header
    record names the library ``imu_dcm.bag_writer`` (or ``imu_dcm.live``).
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
    return KINDS["mcap"].recognise(head)


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

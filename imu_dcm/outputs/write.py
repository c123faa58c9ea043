"""Output-path safety shared by every command that writes files (replay, batch, live,
convert-csv, data_synth): ONE OUTPUT RULE, checked before any work is done and again just
before a file is replaced.

* **Ours or new.** An existing file is replaced only when this tool wrote it, recognised by its
  content (:mod:`imu_dcm.outputs.signatures`: a JSON key, a comment line, PNG metadata, the ``.rrd``
  application id, the batch table's header). Anything else is refused in one line, ``--force``
  or not (``--force`` only lets this tool's own batch table or bag folder be replaced). An empty
  file holds nothing to lose and may be replaced.
* **Never an input.** An output is never an input (same path, or same device and inode: a hard
  link, a symlink, the file on standard input), never holds one and never lies inside an input
  folder (a bag folder is an input as a whole).
* **No symbolic link to a file.** An output whose last component is a symbolic link is refused
  when the link leads to a file, a folder or nowhere (nothing is ever written through a link
  into another file; the link itself is not replaced either). A link to a stream (``/dev/stdout``
  -> a pipe) is written through.
* **Streams are written directly.** ``-`` is standard output; a path that is the process's
  standard output or error (``/dev/stdout``, ``/proc/self/fd/1``, even a regular file the shell
  redirected stdout to) is written to that stream; a FIFO, a pipe or a character device
  (``/dev/null``, a terminal) is opened and written, never replaced; a FIFO without a reader is
  refused, never waited on. Folders, block devices and sockets are refused.
* **Whole or not at all.** A file is written to a temporary sibling, then ``os.replace``; on any
  error the temporary file is removed and the target is untouched. A replaced file keeps its
  mode; a new one gets the umask's (``0o666 & ~umask``), not the temporary file's 0o600. A
  stream gets the bytes only once the whole output exists.
* **Missing parent folders** are created when the output is written, and removed again if that
  write fails (``--out out/top``, ``--summary-json out/flip.json``); the nearest existing one must
  be a writable folder. A run that fails before writing creates none.

For a file named by a user, call :func:`claim_output` before the work and :func:`write_atomic`
(or :func:`claimed_path` / :class:`PendingOutput` for a writer that needs a path) after it::

    claim = claim_output(args.export_csv, "csv", inputs, what="--export-csv")  # before the work
    ...                                                                         # the work
    write_atomic(claim, comment_line("estimate") + text)   # imu_dcm.outputs.signatures.comment_line
    with claimed_path(claim_output(path, "chart", inputs)) as tmp:  # a writer needing a path
        fig.savefig(tmp, format="png", metadata={"Software": signature("chart")})

A new kind of output gets its signature and recogniser in :data:`imu_dcm.outputs.signatures.KINDS`.
:func:`atomic_path` and :func:`write_text_atomic` are the low-level writes for files inside an
output folder already claimed (a bag's ``metadata.yaml``).

Errors are :class:`imu_dcm.errors.OutputError` with one line "Expected ..., got ...".
"""

from __future__ import annotations

import contextlib
import json
import os
import stat
import sys
import tempfile
import threading
from collections.abc import Iterable, Iterator
from pathlib import Path

from imu_dcm.outputs.rule import (
    Claim,
    OutputError,
    check_not_input,
    check_output_dir,
    check_output_file,
    check_output_folder,
    claim_output,
    ensure_parent,
    file_kind,
    is_own_bag,
    make_parents,
    open_stream,
    plain_file,
    remove_made,
    writes_to_stdout,
)
from imu_dcm.outputs.signatures import signature

__all__ = [
    "Claim",
    "OutputError",
    "PendingOutput",
    "atomic_path",
    "check_not_input",
    "check_output_dir",
    "check_output_file",
    "check_output_folder",
    "claim_output",
    "claimed_path",
    "ensure_parent",
    "file_kind",
    "is_own_bag",
    "save_figure",
    "write_atomic",
    "write_json",
    "write_text_atomic",
    "writes_to_stdout",
]


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


def _replace_with(tmp: Path, out: Path) -> None:
    """Give ``tmp`` the mode ``out`` has (or the umask's), sync it, and rename it onto ``out``."""
    try:
        mode = stat.S_IMODE(os.stat(out).st_mode)
    except FileNotFoundError:
        mode = 0o666 & ~_umask()
    os.chmod(tmp, mode)
    with open(tmp, "rb") as f:
        os.fsync(f.fileno())
    os.replace(tmp, out)


def _write_stream(claim: Claim, data: bytes) -> None:
    """Write ``data`` to a stream claim: the process's stdout / stderr, or a FIFO, pipe or
    character device (:func:`~imu_dcm.outputs.rule.open_stream`: a FIFO's end held since its
    claim; one without a reader is refused, never waited on)."""
    if claim.stream in ("stdout", "stderr"):
        stream = sys.stdout if claim.stream == "stdout" else sys.stderr
        stream.flush()
        buffer = getattr(stream, "buffer", None)
        if buffer is None:
            stream.write(data.decode("utf-8"))
        else:
            buffer.write(data)
        stream.flush()
        return
    fd = open_stream(claim.path, claim.what)
    try:
        view = memoryview(data)
        while view:
            view = view[os.write(fd, view) :]
    finally:
        os.close(fd)


def _write_failed(claim: Claim, exc: OSError) -> OutputError:
    return OutputError(
        f"Expected to write {claim.what} {str(claim.path)!r}, got {type(exc).__name__}: "
        f"{exc.strerror or exc}"
    )


class PendingOutput:
    """An output being written: fill :attr:`path` (a temporary file), then :meth:`commit`
    makes it the output, whole, or :meth:`abort` removes it. For a writer that needs a path and
    takes long (a live recording): :func:`claimed_path` is the short form.

    A file claim's temporary file is a hidden sibling of the target (same folder, so the rename
    is atomic; missing parent folders are made here and removed again on :meth:`abort`). A
    stream claim's is in the system's temporary folder; :meth:`commit` copies it to the stream.
    """

    def __init__(self, claim: Claim) -> None:
        self.claim = claim
        self._made: list[Path] = []
        folder, prefix = None, ".imu_dcm."
        if claim.stream == "file":
            self._made = make_parents(claim.path, claim.what)
            folder, prefix = claim.path.parent, f".{claim.path.name}."
        try:
            fd, name = tempfile.mkstemp(prefix=prefix, suffix=".tmp", dir=folder)
            os.close(fd)
        except OSError as exc:
            remove_made(self._made)
            raise _write_failed(claim, exc) from None
        self.path = Path(name)

    def commit(self) -> Path:
        """Check the target again, then replace it with the temporary file (or copy that to the
        stream); returns the output's path. On failure nothing of the output is left."""
        c = self.claim
        try:
            if c.stream == "file":
                again = claim_output(c.path, c.kind, c.inputs, what=c.what)
                if again.stream != "file":
                    raise OutputError(
                        f"Expected {c.what} to stay a file until written, got a stream "
                        f"{str(c.path)!r}"
                    )
                _replace_with(self.path, c.path)
            else:
                _write_stream(c, self.path.read_bytes())
                self.path.unlink(missing_ok=True)
        except BrokenPipeError:
            self.abort()
            raise  # ... | head: the reader had what it wanted (the commands end quietly)
        except OSError as exc:
            self.abort()
            raise _write_failed(c, exc) from None
        except BaseException:
            self.abort()
            raise
        return c.path

    def abort(self) -> None:
        """Remove the temporary file and the folders made for it; the target is untouched."""
        self.path.unlink(missing_ok=True)
        remove_made(self._made)


@contextlib.contextmanager
def claimed_path(claim: Claim) -> Iterator[Path]:
    """Yield a temporary path to write the output ``claim`` to; on leaving the block it becomes
    the output (:meth:`PendingOutput.commit`); on an exception it is removed and the target is
    untouched."""
    pending = PendingOutput(claim)
    try:
        yield pending.path
    except BaseException:
        pending.abort()
        raise
    pending.commit()


def write_atomic(claim: Claim, data: str | bytes) -> Path:
    """Write ``data`` (text as UTF-8) as the output ``claim``, whole or not at all; returns its
    path. A stream gets the bytes in one go; a file is replaced by a rename."""
    raw = data.encode("utf-8") if isinstance(data, str) else bytes(data)
    if claim.stream == "file":
        with claimed_path(claim) as tmp:
            tmp.write_bytes(raw)
        return claim.path
    try:
        _write_stream(claim, raw)
    except BrokenPipeError:
        raise
    except OSError as exc:
        raise _write_failed(claim, exc) from None
    return claim.path


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, what: str = "output") -> Iterator[Path]:
    """Yield a temporary sibling of ``path`` to write; on success it replaces ``path`` whole.

    The low-level write for files inside an output folder already checked (a bag's
    ``metadata.yaml``), and for the benchmarks' figures; a file a user names goes through
    :func:`claim_output` and :func:`claimed_path` instead. Missing parent folders are created
    (and removed again on failure). The result keeps the mode of the file it replaces, or gets
    ``0o666 & ~umask`` when new. On any error (or an exception in the ``with`` body) the
    temporary file is removed, ``path`` is untouched and an ``OSError`` becomes one
    :class:`OutputError` line.
    """
    out = Path(path)
    made = make_parents(out, what)
    tmp = None
    try:
        fd, name = tempfile.mkstemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent)
        os.close(fd)
        tmp = Path(name)
        yield tmp
        _replace_with(tmp, out)
    except OSError as exc:
        if tmp is not None:
            tmp.unlink(missing_ok=True)
        remove_made(made)
        raise OutputError(
            f"Expected to write {str(out)!r}, got {type(exc).__name__}: {exc.strerror or exc}"
        ) from None
    except BaseException:
        if tmp is not None:
            tmp.unlink(missing_ok=True)
        remove_made(made)
        raise


def write_text_atomic(
    path: str | os.PathLike,
    text: str,
    inputs: Iterable[str | os.PathLike] = (),
    what: str = "output file",
) -> Path:
    """Write ``text`` to ``path`` whole or not at all (:func:`atomic_path`): the low-level write
    of a file inside a checked output folder (no signature is asked of an existing file).

    Re-checks that the target is not an input and is a regular file or new. Raises
    :class:`OutputError` for an unsafe target or a write that fails (permission, disk full),
    leaving no temporary file; the mode of a replaced file is kept.
    """
    out = plain_file(path, inputs, what)
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
    path: str | os.PathLike | Claim,
    data,
    inputs: Iterable[str | os.PathLike] = (),
    what: str = "JSON file",
    writer: str = "summary",
) -> Path:
    """Write the mapping ``data`` as indented JSON (numpy values as numbers; NaN refused), signed
    with a first key ``"written_by": "imu_dcm <version> <writer>"``, as the output ``path``
    (a :class:`Claim`, or a path claimed here as kind ``json``)."""

    claim = path if isinstance(path, Claim) else claim_output(path, "json", inputs, what=what)
    rest = {k: v for k, v in data.items() if k != "written_by"}
    signed = {"written_by": signature(writer), **rest}
    text = json.dumps(signed, indent=2, default=_json_default, allow_nan=False) + "\n"
    return write_atomic(claim, text)


def save_figure(fig, path: str | os.PathLike | Claim, **savefig_kwargs) -> Path:
    """``fig.savefig`` (matplotlib) whole or not at all.

    ``path`` a :class:`Claim` (kind ``"figure"``, from :func:`claim_output`): the figure is
    signed (PNG ``Software``, SVG ``Creator`` metadata) so that a later run may replace it, and
    written under the output rule. A plain path (the benchmarks' own figures): written through
    :func:`atomic_path`, unsigned.
    """
    if isinstance(path, Claim):
        from imu_dcm.outputs.signatures import signature

        fmt = savefig_kwargs.pop("format", None) or path.path.suffix.lstrip(".") or "png"
        key = "Creator" if fmt == "svg" else "Software"
        meta = {key: signature(path.what), **savefig_kwargs.pop("metadata", {})}
        with claimed_path(path) as tmp:
            fig.savefig(tmp, format=fmt, metadata=meta, **savefig_kwargs)
        return path.path
    out = plain_file(path, (), "figure")
    fmt = savefig_kwargs.pop("format", None) or out.suffix.lstrip(".") or "png"
    with atomic_path(out, "figure") as tmp:
        fig.savefig(tmp, format=fmt, **savefig_kwargs)
    return out

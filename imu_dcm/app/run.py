"""The exit codes of every command, and :func:`run_main`, the one wrapper around a command's
work that turns what it raised into a code and at most one line on stderr (standard library
only).

Exit codes, the same for every command:

* 0: done;
* 1: ran, but with failures (a batch with error rows; live that never connected or received
  no sample);
* 2: bad input or options (one line on stderr, ``Expected X, got Y``);
* 130 / 143: interrupted (Ctrl-C / SIGTERM).

A closed output pipe (``... | head``) ends the command quietly: the reader had what it wanted.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import warnings
from collections.abc import Callable

from imu_dcm.errors import ImuDcmError

__all__ = [
    "EXIT_BAD_INPUT",
    "EXIT_FAILED",
    "EXIT_INTERRUPTED",
    "EXIT_OK",
    "EXIT_TERMINATED",
    "Terminated",
    "end_quietly_on_broken_pipe",
    "error_line",
    "one_line",
    "run_main",
]

#: The exit codes (module doc).
EXIT_OK, EXIT_FAILED, EXIT_BAD_INPUT, EXIT_INTERRUPTED, EXIT_TERMINATED = 0, 1, 2, 130, 143


class Terminated(BaseException):
    """SIGTERM, raised like KeyboardInterrupt (a per-item ``except Exception`` never eats it)."""


def _raise_terminated(signum, frame):
    raise Terminated


def one_line(text: str) -> str:
    """The first line of ``text``, without carriage returns ("" for no text)."""
    return (text.splitlines() or [""])[0].replace("\r", " ").strip()


def error_line(exc: BaseException) -> str:
    """The one line said for an error: its message's first line; for an ``OSError`` the system's
    words and the file, as "Expected a readable input and writable outputs, got ..."."""
    text = one_line(str(exc))
    if isinstance(exc, OSError):
        where = f" {exc.filename!r}" if exc.filename else ""
        return (
            f"Expected a readable input and writable outputs, got {type(exc).__name__}: "
            f"{exc.strerror or text}{where}"
        )
    return text or type(exc).__name__


def end_quietly_on_broken_pipe() -> None:
    """After ``BrokenPipeError`` on stdout (``... | head``): point stdout at /dev/null so the
    interpreter's final flush does not complain."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass


def run_main(
    prog: str,
    body: Callable[[list[str]], int],
    argv: list[str] | None = None,
    *,
    interrupted: str = "interrupted",
    terminated: str = "terminated",
) -> int:
    """Run a command's work, ``body(argv)``, and return its exit code (module doc).

    ``body`` returns the code of a run that ended; what it raises becomes a code and one line
    on stderr, ``PROG: error: ...``: an :class:`~imu_dcm.errors.ImuDcmError` or ``OSError``
    2 (:func:`error_line`), ``SystemExit`` (argparse: ``--help``, a bad option, already
    printed) its own code, Ctrl-C 130 with ``interrupted``, SIGTERM 143 with ``terminated``, a
    closed stdout 0. Each warning raised meanwhile is printed once as ``PROG: warning: ...``,
    its first line. In the main thread, SIGTERM raises :class:`Terminated` in ``body`` for the
    run's length (a body may set its own handler meanwhile, and put this one back).

    Parameters
    ----------
    prog : str
        The command's name, the prefix of its lines.
    body : callable(list of str) -> int
    argv : list of str, optional
        The arguments (default ``sys.argv[1:]``).
    interrupted, terminated : str
        The line said on Ctrl-C, on SIGTERM.
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    message, code = "", EXIT_BAD_INPUT
    trap = threading.current_thread() is threading.main_thread()
    old = signal.signal(signal.SIGTERM, _raise_terminated) if trap else None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            code = body(argv)
        except BrokenPipeError:  # ... | head: the reader had what it wanted
            end_quietly_on_broken_pipe()
            code = EXIT_OK
        except (ImuDcmError, OSError) as exc:  # FileExistsError is an OSError
            message = error_line(exc)
        except SystemExit as exc:  # argparse: --help (0) or a bad option (2), already printed
            code = exc.code if isinstance(exc.code, int) else EXIT_BAD_INPUT
        except KeyboardInterrupt:
            code, message = EXIT_INTERRUPTED, interrupted
        except Terminated:
            code, message = EXIT_TERMINATED, terminated
        finally:
            if trap:  # None: the handler was not set from Python (the default, then)
                signal.signal(signal.SIGTERM, signal.SIG_DFL if old is None else old)
            for w in caught:
                print(f"{prog}: warning: {one_line(str(w.message))}", file=sys.stderr)
    if message:
        print(f"{prog}: error: {message}", file=sys.stderr)
    return code

"""Command-line plumbing shared by the project's commands: a one-line argument parser (negative
numbers as option values, near-miss suggestions, ``--version``), the parsing of ``"a,b,c"``
option values and of ``--bias``, the exit-code convention, and a terminal progress line
(standard library only, so ``--help`` stays fast).

Exit codes, the same for every command:

* 0: done;
* 1: ran, but with failures (a batch with error rows; live that never connected or received
  no sample);
* 2: bad input or options (one line on stderr, ``Expected X, got Y``);
* 130 / 143: interrupted (Ctrl-C / SIGTERM).

A closed output pipe (``... | head``) ends the command quietly with the code it would have had.
"""

from __future__ import annotations

import argparse
import os
import re
import sys
import time
from typing import NoReturn

#: The exit codes (module doc).
EXIT_OK, EXIT_FAILED, EXIT_BAD_INPUT, EXIT_INTERRUPTED, EXIT_TERMINATED = 0, 1, 2, 130, 143

# An option value that starts with "-" but is numbers: "-0.01,0,0", "-1e-3", "-.5,1,2,3".
_NEGATIVE_NUMBERS = re.compile(r"^-(\d|\.\d)[\d.eE+,-]*$")
_INVALID_CHOICE = re.compile(r"invalid choice: '([^']*)' \(choose from (.*)\)$")


def did_you_mean(word: str, choices) -> str:
    """`` (did you mean 'auto'?)`` for a near miss of one of ``choices``, else ``""``."""
    import difflib  # only on a bad option

    close = difflib.get_close_matches(str(word), [str(c) for c in choices], n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


def prog_name(script: str, module_form: str) -> str:
    """How the user started the command: the console script's name, or ``python -m ...``."""
    return script if os.path.basename(sys.argv[0] or "") == script else module_form


def version_text(prog: str) -> str:
    """``PROG 0.1.0`` (the installed distribution's version, else the package's)."""
    try:
        from importlib.metadata import version

        v = version("imu_dcm")
    except Exception:  # not installed (run from a checkout)
        from imu_dcm import __version__ as v
    return f"{prog} {v}"


class _VersionAction(argparse.Action):
    """``--version``: the version is looked up only when asked (``importlib.metadata`` costs
    ~20 ms of every start-up otherwise)."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, **kw):
        super().__init__(option_strings, dest, nargs=0, default=default, **kw)

    def __call__(self, parser, namespace, values, option_string=None):
        parser._print_message(version_text(parser.prog) + "\n", sys.stdout)
        parser.exit()


class OneLineArgumentParser(argparse.ArgumentParser):
    """argparse that reports a bad option in one line (no usage dump) and exits with status 2,
    suggests the nearest choice for a near miss, takes negative numbers as option values
    (``--bias -0.01,0,0``) and has ``--version``.

    Sub-command parsers made by ``add_subparsers`` inherit the class.
    """

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.add_argument("--version", action=_VersionAction, help=argparse.SUPPRESS)

    def error(self, message: str) -> NoReturn:
        m = _INVALID_CHOICE.search(message)
        if m:
            choices = [c.strip().strip("'\"") for c in m.group(2).split(",")]
            message += did_you_mean(m.group(1), choices)
        self.exit(2, f"{self.prog}: error: {message}\n")

    def parse_known_args(self, args=None, namespace=None):
        args = list(sys.argv[1:] if args is None else args)
        return super().parse_known_args(self._join_negative_values(args), namespace)

    def _join_negative_values(self, args: list[str]) -> list[str]:
        """``--opt -1,2,3`` -> ``--opt=-1,2,3`` for options that take one value."""
        out: list[str] = []
        i = 0
        while i < len(args):
            tok = args[i]
            if tok == "--":
                out.extend(args[i:])
                break
            action = self._option_string_actions.get(tok)
            if (
                action is not None
                and action.nargs is None
                and i + 1 < len(args)
                and _NEGATIVE_NUMBERS.match(args[i + 1])
            ):
                out.append(f"{tok}={args[i + 1]}")
                i += 2
                continue
            out.append(tok)
            i += 1
        return out


def end_quietly_on_broken_pipe() -> None:
    """After ``BrokenPipeError`` on stdout (``... | head``): point stdout at /dev/null so the
    interpreter's final flush does not complain."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass


class Progress:
    """A plain-text progress line on stderr, drawn only when stderr is a terminal and only once
    the replay has run for ``delay_s`` (short replays print nothing)."""

    def __init__(self, stream=None, min_interval_s: float = 0.1, delay_s: float = 0.5):
        self.stream = stream or sys.stderr
        self.enabled = bool(getattr(self.stream, "isatty", lambda: False)())
        self.min_interval_s = min_interval_s
        self._start = time.monotonic()
        self.delay_s = delay_s
        self._last = 0.0
        self._drawn = False

    def __call__(self, stage: str, fraction: float) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if now - self._start < self.delay_s:
            return
        if fraction < 1.0 and now - self._last < self.min_interval_s:
            return
        self._last = now
        width = 30
        filled = round(width * min(max(fraction, 0.0), 1.0))
        self.stream.write(
            f"\r{stage:<10} [{'#' * filled}{'.' * (width - filled)}] {100 * fraction:5.1f}%"
        )
        self.stream.flush()
        self._drawn = True

    def close(self) -> None:
        if self._drawn:
            self.stream.write("\r" + " " * 60 + "\r")
            self.stream.flush()


def parse_numbers(text: str, n: int, name: str) -> list[float]:
    """``"a,b,c"`` -> n finite floats; raises InputError "Expected {name} as n ... numbers"."""
    from imu_dcm.errors import InputError

    try:
        values = [float(x) for x in text.split(",")]
    except ValueError:
        raise InputError(f"Expected {name} as {n} comma-separated numbers, got {text!r}") from None
    if len(values) != n or not all(abs(v) < float("inf") for v in values):
        raise InputError(f"Expected {name} as {n} finite numbers, got {text!r}")
    return values


def _word_or_numbers(text: str, n: int, name: str, what: str) -> str | list[float]:
    """``auto``, ``none`` or ``n`` comma-separated numbers (``what`` names them)."""
    from imu_dcm.errors import InputError

    word = text.strip().lower()
    if word in ("auto", "none"):
        return word
    if any(c.isalpha() for c in word.replace("e", "")):
        raise InputError(
            f"Expected {name} auto, none or {what}, got {text!r}"
            f"{did_you_mean(word, ('auto', 'none'))}"
        )
    return parse_numbers(text, n, f"{name} ({what})")


def parse_bias(text: str, name: str = "--bias") -> str | list[float]:
    """``auto``, ``none`` or ``x,y,z`` (rad/s) -> ``"auto"``, ``"none"`` or 3 floats.

    The one parser of bias text (replay, batch and live); the libraries take numbers or
    ``"auto"``/``"none"``. A near miss such as ``atuo`` is answered with the word meant.
    """
    return _word_or_numbers(text, 3, name, "x,y,z in rad/s")


def parse_mounting(text: str, name: str = "--mounting") -> str | list[float]:
    """``auto``, ``none`` or ``x,y,z,w`` (the gyro-to-truth-body rotation) -> the word or 4
    floats (normalised and checked by the replay)."""
    return _word_or_numbers(text, 4, name, "a quaternion x,y,z,w")


def parse_init_quat(text: str | None) -> list[float] | None:
    """``x,y,z,w`` -> 4 floats, not all zero (None passes through)."""
    from imu_dcm.errors import InputError

    if text is None:
        return None
    q = parse_numbers(text, 4, "--init-quat x,y,z,w")
    if sum(v * v for v in q) < 1e-12:
        raise InputError(f"Expected a non-zero --init-quat x,y,z,w, got {text!r}")
    return q


#: Values of the environment variable ``RERUN`` with which rerun's SDK records nothing (its own
#: switch; compared without case: ``0``, ``false``, ``off``; any other value leaves it on).
RERUN_OFF_VALUES = ("0", "false", "off")


def rerun_switched_off() -> bool:
    """True when ``RERUN`` in the environment turns rerun's SDK off (:data:`RERUN_OFF_VALUES`):
    a recording would then be empty, and a viewer would get nothing."""
    return os.environ.get("RERUN", "").lower() in RERUN_OFF_VALUES


def check_rerun_switch(mode: str | None) -> str | None:
    """The ``--rerun`` mode to use under the environment's ``RERUN`` switch: ``mode`` itself
    when rerun is on; ``"off"`` for the default (None) when it is off. A view asked for by name
    (spawn, serve, save:) while it is off is refused in one line (:class:`InputError`): rerun
    would write an empty ``.rrd`` over the target, or show nothing."""
    if mode == "off" or not rerun_switched_off():
        return mode
    if mode is None:
        return "off"
    from imu_dcm.errors import InputError

    raise InputError(
        f"Expected rerun switched on for --rerun {mode}, got RERUN={os.environ['RERUN']} in "
        "the environment (rerun's own switch: unset it, or use --rerun off)"
    )

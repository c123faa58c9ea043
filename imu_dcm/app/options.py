"""The option parsing every command shares: a one-line argument parser (negative numbers as
option values, near-miss suggestions, ``--version``) and the parsing of option text (``"a,b,c"``,
``--bias``, ``--mounting``, ``--init-quat``) into numbers or words (standard library only, so
``--help`` stays fast). The values are checked by the libraries (:mod:`imu_dcm.app.checks`),
which a command calls before any I/O.
"""

from __future__ import annotations

import argparse
import os
import re
import sys
from typing import NoReturn

from imu_dcm import __version__
from imu_dcm.errors import InputError

__all__ = [
    "OneLineArgumentParser",
    "did_you_mean",
    "parse_bias",
    "parse_init_q_w_b",
    "parse_mounting",
    "parse_numbers",
    "prog_name",
    "version_text",
]

# An option value that starts with "-" but is numbers: "-0.01,0,0", "-1e-3", "-.5,1,2,3".
_NEGATIVE_NUMBERS = re.compile(r"^-(\d|\.\d)[\d.eE+,-]*$")
_INVALID_CHOICE = re.compile(r"invalid choice: '([^']*)' \(choose from (.*)\)$")


def did_you_mean(word: str, choices) -> str:
    """`` (did you mean 'auto'?)`` for a near miss of one of ``choices``, else ``""``."""
    import difflib  # only on a bad option (a command's start-up does not pay for it)

    close = difflib.get_close_matches(str(word), [str(c) for c in choices], n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


def prog_name(script: str, module_form: str) -> str:
    """How the user started the command: the console script's name, or ``python -m ...``."""
    return script if os.path.basename(sys.argv[0] or "") == script else module_form


def version_text(prog: str) -> str:
    """``PROG 0.1.0`` (the installed distribution's version, else the package's)."""
    try:
        from importlib.metadata import version  # ~20 ms: only when --version is asked for

        v = version("imu_dcm")
    except Exception:  # not installed (run from a checkout)
        v = __version__
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


def parse_numbers(text: str, n: int, name: str) -> list[float]:
    """``"a,b,c"`` -> n finite floats; raises InputError "Expected {name} as n ... numbers"."""
    try:
        values = [float(x) for x in text.split(",")]
    except ValueError:
        raise InputError(f"Expected {name} as {n} comma-separated numbers, got {text!r}") from None
    if len(values) != n or not all(abs(v) < float("inf") for v in values):
        raise InputError(f"Expected {name} as {n} finite numbers, got {text!r}")
    return values


def _word_or_numbers(text: str, n: int, name: str, what: str) -> str | list[float]:
    """``auto``, ``none`` or ``n`` comma-separated numbers (``what`` names them)."""
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


def parse_init_q_w_b(text: str | None, name: str = "--init-quat") -> list[float] | None:
    """``x,y,z,w`` (the start attitude ``q_w_b``, scalar last) -> 4 floats; None passes
    through. The libraries check the quaternion itself
    (:func:`imu_dcm.app.checks.check_init_q_w_b`: finite, not zero, normalised)."""
    if text is None:
        return None
    return parse_numbers(text, 4, f"{name} x,y,z,w")

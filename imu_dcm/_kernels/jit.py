"""How the kernels are compiled with numba: cached, inlined helpers, one notice on a compile.

Each kernel module (:mod:`~imu_dcm._kernels.integrator`, :mod:`~imu_dcm._kernels.ulog_scan`,
:mod:`~imu_dcm._kernels.csv_scan`) decorates its helpers with :func:`njit` or :func:`inline`
and leaves its entry points plain, with one signature each; :func:`compile_entry` compiles an
entry point (on first use, when no up-to-date module built ahead of time is present) and
:mod:`imu_dcm._kernels.build` exports the same functions with the same signatures ahead of time.

Compiled code is cached next to each kernel's file (``__pycache__``) or, when that folder is
read-only, in numba's user cache folder (``NUMBA_CACHE_DIR`` overrides both); a cache miss says so
once per process on stderr before it compiles. When no folder is writable the kernels are
compiled in every process and :class:`imu_dcm.errors.ImuDcmWarning` says so once.

numba's cache is keyed on each kernel's own file: after changing a constant a kernel compiles in
(the series, the ``Method`` codes, the state layout), touch that file. (The tests compare the
compiled exponential with so3's and the streaming gap warning with ``find_gaps``, so a stale cache
does not go unnoticed; the module built ahead of time is keyed on every file of the kernels.)
"""

from __future__ import annotations

import sys
import warnings

import numba
from numba.core import event as numba_event

from imu_dcm.errors import ImuDcmWarning

__all__ = ["COMPILE_S", "compile_entry", "inline", "njit"]

#: CPU seconds to compile every entry point a replay uses (measured: see docs/integrator.md).
COMPILE_S = 3
#: The kernels' modules: a compile of a function of theirs is what the notice announces.
_PACKAGE_PREFIX = __name__.rpartition(".")[0] + "."


def njit(fn=None, signature: str | None = None, **options):
    """``numba.njit([signature], cache=True, error_model="numpy", **options)``: inputs are
    checked before they get here, so no Python-style division checks. Without any writable cache
    folder (see the module doc), compile uncached and warn once."""
    sig = () if signature is None else (signature,)

    def decorate(f):
        try:
            return numba.njit(*sig, cache=True, error_model="numpy", **options)(f)
        except RuntimeError as e:  # numba: "cannot cache function ...: no locator available"
            if "no locator" not in str(e):
                raise
            _warn_uncached()
            return numba.njit(*sig, error_model="numpy", **options)(f)

    return decorate if fn is None else decorate(fn)


def inline(fn):
    """A helper compiled into each caller (numba IR inlining): no function of its own to
    compile, cache and load, and the caller's constants (the method) fold into it."""
    return njit(fn, inline="always")


_warned_uncached = []


def _warn_uncached() -> None:
    if not _warned_uncached:
        _warned_uncached.append(True)
        warnings.warn(
            "Expected a writable folder to cache imu_dcm's compiled kernel, got none "
            "(package folder and user cache read-only): it is compiled in every "
            "process; set NUMBA_CACHE_DIR to a writable folder",
            ImuDcmWarning,
            stacklevel=4,
        )


class _CompileNotice(numba_event.Listener):
    """Says once per process, on stderr, that the kernel is being compiled: numba sends the
    "numba:compile" event only after it found no cached code for the signature."""

    said = False
    why = ""  # why the kernel built ahead of time is not used (set by compile_entry())

    def on_start(self, event) -> None:
        module = event.data["dispatcher"].py_func.__module__
        if not self.said and module.startswith(_PACKAGE_PREFIX):
            type(self).said = True
            print(
                f"imu_dcm: compiling the integrator kernel once, about {COMPILE_S} s; "
                f"later runs load it from the cache{self.why}",
                file=sys.stderr,
                flush=True,
            )

    def on_end(self, event) -> None:
        pass


_NOTICE = _CompileNotice()


def compile_entry(fn, signature: str, why: str = ""):
    """The entry point ``fn`` compiled by numba for its one ``signature``, or loaded from numba's
    cache (saying so once, with ``why``, when it compiles)."""
    _NOTICE.why = why
    with numba_event.install_listener("numba:compile", _NOTICE):
        return njit(fn, signature)

"""Which compiled code a process runs: the module built ahead of time, or numba's compile.

Installing the package builds the kernels ahead of time into one extension module
(:data:`AOT_MODULE`, by :mod:`imu_dcm._kernels.build`), which loads in about a millisecond and
needs no numba at run time. The module carries a digest of the files it was built from
(:data:`KERNEL_SOURCES`) and of the constants they take from :mod:`imu_dcm.so3` and
:mod:`imu_dcm.integrator.methods`; a module built from other versions of them is stale and not used.
Without an up-to-date module (no C compiler at install, an edited kernel, or
``IMU_DCM_KERNEL=jit`` in the environment) each entry point is compiled by numba on its first
use instead, and cached (:mod:`imu_dcm._kernels.jit`). :func:`backend` says which one a process
runs; :func:`entry` gives an entry point of either, by name
(:data:`imu_dcm._kernels.entries.ENTRIES`).
"""

from __future__ import annotations

import importlib
import os
import zlib
from pathlib import Path

from imu_dcm.integrator.methods import GAP_FACTOR, DeltaMethod, Method
from imu_dcm.so3 import COS_HALF_SERIES, SERIES_THETA2, SINC_HALF_SERIES, SMALL_ANGLE_RAD

__all__ = [
    "AOT_MODULE",
    "ENV",
    "KERNEL_SOURCES",
    "backend",
    "digest_entry",
    "entry",
    "source_digest",
]

#: The module the kernel is built into ahead of time.
AOT_MODULE = "imu_dcm._kernels._aot"
#: The files (of this package) the compiled code is made from: the kernels, the state layout,
#: the table of entry points and the compile options. The digest covers them and the constants
#: they take from elsewhere (:func:`_constants`).
KERNEL_SOURCES = (
    "integrator.py",
    "ulog_scan.py",
    "mcap_scan.py",
    "csv_scan.py",
    "series.py",
    "ros_fields.py",
    "field_steps.py",
    "state.py",
    "entries.py",
    "jit.py",
)
#: ``IMU_DCM_KERNEL=jit`` makes a process compile with numba even when a built module exists.
ENV = "IMU_DCM_KERNEL"


def _constants() -> str:
    """The values the compiled code folds in from other modules: the series of the
    exponential, the small-angle bound of the logarithm, the gap factor, the method codes."""
    codes = [(m.name, int(m)) for m in (*Method, *DeltaMethod)]
    series = (SINC_HALF_SERIES, COS_HALF_SERIES, SERIES_THETA2, SMALL_ANGLE_RAD)
    return repr((series, GAP_FACTOR, codes))


def source_digest() -> str:
    """CRC-32 (8 hex digits) of :data:`KERNEL_SOURCES` and :func:`_constants`: what a built module
    must have been built from to be used. (A check against stale builds, not a signature:
    zlib is loaded anyway, where hashlib's OpenSSL would cost ~3 ms of every start-up.)"""
    here = Path(__file__).parent
    crc = zlib.crc32(_constants().encode())
    for name in KERNEL_SOURCES:
        crc = zlib.crc32((here / name).read_bytes(), crc)
    return f"{crc:08x}"


def digest_entry() -> str:
    """The name of the built module's marker function: ``source_<digest>``."""
    return f"source_{source_digest()}"


_AOT: list = []  # [module or None, why not]: loaded once per process
_FUNCTIONS: dict = {}


def _aot():
    """The module built ahead of time if it is present and up to date, else None (and why)."""
    if not _AOT:
        _AOT.extend(_load_aot())
    return _AOT[0]


def _load_aot() -> tuple[object, str]:
    if os.environ.get(ENV, "").strip().lower() == "jit":
        return None, f" ({ENV}=jit)"
    try:
        module = importlib.import_module(AOT_MODULE)
    except ImportError:
        return (
            None,
            " (no kernel built ahead of time: `python -m imu_dcm._kernels.build` builds it)",
        )
    if not hasattr(module, digest_entry()):
        return None, (
            " (the kernel built ahead of time is out of date: `python -m imu_dcm._kernels.build` "
            "rebuilds it)"
        )
    return module, ""


def backend() -> str:
    """``"ahead-of-time"`` when this process runs the built module, else ``"jit"`` (numba)."""
    return "ahead-of-time" if _aot() is not None else "jit"


def entry(name: str):
    """The compiled entry point ``name`` (see :data:`imu_dcm._kernels.entries.ENTRIES`): from
    the module built ahead of time, else compiled (or loaded from numba's cache) on first use.
    Only then are the kernels' sources (and numba, about half a second) imported."""
    fn = _FUNCTIONS.get(name)
    if fn is None:
        module = _aot()
        if module is not None:
            fn = getattr(module, name)
        else:
            from imu_dcm._kernels import entries

            fn = entries.compiled(name, _AOT[1])
        _FUNCTIONS[name] = fn
    return fn

"""The integrator kernel: the DCM recursion ``q_{i+1} = q_i ⊗ exp(φ_i)`` as one compiled loop.

One kernel serves the batch :func:`imu_dcm.integrate`, :func:`imu_dcm.integrate_delta` and the
streaming :class:`imu_dcm.DcmIntegrator`: every sample goes through :func:`push` (or
:func:`feed`, the same over an array), which keeps what carries across samples in a small
``state`` array (:mod:`imu_dcm.kernel_state`) and commits each step as soon as its stencil is
complete. Batch is "feed every sample, then :func:`close`"; streaming feeds them as they come,
so the two are the same arithmetic. The code itself is :mod:`imu_dcm.kernel_jit`.

Conventions: quaternions Hamilton ``[x, y, z, w]``, ``q_w_b`` body to world; rates ``ω`` rad/s
in body axes; stamps ``t`` s; increments multiply on the right.

Loading. Installing the package builds the kernel ahead of time into one extension module
(``imu_dcm._kernel_aot``, by :mod:`imu_dcm.kernel_build`), which loads in about a millisecond
and needs no numba at run time. The module carries a digest of the files it was built from
(:data:`SOURCES`) and of the constants they take from :mod:`imu_dcm.so3` and
:mod:`imu_dcm.integrator.methods`; a module built from other versions of them is not used. Without
an
up-to-date module (no C compiler at install, an edited kernel, or ``IMU_DCM_KERNEL=jit`` in
the environment) each entry point is compiled by numba on its first use instead, and cached
(see :mod:`imu_dcm.kernel_jit`). :func:`backend` says which one a process runs.

The entry points take float64 C-contiguous arrays and do not check their types: the functions
below check the arrays of a batch call (a ``TypeError`` otherwise), and :func:`push_for` gives
the unchecked per-sample function, whose caller converts (as :class:`imu_dcm.DcmIntegrator`
does).
"""

from __future__ import annotations

import importlib
import os
import zlib
from pathlib import Path

import numpy as np

from imu_dcm.integrator.methods import Method
from imu_dcm.kernel_state import (
    CLOSED,
    IS_CLOSED,
    MAGNUS4,
    MAYBE_GAP,
    METHOD,
    NOT_FINITE,
    NOT_INCREASING,
    OK,
    PHI_SUM,
    Q0,
    ROWS,
    STATE_FIELDS,
    STATE_SIZE,
    N,
    Q,
    T,
    W,
    feed_entry,
    new_state,
    push_entry,
    state_fields,
)

__all__ = [
    "CLOSED",
    "IS_CLOSED",
    "MAGNUS4",
    "MAYBE_GAP",
    "METHOD",
    "N",
    "NOT_FINITE",
    "NOT_INCREASING",
    "OK",
    "PHI_SUM",
    "Q",
    "Q0",
    "ROWS",
    "SOURCES",
    "STATE_FIELDS",
    "STATE_SIZE",
    "T",
    "W",
    "backend",
    "check_record",
    "close",
    "entry",
    "feed",
    "feed_delta",
    "new_state",
    "push",
    "push_for",
    "record_chain",
    "source_digest",
    "state_fields",
]

#: The module the kernel is built into ahead of time.
AOT_MODULE = "imu_dcm._kernel_aot"
#: The files (in this package) the compiled code is made from; the digest covers them and the
#: constants they take from elsewhere (:func:`_constants`).
SOURCES = ("kernel_jit.py", "kernel_state.py")
#: ``IMU_DCM_KERNEL=jit`` makes a process compile with numba even when a built module exists.
ENV = "IMU_DCM_KERNEL"


def _constants() -> str:
    """The values the compiled code folds in from other modules: the series of the
    exponential, the gap factor, the method codes."""
    from imu_dcm.integrator.methods import GAP_FACTOR, DeltaMethod
    from imu_dcm.so3 import COS_HALF_SERIES, SERIES_THETA2, SINC_HALF_SERIES

    codes = [(m.name, int(m)) for m in (*Method, *DeltaMethod)]
    series = (SINC_HALF_SERIES, COS_HALF_SERIES, SERIES_THETA2)
    return repr((series, GAP_FACTOR, codes))


def source_digest() -> str:
    """CRC-32 (8 hex digits) of :data:`SOURCES` and :func:`_constants`: what a built module
    must have been built from to be used. (A check against stale builds, not a signature:
    zlib is loaded anyway, where hashlib's OpenSSL would cost ~3 ms of every start-up.)"""
    here = Path(__file__).parent
    crc = zlib.crc32(_constants().encode())
    for name in SOURCES:
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
        return None, " (no kernel built ahead of time: `python -m imu_dcm.kernel_build` builds it)"
    if not hasattr(module, digest_entry()):
        return None, (
            " (the kernel built ahead of time is out of date: `python -m imu_dcm.kernel_build` "
            "rebuilds it)"
        )
    return module, ""


def backend() -> str:
    """``"ahead-of-time"`` when this process runs the built module, else ``"jit"`` (numba)."""
    return "ahead-of-time" if _aot() is not None else "jit"


def entry(name: str):
    """The compiled entry point ``name`` (see :data:`imu_dcm.kernel_jit.ENTRIES`): from the
    module built ahead of time, else compiled (or loaded from numba's cache) on first use."""
    fn = _FUNCTIONS.get(name)
    if fn is None:
        module = _aot()
        if module is not None:
            fn = getattr(module, name)
        else:
            from imu_dcm import kernel_jit

            fn = kernel_jit.compiled(name, _AOT[1])
        _FUNCTIONS[name] = fn
    return fn


def _arrays(**arrays: tuple[np.ndarray, int]) -> None:
    """Refuse any array the compiled code would misread: float64, C-contiguous, ``ndim``."""
    for name, (a, ndim) in arrays.items():
        if not (
            isinstance(a, np.ndarray)
            and a.dtype == np.float64
            and a.ndim == ndim
            and a.flags.c_contiguous
        ):
            raise TypeError(
                f"Expected `{name}` a float64 C-contiguous array of {ndim} dimension(s), "
                f"got {type(a).__name__} {getattr(a, 'dtype', '')} {getattr(a, 'shape', '')}"
            )


def feed(state, omega, t, out, emit_phi: bool = False) -> int:
    """Push samples ``omega[j], t[j]`` (checked: finite, increasing after the state's last
    stamp); ``out`` gets one row per committed step (the attitude after it, or its ``φ`` when
    ``emit_phi``). Returns the rows written (at most ``len(t) + 1``). Runs the loop compiled
    for the state's method."""
    _arrays(state=(state, 1), omega=(omega, 2), t=(t, 1), out=(out, 2))
    return entry(feed_entry(int(state[METHOD]), emit_phi))(state, omega, t, out)


def push(state, omega, t: float) -> int:
    """One sample (``omega`` a float64 (3,) array, ``t`` a number) into the state; a code
    (:data:`OK`, :data:`NOT_FINITE`, ...). See :func:`push_for`."""
    _arrays(state=(state, 1), omega=(omega, 1))
    return push_for(int(state[METHOD]))(state, omega, float(t))


def push_for(method: int):
    """The compiled per-sample push for ``method``, unchecked: ``fn(state, omega, t)`` with
    ``state`` and ``omega`` float64 C-contiguous 1-D arrays and ``t`` a float. It checks the
    sample (finite, after the last stamp, not closed) and returns :data:`IS_CLOSED`,
    :data:`NOT_FINITE` or :data:`NOT_INCREASING` (state unchanged); :data:`MAYBE_GAP` when the
    step exceeds ``GAP_FACTOR`` times the shortest of the last three; else :data:`OK`."""
    return entry(push_entry(int(method)))


def close(state, emit_phi: bool = False) -> int:
    """End of record: ``magnus4`` commits the steps still open, with a ghost sample after the
    last one (and before the first, for records of 2 or 3 samples) on the polynomial through
    the last (up to four) samples. Other methods: nothing. Returns the rows written to
    ``state[ROWS:ROWS + 8]`` (two rows of four)."""
    _arrays(state=(state, 1))
    state[CLOSED] = 1.0
    if int(state[METHOD]) != Method.MAGNUS4 or state[N] < 2.0:
        return 0
    return entry("close_magnus4")(state, bool(emit_phi))


def check_record(values, t, t_before: float) -> tuple[int, int, int, float, float]:
    """One pass over samples ``values`` (n, 3) and stamps ``t``: ``(row, stamp, order, dt_min,
    dt_max)``, the first row with a non-finite number, the first non-finite stamp, the first
    index not after the stamp before it (``t_before`` for index 0; ``-inf``: none), each ``-1``
    when there is none, and the shortest and longest step (s)."""
    _arrays(values=(values, 2), t=(t, 1))
    return entry("check_record")(values, t, float(t_before))


def feed_delta(q0, dtheta, dt, method: int, out) -> None:
    """Attitudes from checked delta angles: ``out[0] = q0``, then one row per update (per
    interval, or per set of 2 or 3 intervals)."""
    _arrays(q0=(q0, 1), dtheta=(dtheta, 2), dt=(dt, 1), out=(out, 2))
    entry("feed_delta")(q0, dtheta, dt, int(method), out)


def record_chain(b, pos: int) -> tuple[np.ndarray, np.ndarray, int]:
    """The ``[uint16 size][uint8 type]`` record chain of the bytes ``b`` (a uint8 array) from
    ``pos``: ``(positions, types, end)``, every whole record and where the first incomplete one
    starts (:func:`imu_dcm.kernel_jit.record_chain`)."""
    if not (isinstance(b, np.ndarray) and b.dtype == np.uint8 and b.ndim == 1):
        raise TypeError(f"Expected `b` a 1-D uint8 array, got {type(b).__name__}")
    b = np.ascontiguousarray(b)
    if _aot() is None and not b.flags.writeable:
        b = b.copy()  # numba's signature is of a writable array (the built one reads any)
    return entry("record_chain")(b, int(pos))


def csv_scan(blob: bytes, scale: int, digits: int) -> tuple[np.ndarray, bytes, int]:
    """Plain CSV lines ``t,gx,gy,gz`` of ``blob`` in one compiled pass
    (:func:`imu_dcm.kernel_jit.csv_scan`): ``(t_ns, rates_text, rows)``, the exact stamps, the
    rate fields as ``b"gx,gy,gz,..."``, and the lines read; ``rows < 0`` when a line is not of
    that form."""
    b = np.frombuffer(blob, np.uint8)
    if _aot() is None:
        b = b.copy()  # numba's signature is of a writable array (the built one reads any)
    t, text, rows = entry("csv_scan")(b, int(scale), int(digits))
    return t, text.tobytes(), int(rows)

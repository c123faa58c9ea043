"""What a data_synth job will cost, estimated before it runs, so an absurd job is refused up front.

Three costs grow with the options:

* the samples: ``N = floor(duration_s · rate_hz) + 1`` gyro samples and as many truth samples
  are made and written a block of ``BLOCK_ROWS`` at a time, so their memory is one block's
  (``BYTES_PER_BLOCK_ROW``), their time grows with N (``SECONDS_PER_SAMPLE``) and so does the
  bag on disk (``DISK_BYTES_PER_SAMPLE``, checked against the free space where it goes);
  the reference scheme keeps its whole run (``BYTES_PER_REFERENCE_STEP``);
* the ODE solve of ``heavy-top`` and ``free-body``: DOP853 at 1e-12 takes a number of steps
  proportional to the duration times the fastest motion (spin, |omega|); each step keeps its
  dense-output interpolant (``BYTES_PER_STEP``, ``SECONDS_PER_STEP``). The steps are estimated by
  :func:`estimate_ode_steps`, which takes the solver's first ``PROBE_STEPS`` steps and
  extrapolates them to the whole duration (the motions are periodic or nearly so).

The per-unit figures are measured peak-RSS, wall-clock and file-size slopes on a 2-core x86-64
machine (coning at 1 kHz, 0.5 s → 1 h: 565 B per row of a full block above the interpreter,
2.9 µs per sample; 88 B per sample on disk ideal, 141 B with noise, walk and jitter; the
reference scheme 1e4 → 6e4 steps: 362 B per step; heavy top and free box at 1e-12: 1.2-1.4 kB
and 130-260 µs per step), rounded up. They are
estimates for refusing jobs that cannot finish (hundreds of GiB, days), not promises.
"""

from __future__ import annotations

import math
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from imu_dcm.errors import InputError

__all__ = [
    "BYTES_PER_BLOCK_ROW",
    "DISK_BYTES_PER_SAMPLE",
    "BYTES_PER_STEP",
    "JobEstimate",
    "JobTooLarge",
    "estimate_ode_steps",
    "free_bytes",
    "format_bytes",
    "format_seconds",
]

#: Peak memory per row of the block being written (its gyro and truth series, the CDR rows
#: and records of its chunks); a job holds one block of at most ``BLOCK_ROWS`` rows.
BYTES_PER_BLOCK_ROW = 600
#: Bag size on disk per gyro sample (the Imu, truth quaternion and truth rate messages, zstd).
DISK_BYTES_PER_SAMPLE = 160
#: Memory per step of the reference scheme's run (kept whole, sampled at the end).
BYTES_PER_REFERENCE_STEP = 400
#: Wall-clock time per gyro sample (sampling, CDR encoding, zstd), s.
SECONDS_PER_SAMPLE = 5e-6
#: Memory per DOP853 step kept for the dense output (interpolant + its Python objects).
BYTES_PER_STEP = 1_500
#: Wall-clock time per DOP853 step (about 15 Python right-hand-side calls), s.
SECONDS_PER_STEP = 3e-4
#: Wall-clock time per step of the reference scheme's Python RK4 + DCM loop, s.
SECONDS_PER_REFERENCE_STEP = 1e-4
#: Steps taken to measure the ODE's step size before the whole solve.
PROBE_STEPS = 200


class JobTooLarge(InputError):
    """The job would need more memory or time than allowed (an :class:`InputError`)."""


@dataclass(frozen=True)
class JobEstimate:
    """Estimated cost of a job: ``samples`` gyro samples, ``steps`` ODE (or reference) steps."""

    samples: int
    steps: float
    memory_bytes: float
    seconds: float


def format_bytes(n: float) -> str:
    """``3.1 GiB``, ``745 GiB``, ``12 MiB``: a byte count for a person."""
    for unit, size in (("TiB", 2.0**40), ("GiB", 2.0**30), ("MiB", 2.0**20)):
        if n >= size:
            return f"{n / size:.3g} {unit}"
    return f"{n / 2.0**10:.3g} KiB"


def format_seconds(s: float) -> str:
    """``40 s``, ``12 min``, ``3.5 h``, ``2.1e+03 days``: a duration for a person."""
    if s < 120:
        return f"{s:.2g} s"
    if s < 7200:
        return f"{s / 60:.3g} min"
    if s < 2 * 86400:
        return f"{s / 3600:.3g} h"
    return f"{s / 86400:.3g} days"


def estimate_ode_steps(
    rhs: Callable,
    y0: np.ndarray,
    duration_s: float,
    rtol: float,
    atol: float,
    probe_steps: int = PROBE_STEPS,
) -> float:
    """Estimated number of DOP853 steps to solve ``y' = rhs(t, y)`` over ``[0, duration_s]``.

    Takes up to ``probe_steps`` steps and extrapolates linearly in time; returns the exact count
    when the probe reaches the end. Raises :class:`InputError` when the solver fails or the state
    stops being finite (e.g. rates near the float range).
    """
    from scipy.integrate import DOP853

    with np.errstate(all="ignore"):  # rates near the float range: refused just below
        solver = DOP853(rhs, 0.0, y0, float(duration_s), rtol=rtol, atol=atol)
    for k in range(1, probe_steps + 1):
        with np.errstate(all="ignore"):
            message = solver.step()
        if solver.status == "failed" or not np.all(np.isfinite(solver.y)):
            raise InputError(
                f"Expected the rigid-body ODE to solve from its initial state, got "
                f"{message or 'a non-finite state'} at t = {solver.t:.3g} s"
            )
        if solver.status == "finished":
            return float(k)
    if not solver.t > 0:
        return math.inf
    return probe_steps * float(duration_s) / solver.t


def free_bytes(out: Path) -> int | None:
    """Free space on the file system where ``out`` will be made (its nearest existing parent),
    bytes; None when it cannot be told."""
    p = Path(out).absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    try:
        return shutil.disk_usage(p).free
    except OSError:
        return None

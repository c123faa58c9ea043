"""Export a replay for other tools: TUM trajectory files for evo.

``estimate.tum`` and ``truth.tum`` hold one line per sample, ``t x y z qx qy qz qw``: the stamp
in seconds (the log's clock, nanosecond digits), a zero position (attitude only) and ``q_w_b``
``[x, y, z, w]``. ``evo_ape tum truth.tum estimate.tum`` then compares the attitudes (use
``--pose_relation angle_deg``).
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from imu_dcm.errors import InputError
from imu_dcm.outputs import OutputError, check_not_input, check_output_file, write_text_atomic

__all__ = ["check_export_dir", "export_tum", "tum_text"]

TUM_NAMES = ("estimate.tum", "truth.tum")


def tum_text(t_ns: NDArray[np.int64], q_w_b: NDArray[np.float64]) -> str:
    """TUM lines ``t 0 0 0 qx qy qz qw`` for the rows of ``q_w_b`` (N, 4) that are finite."""
    t = np.asarray(t_ns, dtype=np.int64)
    q = np.asarray(q_w_b, dtype=float)
    if q.ndim != 2 or q.shape[1] != 4 or len(q) != len(t):
        raise InputError(f"Expected q_w_b of shape ({len(t)}, 4), got {q.shape}")
    ok = np.all(np.isfinite(q), axis=1)
    sec, nsec = np.divmod(t[ok], 1_000_000_000)
    lines = [
        f"{s}.{ns:09d} 0 0 0 {a:.17g} {b:.17g} {c:.17g} {d:.17g}"
        for s, ns, (a, b, c, d) in zip(sec.tolist(), nsec.tolist(), q[ok].tolist(), strict=True)
    ]
    return "".join(line + "\n" for line in lines)


def check_export_dir(folder: str | os.PathLike, inputs: Iterable[str | os.PathLike] = ()) -> Path:
    """Check ``--export-tum DIR`` before anything is written: DIR is a folder (or new, with an
    existing parent), not an input and not holding one; the two files in it are regular or new.
    """
    out = Path(os.path.abspath(os.path.realpath(os.fspath(folder))))
    inputs = tuple(inputs)
    check_not_input(out, inputs, "--export-tum folder")
    if not out.exists():
        check_output_file(out, inputs, "--export-tum folder")  # a writable parent folder
    elif not out.is_dir():
        raise OutputError(f"Expected --export-tum to name a folder, got a file {str(out)!r}")
    else:
        for name in TUM_NAMES:
            check_output_file(out / name, inputs, f"--export-tum {name}")
    return out


def export_tum(
    folder: str | os.PathLike,
    t_ns: NDArray[np.int64],
    q_est: NDArray[np.float64],
    q_truth: NDArray[np.float64] | None,
    inputs: Iterable[str | os.PathLike] = (),
) -> list[Path]:
    """Write ``estimate.tum`` (and ``truth.tum`` when a truth row is finite) into ``folder``.

    Returns the files written. Each file is whole or absent (atomic replace).
    """
    inputs = tuple(inputs)
    out = check_export_dir(folder, inputs)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(
            f"Expected to create the folder {str(out)!r}, got {type(exc).__name__}: {exc.strerror}"
        ) from None
    written = [write_text_atomic(out / "estimate.tum", tum_text(t_ns, q_est), inputs)]
    if q_truth is not None and np.isfinite(q_truth).all(axis=1).any():
        written.append(write_text_atomic(out / "truth.tum", tum_text(t_ns, q_truth), inputs))
    return written

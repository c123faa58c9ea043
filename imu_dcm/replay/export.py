"""Export a replay for other tools: TUM trajectory files for evo.

``estimate.tum`` and ``truth.tum`` begin with one comment line ``# imu_dcm <version> ...`` (the
signature by which a later run recognises its own file, :mod:`imu_dcm.outputs.signatures`; evo and
the
TUM tools skip ``#`` lines), then hold one line per sample, ``t x y z qx qy qz qw``: the stamp
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
from imu_dcm.outputs import Claim, OutputError, check_not_input, claim_output, write_atomic
from imu_dcm.outputs.signatures import comment_line

__all__ = ["TUM_NAMES", "claim_export", "export_tum", "tum_text"]

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


def claim_export(
    folder: str | os.PathLike, inputs: Iterable[str | os.PathLike] = ()
) -> tuple[Claim, Claim]:
    """Check ``--export-tum DIR`` before anything is written: DIR is a folder (or new, with an
    existing parent), not an input and not holding one; ``estimate.tum`` and ``truth.tum`` in it
    are new or TUM files this tool wrote (:func:`imu_dcm.outputs.claim_output`, kind ``tum``).
    Returns the two files' claims."""
    out = Path(os.path.abspath(os.path.realpath(os.fspath(folder))))
    inputs = tuple(inputs)
    check_not_input(out, inputs, "--export-tum folder")
    if out.exists() and not out.is_dir():
        raise OutputError(f"Expected --export-tum to name a folder, got a file {str(out)!r}")
    est, truth = (claim_output(out / n, "tum", inputs, what=f"--export-tum {n}") for n in TUM_NAMES)
    return est, truth


def export_tum(
    claims: tuple[Claim, Claim],
    t_ns: NDArray[np.int64],
    q_est: NDArray[np.float64],
    q_truth: NDArray[np.float64] | None,
) -> list[Path]:
    """Write ``estimate.tum`` (and ``truth.tum`` when a truth row is finite), claimed by
    :func:`claim_export`. Returns the files written. Each file is whole or absent (atomic
    replace)."""
    est, truth = claims
    head = "q_w_b of the {}: t x y z qx qy qz qw"
    written = [write_atomic(est, comment_line(head.format("estimate")) + tum_text(t_ns, q_est))]
    if q_truth is not None and np.isfinite(q_truth).all(axis=1).any():
        text = comment_line(head.format("truth")) + tum_text(t_ns, q_truth)
        written.append(write_atomic(truth, text))
    return written

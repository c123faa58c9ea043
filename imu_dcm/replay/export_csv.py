"""``--export-csv FILE``: the replay per estimate sample, as one CSV table.

One row per estimated gyro sample (from the first one inside the truth's coverage); the columns,
each named with its unit:

========================== ===================================================================
``t_ns``                   stamp, int64 ns, on the replay's time base (header or log time)
``t_s``                    s since the first gyro sample
``q_w_b_x`` … ``q_w_b_w``  the estimate ``q_w_b``, Hamilton, ``[x, y, z, w]``
``q_true_x`` … ``q_true_w`` the truth slerped at the stamp, where the sample is scored
``error_total_deg``        total error, deg (angle of ``q_est ⊗ q_true*``)
``error_inclination_deg``  inclination (tilt) error, deg
``error_heading_deg``      heading error (twist about the world vertical), deg
``error_body_x_deg`` …     body error vector ``e_b = log(q_true* ⊗ q_est)``, deg, body axes
========================== ===================================================================

Truth and error cells are empty where the sample is not scored (no truth there, or across a
truth jump). Numbers are written as the shortest text that reads back to the same double
(pyarrow's CSV writer), so the file's figures equal the summary's. Written whole or not at all.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from imu_dcm.arrays import row_finite
from imu_dcm.metrics import error_planes_rad
from imu_dcm.outputs import claim_output, claimed_path
from imu_dcm.outputs.rule import Claim
from imu_dcm.outputs.signatures import comment_line

__all__ = ["CSV_COLUMNS", "export_csv"]

CSV_COLUMNS = (
    "t_ns",
    "t_s",
    *(f"q_w_b_{c}" for c in "xyzw"),
    *(f"q_true_{c}" for c in "xyzw"),
    "error_total_deg",
    "error_inclination_deg",
    "error_heading_deg",
    *(f"error_body_{c}_deg" for c in "xyz"),
)


def _columns(result) -> list:
    """The table's columns over the estimated samples (NaN where not scored)."""
    k = slice(result.start_index, None)
    q_est, q_true = result.q_est[k], result.q_truth[k]
    err = result.error
    scored = np.isfinite(err.total_deg[k]) & row_finite(q_true)
    unit = np.array([0.0, 0.0, 0.0, 1.0])
    e_b = np.degrees(
        error_planes_rad(
            np.where(scored[:, None], q_est, unit), np.where(scored[:, None], q_true, unit), "body"
        )
    )
    e_b[:, ~scored] = np.nan
    q_true = np.where(scored[:, None], q_true, np.nan)
    return [
        result.t_ns[k],
        result.t_s[k],
        *q_est.T,
        *q_true.T,
        err.total_deg[k],
        err.inclination_deg[k],
        err.heading_deg[k],
        *e_b,
    ]


def claim_csv(path: str | os.PathLike, inputs: Iterable[str | os.PathLike] = ()):
    """Check ``--export-csv`` before the log is read (:func:`imu_dcm.outputs.claim_output`:
    new, or a CSV export of this tool's, never an input)."""
    return claim_output(path, "csv", tuple(inputs), what="--export-csv file")


def export_csv(path, result, inputs: Iterable[str | os.PathLike] = ()) -> Path:
    """Write the per-sample table of a :class:`imu_dcm.replay.summary.ReplayResult` to ``path``
    (a path, or the claim of :func:`claim_csv`).

    The first line is a comment naming this tool (``# imu_dcm <version> csv export``, so that a
    later run may replace the file: read with ``comment="#"`` or skip it), then the header.
    Returns the path written, whole or not at all.
    """
    import pyarrow as pa  # lazy: ~24 ms of CPU, for --export-csv only
    import pyarrow.csv as pacsv

    claim = path if isinstance(path, Claim) else claim_csv(path, inputs)
    arrays = [
        pa.array(np.ascontiguousarray(c), from_pandas=True)  # NaN -> null: an empty cell
        for c in _columns(result)
    ]
    table = pa.Table.from_arrays(arrays, names=list(CSV_COLUMNS))
    options = pacsv.WriteOptions(include_header=False, quoting_style="none")
    with claimed_path(claim) as tmp, open(tmp, "wb") as f:
        f.write(comment_line("csv export").encode())
        f.write((",".join(CSV_COLUMNS) + "\n").encode())  # plain names: no quotes
        pacsv.write_csv(table, f, options)
    return claim.path

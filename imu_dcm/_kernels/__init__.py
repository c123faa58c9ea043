"""The compiled kernels (private): the attitude update, log scans, series passes, ROS fields.

What the rest of the package uses is here (:data:`__all__`): the state layout and the codes of
a push (:mod:`~imu_dcm._kernels.state`), the checked entry points
(:mod:`~imu_dcm._kernels.calls`) and :func:`backend`, which says whether a process runs the
module built ahead of time or numba's compile (:mod:`~imu_dcm._kernels.loader`). Importing this
package imports neither numba nor the kernels' sources.

One kernel a file, each written for numba with its entry points:
:mod:`~imu_dcm._kernels.integrator` (the DCM recursion, the per-sample push, the end step, the
input check, the delta-angle rules), :mod:`~imu_dcm._kernels.ulog_scan` (PX4 ULog's record
chain), :mod:`~imu_dcm._kernels.mcap_scan` (a batch's MCAP message records),
:mod:`~imu_dcm._kernels.csv_scan` (live CSV lines), :mod:`~imu_dcm._kernels.series` (passes
over whole series) and :mod:`~imu_dcm._kernels.ros_fields` (the wanted fields of a batch of ROS
messages). :mod:`~imu_dcm._kernels.entries`
lists their entry points, :mod:`~imu_dcm._kernels.jit` compiles them with numba, and
:mod:`~imu_dcm._kernels.build` builds them ahead of time into ``imu_dcm._kernels._aot``
(``python -m imu_dcm._kernels.build``).
"""

from imu_dcm._kernels.calls import (
    check_record,
    close,
    feed,
    feed_delta,
    locate_batch,
    push,
    push_for,
    record_chain,
    scan_csv,
)
from imu_dcm._kernels.loader import backend
from imu_dcm._kernels.state import (
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
    "STATE_FIELDS",
    "STATE_SIZE",
    "T",
    "W",
    "backend",
    "check_record",
    "close",
    "feed",
    "feed_delta",
    "feed_entry",
    "locate_batch",
    "new_state",
    "push",
    "push_entry",
    "push_for",
    "record_chain",
    "scan_csv",
    "state_fields",
]

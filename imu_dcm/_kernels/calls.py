"""The kernels' entry points as the package calls them: arrays checked, then the compiled code.

One kernel serves the batch :func:`imu_dcm.integrate`, :func:`imu_dcm.integrate_delta` and the
streaming :class:`imu_dcm.DcmIntegrator`: every sample goes through :func:`push` (or
:func:`feed`, the same over an array), which keeps what carries across samples in a small
``state`` array (:mod:`imu_dcm._kernels.state`) and commits each step as soon as its stencil is
complete. Batch is "feed every sample, then :func:`close`"; streaming feeds them as they come,
so the two are the same arithmetic. The code itself is :mod:`imu_dcm._kernels.integrator`;
:func:`record_chain` and :func:`scan_csv` run the ULog and CSV scans
(:mod:`~imu_dcm._kernels.ulog_scan`, :mod:`~imu_dcm._kernels.csv_scan`), :func:`locate_batch`
the MCAP records of a batch (:mod:`~imu_dcm._kernels.mcap_scan`), and :func:`step_rotvecs`,
:func:`slerp_rows`, :func:`integrated_rate`, :func:`window_norms`, :func:`min_steps`,
:func:`attitude_errors`, :func:`error_vectors`, :func:`quat_angles`, :func:`second_steps`,
:func:`rate_ratios`,
:func:`window_rates` and :func:`row_norms` the passes over whole series
(:mod:`~imu_dcm._kernels.series`), and :func:`walk_fields` the wanted fields of a batch of ROS
messages (:mod:`~imu_dcm._kernels.ros_fields`).

Conventions: quaternions Hamilton ``[x, y, z, w]``, ``q_w_b`` body to world; rates ``ω`` rad/s
in body axes; stamps ``t`` s; increments multiply on the right.

The compiled entry points (:func:`imu_dcm._kernels.loader.entry`) take float64 C-contiguous
arrays and do not check their types: the functions below check the arrays of a batch call (a
``TypeError`` otherwise), and :func:`push_for` gives the unchecked per-sample function, whose
caller converts (as :class:`imu_dcm.DcmIntegrator` does).
"""

from __future__ import annotations

import numpy as np

from imu_dcm._kernels.loader import backend, entry
from imu_dcm._kernels.state import CLOSED, METHOD, N, feed_entry, push_entry
from imu_dcm.integrator.methods import Method

__all__ = [
    "attitude_errors",
    "check_record",
    "close",
    "error_vectors",
    "feed",
    "feed_delta",
    "integrated_rate",
    "locate_batch",
    "min_steps",
    "push",
    "push_for",
    "quat_angles",
    "rate_ratios",
    "record_chain",
    "row_norms",
    "scan_csv",
    "second_steps",
    "slerp_rows",
    "step_rotvecs",
    "walk_fields",
    "window_norms",
    "window_rates",
]


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
    starts (:func:`imu_dcm._kernels.ulog_scan.record_chain`)."""
    if not (isinstance(b, np.ndarray) and b.dtype == np.uint8 and b.ndim == 1):
        raise TypeError(f"Expected `b` a 1-D uint8 array, got {type(b).__name__}")
    b = np.ascontiguousarray(b)
    if backend() == "jit" and not b.flags.writeable:
        b = b.copy()  # numba's signature is of a writable array (the built one reads any)
    return entry("record_chain")(b, int(pos))


def locate_batch(buf, offs, seg, seg_chunk, seg_slot, bases, sizes, seqs, slot_cid) -> tuple:
    """The MCAP message records a batch's message indexes point at, located, checked and
    grouped by channel slot in one compiled pass
    (:func:`imu_dcm._kernels.mcap_scan.locate_batch`): ``(start, length, log_time, order,
    bounds, gaps, bad)``, ``bad`` -1 when every record checks out."""
    if not (isinstance(buf, np.ndarray) and buf.dtype == np.uint8 and buf.ndim == 1):
        raise TypeError(f"Expected `buf` a 1-D uint8 array, got {type(buf).__name__}")
    ints = [
        np.ascontiguousarray(a, dtype=np.int64)
        for a in (offs, seg, seg_chunk, seg_slot, bases, sizes, seqs, slot_cid)
    ]
    offs, seg, seg_chunk, seg_slot, bases, sizes, seqs, slot_cid = ints
    n_seg = len(seg) - 1
    fits = (
        n_seg >= 0
        and seg[0] == 0
        and seg[-1] == len(offs)
        and np.all(np.diff(seg) >= 0)
        and len(seg_chunk) == len(seg_slot) == n_seg
        and len(sizes) == len(seqs) == len(bases)
        and (not len(bases) or (bases.min() >= 0 and (bases + sizes).max() <= len(buf)))
    )
    if fits and n_seg:  # each segment's chunk (in order) and slot exist
        fits = np.all(np.diff(seg_chunk) >= 0) and seg_chunk[0] >= 0
        fits = fits and seg_chunk[-1] < len(bases) and seg_slot.min() >= 0
        fits = fits and seg_slot.max() < len(slot_cid)
    if not fits:
        raise TypeError("Expected segments that match their entries, chunks and slots")
    buf = np.ascontiguousarray(buf)
    if backend() == "jit" and not buf.flags.writeable:
        buf = buf.copy()  # numba's signature is of a writable array (the built one reads any)
    *arrays, bad = entry("locate_batch")(buf, *ints)
    return (*arrays, int(bad))


def walk_fields(buf, start, length, cdr: bool, steps, out, good) -> int:
    """The wanted values of the messages ``buf[start[i] : start[i] + length[i]]`` (CDR, else
    ROS 1) into the rows of ``out`` (n, W) uint64, following the layout ``steps`` (k, 6) int64
    (:mod:`~imu_dcm._kernels.field_steps`); ``good[i]`` whether message ``i`` lies inside
    ``buf`` and holds them all (:func:`imu_dcm._kernels.ros_fields.walk_fields`). Returns how
    many do not."""
    if not (isinstance(buf, np.ndarray) and buf.dtype == np.uint8 and buf.ndim == 1):
        raise TypeError(f"Expected `buf` a 1-D uint8 array, got {type(buf).__name__}")
    start, length = (np.ascontiguousarray(a, dtype=np.int64) for a in (start, length))
    n = len(start)
    if not (
        len(length) == n
        and isinstance(steps, np.ndarray) and steps.dtype == np.int64
        and steps.ndim == 2 and steps.shape[1] == 6 and steps.flags.c_contiguous
        and isinstance(out, np.ndarray) and out.dtype == np.uint64
        and out.ndim == 2 and len(out) == n and out.flags.c_contiguous
        and isinstance(good, np.ndarray) and good.dtype == np.bool_ and good.shape == (n,)
    ):  # fmt: skip
        raise TypeError(
            "Expected start and length (n,), steps (k, 6) int64, out (n, W) uint64, good (n,) bool"
        )
    kind, size, count, col, want = steps[:, 0], steps[:, 1], steps[:, 2], steps[:, 4], steps[:, 5]
    if len(steps) and not (
        np.isin(size, (1, 2, 4, 8)).all()
        and (count >= 0).all()
        and (col >= -1).all()
        and (col + want <= out.shape[1]).all()
        and (want <= np.where((kind == 0) & (col >= 0), count, 0)).all()
    ):
        raise TypeError("Expected steps of 1, 2, 4 or 8 bytes whose wanted values fit `out`")
    buf = np.ascontiguousarray(buf)
    if backend() == "jit" and not buf.flags.writeable:
        buf = buf.copy()  # numba's signature is of a writable array (the built one reads any)
    return int(entry("walk_fields")(buf, start, length, bool(cdr), steps, out, good))


def scan_csv(blob: bytes, scale: int, digits: int) -> tuple[np.ndarray, bytes, int]:
    """Plain CSV lines ``t,gx,gy,gz`` of ``blob`` in one compiled pass
    (:func:`imu_dcm._kernels.csv_scan.csv_scan`): ``(t_ns, rates_text, rows)``, the exact
    stamps, the rate fields as ``b"gx,gy,gz,..."``, and the lines read; ``rows < 0`` when a line
    is not of that form."""
    b = np.frombuffer(blob, np.uint8)
    if backend() == "jit":
        b = b.copy()  # numba's signature is of a writable array (the built one reads any)
    t, text, rows = entry("csv_scan")(b, int(scale), int(digits))
    return t, text.tobytes(), int(rows)


def step_rotvecs(q, ok, out) -> int:
    """``out[k] = log(q_k⁻¹ ⊗ q_{k+1})`` for the rows of ``q`` (n, 4), NaN where ``ok[k]`` or
    ``ok[k + 1]`` is False (:func:`imu_dcm._kernels.series.step_rotvecs`); the first pair
    with a zero or non-finite norm (-1: none)."""
    _arrays(q=(q, 2), out=(out, 2))
    if not (isinstance(ok, np.ndarray) and ok.dtype == np.bool_ and ok.ndim == 1):
        raise TypeError(f"Expected `ok` a 1-D bool array, got {type(ok).__name__}")
    if q.shape[1:] != (4,) or out.shape != (max(len(q) - 1, 0), 3) or len(ok) != len(q):
        raise TypeError(
            f"Expected q (n, 4), ok (n,) and out (n - 1, 3), got {q.shape}, {ok.shape}, {out.shape}"
        )
    return int(entry("step_rotvecs")(q, np.ascontiguousarray(ok), out))


def slerp_rows(tt, q, norm, bridged, t, out) -> None:
    """The attitudes ``q[j] / norm[j]`` at stamps ``tt`` (int64, strictly increasing) slerped
    at the stamps ``t`` into ``out`` (len(t), 4), NaN outside them and across a step that
    ``bridged`` (len(tt) - 1,) does not bridge
    (:func:`imu_dcm._kernels.series.slerp_rows`)."""
    _arrays(q=(q, 2), norm=(norm, 1), out=(out, 2))
    ints = [np.ascontiguousarray(a, dtype=np.int64) for a in (tt, t)]
    bridged = np.ascontiguousarray(bridged, dtype=bool)
    if q.shape != (len(ints[0]), 4) or len(norm) != len(q) or out.shape != (len(ints[1]), 4):
        raise TypeError(
            f"Expected tt (m,), q (m, 4), norm (m,), t (n,) and out (n, 4), got "
            f"{ints[0].shape}, {q.shape}, {norm.shape}, {ints[1].shape}, {out.shape}"
        )
    if len(bridged) != max(len(q) - 1, 0):
        raise TypeError(f"Expected `bridged` of {max(len(q) - 1, 0)} steps, got {len(bridged)}")
    entry("slerp_rows")(ints[0], q, norm, bridged, ints[1], out)


def integrated_rate(t_ns, w, at_ns, out) -> None:
    """The trapezoid integral of ``w`` (N, C) over ``t_ns`` (N >= 1, increasing) at the
    stamps ``at_ns`` (non-decreasing) into ``out`` (K, C)
    (:func:`imu_dcm._kernels.series.integrated_rate`)."""
    _arrays(w=(w, 2), out=(out, 2))
    t, at = (np.ascontiguousarray(a, dtype=np.int64) for a in (t_ns, at_ns))
    if len(t) < 1 or len(w) != len(t) or out.shape != (len(at), w.shape[1]):
        raise TypeError(
            f"Expected t_ns (N >= 1,), w (N, C) and out (K, C), got {t.shape}, {w.shape}, "
            f"{out.shape} for {at.shape} stamps"
        )
    entry("integrated_rate")(t, w, at, out)


def window_norms(x, m: int, norm, max_var) -> None:
    """The norm of the mean and the largest column's variance of every window of ``m`` rows of
    ``x`` (N, k), ``1 <= m <= N``, into ``norm`` and ``max_var`` (N - m + 1,)
    (:func:`imu_dcm._kernels.series.window_norms`)."""
    _arrays(x=(x, 2), norm=(norm, 1), max_var=(max_var, 1))
    if not 1 <= m <= len(x) or len(norm) != len(x) - m + 1 or len(max_var) != len(norm):
        raise TypeError(
            f"Expected 1 <= m <= N and outputs of N - m + 1, got m={m}, x {x.shape}, "
            f"{norm.shape}, {max_var.shape}"
        )
    entry("window_norms")(x, int(m), norm, max_var)


def min_steps(x, out) -> None:
    """The smallest positive step of each column of ``x`` (N, k) into ``out`` (k,)
    (:func:`imu_dcm._kernels.series.min_steps`)."""
    _arrays(x=(x, 2), out=(out, 1))
    if out.shape != x.shape[1:]:
        raise TypeError(f"Expected `out` of {x.shape[1:]}, got {out.shape}")
    entry("min_steps")(x, out)


def attitude_errors(q_est, q_true, out) -> int:
    """The total, inclination and heading error, deg, of each row of ``q_est`` against
    ``q_true`` (n, 4) into the rows of ``out`` (3, n)
    (:func:`imu_dcm._kernels.series.attitude_errors`);
    the first row with a zero or non-finite norm (-1: none)."""
    _arrays(q_est=(q_est, 2), q_true=(q_true, 2), out=(out, 2))
    if q_est.shape[1:] != (4,) or q_true.shape != q_est.shape or out.shape != (3, len(q_est)):
        raise TypeError(
            f"Expected q_est and q_true (n, 4) and out (3, n), got {q_est.shape}, "
            f"{q_true.shape}, {out.shape}"
        )
    return int(entry("attitude_errors")(q_est, q_true, out))


def error_vectors(q_est, q_true, angle, out) -> None:
    """The world and body error vectors, rad, of each row of ``q_est`` against ``q_true``
    (n, 4), of known angles ``angle`` (n,) rad, into the rows of ``out`` (6, n)
    (:func:`imu_dcm._kernels.series.error_vectors`)."""
    _arrays(q_est=(q_est, 2), q_true=(q_true, 2), angle=(angle, 1), out=(out, 2))
    n = len(q_est)
    if (
        q_est.shape[1:] != (4,)
        or q_true.shape != q_est.shape
        or angle.shape != (n,)
        or (out.shape != (6, n))
    ):
        raise TypeError(
            f"Expected q_est and q_true (n, 4), angle (n,) and out (6, n), got {q_est.shape}, "
            f"{q_true.shape}, {angle.shape}, {out.shape}"
        )
    entry("error_vectors")(q_est, q_true, angle, out)


def _flags(**flags) -> None:
    for name, a in flags.items():
        if not (isinstance(a, np.ndarray) and a.dtype == np.bool_ and a.ndim == 1):
            raise TypeError(f"Expected `{name}` a 1-D bool array, got {type(a).__name__}")


def second_steps(q, ok, step_ok, out) -> int:
    """``|d_{k+1} - d_k|`` of the consecutive usable steps of ``q`` (n, 4) into the columns of
    ``out`` (3, >= n - 2); how many (:func:`imu_dcm._kernels.series.second_steps`)."""
    _arrays(q=(q, 2), out=(out, 2))
    _flags(ok=ok, step_ok=step_ok)
    n = len(q)
    if (
        q.shape[1:] != (4,)
        or len(ok) != n
        or len(step_ok) != max(n - 1, 0)
        or (out.shape[0] != 3 or out.shape[1] < max(n - 2, 0))
    ):
        raise TypeError(
            f"Expected q (n, 4), ok (n,), step_ok (n - 1,) and out (3, >= n - 2), got "
            f"{q.shape}, {ok.shape}, {step_ok.shape}, {out.shape}"
        )
    ok, step_ok = np.ascontiguousarray(ok), np.ascontiguousarray(step_ok)
    return int(entry("second_steps")(q, ok, step_ok, out))


def rate_ratios(w, t, q, ok, moving: float, out) -> int:
    """The gyro's rate over the truth's on each step of ``q`` (n, 4) where both ends are ``ok``
    and the truth turns faster than ``moving`` rad/s, into ``out`` (>= n - 1); how many
    (:func:`imu_dcm._kernels.series.rate_ratios`)."""
    _arrays(w=(w, 2), t=(t, 1), q=(q, 2), out=(out, 1))
    _flags(ok=ok)
    n = len(q)
    if (
        w.shape != (n, 3)
        or q.shape[1:] != (4,)
        or len(t) != n
        or len(ok) != n
        or (len(out) < max(n - 1, 0))
    ):
        raise TypeError(
            f"Expected w (n, 3), t (n,), q (n, 4), ok (n,) and out (>= n - 1,), got {w.shape}, "
            f"{t.shape}, {q.shape}, {ok.shape}, {out.shape}"
        )
    return int(entry("rate_ratios")(w, t, q, np.ascontiguousarray(ok), float(moving), out))


def row_norms(x, out) -> None:
    """The norm of each row of ``x`` (n, k) float64, any strides, into ``out`` (n,)
    (:func:`imu_dcm._kernels.series.row_norms`)."""
    _arrays(out=(out, 1))
    if not (isinstance(x, np.ndarray) and x.dtype == np.float64 and x.ndim == 2):
        raise TypeError(f"Expected `x` a 2-D float64 array, got {type(x).__name__}")
    if len(out) != len(x):
        raise TypeError(f"Expected `out` of {len(x)} rows, got {out.shape}")
    if backend() == "jit" and not x.flags.writeable:
        x = x.copy()  # numba's signature is of a writable array (the built one reads any)
    entry("row_norms")(x, out)


def quat_angles(q_a, q_b, out) -> int:
    """The angle, rad, of ``q_a* ⊗ q_b`` for each row of ``q_a`` and ``q_b`` (n, 4) into ``out``
    (n,) (:func:`imu_dcm._kernels.series.quat_angles`); the first row with a zero or
    non-finite norm (-1: none)."""
    _arrays(q_a=(q_a, 2), q_b=(q_b, 2), out=(out, 1))
    if q_a.shape[1:] != (4,) or q_b.shape != q_a.shape or out.shape != (len(q_a),):
        raise TypeError(
            f"Expected q_a and q_b (n, 4) and out (n,), got {q_a.shape}, {q_b.shape}, {out.shape}"
        )
    return int(entry("quat_angles")(q_a, q_b, out))


def window_rates(q, t, ok, m: int, out) -> None:
    """``|omega_T|`` of every window of ``m >= 2`` rows of ``q`` (n, 4) at ``t`` (n,) s into
    ``out`` (n - m + 1,), NaN where a step is not between two ``ok`` rows
    (:func:`imu_dcm._kernels.series.window_rates`)."""
    _arrays(q=(q, 2), t=(t, 1), out=(out, 1))
    _flags(ok=ok)
    n = len(q)
    if (
        q.shape[1:] != (4,)
        or len(t) != n
        or len(ok) != n
        or not 2 <= m <= max(n, 2)
        or (out.shape != (max(n - m + 1, 0),))
    ):
        raise TypeError(
            f"Expected q (n, 4), t (n,), ok (n,), 2 <= m and out (n - m + 1,), got {q.shape}, "
            f"{t.shape}, {ok.shape}, m={m}, {out.shape}"
        )
    entry("window_rates")(q, t, np.ascontiguousarray(ok), int(m), out)

"""Streaming DCM integrator: one sample (or a chunk) at a time, equal to the batch result.

:class:`DcmIntegrator` holds only what carries across samples — the attitude, the last four rate
samples and their stamps, the sample count — in one small array that the compiled kernel
(:mod:`imu_dcm._kernels`) updates in place. The batch :func:`imu_dcm.integrate` runs the very same
kernel over the whole record, so the two do the same arithmetic. Conventions are the batch
ones: ``q_w_b`` Hamilton ``[x, y, z, w]`` body to world, ``omega_b`` rad/s in body axes,
increments on the right, ``t_s`` seconds.

**The look-ahead of magnus4.** The mid-step rate of step ``[t_i, t_{i+1}]`` comes from the cubic
through ``ω_{i-1..i+2}``, so step ``i`` is final only once sample ``i+2`` has arrived. Two ways
to stream it were measured (``python -m benchmarks.core_speed``, look-ahead table; pure coning,
half-angle 0.3 rad at 2 Hz, max error over 1 s):

* *lag one sample*: after sample ``k`` return the attitude at ``t_{k-1}``: the batch result at
  that stamp (to rounding); :meth:`DcmIntegrator.finish` closes the last step with the batch's
  one-sided end stencil. Error 3.8e-4 deg at 100 Hz, 3.9e-8 deg at 1 kHz.
* *causal*: close step ``i`` at once with the one-sided cubic through ``ω_{i-2..i+1}``: also
  fourth order and as accurate (3.0e-4 / 3.0e-8 deg), but a different integrator from the batch
  one, so streaming would no longer equal batch.

``magnus4`` streams with the one-sample lag: streaming then equals batch for every method
(tested to 1e-9 deg) and :attr:`DcmIntegrator.t_s` names the stamp of the returned attitude.
Reading the lagged attitude as if it were at ``t_k`` costs one sample of motion (2.2 deg at
100 Hz in the same test). The other methods have no look-ahead and no lag.
"""

from __future__ import annotations

import itertools
import math
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imu_dcm import _kernels as kernel
from imu_dcm.errors import Diagnostics, GapWarning, InputError, say
from imu_dcm.integrator.batch import (
    as_float_array,
    check_method,
    find_gaps,
    gap_message,
    to_rotation,
    warn_rotvec_sum,
)
from imu_dcm.integrator.methods import GAP_FACTOR, METHODS, Method
from imu_dcm.so3 import as_quat_xyzw

if TYPE_CHECKING:
    from scipy.spatial.transform import Rotation

__all__ = ["DcmIntegrator"]

_F8 = np.dtype(np.float64)  # numpy's one native float64 dtype: `is` compares it


class DcmIntegrator:
    """Streaming strapdown integrator ``q_w_b <- q_w_b ⊗ exp(φ)``, the twin of
    :func:`imu_dcm.integrate`.

    Parameters
    ----------
    q0 : array_like (4,) or (3, 3), or scipy ``Rotation``
        Attitude ``q_w_b`` (``[x, y, z, w]``), ``R_w_b`` or ``Rotation`` at the first sample's
        stamp (or at ``t0_s`` when given).
    method : str
        As :func:`imu_dcm.integrate`: ``magnus4`` (default; returns the attitude one sample
        late, see the module doc), ``coning``, ``trapezoid``, ``start``, ``end``, ``rotvec_sum``.
    t0_s : float or None
        Stamp of ``q0``. ``None`` (default): ``q0`` is the attitude at the first sample. A float:
        ``q0`` is the attitude at ``t0_s`` and the first sample's rate is taken to hold from
        ``t0_s`` (as if that sample had also been received at ``t0_s``).
    diagnostics : Diagnostics, optional
        Receives the one-line warnings (a gap, ``rotvec_sum``) instead of :mod:`warnings`, as
        :func:`imu_dcm.integrate`'s do: a pass that runs on a thread of its own then leaves the
        process's warning filters alone.

    Notes
    -----
    Feeding ``omega_b[k], t_s[k]`` for ``k = 0..N-1`` and calling :meth:`finish` reproduces
    ``integrate(omega_b, t_s, q0, method)`` sample by sample (``t0_s=None``): both run the same
    compiled kernel. The first integrator of a process loads the kernel (numba;
    see docs/integrator.md for its cache).

    Examples
    --------
    >>> import numpy as np
    >>> integ = DcmIntegrator([0, 0, 0, 1], method="trapezoid")
    >>> for k in range(101):
    ...     q = integ.update([0.0, 0.0, np.pi / 2], 0.01 * k)   # 90 deg/s about body z
    >>> q.round(6), integ.t_s
    (array([0.      , 0.      , 0.707107, 0.707107]), 1.0)
    """

    def __init__(
        self,
        q0: ArrayLike | Rotation,
        method: str = "magnus4",
        t0_s: float | None = None,
        diagnostics: Diagnostics | None = None,
    ) -> None:
        check_method(method, METHODS)
        self._diagnostics = diagnostics
        try:
            t0 = None if t0_s is None else float(t0_s)
        except (TypeError, ValueError):
            raise InputError(f"Expected `t0_s` a number (s) or None, got {t0_s!r}") from None
        if t0 is not None and not math.isfinite(t0):
            raise InputError(f"Expected `t0_s` finite or None, got {t0_s}")
        self._method = method
        self._t0_s = t0
        self._state = kernel.new_state(as_quat_xyzw(q0), Method[method.upper()])
        self._q = self._state[kernel.Q : kernel.Q + 4]  # a view: the attitude, updated in place
        self._push = kernel.push_for(int(Method[method.upper()]))
        self._finished = False
        self._t0_pending = t0 is not None
        if method == "rotvec_sum":
            warn_rotvec_sum(diagnostics=diagnostics)

    # -- read-only state ------------------------------------------------------------------------

    @property
    def method(self) -> str:
        """The increment rule."""
        return self._method

    @property
    def q_w_b(self) -> NDArray[np.float64]:
        """Current attitude ``[x, y, z, w]``, body to world, shape (4,)."""
        return self._q.copy()

    @property
    def rotation(self) -> Rotation:
        """Current attitude as a scipy ``Rotation``."""
        from scipy.spatial.transform import Rotation

        return Rotation.from_quat(self._q)

    def state(self) -> dict[str, NDArray[np.float64]]:
        """A copy of the kernel state, field by field (:data:`imu_dcm._kernels.STATE_FIELDS`:
        the attitude, the last four rates and stamps, the sample count, ...)."""
        return kernel.state_fields(self._state.copy())

    @property
    def n_samples(self) -> int:
        """Samples received (a ``t0_s`` start counts as one)."""
        return int(self._state[kernel.N])

    @property
    def t_s(self) -> float | None:
        """Stamp (s) of the current attitude; ``None`` before the first sample (unless ``t0_s``)."""
        n = self.n_samples
        if n == 0:
            return self._t0_s
        slot = 3  # the newest of the four buffered stamps
        if self._method == "magnus4" and not self._finished:
            slot = 2 if n >= 4 else 4 - n  # one sample late; the first sample until step 0 ends
        return float(self._state[kernel.T + slot])

    # -- feeding --------------------------------------------------------------------------------

    def update(self, omega_b: ArrayLike, t_s: float) -> NDArray[np.float64]:
        """Add one rate sample; return the current attitude.

        Parameters
        ----------
        omega_b : array_like, shape (3,)
            Body rate relative to the world, in body axes, rad/s.
        t_s : float
            Its stamp, s, greater than the previous one.

        Returns
        -------
        ndarray, shape (4,)
            ``q_w_b`` ``[x, y, z, w]`` at :attr:`t_s` (the newest stamp; for ``magnus4`` the one
            before, see the module doc). A plain array, not a ``Rotation``: constructing a scipy
            ``Rotation`` costs ~13 µs, ten times this update (use :attr:`rotation`).

        Raises
        ------
        InputError
            Not 3 finite numbers, stamp not finite or not after the previous one, or called
            after :meth:`finish`.

        Warns
        -----
        GapWarning
            The step is a gap (:func:`imu_dcm.integrator.batch.find_gaps`) among the last four
            steps.
        """
        # The compiled push takes a float64 (3,) C-contiguous array and a float, unchecked:
        # anything else is converted here first. It checks the sample (finite, increasing, not
        # closed) and returns a code.
        # (1-D float64 with stride 8 is contiguous; the push refuses a length other than 3.)
        if type(omega_b) is not np.ndarray or omega_b.strides != (8,) or omega_b.dtype is not _F8:
            omega_b = self._as_rate(omega_b, t_s)
        if not isinstance(t_s, float):  # float, or numpy's float64 (a float subclass)
            t_s = self._as_stamp(omega_b, t_s)
        if self._t0_pending:
            self._start_at_t0(omega_b, t_s)
        code = self._push(self._state, omega_b, t_s)
        if code:
            self._not_ok(code, omega_b, t_s)
        return self._q.copy()

    def _as_rate(self, omega_b: ArrayLike, t_s: object) -> NDArray[np.float64]:
        try:
            w = np.ascontiguousarray(omega_b, dtype=np.float64)
        except (TypeError, ValueError):
            w = None
        if w is None or w.shape != (3,):
            raise InputError(
                f"Expected `omega_b` 3 numbers (rad/s) and `t_s` a number, got "
                f"{omega_b!r} and {t_s!r} (sample {self.n_samples})"
            )
        return w

    def _as_stamp(self, omega_b: object, t_s: object) -> float:
        try:
            return float(t_s)
        except (TypeError, ValueError):
            raise InputError(
                f"Expected `omega_b` 3 numbers (rad/s) and `t_s` a number, got "
                f"{omega_b!r} and {t_s!r} (sample {self.n_samples})"
            ) from None

    def _start_at_t0(self, w: NDArray, t: float) -> None:
        """First sample with ``t0_s``: its rate enters at ``t0_s`` too."""
        if self._finished:
            raise InputError("Expected no samples after finish(), got one")
        if not t > self._t0_s:
            raise InputError(f"Expected the first `t_s` after t0_s = {self._t0_s!r} s, got {t!r} s")
        code = self._push(self._state, w, self._t0_s)
        if code:
            self._not_ok(code, w, self._t0_s)
        self._t0_pending = False

    def _not_ok(self, code: int, w: NDArray, t: float) -> None:
        """Raise for a refused sample (the state is unchanged) or warn about a gap."""
        n = self.n_samples
        if code == kernel.IS_CLOSED:
            raise InputError("Expected no samples after finish(), got one")
        if code == kernel.NOT_FINITE and w.shape != (3,):
            self._as_rate(w, t)  # raises: not 3 numbers
        if code == kernel.NOT_FINITE:
            raise InputError(
                f"Expected finite `omega_b` and `t_s`, got {w.tolist()} at t_s = {t} (sample {n})"
            )
        if code == kernel.NOT_INCREASING:
            last = float(self._state[kernel.T + 3])
            raise InputError(
                f"Expected `t_s` strictly increasing, got t_s[{n}] = {t!r} s "
                f"after t_s[{n - 1}] = {last!r} s"
            )
        gaps = find_gaps(self._state[kernel.T + max(0, 4 - n) : kernel.T + 4])
        if gaps:
            say(self._diagnostics, gap_message(gaps), GapWarning, stacklevel=3)

    def finish(self) -> NDArray[np.float64]:
        """Close the record: for ``magnus4`` commit the last step (one-sided end stencil, as the
        batch does) and return the attitude at the last stamp. Other methods: no-op.

        No sample may follow. Returns the ``[x, y, z, w]`` attitude, shape (4,).
        """
        if not self._finished:
            kernel.close(self._state, False)
            self._finished = True
        return self._q.copy()

    def update_many(self, omega_b: ArrayLike, t_s: ArrayLike) -> Rotation:
        """Add a chunk of samples; return the attitude after each one.

        Parameters
        ----------
        omega_b : array_like, shape (n, 3)
            Body rates, rad/s, body axes.
        t_s : array_like, shape (n,)
            Their stamps, s, strictly increasing and after the previous sample.

        Returns
        -------
        scipy.spatial.transform.Rotation, length n
            Element ``j`` is what :meth:`update` would have returned after sample ``j``
            (``magnus4``: the attitude one stamp earlier).

        Raises
        ------
        InputError
            As :meth:`update`, for the first bad sample of the chunk.

        Warns
        -----
        GapWarning
            A gap (:func:`imu_dcm.integrator.batch.find_gaps`) in the chunk with the buffered
            stamps.
        """
        return to_rotation(self._many(omega_b, t_s))

    def update_many_quat(self, omega_b: ArrayLike, t_s: ArrayLike) -> NDArray[np.float64]:
        """:meth:`update_many` as an ``(n, 4)`` array of ``[x, y, z, w]`` attitudes, without
        building a scipy ``Rotation`` (which costs more than integrating a short chunk)."""
        return self._many(omega_b, t_s)

    def _many(self, omega_b: ArrayLike, t_s: ArrayLike) -> NDArray[np.float64]:
        """The body of :meth:`update_many` and :meth:`update_many_quat` (warnings name their
        caller's caller)."""
        w = np.asarray(omega_b)
        t = np.asarray(t_s)
        if w.ndim != 2 or w.shape[1] != 3 or t.shape != (len(w),):
            raise InputError(
                f"Expected `omega_b` (n, 3) and `t_s` (n,), got {w.shape} and {t.shape}"
            )
        if len(w) == 0:
            raise InputError("Expected at least one sample, got 0")
        if self._finished:
            raise InputError("Expected no samples after finish(), got some")
        w = as_float_array(w, "omega_b")
        t = as_float_array(t, "t_s")
        n_user = len(t)
        if self._t0_pending:
            w = np.vstack([w[:1], w])
            t = np.concatenate([[self._t0_s], t])
        w, t = self._checked(w, t)
        self._t0_pending = False
        n0 = self.n_samples
        q_before = self._q.copy()
        out = np.empty((len(t) + 1, 4))
        k = kernel.feed(self._state, w, t, out, False)
        if n0 >= (4 if self._method == "magnus4" else 1) and k == n_user:
            return out[:k]  # steady state: one committed row per sample
        # Warm-up: row j is the attitude committed by then (the start attitude before any).
        n_after = n0 + np.arange(1, len(t) + 1)
        rows = np.vstack([q_before, out[:k]])
        idx = self._committed(n_after) - self._committed(np.array([n0]))
        return np.ascontiguousarray(rows[idx][-n_user:])

    def _committed(self, n: NDArray) -> NDArray:
        """Rows committed after ``n`` samples in all."""
        if self._method == "magnus4":
            return np.where(n >= 4, n - 2, 0)
        return np.maximum(n - 1, 0)

    def _checked(self, w: NDArray, t: NDArray) -> tuple[NDArray, NDArray]:
        """Check a chunk as the continuation of the record (finite, increasing across the
        junction, gaps among the buffered and new stamps); one compiled pass."""
        n = self.n_samples
        w, t = np.ascontiguousarray(w), np.ascontiguousarray(t)
        stamps = self._state[kernel.T + 4 - min(n, 4) : kernel.T + 4]  # buffered, oldest first
        t_before = stamps[-1] if n else -math.inf
        row, stamp, order, dt_min, dt_max = kernel.check_record(w, t, t_before)
        if row >= 0:
            raise InputError(
                f"Expected finite `omega_b`, got {w[row].tolist()} at row {row} (sample {n + row})"
            )
        if stamp >= 0:
            raise InputError(
                f"Expected finite `t_s`, got t_s[{stamp}] = {float(t[stamp])} (sample {n + stamp})"
            )
        if order >= 0:
            before = t[order - 1] if order else t_before
            raise InputError(
                f"Expected `t_s` strictly increasing, got t_s[{n + order}] = "
                f"{float(t[order])!r} s after t_s[{n + order - 1}] = "
                f"{float(before)!r} s"
            )
        old = stamps.tolist()
        for a, b in itertools.pairwise(old):
            dt_min = min(dt_min, b - a)
        if dt_max > GAP_FACTOR * dt_min:  # else no step can exceed GAP_FACTOR x the median
            gaps = find_gaps(np.concatenate([stamps, t]))
            if gaps:
                say(self._diagnostics, gap_message(gaps), GapWarning, stacklevel=4)
        return w, t

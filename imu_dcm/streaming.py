"""Streaming DCM integrator: one sample (or a chunk) at a time, equal to the batch result.

:class:`DcmIntegrator` holds only what carries across samples — the attitude, the last few rate
samples and stamps, a step counter, a memo of magnus4 weights — and delegates every formula to
:mod:`imu_dcm.integrate` (``phi_parts`` and its magnus4 halves, ``exp_parts``, ``rate_quats``)
and :mod:`imu_dcm.scan`. Conventions are the batch ones: ``q_w_b`` Hamilton ``[x, y, z, w]``
body to world, ``omega_b`` rad/s in body axes, increments on the right, ``t_s`` seconds.

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
import warnings

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from imu_dcm.errors import GapWarning, InputError
from imu_dcm.integrate import (
    GAP_FACTOR,
    METHODS,
    _as_float_array,
    _check_method,
    _to_rotation,
    _warn_rotvec_sum,
    check_samples,
    exp_parts,
    magnus4_phi,
    magnus4_weights,
    phi_parts,
    rate_quats,
)
from imu_dcm.scan import quat_mul_parts
from imu_dcm.so3 import as_quat_xyzw

__all__ = ["RENORMALIZE_EVERY", "DcmIntegrator"]

#: The attitude quaternion is renormalised every this many samples (a power of two).
RENORMALIZE_EVERY = 64
_RENORM_MASK = RENORMALIZE_EVERY - 1
#: Bound of the per-integrator memo of magnus4 weights (distinct step triples).
_W4_CACHE_SIZE = 256
_ndarray = np.ndarray
_fromiter = np.fromiter
_F64 = np.dtype(np.float64)
_W4_UNSET: dict = {}  # memo node "unknown": always misses, never written


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

    Notes
    -----
    Feeding ``omega_b[k], t_s[k]`` for ``k = 0..N-1`` and calling :meth:`finish` reproduces
    ``integrate(omega_b, t_s, q0, method)`` to rounding, sample by sample (``t0_s=None``).

    Examples
    --------
    >>> import numpy as np
    >>> integ = DcmIntegrator([0, 0, 0, 1], method="trapezoid")
    >>> for k in range(101):
    ...     q = integ.update([0.0, 0.0, np.pi / 2], 0.01 * k)   # 90 deg/s about body z
    >>> q.round(6), integ.t_s
    (array([0.      , 0.      , 0.707107, 0.707107]), 1.0)
    """

    def __init__(self, q0: ArrayLike | Rotation, method: str = "magnus4",
                 t0_s: float | None = None) -> None:
        _check_method(method, METHODS)
        self._method = method
        self._q0 = tuple(float(v) for v in as_quat_xyzw(q0))
        self._q = self._q0
        try:
            self._t0_s = None if t0_s is None else float(t0_s)
        except (TypeError, ValueError):
            raise InputError(f"Expected `t0_s` a number (s) or None, got {t0_s!r}") from None
        if self._t0_s is not None and not math.isfinite(self._t0_s):
            raise InputError(f"Expected `t0_s` finite or None, got {t0_s}")
        self._lag = 1 if method == "magnus4" else 0
        self._ws: list = []  # last (up to) 4 rate samples (x, y, z) (tuples or lists), oldest first
        self._ts: list[float] = []  # their stamps
        self._n = 0  # samples received
        self._pending = 0  # samples received after the one whose attitude self._q is
        self._gap_dt = math.inf  # GAP_FACTOR x the last step
        self._steady = False
        self._finished = False
        self._phi_sum = (0.0, 0.0, 0.0)
        # magnus4 weights memo (see _weights4); _w4_next is reset whenever the buffer changes
        # outside the steady-state path.
        self._w4_nodes: dict[tuple, dict] = {}
        self._w4_next: dict = _W4_UNSET
        self._w4_size = 0  # triples memoised; -1: memo off
        self._w4_since = 0  # self._n when the memo was last (re)started
        if method == "rotvec_sum":
            _warn_rotvec_sum()

    # -- read-only state ------------------------------------------------------------------------

    @property
    def method(self) -> str:
        """The increment rule."""
        return self._method

    @property
    def q_w_b(self) -> NDArray[np.float64]:
        """Current attitude ``[x, y, z, w]``, body to world, shape (4,)."""
        return np.array(self._q)

    @property
    def rotation(self) -> Rotation:
        """Current attitude as a scipy ``Rotation``."""
        return Rotation.from_quat(self._q)

    @property
    def t_s(self) -> float | None:
        """Stamp (s) of the current attitude; ``None`` before the first sample (unless ``t0_s``)."""
        if self._n == 0:
            return self._t0_s
        return self._ts[len(self._ts) - 1 - self._pending]

    @property
    def n_samples(self) -> int:
        """Samples received (a ``t0_s`` start counts as one)."""
        return self._n

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
        """
        try:
            if type(omega_b) is _ndarray:
                w = omega_b.tolist()  # Python numbers already (fast arithmetic); our own list
                x, y, z = w
            else:
                x, y, z = omega_b
                w = x, y, z = float(x), float(y), float(z)
            t = float(t_s)
            s = x + y + z + t
        except (TypeError, ValueError):
            raise InputError(f"Expected `omega_b` 3 numbers (rad/s) and `t_s` a number, got "
                             f"{omega_b!r} and {t_s!r} (sample {self._n})") from None
        # s - s is nan iff s is inf or nan: one test for the usual all-finite sample, then the
        # exact one (a finite sum can overflow).
        if s - s and (x - x or y - y or z - z or t - t):  # nan (also inf - inf) is truthy
            raise InputError(f"Expected finite `omega_b` and `t_s`, got {[x, y, z]} at "
                             f"t_s = {t} (sample {self._n})")
        ts = self._ts
        if self._steady:
            # Steady state (buffers full, not finished): one step, formulas from integrate.py.
            h = t - ts[-1]
            if not h > 0.0:
                self._raise_order(t)
            if h > self._gap_dt:
                self._check_gap(h, t)
            self._gap_dt = GAP_FACTOR * h
            ws = self._ws
            ws.append(w)
            ts.append(t)
            del ws[0], ts[0]
            n = self._n = self._n + 1
            if self._lag:
                # magnus4 weights, memoised exactly (see _weights4): one float-keyed lookup.
                entry = self._w4_next.get(h)
                if entry is None:
                    entry = self._weights4(h)
                wts, self._w4_next = entry
                phi = magnus4_phi(wts, ws[0], ws[1], ws[2], ws[3])
            else:
                phi = phi_parts(self._method, ws[2], ws[2], ws[3], ws[3], h, h, h)
            q = quat_mul_parts(self._q, exp_parts(*phi))  # _step, inlined on the hot path
            if not n & _RENORM_MASK:
                inv = 1.0 / math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
                q = (q[0] * inv, q[1] * inv, q[2] * inv, q[3] * inv)
            self._q = q
            return _fromiter(q, _F64, 4)  # = np.array(q), ~50 ns faster
        if self._n == 0 and self._t0_s is not None:
            self._push(w, self._t0_s)
        self._push(w, t)
        return np.array(self._q)

    def _weights4(self, h: float) -> tuple:
        """Memo miss: magnus4 weights of the newest step triple (after the buffers shifted),
        ending with step ``h``. Returns ``(weights, node of the two newest steps)``.

        The weights depend only on the steps ``(h_m, h_0, h)``, and float stamps from a uniform
        clock give a few dozen distinct triples, so they are memoised, keyed by the exact floats
        (results unchanged). The memo is a graph: ``self._w4_nodes[(h_m, h_0)]`` maps the next
        step ``h`` to ``(weights, node of (h_0, h))``, and ``self._w4_next`` is the node of the
        two newest steps, so the hot path does one float-keyed lookup. When it holds
        ``_W4_CACHE_SIZE`` triples it is cleared, or, if that took fewer than 8 samples per
        triple (jittery stamps: the memo would cost more than it saves), switched off.
        """
        ts = self._ts
        h_m, h_0 = ts[1] - ts[0], ts[2] - ts[1]
        nodes = self._w4_nodes
        if self._w4_size >= _W4_CACHE_SIZE:
            if self._n - self._w4_since < 8 * _W4_CACHE_SIZE:
                self._w4_size = -1  # off: never >= 0 again
                nodes.clear()
            else:
                nodes.clear()
                self._w4_size = 0
                self._w4_since = self._n
        if self._w4_size < 0:
            return magnus4_weights(h_m, h_0, h), _W4_UNSET
        node = nodes.setdefault((h_m, h_0), {})
        entry = node.get(h)
        if entry is None:
            entry = node[h] = (magnus4_weights(h_m, h_0, h), nodes.setdefault((h_0, h), {}))
            self._w4_size += 1
        return entry

    def _step(self, phi: tuple) -> None:
        """Commit one step ``q <- q ⊗ exp(φ)``, renormalising every RENORMALIZE_EVERY steps."""
        q = quat_mul_parts(self._q, exp_parts(*phi))
        if not self._n & _RENORM_MASK:
            inv = 1.0 / math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
            q = (q[0] * inv, q[1] * inv, q[2] * inv, q[3] * inv)
        self._q = q
        self._pending -= 1

    def _raise_order(self, t: float) -> None:
        raise InputError(f"Expected `t_s` strictly increasing, got t_s[{self._n}] = "
                         f"{t!r} s after t_s[{self._n - 1}] = {self._ts[-1]!r} s")

    def _push(self, w: tuple | list, t: float) -> None:
        """General (warm-up and rotvec_sum) path of :meth:`update`."""
        if self._finished:
            raise InputError("Expected no samples after finish(), got one")
        ts = self._ts
        if ts:
            h = t - ts[-1]
            if not h > 0.0:
                self._raise_order(t)
            if h > self._gap_dt:
                self._check_gap(h, t)
            self._gap_dt = GAP_FACTOR * h
        ws = self._ws
        ws.append(w)
        ts.append(t)
        if len(ws) > 4:
            del ws[0], ts[0]
        self._n += 1
        n = self._n
        method = self._method
        self._steady = method != "rotvec_sum" and n >= (4 if self._lag else 2) and len(ws) == 4
        self._w4_next = _W4_UNSET
        if n == 1:
            return
        self._pending += 1
        if method == "magnus4":
            if n < 4:
                return
            if n == 4:  # first commit: steps 0 and 1 (step 0 with the start ghost)
                self._commit_window(lo=0, hi=2)
                return
            phi = phi_parts(method, ws[0], ws[1], ws[2], ws[3], ts[1] - ts[0], ts[2] - ts[1],
                            ts[3] - ts[2])
        elif method == "rotvec_sum":
            w_0 = ws[-2]
            h = ts[-1] - ts[-2]
            s = self._phi_sum
            s = (s[0] + w_0[0] * h, s[1] + w_0[1] * h, s[2] + w_0[2] * h)
            self._phi_sum = s
            self._q = quat_mul_parts(self._q0, exp_parts(*s))
            self._pending = 0
            return
        else:
            h = ts[-1] - ts[-2]
            phi = phi_parts(method, ws[-2], ws[-2], ws[-1], ws[-1], h, h, h)
        self._step(phi)

    def _check_gap(self, h: float, t: float) -> None:
        ts = self._ts
        steps = sorted(b - a for a, b in itertools.pairwise(ts))
        med = steps[len(steps) // 2] if steps else h
        if h > GAP_FACTOR * med:
            warnings.warn(f"Gap of {h:.6g} s (> {GAP_FACTOR:g}x the recent step {med:.6g} s) "
                          f"after t_s = {ts[-1]:.6f} s", GapWarning, stacklevel=4)

    def _window(self) -> tuple[NDArray, NDArray]:
        return np.array(self._ws, dtype=float), np.array(self._ts, dtype=float)

    def _commit_window(self, lo: int, hi: int) -> None:
        """Commit steps ``lo..hi-1`` of the buffered window with the batch code."""
        w, t = self._window()
        q = rate_quats(w, t, np.diff(t), np.array(self._q), self._method, lo=lo, hi=hi)
        self._q = tuple(q[-1].tolist())
        self._pending -= hi - lo

    def finish(self) -> NDArray[np.float64]:
        """Close the record: for ``magnus4`` commit the last step (one-sided end stencil, as the
        batch does) and return the attitude at the last stamp. Other methods: no-op.

        No sample may follow. Returns the ``[x, y, z, w]`` attitude, shape (4,).
        """
        if not self._finished and self._method == "magnus4" and self._n >= 2:
            n_buf = len(self._ws)
            pending = self._pending
            if pending:
                self._commit_window(lo=n_buf - 1 - pending, hi=n_buf - 1)
        self._finished = True
        self._steady = False
        return np.array(self._q)

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
        """
        w = np.asarray(omega_b)
        t = np.asarray(t_s)
        if w.ndim != 2 or w.shape[1] != 3 or t.shape != (len(w),):
            raise InputError(f"Expected `omega_b` (n, 3) and `t_s` (n,), got {w.shape} and "
                             f"{t.shape}")
        if len(w) == 0:
            raise InputError("Expected at least one sample, got 0")
        if self._finished:
            raise InputError("Expected no samples after finish(), got some")
        w = _as_float_array(w, "omega_b")
        t = _as_float_array(t, "t_s")
        out = np.empty((len(w), 4)) if self._n < 4 else None
        # Warm-up samples one at a time (checked by update), until the stencil buffer is full.
        need = 4 if self._method == "magnus4" else 1
        j = 0
        while j < len(w) and self._n < need:
            out[j] = self.update(w[j], t[j])
            j += 1
        if j < len(w):
            # Steady state: the chunk with the buffered samples its first stencils need, checked
            # as one record (finite, increasing across the junction, gaps).
            keep = 3 if self._method == "magnus4" else 1
            r = len(w) - j
            W = np.empty((keep + r, 3))
            T = np.empty(keep + r)
            W[:keep] = self._ws[-keep:]
            W[keep:] = w[j:]
            T[:keep] = self._ts[-keep:]
            T[keep:] = t[j:]
            W, T, dt = check_samples(W, T)
            q = self._batch(W, T, dt, keep)
            if j == 0:  # the usual case: no warm-up sample, no copy
                return _to_rotation(q)
            out[j:] = q
        return _to_rotation(out)

    def _batch(self, w: NDArray, t: NDArray, dt: NDArray, keep: int) -> NDArray:
        """Process checked samples in steady state with the batch code; update the state.

        ``w``, ``t`` start with the ``keep`` newest buffered samples, then the new ones.
        """
        if self._method == "rotvec_sum":
            inc = np.vstack([self._phi_sum, w[:-1] * dt[:, None]])
            phi = np.cumsum(inc, axis=0)[1:]
            q = np.stack(quat_mul_parts(self._q0, exp_parts(phi[:, 0], phi[:, 1], phi[:, 2])),
                         axis=-1)
            self._phi_sum = tuple(phi[-1].tolist())
        else:
            lo = keep - 1 - self._lag  # window index of the committed sample
            hi = len(t) - 1 - self._lag
            q = rate_quats(w, t, dt, np.array(self._q), self._method, lo=lo, hi=hi)[1:]
        self._q = tuple(q[-1].tolist())
        n_new = len(t) - keep
        self._n += n_new
        self._ws = (self._ws[:-keep] + [tuple(r) for r in w[-4:].tolist()])[-4:]
        self._ts = (self._ts[:-keep] + t[-4:].tolist())[-4:]
        self._gap_dt = GAP_FACTOR * float(dt[-1])
        self._steady = (self._method != "rotvec_sum" and len(self._ws) == 4
                        and self._n >= (4 if self._lag else 2))
        self._w4_next = _W4_UNSET
        return q

"""Rest live: the rest rule of :mod:`imu_dcm.gyro.rest_rule` run causally, sample by sample or in
batches, with the bias each sample gets as it arrives.

Conventions: ``omega_b`` (N, 3) body rate in body axes, rad/s; ``t_s`` (N,) seconds, increasing.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from imu_dcm.errors import InputError
from imu_dcm.gyro.rest_agreement import CausalAgreement
from imu_dcm.gyro.rest_evidence import Signals
from imu_dcm.gyro.rest_rule import (
    RestConfig,
    RestSegment,
    bias_span,
    evidence_of,
    noise_floor_var,
    runs,
    still_windows,
    touches,
    window_conditions,
    window_samples,
)
from imu_dcm.gyro.windows import min_steps, step_var, window_norms

__all__ = ["CausalRestBias"]


class CausalRestBias:
    """The rest rule of :func:`imu_dcm.gyro.rest.rest_segments`, run causally as samples arrive
    (live).

    The same window test (:func:`~imu_dcm.gyro.rest_rule.window_conditions`) and trimming
    (:func:`~imu_dcm.gyro.rest_rule.bias_span`), looking back only. A live stream carries no
    truth. Where it carries the accelerometer (``accel_b``, m/s², from the first batch on), it
    judges with the gyro as offline: its spread at its own floor and ``|mean a|`` near g, the
    mean rate under ``max_bias_rad_s``; the rest's evidence is ("gyro floor",
    "accelerometer"). Without one the gyro judges alone, and the mean rate stays under
    ``max_rate_rad_s`` (evidence ("gyro floor",)). Each floor is the stillest window seen so
    far (offline: of the whole log).
    The window ending at the newest sample ``k`` is judged when ``k`` arrives. While a segment
    ``[a, ...)`` lasts, the bias is the mean over ``[lo, k + 1 - m)`` (``lo`` from
    :func:`~imu_dcm.gyro.rest_rule.bias_span`): one window behind the newest sample. When motion
    starts, the last still window ends at ``b - 1``, and the segment's bias becomes
    :func:`~imu_dcm.gyro.rest_rule.bias_span`'s for ``[a, b)`` (its first ``3 m`` samples are kept
    for the middle half of a short rest), the value :func:`~imu_dcm.gyro.rest.rest_segments` gives
    it
    under the same floor. The bias applied to a sample is the estimate available when it
    arrives.

    When a segment closes, its bias is judged against the rests before it by the agreement rule
    (:class:`~imu_dcm.gyro.rest_agreement.CausalAgreement`, the rule replay's
    :func:`~imu_dcm.gyro.rest_agreement.rests_agree` applies offline): one that disagrees with
    the two before it beyond their noise while those two agree is not used, and the estimate
    goes back to the last rest used (zeros before any). While it lasts, its running mean is
    applied (nothing can judge it before it closes). :meth:`update_many` applies the rule to a
    batch as arrays and returns, for each sample, what :meth:`update` would have returned (to
    rounding). The window length comes from the median of the first ``probe`` steps (offline:
    of the whole log).

    Parameters
    ----------
    config : RestConfig, optional
        The rest rule (default ``RestConfig()``).
    probe : int
        Steps used to fix the window length (median step).

    Attributes
    ----------
    bias_rad_s : tuple of 3 floats — current estimate, body axes, rad/s (zeros before any rest).
    segments : list of RestSegment — each finished segment (``lo``/``hi`` as in replay), used or
        not.
    agreement : CausalAgreement — how the segments' biases agree; ``agreement.used[i]``: whether
        segment ``i``'s bias is used.
    updates : int — how many times the estimate changed.
    """

    def __init__(self, config: RestConfig | None = None, probe: int = 64) -> None:
        self.config = config or RestConfig()
        self.probe = probe
        self.bias_rad_s = (0.0, 0.0, 0.0)
        self.segments: list[RestSegment] = []
        self.updates = 0
        self.agreement = CausalAgreement(self.config.floor_spreads)
        self._used_bias = (0.0, 0.0, 0.0)  # the last rest used
        self.at_rest = False
        self.win = 0
        self._floor_var = math.inf  # the stillest window so far (variance, largest axis)
        self._min_steps = np.full(3, np.inf)  # the smallest step of each axis so far
        self._accel: bool | None = None  # whether the stream carries the accelerometer
        self._a_floor_var = math.inf  # the accelerometer's stillest window so far
        self._a_min_steps = np.full(3, np.inf)
        self._evidence: tuple[str, ...] = ("gyro floor",)  # the signals that judge the windows
        self._probe_a: list[NDArray] = []
        self._tail_a = np.zeros((0, 3))
        self._a_missing: NDArray | None = None  # windows holding a sample without a reading
        self._probe_w: list[NDArray] = []  # samples before the window length is known
        self._probe_t: list[NDArray] = []
        self._tail_w = np.zeros((0, 3))  # the last win samples
        self._tail_t = np.zeros(0)
        self._k = -1  # index of the newest sample
        self._seg_start = -1  # a, or -1 when not in a segment
        self._seg_t0 = 0.0
        self._seg_end = 0  # b - 1 of the open segment so far
        self._seg_end_t = 0.0
        self._head = np.zeros((0, 3))  # the open segment's first 3 win samples
        self._lo = 0  # the segment's bias averages the samples [lo, acc_hi)
        self._acc_hi = 0
        self._acc = np.zeros(3)
        self._shift = np.zeros(3)  # the squares of [lo, acc_hi) about this sample (its first)
        self._sq = np.zeros(3)

    def update(
        self, w: tuple[float, float, float], t_s: float, a=None
    ) -> tuple[float, float, float]:
        """Add one sample (rad/s, body axes; stamp s; specific force ``a`` m/s² or None);
        return the bias to subtract from it."""
        acc = None if a is None else np.array([a], dtype=float)
        self.update_many(np.array([w], dtype=float), np.array([t_s], dtype=float), acc)
        return self.bias_rad_s

    def update_many(
        self, omega_b: NDArray, t_s: NDArray, accel_b: NDArray | None = None
    ) -> NDArray:
        """Add samples in order; return the bias to subtract from each, as :meth:`update` would.

        Parameters
        ----------
        omega_b : float64 (n, 3) — body rates, rad/s.
        t_s : float64 (n,) — their stamps, s, increasing.
        accel_b : float64 (n, 3) or None — specific force on the same rows, m/s², in the
            gyro's axes; NaN rows where a sample has none (a window holding one is not rest).
            Given with every batch or with none (the first batch decides).

        Returns
        -------
        float64 (n, 3) — row ``j``: the estimate available once sample ``j`` has arrived.
        """
        w = np.asarray(omega_b, dtype=float).reshape(-1, 3)
        t = np.asarray(t_s, dtype=float).reshape(-1)
        a = None if accel_b is None else np.asarray(accel_b, dtype=float).reshape(-1, 3)
        if self._accel is None:
            self._accel = a is not None
        elif self._accel != (a is not None):
            had = "with" if self._accel else "without"
            raise InputError(
                f"Expected accel_b with every batch or with none, got "
                f"{'none' if a is None else 'one'} after batches {had}"
            )
        if a is not None and a.shape != w.shape:
            raise InputError(f"Expected accel_b of shape {w.shape}, got {a.shape}")
        if self.win:
            return self._steps(w, t, a)
        # the window length needs the median of the first `probe` steps
        self._probe_w.append(w)
        self._probe_t.append(t)
        if a is not None:
            self._probe_a.append(a)
        seen = sum(len(x) for x in self._probe_t)
        if seen < self.probe:
            return np.tile(self.bias_rad_s, (len(w), 1))
        pw, pt = np.concatenate(self._probe_w), np.concatenate(self._probe_t)
        pa = np.concatenate(self._probe_a) if self._accel else None
        self._probe_w, self._probe_t, self._probe_a = [], [], []
        p = self.probe
        self.win = window_samples(pt[:p], self.config.min_duration_s)
        before = np.tile(self.bias_rad_s, (p - 1 - (seen - len(w)), 1))  # this call's, held
        out = self._steps(pw, pt, pa)
        return np.concatenate([before, out[p - 1 :]])[-len(w) :]

    def _still(self, X: NDArray, T: NDArray, rows: NDArray, XA: NDArray | None) -> NDArray:
        """The rule for the windows starting at ``rows`` (consecutive) of ``X`` (and of the
        accelerometer's ``XA``), each judged against the floor of the windows up to it
        (:func:`~imu_dcm.gyro.rest_rule.noise_floor_var`, causal), the accelerometer's too."""
        m = self.win
        rate, max_var = window_norms(X, m)
        rate, max_var = rate[rows], max_var[rows]
        self._min_steps = np.minimum(self._min_steps, min_steps(X))
        floor = noise_floor_var(max_var, self._min_steps, self._floor_var, causal=True)
        if len(floor):
            self._floor_var = float(floor[-1])
        sig, self._a_missing = Signals(), None
        if XA is not None:
            A = XA[rows[0] : rows[-1] + m]
            missing = ~np.isfinite(A).all(axis=1)
            if missing.any():  # a window holding a sample without a reading is not still
                A = np.where(missing[:, None], 0.0, A)
                count = np.concatenate([[0], np.cumsum(missing)])
                self._a_missing = (count[m:] - count[:-m]) > 0
            self._a_min_steps = np.minimum(self._a_min_steps, min_steps(A))
            sig = Signals(A)
        conds = window_conditions(
            rate, max_var, floor, T, m, self.config, sig, accel_floor=self._accel_floor
        )[0]
        self._evidence = evidence_of(conds, None, None, 0, 0)
        still = still_windows(conds)
        return still if self._a_missing is None else still & ~self._a_missing

    def _accel_floor(self, a_var: NDArray) -> NDArray:
        """The accelerometer's floor for each window (``a_var`` its largest per-axis variance,
        (k,)): the stillest of it and those before it (windows holding a sample without a
        reading do not count)."""
        if self._a_missing is not None:
            a_var = np.where(self._a_missing, np.inf, a_var)
        floor = noise_floor_var(a_var, self._a_min_steps, self._a_floor_var, causal=True)
        if len(floor):
            self._a_floor_var = float(floor[-1])
        return floor

    def _steps(self, w: NDArray, t: NDArray, a: NDArray | None = None) -> NDArray:
        """The rule over a batch: windows ending at each sample, then the segments' runs."""
        n, m = len(w), self.win
        X = np.concatenate([self._tail_w, w])
        T = np.concatenate([self._tail_t, t])
        XA = None if a is None else np.concatenate([self._tail_a, a])
        base = self._k + 1 - len(self._tail_w)  # index of X[0]
        k0 = self._k + 1  # index of w[0]
        still = np.zeros(n, dtype=bool)
        first_full = max(0, m - 1 - k0)  # the first sample whose window is full
        if first_full < n:
            rows = np.arange(first_full, n) + (k0 - base) - m + 1  # window ending at sample j
            still[first_full:] = self._still(X, T, rows, XA)
        out = np.full((n, 3), np.nan)
        before = self.bias_rad_s
        for p, q in runs(still):
            if self._seg_start >= 0 and not touches(self._seg_end + 1, k0 + p - m + 1):
                self._close_segment(out, k0)  # motion of a window or more since its end
            self._run(X, T, base, k0, p, q, out)
        self.at_rest = bool(n and still[-1])
        if self._seg_start >= 0 and k0 + n - 1 >= self._seg_end + m:
            self._close_segment(out, k0)  # no window that can still come touches it
        # each sample keeps the newest estimate at its arrival (forward fill)
        have = ~np.isnan(out[:, 0])
        if have.any():
            last = np.maximum.accumulate(np.where(have, np.arange(n), -1))
            filled = np.where((last >= 0)[:, None], out[np.maximum(last, 0)], before)
        else:
            filled = np.tile(before, (n, 1))
        self._k += n
        self._tail_w, self._tail_t = X[-m:], T[-m:]
        if XA is not None:
            self._tail_a = XA[-m:]
        return filled

    def _run(self, X, T, base: int, k0: int, p: int, q: int, out: NDArray) -> None:
        """Still samples ``p..q-1`` of the batch: open (or go on with) the segment and write the
        bias after each sample into ``out`` (NaN while the segment has no sample yet)."""
        m = self.win
        if self._seg_start < 0:
            a = k0 + p - m + 1  # a segment starts with the first sample of its first still window
            self._seg_start, self._seg_t0 = a, float(T[a - base])
            self._lo = a if a == 0 else a + m
            self._acc_hi, self._acc = self._lo, np.zeros(3)
            self._head = X[a - base : a - base + 3 * m].copy()
        elif len(self._head) < 3 * m:
            have = self._seg_start + len(self._head) - base
            self._head = np.concatenate([self._head, X[have : have + 3 * m - len(self._head)]])
        hi = k0 + np.arange(p, q) + 1 - m  # sample k's estimate: the mean over [lo, k + 1 - m)
        grow = hi > self._acc_hi  # a suffix of the run: hi grows by one per sample
        if self._acc_hi > self._lo:  # samples whose window adds nothing keep the estimate
            keep = np.flatnonzero(~grow) + p
            out[keep] = self._acc / (self._acc_hi - self._lo)
            self.updates += len(keep)
        if grow.any():
            start = self._acc_hi - base
            self._add_squares(X[start : hi[-1] - base])
            partial = np.cumsum(X[start : hi[-1] - base], axis=0)
            sums = self._acc + partial[hi[grow] - base - start - 1]
            out[np.flatnonzero(grow) + p] = sums / (hi[grow] - self._lo)[:, None]
            self._acc, self._acc_hi = sums[-1], int(hi[-1])
            self.updates += len(sums)
        if not np.isnan(out[q - 1, 0]):
            self.bias_rad_s = tuple(out[q - 1].tolist())
        self._seg_end = k0 + q - 1
        self._seg_end_t = float(T[k0 + q - 1 - base])

    def _add_squares(self, x: NDArray) -> None:
        """Samples joining ``[lo, acc_hi)``: their squares about its first sample."""
        if self._acc_hi == self._lo and len(x):
            self._shift, self._sq = x[0].copy(), np.zeros(3)
        self._sq = self._sq + ((x - self._shift) ** 2).sum(axis=0)

    def _span_var(self) -> NDArray:
        """Per-axis sample variance of ``[lo, acc_hi)`` (from the sums about its first sample)."""
        n = self._acc_hi - self._lo
        if n < 2:
            return np.zeros(3)
        d = self._acc - n * self._shift
        return np.maximum(self._sq - d * d / n, 0.0) / (n - 1)

    def _close_segment(self, out: NDArray | None = None, k0: int = 0, at_end: bool = False) -> None:
        """End the open segment ``[a, b)``; its final bias holds from sample ``b - 1 + m`` (row
        of ``out`` for a batch starting at sample ``k0``). ``at_end``: the stream ended in it."""
        a, b, m = self._seg_start, self._seg_end + 1, self.win
        lo, hi = bias_span(a, b, b + (0 if at_end else 1), m)
        if at_end and hi > self._acc_hi:  # the last window's samples: the tail
            tail = self._tail_w[len(self._tail_w) - (hi - self._acc_hi) :]
            self._add_squares(tail)
            self._acc = self._acc + tail.sum(0)
            self._acc_hi = hi
        var = self._span_var()
        if lo != self._lo or hi != self._acc_hi:  # a short rest: its middle half
            x = self._head[lo - a : hi - a]
            self.bias_rad_s = tuple(x.mean(axis=0).tolist())
            var = x.var(axis=0, ddof=1) if len(x) >= 2 else np.zeros(3)
        elif hi > lo:
            self.bias_rad_s = tuple((self._acc / (hi - lo)).tolist())
        seg = RestSegment(
            a, b, self._seg_t0, self._seg_end_t, self.bias_rad_s, lo, hi, self._evidence
        )
        self.segments.append(seg)
        if self.agreement.add(seg, var, hi - lo, step_var(self._min_steps)) is None:
            self._used_bias = self.bias_rad_s
        else:  # not used: the estimate goes back to the last rest used
            self.bias_rad_s = self._used_bias
        self._seg_start = -1
        j = b - 1 + m - k0
        if out is not None and 0 <= j < len(out):
            out[j] = self.bias_rad_s

    def finish(self) -> None:
        """Close an open segment (at stop): the stream ended in it."""
        if self._seg_start >= 0:
            self._close_segment(at_end=True)
            self.at_rest = False

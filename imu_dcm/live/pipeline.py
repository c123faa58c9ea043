"""The live pipeline: reorder window -> gap check -> bias -> DcmIntegrator -> view and recording.

:class:`Pipeline` handles every sample a source delivers (:func:`imu_dcm.live.run` feeds it), in
stamp order:

1. puts it in order within the reorder window (:mod:`imu_dcm.live.reorder`); later samples,
   duplicate stamps and non-finite rates are dropped and counted; when the source has been
   quiet for longer than the window (wall time), the held samples are released;
2. reports a gap when the step exceeds ``GAP_FACTOR`` times the median of the recent steps
   (replay's rule, on the steps seen so far);
3. subtracts the bias (``auto``: :class:`imu_dcm.rest.CausalRestBias`; ``none``; a vector);
4. integrates it with :class:`imu_dcm.DcmIntegrator`, starting — as replay does — at the first
   sample inside the truth's coverage, from the truth slerped there (or from ``init_quat`` /
   identity when there is no truth).

Every ``view_interval_s`` (display rate) the new rows go to the rerun view in one batch of
``send_columns`` calls and to the recording; the estimate is compared with the truth where the
truth covers it. Times: ``t_s`` = seconds since the first sample, computed from the source's
int64 ns stamps exactly as replay computes them, so the same messages give the same attitude.
"""

from __future__ import annotations

import math
import time
import warnings
from collections import deque
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from imu_dcm.errors import GapWarning
from imu_dcm.integrate import GAP_FACTOR, integrate
from imu_dcm.live.reorder import ReorderBuffer
from imu_dcm.live.sources import Received
from imu_dcm.metrics import attitude_error_deg
from imu_dcm.rest import CausalRestBias
from imu_dcm.streaming import DcmIntegrator

__all__ = ["LiveResult", "Pipeline"]

DEG = math.pi / 180.0
_TRUTH_KEEP_NS = 5_000_000_000  # truth kept for slerp, ns behind the newest
_ERROR_GIVE_UP_NS = 2_000_000_000  # an estimate uncovered by truth this long: no error


@dataclass(frozen=True)
class LiveResult:
    """What a live run produced.

    Attributes
    ----------
    summary : dict — JSON-ready summary (keys as replay's where they apply; see :func:`run`).
    q_w_b : float64 (4,) or None — final attitude ``[x, y, z, w]`` at ``t_ns`` (None if the
        estimate never started).
    t_ns : int or None — source stamp of the final attitude, ns.
    latency_ms : float64 (n,) — receive -> view log call, per sample logged, ms.
    """

    summary: dict
    q_w_b: NDArray[np.float64] | None
    t_ns: int | None
    latency_ms: NDArray[np.float64] = field(repr=False)


def _slerp(truth_t: NDArray, truth_q: NDArray, t_ns: NDArray) -> NDArray:
    from imu_dcm.resample import slerp_truth

    return slerp_truth(truth_t, truth_q, t_ns)


class _Stats:
    """Running error statistics (RMS and max of total, inclination, heading)."""

    def __init__(self) -> None:
        self.n = 0
        self.sq = np.zeros(3)
        self.max = np.zeros(3)

    def add(self, err: NDArray) -> None:
        if len(err):
            self.n += len(err)
            self.sq += (err * err).sum(axis=0)
            self.max = np.maximum(self.max, err.max(axis=0))


class Pipeline:
    """Per-sample state of a live run (see the module doc), fed by :func:`imu_dcm.live.run`."""

    def __init__(
        self,
        *,
        method: str,
        bias,
        init_q: NDArray | None,
        window_ns: int,
        truth_wait_s: float,
        lines: bool,
        view,
        recorder,
        say,
    ) -> None:
        self.method = method
        self.bias_mode = (
            "auto"
            if isinstance(bias, str) and bias == "auto"
            else ("none" if isinstance(bias, str) else "fixed")
        )
        self.fixed_bias = (
            tuple(float(v) for v in bias) if self.bias_mode == "fixed" else (0.0, 0.0, 0.0)
        )
        self.rest = CausalRestBias() if self.bias_mode == "auto" else None
        self.init_q = init_q
        self.reorder = ReorderBuffer(window_ns)
        self.truth_wait_ns = int(truth_wait_s * 1e9)
        self.lines = lines
        self.view = view
        self.recorder = recorder
        self.say = say
        self.t0_ns: int | None = None
        self.n = 0
        self.malformed = 0
        self.gaps: list[tuple[float, float]] = []
        self._steps: deque = deque(maxlen=64)
        self._median = math.inf
        self._since_median = 0
        self._prev_t_s: float | None = None
        self.integ: DcmIntegrator | None = None
        self._warm: list | None = None
        self.q0: NDArray | None = None
        self.start_t_s: float | None = None
        self.waiting: list[tuple[int, float, tuple]] = []
        self.truth_channel = False
        self.truth_t: deque = deque()  # arrays of truth stamps / quats, oldest first
        self.truth_q: deque = deque()
        self.truth_max_ns: int | None = None
        self.truth_count = 0
        self._recent_ns: deque = deque(maxlen=4)  # (t_s, t_ns) of the newest samples
        self.last_est_t_s = -math.inf
        self.q_last: NDArray | None = None
        self.t_last_ns: int | None = None
        self.bias_sum = np.zeros(3)
        self.bias_n = 0
        self.stats = _Stats()
        self.truth_used = 0
        # rows since the last flush
        self.g_t: list[float] = []
        self.g_w: list[tuple] = []
        self.g_arr: list[int] = []
        self.e_rows: list[tuple[int, float, tuple]] = []  # estimate (t_ns, t_s, q)
        self.err_pending: list[tuple[int, float, tuple]] = []
        self.tr_rows_t: list[int] = []
        self.tr_rows_q: list[NDArray] = []
        self.latency: list[NDArray] = []
        self.last_arrival_wall = time.monotonic()
        self.samples_before_start = 0

    # -- input -----------------------------------------------------------------------------
    def on_imu(self, rec: Received) -> None:
        out: list = []
        push = self.reorder.push
        for t, w, a in zip(
            rec.t_ns.tolist(), rec.values.tolist(), rec.arrival_ns.tolist(), strict=False
        ):
            push(t, w, a, out)
        if out:
            self._process(out)
        self.last_arrival_wall = time.monotonic()

    def on_truth(self, rec: Received) -> None:
        ok = np.all(np.isfinite(rec.values), axis=1)
        if not ok.any():
            return
        t, q = rec.t_ns[ok], rec.values[ok]
        self.truth_t.append(t)
        self.truth_q.append(q)
        self.truth_count += len(t)
        m = int(t.max())
        self.truth_max_ns = m if self.truth_max_ns is None else max(self.truth_max_ns, m)
        while len(self.truth_t) > 1 and int(self.truth_t[0].max()) < m - _TRUTH_KEEP_NS:
            self.truth_t.popleft()
            self.truth_q.popleft()
        self.tr_rows_t.extend(t.tolist())
        self.tr_rows_q.append(q)
        if self.integ is None and self.waiting:
            self._try_start()

    def _truth_arrays(self) -> tuple[NDArray, NDArray]:
        return np.concatenate(list(self.truth_t)), np.concatenate(list(self.truth_q))

    # -- per sample ------------------------------------------------------------------------
    def _process(self, released: list) -> None:
        rest = self.rest
        fixed = self.fixed_bias
        for t_ns, w, arrival in released:
            if self.t0_ns is None:
                self.t0_ns = t_ns
            t_s = (t_ns - self.t0_ns) * 1e-9
            prev = self._prev_t_s
            if prev is not None:
                h = t_s - prev
                if h > GAP_FACTOR * self._median and len(self._steps) >= 3:
                    self.gaps.append((prev, h))
                    self.say(
                        f"gap of {h:.3f} s after t = {prev:.3f} s "
                        f"(> {GAP_FACTOR:g}x the median step {self._median * 1e3:.3f} ms)"
                    )
                self._steps.append(h)
                self._since_median += 1
                if self._since_median >= 16 or len(self._steps) < 16:
                    self._since_median = 0
                    s = sorted(self._steps)
                    self._median = s[len(s) // 2]
            self._prev_t_s = t_s
            if rest is not None:
                n_seg = len(rest.segments)
                b = rest.update(w, t_s)
                if len(rest.segments) > n_seg:
                    seg = rest.segments[-1]
                    v = seg["bias_rad_s"]
                    self.say(
                        f"bias from rest {seg['start_s']:.3f}-{seg['end_s']:.3f} s: "
                        f"({v[0]:+.5f}, {v[1]:+.5f}, {v[2]:+.5f}) rad/s"
                    )
            else:
                b = fixed
            wc = (w[0] - b[0], w[1] - b[1], w[2] - b[2])
            self.n += 1
            self.g_t.append(t_s)
            self.g_w.append(wc)
            self.g_arr.append(arrival)
            self._recent_ns.append((t_s, t_ns))
            if self.integ is None:
                self.waiting.append((t_ns, t_s, wc))
                self._try_start()
            else:
                self._step(t_ns, t_s, wc)
            if self.integ is not None:
                self.bias_sum += b
                self.bias_n += 1

    def _start(self, i: int, q0: NDArray, why: str | None) -> None:
        waiting = self.waiting
        self.samples_before_start += i
        self.q0 = np.asarray(q0, dtype=float)
        t_ns, t_s, _ = waiting[i]
        self.start_t_s = t_s
        self.integ = DcmIntegrator(self.q0, self.method)
        self._warm = [] if self.method == "magnus4" else None
        if why:
            self.say(why)
        self.waiting = []
        for t_ns, t_s, wc in waiting[i:]:
            self._step(t_ns, t_s, wc)

    def _try_start(self) -> None:
        waiting = self.waiting
        if self.init_q is not None:
            self._start(0, self.init_q, None)
            return
        if self.truth_max_ns is not None:
            tt, tq = self._truth_arrays()
            stamps = np.array([w[0] for w in waiting], dtype=np.int64)
            covered = stamps <= self.truth_max_ns
            if not covered.any():
                if stamps[-1] - stamps[0] >= 10 * self.truth_wait_ns:  # the truth stalled
                    self._start(
                        0,
                        np.array([0.0, 0.0, 0.0, 1.0]),
                        f"the truth stopped {(stamps[-1] - self.truth_max_ns) * 1e-9:.3f} s "
                        f"before the gyro: starting from the identity attitude",
                    )
                return
            q = _slerp(tt, tq, stamps[covered])
            ok = np.flatnonzero(np.all(np.isfinite(q), axis=1))
            if len(ok):
                self._start(int(ok[0]), q[ok[0]], None)
            else:
                k = int(covered.sum())  # covered but outside the truth: never estimated
                self.samples_before_start += k
                del waiting[:k]
            return
        if self.lines and not self.truth_channel:
            self._start(0, np.array([0.0, 0.0, 0.0, 1.0]), None)
            return
        if waiting[-1][0] - waiting[0][0] >= self.truth_wait_ns:
            self._start(
                0,
                np.array([0.0, 0.0, 0.0, 1.0]),
                f"no truth within {self.truth_wait_ns * 1e-9:g} s of source time: "
                f"starting from the identity attitude",
            )

    def _ns_of(self, t_s: float) -> int:
        for ts, tn in reversed(self._recent_ns):
            if ts == t_s:
                return tn
        return round(t_s * 1e9) + (self.t0_ns or 0)

    def _step(self, t_ns: int, t_s: float, wc: tuple) -> None:
        q = self.integ.update(wc, t_s)
        te = self.integ.t_s
        warm = self._warm
        if warm is not None:
            warm.append((t_ns, t_s, wc))
            if len(warm) == 4:
                # magnus4 commits its first two steps at once (the start stencil needs four
                # samples): the attitude at the second stamp comes from the batch integrator on
                # the same four samples, which is what the streaming one computes inside.
                self._warm = None
                W = np.array([r[2] for r in warm])
                T = np.array([r[1] for r in warm])
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", GapWarning)
                    q1 = integrate(W, T, self.q0, self.method).as_quat()[1]
                self.e_rows.append((warm[1][0], warm[1][1], tuple(q1.tolist())))
                self.last_est_t_s = warm[1][1]
        if te is not None and te > self.last_est_t_s:
            self.last_est_t_s = te
            tn = t_ns if te == t_s else self._ns_of(te)
            row = (tn, te, tuple(q.tolist()))
            self.e_rows.append(row)
            self.q_last, self.t_last_ns = q, tn

    def release_held(self) -> None:
        """Release every sample held by the reorder window (the source has gone quiet for
        longer than the window: nothing can arrive that would still be put in order)."""
        out: list = []
        self.reorder.flush(out)
        if out:
            self._process(out)

    def finish(self) -> None:
        out: list = []
        self.reorder.flush(out)
        if out:
            self._process(out)
        if self.integ is None and self.waiting:
            q0 = self.init_q if self.init_q is not None else np.array([0.0, 0.0, 0.0, 1.0])
            if self.truth_max_ns is not None:
                tt, tq = self._truth_arrays()
                q = _slerp(tt, tq, np.array([w[0] for w in self.waiting], np.int64))
                ok = np.flatnonzero(np.all(np.isfinite(q), axis=1))
                if len(ok):
                    self._start(int(ok[0]), q[ok[0]], None)
            if self.integ is None:
                self._start(0, q0, None)
        if self.integ is not None:
            q = self.integ.finish()
            te = self.integ.t_s
            if te is not None and te > self.last_est_t_s:
                self.last_est_t_s = te
                tn = self._ns_of(te)
                self.e_rows.append((tn, te, tuple(q.tolist())))
                self.q_last, self.t_last_ns = q, tn
            elif te is not None:
                self.q_last = q
        if self.rest is not None:
            self.rest.finish()

    # -- display rate ----------------------------------------------------------------------
    def flush(self, final: bool = False) -> None:
        """Errors for covered estimates, one batch to the view and the recording, latency."""
        est = self.e_rows
        self.e_rows = []
        err_t: list[float] = []
        err: NDArray = np.zeros((0, 3))
        if self.truth_count:
            pend = self.err_pending + est
            if pend:
                stamps = np.array([r[0] for r in pend], np.int64)
                cover = self.truth_max_ns if self.truth_max_ns is not None else -1
                ready = stamps <= cover
                newest = stamps[-1]
                give_up = ~ready & (final | (stamps < newest - _ERROR_GIVE_UP_NS))
                idx = np.flatnonzero(ready)
                if len(idx):
                    tt, tq = self._truth_arrays()
                    qt = _slerp(tt, tq, stamps[idx])
                    qe = np.array([pend[i][2] for i in idx])
                    ok = np.all(np.isfinite(qt), axis=1)
                    if ok.any():
                        e = attitude_error_deg(qe[ok], qt[ok])
                        err = np.stack([e.total_deg, e.inclination_deg, e.heading_deg], axis=1)
                        err_t = [pend[i][1] for i in idx[ok]]
                        self.stats.add(err)
                        self.truth_used += int(ok.sum())
                self.err_pending = [pend[i] for i in np.flatnonzero(~ready & ~give_up)]
        tr_t = self.tr_rows_t
        tr_q = np.concatenate(self.tr_rows_q) if self.tr_rows_q else np.zeros((0, 4))
        self.tr_rows_t, self.tr_rows_q = [], []
        g_t, g_w, g_arr = self.g_t, self.g_w, self.g_arr
        self.g_t, self.g_w, self.g_arr = [], [], []
        t0 = self.t0_ns
        if self.view is not None and t0 is not None:
            tr_s = (np.array(tr_t, np.int64) - t0) * 1e-9 if tr_t else np.zeros(0)
            self.view.log(
                gyro_t_s=np.array(g_t),
                omega_b=np.array(g_w).reshape(-1, 3),
                est_t_s=np.array([r[1] for r in est]),
                q_est=np.array([r[2] for r in est]).reshape(-1, 4),
                truth_t_s=tr_s,
                q_truth=tr_q,
                err_t_s=np.array(err_t),
                err_deg=err,
            )
        elif t0 is None and tr_t:  # no gyro sample yet: keep the truth rows for later
            self.tr_rows_t, self.tr_rows_q = tr_t, [tr_q]
        if g_arr:
            now = time.perf_counter_ns()
            self.latency.append((now - np.array(g_arr, np.int64)) * 1e-6)
        if self.recorder is not None and est:
            self.recorder.add_estimate(
                np.array([r[0] for r in est], np.int64), np.array([r[2] for r in est])
            )

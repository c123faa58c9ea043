"""The live pipeline: reorder window -> gap check -> bias -> DcmIntegrator -> view and recording.

:class:`Pipeline` handles every batch of samples a source delivers (:func:`imu_dcm.live.run`
feeds it) as arrays, in stamp order:

1. puts the batch in order within the reorder window (:mod:`imu_dcm.live.reorder`); later
   samples, duplicate stamps and non-finite rates are dropped and counted; when the source has
   been quiet for longer than the window (wall time), the held samples are released;
2. reports gaps with replay's rule (:func:`imu_dcm.integrator.batch.find_gaps`) over the recent
   steps and the new ones;
3. subtracts the bias (``auto``: :class:`imu_dcm.gyro.rest_causal.CausalRestBias` over the batch,
   with the accelerometer where the source's first IMU batch carries one (else the gyro alone),
   each rest said as it closes: its bias, or why it is not used; ``none``; a vector);
4. integrates the batch with :meth:`imu_dcm.DcmIntegrator.update_many` (the compiled kernel's
   feed), starting — as replay does — at the first sample inside the truth's coverage, from the
   truth slerped there (or from ``init_q_w_b`` / identity when there is no truth). When the truth
   starts late (its channel is announced but its first sample comes more than ``truth_wait_s``
   after the gyro's), the estimate starts from the identity and *re-anchors* to the truth when
   the truth first arrives, at the first sample it covers, as replay would; the start before
   that is reported as unscored.

Every ``view_interval_s`` (display rate) the new rows go to the rerun view in one batch of
``send_columns`` calls and to the recording; the estimate is compared with the truth where the
truth covers it. Times: ``t_s`` = seconds since the first sample, computed from the source's
int64 ns stamps exactly as replay computes them, so the same messages give the same attitude.
"""

from __future__ import annotations

import math
import time
import warnings

import numpy as np
from numpy.typing import NDArray

from imu_dcm.errors import GapWarning
from imu_dcm.gyro.rates import deg_evidence
from imu_dcm.gyro.resample import slerp_truth
from imu_dcm.gyro.rest_agreement import EVIDENCE
from imu_dcm.gyro.rest_causal import CausalRestBias
from imu_dcm.integrator.batch import find_gaps, gap_message, integrate_quat
from imu_dcm.integrator.streaming import DcmIntegrator
from imu_dcm.live.events import Received
from imu_dcm.live.latency import Latency
from imu_dcm.live.lines import time_unit_hint
from imu_dcm.live.reorder import ReorderBuffer
from imu_dcm.live.rows import Rows, Stats
from imu_dcm.metrics import attitude_error_deg

__all__ = ["DEG", "GAPS_KEEP", "UNITS_PROBE_MAX", "UNITS_PROBE_S", "Pipeline"]

DEG = math.pi / 180.0
_TRUTH_KEEP_NS = 5_000_000_000  # truth kept for slerp, ns behind the newest
_ERROR_GIVE_UP_NS = 2_000_000_000  # an estimate uncovered by truth this long: no error
_ANCHOR_KEEP_NS = 10_000_000_000  # samples kept to re-anchor on a late truth, ns
_RECENT = 65  # stamps kept for the gap rule and the rate (64 steps)
_IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])
#: The first seconds of rates (source time) judged for deg/s declared as rad/s, and at most
#: this many samples of them (bounded memory: 1.6 MB).
UNITS_PROBE_S = 5.0
UNITS_PROBE_MAX = 50_000
#: Gaps kept with their times (the count goes on past them).
GAPS_KEEP = 1000


_SAMPLES = ((np.int64,), (float,), (float, 3))  # t_ns, t_s, omega_b (bias removed)
_ESTIMATES = ((np.int64,), (float,), (float, 4))  # t_ns, t_s, q_w_b


def rest_line(rest: CausalRestBias, i: int) -> str:
    """The line for rest segment ``i`` as it closes: its bias, or why it is not used."""
    seg = rest.segments[i]
    v = seg.bias_rad_s
    bias = f"({v[0]:+.5f}, {v[1]:+.5f}, {v[2]:+.5f}) rad/s"
    if rest.agreement.used[i]:
        return f"bias from rest {seg.start_s:.3f}-{seg.end_s:.3f} s: {bias}"
    r = dict(rest.agreement.outliers)[i]
    return (
        f"rest {seg.start_s:.3f}-{seg.end_s:.3f} s not used: its bias {bias} is {r:.1f}x its "
        f"noise from the two rests before it, which agree ({EVIDENCE}, "
        f"z = {rest.agreement.spreads:g})"
    )


class Pipeline:
    """The state of a live run (see the module doc), fed by :func:`imu_dcm.live.run`."""

    def __init__(
        self,
        *,
        method: str,
        bias,
        init_q_w_b: NDArray | None,
        window_ns: int,
        truth_wait_s: float,
        lines: bool,
        view,
        recorder,
        say,
        time_units: str | None = None,
        check_units: bool = False,
    ) -> None:
        self.method = method
        #: rates declared rad/s: their first seconds are judged once for deg/s (_units_probe)
        self.units_probe = Rows(*_SAMPLES) if check_units else None
        self.units_evidence: str | None = None
        self.bias_mode = (
            "auto"
            if isinstance(bias, str) and bias == "auto"
            else ("none" if isinstance(bias, str) else "fixed")
        )
        self.fixed_bias = (
            tuple(float(v) for v in bias) if self.bias_mode == "fixed" else (0.0, 0.0, 0.0)
        )
        self.rest = CausalRestBias() if self.bias_mode == "auto" else None
        self.accel: bool | None = None  # whether the rest rule gets the accelerometer
        self.init_q_w_b = init_q_w_b
        self.reorder = ReorderBuffer(window_ns)
        self.truth_wait_ns = int(truth_wait_s * 1e9)
        self.lines = lines
        self.time_units = time_units
        self.view = view
        self.recorder = recorder
        self.say = say
        self.t0_ns: int | None = None
        self.n = 0
        self.malformed = 0
        self.gaps: list[tuple[float, float]] = []  # the first GAPS_KEEP
        self.gap_count = 0
        self.recent_t_s = np.zeros(0)  # the newest stamps, s
        self.rates_checked = False
        self.integ: DcmIntegrator | None = None
        self.q0: NDArray | None = None
        self.start_t_s: float | None = None
        self.unscored_before_s: float | None = None  # re-anchored: the start before is unscored
        self.anchor_pending = False
        self.waiting = Rows(*_SAMPLES)  # before the start
        self.history = Rows(*_SAMPLES)  # since an identity start, to re-anchor on a late truth
        self.truth_channel = False
        self.channels: dict = {}
        self.truth_t: list[NDArray] = []  # truth stamps / quats, oldest first
        self.truth_q: list[NDArray] = []
        self.truth_max_ns: int | None = None
        self.truth_min_ns: int | None = None  # the first truth stamp (where re-anchoring may be)
        self.truth_count = 0
        self.fed = Rows(*_SAMPLES)  # the last samples fed (stamps of the lagged rows)
        self.emitted = -1  # index (since the start) of the newest estimate row
        self.first4 = Rows(*_SAMPLES)  # magnus4: the first four samples (its warm-up)
        self.q_last: NDArray | None = None
        self.t_last_ns: int | None = None
        self.bias_sum = np.zeros(3)
        self.bias_n = 0
        self.stats = Stats()
        self.truth_used = 0
        # rows since the last flush
        self.gyro = Rows((float,), (float, 3), (np.int64,))  # t_s, omega_b, arrival ns
        self.est = Rows(*_ESTIMATES)
        self.err_pending = Rows(*_ESTIMATES)
        self.truth_rows = Rows((np.int64,), (float, 4))
        self.latency = Latency()
        self.samples_before_start = 0
        self.cpu_s: float | None = None
        self.read_interval_s: float | None = None  # the loop's final cadence

    # -- input -----------------------------------------------------------------------------
    def on_imu(self, rec: Received) -> None:
        values = rec.values
        if self.accel is None:  # the first batch decides: with the accelerometer or without
            self.accel = self.rest is not None and rec.accel is not None
        if self.accel:  # it rides along with the rates through the reorder window
            acc = rec.accel if rec.accel is not None else np.full((len(values), 3), np.nan)
            values = np.concatenate([values, acc], axis=1)
        t_ns, w, arrival = self.reorder.push(rec.t_ns, values, rec.arrival_ns)
        if len(t_ns):
            self._process(t_ns, w, arrival)

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
        lo = int(t.min())
        self.truth_min_ns = lo if self.truth_min_ns is None else min(self.truth_min_ns, lo)
        while len(self.truth_t) > 1 and int(self.truth_t[0].max()) < m - _TRUTH_KEEP_NS:
            del self.truth_t[0], self.truth_q[0]
        self.truth_rows.add(t, q)
        if self.integ is None and len(self.waiting):
            self._try_start()
        elif self.anchor_pending:
            self._try_anchor()

    def _truth_arrays(self) -> tuple[NDArray, NDArray]:
        return np.concatenate(self.truth_t), np.concatenate(self.truth_q)

    def release_held(self) -> None:
        """Release every sample held by the reorder window (the source has gone quiet for
        longer than the window: nothing can arrive that would still be put in order)."""
        t_ns, w, arrival = self.reorder.flush()
        if len(t_ns):
            self._process(t_ns, w, arrival)

    # -- per batch -------------------------------------------------------------------------
    def _process(self, t_ns: NDArray, w: NDArray, arrival: NDArray) -> None:
        if self.t0_ns is None:
            self.t0_ns = int(t_ns[0])
        acc, w = (w[:, 3:], np.ascontiguousarray(w[:, :3])) if w.shape[1] > 3 else (None, w)
        t_s = (t_ns - self.t0_ns) * 1e-9
        self._check_steps(t_s)
        if self.units_probe is not None:
            self._probe_units(t_ns, t_s, w)
        if self.rest is not None:
            n_seg = len(self.rest.segments)
            b = self.rest.update_many(w, t_s, acc)
            for i in range(n_seg, len(self.rest.segments)):
                self.say(rest_line(self.rest, i))
            wc = w - b
        else:
            b = np.asarray(self.fixed_bias)
            wc = w - b if self.bias_mode == "fixed" else w
        self.n += len(t_ns)
        self.gyro.add(t_s, wc, arrival)
        if self.integ is None:
            self.waiting.add(t_ns, t_s, wc)
            self._try_start()
        else:
            self._feed(t_ns, t_s, wc)
            if self.anchor_pending:
                self.history.add(t_ns, t_s, wc)
                self.history.trim(_ANCHOR_KEEP_NS)
                self._try_anchor()
        if self.integ is not None:  # the mean bias over the samples estimated
            self.bias_sum += b.sum(axis=0) if b.ndim == 2 else b * len(t_ns)
            self.bias_n += len(t_ns)

    def _check_steps(self, t_s: NDArray) -> None:
        """Gaps by replay's rule over the recent and the new steps; once, a rate or steps that
        no IMU produces."""
        stamps = np.concatenate([self.recent_t_s, t_s])
        after = self.recent_t_s[-1] if len(self.recent_t_s) else -math.inf
        new = tuple(g for g in find_gaps(stamps) if g[0] >= after)  # the new steps' gaps
        if new:
            self.gap_count += len(new)
            self.gaps.extend(new[: max(0, GAPS_KEEP - len(self.gaps))])
            self.say(gap_message(new))
        self.recent_t_s = stamps[-_RECENT:]
        if not self.rates_checked and len(stamps) >= 17:
            self.rates_checked = True
            steps = np.diff(stamps)
            hint = time_unit_hint(float(np.median(steps)), float(steps.max()), self.time_units)
            if hint:
                self.say(hint)

    def _probe_units(self, t_ns: NDArray, t_s: NDArray, w: NDArray, final: bool = False) -> None:
        """Rates declared rad/s that look like deg/s, judged once on the first
        :data:`UNITS_PROBE_S` s (at most :data:`UNITS_PROBE_MAX` samples) by replay's rule
        (:func:`imu_dcm.gyro.rates.deg_evidence`: against the truth's rotation rate where the truth
        covers them, else the gyro full-scale bound); said in one line, and in the summary."""
        probe = self.units_probe
        probe.add(t_ns, t_s, w)
        n = len(probe)
        if not final and n < UNITS_PROBE_MAX and t_s[-1] < UNITS_PROBE_S:
            return
        self.units_probe = None
        pt_ns, pt_s, pw = probe.take()
        if len(pt_ns) < 20:
            return
        q = np.full((len(pt_ns), 4), np.nan)
        if self.truth_t:
            q = slerp_truth(*self._truth_arrays(), pt_ns)
        evidence = deg_evidence(pw, pt_s, q)
        if evidence:
            self.units_evidence = evidence
            self.say(f"the rates look like deg/s: {evidence}; pass --gyro-units deg/s to convert")

    @property
    def median_step_s(self) -> float | None:
        """Median of the recent steps, s (None before three samples)."""
        if len(self.recent_t_s) < 3:
            return None
        return float(np.median(np.diff(self.recent_t_s)))

    # -- start and re-anchoring ------------------------------------------------------------
    def _start(self, i: int, q0: NDArray, why: str | None) -> None:
        t_ns, t_s, wc = self.waiting.take()
        self.samples_before_start += i
        self.q0 = np.asarray(q0, dtype=float)
        self.start_t_s = float(t_s[i])
        self.integ = DcmIntegrator(self.q0, self.method)
        self.emitted = -1
        self.first4 = Rows(*_SAMPLES)
        self.fed = Rows(*_SAMPLES)
        if why:
            self.say(why)
        self._feed(t_ns[i:], t_s[i:], wc[i:])

    def _try_start(self) -> None:
        if self.init_q_w_b is not None:
            self._start(0, self.init_q_w_b, None)
            return
        t_ns, t_s, wc = self.waiting.take()
        self.waiting.add(t_ns, t_s, wc)
        if self.truth_max_ns is not None:
            self._start_in_truth(t_ns)
            return
        why = None
        if not self.lines or self.truth_channel:  # a truth channel: wait for its first sample
            if t_ns[-1] - t_ns[0] < self.truth_wait_ns:
                return
            why = (
                f"no truth within {self.truth_wait_ns * 1e-9:g} s of source time: starting "
                f"from the identity attitude (re-anchored to the truth when it comes)"
            )
        self.anchor_pending = True  # a truth that comes later re-anchors the estimate
        self._start(0, _IDENTITY, why)
        self.history.add(t_ns, t_s, wc)
        self.history.trim(_ANCHOR_KEEP_NS)

    def _start_in_truth(self, t_ns: NDArray) -> None:
        covered = t_ns <= self.truth_max_ns
        if not covered.any():
            if t_ns[-1] - t_ns[0] >= 10 * self.truth_wait_ns:  # the truth stalled
                self._start(
                    0,
                    _IDENTITY,
                    f"the truth stopped {(t_ns[-1] - self.truth_max_ns) * 1e-9:.3f} s "
                    f"before the gyro: starting from the identity attitude",
                )
            return
        q = slerp_truth(*self._truth_arrays(), t_ns[covered])
        ok = np.flatnonzero(np.all(np.isfinite(q), axis=1))
        if len(ok):
            self._start(int(ok[0]), q[ok[0]], None)
            return
        k = int(covered.sum())  # covered but outside the truth: never estimated
        self.samples_before_start += k
        t_ns, t_s, wc = self.waiting.take()
        self.waiting.add(t_ns[k:], t_s[k:], wc[k:])

    def _try_anchor(self) -> None:
        """The truth came after an identity start: restart the estimate from it at the first
        sample it covers (as replay starts there); what came before is unscored."""
        if self.truth_max_ns is None:
            return
        t_ns, t_s, wc = self.history.take()
        keep = t_ns >= t_ns[-1] - _ANCHOR_KEEP_NS
        t_ns, t_s, wc = t_ns[keep], t_s[keep], wc[keep]
        self.history.add(t_ns, t_s, wc)
        covered = np.flatnonzero((t_ns >= self.truth_min_ns) & (t_ns <= self.truth_max_ns))
        if not len(covered):
            return  # no sample inside the truth yet (cheap: no slerp)
        q = slerp_truth(*self._truth_arrays(), t_ns[covered])
        ok = np.flatnonzero(np.all(np.isfinite(q), axis=1))
        if not len(ok):
            return
        i = int(covered[ok[0]])
        self.anchor_pending = False
        self.history = Rows(*_SAMPLES)
        est = self.est.take()
        before = est[0] < t_ns[i]
        self.est.add(*(c[before] for c in est))  # rows from the anchor on are estimated again
        self.unscored_before_s = float(t_s[i])
        self.say(
            f"the truth starts at t = {t_s[i]:.3f} s: the estimate restarts from it there "
            f"(as replay starts); the {t_s[i] - self.start_t_s:.3f} s before are unscored"
        )
        self.samples_before_start += self.integ.n_samples - (len(t_ns) - i)
        self.waiting.add(t_ns[i:], t_s[i:], wc[i:])
        self._start(0, q[ok[0]], None)

    # -- integration -----------------------------------------------------------------------
    def _feed(self, t_ns: NDArray, t_s: NDArray, wc: NDArray) -> None:
        """Integrate a batch; queue one estimate row per sample whose attitude is final."""
        if not len(t_ns):
            return
        integ = self.integ
        n0 = integ.n_samples
        q = integ.update_many_quat(wc, t_s)
        n_after = n0 + 1 + np.arange(len(t_ns))
        if self.method == "magnus4":  # the attitude is one sample late (see streaming)
            idx = np.where(n_after >= 4, n_after - 2, 0)
            if n0 < 4:
                self.first4.add(t_ns[: 4 - n0], t_s[: 4 - n0], wc[: 4 - n0])
        else:
            idx = n_after - 1
        prev_ns, prev_s, _ = self.fed.take()
        stamps_ns = np.concatenate([prev_ns[-1:], t_ns])
        stamps_s = np.concatenate([prev_s[-1:], t_s])
        self.fed.add(t_ns[-1:], t_s[-1:], wc[-1:])
        new = idx > np.maximum.accumulate(np.concatenate([[self.emitted], idx[:-1]]))
        if not new.any():
            return
        rows = idx[new] - (n0 - len(prev_ns[-1:]))  # index into stamps_*
        qs = q[new]
        j = 0
        if self.method == "magnus4" and self.emitted < 2 <= idx[new][-1]:
            j = int(np.searchsorted(idx[new], 2))  # rows before the second stamp's
            if j:
                self._emit(stamps_ns[rows[:j]], stamps_s[rows[:j]], qs[:j])
            self._emit_second()
        self._emit(stamps_ns[rows[j:]], stamps_s[rows[j:]], qs[j:])
        self.emitted = int(idx[new][-1])

    def _emit_second(self) -> None:
        """magnus4 commits its first two steps at once (the start stencil needs four samples):
        the attitude at the second stamp comes from the batch integrator on the same four
        samples, which is what the streaming one computes inside."""
        t_ns, t_s, wc = self.first4.take()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", GapWarning)
            q1 = integrate_quat(wc, t_s, self.q0, self.method)[1]
        self._emit(t_ns[1:2], t_s[1:2], q1[None, :])

    def _emit(self, t_ns: NDArray, t_s: NDArray, q: NDArray) -> None:
        self.est.add(t_ns, t_s, q)
        self.q_last, self.t_last_ns = q[-1].copy(), int(t_ns[-1])

    def finish(self) -> None:
        t_ns, w, arrival = self.reorder.flush()
        if len(t_ns):
            self._process(t_ns, w, arrival)
        if self.units_probe is not None and len(self.units_probe):
            empty = np.zeros(0)
            self._probe_units(empty.astype(np.int64), empty, np.zeros((0, 3)), final=True)
        if self.integ is None and len(self.waiting):
            t_ns, t_s, wc = self.waiting.take()
            self.waiting.add(t_ns, t_s, wc)
            if self.truth_max_ns is not None:
                q = slerp_truth(*self._truth_arrays(), t_ns)
                ok = np.flatnonzero(np.all(np.isfinite(q), axis=1))
                if len(ok):
                    self._start(int(ok[0]), q[ok[0]], None)
            if self.integ is None:
                self._start(0, self.init_q_w_b if self.init_q_w_b is not None else _IDENTITY, None)
        if self.integ is not None:
            q = self.integ.finish()
            last = self.integ.n_samples - 1
            if last > self.emitted:
                t_ns, t_s, _ = self.fed.take()
                self._emit(t_ns[-1:], t_s[-1:], q[None, :])
                self.emitted = last
            else:
                self.q_last = q
        if self.rest is not None:
            self.rest.finish()

    # -- display rate ----------------------------------------------------------------------
    def _errors(self, est: tuple, final: bool) -> tuple[NDArray, NDArray]:
        """Errors of the estimates the truth now covers (times s, (n, 3) deg); keeps the rest
        pending until covered or given up."""
        self.err_pending.add(*est)
        t_ns, t_s, q = self.err_pending.take()
        if not self.truth_count or self.anchor_pending or not len(t_ns):
            return np.zeros(0), np.zeros((0, 3))
        cover = self.truth_max_ns if self.truth_max_ns is not None else -1
        ready = t_ns <= cover
        give_up = ~ready & (final | (t_ns < t_ns[-1] - _ERROR_GIVE_UP_NS))
        wait = ~ready & ~give_up
        self.err_pending.add(t_ns[wait], t_s[wait], q[wait])
        if not ready.any():
            return np.zeros(0), np.zeros((0, 3))
        qt = slerp_truth(*self._truth_arrays(), t_ns[ready])
        ok = np.all(np.isfinite(qt), axis=1)
        if not ok.any():
            return np.zeros(0), np.zeros((0, 3))
        e = attitude_error_deg(q[ready][ok], qt[ok])
        err = np.stack([e.total_deg, e.inclination_deg, e.heading_deg], axis=1)
        self.stats.add(err)
        self.truth_used += int(ok.sum())
        return t_s[ready][ok], err

    def flush(self, final: bool = False) -> None:
        """Errors for covered estimates, one batch to the view and the recording, latency."""
        est = self.est.take()
        err_t, err = self._errors(est, final)
        g_t, g_w, g_arr = self.gyro.take()
        t0 = self.t0_ns
        if t0 is None:  # no gyro sample yet: keep the truth rows for later
            return
        tr_t, tr_q = self.truth_rows.take()
        if self.view is not None:
            self.view.log(
                gyro_t_s=g_t,
                omega_b=g_w,
                est_t_s=est[1],
                q_est=est[2],
                truth_t_s=(tr_t - t0) * 1e-9,
                q_truth=tr_q,
                err_t_s=err_t,
                err_deg=err,
            )
        if len(g_arr):
            self.latency.add((time.perf_counter_ns() - g_arr) * 1e-6)
        if self.recorder is not None and len(est[0]):
            self.recorder.add_estimate(est[0], est[2])

"""The gyro bias from rest, estimated causally as samples arrive (replay's rule, online).

Replay's rule (``imu_dcm.replay.bias``): a sample is at rest when a window of ``win`` samples
(``min_duration_s`` over the step) covering it has a mean rate magnitude below
``max_rate_rad_s`` and every per-axis standard deviation below ``max_std_rad_s``; consecutive
rest samples form a segment ``[a, b)`` whose bias is the mean over ``[a + win, b - win)``
(``a`` itself at the start of the log), the middle half when that is shorter than a window.

Online, the window ending at the newest sample ``k`` is tested when ``k`` arrives. While the
segment lasts, the bias is the mean over ``[a + win, k + 1 - win)``: one window behind the newest
sample. When motion starts, the last still window ends at ``b - 1``, so the last update covers
exactly ``[a + win, b - win)``, replay's value for the segment. The bias applied to a sample is
the estimate available when it arrives (causal; replay applies a segment's bias from its start).
The step ``dt`` is the median of the first ``win_probe`` steps (replay: of the whole log).
"""

from __future__ import annotations

import math
from collections import deque

__all__ = ["CausalRestBias"]


class CausalRestBias:
    """Online rest detector and bias estimate.

    Parameters
    ----------
    min_duration_s, max_rate_rad_s, max_std_rad_s : float
        The rest rule (defaults as replay's ``RestConfig``).
    probe : int
        Steps used to fix the window length (median step).

    Attributes
    ----------
    bias_rad_s : tuple of 3 floats — current estimate, body axes, rad/s (zeros before any rest).
    segments : list of dict — ``start_s``, ``end_s``, ``bias_rad_s`` of each finished segment.
    updates : int — how many times the estimate changed.
    """

    def __init__(
        self,
        min_duration_s: float = 0.5,
        max_rate_rad_s: float = 0.035,
        max_std_rad_s: float = 0.01,
        probe: int = 64,
    ) -> None:
        self.min_duration_s = min_duration_s
        self.max_rate = max_rate_rad_s
        self.max_var = max_std_rad_s**2
        self.probe = probe
        self.bias_rad_s = (0.0, 0.0, 0.0)
        self.segments: list[dict] = []
        self.updates = 0
        self.at_rest = False
        self._ts: list[float] = []
        self.win = 0
        self._buf: deque = deque()  # last win samples (w, t)
        self._sum = [0.0, 0.0, 0.0]
        self._sq = [0.0, 0.0, 0.0]
        self._k = -1  # index of the newest sample
        self._seg_start = -1  # a, or -1 when not in a segment
        self._seg_t0 = 0.0
        self._acc = [0.0, 0.0, 0.0]
        self._acc_n = 0
        self._hist: deque = deque()  # samples of the segment not yet accumulated (w, index)
        self._recompute = 0
        self._last_t = 0.0

    def _set_window(self) -> None:
        steps = sorted(b - a for a, b in zip(self._ts, self._ts[1:], strict=False))
        dt = steps[len(steps) // 2] if steps else 1.0
        self.win = max(2, math.ceil(self.min_duration_s / dt))

    def update(self, w: tuple[float, float, float], t_s: float) -> tuple[float, float, float]:
        """Add one sample (rad/s, body axes; stamp s); return the bias to subtract from it."""
        self._last_t = t_s
        if not self.win:
            self._ts.append(t_s)
            if len(self._ts) <= self.probe:
                self._buf.append((w, t_s))
                if len(self._ts) < self.probe:
                    return self.bias_rad_s
            self._set_window()
            replay = list(self._buf)
            self._buf.clear()
            self._k = -1
            for wi, ti in replay:
                self._step(wi, ti)
            return self.bias_rad_s
        self._step(w, t_s)
        return self.bias_rad_s

    def _step(self, w, t_s: float) -> None:
        self._k += 1
        k = self._k
        buf, s, q = self._buf, self._sum, self._sq
        buf.append((w, t_s))
        for i in range(3):
            s[i] += w[i]
            q[i] += w[i] * w[i]
        if len(buf) > self.win:
            old, _ = buf.popleft()
            for i in range(3):
                s[i] -= old[i]
                q[i] -= old[i] * old[i]
        self._recompute += 1
        if self._recompute >= 4096:  # bound the drift of the running sums
            self._recompute = 0
            s[:] = [sum(v[0][i] for v in buf) for i in range(3)]
            q[:] = [sum(v[0][i] ** 2 for v in buf) for i in range(3)]
        still = False
        if len(buf) == self.win:
            n = self.win
            m = [s[i] / n for i in range(3)]
            var = [max(q[i] / n - m[i] * m[i], 0.0) for i in range(3)]
            still = math.sqrt(m[0] ** 2 + m[1] ** 2 + m[2] ** 2) < self.max_rate and all(
                v < self.max_var for v in var
            )
        if still:
            if self._seg_start < 0:
                # a segment starts with the first sample of this still window
                a = k - self.win + 1
                self._seg_start = a
                self._seg_t0 = buf[0][1]
                self._acc = [0.0, 0.0, 0.0]
                self._acc_n = 0
                self._lo = a if a == 0 else a + self.win
                self._hist = deque((v[0], a + j) for j, v in enumerate(buf))
            else:
                self._hist.append((w, k))
            # accumulate samples with index in [lo, k + 1 - win)
            hi = k + 1 - self.win
            hist = self._hist
            while hist and hist[0][1] < hi:
                wi, i = hist.popleft()
                if i >= self._lo:
                    for j in range(3):
                        self._acc[j] += wi[j]
                    self._acc_n += 1
            if self._acc_n:
                self.bias_rad_s = tuple(v / self._acc_n for v in self._acc)
                self.updates += 1
            self.at_rest = True
            self._seg_end_t = t_s
        elif self._seg_start >= 0:
            self._close_segment()

    def _close_segment(self) -> None:
        self.segments.append(
            {"start_s": self._seg_t0, "end_s": self._seg_end_t, "bias_rad_s": list(self.bias_rad_s)}
        )
        self._seg_start = -1
        self.at_rest = False

    def finish(self) -> None:
        """Close an open segment (at stop)."""
        if self._seg_start >= 0:
            self._close_segment()

"""Put samples in stamp order within a window; drop and count what comes later than that.

A sample is held until a sample stamped at least ``window_ns`` later has arrived, then released
in stamp order. A sample stamped at or before the last released one is too late: a duplicate
stamp (equal, or equal to one still held) is dropped as ``duplicate``, an earlier one as
``backward`` (out of order by more than the window, or a clock that jumped back). Non-finite
rates are dropped as ``nonfinite``, and rates no gyro produces
(:func:`imu_dcm.gyro.rates.implausible_rates`, the rule replay's cleaning applies) as
``implausible``,
before anything else (the rest rule, the integrator) sees them. :meth:`ReorderBuffer.flush`
releases everything held (at stop). Stamps are the source's, never arrival times.

Samples come and go as arrays (one batch per wake-up of the source). A batch in order and after
everything seen is merged by slicing; only a batch with a sample out of order, or a duplicate, is
judged sample by sample (the rule above depends on what the earlier samples released).
"""

from __future__ import annotations

import bisect

import numpy as np
from numpy.typing import NDArray

from imu_dcm.gyro.rates import implausible_rates

__all__ = ["ReorderBuffer"]

_EMPTY_T = np.zeros(0, np.int64)


class ReorderBuffer:
    """Reorder window over samples ``(t_ns, omega_b, arrival_ns)``; columns of ``omega_b``
    after its first three (the accelerometer, where the source has one) ride along.

    Parameters
    ----------
    window_ns : int
        Hold time in source time, ns (0: release at once; then any out-of-order sample is late).
    """

    def __init__(self, window_ns: int) -> None:
        if window_ns < 0:
            raise ValueError(f"Expected a reorder window >= 0 ns, got {window_ns}")
        self.window_ns = int(window_ns)
        self._t = _EMPTY_T  # held, in stamp order
        self._w = np.zeros((0, 3))
        self._a = _EMPTY_T
        self.newest_ns: int | None = None
        self.last_released_ns: int | None = None
        self.dropped_duplicate = 0
        self.dropped_backward = 0
        self.dropped_nonfinite = 0
        self.dropped_implausible = 0
        self.reordered = 0  # samples that arrived out of order and were put back in order

    def __len__(self) -> int:
        return len(self._t)

    def push(
        self, t_ns: NDArray[np.int64], omega_b: NDArray, arrival_ns: NDArray[np.int64]
    ) -> tuple[NDArray[np.int64], NDArray, NDArray[np.int64]]:
        """Add a batch of samples in arrival order; return the released ones, in stamp order.

        Parameters
        ----------
        t_ns : int64 (n,) — stamps, ns.
        omega_b : float64 (n, 3) — rates, rad/s (judged finite and plausible); (n, 3 + k):
            the rates and k columns carried along (as many in every batch).
        arrival_ns : int64 (n,) — carried along with each sample.

        Returns
        -------
        t_ns, omega_b, arrival_ns of the released samples, stamps strictly increasing.
        """
        if not len(self._t):  # the columns of the batches to come
            self._w = self._w.reshape(0, omega_b.shape[1])
        rates = omega_b[:, :3]
        finite = np.isfinite(rates).all(axis=1)
        ok = finite & ~implausible_rates(rates)
        if not ok.all():
            n_bad = len(ok) - int(finite.sum())
            self.dropped_nonfinite += n_bad
            self.dropped_implausible += len(ok) - int(ok.sum()) - n_bad
            t_ns, omega_b, arrival_ns = t_ns[ok], omega_b[ok], arrival_ns[ok]
        if not len(t_ns):
            return self._release(-1)  # nothing new: nothing to release
        newest = self.newest_ns
        if (newest is None or t_ns[0] > newest) and bool(np.all(t_ns[1:] > t_ns[:-1])):
            # in order, after everything seen: merged by concatenation, released by slicing
            self.newest_ns = int(t_ns[-1])
            self._t = np.concatenate([self._t, t_ns])
            self._w = np.concatenate([self._w, omega_b])
            self._a = np.concatenate([self._a, arrival_ns])
            return self._release(self.newest_ns - self.window_ns)
        return self._push_each(t_ns, omega_b, arrival_ns)

    def _release(self, limit_ns: int) -> tuple[NDArray[np.int64], NDArray, NDArray[np.int64]]:
        """Release the held samples stamped at or before ``limit_ns`` (stamps are >= 0)."""
        k = int(np.searchsorted(self._t, limit_ns, side="right"))
        out = self._t[:k], self._w[:k], self._a[:k]
        if k:
            self._t, self._w, self._a = self._t[k:], self._w[k:], self._a[k:]
            self.last_released_ns = int(out[0][-1])
        return out

    def _push_each(
        self, t_ns: NDArray[np.int64], omega_b: NDArray, arrival_ns: NDArray[np.int64]
    ) -> tuple[NDArray[np.int64], NDArray, NDArray[np.int64]]:
        """The rule sample by sample (a batch with a sample out of order or a duplicate)."""
        held_t = self._t.tolist()  # sorted
        rows = dict(zip(held_t, zip(self._w.tolist(), self._a.tolist(), strict=True), strict=True))
        out_t: list[int] = []
        out_rows: list[tuple] = []
        for t, w, a in zip(t_ns.tolist(), omega_b.tolist(), arrival_ns.tolist(), strict=True):
            last = self.last_released_ns
            if (last is not None and t <= last) or t in rows:
                if t == last or t in rows:
                    self.dropped_duplicate += 1
                else:
                    self.dropped_backward += 1
                continue
            if self.newest_ns is None or t > self.newest_ns:
                self.newest_ns = t
            else:
                self.reordered += 1
            bisect.insort(held_t, t)
            rows[t] = (w, a)
            k = bisect.bisect_right(held_t, self.newest_ns - self.window_ns)
            if k:
                out_t.extend(held_t[:k])
                out_rows.extend(rows.pop(s) for s in held_t[:k])
                self.last_released_ns = held_t[k - 1]
                del held_t[:k]
        self._t = np.array(held_t, np.int64)
        cols = self._w.shape[1]
        self._w = np.array([rows[s][0] for s in held_t], float).reshape(-1, cols)
        self._a = np.array([rows[s][1] for s in held_t], np.int64)
        return (
            np.array(out_t, np.int64),
            np.array([r[0] for r in out_rows], float).reshape(-1, cols),
            np.array([r[1] for r in out_rows], np.int64),
        )

    def flush(self) -> tuple[NDArray[np.int64], NDArray, NDArray[np.int64]]:
        """Release everything held, in order."""
        if not len(self._t):
            return self._release(-1)
        return self._release(int(self._t[-1]))

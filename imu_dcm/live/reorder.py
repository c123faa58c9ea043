"""Put samples in stamp order within a window; drop and count what comes later than that.

A sample is held until a sample stamped at least ``window_ns`` later has arrived, then released
in stamp order. A sample stamped at or before the last released one is too late: a duplicate
stamp (equal, or equal to one still held) is dropped as ``duplicate``, an earlier one as
``backward`` (out of order by more than the window, or a clock that jumped back). Non-finite
rates are dropped as ``nonfinite``. :meth:`ReorderBuffer.flush` releases everything held (at
stop). Stamps are the source's, never arrival times.
"""

from __future__ import annotations

import heapq
import math

__all__ = ["ReorderBuffer"]


class ReorderBuffer:
    """Reorder window over ``(t_ns, item)`` pairs.

    Parameters
    ----------
    window_ns : int
        Hold time in source time, ns (0: release at once; then any out-of-order sample is late).
    """

    def __init__(self, window_ns: int) -> None:
        if window_ns < 0:
            raise ValueError(f"Expected a reorder window >= 0 ns, got {window_ns}")
        self.window_ns = int(window_ns)
        self._heap: list[tuple[int, int, object]] = []
        self._held: set[int] = set()
        self._seq = 0
        self.newest_ns: int | None = None
        self.last_released_ns: int | None = None
        self.dropped_duplicate = 0
        self.dropped_backward = 0
        self.dropped_nonfinite = 0
        self.reordered = 0  # samples that arrived out of order and were put back in order

    def __len__(self) -> int:
        return len(self._heap)

    def push(self, t_ns: int, omega: tuple[float, float, float], item: object, out: list) -> None:
        """Add one sample; append the released ``(t_ns, omega, item)`` to ``out`` in order."""
        x, y, z = omega
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
            self.dropped_nonfinite += 1
            return
        last = self.last_released_ns
        if last is not None and t_ns <= last:
            if t_ns == last:
                self.dropped_duplicate += 1
            else:
                self.dropped_backward += 1
            return
        if t_ns in self._held:
            self.dropped_duplicate += 1
            return
        newest = self.newest_ns
        if newest is None or t_ns > newest:
            self.newest_ns = newest = t_ns
        else:
            self.reordered += 1
        if self.window_ns == 0 and not self._heap:
            self.last_released_ns = t_ns
            out.append((t_ns, omega, item))
            return
        self._seq += 1
        heapq.heappush(self._heap, (t_ns, self._seq, (omega, item)))
        self._held.add(t_ns)
        limit = newest - self.window_ns
        heap = self._heap
        while heap and heap[0][0] <= limit:
            t, _, (w, it) = heapq.heappop(heap)
            self._held.discard(t)
            self.last_released_ns = t
            out.append((t, w, it))

    def flush(self, out: list) -> None:
        """Release everything held, in order."""
        while self._heap:
            t, _, (w, it) = heapq.heappop(self._heap)
            self._held.discard(t)
            self.last_released_ns = t
            out.append((t, w, it))

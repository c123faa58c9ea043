"""Receive -> view latencies of a live run in bounded memory (:class:`Latency`)."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

__all__ = ["LATENCY_KEEP", "LATENCY_REL", "Latency"]

#: Latency histogram: bins this wide in relative terms, from _LAT_MIN_MS ms up (~1e6 ms).
LATENCY_REL = 1e-3
_LAT_MIN_MS = 1e-3
_LAT_BINS = 20_800
#: Latencies kept as values for :attr:`LiveResult.latency_ms` (the newest ones).
LATENCY_KEEP = 1 << 16


class Latency:
    """Receive -> view latencies in bounded memory: a histogram of every sample's (bins
    :data:`LATENCY_REL` wide in relative terms, so a percentile is read to 0.1 %), the newest
    batch (the status line) and the newest :data:`LATENCY_KEEP` values (the result's array).

    A live run of any length holds the same: 27 bytes a sample grew without bound when every
    latency was kept (836 MB after 31 M samples).
    """

    def __init__(self) -> None:
        self.counts = np.zeros(_LAT_BINS, np.int64)
        self.n = 0
        self.last = np.zeros(0)
        self._recent: list[NDArray] = []
        self._recent_n = 0

    def add(self, ms: NDArray) -> None:
        """Latencies of one batch, ms."""
        self.last = ms
        self.n += len(ms)
        k = np.log(np.maximum(ms, _LAT_MIN_MS) / _LAT_MIN_MS) / np.log1p(LATENCY_REL)
        self.counts += np.bincount(np.minimum(k.astype(np.int64), _LAT_BINS - 1), None, _LAT_BINS)
        self._recent.append(ms)
        self._recent_n += len(ms)
        while self._recent_n - len(self._recent[0]) >= LATENCY_KEEP:
            self._recent_n -= len(self._recent.pop(0))

    def percentile(self, p: float) -> float | None:
        """The ``p`` th percentile of every latency, ms (the centre of its bin), or None."""
        if not self.n:
            return None
        k = int(np.searchsorted(np.cumsum(self.counts), max(1, math.ceil(p / 100 * self.n))))
        return float(_LAT_MIN_MS * (1 + LATENCY_REL) ** (k + 0.5))

    def recent(self) -> NDArray:
        """The newest latencies kept (at most :data:`LATENCY_KEEP` and one batch), ms."""
        return np.concatenate(self._recent) if self._recent else np.zeros(0)

"""The pipeline's buffers: columns collected in array chunks, and running error statistics."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

__all__ = ["Rows", "Stats"]


class Rows:
    """Columns collected as a list of array chunks; :meth:`take` concatenates and empties.
    ``shapes``: per column, its dtype and the shape of a row after it (``(float, 3)``)."""

    def __init__(self, *shapes: tuple) -> None:
        self.shapes = shapes
        self.chunks: list[tuple] = []

    def add(self, *cols: NDArray) -> None:
        if len(cols[0]):
            self.chunks.append(cols)

    def take(self) -> tuple[NDArray, ...]:
        chunks, self.chunks = self.chunks, []
        if not chunks:
            return tuple(np.zeros((0, *s[1:]), s[0]) for s in self.shapes)
        return tuple(np.concatenate([c[k] for c in chunks]) for k in range(len(self.shapes)))

    def __len__(self) -> int:
        return sum(len(c[0]) for c in self.chunks)

    def trim(self, keep: int) -> None:
        """Drop whole leading chunks older than ``keep`` (in the first column's unit) behind
        the newest row."""
        if len(self.chunks) > 1:
            newest = self.chunks[-1][0][-1]
            while len(self.chunks) > 1 and self.chunks[1][0][0] <= newest - keep:
                del self.chunks[0]


@dataclass(slots=True)
class Stats:
    """Running error statistics (RMS and max of total, inclination, heading): ``n`` rows,
    ``sq`` the sum of their squares, ``max`` the largest, deg."""

    n: int = 0
    sq: NDArray = field(default_factory=lambda: np.zeros(3))
    max: NDArray = field(default_factory=lambda: np.zeros(3))

    def add(self, err: NDArray) -> None:
        if len(err):
            self.n += len(err)
            self.sq += (err * err).sum(axis=0)
            self.max = np.maximum(self.max, err.max(axis=0))

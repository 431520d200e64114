"""The time series a :class:`formation.record.collector.RunCollector` keeps: values stamped with a
row
key (tick or bus time), in arrival order, decimated under the collector's memory bound, and read
back as "the latest value at or before each row"."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

__all__ = ["Series", "sample_at"]

F64 = npt.NDArray[np.float64]


@dataclass
class Series:
    """Time-stamped values of one quantity, appended in arrival order.

    A decimated series (``stride`` > 1, set by the collector's memory bound) keeps one value in
    ``stride`` of those added."""

    keys: list[float] = field(default_factory=list)
    values: list[Any] = field(default_factory=list)
    stride: int = 1
    max_key: float = -math.inf  # the largest key added (stored or not)
    _seen: int = 0

    def add(self, key: float, value: Any) -> int:
        """Store the value (or skip it, decimated); returns how many entries were stored."""
        self._seen += 1
        if key > self.max_key:
            self.max_key = key
        if self.stride > 1 and self._seen % self.stride:
            return 0
        self.keys.append(key)
        self.values.append(value)
        return 1

    def halve(self) -> None:
        """Keep every other stored value (the first kept) and double the stride."""
        self.keys = self.keys[::2]
        self.values = self.values[::2]
        self.stride *= 2

    def sorted(self) -> tuple[F64, list[Any]]:
        order = sorted(range(len(self.keys)), key=self.keys.__getitem__)  # stable: arrival order
        return np.array([self.keys[i] for i in order], dtype=float), [self.values[i] for i in order]

    def latest(self) -> Any:
        return self.values[-1] if self.values else None


def sample_at(series: Series, rows: F64) -> list[Any]:
    """For every row key, the latest value with key <= the row key (None before the first)."""
    k, v = series.sorted()
    if k.size == 0:
        return [None] * rows.size
    idx = np.searchsorted(k, rows, side="right") - 1
    return [v[i] if i >= 0 else None for i in idx.tolist()]

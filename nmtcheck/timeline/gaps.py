"""Heartbeat intervals as a multiset: plain values, plus value counts for the runs of
steady heartbeats that a very long log keeps only as counts (`ec_compact`).

Without counts every statistic is numpy's own on the plain values, so a log that is
not compacted gets exactly the figures it always got; with counts, the order statistics
(minimum, maximum, median, percentiles) are computed the way numpy computes them on the
expanded values, bit for bit, and the standard deviation from the weighted sums.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Gaps:
    """Intervals in seconds: `values`, each counted `counts` times (None: once each)."""

    values: np.ndarray
    counts: np.ndarray | None = None

    @classmethod
    def join(cls, plain: np.ndarray, hists: list[tuple[np.ndarray, np.ndarray]]) -> Gaps:
        """Plain intervals and compacted runs' (values, counts) as one multiset."""
        if not hists:
            return cls(plain)
        values = np.concatenate([plain, *(v for v, _ in hists)])
        counts = np.concatenate([np.ones(len(plain), np.int64),
                                 *(c.astype(np.int64) for _, c in hists)])
        order = np.argsort(values, kind="stable")
        return cls(values[order], counts[order])

    @property
    def count(self) -> int:
        return len(self.values) if self.counts is None else int(self.counts.sum())

    def __len__(self) -> int:
        return self.count

    def minimum(self) -> float:
        return float(self.values.min())

    def maximum(self) -> float:
        return float(self.values.max())

    def _kth(self, k: np.ndarray) -> np.ndarray:
        """The k-th smallest values (0-based) of the expanded multiset (sorted values)."""
        assert self.counts is not None
        ends = np.cumsum(self.counts)
        return self.values[np.searchsorted(ends, k, side="right")]

    def median(self) -> float:
        if self.counts is None:
            return float(np.median(self.values))
        n = self.count
        lo, hi = self._kth(np.asarray([(n - 1) // 2, n // 2]))
        return float(lo) if n % 2 else float(np.mean([lo, hi]))

    def percentile(self, q: float) -> float:
        """numpy's default ('linear') percentile."""
        if self.counts is None:
            return float(np.percentile(self.values, q))
        n = self.count
        virtual = np.asarray(q / 100.0, np.float64) * (n - 1)
        below = np.floor(virtual)
        gamma = float(virtual - below)
        lo_i = int(below)
        a, b = (float(x) for x in self._kth(np.asarray([lo_i, min(lo_i + 1, n - 1)])))
        diff = b - a
        return b - diff * (1 - gamma) if gamma >= 0.5 else a + diff * gamma

    def std(self) -> float:
        """Population standard deviation."""
        if self.counts is None:
            return float(np.std(self.values))
        w = self.counts.astype(np.float64)
        mean = float((self.values * w).sum() / w.sum())
        return float(np.sqrt(((self.values - mean) ** 2 * w).sum() / w.sum()))

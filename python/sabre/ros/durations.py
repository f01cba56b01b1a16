"""Bounded-memory records of the durations the bridge's nodes measure at 1 kHz (latency, loop work)."""

from __future__ import annotations

import math

import numpy as np

#: Longest duration a record resolves (s); longer ones count as this long.
LONGEST = 3600.0

#: Relative width of a bucket: percentiles to three significant digits.
_RESOLUTION = 1e-3
_SMALLEST = 1e-6  # s: one microsecond, the first bucket's upper edge
_BUCKETS = int(math.ceil(math.log(LONGEST / _SMALLEST) / math.log1p(_RESOLUTION))) + 2


class Durations:
    """Durations (s) recorded for as long as a node runs, in a histogram of logarithmic buckets one
    part in a thousand wide (three significant digits, from a microsecond to an hour): memory and
    the cost of a percentile stay the same after an hour at 1 kHz as after a second. A record is a
    list append on the 1 kHz path; the buckets are filled in one vectorised step when a percentile
    is asked for (the status thread). Negative durations (clocks of two processes a few
    microseconds apart) count as zero; NaN is not recorded."""

    def __init__(self) -> None:
        self._counts = np.zeros(_BUCKETS, dtype=np.int64)
        self._pending: list[float] = []
        self._max = -math.inf
        self._total = 0

    def record(self, seconds: float) -> None:
        if seconds == seconds:  # not NaN
            self._pending.append(seconds)

    def record_all(self, seconds: np.ndarray) -> None:
        """Records each of ``seconds`` (NaN skipped)."""
        values = np.asarray(seconds, dtype=np.float64)
        self._pending.extend(values[~np.isnan(values)].tolist())

    def _flush(self) -> None:
        pending, self._pending = self._pending, []
        if not pending:
            return
        values = np.clip(np.asarray(pending, dtype=np.float64), 0.0, LONGEST)
        self._max = max(self._max, float(values.max()))
        index = np.zeros(len(values), dtype=np.int64)
        above = values > _SMALLEST
        index[above] = 1 + np.floor(np.log(values[above] / _SMALLEST) / math.log1p(_RESOLUTION)).astype(np.int64)
        np.add.at(self._counts, np.minimum(index, _BUCKETS - 1), 1)
        self._total += len(values)

    def __len__(self) -> int:
        self._flush()
        return self._total

    def percentile_ms(self, q: float) -> float:
        """The q-th percentile (ms) to three significant digits (the smallest recorded value with q %
        at or below it, as its bucket's middle); NaN before the first record."""
        self._flush()
        if not self._total:
            return math.nan
        rank = max(1, int(math.ceil(q / 100.0 * self._total)))
        k = int(np.searchsorted(np.cumsum(self._counts), rank))
        if k == 0:
            return 0.0 if self._counts[0] and self._max <= 0.0 else min(self._max, _SMALLEST) * 1e3
        middle = _SMALLEST * (1.0 + _RESOLUTION) ** (k - 0.5)
        return min(middle, self._max) * 1e3

    def max_ms(self) -> float:
        self._flush()
        return self._max * 1e3 if self._total else math.nan


def gap_percentiles(counts: np.ndarray, period: float) -> dict[str, float]:
    """The p50, p99, p99.9 and largest of gaps counted by length in cycles (``counts[k]``: gaps of
    k cycles of ``period`` s; the last bin holds every longer one), in ms, and how many there were."""
    counts = np.asarray(counts, dtype=np.int64)
    total = int(counts.sum())
    out: dict[str, float] = {"count": float(total)}
    if total == 0:
        return out | {"p50_ms": math.nan, "p99_ms": math.nan, "p99.9_ms": math.nan, "max_ms": math.nan}
    cumulative = np.cumsum(counts)
    for name, q in (("p50_ms", 0.5), ("p99_ms", 0.99), ("p99.9_ms", 0.999)):
        out[name] = float(np.searchsorted(cumulative, q * total) * period * 1e3)
    out["max_ms"] = float(np.flatnonzero(counts)[-1] * period * 1e3)
    return out

"""Bounded-memory records of the durations the bridge's nodes measure at 1 kHz (latency, loop work)."""

from __future__ import annotations

import math

from hdrh.histogram import HdrHistogram

#: Longest duration a record resolves (s); longer ones count as this long.
LONGEST = 3600.0


class Durations:
    """Durations (s) recorded for as long as a node runs, in an HdrHistogram of microseconds with
    three significant digits: memory and the cost of a percentile stay the same after an hour at
    1 kHz as after a second, where a list would grow by 3.6 million entries and its percentiles
    (computed for every status message) would slow the node down. Negative durations (clocks of
    two processes a few microseconds apart) count as zero; NaN is not recorded."""

    def __init__(self) -> None:
        self._histogram = HdrHistogram(1, int(LONGEST * 1e6), 3)

    def record(self, seconds: float) -> None:
        if math.isnan(seconds):
            return
        self._histogram.record_value(int(round(min(max(seconds, 0.0), LONGEST) * 1e6)))

    def __len__(self) -> int:
        return int(self._histogram.get_total_count())

    def percentile_ms(self, q: float) -> float:
        """The q-th percentile (ms) to three significant digits; NaN before the first record."""
        return self._histogram.get_value_at_percentile(q) / 1e3 if len(self) else math.nan

    def max_ms(self) -> float:
        return self._histogram.get_max_value() / 1e3 if len(self) else math.nan

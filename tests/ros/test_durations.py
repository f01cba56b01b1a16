"""The bridge's bounded-memory duration records agree with numpy's percentiles on the same samples."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sabre.ros.durations import LONGEST, Durations


def test_percentiles_match_numpy_to_three_significant_digits():
    rng = np.random.default_rng(0)
    samples = rng.lognormal(mean=np.log(1e-3), sigma=1.0, size=20_000)  # latencies around 1 ms
    record = Durations()
    for s in samples:
        record.record(float(s))
    assert len(record) == len(samples)
    for q in (1, 50, 90, 99, 99.9):
        # nearest-rank percentile, as the histogram reports it (the smallest sample with q % at or below)
        expected = np.percentile(samples, q, method="inverted_cdf") * 1e3
        assert record.percentile_ms(q) == pytest.approx(expected, rel=2e-3, abs=1e-3), q
    assert record.max_ms() == pytest.approx(samples.max() * 1e3, rel=2e-3)


def test_empty_negative_nan_and_overlong_durations():
    record = Durations()
    assert math.isnan(record.percentile_ms(50)) and math.isnan(record.max_ms())
    record.record(float("nan"))
    assert len(record) == 0
    record.record(-5e-6)  # two processes' clocks a few microseconds apart
    assert len(record) == 1 and record.percentile_ms(100) == 0.0
    record.record(10 * LONGEST)
    assert record.max_ms() == pytest.approx(LONGEST * 1e3, rel=2e-3)


def test_recording_many_at_once_skips_nan_and_matches_numpy():
    rng = np.random.default_rng(1)
    samples = rng.lognormal(mean=np.log(2e-4), sigma=0.5, size=5_000)
    record = Durations()
    record.record_all(np.r_[samples[:2_500], np.nan, samples[2_500:]])
    record.record_all(np.zeros(0))
    assert len(record) == len(samples)
    expected = np.percentile(samples, 99, method="inverted_cdf") * 1e3
    assert record.percentile_ms(99) == pytest.approx(expected, rel=2e-3)

"""The real-time timer's statistics in bounded memory (gnc_common.timing)."""

from __future__ import annotations

import numpy as np

from gnc_common.timing import BIN_S, N_BINS, PeriodStatistics

MS = 1_000_000


def test_period_error_counts_missed_ticks_strictly_beyond_one_and_a_half_periods() -> None:
    stats = PeriodStatistics(0.01)
    for t_ns in (0, 10 * MS + 3000, 20 * MS + 3000, 35 * MS + 3000, 51 * MS + 3000):
        stats.tick(t_ns)
    # intervals 10.003, 10, 15 (exactly 1.5 periods: not missed), 16 ms (missed)
    assert stats.ticks == 5 and stats.missed == 1
    assert stats.max_error_s == 6e-3
    s = stats.summary()
    assert s["missed_ticks"] == 1 and s["period_error_max_ms"] == 6.0
    # errors 3 us, 0, 5 ms, 6 ms: the median (2nd of 4) is 3 us, reported as its bin's upper edge
    assert s["period_error_p50_ms"] == BIN_S * 1e3
    assert s["period_error_p99_ms"] == 6.0  # the top bin's edge, capped at the exact maximum


def test_before_two_ticks_there_is_no_period() -> None:
    stats = PeriodStatistics(0.01)
    assert stats.summary() == {"ticks": 0}
    stats.tick(123)
    assert stats.summary() == {"ticks": 1} and stats.percentile_s(99) == 0.0


def test_percentiles_bound_the_exact_ones_to_one_bin_and_memory_does_not_grow(rng) -> None:  # type: ignore[no-untyped-def]
    stats = PeriodStatistics(0.01)
    intervals_ns = (10 * MS + rng.normal(0.0, 300_000, 20_000)).astype(np.int64)
    intervals_ns[::1000] += 150 * MS  # a few errors beyond the histogram (100 ms): the last bin
    ticks = np.concatenate(([0], np.cumsum(intervals_ns)))
    size = stats.errors._hist.nbytes
    for t in ticks:
        stats.tick(int(t))
    assert stats.errors._hist.nbytes == size == N_BINS * 8
    errors = np.abs(intervals_ns - 10 * MS) / 1e9
    for q in (50, 90, 99, 99.9):
        exact = float(np.percentile(errors, q, method="inverted_cdf"))
        if exact < N_BINS * BIN_S:
            assert exact <= stats.percentile_s(q) <= exact + BIN_S, q
        else:  # beyond the histogram: bounded by the exact maximum
            assert stats.percentile_s(q) == errors.max() >= exact, q
    assert stats.max_error_s == errors.max()
    assert stats.missed == int(np.sum(intervals_ns > 15 * MS)) == 20

"""Statistics of a periodic timer's ticks in bounded memory (the real-time controller's timing).

A run of an hour at 100 Hz has 360,000 ticks; keeping each tick's wall time grew the controller
by about 40 bytes a tick without bound.  :class:`PeriodStatistics` keeps a fixed histogram of the
period error instead: its percentiles are exact to :data:`BIN_S` (the upper edge of the bin is
reported, so a percentile is never under-stated), its maximum and its counts are exact.  No clock
is read here: the caller passes each tick's time.
"""

from __future__ import annotations

import numpy as np

__all__ = ["BIN_S", "N_BINS", "PeriodStatistics"]

#: Width of a bin of the period-error histogram [s]: 10 us, twenty times finer than the 0.5 ms
#: p99 target the real-time loop is judged by.
BIN_S = 1e-5
#: Number of bins: errors up to N_BINS * BIN_S = 100 ms are binned, larger ones fall in the last
#: bin (the maximum is kept exactly).  80 kB of int64.
N_BINS = 10_000
#: A tick whose interval exceeds this many periods counts as a missed tick.
MISSED_FACTOR = 1.5


class PeriodStatistics:
    """Period error ``|interval - period|`` of consecutive ticks, and missed ticks (intervals
    longer than :data:`MISSED_FACTOR` periods), in bounded memory."""

    def __init__(self, period_s: float) -> None:
        self.period_ns = period_s * 1e9
        self.ticks = 0
        self.missed = 0
        self.max_error_s = 0.0
        self._last_ns: int | None = None
        self._hist = np.zeros(N_BINS, dtype=np.int64)

    def tick(self, wall_ns: int) -> None:
        """Record a tick at ``wall_ns`` (a monotonic clock, nanoseconds)."""
        self.ticks += 1
        if self._last_ns is not None:
            interval_ns = wall_ns - self._last_ns
            error_s = abs(interval_ns - self.period_ns) / 1e9
            self._hist[min(int(error_s / BIN_S), N_BINS - 1)] += 1
            self.max_error_s = max(self.max_error_s, error_s)
            self.missed += interval_ns > MISSED_FACTOR * self.period_ns
        self._last_ns = wall_ns

    def percentile_s(self, q: float) -> float:
        """The ``q``-th percentile (0 < q <= 100) of the period error [s], to the upper edge of its
        bin (never more than the exact maximum; the maximum itself when it falls beyond the
        histogram's 100 ms); 0 before two ticks."""
        n = int(self._hist.sum())
        if n == 0:
            return 0.0
        rank = int(np.ceil(q / 100.0 * n))
        k = int(np.searchsorted(np.cumsum(self._hist), rank))
        if k == N_BINS - 1:  # beyond the histogram: the maximum bounds it
            return self.max_error_s
        return min((k + 1) * BIN_S, self.max_error_s)

    def summary(self) -> dict[str, float | int]:
        """``ticks``, then (after two ticks) the period error's p50, p99 and max [ms] and ``missed_ticks``."""
        if self.ticks < 2:
            return {"ticks": self.ticks}
        return {
            "ticks": self.ticks,
            "period_error_p50_ms": self.percentile_s(50) * 1e3,
            "period_error_p99_ms": self.percentile_s(99) * 1e3,
            "period_error_max_ms": self.max_error_s * 1e3,
            "missed_ticks": self.missed,
        }

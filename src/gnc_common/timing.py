"""Timing statistics of the real-time loop in bounded memory.

A run of an hour at 100 Hz has 360,000 ticks; keeping each tick's wall time grew the controller
by about 40 bytes a tick without bound.  :class:`Histogram` keeps a fixed histogram instead: its
percentiles are exact to :data:`BIN_S` (the upper edge of the bin is reported, so a percentile is
never under-stated), its maximum and its counts are exact.  Two uses:
:class:`PeriodStatistics` (a periodic timer's period error and missed ticks: the plant's frame
timer) and :class:`LatencyStatistics` (how long after a state's stamp the controller's torque was
out, and how often that missed the deadline).  No clock is read here: the caller passes the times.
"""

from __future__ import annotations

import numpy as np

__all__ = ["BIN_S", "MISSED_FACTOR", "N_BINS", "Histogram", "LatencyStatistics", "PeriodStatistics"]

#: Width of a bin [s]: 10 us, twenty times finer than the 0.5 ms p99 target the real-time loop is
#: judged by.
BIN_S = 1e-5
#: Number of bins: values up to N_BINS * BIN_S = 100 ms are binned, larger ones fall in the last
#: bin (the maximum is kept exactly).  80 kB of int64.
N_BINS = 10_000
#: A tick whose interval exceeds this many periods counts as a missed tick.
MISSED_FACTOR = 1.5


class Histogram:
    """Non-negative durations [s] in :data:`N_BINS` bins of :data:`BIN_S`, with the exact maximum."""

    def __init__(self) -> None:
        self.count = 0
        self.max_s = 0.0
        self._hist = np.zeros(N_BINS, dtype=np.int64)

    def add(self, value_s: float) -> None:
        self.count += 1
        self._hist[min(max(int(value_s / BIN_S), 0), N_BINS - 1)] += 1
        self.max_s = max(self.max_s, value_s)

    def percentile_s(self, q: float) -> float:
        """The ``q``-th percentile (0 < q <= 100) [s], to the upper edge of its bin (never more than
        the exact maximum; the maximum itself when it falls beyond the histogram's 100 ms); 0
        when empty."""
        if self.count == 0:
            return 0.0
        rank = int(np.ceil(q / 100.0 * self.count))
        k = int(np.searchsorted(np.cumsum(self._hist), rank))
        if k == N_BINS - 1:  # beyond the histogram: the maximum bounds it
            return self.max_s
        return min((k + 1) * BIN_S, self.max_s)


class PeriodStatistics:
    """Period error ``|interval - period|`` of consecutive ticks, and missed ticks (intervals
    longer than :data:`MISSED_FACTOR` periods), in bounded memory."""

    def __init__(self, period_s: float) -> None:
        self.period_ns = period_s * 1e9
        self.ticks = 0
        self.missed = 0
        self.errors = Histogram()
        self._last_ns: int | None = None

    @property
    def max_error_s(self) -> float:
        return self.errors.max_s

    def tick(self, wall_ns: int) -> None:
        """Record a tick at ``wall_ns`` (a monotonic clock, nanoseconds)."""
        self.ticks += 1
        if self._last_ns is not None:
            interval_ns = wall_ns - self._last_ns
            self.errors.add(abs(interval_ns - self.period_ns) / 1e9)
            self.missed += interval_ns > MISSED_FACTOR * self.period_ns
        self._last_ns = wall_ns

    def percentile_s(self, q: float) -> float:
        """The ``q``-th percentile of the period error [s] (:meth:`Histogram.percentile_s`); 0 before two ticks."""
        return self.errors.percentile_s(q)

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


class LatencyStatistics:
    """Latency of each step (its output's time minus its input's stamp) and the steps later than
    ``deadline_s``, in bounded memory."""

    def __init__(self, deadline_s: float) -> None:
        self.deadline_ns = deadline_s * 1e9
        self.late = 0
        self.latency = Histogram()

    def add(self, latency_ns: int) -> None:
        self.latency.add(latency_ns / 1e9)
        self.late += latency_ns > self.deadline_ns

    def summary(self) -> dict[str, float | int]:
        """``steps``, then (after one) the latency's p50, p99 and max [ms] and ``late_steps``."""
        h = self.latency
        if h.count == 0:
            return {"steps": 0}
        return {"steps": h.count, "latency_p50_ms": h.percentile_s(50) * 1e3, "latency_p99_ms": h.percentile_s(99) * 1e3,
                "latency_max_ms": h.max_s * 1e3, "late_steps": self.late}

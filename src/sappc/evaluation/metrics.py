"""Run metrics, accumulated sample by sample for a batch of runs.

One implementation serves every path: `sappc simulate` (one run), Monte Carlo campaigns
(thousands of runs, each sub-batch's history fed as one block, then dropped) and recorded
bags.  Feed blocks of control samples to :class:`MetricsAccumulator` (:meth:`~MetricsAccumulator.update`,
:meth:`~MetricsAccumulator.add_history`), combine accumulators of disjoint sets of runs with
:meth:`~MetricsAccumulator.concatenate`, and read :meth:`MetricsAccumulator.run_metrics`.
Definitions, per run:

``settling_time_s``
    The first sample time after which ``max_i |q_ev,i|`` stays below
    ``settle_threshold`` until the end; ``0`` if it always was, ``None`` if it
    never settles.
``steady_max_abs_qev``, ``steady_mean_abs_qev``
    Over ``t >= steady_from_s``: the largest ``|q_ev,i|``, and the largest over
    ``i`` of the time-mean of ``|q_ev,i|`` (the paper's Monte Carlo criterion).
``rpf_error_at_t2``
    ``max_i |q_ev,i - rho_i|`` at the sample nearest ``t2_s`` (``None`` when the run ends
    before ``t2_s``), with ``rho`` the
    controller's own performance function (the RPF for SAPPC): the paper's
    other Monte Carlo criterion.
``overshoot``
    The largest excursion of any component to the sign opposite its initial
    error, ``max_{i,t} max(0, -sign(q_ev,i(0)) q_ev,i(t))`` (``sign(0) = +1``).
``max_abs_torque_Nm``
    Largest produced per-axis torque magnitude.
``saturation_fraction``
    Fraction of control samples at which at least one axis was saturated.
``time_outside_constraint_s``
    Time with any component outside its constraint band, each sample held until the next
    (zero-order hold): the number of such samples times ``dt`` on a uniform grid (every
    interval within 1e-9 s of the first), else the sum of their intervals ``t[k+1] - t[k]``
    (a real-time bag's jittered stamps), the last sample holding for the median interval.
``returned_to_constraint``
    Only with faults: ``True`` when every component is inside its band at the
    end of the run, i.e. from the sample after the last one outside the band
    to the end.  ``left_constraint_after_fault`` says whether the error left
    the band at or after the first fault's start, ``returned_at_s`` when it
    re-entered for good (``None`` if it never left or never returned).
``finite``
    ``False`` if the run's state or torque ever became non-finite (the run
    failed); the other metrics then describe the samples before that.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sappc.evaluation.history import History

__all__ = ["MetricsAccumulator"]

Array = NDArray[np.float64]

#: Time comparisons on the sampling grid allow this much rounding in k * dt [s].
_TIME_TOL_S = 1e-9

class MetricsAccumulator:
    """Accumulates the metrics of N runs from blocks of samples (the history need not be kept).

    Parameters
    ----------
    t : ndarray, shape (T,)
        The sample times the run will visit (``k dt``).
    n_runs : int
    steady_from_s, settle_threshold, t2_s : float
        See :class:`sappc.scenario.MetricSettings`.
    fault_windows : list of (start_s, end_s)
        Injected fault windows; empty when there are none.
    """

    def __init__(
        self,
        t: Array,
        n_runs: int,
        *,
        steady_from_s: float,
        settle_threshold: float,
        t2_s: float,
        fault_windows: list[tuple[float, float]],
    ) -> None:
        self.t = np.asarray(t, dtype=np.float64)
        self.dt = float(self.t[1] - self.t[0]) if self.t.size > 1 else 0.0
        intervals = np.diff(self.t)
        # hold interval of each sample on a non-uniform grid (None: uniform, count * dt is exact)
        self.hold_s: Array | None = None
        if intervals.size and np.any(np.abs(intervals - self.dt) > _TIME_TOL_S):
            self.hold_s = np.append(intervals, np.median(intervals))
        self.settle_threshold = settle_threshold
        self.steady_from_s = steady_from_s
        # the sample nearest t2, or none (-1) when the run ends before t2 (a run cut short)
        k_t2 = int(np.argmin(np.abs(self.t - t2_s))) if self.t.size else -1
        self.k_t2 = k_t2 if k_t2 >= 0 and abs(self.t[k_t2] - t2_s) <= 0.5 * self.dt + _TIME_TOL_S else -1
        self.fault_start_s = min((s for s, _ in fault_windows), default=None)
        n = n_runs
        self.last_unsettled = np.full(n, -1)  # last sample with max|q_ev| >= threshold
        self.steady_sum = np.zeros((n, 3))
        self.steady_count = 0
        self.steady_max = np.zeros(n)
        self.rpf_error_t2_axis = np.full((n, 3), np.nan)
        self.sign0: Array | None = None
        self.overshoot = np.zeros(n)
        self.max_torque = np.zeros(n)
        self.saturated_count = np.zeros(n, dtype=np.int64)
        self.outside_count = np.zeros(n, dtype=np.int64)
        self.outside_s = np.zeros(n)  # only on a non-uniform grid (hold_s)
        self.last_outside = np.full(n, -1)
        self.left_after_fault = np.zeros(n, dtype=bool)
        self.finite = np.ones(n, dtype=bool)
        self.samples = 0

    #: Per-run state (leading axis N), concatenated by :meth:`concatenate`.
    _PER_RUN = ("last_unsettled", "steady_sum", "steady_max", "rpf_error_t2_axis", "sign0", "overshoot", "max_torque",
                "saturated_count", "outside_count", "outside_s", "last_outside", "left_after_fault", "finite")

    @classmethod
    def concatenate(cls, parts: Sequence[MetricsAccumulator]) -> MetricsAccumulator:
        """One accumulator of the runs of ``parts`` in order (the same grid and settings, every part
        fed the same samples: sub-batches of a campaign).  Per-run results are unchanged."""
        first = parts[0]
        if any(p.samples != first.samples or p.steady_count != first.steady_count for p in parts):
            raise ValueError("accumulators fed different samples cannot be concatenated")
        merged = copy.copy(first)
        for name in cls._PER_RUN:
            values = [getattr(p, name) for p in parts]
            setattr(merged, name, None if any(v is None for v in values) else np.concatenate(values))
        return merged

    def add_history(self, h: History) -> None:
        """Observe every sample of a stored history at once (offline runs, campaign sub-batches, bags)."""
        x = np.concatenate((h.q_BN, h.omega_BN_B), axis=-1)
        self.update(0, h.t, x, h.torque_B, h.q_BR, h.rho, h.saturated, h.band_lower, h.band_upper)

    def update(self, k0: int, t: Array, x: Array, torque_B: Array, q_BR: Array, rho: Array, saturated: NDArray[np.bool_],
               band_lower: Array, band_upper: Array) -> None:
        """Observe the block of samples ``k0 .. k0 + B - 1``: ``t`` (B,), the others (B, N, ...).

        A block gives the same result as its samples one by one.
        """
        B = t.size
        if B == 0:
            return

        def over_block(a: NDArray[Any], reduce: np.ufunc) -> NDArray[Any]:
            """``reduce`` over the block's samples (a view for a one-sample block: the hot path)."""
            reduced: NDArray[Any] = a[0] if B == 1 else reduce.reduce(a, axis=0)
            return reduced

        def last_true(mask: NDArray[np.bool_], previous: NDArray[np.int64]) -> NDArray[np.int64]:
            """Per run, the last sample of the block where ``mask`` holds, else ``previous``."""
            return np.where(over_block(mask, np.logical_or), k0 + B - 1 - np.argmax(mask[::-1], axis=0), previous)

        q_ev = q_BR[..., :3]
        ok = np.isfinite(x).all(axis=-1) & np.isfinite(torque_B).all(axis=-1)
        live = (ok if B == 1 else np.logical_and.accumulate(ok, axis=0)) & self.finite  # a failed run stops at its last finite sample
        self.finite = live[-1].copy()
        abs_q = np.abs(q_ev)
        max_abs_q = abs_q.max(axis=-1)
        if self.sign0 is None:
            self.sign0 = np.where(q_ev[0] >= 0.0, 1.0, -1.0)
        self.last_unsettled = last_true(live & (max_abs_q >= self.settle_threshold), self.last_unsettled)
        steady = t >= self.steady_from_s - _TIME_TOL_S
        if steady.any():
            use = live & steady[:, None]
            # a sequential running sum (add.accumulate), so that a block sums exactly as its samples one by one would
            rows = np.where(use[..., None], abs_q, 0.0)
            rows[0] += self.steady_sum
            self.steady_sum = np.add.accumulate(rows, axis=0, out=rows)[-1].copy()
            self.steady_count += int(steady.sum())
            self.steady_max = np.maximum(self.steady_max, over_block(np.where(use, max_abs_q, 0.0), np.maximum))
        if k0 <= self.k_t2 < k0 + B:
            j = self.k_t2 - k0
            self.rpf_error_t2_axis = np.where(live[j][:, None], np.abs(q_ev[j] - rho[j]), np.nan)
        self.overshoot = np.maximum(self.overshoot, over_block(np.where(live, (-self.sign0 * q_ev).max(axis=-1), -np.inf), np.maximum))
        self.max_torque = np.maximum(self.max_torque, over_block(np.where(live, np.abs(torque_B).max(axis=-1), 0.0), np.maximum))
        self.saturated_count += over_block(live & saturated.any(axis=-1), np.add)
        outside = live & ((q_ev < band_lower) | (q_ev > band_upper)).any(axis=-1)
        self.outside_count += over_block(outside, np.add)
        if self.hold_s is not None:
            # a sequential running sum (cumsum), so that a block adds exactly as its samples one by one
            held = np.where(outside, self.hold_s[k0 : k0 + B, None], 0.0)
            self.outside_s = np.cumsum(np.concatenate((self.outside_s[None], held)), axis=0)[-1]
        self.last_outside = last_true(outside, self.last_outside)
        if self.fault_start_s is not None:
            self.left_after_fault |= over_block(outside & (t >= self.fault_start_s - _TIME_TOL_S)[:, None], np.logical_or)
        self.samples += B

    def settling_times(self) -> Array:
        """``settling_time_s`` of every run, NaN for a run that never settles."""
        lu = self.last_unsettled
        after = np.minimum(lu + 1, self.t.size - 1)
        return np.where(lu < 0, 0.0, np.where(lu >= self.samples - 1, np.nan, self.t[after]))

    def run_metrics(self, run: int = 0) -> dict[str, Any]:
        """The metrics of run ``run`` (see the module docstring), JSON-ready."""
        t, last = self.t, self.samples - 1
        settling_s = float(self.settling_times()[run])
        settling = None if np.isnan(settling_s) else settling_s
        steady = self.steady_count > 0
        lo = int(self.last_outside[run])
        m: dict[str, Any] = {
            "settling_time_s": settling,
            "steady_max_abs_qev": float(self.steady_max[run]) if steady else None,
            "steady_mean_abs_qev": float((self.steady_sum[run] / self.steady_count).max()) if steady else None,
            "rpf_error_at_t2": None if np.isnan(self.rpf_error_t2_axis[run, 0]) else float(self.rpf_error_t2_axis[run].max()),
            "overshoot": float(max(0.0, self.overshoot[run])),
            "max_abs_torque_Nm": float(self.max_torque[run]),
            "saturation_fraction": float(self.saturated_count[run] / max(self.samples, 1)),
            "time_outside_constraint_s": float(self.outside_count[run] * self.dt if self.hold_s is None else self.outside_s[run]),
            "returned_to_constraint": None,
            "left_constraint_after_fault": None,
            "returned_at_s": None,
            "finite": bool(self.finite[run]),
        }
        if self.fault_start_s is not None:
            left = bool(self.left_after_fault[run])
            returned = lo < last
            m["left_constraint_after_fault"] = left
            m["returned_to_constraint"] = returned
            if left and returned:
                m["returned_at_s"] = float(t[lo + 1])
        return m

    def criteria_arrays(self) -> dict[str, Array]:
        """Per-run arrays for campaign tables: the two Monte Carlo criteria per component and more."""
        steady_mean = self.steady_sum / max(self.steady_count, 1)
        return {
            "steady_mean_abs_qev_per_axis": steady_mean,
            "steady_mean_abs_qev": steady_mean.max(axis=1),
            "rpf_error_at_t2_per_axis": self.rpf_error_t2_axis,
            "rpf_error_at_t2": self.rpf_error_t2_axis.max(axis=1),
            "steady_max_abs_qev": self.steady_max,
            "max_abs_torque_Nm": self.max_torque,
            "settling_time_s": self.settling_times(),
            "finite": self.finite,
        }

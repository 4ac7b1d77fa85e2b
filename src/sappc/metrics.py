"""Run metrics, accumulated sample by sample for a batch of runs.

One implementation serves every path: `sappc simulate` (one run), Monte Carlo campaigns
(thousands of runs, no stored histories) and, later, recorded bags.  Feed every control
sample to :class:`MetricsAccumulator` (it is a closed-loop observer) and read
:meth:`MetricsAccumulator.run_metrics`.  Definitions, per run:

``settling_time_s``
    The first sample time after which ``max_i |q_ev,i|`` stays below
    ``settle_threshold`` until the end; ``0`` if it always was, ``None`` if it
    never settles.
``steady_max_abs_qev``, ``steady_mean_abs_qev``
    Over ``t >= steady_from_s``: the largest ``|q_ev,i|``, and the largest over
    ``i`` of the time-mean of ``|q_ev,i|`` (the paper's Monte Carlo criterion).
``rpf_error_at_t2``
    ``max_i |q_ev,i - rho_i|`` at the sample nearest ``t2_s``, with ``rho`` the
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
    Number of samples with any component outside its constraint band, times ``dt``.
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

from typing import Any

import numpy as np
from numpy.typing import NDArray

from sappc_controller.core.base import ControlOutput

__all__ = ["MetricsAccumulator", "METRIC_KEYS"]

Array = NDArray[np.float64]

#: Time comparisons on the sampling grid allow this much rounding in k * dt [s].
_TIME_TOL_S = 1e-9

#: Keys of :meth:`MetricsAccumulator.run_metrics`, in order.
METRIC_KEYS = (
    "settling_time_s",
    "steady_max_abs_qev",
    "steady_mean_abs_qev",
    "rpf_error_at_t2",
    "overshoot",
    "max_abs_torque_Nm",
    "saturation_fraction",
    "time_outside_constraint_s",
    "returned_to_constraint",
    "left_constraint_after_fault",
    "returned_at_s",
    "finite",
)


class MetricsAccumulator:
    """Closed-loop observer that accumulates the metrics of N runs without storing histories.

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
        self.settle_threshold = settle_threshold
        self.steady_from_s = steady_from_s
        self.k_t2 = int(np.argmin(np.abs(self.t - t2_s)))
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
        self.last_outside = np.full(n, -1)
        self.left_after_fault = np.zeros(n, dtype=bool)
        self.finite = np.ones(n, dtype=bool)
        self.samples = 0

    def __call__(self, k: int, t: float, x: Array, out: ControlOutput, d: Array) -> None:
        q_ev = out.q_BR[:, :3]
        ok = np.isfinite(x).all(axis=1) & np.isfinite(out.torque_B).all(axis=1)
        self.finite &= ok
        live = self.finite  # a failed run's metrics stop at its last finite sample
        abs_q = np.abs(q_ev)
        if self.sign0 is None:
            self.sign0 = np.where(q_ev >= 0.0, 1.0, -1.0)
        unsettled = live & (abs_q.max(axis=1) >= self.settle_threshold)
        self.last_unsettled[unsettled] = k
        if t >= self.steady_from_s - _TIME_TOL_S:
            self.steady_sum += np.where(live[:, None], abs_q, 0.0)
            self.steady_count += 1
            self.steady_max = np.where(live, np.maximum(self.steady_max, abs_q.max(axis=1)), self.steady_max)
        if k == self.k_t2:
            self.rpf_error_t2_axis = np.where(live[:, None], np.abs(q_ev - out.rho), np.nan)
        self.overshoot = np.where(live, np.maximum(self.overshoot, (-self.sign0 * q_ev).max(axis=1)), self.overshoot)
        self.max_torque = np.where(live, np.maximum(self.max_torque, np.abs(out.torque_B).max(axis=1)), self.max_torque)
        self.saturated_count += live & out.saturated.any(axis=1)
        outside = live & ((q_ev < out.band_lower) | (q_ev > out.band_upper)).any(axis=1)
        self.outside_count += outside
        self.last_outside[outside] = k
        if self.fault_start_s is not None and t >= self.fault_start_s - _TIME_TOL_S:
            self.left_after_fault |= outside
        self.samples += 1

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
            "time_outside_constraint_s": float(self.outside_count[run] * self.dt),
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

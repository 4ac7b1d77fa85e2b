"""Run metrics, accumulated sample by sample for a batch of runs.

One implementation serves every path: `sappc simulate` (one run), Monte Carlo campaigns
(thousands of runs, each sub-batch's history fed as one block, then dropped) and recorded
bags.  Feed blocks of control samples to :class:`MetricsAccumulator` (:meth:`~MetricsAccumulator.update`,
:meth:`~MetricsAccumulator.add_history`), combine accumulators of disjoint sets of runs with
:meth:`~MetricsAccumulator.concatenate`, and read :meth:`MetricsAccumulator.run_metrics`.

Its memory does not grow with a run's duration (issue 47) when it is given the sample grid as a
:class:`SampleGrid` (``k dt``, described, not stored) and fed the run a block at a time: it keeps
per-run state, the per-orbit table (a row per orbit), the open orbit's rods' duty samples (one
orbit at most) and the campaign's per-sample NEES (at most :data:`NEES_EXACT_MAX_SAMPLES`
samples).  Every metric is the same bits for any split of the run into blocks.
Each run is measured from its **origin**: its first sample, or with flight modes its first sample
in TRACK (docs/design/modes.md: the scenario's controller starts there); the samples before the
origin enter none of the tracking metrics below but the loss-of-control rule's (they are before the
steady window) and ``finite``, and a run that never reaches TRACK has no origin (its settling time,
steady and RPF metrics unknown).  Times ``t`` below count from the origin (``steady_from_s`` and
``t2_s`` after it), except ``control_lost_at_s`` and ``returned_at_s``, which are the run's own
times; the wheels' metrics cover the whole run.

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
    before ``t2_s``, or the controller had no performance function yet), with ``rho`` the
    controller's own performance function (the RPF for SAPPC): the paper's
    other Monte Carlo criterion.
``overshoot``
    The largest excursion of any component to the sign opposite its initial
    error, ``max_{i,t} max(0, -sign(q_ev,i(0)) q_ev,i(t))`` (``sign(0) = +1``).
``max_abs_torque_Nm``
    Largest produced per-axis torque magnitude.
``torque_sign_changes_per_s``
    Actuator switching (chattering) over the steady window: per axis, the number of
    changes of ``sign(u_i)`` in ``{-1, 0, +1}`` (``u`` the produced torque, after the
    saturation and the minimum-output deadband; ``sign(0) = 0``) between consecutive samples
    both at ``t >= steady_from_s``, divided by the window's span ``t_last - t_first`` (its
    first and last sample); the largest over axes [1/s].  Switching on or off counts (``+``
    to ``0``, ``0`` to ``-``: one change each), so ``+, 0, +, 0`` is three changes, and a
    direct reversal ``+`` to ``-`` is one.  A deadband limit cycle of pulses of one sign is
    chattering, which a count of reversals alone would miss; hence this definition.  A torque
    constant over the window (zero included) gives ``0``; one that changes at every sample
    gives ``1 / dt``.  ``None`` when the window holds fewer than two samples.  A failed run
    counts its changes before its first non-finite sample (over the whole window's span).
``torque_reversals_per_s``
    As ``torque_sign_changes_per_s``, counting only strict reversals: a non-zero ``sign(u_i)``
    opposite to the axis's last non-zero sign in the window, zeros skipped (``+, 0, -`` is one
    reversal, ``+, 0, +`` none).  It tells sign chattering apart from on/off pulsing.
``saturation_fraction``
    Fraction of control samples at which at least one axis was saturated.
``time_outside_constraint_s``
    Time with any component outside its constraint band, each sample held until the next
    (zero-order hold): the number of such samples times ``dt`` on a uniform grid (every
    interval within 1e-9 s of the first), else the sum of their intervals ``t[k+1] - t[k]``
    (a real-time bag's jittered stamps), the last sample holding for the median interval.
    A component is inside when ``band_lower <= q_ev,i <= band_upper``; a sample without a band
    (NaN: the controller had not started, it computes its performance function from its first
    valid sample on) is outside: no constraint holds there.  So a run whose controller never
    commanded is outside for its whole length and never returns.
``returned_to_constraint``
    Only with faults: ``True`` when every component is inside its band at the
    end of the run, i.e. from the sample after the last one outside the band
    to the end.  ``left_constraint_after_fault`` says whether the error left
    the band at or after the first fault's start, ``returned_at_s`` when it
    re-entered for good (``None`` if it never left or never returned).
``finite``
    ``False`` if the run's state or torque ever became non-finite (the run
    failed); the other metrics then describe the samples before that.
``control_lost_at_s``
    The loss-of-control rule (:mod:`sappc.evaluation.requirements`): the time from which
    ``max_i |q_ev,i|`` stayed above :data:`LOSS_OF_CONTROL_FACTOR` times ``settle_threshold`` (ten
    times the scenario's settling band: 1e-2, about 1.1 deg about an axis, for the bundled
    scenarios) to the last sample, counting only samples at ``t >= steady_from_s`` (the transient
    is not judged); ``None`` when the last sample is within that bound, the run ends before the
    steady window, or the run is not finite (its failure is ``finite``).  A run that ends with its error that far out has lost its attitude, whatever its
    requirements; one that leaves the bound and comes back (a fault's transient) has not.
``steady_max_abs_attitude_estimation_error_rad``, ``steady_rms_attitude_estimation_error_rad``
    Only with an estimator (a history with its record): over ``t >= steady_from_s``, the largest
    ``|a_i|`` and the largest over axes of the root mean square of ``a_i``, with ``a`` the true
    attitude relative to the estimate (:func:`sappc.evaluation.estimation.attitude_errors`, the
    filter's error convention) [rad].  Samples without an estimate are left out.
``final_abs_bias_estimation_error_rad_s``
    The largest ``|b_true,i - b_hat,i|`` at the last sample with an estimate [rad/s].
``mean_nees``
    The time-mean over ``t >= NEES_FROM_S`` of the normalised estimation error squared
    (:func:`sappc.evaluation.estimation.nees`'s definition, 6 degrees of freedom): 6 for a
    consistent filter.  Computed by :func:`_estimate_kernel` sample by sample (``P = L D L^T`` from
    the covariance's upper triangle: within ``10 n cond(P) eps`` of numpy's LAPACK solve, tested); a
    sample whose covariance is not finite or is singular has none.
``estimator_updates``, ``estimator_gate_rejections``, ``estimator_reinitialisations``
    The filter's steps of each status (:data:`sappc_estimator.core.mekf.STATUS_NAMES`).
``filter_inconsistent_fraction``
    The share of the samples with the filter's figures at which its health monitor's level is
    ERROR (its window's NIS outside the error band: docs/estimator.md, "Health monitor");
    ``None`` when the record has no monitor.  A scenario bounds it with
    ``metrics.requirements.filter_inconsistent_fraction_max``.
``estimator_recoveries``, ``estimate_withheld_samples``
    The bias recoveries after a failed monitor, and the samples whose estimate the filter withheld
    from the controller (a prior, or a re-initialisation, not yet confirmed by a tracker sample): the controller
    answered them as a dropped input (``controller_summary``'s held and zero answers).
``max_abs_wheel_speed_rad_s``, ``max_abs_wheel_torque_Nm``
    Only with reaction wheels (a history with wheel records): the largest speed of any wheel
    relative to the body, and the largest motor torque, over the finite samples.
``wheel_energy_J``
    Only with reaction wheels: the mechanical work of the wheels' motors in magnitude,
    ``sum_k sum_i |u_i[k] Omega_i[k]| dt`` over the run's finite samples (``u_i`` a motor's torque,
    held over the sample's period ``dt``, ``Omega_i`` its speed relative to the body at the sample;
    braking is counted as spent, as a motor without regeneration spends it) [J].  The effort of
    a controller's steady jitter and of its transient, in one number.

``mode_sequence``, ``time_to_track_s``, ``time_in_mode_s``, ``mode_transitions``
    Only with flight modes (a history with its mode record: docs/design/modes.md): the modes in the
    order flown (their names; the first :data:`MAX_MODE_SEQUENCE`), the first entry into TRACK
    [s] (``None``: never), each mode's samples times ``dt`` [s] (on a non-uniform grid, the samples'
    hold intervals), and the transitions taken.

Per orbit (a scenario in orbit: :meth:`MetricsAccumulator.orbit_metrics`, one entry per orbit ``j``,
the samples with ``j T <= t < (j + 1) T``, ``T`` the orbit's period):

``steady_max_abs_qev``, ``steady_mean_abs_qev``
    As above over the orbit's samples in the steady window (``None``: none there).
``max_wheel_momentum_B_Nms``, ``end_wheel_momentum_B_Nms``
    With reaction wheels: the largest and the orbit's last ``|G_s J_s Omega|``, the wheels' momentum
    in the body frame [N m s].
``max_abs_wheel_speed_rad_s``
    With reaction wheels: the largest speed of any wheel relative to the body.
``rods_mean_dipole_fraction``
    With magnetorquers: the rods' duty, the mean over the orbit's samples and the rods of
    ``|m_i| / m_max,i`` (``None`` when the record has no rods' commands: a bag without a
    management node).
"""

from __future__ import annotations

import copy
import dataclasses
import sys
import types
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from gnc_common.compiled import jit
from sappc.evaluation.estimation import N_ERROR_STATES, EstimateHistory
from sappc.evaluation.history import History
from sappc_estimator.core.mekf import MON_ERROR, STATUS_NAMES, rotation_vector
from sappc_modes.core.modes import MODE_NAMES, TRACK

__all__ = ["LOSS_OF_CONTROL_FACTOR", "NEES_EXACT_MAX_SAMPLES", "MetricsAccumulator", "SampleGrid", "nees_sample_stride"]

Array = NDArray[np.float64]

#: The modes of ``mode_sequence`` kept per run: a flight's sequence is a handful (DETUMBLE, HOLD,
#: TRACK, and a SAFE and HOLD per health failure); a run cycling more than this is reported by its
#: ``mode_transitions``, its sequence cut.
MAX_MODE_SEQUENCE = 32
#: Time comparisons on the sampling grid allow this much rounding in k * dt [s].
_TIME_TOL_S = 1e-9
#: Start of the NEES statistics [s]: the filter's transient from its initial covariance is over
#: (the bias's 1e-5 rad/s prior is resolved within about 2 s at 10 Hz tracker updates; 5 s is the
#: issue's consistency window).
NEES_FROM_S = 5.0
#: The loss-of-control bound as a multiple of the scenario's ``settle_threshold`` (its settling
#: band): an error ten times the band the run had to settle into is not an inaccurate pointing but
#: a lost one (the bundled 1e-3 band gives 1e-2, about 1.1 deg about an axis).  Measured on every
#: bundled scenario of at most 80 s with each controller it has: every run ends below 4e-3 but one,
#: TraPPC after the sudden fault, which ends 3.3e-2 off and never recovers (lost at 50.45 s); the
#: fault's transient peaks (1.8e-2 to 3.1e-2) come back and are not losses.  ``control_lost_at_s``.
LOSS_OF_CONTROL_FACTOR = 10.0
#: ``hold_s`` of a uniform grid, for the compiled update (no per-sample hold intervals).
_NO_HOLD = np.zeros(0)
#: The campaign's per-sample NEES (:meth:`MetricsAccumulator.mean_nees_over_runs`, the consistency
#: test and its figure) is kept at every sample of a run of up to this many samples, else at every
#: :func:`nees_sample_stride`-th sample: 2**22 (11.6 h at 100 Hz) keeps every bundled scenario's
#: at every sample, the 6 h orbit campaign's included (2,160,001 samples), and bounds the two
#: arrays to 64 MiB (float64 and int64) whatever the run's length (a week at 100 Hz: every 15th).
NEES_EXACT_MAX_SAMPLES = 1 << 22


def nees_sample_stride(n_samples: int) -> int:
    """The samples between two of those whose NEES :class:`MetricsAccumulator` keeps per sample
    (samples ``0, s, 2 s, ...``; ``s = 1``: every sample), for a run of ``n_samples``: the least
    ``s`` that keeps at most :data:`NEES_EXACT_MAX_SAMPLES` of them."""
    return max(1, -(-int(n_samples) // NEES_EXACT_MAX_SAMPLES))


@dataclass(frozen=True)
class SampleGrid:
    """A uniform sample grid described, not stored: ``t_k = k dt_s`` [s] for ``k = 0 .. n_samples - 1``.

    Each time is the one float64 product ``float(k) * dt_s``: the bits of
    ``np.arange(n_samples, dtype=np.float64) * dt_s``, the offline grid
    (:func:`spacecraft_sim.core.reference.sample_times`; IEEE multiplication is correctly rounded
    whether scalar or vectorised, checked at every 65536-sample block and 2 million random
    indices of 7 days at 100 Hz).  A :class:`MetricsAccumulator` on it holds nothing of the run's
    length.  It is uniform by definition: ``hold_s`` is ``None``, as the explicit array's check
    finds for any run shorter than 2**23 s (97 days), where ``k dt`` rounds within 1e-9 s.
    """

    n_samples: int
    dt_s: float

    @classmethod
    def of_run(cls, duration_s: float, control_period_s: float) -> SampleGrid:
        """The grid of :func:`~spacecraft_sim.core.reference.sample_times` ``(duration_s, control_period_s)``:
        ``round(duration_s / control_period_s) + 1`` samples ``control_period_s`` apart."""
        return cls(int(round(duration_s / control_period_s)) + 1, float(control_period_s))

    def times_s(self, k: Any) -> Any:
        """The times of samples ``k`` (an index or an array of them) [s]."""
        return np.asarray(k, dtype=np.float64) * self.dt_s


def _finite_or_none(x: Any) -> float | None:
    """``x`` as a float, ``None`` when it is not finite (nothing measured, or a failed run)."""
    v = float(x)
    return v if np.isfinite(v) else None


class MetricsAccumulator:
    """Accumulates the metrics of N runs from blocks of samples (the history need not be kept).

    Parameters
    ----------
    t : SampleGrid or ndarray, shape (T,)
        The sample times the run will visit: a :class:`SampleGrid` (``k dt``, computed per index:
        nothing of size T is kept, for a long run fed a block at a time), or the times themselves
        (a bag's stamps, possibly jittered; kept, with their hold intervals on a non-uniform grid).
        The offline grid gives every metric the same bits either way.
    n_runs : int
    steady_from_s, settle_threshold, t2_s : float
        See :class:`sappc.scenario.MetricSettings`.
    fault_windows : list of (start_s, end_s)
        Injected fault windows; empty when there are none.
    orbit_bins : sappc.scenario.OrbitBins or None
        A scenario in orbit: the per-orbit metrics (:meth:`orbit_metrics`); ``None``: none.
    """

    def __init__(
        self,
        t: Array | SampleGrid,
        n_runs: int,
        *,
        steady_from_s: float,
        settle_threshold: float,
        t2_s: float,
        fault_windows: list[tuple[float, float]],
        orbit_bins: Any = None,
        origin: str = "first_track",
    ) -> None:
        # the grid: described (grid) or its times (t); n_grid its samples
        self.grid: SampleGrid | None = t if isinstance(t, SampleGrid) else None
        self.t: Array | None = None if self.grid is not None else np.asarray(t, dtype=np.float64)
        self.n_grid = self.grid.n_samples if self.grid is not None else int(self.t.size)  # type: ignore[union-attr]
        # t[1] - t[0] (1 * dt - 0 * dt: dt's bits on a grid); 0 with a single sample, as from the times
        self.dt = 0.0
        if self.n_grid > 1:
            self.dt = self.grid.dt_s if self.grid is not None else float(self.t[1] - self.t[0])  # type: ignore[index]
        # hold interval of each sample on a non-uniform grid (None: uniform, count * dt is exact)
        self.hold_s: Array | None = None
        if self.t is not None:
            intervals = np.diff(self.t)
            if intervals.size and np.any(np.abs(intervals - self.dt) > _TIME_TOL_S):
                self.hold_s = np.append(intervals, np.median(intervals))
        self.settle_threshold = settle_threshold
        self.steady_from_s = steady_from_s
        # the sample nearest t2, or none (-1) when the run ends before t2 (a run cut short)
        k_t2 = self._nearest_sample(t2_s)
        self.k_t2 = k_t2 if k_t2 >= 0 and abs(self.time_s(k_t2) - t2_s) <= 0.5 * self.dt + _TIME_TOL_S else -1
        self.fault_start_s = min((s for s, _ in fault_windows), default=None)
        n = n_runs
        # each run's origin: the sample its tracking starts at (0; with flight modes TRACK's first
        # sample, -1 until the run reaches it: set by add_history from the mode record), its steady
        # samples and the first one's index, its sample nearest t2 after the origin (-1: none)
        self.origin_k = np.zeros(n, dtype=np.int64)
        self.steady_n = np.zeros(n, dtype=np.int64)
        self.steady_first = np.full(n, -1, dtype=np.int64)
        self.k_t2_run = np.full(n, self.k_t2, dtype=np.int64)
        self.t2_s = t2_s
        if origin not in ("first_track", "last_track"):
            raise ValueError(f"origin must be first_track or last_track, got {origin!r}")
        self.origin = origin  # with modes: the first entry into TRACK, or each later one starting the run's tracking afresh
        self.last_unsettled = np.full(n, -1)  # last sample with max|q_ev| >= threshold
        self.last_controlled = np.full(n, -1)  # last finite sample before the steady window or within the loss bound
        self.steady_sum = np.zeros((n, 3))
        self.steady_max = np.zeros(n)
        self.rpf_error_t2_axis = np.full((n, 3), np.nan)
        self.sign0 = np.zeros((n, 3))  # the error's signs at the run's origin (the overshoot's)
        self.overshoot = np.zeros(n)
        self.max_torque = np.zeros(n)
        # per axis: sign(u) of the last steady sample (NaN: none yet), the last non-zero one (0: none yet), the counts
        self.torque_sign = np.full((n, 3), np.nan)
        self.torque_sign_nonzero = np.zeros((n, 3))
        self.torque_sign_changes = np.zeros((n, 3), dtype=np.int64)
        self.torque_reversals = np.zeros((n, 3), dtype=np.int64)
        self.saturated_count = np.zeros(n, dtype=np.int64)
        self.outside_count = np.zeros(n, dtype=np.int64)
        self.outside_s = np.zeros(n)  # only on a non-uniform grid (hold_s)
        self.last_outside = np.full(n, -1)
        self.left_after_fault = np.zeros(n, dtype=bool)
        self.finite = np.ones(n, dtype=bool)
        self.samples = 0
        self.wheel_speed_max: Array | None = None  # only with wheels
        self.wheel_torque_max: Array | None = None
        self.wheel_energy: Array | None = None
        # only with an estimator: per run, steady max |a_i| and sum of a_i^2 (and their samples),
        # the last bias error, the NEES sum and count from NEES_FROM_S, the statuses' counts; per
        # sample of the grid, the NEES summed over the runs that have it and their number
        self.est_att_max: Array | None = None
        self.est_att_sq: Array | None = None
        self.est_att_n: Array | None = None
        self.est_bias_last: Array | None = None
        self.est_nees_sum: Array | None = None
        self.est_nees_n: Array | None = None
        self.est_status_counts: Array | None = None
        self.est_mon_error: Array | None = None  # per run: samples with the monitor at ERROR
        self.est_mon_n: Array | None = None  # per run: samples with a monitor level (-1: no monitor recorded)
        self.est_withheld: Array | None = None  # per run: samples whose estimate was withheld
        self.est_recoveries: Array | None = None  # per run: the recoveries at the last sample with figures
        # with an estimator (allocated with its first block): at every nees_stride-th sample of the grid
        # (every sample of a run of up to NEES_EXACT_MAX_SAMPLES), the NEES summed over the runs that
        # have it there, and their number
        self.nees_stride = nees_sample_stride(self.n_grid)
        self.nees_sum_t: Array | None = None
        self.nees_runs_t: NDArray[np.int64] | None = None
        # a block computed online (online_flight_state): each sample's NEES and whether it was counted (B, N)
        self._online_nees: tuple[Array, NDArray[np.bool_]] = (np.zeros((0, 0)), np.zeros((0, 0), dtype=np.bool_))
        # only in orbit: per run and orbit the steady max of max_i |q_ev,i|, the steady sums of |q_ev,i|, the
        # wheels' largest and last |h_B| and largest speed, the rods' summed |m| / m_max; per orbit the
        # samples seen and those in the steady window.  The orbit of the last sample seen is open: its
        # rods' |m| / m_max (S, n, M) wait in _rods_buffers, one per group of runs (one, or one per part
        # concatenated), until it closes (their sum is numpy's pairwise sum over the whole orbit's samples)
        self.orbit_bins = orbit_bins
        n_orbits = int(self.time_s(self.n_grid - 1) // orbit_bins.period_s) + 1 if orbit_bins is not None and self.n_grid else 0
        self.orb_steady_max = np.full((n, n_orbits), np.nan)
        self.orb_steady_sum = np.zeros((n, n_orbits, 3))
        self.orb_h_max = np.full((n, n_orbits), np.nan)
        self.orb_h_end = np.full((n, n_orbits), np.nan)
        self.orb_speed_max = np.full((n, n_orbits), np.nan)
        self.orb_dipole_sum = np.full((n, n_orbits), np.nan)
        self.orb_samples = np.zeros(n_orbits, dtype=np.int64)
        self.orb_steady_samples = np.zeros((n, n_orbits), dtype=np.int64)  # per run: its steady window is its own
        self._orb_open = -1  # the open orbit (-1: none yet)
        self._rods_runs = [n]  # the runs of each group of the rods' buffers
        self._rods_buffers: list[Array | None] = [None]  # per group (capacity, runs, M), allocated with the first rods' samples
        self._rods_filled = 0  # the open orbit's samples in each buffer
        self._rods_written = True  # orb_dipole_sum holds the open orbit's buffered samples' sum
        # only with flight modes (allocated with the first block's mode record): per run the samples in
        # each mode (on a non-uniform grid, their summed hold intervals [s]), each mode's first entry [s] (NaN: never), the transitions, the last mode
        # seen (-1: none) and the sequence flown (its first MAX_MODE_SEQUENCE modes, -1 after)
        self.mode_time_s: Array | None = None
        self.mode_entry_s: Array | None = None
        self.mode_transitions: NDArray[np.int64] | None = None
        self.mode_last: NDArray[np.int64] | None = None
        self.mode_seq: NDArray[np.int64] | None = None

    def time_s(self, k: Any) -> Any:
        """The time of sample ``k`` of the grid (an index or an array of them) [s]."""
        return self.t[k] if self.t is not None else self.grid.times_s(k)  # type: ignore[union-attr]

    def _nearest_sample(self, t_s: float) -> int:
        """The grid's sample nearest ``t_s``, the first of two as near (``argmin``); -1: no sample.
        On a :class:`SampleGrid`, among the samples around ``t_s / dt`` (``k dt`` increases with
        ``k``: the nearest is where it crosses ``t_s``, within one sample of the rounded quotient)."""
        if self.n_grid == 0:
            return -1
        if self.t is not None:
            return int(np.argmin(np.abs(self.t - t_s)))
        if not np.isfinite(t_s) or self.n_grid == 1:
            return 0  # argmin of a NaN or infinite distance everywhere, or of one sample
        last = self.n_grid - 1
        mid = min(max(round(t_s / self.grid.dt_s), 0), last)  # type: ignore[union-attr]
        candidates = range(max(mid - 2, 0), min(mid + 2, last) + 1)
        return min(candidates, key=lambda k: abs(float(self.time_s(k)) - t_s))  # min keeps the first of equals

    #: Per-run state (leading axis N), concatenated by :meth:`concatenate`.
    _PER_RUN = ("origin_k", "steady_n", "steady_first", "k_t2_run", "last_unsettled", "last_controlled", "steady_sum", "steady_max", "rpf_error_t2_axis", "sign0", "overshoot", "max_torque",
                "torque_sign", "torque_sign_nonzero", "torque_sign_changes", "torque_reversals", "saturated_count", "outside_count",
                "outside_s", "last_outside", "left_after_fault", "finite", "wheel_speed_max", "wheel_torque_max", "wheel_energy", "est_att_max",
                "est_att_sq", "est_att_n", "est_bias_last", "est_nees_sum", "est_nees_n", "est_status_counts", "est_mon_error", "est_mon_n",
                "est_withheld", "est_recoveries", "orb_steady_max", "orb_steady_sum", "orb_h_max", "orb_h_end", "orb_speed_max",
                "orb_dipole_sum", "orb_steady_samples", "mode_time_s", "mode_entry_s", "mode_transitions", "mode_last", "mode_seq")
    #: The per-run state a new origin (``origin="last_track"``, :meth:`_restart_origin`) sets back to
    #: a run not yet started: each tracking metric's, with its fresh value (``__init__``'s).
    _RESTARTED_AT_ORIGIN = (("last_unsettled", -1), ("steady_sum", 0.0), ("steady_max", 0.0), ("rpf_error_t2_axis", np.nan),
                            ("overshoot", 0.0), ("max_torque", 0.0), ("torque_sign", np.nan), ("torque_sign_nonzero", 0.0),
                            ("torque_sign_changes", 0), ("torque_reversals", 0), ("saturated_count", 0), ("outside_count", 0),
                            ("outside_s", 0.0), ("last_outside", -1), ("left_after_fault", False), ("steady_n", 0), ("steady_first", -1),
                            ("est_att_max", 0.0), ("est_att_sq", 0.0), ("est_att_n", 0), ("orb_steady_max", np.nan), ("orb_steady_sum", 0.0),
                            ("orb_steady_samples", 0))
    #: ... and what it keeps: the origin itself and what follows from it (``t2``'s sample, the
    #: overshoot's signs, set at the origin's sample), and the run's own figures (finiteness, the
    #: loss-of-control rule's, the wheels', the estimator's whole-run ones, the per-orbit momentum,
    #: the modes').  Every name of :data:`_PER_RUN` is in exactly one of the two (tested): a new
    #: per-run metric must say which.
    _KEPT_AT_ORIGIN = ("origin_k", "k_t2_run", "sign0", "last_controlled", "finite", "wheel_speed_max", "wheel_torque_max", "wheel_energy",
                       "est_bias_last", "est_nees_sum", "est_nees_n", "est_status_counts", "est_mon_error", "est_mon_n", "est_withheld",
                       "est_recoveries", "orb_h_max", "orb_h_end", "orb_speed_max", "orb_dipole_sum", "mode_time_s", "mode_entry_s",
                       "mode_transitions", "mode_last", "mode_seq")
    #: Per-sample sums over runs, added by :meth:`concatenate`.
    _SUMMED = ("nees_sum_t", "nees_runs_t")

    @classmethod
    def concatenate(cls, parts: Sequence[MetricsAccumulator]) -> MetricsAccumulator:
        """One accumulator of the runs of ``parts`` in order (the same grid and settings, every part
        fed the same samples: sub-batches of a campaign).  Per-run results are unchanged: each part's
        open orbit's rods' samples stay a group of their own (their duty summed as the part's)."""
        first = parts[0]
        if any(p.samples != first.samples for p in parts):
            raise ValueError("accumulators fed different samples cannot be concatenated")
        for p in parts:
            p._write_open_rods()
        merged = copy.copy(first)
        for name in cls._PER_RUN:
            values = [getattr(p, name) for p in parts]
            setattr(merged, name, None if any(v is None for v in values) else np.concatenate(values))
        for name in cls._SUMMED:
            values = [getattr(p, name) for p in parts]
            setattr(merged, name, None if any(v is None for v in values) else sum(values))
        merged._rods_runs = [r for p in parts for r in p._rods_runs]
        merged._rods_buffers = [None if b is None else b.copy() for p in parts for b in p._rods_buffers]
        return merged

    def add_history(self, h: History, *, block_samples: int | None = None) -> None:
        """Observe every sample of a stored history, after the samples seen so far (offline runs,
        campaign sub-batches, bags; a long run a block at a time, each call's ``h.t`` the block's
        own times).  ``block_samples``: every metric takes at most that many samples at a time
        (views: their temporaries bounded by the block, not by the record).  Every metric, the
        per-orbit table included, is the same bits for any split into blocks and calls (sums run
        sample after sample; the rods' duty waits for its orbit's last sample)."""
        T = h.t.size
        cuts: dict[int, list[int]] = {}
        if h.mode is not None:
            self._set_origins(h.mode)
            if self.origin == "last_track":
                cuts = self._later_entries(h.mode)
        step = T if block_samples is None or T == 0 else max(1, int(block_samples))
        edges = sorted({0, T, *cuts})
        pieces = [(lo, min(lo + step, hi)) for a, hi in zip(edges[:-1], edges[1:]) for lo in range(a, hi, max(step, 1))] or [(0, 0)]
        for lo, hi in pieces:
            if lo in cuts:  # a later entry into TRACK: those runs' tracking counts afresh from it
                self._restart_origin(cuts[lo], self.samples)
            b = h if (lo, hi) == (0, T) else h.samples(lo, hi)
            self._update(self.samples, b.t, b.q_BN, b.omega_BN_B, b.torque_B, b.q_BR, b.rho, b.saturated, b.band_lower, b.band_upper)
            if b.wheel_speed_rad_s is not None and b.wheel_torque_Nm is not None:
                self.update_wheels(b.wheel_speed_rad_s, b.wheel_torque_Nm)
            if b.estimate is not None:
                self.update_estimate(self.samples - b.t.size, b.t, b.q_BN, b.estimate)
            if self.orbit_bins is not None:
                self._update_orbits(b)
            if b.mode is not None:
                self._update_modes(b.t, b.mode)

    def _set_origins(self, mode: NDArray[np.int8]) -> None:
        """With flight modes, each run's origin is TRACK's first sample (module docstring): from a
        block's mode record (B, N), the block that follows the samples seen; a run not yet in
        TRACK has none (-1), its metrics waiting for it."""
        m = np.asarray(mode)
        if self.samples == 0:  # a record with modes: every origin (and its t2 sample) waits for TRACK
            self.origin_k[:] = -1
            self.k_t2_run[:] = -1
        waiting = self.origin_k < 0
        if not waiting.any() or m.shape[0] == 0:
            return
        tracking = m[:, waiting] == TRACK
        found = tracking.any(axis=0)
        runs = np.flatnonzero(waiting)[found]
        self.origin_k[runs] = self.samples + np.argmax(tracking[:, found], axis=0)
        origin = self.origin_s()
        for r in runs:  # the RPF's error is read t2 after the origin
            k = self._nearest_sample(float(origin[r]) + self.t2_s)
            ok = k >= 0 and abs(float(self.time_s(k)) - float(origin[r]) - self.t2_s) <= 0.5 * self.dt + _TIME_TOL_S
            self.k_t2_run[r] = k if ok else -1

    def _later_entries(self, mode: NDArray[np.int8]) -> dict[int, list[int]]:
        """``origin="last_track"``: the samples of a block (B, N) at which a run enters TRACK again
        after its origin (block-relative index: the runs entering there)."""
        m = np.asarray(mode, dtype=np.int64)
        last = self.mode_last if self.mode_last is not None else np.full(m.shape[1], -1, dtype=np.int64)
        prev = np.concatenate((last[None, :], m[:-1]), axis=0)
        cuts: dict[int, list[int]] = {}
        for k, r in zip(*np.nonzero((m == TRACK) & (prev != TRACK))):
            if 0 <= self.origin_k[r] < self.samples + int(k):
                cuts.setdefault(int(k), []).append(int(r))
        return cuts

    def _restart_origin(self, runs: list[int], k: int) -> None:
        """Runs ``runs`` start their tracking afresh at sample ``k`` (``origin="last_track"``): their
        origin moves there and every tracking metric's state is that of a run not yet started
        (the wheels', finiteness and the loss-of-control rule's stay the run's own)."""
        r = np.asarray(runs, dtype=np.int64)
        self.origin_k[r] = k
        origin = self.origin_s()
        for i in r:
            kk = self._nearest_sample(float(origin[i]) + self.t2_s)
            ok = kk >= 0 and abs(float(self.time_s(kk)) - float(origin[i]) - self.t2_s) <= 0.5 * self.dt + _TIME_TOL_S
            self.k_t2_run[i] = kk if ok else -1
        for name, value in self._RESTARTED_AT_ORIGIN:
            a = getattr(self, name)
            if a is not None:
                a[r] = value

    def origin_s(self) -> Array:
        """Each run's origin's time [s]: 0 for a run counted from its first sample (the times are
        the run's own: a bag's may start later), else its origin sample's time (TRACK's entry);
        NaN: not reached."""
        o = self.origin_k
        return np.where(o > 0, self.time_s(np.maximum(o, 0)), np.where(o == 0, 0.0, np.nan))

    def steady_from_per_run(self) -> Array:
        """Each run's steady window's start [s]: its origin plus ``steady_from_s`` (infinite while
        the origin is not known: no steady sample)."""
        origin = self.origin_s()
        return np.where(np.isnan(origin), np.inf, np.nan_to_num(origin) + self.steady_from_s)

    def _update_modes(self, t: Array, mode: NDArray[np.int8]) -> None:
        """The mode metrics of a block (``mode`` (B, N) the mode of each sample), after the samples
        seen: the time in each mode (each sample held ``dt``, or its interval on a non-uniform
        grid), and each change of mode (at a block's first sample too, against the last seen)."""
        m = np.asarray(mode, dtype=np.int64)
        B, n = m.shape
        if B == 0:
            return
        if self.mode_time_s is None:
            self.mode_time_s = np.zeros((n, len(MODE_NAMES)))
            self.mode_entry_s = np.full((n, len(MODE_NAMES)), np.nan)
            self.mode_transitions = np.zeros(n, dtype=np.int64)
            self.mode_last = np.full(n, -1, dtype=np.int64)
            self.mode_seq = np.full((n, MAX_MODE_SEQUENCE), -1, dtype=np.int64)
        assert self.mode_entry_s is not None and self.mode_transitions is not None and self.mode_last is not None and self.mode_seq is not None
        k0 = self.samples - B  # the block's first sample's index in the run
        if self.hold_s is None:  # a uniform grid: the samples counted (exact), times dt when read
            for j in range(len(MODE_NAMES)):
                self.mode_time_s[:, j] += np.count_nonzero(m == j, axis=0)
        else:  # each sample's interval, summed in time order (the same bits for any split into blocks)
            held = self.hold_s[k0:k0 + B]
            self.mode_time_s[...] = _summed_onto(self.mode_time_s, held[:, None, None] * (m[..., None] == np.arange(len(MODE_NAMES))))
        prev = np.concatenate((self.mode_last[None, :], m[:-1]), axis=0)  # (B, N) each sample's previous mode (-1: the run's first)
        for k, r in zip(*np.nonzero(m != prev)):
            entered = int(m[k, r])
            if prev[k, r] >= 0:
                self.mode_transitions[r] += 1
            if np.isnan(self.mode_entry_s[r, entered]):
                self.mode_entry_s[r, entered] = float(t[k])
            free = np.flatnonzero(self.mode_seq[r] < 0)
            if free.size:
                self.mode_seq[r, free[0]] = entered
        self.mode_last[:] = m[-1]

    def _update_orbits(self, h: History) -> None:
        """The per-orbit sums and extremes of a block of samples (a history, after the samples seen,
        in time order), the same bits for any split into blocks: the extremes are exact, the steady
        sums run sample after sample (what numpy's sum along the first axis of an orbit's (S, N, 3)
        does: checked on 567,600 samples), the rods' samples wait in their buffer for the orbit's
        end (:meth:`_write_open_rods`)."""
        ob = self.orbit_bins
        t = np.asarray(h.t, dtype=np.float64)
        if t.size == 0:
            return
        orbit = (t // ob.period_s).astype(np.int64)
        bounds = np.flatnonzero(np.diff(orbit)) + 1
        q_BR = np.asarray(h.q_BR, dtype=np.float64)
        speed = None if h.wheel_speed_rad_s is None or ob.wheel_spin_inertia_kg_m2 is None else np.asarray(h.wheel_speed_rad_s, dtype=np.float64)
        dipoles = None
        m = 0 if ob.rod_max_dipole_Am2 is None else ob.rod_max_dipole_Am2.size
        if h.orbit is not None and m and h.orbit.shape[-1] >= 9 + m:  # a bag without a management node has no rods' columns
            dipoles = np.asarray(h.orbit, dtype=np.float64)[..., 9:9 + m]
        # the runs by their steady window's start (its origin plus steady_from_s; a run whose origin is
        # not known yet has none): runs of one start share every mask, from the first sample on
        starts = self.steady_from_per_run()
        groups = [(float(v), np.flatnonzero(starts == v)) for v in np.unique(starts[np.isfinite(starts)])]
        for lo, hi in zip(np.concatenate(([0], bounds)), np.concatenate((bounds, [t.size]))):
            j = int(orbit[lo])
            if j != self._orb_open:  # the open orbit has ended: its rods' duty is final
                self._write_open_rods()
                self._orb_open, self._rods_filled = j, 0
            seen = self.orb_samples[j] > 0  # the orbit's extremes so far (else NaN: none yet)
            self.orb_samples[j] += hi - lo
            for start_s, runs in groups:  # the runs of one steady window together (every run, without modes)
                steady = t[lo:hi] >= start_s
                if steady.any():
                    q = np.abs(q_BR[lo:hi, runs, :3])[steady]  # (S, R, 3)
                    q_max = np.max(q, axis=(0, 2))  # a NaN wins, as over the whole orbit
                    self.orb_steady_max[runs, j] = np.maximum(self.orb_steady_max[runs, j], q_max) if self.orb_steady_samples[runs[0], j] else q_max
                    self.orb_steady_sum[runs, j] = _summed_onto(self.orb_steady_sum[runs, j], q)
                    self.orb_steady_samples[runs, j] += int(steady.sum())
            if speed is not None:
                w = speed[lo:hi]  # (S, N, W)
                hB = np.linalg.norm((w * ob.wheel_spin_inertia_kg_m2) @ np.asarray(ob.wheel_axes_B).T, axis=2)  # (S, N) [N m s]
                h_max, w_max = hB.max(axis=0), np.abs(w).max(axis=(0, 2))
                self.orb_h_max[:, j] = np.maximum(self.orb_h_max[:, j], h_max) if seen else h_max
                self.orb_h_end[:, j] = hB[-1]
                self.orb_speed_max[:, j] = np.maximum(self.orb_speed_max[:, j], w_max) if seen else w_max
            if dipoles is not None:
                self._buffer_rods(np.abs(dipoles[lo:hi]) / ob.rod_max_dipole_Am2)  # (S, N, M)

    def _orbit_samples_max(self) -> int:
        """The most samples an orbit of the grid holds (the rods' buffer's capacity)."""
        period_s = self.orbit_bins.period_s
        if self.t is None:  # k dt in [j T, (j + 1) T): at most T / dt + 1, one more for k dt's rounding
            return int(min(self.n_grid, period_s // self.dt + 2)) if self.dt > 0 else self.n_grid
        return int(np.unique(self.t // period_s, return_counts=True)[1].max()) if self.t.size else 0

    def _buffer_rods(self, rods: Array) -> None:
        """The open orbit's rods' ``|m| / m_max`` of a block (S, N, M) onto each group's buffer."""
        S, filled = rods.shape[0], self._rods_filled
        lo = 0
        for g, runs in enumerate(self._rods_runs):
            buf = self._rods_buffers[g]
            if buf is None or filled + S > buf.shape[0]:  # allocated once (an orbit), grown only past it
                rows = max(self._orbit_samples_max(), filled + S, 2 * (0 if buf is None else buf.shape[0]))
                grown = np.empty((rows, runs, rods.shape[2]))
                if buf is not None:
                    grown[:filled] = buf[:filled]
                self._rods_buffers[g] = buf = grown
            buf[filled:filled + S] = rods[:, lo:lo + runs]
            lo += runs
        self._rods_filled = filled + S
        self._rods_written = False

    def _write_open_rods(self) -> None:
        """The open orbit's rods' duty from its buffered samples into ``orb_dipole_sum``: per group,
        ``np.nansum`` over the (S, runs, M) samples' axes 0 and 2, the whole orbit's at once, as over
        the whole record (numpy's pairwise order, which depends on the orbit's length)."""
        if self._rods_written or self._orb_open < 0:
            return
        lo = 0
        for runs, buf in zip(self._rods_runs, self._rods_buffers):
            assert buf is not None
            self.orb_dipole_sum[lo:lo + runs, self._orb_open] = np.nansum(buf[:self._rods_filled], axis=(0, 2))
            lo += runs
        self._rods_written = True

    def orbit_metrics(self, run: int = 0) -> list[dict[str, Any]]:
        """The per-orbit metrics of run ``run`` (module docstring), one entry per orbit with samples;
        empty without an orbit.  The last orbit's are those of its samples seen so far."""
        if self.orbit_bins is None:
            return []
        self._write_open_rods()
        out = []
        for j in np.flatnonzero(self.orb_samples):
            n_steady = int(self.orb_steady_samples[run, j])
            entry: dict[str, Any] = {
                "orbit": int(j), "from_s": float(j * self.orbit_bins.period_s),
                "steady_max_abs_qev": _finite_or_none(self.orb_steady_max[run, j]) if n_steady else None,
                "steady_mean_abs_qev": _finite_or_none((self.orb_steady_sum[run, j] / n_steady).max()) if n_steady else None,
            }
            if self.orbit_bins.wheel_spin_inertia_kg_m2 is not None:
                entry.update(max_wheel_momentum_B_Nms=_finite_or_none(self.orb_h_max[run, j]),
                             end_wheel_momentum_B_Nms=_finite_or_none(self.orb_h_end[run, j]),
                             max_abs_wheel_speed_rad_s=_finite_or_none(self.orb_speed_max[run, j]))
            if self.orbit_bins.rod_max_dipole_Am2 is not None and self.orbit_bins.rod_max_dipole_Am2.size:
                m = self.orbit_bins.rod_max_dipole_Am2.size
                entry["rods_mean_dipole_fraction"] = _finite_or_none(self.orb_dipole_sum[run, j] / (self.orb_samples[j] * m))
            out.append(entry)
        return out

    def _estimate_arrays(self) -> None:
        """The estimation metrics' arrays, allocated with their first samples (recorded or online)."""
        n = self.finite.shape[0]
        if self.est_att_max is None:
            self.est_att_max, self.est_att_sq = np.zeros((n, 3)), np.zeros((n, 3))
            self.est_att_n, self.est_nees_n = np.zeros(n, dtype=np.int64), np.zeros(n, dtype=np.int64)
            self.est_bias_last, self.est_nees_sum = np.full((n, 3), np.nan), np.zeros(n)
            self.est_status_counts = np.zeros((n, len(STATUS_NAMES)), dtype=np.int64)
            self.est_mon_error, self.est_mon_n = np.zeros(n, dtype=np.int64), np.zeros(n, dtype=np.int64)
            self.est_withheld, self.est_recoveries = np.zeros(n, dtype=np.int64), np.zeros(n, dtype=np.int64)
            n_kept = -(-self.n_grid // self.nees_stride)  # the grid's samples 0, s, 2 s, ...
            self.nees_sum_t, self.nees_runs_t = np.zeros(n_kept), np.zeros(n_kept, dtype=np.int64)

    def update_estimate(self, k0: int, t: Array, q_BN: Array, est: EstimateHistory, runs: slice = slice(None),
                        nees: tuple[Array, NDArray[np.bool_]] | None = None) -> None:
        """Observe a block of samples ``k0 ..`` (``t`` (B,), arrays (B, N, ...)) of the estimator's
        record against the true attitude ``q_BN``: the estimation metrics (module docstring).
        ``runs``: the arrays hold only those runs (:meth:`add_online_block`), whose samples' NEES
        go into ``nees`` (the block's (B, N) NEES and counted flags, which the caller sums over
        the runs) instead of the sums over runs."""
        self._estimate_arrays()
        assert self.est_att_max is not None and self.est_att_sq is not None and self.est_att_n is not None and self.est_bias_last is not None
        assert self.est_nees_sum is not None and self.est_nees_n is not None and self.est_status_counts is not None
        att_max, att_sq, att_n, bias_last = self.est_att_max[runs], self.est_att_sq[runs], self.est_att_n[runs], self.est_bias_last[runs]
        nees_sum, nees_n, status_counts = self.est_nees_sum[runs], self.est_nees_n[runs], self.est_status_counts[runs]
        n = att_n.shape[0]
        t = np.asarray(t, dtype=np.float64).reshape(-1)
        B = t.size
        truth = est.gyro_bias_true is not None
        def f64(a: Any) -> Array:
            return np.asarray(a, dtype=np.float64)

        b_true, b_hat = (f64(est.gyro_bias_true), f64(est.gyro_bias)) if truth else (np.zeros((0, n, 3)), np.zeros((0, n, 3)))
        e = np.zeros((B if truth else 0, n))  # each sample's NEES where counted, else 0
        counted = np.zeros((B if truth else 0, n), dtype=np.bool_)
        with np.errstate(divide="ignore", invalid="ignore"):  # (interpreted: a singular covariance's NEES is NaN, not counted)
            _estimate_function(B * n)(t, self.steady_from_per_run()[runs], f64(est.q_BN), f64(q_BN), b_hat, b_true, f64(est.covariance), att_max,
                                      att_sq, att_n, bias_last, nees_sum, nees_n, e, counted)
        if truth and nees is not None:
            nees[0][:, runs] = e
            nees[1][:, runs] = counted
        elif truth:
            self._add_nees(k0, e, counted)
        status = np.asarray(est.status)
        for code in range(len(STATUS_NAMES)):
            status_counts[:, code] += np.count_nonzero(status == code, axis=0)
        assert self.est_mon_error is not None and self.est_mon_n is not None and self.est_withheld is not None
        assert self.est_recoveries is not None
        if est.monitor_level is None:
            self.est_mon_n[runs] = -1
        else:
            level = np.asarray(est.monitor_level, dtype=np.float64)
            self.est_mon_n[runs] += np.isfinite(level).sum(axis=0)
            self.est_mon_error[runs] += (level == MON_ERROR).sum(axis=0)
        if est.usable is not None:
            self.est_withheld[runs] += (np.asarray(est.usable, dtype=np.float64) == 0.0).sum(axis=0)
        if est.recoveries is not None:
            rec = np.asarray(est.recoveries, dtype=np.float64)
            self.est_recoveries[runs] = np.maximum(self.est_recoveries[runs], np.where(np.isfinite(rec), rec, 0.0).max(axis=0)).astype(np.int64)

    def _add_nees(self, k0: int, e: Array, counted: NDArray[np.bool_]) -> None:
        """A block's NEES (B, N) (0 where not counted) and counted flags, samples ``k0 ..``, summed over
        the runs at the grid's kept samples (k a multiple of nees_stride) into their places k / nees_stride
        (the sum over runs, then over chunks: its last bits depend on how a campaign is chunked)."""
        assert self.nees_sum_t is not None and self.nees_runs_t is not None
        B = e.shape[0]
        s = self.nees_stride
        first = -(-k0 // s) * s
        rows, kept = slice(first - k0, B, s), slice(first // s, first // s + len(range(first - k0, B, s)))
        self.nees_sum_t[kept] += e[rows].sum(axis=1)
        self.nees_runs_t[kept] += counted[rows].sum(axis=1)

    def mean_nees_over_runs(self) -> tuple[Array, Array]:
        """The NEES averaged over the runs at every sample from :data:`NEES_FROM_S` (NaN where no
        run has one) and the number of runs averaged: the consistency test of a campaign
        (:func:`sappc.evaluation.estimation.nees_band`).  At the grid's samples ``0, s, 2 s, ...``,
        ``s`` = ``nees_stride`` (:func:`nees_sample_stride`: every sample of a run of up to
        :data:`NEES_EXACT_MAX_SAMPLES`, the same figures at each sample kept for a longer one);
        their times :meth:`nees_times_s`.  Without an estimator, NaN and 0 there."""
        n_kept = -(-self.n_grid // self.nees_stride)
        runs = self.nees_runs_t if self.nees_runs_t is not None else np.zeros(n_kept, dtype=np.int64)
        total = self.nees_sum_t if self.nees_sum_t is not None else np.zeros(runs.size)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = np.where(runs > 0, total / np.maximum(runs, 1), np.nan)
        return mean, runs.copy()

    def nees_times_s(self) -> Array:
        """The times of the samples of :meth:`mean_nees_over_runs` [s]."""
        return np.asarray(self.time_s(np.arange(0, self.n_grid, self.nees_stride)), dtype=np.float64)

    def _wheel_arrays(self) -> None:
        """The wheel metrics' arrays (zero: a maximum of magnitudes, a sum), with their first samples."""
        n = self.finite.shape[0]
        if self.wheel_speed_max is None or self.wheel_torque_max is None or self.wheel_energy is None:
            self.wheel_speed_max, self.wheel_torque_max, self.wheel_energy = np.zeros(n), np.zeros(n), np.zeros(n)

    def update_wheels(self, speed_rad_s: Array, torque_Nm: Array, runs: slice = slice(None)) -> None:
        """Observe a block of wheel records (B, N, W): speeds relative to the body and motor torques
        (``runs``: the arrays hold only those runs).  The same bits as the SIMD lanes' online
        :func:`wheel_metric_sample`, sample by sample."""
        self._wheel_arrays()
        assert self.wheel_speed_max is not None and self.wheel_torque_max is not None and self.wheel_energy is not None
        n = self.wheel_energy[runs].shape[0]
        for m, block in ((self.wheel_speed_max, speed_rad_s), (self.wheel_torque_max, torque_Nm)):
            a = np.abs(np.asarray(block, dtype=np.float64))
            block_max = np.where(np.isfinite(a), a, 0.0).max(axis=(0, 2)) if a.size else np.zeros(n)
            m[runs] = np.maximum(m[runs], block_max)
        # wheel_energy_J: sum_k sum_i |u_i Omega_i| dt, summed sample by sample in time order (cumsum is
        # sequential), the wheels in their order, so that any blocking gives the same bits
        power = np.abs(np.asarray(speed_rad_s, dtype=np.float64) * np.asarray(torque_Nm, dtype=np.float64))  # |u_i Omega_i| [W], (B, N, W)
        power = np.where(np.isfinite(power), power, 0.0)
        per_sample = np.zeros(power.shape[:2])
        for i in range(power.shape[2]):
            per_sample = per_sample + power[:, :, i]
        self.wheel_energy[runs] = np.cumsum(np.vstack((self.wheel_energy[runs][None, :], per_sample * self.dt)), axis=0)[-1]  # held over dt [J]

    def update(self, k0: int, t: Array, x: Array, torque_B: Array, q_BR: Array, rho: Array, saturated: NDArray[np.bool_],
               band_lower: Array, band_upper: Array) -> None:
        """Observe the block of samples ``k0 .. k0 + B - 1``: ``t`` (B,), the others (B, N, ...).

        A block gives the same result as its samples one by one.
        """
        x = np.asarray(x, dtype=np.float64)
        self._update(k0, t, x[..., :4], x[..., 4:], torque_B, q_BR, rho, saturated, band_lower, band_upper)

    def _update(self, k0: int, t: Array, q_BN: Array, omega: Array, torque_B: Array, q_BR: Array, rho: Array,
                saturated: NDArray[np.bool_], band_lower: Array, band_upper: Array, runs: slice = slice(None)) -> None:
        """:meth:`update` with the state split into attitude and rate: one compiled pass over the block
        (:func:`_update_kernel`, run by run, in the arrays' own layout: no copies, no temporaries).
        ``runs``: the arrays hold only those runs, into their state (views), the samples seen left to
        the caller."""
        t = np.asarray(t, dtype=np.float64).reshape(-1)
        if t.size == 0:
            return
        hold = self.hold_s if self.hold_s is not None else _NO_HOLD
        fault = np.nan if self.fault_start_s is None else float(self.fault_start_s)
        def f64(a: Any) -> Array:
            return np.asarray(a, dtype=np.float64)

        _update_function(t.size * self.finite[runs].shape[0])(
            int(k0), t, f64(q_BN), f64(omega), f64(torque_B), f64(q_BR), f64(rho), np.asarray(saturated, dtype=np.bool_), f64(band_lower),
            f64(band_upper), self.origin_k[runs], float(self.settle_threshold), float(LOSS_OF_CONTROL_FACTOR * self.settle_threshold),
            self.steady_from_per_run()[runs], self.k_t2_run[runs], hold, fault, self.finite[runs], self.last_unsettled[runs],
            self.last_controlled[runs], self.steady_sum[runs], self.steady_max[runs], self.rpf_error_t2_axis[runs], self.sign0[runs],
            self.overshoot[runs], self.max_torque[runs], self.saturated_count[runs], self.outside_count[runs], self.outside_s[runs],
            self.last_outside[runs], self.left_after_fault[runs], self.torque_sign[runs], self.torque_sign_nonzero[runs],
            self.torque_sign_changes[runs], self.torque_reversals[runs], self.steady_n[runs], self.steady_first[runs],
        )
        if runs == slice(None):
            self.samples += t.size

    def online_state(self, keep_stride: int = 0, trajectory: Array | None = None) -> tuple[MetricArrays, MetricConstants]:
        """What a loop that computes the metrics online, sample by sample, reads and writes (the
        SIMD lanes, :func:`sappc.offline.lanes.online_metrics`; every sample's contribution is
        :func:`metric_sample_of`'s, as in :meth:`add_history`): the per-run arrays
        (:func:`metric_state_load`, written in place), each run's constants (N, 3) (its steady
        window's start less the grid's tolerance, its origin, t2's sample; float64, exact), the
        settling threshold, the loss-of-control bound and the fault's start less the tolerance
        (NaN: no fault): :class:`MetricArrays` and :class:`MetricConstants`.  Only on a uniform
        grid without flight modes or orbits (what the lanes cover; the wheels' and the estimator's
        metrics: :meth:`online_flight_state`); the loop then calls :meth:`add_online_block` for
        every block.  ``keep_stride``, ``trajectory``: the trajectories' samples and where the loop
        writes them (:class:`MetricConstants`; ``None``: no trajectory)."""
        if self.hold_s is not None or self.orbit_bins is not None or self.mode_time_s is not None:
            raise ValueError("online metrics need a uniform grid without orbits or flight modes")
        arrays = MetricArrays(*(getattr(self, name) for name in MetricArrays._fields))
        per_run = np.column_stack((self.steady_from_per_run() - _TIME_TOL_S, self.origin_k.astype(np.float64),
                                   self.k_t2_run.astype(np.float64)))
        fault_from = np.nan if self.fault_start_s is None else float(self.fault_start_s) - _TIME_TOL_S
        settle = float(self.settle_threshold)
        trajectory = np.zeros((0, 0, 6)) if trajectory is None else trajectory
        return arrays, MetricConstants(np.int64(1), np.int64(keep_stride), trajectory, per_run, settle, float(LOSS_OF_CONTROL_FACTOR * self.settle_threshold),
                                       fault_from)

    def online_flight_state(self, block_samples: int, *, wheels: bool, estimating: bool) -> FlightMetricArrays:
        """:meth:`online_state`'s counterpart for the flight stack's metrics (the SIMD lanes'
        :func:`wheel_metric_sample` and :func:`estimate_metric_sample`, sample by sample): the
        wheels' and the estimator's per-run arrays (views, written in place; none where the runs
        have no wheels, no estimator) and the block's NEES per sample and run (``block_samples``
        rows), which :meth:`add_online_block` sums over the runs."""
        n = self.finite.shape[0]
        none_f, none_i = np.zeros(0), np.zeros(0, dtype=np.int64)
        if wheels:
            self._wheel_arrays()
        if estimating:
            self._estimate_arrays()
            self._online_nees = (np.zeros((block_samples, n)), np.zeros((block_samples, n), dtype=np.bool_))
        def own(a: NDArray[Any] | None, on: bool, empty: NDArray[Any]) -> NDArray[Any]:
            return a if on and a is not None else empty  # (allocated above where on)

        w, e = wheels, estimating
        return FlightMetricArrays(
            np.int64(1 if w else 0), np.int64(1 if e else 0), own(self.wheel_speed_max, w, none_f), own(self.wheel_torque_max, w, none_f),
            own(self.wheel_energy, w, none_f), float(self.dt), float(NEES_FROM_S - _TIME_TOL_S), own(self.est_att_max, e, np.zeros((0, 3))),
            own(self.est_att_sq, e, np.zeros((0, 3))), own(self.est_att_n, e, none_i), own(self.est_bias_last, e, np.zeros((0, 3))),
            own(self.est_nees_sum, e, none_f), own(self.est_nees_n, e, none_i),
            own(self.est_status_counts, e, np.zeros((0, len(STATUS_NAMES)), dtype=np.int64)), own(self.est_mon_error, e, none_i),
            own(self.est_mon_n, e, none_i), own(self.est_withheld, e, none_i), own(self.est_recoveries, e, none_i),
            own(self._online_nees[0], e, np.zeros((0, 0))), own(self._online_nees[1], e, np.zeros((0, 0), dtype=np.bool_)))

    def add_online_block(self, h: History, recorded: Sequence[int], *, block_samples: int | None = None) -> None:
        """A block of samples whose metrics the loop computed online (:meth:`online_state`, and
        :meth:`online_flight_state` with wheels or an estimator) for every run but ``recorded``
        (runs the SIMD lanes handed back to the per-run loop), whose samples ``h`` holds (its run
        ``i`` is run ``recorded[i]``): those runs' metrics from ``h``, as :meth:`add_history`'s,
        the block's NEES summed over the runs, and the block's samples counted as seen."""
        if h.mode is not None:
            raise ValueError("online metrics cover no flight modes")
        T = h.t.size
        nees = self._online_nees if self._online_nees[0].shape[0] else None  # (the block's, when it had an estimator)
        step = T if block_samples is None or T == 0 else max(1, int(block_samples))
        for i, r in enumerate(recorded):
            run, into = slice(i, i + 1), slice(int(r), int(r) + 1)
            for lo in range(0, T, step):
                b = h.samples(lo, min(lo + step, T))
                self._update(self.samples + lo, b.t, b.q_BN[:, run], b.omega_BN_B[:, run], b.torque_B[:, run], b.q_BR[:, run], b.rho[:, run],
                             b.saturated[:, run], b.band_lower[:, run], b.band_upper[:, run], runs=into)
                if b.wheel_speed_rad_s is not None and b.wheel_torque_Nm is not None:
                    self.update_wheels(b.wheel_speed_rad_s[:, run], b.wheel_torque_Nm[:, run], runs=into)
                if b.estimate is not None and nees is not None:
                    est = dataclasses.replace(b.estimate, **{f.name: getattr(b.estimate, f.name)[:, run] for f in dataclasses.fields(b.estimate)
                                                             if getattr(b.estimate, f.name) is not None})
                    self.update_estimate(self.samples + lo, b.t, b.q_BN[:, run], est, runs=into,
                                         nees=(nees[0][lo:lo + b.t.size], nees[1][lo:lo + b.t.size]))
        if nees is not None and T:
            self._add_nees(self.samples, nees[0][:T], nees[1][:T])
        self.samples += T

    def settling_times(self) -> Array:
        """``settling_time_s`` of every run from its origin, NaN for a run that never settles (or
        never reached its origin)."""
        lu = self.last_unsettled
        after = np.minimum(lu + 1, self.n_grid - 1)
        origin = self.origin_s()
        settled = np.where(lu < 0, 0.0, np.where(lu >= self.samples - 1, np.nan, self.time_s(after) - np.nan_to_num(origin)))
        return np.where(np.isnan(origin), np.nan, settled)

    def control_lost_times(self) -> Array:
        """``control_lost_at_s`` of every run, NaN for a run that did not lose control (module docstring)."""
        last = self.samples - 1
        if last < 0:
            return np.full(self.finite.shape[0], np.nan)
        before_window = self.time_s(last) < self.steady_from_per_run() - _TIME_TOL_S  # the run ends before its steady window
        lc = self.last_controlled
        return np.where((lc >= last) | ~self.finite | before_window, np.nan, self.time_s(np.minimum(lc + 1, last)))

    def steady_span_s(self) -> Array:
        """Each run's steady window's span ``t_last - t_first`` over the samples seen (NaN: fewer
        than two samples in it): the time base of the switching rates."""
        n = self.steady_n
        span = np.full(n.shape[0], np.nan)
        ok = n >= 2
        if self.samples > 0 and ok.any():
            span[ok] = self.time_s(self.samples - 1) - self.time_s(self.steady_first[ok])
        return span

    def switching_rates(self) -> tuple[Array, Array]:
        """``torque_sign_changes_per_s`` and ``torque_reversals_per_s`` of every run (NaN: no span)."""
        span = self.steady_span_s()
        return self.torque_sign_changes.max(axis=1) / span, self.torque_reversals.max(axis=1) / span

    def run_metrics(self, run: int = 0) -> dict[str, Any]:
        """The metrics of run ``run`` (see the module docstring), JSON-ready."""
        last = self.samples - 1
        settling_s = float(self.settling_times()[run])
        settling = None if np.isnan(settling_s) else settling_s
        steady = self.steady_n[run] > 0
        lo = int(self.last_outside[run])
        changes, reversals = self.switching_rates()
        m: dict[str, Any] = {
            "settling_time_s": settling,
            "steady_max_abs_qev": float(self.steady_max[run]) if steady else None,
            "steady_mean_abs_qev": float((self.steady_sum[run] / self.steady_n[run]).max()) if steady else None,
            "rpf_error_at_t2": None if np.isnan(self.rpf_error_t2_axis[run]).any() else float(self.rpf_error_t2_axis[run].max()),
            "overshoot": float(max(0.0, self.overshoot[run])),
            "max_abs_torque_Nm": float(self.max_torque[run]),
            "torque_sign_changes_per_s": None if np.isnan(changes[run]) else float(changes[run]),
            "torque_reversals_per_s": None if np.isnan(reversals[run]) else float(reversals[run]),
            "saturation_fraction": float(self.saturated_count[run] / max(self.samples, 1)),
            "time_outside_constraint_s": float(self.outside_count[run] * self.dt if self.hold_s is None else self.outside_s[run]),
            "returned_to_constraint": None,
            "left_constraint_after_fault": None,
            "returned_at_s": None,
            "finite": bool(self.finite[run]),
            "control_lost_at_s": _finite_or_none(self.control_lost_times()[run]),
        }
        if self.wheel_speed_max is not None and self.wheel_torque_max is not None:
            m["max_abs_wheel_speed_rad_s"] = float(self.wheel_speed_max[run])
            m["max_abs_wheel_torque_Nm"] = float(self.wheel_torque_max[run])
            if self.wheel_energy is not None:
                m["wheel_energy_J"] = float(self.wheel_energy[run])
        if self.est_att_max is not None:
            m.update(self._estimation_metrics(run))
        if self.mode_time_s is not None:
            assert self.mode_entry_s is not None and self.mode_transitions is not None and self.mode_seq is not None
            seq = self.mode_seq[run]
            m["mode_sequence"] = [MODE_NAMES[int(j)] for j in seq[seq >= 0]]
            m["time_to_track_s"] = _finite_or_none(self.mode_entry_s[run, TRACK])
            scale = self.dt if self.hold_s is None else 1.0
            m["time_in_mode_s"] = {name: float(self.mode_time_s[run, j] * scale) for j, name in enumerate(MODE_NAMES)}
            m["mode_transitions"] = int(self.mode_transitions[run])
        if self.fault_start_s is not None:
            left = bool(self.left_after_fault[run])
            returned = lo < last
            m["left_constraint_after_fault"] = left
            m["returned_to_constraint"] = returned
            if left and returned:
                m["returned_at_s"] = float(self.time_s(lo + 1))
        return m

    def _estimation_metrics(self, run: int) -> dict[str, Any]:
        assert self.est_att_max is not None and self.est_att_sq is not None and self.est_att_n is not None
        assert self.est_bias_last is not None and self.est_nees_sum is not None and self.est_nees_n is not None
        assert self.est_status_counts is not None and self.est_mon_error is not None and self.est_mon_n is not None
        assert self.est_withheld is not None and self.est_recoveries is not None
        n_att, n_nees = int(self.est_att_n[run]), int(self.est_nees_n[run])
        bias = self.est_bias_last[run]
        counts = self.est_status_counts[run]
        return {
            "steady_max_abs_attitude_estimation_error_rad": float(self.est_att_max[run].max()) if n_att else None,
            "steady_rms_attitude_estimation_error_rad": float(np.sqrt(self.est_att_sq[run] / n_att).max()) if n_att else None,
            "final_abs_bias_estimation_error_rad_s": float(np.abs(bias).max()) if np.all(np.isfinite(bias)) else None,
            "mean_nees": float(self.est_nees_sum[run] / n_nees) if n_nees else None,
            "estimator_updates": int(counts[STATUS_NAMES.index("updated")]),
            "estimator_gate_rejections": int(counts[STATUS_NAMES.index("rejected")]),
            "estimator_reinitialisations": int(counts[STATUS_NAMES.index("reinitialised")]),
            "filter_inconsistent_fraction": (float(self.est_mon_error[run] / self.est_mon_n[run]) if self.est_mon_n[run] > 0
                                             else 0.0 if self.est_mon_n[run] == 0 else None),
            "estimator_recoveries": int(self.est_recoveries[run]),
            "estimate_withheld_samples": int(self.est_withheld[run]),
        }

    def criteria_arrays(self) -> dict[str, Array]:
        """Per-run arrays for campaign tables: the two Monte Carlo criteria per component and more."""
        steady_mean = self.steady_sum / np.maximum(self.steady_n, 1)[:, None]
        changes, reversals = self.switching_rates()
        wheels = {} if self.wheel_speed_max is None or self.wheel_torque_max is None else {
            "max_abs_wheel_speed_rad_s": self.wheel_speed_max, "max_abs_wheel_torque_Nm": self.wheel_torque_max}
        if wheels and self.wheel_energy is not None:
            wheels["wheel_energy_J"] = self.wheel_energy
        if self.mode_entry_s is not None and self.mode_transitions is not None:
            wheels["time_to_track_s"] = self.mode_entry_s[:, TRACK].copy()
            wheels["mode_transitions"] = self.mode_transitions.astype(np.float64)
        if self.est_att_max is not None:
            per_run = [self._estimation_metrics(k) for k in range(self.finite.shape[0])]
            wheels.update({key: np.array([np.nan if m[key] is None else m[key] for m in per_run], dtype=np.float64)
                           for key in ("steady_max_abs_attitude_estimation_error_rad", "final_abs_bias_estimation_error_rad_s", "mean_nees",
                                       "filter_inconsistent_fraction", "estimator_recoveries")})
        return {**wheels,
            "steady_mean_abs_qev_per_axis": steady_mean,
            "steady_mean_abs_qev": steady_mean.max(axis=1),
            "rpf_error_at_t2_per_axis": self.rpf_error_t2_axis,
            "rpf_error_at_t2": self.rpf_error_t2_axis.max(axis=1),
            "steady_max_abs_qev": self.steady_max,
            "max_abs_torque_Nm": self.max_torque,
            "torque_sign_changes_per_s": changes,
            "torque_reversals_per_s": reversals,
            "settling_time_s": self.settling_times(),
            "control_lost_at_s": self.control_lost_times(),
            "finite": self.finite,
        }


#: The largest block (samples times runs) that :func:`_update_function` has the interpreter run
#: while numba is not loaded in the process: a 60 s bag at 100 Hz is 6001 (about 0.1 s
#: interpreted, against about 0.5 s to import numba and load the compiled kernel).
INTERPRETED_MAX_SAMPLES = 20_000
_interpreted_kernel: Callable[..., int] | None = None


def _update_function(samples: int) -> Callable[..., int]:
    """The function that runs :func:`_update_kernel` on a block of ``samples`` run-samples: the
    compiled kernel, or, for a small block while numba is not loaded (``sappc report`` on one bag),
    the same source run by the interpreter (:func:`interpreted_update_kernel`).  Both give the same
    bits: the kernel is compiled with ``fastmath=False`` (IEEE float64, no contraction, no
    reassociation) and calls no transcendental function; ``tests/tools/evaluation`` checks it."""
    if samples <= INTERPRETED_MAX_SAMPLES and "numba" not in sys.modules:
        return interpreted_update_kernel()
    return _update_kernel  # type: ignore[no-any-return]


def interpreted_update_kernel() -> Callable[..., int]:
    """:func:`_update_kernel`'s Python source with its helpers' Python sources, run by the interpreter."""
    global _interpreted_kernel
    if _interpreted_kernel is None:
        _interpreted_kernel = _interpreted(_update_kernel, (_maximum, _switch, metric_sample_of, metric_state_load, metric_state_store))
    return _interpreted_kernel


def _interpreted(kernel: Any, helpers: tuple[Any, ...]) -> Callable[..., Any]:
    """``kernel``'s Python source, calling its ``helpers``' Python sources (never a compiled kernel)."""
    f = kernel.py_func
    namespace = dict(f.__globals__)
    for helper in helpers:
        g = helper.py_func
        namespace[g.__name__] = types.FunctionType(g.__code__, namespace, g.__name__, g.__defaults__, g.__closure__)
    return types.FunctionType(f.__code__, namespace, f.__name__, f.__defaults__, f.__closure__)


def _summed_onto(total: Array, x: Array) -> Array:
    """``total`` plus the samples of ``x`` (B, ...) one after the other in time order: the same bits
    for a run alone as in any batch and for any split into blocks, as the compiled kernel's sums
    (numpy's pairwise ``sum`` orders its terms by the array's layout)."""
    out: Array = np.cumsum(np.concatenate((total[None], x), axis=0), axis=0)[-1]
    return out


@jit
def _maximum(a, b):  # type: ignore[no-untyped-def]  # a numba kernel (float64 scalars)
    """``numpy.maximum`` of two floats (a NaN wins, the first argument on a tie)."""
    return a if (a >= b or a != a) else b


@jit
def _switch(u, sign, nonzero):  # type: ignore[no-untyped-def]  # a numba kernel (float64 scalars)
    """One steady sample ``u`` of an axis after the signs ``sign`` (the last sample's, NaN: none) and
    ``nonzero`` (the last non-zero one, 0: none): its sign, the new last non-zero sign, whether the
    sign changed (0 or 1), whether it reversed (0 or 1)."""
    s = 1.0 if u > 0.0 else (-1.0 if u < 0.0 else 0.0)
    change = 1 if (s != sign and sign == sign) else 0  # NaN: the window's first sample
    if s == 0.0:
        return s, nonzero, change, 0
    return s, s, change, (1 if s == -nonzero else 0)  # nonzero 0: no non-zero sample yet


class MetricArrays(NamedTuple):
    """A :class:`MetricsAccumulator`'s per-run arrays that :func:`metric_state_load` reads and
    :func:`metric_state_store` writes (views: written in place), in their order."""

    finite: NDArray[np.bool_]
    last_unsettled: NDArray[np.int64]
    last_outside: NDArray[np.int64]
    last_controlled: NDArray[np.int64]
    steady_sum: Array
    steady_max: Array
    overshoot: Array
    max_torque: Array
    saturated_count: NDArray[np.int64]
    outside_count: NDArray[np.int64]
    left_after_fault: NDArray[np.bool_]
    outside_s: Array
    sign0: Array
    torque_sign: Array
    torque_sign_nonzero: Array
    torque_sign_changes: NDArray[np.int64]
    torque_reversals: NDArray[np.int64]
    steady_n: NDArray[np.int64]
    steady_first: NDArray[np.int64]
    rpf_error_t2_axis: Array


class MetricConstants(NamedTuple):
    """What a loop computing the metrics online reads besides :class:`MetricArrays`
    (:meth:`MetricsAccumulator.online_state`): ``on`` (0: the loop records its samples instead),
    ``keep_stride`` (``s`` > 0: every sample of the run whose index is a multiple of ``s`` is a
    trajectory's, for a campaign's figures; 0: none), ``trajectory`` (K, M, 6) where the loop writes
    those samples of the first M runs (the block's K such samples in order: the error
    quaternion's vector part ``q_BR[:3]`` and the funnel ``rho`` (3), as the record holds them;
    (0, 0, 6): none), each run's
    constants ``per_run`` (N, 3) (its steady window's start less the grid's tolerance, its origin,
    t2's sample; float64, exact), the settling threshold, the loss-of-control bound, the fault's
    start less the tolerance (NaN: no fault)."""

    on: np.int64
    keep_stride: np.int64
    trajectory: Array
    per_run: Array
    settle_threshold: float
    loss_bound: float
    fault_from: float


class FlightMetricArrays(NamedTuple):
    """What a loop computing the flight stack's metrics online writes
    (:meth:`MetricsAccumulator.online_flight_state`): whether the runs have wheels and an
    estimator (``wheels``, ``estimating``: 1 or 0; the arrays of what they lack have no rows); per
    run the wheels' largest speed and motor torque magnitudes and their energy [J]
    (:func:`wheel_metric_sample`), the grid's step ``dt`` [s], the NEES's start less the grid's
    tolerance [s], and the estimator's arrays (:func:`estimate_metric_sample`, then the statuses'
    counts, the samples at the monitor's ERROR and with a level, the withheld ones, the
    recoveries); per sample of the block and run, its NEES (0 where not counted) and whether it
    was counted."""

    wheels: np.int64
    estimating: np.int64
    wheel_speed_max: Array
    wheel_torque_max: Array
    wheel_energy: Array
    dt: float
    nees_from: float
    att_max: Array
    att_sq: Array
    att_n: NDArray[np.int64]
    bias_last: Array
    nees_sum: Array
    nees_n: NDArray[np.int64]
    status_counts: NDArray[np.int64]
    mon_error: NDArray[np.int64]
    mon_n: NDArray[np.int64]
    withheld: NDArray[np.int64]
    recoveries: NDArray[np.int64]
    nees_out: Array
    counted: NDArray[np.bool_]


#: The fields of :class:`FlightMetricArrays` with a row per run (the others: flags, constants, the
#: block's NEES per sample).
FLIGHT_METRICS_PER_RUN = ("wheel_speed_max", "wheel_torque_max", "wheel_energy", "att_max", "att_sq", "att_n", "bias_last", "nees_sum", "nees_n",
                          "status_counts", "mon_error", "mon_n", "withheld", "recoveries")


@jit(inline="always")  # type: ignore[no-untyped-call]
def wheel_metric_sample(n, speed, torque, dt, speed_max, torque_max, energy):  # type: ignore[no-untyped-def]
    """One sample of run ``n``'s wheel metrics (:meth:`MetricsAccumulator.update_wheels`'s, the same
    bits): the wheels' speeds relative to the body ``speed`` (W,) [rad/s] and motor torques
    ``torque`` (W,) [N m] into the largest finite magnitudes and the energy ``sum_i |u_i Omega_i|
    dt`` (the wheels in their order, then onto the run's sum)."""
    power = 0.0
    for i in range(speed.shape[0]):
        s, u = abs(speed[i]), abs(torque[i])
        speed_max[n] = max(speed_max[n], s if np.isfinite(s) else 0.0)
        torque_max[n] = max(torque_max[n], u if np.isfinite(u) else 0.0)
        p = abs(speed[i] * torque[i])
        power = power + (p if np.isfinite(p) else 0.0)
    energy[n] = energy[n] + power * dt


#: One run's metric state as :func:`metric_sample_of` takes and gives it: a tuple of
#: :data:`N_METRIC_STATE` float64 (sample indices and counts exact below 2**53; flags 1.0 or 0.0),
#: in this order: finite; the last unsettled, outside and controlled samples; the steady sums of
#: ``|q_ev,i|``; the steady max; the overshoot; the largest torque; the saturated and outside
#: samples; left after the fault; the outside time (non-uniform grid); the error's signs at the
#: origin; per axis the last steady torque sign, the last non-zero one, the sign changes and the
#: reversals; the steady samples and the first one's index; the RPF's error at t2 per axis.
N_METRIC_STATE = 34


@jit(inline="always")  # type: ignore[no-untyped-call]
def metric_sample_of(m, k, t_k, ok, e0, e1, e2, u0, u1, u2, rho0, rho1, rho2, sat, bl0, bl1, bl2, bu0, bu1, bu2, hold_k, has_hold,  # type: ignore[no-untyped-def]
                     steady_from, origin, k_t2, settle_threshold, loss_bound, fault_from):
    """One sample ``k`` (float) at ``t_k`` [s] of one run into its metric state ``m``
    (:data:`N_METRIC_STATE`; the new state returned): the definitions of the module docstring,
    the one implementation of every sample's contribution (the batch kernel :func:`_update_kernel`
    and the SIMD lanes of :mod:`sappc.offline.lanes` call it).  ``ok``: the sample's attitude,
    rate and torque are finite; ``e`` its error ``q_ev``, ``u`` the torque, ``rho`` the
    performance function, ``sat`` any axis saturated, ``bl``/``bu`` the band; ``hold_k`` its hold
    interval, summed only when ``has_hold`` (a non-uniform grid).  The run's constants: its steady
    window from ``steady_from`` [s] (less the grid's tolerance), its origin ``origin`` (-1: none
    yet) and t2's sample ``k_t2`` (-1: none), the thresholds, the fault's start less the
    tolerance ``fault_from`` (NaN: no fault).  Sums run sample after sample and maxima keep the
    first of equals (NaN wins), so any split of a run into blocks gives the same bits."""
    (live, lu, lo, lc, s0, s1, s2, smax, over, tmax, n_sat, n_out, left, held, sg0, sg1, sg2, p0, p1, p2, z0, z1, z2,
     c0, c1, c2, r0, r1, r2, sn, sf, x0, x1, x2) = m
    live = 1.0 if (live != 0.0 and ok) else 0.0  # a failed run stops at its last finite sample
    if k == origin:  # the run's origin: the overshoot's initial signs
        sg0 = 1.0 if e0 >= 0.0 else -1.0
        sg1 = 1.0 if e1 >= 0.0 else -1.0
        sg2 = 1.0 if e2 >= 0.0 else -1.0
    alive = live != 0.0
    counted = alive and origin >= 0.0 and k >= origin  # from the run's origin on
    a0, a1, a2 = abs(e0), abs(e1), abs(e2)
    max_abs_q = _maximum(_maximum(a0, a1), a2)
    if counted and max_abs_q >= settle_threshold:
        lu = k
    if alive and (t_k < steady_from or max_abs_q <= loss_bound):  # control_lost_at_s: a NaN error is not within
        lc = k
    steady = t_k >= steady_from
    if steady:
        sn = sn + 1.0
        if sf < 0.0:
            sf = k
    if alive and steady:
        s0 = s0 + a0  # a sequential running sum, sample by sample
        s1 = s1 + a1
        s2 = s2 + a2
        smax = _maximum(smax, max_abs_q)
        p0, z0, a, b = _switch(u0, p0, z0)
        c0, r0 = c0 + a, r0 + b
        p1, z1, a, b = _switch(u1, p1, z1)
        c1, r1 = c1 + a, r1 + b
        p2, z2, a, b = _switch(u2, p2, z2)
        c2, r2 = c2 + a, r2 + b
    if k == k_t2:
        x0 = abs(e0 - rho0) if alive else np.nan
        x1 = abs(e1 - rho1) if alive else np.nan
        x2 = abs(e2 - rho2) if alive else np.nan
    if counted:
        over = _maximum(over, _maximum(_maximum(-sg0 * e0, -sg1 * e1), -sg2 * e2))
        tmax = _maximum(tmax, _maximum(_maximum(abs(u0), abs(u1)), abs(u2)))
        if sat:
            n_sat = n_sat + 1.0
        # inside: within every component's band; a NaN band (none yet) fails the comparison
        inside = ((e0 >= bl0 and e0 <= bu0) and (e1 >= bl1 and e1 <= bu1) and (e2 >= bl2 and e2 <= bu2))
        if not inside:
            n_out = n_out + 1.0
            lo = k
            if t_k >= fault_from:
                left = 1.0
            if has_hold:
                held = held + hold_k  # a sequential running sum
    # two literals joined: CPython builds a literal of over 30 items through a list, which numba does not type
    return ((live, lu, lo, lc, s0, s1, s2, smax, over, tmax, n_sat, n_out, left, held, sg0, sg1, sg2)
            + (p0, p1, p2, z0, z1, z2, c0, c1, c2, r0, r1, r2, sn, sf, x0, x1, x2))


@jit(inline="always")  # type: ignore[no-untyped-call]
def metric_state_load(a, n):  # type: ignore[no-untyped-def]
    """Run ``n``'s metric state (:data:`N_METRIC_STATE`) from the accumulator's per-run arrays
    ``a`` (:class:`MetricArrays`, or a tuple of them in its order)."""
    (finite, last_unsettled, last_outside, last_controlled, steady_sum, steady_max, overshoot, max_torque, saturated_count, outside_count,
     left_after_fault, outside_s, sign0, torque_sign, torque_sign_nonzero, torque_sign_changes, torque_reversals, steady_n, steady_first,
     rpf_error_t2_axis) = a
    return (1.0 if finite[n] else 0.0, float(last_unsettled[n]), float(last_outside[n]), float(last_controlled[n]), steady_sum[n, 0],
            steady_sum[n, 1], steady_sum[n, 2], steady_max[n], overshoot[n], max_torque[n], float(saturated_count[n]), float(outside_count[n]),
            1.0 if left_after_fault[n] else 0.0, outside_s[n], sign0[n, 0], sign0[n, 1], sign0[n, 2]) + (torque_sign[n, 0], torque_sign[n, 1],
            torque_sign[n, 2], torque_sign_nonzero[n, 0], torque_sign_nonzero[n, 1], torque_sign_nonzero[n, 2], float(torque_sign_changes[n, 0]),
            float(torque_sign_changes[n, 1]), float(torque_sign_changes[n, 2]), float(torque_reversals[n, 0]), float(torque_reversals[n, 1]),
            float(torque_reversals[n, 2]), float(steady_n[n]), float(steady_first[n]), rpf_error_t2_axis[n, 0], rpf_error_t2_axis[n, 1],
            rpf_error_t2_axis[n, 2])


@jit(inline="always")  # type: ignore[no-untyped-call]
def metric_state_store(a, n, m):  # type: ignore[no-untyped-def]
    """Run ``n``'s metric state ``m`` into the accumulator's per-run arrays ``a`` (the inverse of
    :func:`metric_state_load`: every conversion exact)."""
    (finite, last_unsettled, last_outside, last_controlled, steady_sum, steady_max, overshoot, max_torque, saturated_count, outside_count,
     left_after_fault, outside_s, sign0, torque_sign, torque_sign_nonzero, torque_sign_changes, torque_reversals, steady_n, steady_first,
     rpf_error_t2_axis) = a
    finite[n] = m[0] != 0.0
    last_unsettled[n], last_outside[n], last_controlled[n] = int(m[1]), int(m[2]), int(m[3])
    steady_sum[n, 0], steady_sum[n, 1], steady_sum[n, 2] = m[4], m[5], m[6]
    steady_max[n], overshoot[n], max_torque[n] = m[7], m[8], m[9]
    saturated_count[n], outside_count[n] = int(m[10]), int(m[11])
    left_after_fault[n] = m[12] != 0.0
    outside_s[n] = m[13]
    sign0[n, 0], sign0[n, 1], sign0[n, 2] = m[14], m[15], m[16]
    torque_sign[n, 0], torque_sign[n, 1], torque_sign[n, 2] = m[17], m[18], m[19]
    torque_sign_nonzero[n, 0], torque_sign_nonzero[n, 1], torque_sign_nonzero[n, 2] = m[20], m[21], m[22]
    torque_sign_changes[n, 0], torque_sign_changes[n, 1], torque_sign_changes[n, 2] = int(m[23]), int(m[24]), int(m[25])
    torque_reversals[n, 0], torque_reversals[n, 1], torque_reversals[n, 2] = int(m[26]), int(m[27]), int(m[28])
    steady_n[n], steady_first[n] = int(m[29]), int(m[30])
    rpf_error_t2_axis[n, 0], rpf_error_t2_axis[n, 1], rpf_error_t2_axis[n, 2] = m[31], m[32], m[33]


@jit("int64(int64, float64[:], float64[:, :, :], float64[:, :, :], float64[:, :, :], float64[:, :, :], float64[:, :, :], "  # type: ignore[no-untyped-call]
     "boolean[:, :, :], float64[:, :, :], float64[:, :, :], int64[:], float64, float64, float64[:], int64[:], float64[:], float64, boolean[:], "
     "int64[:], int64[:], float64[:, :], float64[:], float64[:, :], float64[:, :], float64[:], float64[:], int64[:], int64[:], float64[:], "
     "int64[:], boolean[:], float64[:, :], float64[:, :], int64[:, :], int64[:, :], int64[:], int64[:])")
def _update_kernel(k0, t, q_BN, omega, torque, q_BR, rho, saturated, band_lower, band_upper, origin_k, settle_threshold,  # type: ignore[no-untyped-def]
                   loss_bound, steady_from_s, k_t2, hold_s, fault_start_s, finite, last_unsettled, last_controlled, steady_sum, steady_max, rpf_error_t2_axis,
                   sign0, overshoot, max_torque, saturated_count, outside_count, outside_s, last_outside, left_after_fault,
                   torque_sign, torque_sign_nonzero, torque_sign_changes, torque_reversals, steady_n, steady_first):
    """One block of samples ``k0 .. k0 + B - 1`` (arrays (B, N, ...)) into the per-run state of a
    :class:`MetricsAccumulator` (in place), run by run, sample by sample
    (:func:`metric_sample_of`: the definitions of the module docstring).  Each run counts from its
    origin ``origin_k[n]`` (the sample its tracking starts at: 0, or with flight modes TRACK's
    first sample; -1: not yet): the samples before it enter no metric but the loss-of-control
    rule's (they are before the steady window, finite or not) and the run's finiteness; its steady
    window from ``steady_from_s[n]`` [s] (its origin's time plus the scenario's ``steady_from_s``;
    infinite before the origin is known), its RPF error at sample ``k_t2[n]`` (-1: none), its
    error's initial signs (the overshoot's) at its origin.  Counts the steady samples of each run
    into ``steady_n`` and the first one's index into ``steady_first`` (-1: none yet); returns the
    block's steady run-samples.  ``fault_start_s`` NaN: no faults; ``hold_s`` empty: uniform grid."""
    B = t.shape[0]
    fault_from = fault_start_s - _TIME_TOL_S  # NaN: no fault (no time is after it)
    has_hold = hold_s.shape[0] > 0
    a = (finite, last_unsettled, last_outside, last_controlled, steady_sum, steady_max, overshoot, max_torque, saturated_count, outside_count,
         left_after_fault, outside_s, sign0, torque_sign, torque_sign_nonzero, torque_sign_changes, torque_reversals, steady_n, steady_first,
         rpf_error_t2_axis)
    total_steady = 0
    for n in range(finite.shape[0]):
        steady_from = steady_from_s[n] - _TIME_TOL_S
        origin, kt2 = float(origin_k[n]), float(k_t2[n])
        before = steady_n[n]
        m = metric_state_load(a, n)
        for k in range(B):
            ok = True
            for i in range(4):
                ok = ok and np.isfinite(q_BN[k, n, i])
            for i in range(3):
                ok = ok and np.isfinite(omega[k, n, i])
            for i in range(3):
                ok = ok and np.isfinite(torque[k, n, i])
            m = metric_sample_of(m, float(k0 + k), t[k], ok, q_BR[k, n, 0], q_BR[k, n, 1], q_BR[k, n, 2], torque[k, n, 0], torque[k, n, 1],
                                 torque[k, n, 2], rho[k, n, 0], rho[k, n, 1], rho[k, n, 2],
                                 saturated[k, n, 0] or saturated[k, n, 1] or saturated[k, n, 2], band_lower[k, n, 0], band_lower[k, n, 1],
                                 band_lower[k, n, 2], band_upper[k, n, 0], band_upper[k, n, 1], band_upper[k, n, 2],
                                 hold_s[k0 + k] if has_hold else 0.0, has_hold, steady_from, origin, kt2, settle_threshold, loss_bound,
                                 fault_from)
        metric_state_store(a, n, m)
        total_steady += steady_n[n] - before
    return total_steady


@jit(inline="always")  # type: ignore[no-untyped-call]
def _nees_of(e, P, A):  # type: ignore[no-untyped-def]  # a numba kernel
    """``e^T P^-1 e`` of the error ``e`` (6,) and the covariance ``P`` (6, 6) (the module
    docstring's ``mean_nees``) by ``P = L D L^T`` (symmetric Gaussian elimination, no pivoting:
    a covariance is symmetric positive definite, where this factorisation is backward stable,
    Higham, *Accuracy and Stability of Numerical Algorithms*, ch. 10): ``sum_c z_c^2 / d_c`` with
    ``z = L^-1 e``, from ``P``'s upper triangle (the filter keeps ``P`` symmetric) on the scratch
    ``A`` (6, 7), ``[P | e]``; each pivot's reciprocal taken once.  Non-finite for a singular
    ``P`` (a zero pivot).  About half the products of elimination with partial pivoting and 6
    divisions instead of 21: the estimator's metrics run at every sample of a flight campaign."""
    m = N_ERROR_STATES
    for i in range(m):
        for j in range(i, m):
            A[i, j] = P[i, j]
        A[i, m] = e[i]
    quadratic = 0.0
    for c in range(m):
        inv = 1.0 / A[c, c]  # 1 / d_c
        z = A[c, m]  # z_c: every earlier pivot's elimination done
        quadratic = quadratic + z * z * inv
        for i in range(c + 1, m):
            f = A[c, i] * inv  # L[i, c] (A[c, i] = d_c L[i, c], the upper triangle)
            for j in range(i, m):
                A[i, j] = A[i, j] - f * A[c, j]
            A[i, m] = A[i, m] - f * z
    return quadratic


@jit(inline="always")  # type: ignore[no-untyped-call]
def estimate_metric_sample(n, t_k, steady_from, nees_from, truth, q_hat, q_true, b_hat, b_true, P, att_max, att_sq, att_n, bias_last,  # type: ignore[no-untyped-def]
                           nees_sum, nees_n, dq, a, err, A):
    """One sample of run ``n``'s estimation metrics (:func:`_estimate_kernel`'s, which calls it for
    every sample of a record, and the SIMD lanes', which call it as they go): the attitude
    estimation error ``a`` (``rotvec(q_hat^* ⊗ q_true)``; ``q_hat`` NaN: no estimate) at ``t_k``
    from ``steady_from`` into ``att_max``, ``att_sq``, ``att_n``; with the true bias (``truth``),
    the bias error ``b_true - b_hat`` into ``bias_last`` and the NEES (:func:`_nees_of` with the
    covariance ``P``) from ``nees_from`` into ``nees_sum``, ``nees_n``.  Returns the sample's NEES
    and whether it was counted (0.0, False where not).  ``dq`` (4), ``a`` (3), ``err`` (6), ``A``
    (6, 7): scratch."""
    ex, ey, ez, ew = -q_hat[0], -q_hat[1], -q_hat[2], q_hat[3]
    tx, ty, tz, tw = q_true[0], q_true[1], q_true[2], q_true[3]
    dq[0] = ew * tx + tw * ex + (ey * tz - ez * ty)
    dq[1] = ew * ty + tw * ey + (ez * tx - ex * tz)
    dq[2] = ew * tz + tw * ez + (ex * ty - ey * tx)
    dq[3] = ew * tw - (ex * tx + ey * ty + ez * tz)
    rotation_vector(dq, a)
    has = np.isfinite(a[0]) and np.isfinite(a[1]) and np.isfinite(a[2])  # NaN: no estimate
    if has and t_k >= steady_from:
        for i in range(3):
            att_max[n, i] = max(att_max[n, i], abs(a[i]))
            att_sq[n, i] = att_sq[n, i] + a[i] * a[i]
        att_n[n] += 1
    if not truth:
        return 0.0, False
    ok = True
    for i in range(3):
        err[i] = a[i]
        err[3 + i] = b_true[i] - b_hat[i]
        ok = ok and np.isfinite(err[3 + i])
    if has:
        for i in range(3):
            bias_last[n, i] = err[3 + i]
    n_bad = 0  # P's non-finite entries: a count, not a chain of tests (one branch, not 36)
    for i in range(N_ERROR_STATES):
        for j in range(N_ERROR_STATES):
            n_bad += 0 if np.isfinite(P[i, j]) else 1
    if ok and has and n_bad == 0 and t_k >= nees_from:
        v = _nees_of(err, P, A)
        if np.isfinite(v):
            nees_sum[n] = nees_sum[n] + v
            nees_n[n] += 1
            return v, True
    return 0.0, False


@jit("void(float64[:], float64[:], float64[:, :, :], float64[:, :, :], float64[:, :, :], float64[:, :, :], float64[:, :, :, :], "  # type: ignore[no-untyped-call]
     "float64[:, :], float64[:, :], int64[:], float64[:, :], float64[:], int64[:], float64[:, :], boolean[:, :])")
def _estimate_kernel(t, steady_from_s, q_hat, q_true, b_hat, b_true, P, att_max, att_sq, att_n, bias_last, nees_sum, nees_n, nees_out,  # type: ignore[no-untyped-def]
                     counted):
    """One block of the estimator's record (arrays (B, N, ...)) into the estimation metrics' per-run
    state (in place; module docstring), run by run, sample by sample: the attitude estimation error
    ``a`` (``rotvec(q_hat^* ⊗ q_true)``, :func:`sappc.evaluation.estimation.attitude_errors`'s
    definition, by the filter's own :func:`~sappc_estimator.core.mekf.rotation_vector`) in the steady
    window into ``att_max`` (per axis) and ``att_sq`` (summed), counted in ``att_n``; with the true
    bias (``b_true`` of B rows, else none), the bias error ``b_true - b_hat`` of the run's last
    estimate into ``bias_last``, and the NEES (:func:`_nees_of`) from :data:`NEES_FROM_S` into
    ``nees_sum`` and ``nees_n``, and each sample's into ``nees_out`` (0 where not counted) and
    ``counted`` (B, N): the campaign's sums over runs."""
    B = t.shape[0]
    truth = b_true.shape[0] == B and B > 0
    nees_from = NEES_FROM_S - _TIME_TOL_S
    dq, a, err, A = np.empty(4), np.empty(3), np.empty(N_ERROR_STATES), np.empty((N_ERROR_STATES, N_ERROR_STATES + 1))
    for n in range(att_n.shape[0]):
        steady_from = steady_from_s[n] - _TIME_TOL_S
        for k in range(B):
            if truth:
                v, c = estimate_metric_sample(n, t[k], steady_from, nees_from, True, q_hat[k, n], q_true[k, n], b_hat[k, n], b_true[k, n],
                                              P[k, n], att_max, att_sq, att_n, bias_last, nees_sum, nees_n, dq, a, err, A)
                if c:
                    nees_out[k, n] = v
                    counted[k, n] = True
            else:
                estimate_metric_sample(n, t[k], steady_from, nees_from, False, q_hat[k, n], q_true[k, n], a, a, P[k, n], att_max, att_sq, att_n,
                                       bias_last, nees_sum, nees_n, dq, a, err, A)


#: :data:`INTERPRETED_MAX_SAMPLES` for :func:`_estimate_kernel`, whose samples cost the interpreter
#: about 125 us each (its 6 x 6 elimination): up to this many (0.5 s, about numba's import and
#: the kernel's load from the cache) it is interpreted, a 40 s record of one run; a 60 s flight
#: bag's report loads numba.
ESTIMATE_INTERPRETED_MAX_SAMPLES = 4_000
_interpreted_estimate_kernel: Callable[..., None] | None = None


def _estimate_function(samples: int) -> Callable[..., None]:
    """:func:`_estimate_kernel` compiled, or (as :func:`_update_function`) its Python source for a
    small block while numba is not loaded: the same bits (``fastmath=False``; its one
    transcendental call, ``arctan2``, is the C library's in both)."""
    global _interpreted_estimate_kernel
    if samples <= ESTIMATE_INTERPRETED_MAX_SAMPLES and "numba" not in sys.modules:
        if _interpreted_estimate_kernel is None:
            _interpreted_estimate_kernel = _interpreted(_estimate_kernel, (_nees_of, rotation_vector, estimate_metric_sample))
        return _interpreted_estimate_kernel
    return _estimate_kernel  # type: ignore[no-any-return]


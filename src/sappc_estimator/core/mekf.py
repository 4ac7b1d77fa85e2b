"""The attitude estimator, compiled: a multiplicative extended Kalman filter (MEKF) on the attitude
error and the gyro bias, one run's step as a numba kernel.

This module is **the** implementation of the filter: the estimator node
(``python -m sappc_estimator``), the offline whole-run loop and Monte Carlo all call
:func:`mekf_step`.  It imports no configuration class: :mod:`.config` packs the settings into the
parameter array below (the kernels are leaves of the room).

References: Lefferts, Markley and Shuster, "Kalman filtering for spacecraft attitude estimation",
J. Guidance 5(5), 1982; Markley and Crassidis, *Fundamentals of Spacecraft Attitude Determination
and Control*, Springer 2014, ch. 6 (cited as "M&C" with their equation numbers).
The filter is specified line by line in ``docs/estimator.md``; ``tests/estimator/oracle.py`` is an
independent numpy transcription of that page.

Model (quaternions scalar last, Hamilton product, ``q_BN``: body relative to inertial)
---------------------------------------------------------------------------------------
Truth ``q = q_hat ⊗ dq(a)``: the attitude error ``a`` is a rotation vector in the *body* frame
(M&C 6.2.1's local error).  The gyro measures ``omega_meas = omega + b + eta_v``, the bias walks
``db/dt = eta_u``; ``eta_v`` and ``eta_u`` are white with per-axis spectral densities
``sigma_v^2`` (angle random walk squared, rad^2/s) and ``sigma_u^2`` (bias random walk squared,
rad^2/s^3).  The star tracker measures ``q_meas = q ⊗ dq(nu)``, ``nu`` (body frame) with per-axis
variances ``R`` [rad^2].  Error state ``x = (a, db)`` (6), ``db = b - b_hat``; covariance ``P``
(6, 6).

One step (:func:`mekf_step`), at a sample of time ``t`` with measurement ``y = (q_meas, omega_meas)``:

0. **No measurement.**  A measurement with a non-finite component (a dropped sample, the
   injector's "no data"), a quaternion whose norm differs from 1 by more than
   ``max_norm_error`` or a rate beyond ``max_rate`` [rad/s] (a sensor or link fault, not a
   state) changes nothing and gives no estimate (status *none*, outputs NaN).
1. **A new tracker sample** is one whose epoch (``y[7]``: the time the tracker measured the
   quaternion, which it holds between updates and through outages,
   ``spacecraft_sim.core.sensors``; on the graph ``state/attitude_epoch``) is later than the epoch
   of the last sample used; never by comparing values: a fault window that ends between two
   epochs changes a held value without making it new.  The first step's sample is new.
2. **Initialisation.**  ``from_tracker`` (default): the first step's sample becomes ``q_hat``,
   with ``b_hat = b0`` and ``P = diag(P0_a, P0_b)``; measured at this step (its epoch is ``t``)
   it is the estimate at once; older (a filter started between two updates: a held quaternion may
   be up to one tracker period old) it is *provisional*: the next new sample re-initialises the
   attitude (``q_hat = q_meas``, ``P_aa = R``, ``P_ab = 0``; status *initialised*) instead of
   updating it.  ``from_prior``: at the first step ``q_hat = q_prior``, same ``b_hat`` and
   ``P``, and that step's tracker sample is then processed as an update (a prior far from the
   truth, e.g. a coarse sensor's attitude 10 deg off, is corrected by the first tracker sample).
   The estimate is *confirmed* (usable, ``out[EO_USABLE] = 1``) when initialised from the tracker
   (a measurement, of now or at most one tracker period old) and after an accepted update; a prior
   and a re-initialised attitude are withheld (0) until a tracker sample is accepted: the callers
   then give the controller "no data".
3. **Propagation** from the previous step's time ``t_prev`` over ``h = t - t_prev`` with the mean
   of the two gyro samples, bias removed: ``w = (omega_prev + omega_meas) / 2 - b_hat``
   (trapezoid: the rate between two samples, not the older one held).
   ``q_hat <- normalise(q_hat ⊗ dq(w h))`` (the exact rotation for a constant rate);
   ``P <- Phi P Phi^T + Qd``, ``Phi`` the transition of ``F = [[-[w x], -I], [0, 0]]`` in closed
   form (M&C 6.83: ``Phi11 = I - [w x] s + [w x]^2 c``, ``Phi12 = [w x] c - I h - [w x]^2 d``,
   ``s = sin(x)/|w|``, ``c = (1 - cos x)/|w|^2``, ``d = (x - sin x)/|w|^3``, ``x = |w| h``), and
   ``Qd`` M&C 6.93 per axis: ``[[sv^2 h + su^2 h^3 / 3, -su^2 h^2 / 2], [-su^2 h^2 / 2, su^2 h]]``.
   ``1 - cos x`` is evaluated as ``2 sin^2(x/2)`` and ``x - sin x`` by its series below
   :data:`SERIES_BELOW` (no cancellation).  ``P`` is symmetrised.
4. **Update** (a new tracker sample, once initialised): residual ``r = rotvec(q_hat^* ⊗ q_meas)``
   (shortest rotation, ``r = 2 atan2(|v|, s) v / |v|`` with ``s >= 0``); ``S = P_aa + diag(R)``;
   the squared Mahalanobis distance ``d2 = r^T S^-1 r`` (the normalised innovation squared, NIS,
   chi-square with 3 degrees of freedom for a consistent filter).
   *Gate*: unless ``d2 <= gate`` the sample is rejected (counted); after ``max_rejections``
   consecutive rejections the filter re-initialises its attitude from the tracker
   (``q_hat = q_meas``, ``P_aa = R``, ``P_ab = 0``; the bias estimate kept, its covariance
   inflated by the recovery's ``Q_r``: the bias knowledge kept, not the confidence that let the
   attitude drift; unconfirmed until the next accepted sample): a filter that has lost its
   attitude must not reject the truth forever.
   *Accepted*: ``K = P H^T S^-1`` with ``H = [I 0]``, ``dx = K r``, the Joseph form
   ``P <- (I - K H) P (I - K H)^T + K R K^T`` (symmetric and positive definite whatever the
   rounding, M&C 6.25), symmetrised; the multiplicative reset ``q_hat <- normalise(q_hat ⊗
   dq(dx_a))``, ``b_hat <- b_hat + dx_b`` (M&C 6.2.3; ``P`` is not transformed by the reset).
   *Health monitor* (after an accepted update): the sample's NIS and whitened innovation
   ``w = L^-1 r`` (``S = L L^T``, Cholesky) go into a window of the last ``n`` accepted samples;
   once full, each sample gives a verdict: the window's NIS sum (chi-square with ``3 n`` degrees
   of freedom for a consistent filter: Bar-Shalom, Li and Kirubarajan, *Estimation with
   Applications to Tracking and Navigation*, 2001, 5.4.2, the time-average NIS test) against its
   two-sided warning and error bands, and the mean test ``|sum w|^2 / n`` (chi-square with 3: the
   innovations are zero-mean, ibid.) against its upper bounds: level OK, WARN or ERROR
   (``MON_*``).  ERROR, a failed monitor, takes ``persistence`` verdicts in a row outside the error
   band (fewer are WARN): the verdicts slide by one sample, ~36 000 an hour at 10 Hz, so a
   per-verdict false-alarm probability alone would fail a consistent filter a few times an hour
   (``docs/estimator.md``, "False alarms").  Beside the window, the *drift test*: Page's CUSUM of
   each whitened component, upward ``g+ <- max(0, g+ + w_i - k)`` and downward
   ``g- <- max(0, g- - w_i - k)`` (six statistics, ``k`` half the mean shift it is tuned to), fails
   the monitor (ERROR, at once) when one exceeds its threshold ``h`` (from a stated false-alarm
   probability per sample: Siegmund's approximation of the CUSUM's run length, :mod:`.config`): a
   small persistent mean (a bias step about the tracker's boresight) that a 20-sample window does
   not see adds up in it (Page, "Continuous inspection schemes", Biometrika 41, 1954; Basseville and
   Nikiforov, *Detection of Abrupt Changes*, 1993, 2.2).  A failed monitor above an error bound, or by
   the drift test (then about the axes whose CUSUM passed its threshold only: the whitened
   components are the body axes' to the small off-diagonal of ``S``, and a bias step of one gyro
   axis shows in its own): the *recovery* adds a bias
   step of covariance ``Q_r = diag(bias_recovery_sigma^2)`` dated at the window's first sample,
   ``age`` s ago, carried to now by the transition's bias columns: ``P_bb += Q_r``,
   ``P_ab += -Q_r age``, ``P_aa += Q_r age^2`` (the adjustable process noise of Bar-Shalom et
   al. 11.2, applied once when the test fails; the covariance inflation of adaptive filtering in
   Crassidis and Junkins, *Optimal Estimation of Dynamic Systems*, 2nd ed., 2012, ch. 5), and
   empties the window and the CUSUMs; a second failure before a verdict inside the band
   re-initialises as after the gate's rejections.
5. **Outputs**: ``q_hat``, ``omega_hat = omega_meas - b_hat`` (the current sample), ``b_hat``, the
   1-sigma of each error state ``sqrt(diag P)``, the last NIS, the step's status, the monitor's
   level, window NIS sum and mean statistic, whether the estimate is usable, the recoveries, the
   drift test's statistic (the largest CUSUM).

Arrays (float64, the caller's; no allocation per step)
------------------------------------------------------
``prm`` (:data:`N_EST_PARAMS`,)
    Columns ``EP_*``: ``R`` (3), ``sigma_v^2`` (3), ``sigma_u^2`` (3), ``P0_a`` (3), ``P0_b`` (3),
    ``b0`` (3), ``gate`` (inf: none), ``max_rejections`` (>= 1), the initialisation mode
    (``INIT_*``), ``q_prior`` (4), the plausibility bounds ``max_norm_error`` and
    ``max_rate`` [rad/s], the monitor's window, its NIS-sum bounds (4), its mean-test bounds (2),
    the recovery's ``Q_r`` (3), the monitor's persistence [verdicts], the drift test's reference
    value and threshold (2) [innovation sigmas] and the tracker's silence before STALE [s] (inf:
    never).
``y`` (:data:`N_MEAS`,)
    The measurement: ``q_meas`` (4), ``omega_meas`` (3), the tracker sample's epoch [s] (``<= t``).
``st`` (:data:`N_EST_STATE`,)
    Columns ``ES_*``: initialised flag, ``q_hat`` (4), ``b_hat`` (3), the previous measurement's
    rate (3), ``t_prev``, counters (updates, rejections, consecutive rejections,
    re-initialisations), the last NIS (NaN before the first update), whether the attitude is
    still provisional, and the monitor's (its window, level and counts, the drift test's CUSUMs).  :func:`new_state` gives a fresh one.  The caller
    gives increasing times (the node rejects a stamp in the past).
``P`` (6, 6) the covariance; ``work`` (:data:`N_EST_WORK`, 6) scratch: what the caller's ``P`` and
    ``work`` held before the first step (or after :func:`reset_state`) does not matter.
``out`` (:data:`N_EST_OUT`,)
    Columns ``EO_*``: ``q_hat`` (4), ``omega_hat`` (3), ``b_hat`` (3), ``sigma`` (6: attitude [rad],
    bias [rad/s]), the last NIS, the status (``STATUS_*``), the monitor's figures.  Before initialisation everything but
    the status is NaN.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from gnc_common.compiled import inverse3, jit, quat_multiply, quat_normalize

__all__ = [
    "EstimatorArrays",
    "EO_B", "EO_NIS", "EO_OMEGA", "EO_Q", "EO_SIGMA", "EO_STATUS",
    "EP_B0", "EP_GATE", "EP_INIT", "EP_MAXREJ", "EP_MAX_NORM_ERR", "EP_MAX_RATE", "EP_P0A", "EP_P0B", "EP_Q0", "EP_R", "EP_SU2", "EP_SV2",
    "ES_B", "ES_CONFIRMED", "ES_EPOCH", "ES_INIT", "ES_LASTW", "ES_MON_LEVEL", "ES_MON_MEAN", "ES_MON_NIS", "ES_NIS",
    "ES_N_CONSEC", "ES_N_RECOVER", "ES_N_REINIT", "ES_N_REJ", "ES_N_UPD", "ES_Q", "ES_TPREV",
    "EO_MON_DRIFT", "EO_MON_LEVEL", "EO_MON_MEAN", "EO_MON_NIS", "EO_N_RECOVER", "EO_USABLE", "EP_MON_DRIFT", "EP_MON_MEAN", "EP_MON_NIS", "EP_MON_PERSIST",
    "EP_MON_WINDOW", "EP_RECOVERY_PBB", "EP_TRACKER_STALE", "ES_MON_DRIFT", "ES_MON_OUTSIDE", "ES_N_DRIFT",
    "MON_ERROR", "MON_LEVEL_NAMES", "MON_MAX_WINDOW", "MON_OK", "MON_STALE", "MON_WARN", "N_MEAS", "Y_EPOCH", "reset_state",
    "INIT_FROM_PRIOR", "INIT_FROM_TRACKER",
    "N_EST_OUT", "N_EST_PARAMS", "N_EST_STATE", "N_EST_WORK",
    "SERIES_BELOW",
    "STATUS_INITIALISED", "STATUS_NAMES", "STATUS_NONE", "STATUS_PROPAGATED", "STATUS_REINITIALISED", "STATUS_REJECTED", "STATUS_UPDATED",
    "mekf_step", "new_state", "rotation_quaternion", "rotation_vector", "transition",
]

# ----------------------------------------------------------------------------- layouts

#: Parameter columns (module docstring).
EP_R, EP_SV2, EP_SU2, EP_P0A, EP_P0B, EP_B0, EP_GATE, EP_MAXREJ, EP_INIT, EP_Q0 = 0, 3, 6, 9, 12, 15, 18, 19, 20, 21
EP_MAX_NORM_ERR, EP_MAX_RATE = 25, 26
#: The health monitor's columns: the window [compared tracker samples], the bounds of the window's
#: NIS sum (error low, warning low, warning high, error high), the bounds of the mean test
#: (warning, error), and the bias covariance a failed monitor adds (3, rad^2/s^2).
EP_MON_WINDOW, EP_MON_NIS, EP_MON_MEAN, EP_RECOVERY_PBB = 27, 28, 32, 34
#: The monitor's persistence: consecutive verdicts outside the error band before the monitor fails
#: (>= 1; 1: the first such verdict fails it).
EP_MON_PERSIST = 37
#: The drift test (a CUSUM of each whitened innovation component, both signs): its reference value
#: [innovation sigmas, half the mean shift it is tuned to] and its threshold [innovation sigmas;
#: inf: no drift test].
EP_MON_DRIFT = 38
#: The tracker's silence after which the health is STALE [s] (inf: never): the last tracker sample
#: used is older than this at a step (a blinded tracker: no innovations, so no verdict of the window).
EP_TRACKER_STALE = 40
N_EST_PARAMS = 41
#: Initialisation modes (``prm[EP_INIT]``).
INIT_FROM_TRACKER, INIT_FROM_PRIOR = 0, 1

#: State columns.
ES_INIT, ES_Q, ES_B, ES_LASTW, ES_TPREV = 0, 1, 5, 8, 11
ES_N_UPD, ES_N_REJ, ES_N_CONSEC, ES_N_REINIT, ES_NIS, ES_PROVISIONAL = 12, 13, 14, 15, 16, 17
#: The epoch [s] of the last tracker sample used, whether the estimate is confirmed (usable), and
#: the monitor: samples in its window, the ring's next slot, its level (``MON_*``), the window's NIS
#: sum and mean statistic at its last verdict, consecutive failed verdicts (too large), the
#: recoveries (bias covariance inflations) so far, the consecutive verdicts outside the error band
#: (the persistence count), then the ring (:data:`MON_MAX_WINDOW` rows of the NIS and the whitened
#: innovation (3)).
ES_EPOCH, ES_CONFIRMED, ES_MON_N, ES_MON_HEAD, ES_MON_LEVEL, ES_MON_NIS, ES_MON_MEAN, ES_MON_FAILS, ES_N_RECOVER = 18, 19, 20, 21, 22, 23, 24, 25, 26
ES_MON_OUTSIDE = 27
#: The drift test's six CUSUMs [innovation sigmas]: the upward ones of the whitened innovation's
#: components x, y, z (3), then the downward ones (3); 0 at the start and after the window is emptied.
ES_MON_DRIFT = 28
#: The drift test's alarms so far (each failed the monitor: a recovery or a re-initialisation).
ES_N_DRIFT = 34
ES_MON_RING = 35
#: The longest monitor window [compared tracker samples]: 10 s at 10 Hz, longer than any bias
#: step's detection should take; the ring is part of the state array.
MON_MAX_WINDOW = 100
#: Columns of a ring row: the sample's time [s], its NIS, its whitened innovation (3).
_RING_WIDTH = 5
N_EST_STATE = ES_MON_RING + _RING_WIDTH * MON_MAX_WINDOW

#: Output columns.
EO_Q, EO_OMEGA, EO_B, EO_SIGMA, EO_NIS, EO_STATUS = 0, 4, 7, 10, 16, 17
#: The monitor's level, the window's NIS sum and mean statistic at its last verdict (NaN before
#: the first), whether the estimate may be used (1) or must not (0: initialising, re-initialised
#: and not yet confirmed), and the recoveries so far.
EO_MON_LEVEL, EO_MON_NIS, EO_MON_MEAN, EO_USABLE, EO_N_RECOVER = 18, 19, 20, 21, 22
#: The drift test's statistic after the step: the largest of its six CUSUMs [innovation sigmas]
#: (it fails the monitor above ``prm[EP_MON_DRIFT + 1]``).
EO_MON_DRIFT = 23
N_EST_OUT = 24

#: The health monitor's levels (``out[EO_MON_LEVEL]``), the values of ROS's
#: ``diagnostic_msgs/DiagnosticStatus`` levels OK, WARN and ERROR.
MON_OK, MON_WARN, MON_ERROR = 0, 1, 2
#: The health's level while the tracker is silent past ``EP_TRACKER_STALE``: ROS's
#: ``diagnostic_msgs/DiagnosticStatus`` STALE (no current information), not a verdict of the window.
MON_STALE = 3
MON_LEVEL_NAMES = ("ok", "warn", "error", "stale")
#: Entries of the measurement ``y``: the tracker's quaternion (4), the gyro's rate (3) and the
#: tracker sample's epoch [s] (the time the quaternion was measured).
N_MEAS = 8
Y_EPOCH = 7

#: What a step did (``out[EO_STATUS]``), in :data:`STATUS_NAMES` order.
STATUS_NONE, STATUS_INITIALISED, STATUS_PROPAGATED, STATUS_UPDATED, STATUS_REJECTED, STATUS_REINITIALISED = 0, 1, 2, 3, 4, 5
STATUS_NAMES = ("none", "initialised", "propagated", "updated", "rejected", "reinitialised")

#: Rows of the scratch array, packed: Phi (6), the product Phi P (6), K (6, as 6 x 3 in the first 3
#: columns), I - K H (6), S and S^-1 side by side (3 rows), two vectors, the whitened innovation.
N_EST_WORK = 30
_W_PHI, _W_TMP, _W_K, _W_IKH, _W_S, _W_V = 0, 6, 12, 18, 24, 27
_W_WHITE = 29

#: Below this ``x = |w| h`` [rad], ``x - sin x`` is its series ``x^3/6 - x^5/120 + x^7/5040``
#: (truncation below 1e-17 relative there); above it the closed form has no harmful cancellation
#: (relative error about ``6 eps / x^2`` < 2e-11 of a term itself ~x^2/6 of ``Phi12``).
SERIES_BELOW = 1e-2


def new_state() -> np.ndarray:
    """A fresh filter state (not initialised)."""
    st = np.zeros(N_EST_STATE)
    reset_state(st)
    return st


@jit(inline="always")
def reset_state(st):
    """Make ``st`` a fresh filter state (not initialised), in place: zeros, the NaNs of the
    statistics not computed yet and no tracker epoch used yet."""
    for i in range(st.shape[0]):
        st[i] = 0.0
    st[ES_NIS] = np.nan
    st[ES_MON_NIS] = np.nan
    st[ES_MON_MEAN] = np.nan
    st[ES_EPOCH] = -np.inf


# ----------------------------------------------------------------------------- rotations


@jit(inline="always")
def rotation_quaternion(rx, ry, rz, out):
    """``dq(r)``: the unit quaternion of the rotation vector ``(rx, ry, rz)`` [rad] (scalar last)."""
    angle = np.sqrt((rx * rx + ry * ry) + rz * rz)
    if angle > 0.0:
        s = np.sin(0.5 * angle) / angle
        out[0] = rx * s
        out[1] = ry * s
        out[2] = rz * s
        out[3] = np.cos(0.5 * angle)
    else:
        out[0] = 0.0
        out[1] = 0.0
        out[2] = 0.0
        out[3] = 1.0


@jit(inline="always")
def rotation_vector(q, out):
    """The rotation vector (3,) of the shortest rotation of the unit quaternion ``q`` (scalar
    last): ``2 atan2(|v|, |s|) v / |v|`` with the sign of ``s`` folded into ``v``."""
    sign = 1.0 if q[3] >= 0.0 else -1.0
    vx, vy, vz, s = sign * q[0], sign * q[1], sign * q[2], sign * q[3]
    nv = np.sqrt((vx * vx + vy * vy) + vz * vz)
    f = 2.0 * np.arctan2(nv, s) / nv if nv > 0.0 else 2.0 / s
    out[0] = f * vx
    out[1] = f * vy
    out[2] = f * vz


# ----------------------------------------------------------------------------- steps


@jit
def _initialise(prm, q, st, P):
    for i in range(4):
        st[ES_Q + i] = q[i]
    for i in range(3):
        st[ES_B + i] = prm[EP_B0 + i]
    for r in range(6):
        for c in range(6):
            P[r, c] = 0.0
    for i in range(3):
        P[i, i] = prm[EP_P0A + i]
        P[3 + i, 3 + i] = prm[EP_P0B + i]
    st[ES_INIT] = 1.0


@jit
def _reinitialise_attitude(prm, st, P, q_meas):
    """``q_hat = q_meas``, ``P_aa = R``, ``P_ab = 0``; the bias and its covariance kept (the
    first fresh sample after a provisional start)."""
    for i in range(4):
        st[ES_Q + i] = q_meas[i]
    for a in range(3):
        for b in range(6):
            P[a, b] = 0.0
            P[b, a] = 0.0
        P[a, a] = prm[EP_R + a]


@jit
def _inflate_bias(prm, P, age, axes=(True, True, True)):
    """The recovery (module docstring, "Health monitor"): a bias step of covariance
    ``Q = diag(recovery)`` that happened ``age`` [s] ago, carried to now by the transition's bias
    columns (``Phi12 = -I age`` to first order): ``P_bb += Q``, ``P_ab += -Q age``,
    ``P_aa += Q age^2`` (``age = 0``: the bias alone), about the ``axes`` (x, y, z) given."""
    for i in range(3):
        if not axes[i]:
            continue
        q = prm[EP_RECOVERY_PBB + i]
        P[3 + i, 3 + i] += q
        P[i, 3 + i] -= q * age
        P[3 + i, i] -= q * age
        P[i, i] += q * age * age


@jit
def _clear_monitor(st):
    """Empty the monitor's window (its samples were judged against a covariance that no longer holds),
    its persistence count and the drift test's CUSUMs (the same samples, summed)."""
    st[ES_MON_N] = 0.0
    st[ES_MON_HEAD] = 0.0
    st[ES_MON_OUTSIDE] = 0.0
    for i in range(6):
        st[ES_MON_DRIFT + i] = 0.0


@jit
def _reinitialise_after_failure(prm, st, P, q_meas):
    """Re-initialisation after a lost attitude (the gate's consecutive rejections, or a monitor that
    fails again after its recovery): ``q_hat = q_meas``, ``P_aa = R``, ``P_ab = 0``, the bias
    estimate kept and its covariance inflated by the recovery's (the knowledge of the bias kept, its
    confidence not); the estimate is unconfirmed (not to be used) until a tracker sample is accepted."""
    _reinitialise_attitude(prm, st, P, q_meas)
    _inflate_bias(prm, P, 0.0)
    _clear_monitor(st)
    st[ES_MON_FAILS] = 0.0
    st[ES_MON_LEVEL] = MON_WARN
    st[ES_CONFIRMED] = 0.0
    st[ES_N_REINIT] += 1.0


@jit(inline="always")
def _symmetrise(P):
    for r in range(6):
        for c in range(r + 1, 6):
            m = 0.5 * (P[r, c] + P[c, r])
            P[r, c] = m
            P[c, r] = m


@jit(inline="always")
def _congruence(A, P, T):
    """``P <- A P A^T`` for (6, 6) matrices, sums in index order; ``T`` (6, 6) scratch.  A row's
    (then a column's) six sums side by side (:func:`_row_times`, :func:`_column_times`)."""
    for i in range(6):
        _row_times(A, i, P, T)
    for j in range(6):
        _column_times(T, A, j, P)


@jit(inline="always")
def _row_times(A, i, P, T):
    """Row ``i`` of ``T = A P`` for (6, 6) matrices, each sum ``sum_k A[i, k] P[k, j]`` in index
    order from 0.0.  The six sums run side by side (``k`` outer: six independent chains of
    additions sharing each load of ``A[i, k]``), stored at the end, instead of one entry's chain
    at a time with its store into ``T`` between, which numba's arrays may alias with ``A`` and
    ``P`` (so their entries are loaded again after it).  The same products and sums in the same
    order, so the same bits; the congruence 0.57 of its time in isolation (scalar code both ways:
    docs/performance.md)."""
    t0 = t1 = t2 = t3 = t4 = t5 = 0.0
    for k in range(6):
        a = A[i, k]
        t0 += a * P[k, 0]
        t1 += a * P[k, 1]
        t2 += a * P[k, 2]
        t3 += a * P[k, 3]
        t4 += a * P[k, 4]
        t5 += a * P[k, 5]
    T[i, 0], T[i, 1], T[i, 2], T[i, 3], T[i, 4], T[i, 5] = t0, t1, t2, t3, t4, t5


@jit(inline="always")
def _column_times(T, A, j, P):
    """Column ``j`` of ``P = T A^T`` for (6, 6) matrices, each sum ``sum_k T[i, k] A[j, k]`` in
    index order from 0.0, the six side by side (:func:`_row_times`)."""
    p0 = p1 = p2 = p3 = p4 = p5 = 0.0
    for k in range(6):
        b = A[j, k]
        p0 += T[0, k] * b
        p1 += T[1, k] * b
        p2 += T[2, k] * b
        p3 += T[3, k] * b
        p4 += T[4, k] * b
        p5 += T[5, k] * b
    P[0, j], P[1, j], P[2, j], P[3, j], P[4, j], P[5, j] = p0, p1, p2, p3, p4, p5


@jit(inline="always")
def _transition_congruence(Phi, P, T):
    """``P <- Phi P Phi^T`` for the transition ``Phi`` (6, 6) of :func:`transition`, whose lower
    rows are exactly ``[0, I]``: :func:`_congruence`'s bits with half its products.  Its sums in
    index order skip only terms that are exact zeros: for a finite ``P``, a lower row of
    ``Phi P`` is ``0.0 + P``'s row (a product ``0 * P[k, j]`` adds a signed zero, which leaves a
    sum unchanged but turns ``-0.0`` into ``0.0``), and so is a right-hand column of the result;
    a ``P`` with a non-finite entry takes :func:`_congruence` itself (there ``0 * inf`` is NaN).
    ``T`` (6, 6) scratch."""
    n_bad = 0
    for i in range(6):
        for j in range(6):
            n_bad += 0 if np.isfinite(P[i, j]) else 1
    if n_bad != 0:
        _congruence(Phi, P, T)
        return
    for i in range(3):  # T = Phi P: the upper rows in full, in index order (as _congruence)
        _row_times(Phi, i, P, T)
    for i in range(3, 6):  # the lower rows: [0, I] P
        for j in range(6):
            T[i, j] = 0.0 + P[i, j]
    for j in range(3):  # P = T Phi^T: the left columns in full, the right ones T [0, I]^T
        _column_times(T, Phi, j, P)
    for i in range(6):
        for j in range(3, 6):
            P[i, j] = 0.0 + T[i, j]


@jit(inline="always")
def transition(w0, w1, w2, h, Phi):
    """The error state's transition ``Phi`` (6, 6) over ``h`` [s] at the constant rate ``w`` [rad/s]
    (bias removed), into ``Phi``: the closed form of ``expm(F h)``, ``F = [[-[w x], -I], [0, 0]]``
    (M&C 6.83; step 3 of the module docstring), ``x - sin x`` by its series below
    :data:`SERIES_BELOW`."""
    wn2 = (w0 * w0 + w1 * w1) + w2 * w2
    wn = np.sqrt(wn2)
    x = wn * h
    if wn > 0.0:
        s = np.sin(x) / wn
        half = np.sin(0.5 * x)
        c = 2.0 * half * half / wn2
        if x < SERIES_BELOW:
            x2 = x * x
            d = h * h * h * ((1.0 / 6.0 - x2 / 120.0) + x2 * x2 / 5040.0)
        else:
            d = (x - np.sin(x)) / (wn2 * wn)
    else:  # w = 0: s, c and d multiply W = 0 and W^2 = 0 (Phi = [[I, -I h], [0, I]])
        s = c = d = 0.0
    for r in range(6):
        for col in range(6):
            Phi[r, col] = 0.0
    # W and W^2 written out: W = [[0, -w2, w1], [w2, 0, -w0], [-w1, w0, 0]], W^2 = w w^T - |w|^2 I
    Wm = ((0.0, -w2, w1), (w2, 0.0, -w0), (-w1, w0, 0.0))
    wv = (w0, w1, w2)
    for r in range(3):
        for col in range(3):
            w_rc = Wm[r][col]
            w2_rc = wv[r] * wv[col] - (wn2 if r == col else 0.0)
            eye = 1.0 if r == col else 0.0
            Phi[r, col] = (eye - w_rc * s) + w2_rc * c
            Phi[r, 3 + col] = (w_rc * c - eye * h) - w2_rc * d
        Phi[3 + r, 3 + r] = 1.0


@jit
def _propagate(prm, st, P, w0, w1, w2, h, work):
    """Step 3 of the module docstring: ``q_hat`` and ``P`` over ``h`` at the rate ``w`` (bias removed).

    Compiled on its own, not inlined into :func:`mekf_step` by numba (``inline="always"``): numba's
    inliner runs a callee's untyped passes again and copies its IR twice at each call site, which
    cost this one 2.7 s of a cold ``sappc simulate``'s compile; compiled on its own it takes 1.1 s,
    and the step (one call a sample) showed no loss beyond the measurement's noise (docs/performance.md,
    "The estimator's propagation compiled on its own")."""
    # attitude: q_hat <- normalise(q_hat ⊗ dq(w h))
    dq = work[_W_V]
    rotation_quaternion(w0 * h, w1 * h, w2 * h, dq)
    q = st[ES_Q:ES_Q + 4]
    quat_multiply(q, dq, q)
    quat_normalize(q, q)
    Phi = work[_W_PHI:_W_PHI + 6]
    transition(w0, w1, w2, h, Phi)
    # P <- Phi P Phi^T + Qd
    _transition_congruence(Phi, P, work[_W_TMP:_W_TMP + 6])
    h2 = h * h
    for i in range(3):
        sv2, su2 = prm[EP_SV2 + i], prm[EP_SU2 + i]
        P[i, i] += sv2 * h + su2 * h2 * h / 3.0  # M&C 6.93
        P[i, 3 + i] += -0.5 * su2 * h2
        P[3 + i, i] += -0.5 * su2 * h2
        P[3 + i, 3 + i] += su2 * h
    _symmetrise(P)


@jit
def _update(prm, st, P, q_meas, work, t):
    """Step 4 of the module docstring; returns the status (updated, rejected or re-initialised)."""
    q = st[ES_Q:ES_Q + 4]
    # residual r = rotvec(q_hat^* ⊗ q_meas)
    dq = work[_W_V]
    qc0, qc1, qc2, qc3 = -q[0], -q[1], -q[2], q[3]
    conj = work[_W_V + 1]
    conj[0], conj[1], conj[2], conj[3] = qc0, qc1, qc2, qc3
    quat_multiply(conj, q_meas, dq)
    r = work[_W_V + 1]
    rotation_vector(dq, r)
    r0, r1, r2 = r[0], r[1], r[2]
    # S = P_aa + R and its inverse
    S = work[_W_S:_W_S + 3, 0:3]
    Si = work[_W_S:_W_S + 3, 3:6]
    for a in range(3):
        for b in range(3):
            S[a, b] = P[a, b] + (prm[EP_R + a] if a == b else 0.0)
    inverse3(S, Si)
    # NIS d2 = r^T S^-1 r
    d2 = 0.0
    rv = (r0, r1, r2)
    for a in range(3):
        row = (Si[a, 0] * r0 + Si[a, 1] * r1) + Si[a, 2] * r2
        d2 += rv[a] * row
    st[ES_NIS] = d2
    # the innovation whitened by S's Cholesky factor L (S = L L^T): w = L^-1 r, N(0, I) for a
    # consistent filter
    l00 = np.sqrt(S[0, 0])
    l10 = S[1, 0] / l00
    l20 = S[2, 0] / l00
    l11 = np.sqrt(S[1, 1] - l10 * l10)
    l21 = (S[2, 1] - l20 * l10) / l11
    l22 = np.sqrt(S[2, 2] - (l20 * l20 + l21 * l21))
    white = work[_W_WHITE]
    white[0] = r0 / l00
    white[1] = (r1 - l10 * white[0]) / l11
    white[2] = (r2 - (l20 * white[0] + l21 * white[1])) / l22
    if not d2 <= prm[EP_GATE]:  # a NaN distance is rejected too
        st[ES_N_REJ] += 1.0
        st[ES_N_CONSEC] += 1.0
        if st[ES_N_CONSEC] >= prm[EP_MAXREJ]:
            _reinitialise_after_failure(prm, st, P, q_meas)
            st[ES_N_CONSEC] = 0.0
            return STATUS_REINITIALISED
        return STATUS_REJECTED  # (the monitor judges the innovations the filter uses: an outlier is the gate's)
    # K = P[:, 0:3] S^-1 (6 x 3)
    K = work[_W_K:_W_K + 6, 0:3]
    for i in range(6):
        for b in range(3):
            K[i, b] = (P[i, 0] * Si[0, b] + P[i, 1] * Si[1, b]) + P[i, 2] * Si[2, b]
    # Joseph form: P <- (I - K H) P (I - K H)^T + K R K^T
    A = work[_W_IKH:_W_IKH + 6]
    for i in range(6):
        for j in range(6):
            A[i, j] = (1.0 if i == j else 0.0) - (K[i, j] if j < 3 else 0.0)
    _congruence(A, P, work[_W_TMP:_W_TMP + 6])
    for i in range(6):
        for j in range(6):
            krk = 0.0
            for b in range(3):
                krk += K[i, b] * prm[EP_R + b] * K[j, b]
            P[i, j] += krk
    _symmetrise(P)
    # dx = K r, multiplicative reset
    dx = work[_W_V + 1]
    for i in range(3):
        dx[i] = (K[i, 0] * r0 + K[i, 1] * r1) + K[i, 2] * r2
    for i in range(3):
        st[ES_B + i] += (K[3 + i, 0] * r0 + K[3 + i, 1] * r1) + K[3 + i, 2] * r2
    rotation_quaternion(dx[0], dx[1], dx[2], dq)
    quat_multiply(q, dq, q)
    quat_normalize(q, q)
    st[ES_N_UPD] += 1.0
    st[ES_N_CONSEC] = 0.0
    st[ES_CONFIRMED] = 1.0
    return _monitor(prm, st, P, q_meas, d2, white, t)


@jit
def _monitor(prm, st, P, q_meas, d2, white, t):
    """The health monitor (module docstring): the compared sample's time ``t``, NIS ``d2`` and
    whitened innovation ``white`` (3) into the window and into the drift test's CUSUMs; once the
    window holds ``EP_MON_WINDOW`` samples, a verdict on the window (the level); on a window too
    large for its band (for ``EP_MON_PERSIST`` verdicts in a row) or a CUSUM above its threshold, the
    recovery (about every axis for the window, about the axes whose CUSUM passed its threshold for
    the drift test alone), or, when the monitor fails again before a verdict has cleared it, the
    re-initialisation.  Returns the step's status (updated, or re-initialised)."""
    n_window = int(prm[EP_MON_WINDOW])
    head = int(st[ES_MON_HEAD])
    ring = ES_MON_RING + _RING_WIDTH * head
    st[ring] = t
    st[ring + 1] = d2
    for i in range(3):
        st[ring + 2 + i] = white[i]
    st[ES_MON_HEAD] = float((head + 1) % n_window)
    if st[ES_MON_N] < n_window:
        st[ES_MON_N] += 1.0
    # the drift test: Page's CUSUM of each component of w, upward and downward, less the reference
    # value; a NaN statistic stays NaN (and fails the test)
    reference = prm[EP_MON_DRIFT]
    drift = 0.0
    for i in range(3):
        up = st[ES_MON_DRIFT + i] + white[i] - reference
        down = st[ES_MON_DRIFT + 3 + i] - white[i] - reference
        up = 0.0 if up < 0.0 else up
        down = 0.0 if down < 0.0 else down
        st[ES_MON_DRIFT + i] = up
        st[ES_MON_DRIFT + 3 + i] = down
        if not up <= drift:
            drift = up
        if not down <= drift:
            drift = down
    drifted = not drift <= prm[EP_MON_DRIFT + 1]  # above the threshold (NaN: above)
    n_held = int(st[ES_MON_N])
    full = n_held >= n_window
    if not (full or drifted):
        return STATUS_UPDATED
    t_first = t
    for j in range(n_held):  # the window's oldest time: the slots hold its samples (0 .. n_held - 1 until full)
        t_first = min(t_first, st[ES_MON_RING + _RING_WIDTH * j])
    too_large = False
    persistent = False
    if full:
        nis_sum = 0.0
        m0, m1, m2 = 0.0, 0.0, 0.0
        for j in range(n_window):  # the window in slot order (the sum's order fixed by the slots)
            row = ES_MON_RING + _RING_WIDTH * j
            nis_sum += st[row + 1]
            m0 += st[row + 2]
            m1 += st[row + 3]
            m2 += st[row + 4]
        mean_stat = ((m0 * m0 + m1 * m1) + m2 * m2) / n_window
        st[ES_MON_NIS] = nis_sum
        st[ES_MON_MEAN] = mean_stat
        too_large = not (nis_sum <= prm[EP_MON_NIS + 3] and mean_stat <= prm[EP_MON_MEAN + 1])  # NaN: too large
        outside = too_large or nis_sum < prm[EP_MON_NIS]  # outside the error band
        if outside:
            st[ES_MON_OUTSIDE] += 1.0
        else:
            st[ES_MON_OUTSIDE] = 0.0
        persistent = st[ES_MON_OUTSIDE] >= prm[EP_MON_PERSIST]  # the persistence count reached: the monitor fails
        if persistent:
            st[ES_MON_LEVEL] = MON_ERROR
        elif outside or nis_sum < prm[EP_MON_NIS + 1] or nis_sum > prm[EP_MON_NIS + 2] or mean_stat > prm[EP_MON_MEAN]:
            st[ES_MON_LEVEL] = MON_WARN
        else:
            st[ES_MON_LEVEL] = MON_OK
        if not too_large:
            st[ES_MON_FAILS] = 0.0
    if drifted:
        st[ES_MON_LEVEL] = MON_ERROR
        st[ES_N_DRIFT] += 1.0
    elif not (too_large and persistent):  # no failure: inside, low, or outside not yet for long enough (a warning)
        return STATUS_UPDATED
    st[ES_MON_FAILS] += 1.0
    if st[ES_MON_FAILS] >= 2.0:  # the recovery did not restore consistency: the attitude is lost
        _reinitialise_after_failure(prm, st, P, q_meas)
        st[ES_N_CONSEC] = 0.0
        return STATUS_REINITIALISED
    if too_large and persistent:  # the window failed: a step about any axis
        _inflate_bias(prm, P, t - t_first)
    else:  # the drift test alone: about the axes whose CUSUMs are above the threshold
        h = prm[EP_MON_DRIFT + 1]
        axes = (not (st[ES_MON_DRIFT] <= h and st[ES_MON_DRIFT + 3] <= h), not (st[ES_MON_DRIFT + 1] <= h and st[ES_MON_DRIFT + 4] <= h),
                not (st[ES_MON_DRIFT + 2] <= h and st[ES_MON_DRIFT + 5] <= h))
        _inflate_bias(prm, P, t - t_first, axes)
    _clear_monitor(st)
    st[ES_N_RECOVER] += 1.0
    return STATUS_UPDATED


@jit
def mekf_step(prm, t, y, st, P, work, out):
    """One step of the filter at time ``t`` [s] with the measurement ``y`` (:data:`N_MEAS`,)
    ``(q_meas (4), omega_meas (3), epoch)``, ``epoch`` [s] the time the tracker measured ``q_meas``
    (module docstring); writes ``out`` and returns the status (``STATUS_*``)."""
    norm = np.sqrt(((y[0] * y[0] + y[1] * y[1]) + y[2] * y[2]) + y[3] * y[3])
    rate = np.sqrt((y[4] * y[4] + y[5] * y[5]) + y[6] * y[6])
    if not (abs(norm - 1.0) <= prm[EP_MAX_NORM_ERR] and rate <= prm[EP_MAX_RATE] and y[Y_EPOCH] <= t):  # no measurement (a NaN fails too)
        for j in range(N_EST_OUT):
            out[j] = np.nan
        out[EO_STATUS] = STATUS_NONE
        return STATUS_NONE
    epoch = y[Y_EPOCH]
    new = epoch > st[ES_EPOCH]  # a tracker sample not used before (its epoch, never its value)
    fresh = epoch >= t  # measured at this step's time
    status = STATUS_NONE
    if st[ES_INIT] == 0.0:
        _initialise(prm, prm[EP_Q0:EP_Q0 + 4] if prm[EP_INIT] == INIT_FROM_PRIOR else y[0:4], st, P)
        status = STATUS_INITIALISED
        if prm[EP_INIT] == INIT_FROM_PRIOR:
            status = _update(prm, st, P, y[0:4], work, t)
        else:  # a tracker measurement: an estimate (of now, or provisional: up to one tracker period old,
            st[ES_CONFIRMED] = 1.0  # replaced by the first new sample)
            if not fresh:
                st[ES_PROVISIONAL] = 1.0
    else:
        h = t - st[ES_TPREV]
        b = st[ES_B:ES_B + 3]
        w0 = 0.5 * (st[ES_LASTW] + y[4]) - b[0]
        w1 = 0.5 * (st[ES_LASTW + 1] + y[5]) - b[1]
        w2 = 0.5 * (st[ES_LASTW + 2] + y[6]) - b[2]
        _propagate(prm, st, P, w0, w1, w2, h, work)
        status = STATUS_PROPAGATED
        if new and st[ES_PROVISIONAL] != 0.0:  # the first new sample replaces the provisional attitude
            _reinitialise_attitude(prm, st, P, y[0:4])
            st[ES_PROVISIONAL] = 0.0
            st[ES_CONFIRMED] = 1.0
            status = STATUS_INITIALISED
        elif new:
            status = _update(prm, st, P, y[0:4], work, t)
    if new:
        st[ES_EPOCH] = epoch
    for i in range(3):
        st[ES_LASTW + i] = y[4 + i]
    st[ES_TPREV] = t
    # (a measurement always leaves the filter initialised: the branch above initialises it)
    for i in range(4):
        out[EO_Q + i] = st[ES_Q + i]
    for i in range(3):
        out[EO_B + i] = st[ES_B + i]
        out[EO_OMEGA + i] = y[4 + i] - st[ES_B + i]
    for i in range(6):
        out[EO_SIGMA + i] = np.sqrt(P[i, i])
    out[EO_NIS] = st[ES_NIS]
    # the window's verdict, or STALE while the tracker has been silent too long (out only: the
    # monitor's own level is unchanged, and comes back with the next tracker sample)
    out[EO_MON_LEVEL] = MON_STALE if t - st[ES_EPOCH] > prm[EP_TRACKER_STALE] else st[ES_MON_LEVEL]
    out[EO_MON_NIS] = st[ES_MON_NIS]
    out[EO_MON_MEAN] = st[ES_MON_MEAN]
    out[EO_USABLE] = st[ES_CONFIRMED]
    out[EO_N_RECOVER] = st[ES_N_RECOVER]
    drift = 0.0
    for i in range(6):
        if not st[ES_MON_DRIFT + i] <= drift:
            drift = st[ES_MON_DRIFT + i]
    out[EO_MON_DRIFT] = drift
    out[EO_STATUS] = status
    return status


class EstimatorArrays(NamedTuple):
    """The estimator of a batch, as the whole-run loop takes it: ``prm`` (N, :data:`N_EST_PARAMS`)
    each run's filter parameters, or (N, 0) for none (the controller is fed the measurements).
    Packed by :func:`.config.pack_estimator`."""

    prm: NDArray[np.float64]

    @staticmethod
    def run_axes() -> dict[str, int]:
        """The axis of runs of each per-run field (the others are shared by every run)."""
        return {"prm": 0}

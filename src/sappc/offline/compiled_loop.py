"""The offline closed loop in compiled code: whole runs, one at a time or many in parallel.

Timing (the same as the lockstep ROS 2 graph): at ``t_k = k dt`` the plant's state is sampled
(the sensors measure it, the estimator filters the measurement), the controller computes the torque
from it and the reference at ``t_k``, the disturbance is sampled at ``t_k``, and the plant
integrates over ``[t_k, t_k+1]`` with both held (zero-order hold).  Samples ``k = 0 .. n_steps``;
the torque of the last sample is recorded but not applied.

The models of the loop, each packing its own compiled arrays
-------------------------------------------------------------
Every model hands the loop one ``NamedTuple`` of arrays, made by its own ``pack_*`` function in its
own room, and the kernels that use it; per-run arrays carry the batch's run axis (the tuple's
``run_axes`` says which axis), the others are shared by every run:

===================  ==========================================================  =========================================
model                arrays (packed by)                                          kernels the loop calls
===================  ==========================================================  =========================================
grid and reference   :class:`LoopGrid` (:func:`prepare`)                         the reference tables
controller           ``ControllerArrays`` (:func:`sappc_controller.core.packing.pack_controller`)  ``controller_step``; the input check
plant (rigid body)   ``PlantArrays`` (:func:`spacecraft_sim.core.dynamics.pack_plant`)              ``propagate``
actuator             ``ActuatorArrays`` (:func:`spacecraft_sim.core.wheels.pack_actuator`)          ``wheel_torques``, ``propagate_wheels_into``
sensors              ``SensorArrays`` (:func:`spacecraft_sim.core.sensors.pack_sensors`)            ``measure_run``
estimator            ``EstimatorArrays`` (:func:`sappc_estimator.core.config.pack_estimator`)       ``mekf_step``
disturbance          ``DisturbanceArrays`` (:func:`spacecraft_sim.core.disturbance.pack_disturbance`)  ``disturbance_at``
faults               ``FaultArrays`` (:func:`spacecraft_sim.core.faults.pack_faults`)               ``fault_sensor``, ``fault_reference``, ``fault_actuator``
environment          ``EnvironmentArrays`` (:func:`spacecraft_sim.core.environment.pack_environment`)  ``field_of``, ``measured_field_of``, ``torque_of``
momentum management  ``MomentumArrays`` (:func:`sappc_momentum.core.law.pack_momentum`)              ``momentum_management_step``
flight modes         ``ModeArrays`` (:func:`sappc_modes.core.packing.pack_modes`)                   ``mode_step``, ``bdot_step``
===================  ==========================================================  =========================================

Adding a model is its room (its arrays, its ``pack_*``, its kernels) and one registration here: a
field of :class:`CompiledInputs`, its ``pack_*`` call in :func:`prepare` and its kernels' call at
their place in :func:`_run_one` (the closed loop's order is the one thing the loop knows); what its
kernels carry from one sample to the next goes into :class:`LoopState`, and its per-sample arrays,
if any, are made per block (:class:`SampleMaker`, :meth:`CompiledInputs.blocks`).

One code path: :func:`_run_one` is the time loop of one run over a block of samples (the whole run
is one block, or the blocks follow one another: :class:`LoopState` carries the run between them,
so the run in blocks is the run in one call, bit for bit); :func:`run_batch_kernel` calls it for
every run in a ``prange`` (runs are independent: each has its own parameters, state and scratch
arrays), and one run calls it from Python (:func:`run_single`) with the same argument types, so run
``k`` of a batch is the run alone, bit for bit (and a one-run command compiles ``_run_one`` alone:
its ~9 s of parallel lowering is the batch kernel's).  A campaign's runs go eight at a time in SIMD
lanes where :mod:`sappc.offline.lanes` covers the scenario (``CompiledInputs.lanes``): the same
scalar pieces of the law, the plant and the input check in the same order, the libm calls
libmvec's (docs/parity.md, "Campaign runs in SIMD lanes"), the flight stack's pieces run by run
(:func:`measure_sample`, :func:`estimate_sample`, :func:`plant_step`, :func:`record_wheels`,
:func:`record_estimate`, which :func:`_run_one` calls too); a run they cannot answer as the node
would goes through :func:`_run_one`.  :func:`run_batch` runs a batch in one block
(its whole record), :func:`run_blocks` a block of :data:`BLOCK_RUN_SAMPLES` run-samples at a time
(memory flat in the run's length: docs/design/streaming.md).

What every run shares (reference, and the disturbance when no run changes it) is computed once per
block: the reference quaternion by the compiled RK4 of
:meth:`spacecraft_sim.core.reference.PaperReference.sample` (continued from block to block), its
rates by the rate kernel; a shared disturbance becomes a (B, 3) table.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import math
import os
import sys
from dataclasses import dataclass
from collections.abc import Callable, Iterator, Sequence
from typing import Any, NamedTuple

import numpy as np
from numba import prange

from gnc_common import collector
from gnc_common.compiled import CACHE_DIR, error_quaternion, jit, jit_parallel
from sappc_controller.core.base import SingularStartError
from gnc_common.input_check import REJECT_REASONS, sample_verdicts
from sappc_controller.core.kernels import N_COEF, N_OUT, N_STATE, N_WORK, O_BL, O_BU, O_CMD, O_EPS, O_QBR, O_RHO, O_SAT, O_TORQUE, O_V, O_Z, S_T0
from sappc_controller.core.kernels import ControllerArrays, controller_step, mrp_feedback_step
from sappc_controller.core.mrp_feedback import hold_and_safe_params
from sappc_controller.core.packing import pack_controller, start_coef
from sappc_estimator.core.config import pack_estimator
from sappc_estimator.core.mekf import EO_B, EO_MON_LEVEL, EO_MON_MEAN, EO_MON_NIS, EO_N_RECOVER, EO_NIS, EO_OMEGA, EO_Q, EO_USABLE
from sappc_estimator.core.mekf import N_EST_OUT, N_EST_STATE, N_EST_WORK, N_MEAS, STATUS_NONE, Y_EPOCH
from sappc_estimator.core.mekf import EstimatorArrays, mekf_step, reset_state
from spacecraft_sim.core.disturbance import pack_disturbance
from spacecraft_sim.core.dynamics import pack_plant
from spacecraft_sim.core.faults import SensorNoise, noise_draws, pack_faults
from spacecraft_sim.core.kernels import DisturbanceArrays, FaultArrays, PlantArrays, disturbance_at, propagate
from spacecraft_sim.core.kernels import N_FVALUE, fault_actuator, fault_rate_bias, fault_reference, fault_sensor
from spacecraft_sim.core.sensors import N_SENSOR_DRAWS, S_BIAS0, SensorArrays, measure_run, pack_sensors, white_noise_params
from spacecraft_sim.core.wheels import ActuatorArrays, ReactionWheels, allocation_matrix, pack_actuator, propagate_wheels_into, wheel_speeds_into
from spacecraft_sim.core.wheels import wheel_torques
from spacecraft_sim.core.magnetometer import magnetometer_generator
from spacecraft_sim.core.environment import EnvironmentArrays, field_of, locked_inertia, measured_field_of, pack_environment, torque_of
from sappc_momentum.core.law import N_MM_WORK, MomentumArrays, dipole_mapping, momentum_management_step, pack_momentum
from sappc_modes.core.bdot import N_BDOT_STATE, bdot_step, reset_bdot_state
from sappc_modes.core.modes import DETUMBLE, HEALTH_OK, HOLD, IN_ERROR, IN_HEALTH, IN_INHIBIT, IN_LOST, IN_RATE, IN_REQUEST, IN_SIGMA, IN_WHEEL, R_NONE
from sappc_modes.core.modes import S_MODE
from sappc_modes.core.modes import SAFE, TRACK, attitude_error_angle, mode_step, sigma_of_covariance, wheel_speed_fraction
from sappc_modes.core.modes import N_INPUTS as N_MODE_INPUTS, N_STATE as N_MODE_STATE
from sappc_modes.core.packing import MAX_RESTARTS, MR_ENTRY, MR_SAMPLES, MR_TRANSITIONS, N_MODE_RUN, ModeArrays, pack_modes
from sappc_momentum.core.predictive import MS_TLAST, MS_TNEXT, N_MM_STATE
from sappc_msgs_py.contract import ANSWER_COMMANDED, ANSWER_INACTIVE, ANSWER_NAMES, ANSWER_HELD, ANSWER_REFUSED, ANSWER_WATCHDOG_ZERO
from sappc_msgs_py.contract import ESTIMATOR_NO_INPUT
from sappc_msgs_py.convert import seconds_to_ns, seconds_to_ns_array

from sappc.evaluation.estimation import EstimateHistory
from sappc.evaluation.history import History
from sappc.evaluation.metrics import FLIGHT_METRICS_PER_RUN, MetricsAccumulator, SampleGrid
from gnc_common.validation import ConfigError
from sappc.scenario import Scenario

__all__ = ["BLOCK_RUN_SAMPLES", "CAMPAIGN_GROUPS", "CompiledInputs", "CompiledRun", "LoopGrid", "LoopRecord", "LoopState", "NoiseStreams", "SampleMaker",
           "cache_is_warm", "ensure_compiled", "lanes_refusal", "prepare", "run_batch", "run_blocks", "run_single", "simulate_compiled", "trajectory_samples", "warm_up"]

#: Nanoseconds per second: the controller's and the estimator's time is each sample's stamp in
#: seconds, as their nodes compute it from the same integer stamps (``k dt`` and
#: ``round(k dt 1e9) / 1e9`` differ in the last bit at 1 sample in 7; the plant, the sensors, the
#: faults and the disturbance use ``k dt``, as their nodes do).
_NS_PER_S = 1_000_000_000
#: Columns of the estimator's record (:attr:`LoopRecord.estimate`): the attitude estimate (4), the
#: rate estimate (3), the bias estimate (3), the covariance (36, row major), the last NIS, the
#: step's status, the gyro's true bias in the sample's rate (3: its walk and every sensor fault's
#: rate bias), the health monitor's level, window NIS sum and mean statistic, whether the estimate
#: was usable (1) or withheld (0), the recoveries so far; NaN where the filter had no estimate (the
#: node's "no data"; the attitude and rate estimates also where it was withheld), the true bias
#: always.
R_Q, R_OMEGA, R_B, R_P, R_NIS, R_STATUS, R_BTRUE = 0, 4, 7, 10, 46, 47, 48
R_MON_LEVEL, R_MON_NIS, R_MON_MEAN, R_USABLE, R_N_RECOVER = 51, 52, 53, 54, 55
N_EST_RECORD = 56


class LoopGrid(NamedTuple):
    """The samples and the reference every run of a batch shares, over a block of samples (B of
    them, the whole run or a part): ``t`` (B,) [s], ``t_ns`` (B,) the plant's stamps [ns], ``dt``
    [s], ``ref_q`` (B, 4), ``ref_w`` and ``ref_wd`` (B, 3); ``n_samples`` the run's samples T (the
    last one's torque is not applied)."""

    t: np.ndarray
    t_ns: np.ndarray
    dt: float
    ref_q: np.ndarray
    ref_w: np.ndarray
    ref_wd: np.ndarray
    n_samples: int

    @staticmethod
    def run_axes() -> dict[str, int]:
        """The axis of runs of each per-run field (the others are shared by every run)."""
        return {}


class LoopRecord(NamedTuple):
    """What the loop writes, every ``stride`` samples (T_rec of them) of each run: ``out`` (N, T_rec,
    N_OUT, 4) the controller's rows as published, ``x`` (N, T_rec, 7) the true state, ``d`` (N,
    T_rec, 3) the disturbance, ``status`` (N, T_rec) int8 the answers (``ANSWER_*``), ``wheels`` (N,
    T_rec, W, 2) each wheel's speed [rad/s] and motor torque [N m], ``estimate`` (N, T_rec,
    :data:`N_EST_RECORD` or 0) the estimator's record (``R_*``); per run: ``rejected`` (N, 2) the
    inputs the controller rejected (invalid, implausible), ``x_final`` (N, 7 + W), ``start`` (N, 7)
    the first valid sample, or a restart's pause (:func:`_run_one`); ``env`` (N, T_rec, 9 + M or 0) with an orbit, the true
    field ``B_B`` [T], the flight software's (measured) field [T], the environment's and the rods'
    torque ``L_env_B`` [N m] and the rods' dipole commands (M) [A m^2] (:func:`_run_one`); with modes,
    ``mode`` (N, T_rec, 2 or 0) int8 the mode flown and the reason of the transition taken at the
    sample (``R_*`` of :mod:`sappc_modes.core.modes`, ``R_NONE`` for none), and per run
    ``mode_run`` (N, :data:`~sappc_modes.core.packing.N_MODE_RUN` or 0) each mode's first entry
    [s], its samples and the transitions (``MR_*``)."""

    out: np.ndarray
    x: np.ndarray
    d: np.ndarray
    status: np.ndarray
    wheels: np.ndarray
    estimate: np.ndarray
    rejected: np.ndarray
    x_final: np.ndarray
    start: np.ndarray
    env: np.ndarray
    mode: np.ndarray
    mode_run: np.ndarray


#: Columns of :attr:`LoopState.flags` (int64): whether the controller has started (its first valid
#: sample), whether it has a last valid answer, that answer's stamp [ns], whether the filter gave
#: the last sample its figures, the controller's starts so far (flight modes: one per entry into TRACK).
L_STARTED, L_HAS_LAST, L_LAST_STATE_NS, L_HAS_ESTIMATE, L_N_STARTS = 0, 1, 2, 3, 4
N_LOOP_FLAGS = 5
#: Rows of :attr:`LoopState.vec3` (3-vectors): the controller's last answer, the torque through the
#: actuator link and the delivered one [N m], the plant's held input and the disturbance [N m],
#: the gyro's bias and its true bias in the sample's rate [rad/s], the orbit's position [m], the
#: field in the inertial and body frames and as measured [T], the environment's torque and the
#: total disturbance [N m], the torque functions' scratch, the wheels' body torque [N m] and the
#: feed-forward's rate [rad/s], B-dot's body dipole [A m^2] (modes), zero (the hold's reference rate
#: and its derivative).
(V_CMD, V_U_CMD, V_U_LAST, V_U, V_D, V_BIAS, V_BIAS_K, V_R_N, V_B_N, V_B_B, V_B_MEAS, V_L_ENV, V_D_TOT, V_R_B_TMP, V_L_MTB_TMP, V_TAU_W,
 V_OMEGA_FF, V_M_B, V_ZERO) = range(19)
N_LOOP_VEC3 = 19


class LoopState(NamedTuple):
    """Everything :func:`_run_one` carries from one sample to the next, one row per run (axis 0):
    every array the loop keeps across samples (its scratch too, so that no analysis of what is
    read before it is written can be wrong) and its scalars (``flags``, ``epoch``: the latest
    tracker epoch delivered to the filter [s]).  A few hundred float64 a run: made zero by
    :func:`_state`, initialised by the run's first block (:func:`_initial_state`).  With modes:
    the mode manager's state and inputs, the hold law's controller state, scratch and rows, the
    attitude held (NaN until HOLD's first valid sample), the unit quaternion (SAFE's attitude and
    reference), B-dot's state and the error quaternion of the mode manager's error input."""

    flags: np.ndarray
    epoch: np.ndarray
    vec3: np.ndarray
    ctrl: np.ndarray
    work: np.ndarray
    out: np.ndarray
    pub: np.ndarray
    x: np.ndarray
    uw: np.ndarray
    wspeed: np.ndarray
    wwork: np.ndarray
    wtmp: np.ndarray
    y: np.ndarray
    held_q: np.ndarray
    ye: np.ndarray
    yc: np.ndarray
    est: np.ndarray
    P: np.ndarray
    ework: np.ndarray
    eout: np.ndarray
    fcount: np.ndarray
    fbuf: np.ndarray
    m_cmd: np.ndarray
    mtmp: np.ndarray
    mst: np.ndarray
    q_ff: np.ndarray
    mode: np.ndarray
    mode_in: np.ndarray
    hctrl: np.ndarray
    hwork: np.ndarray
    hout: np.ndarray
    q_hold: np.ndarray
    q_unit: np.ndarray
    bdot: np.ndarray
    q_err: np.ndarray


@jit(inline="always")
def measure_sample(sens, n, k, kb, t, t_stamp_s, measuring, x, held_q, bias, y):
    """The sensors' part of run ``n``'s sample ``k`` (:func:`_run_one`, the lanes' flight stage):
    with draws, the star tracker's and the gyro's measurement of the true state ``x`` into ``y``
    (:func:`~spacecraft_sim.core.sensors.measure_run`), else the true state, measured now."""
    if measuring:
        measure_run(sens, n, k, kb, t, t_stamp_s, x, held_q, bias, y)
    else:  # exact measurements: the true state, measured now
        for i in range(7):
            y[i] = x[i]
        y[Y_EPOCH] = t_stamp_s


@jit(inline="always")
def estimate_sample(eprm, t_stamp_s, state_in, y, delivered_epoch, ye, est_st, P, ework, eout, yc):
    """The estimator's part of a sample (:func:`_run_one`, the lanes' flight stage): a delivered
    measurement ``y`` (``state_in``) goes through :func:`~sappc_estimator.core.mekf.mekf_step` with
    the quaternion of the tracker sample of the latest new epoch (``ye``; ``delivered_epoch`` the
    latest so far), and the estimate into ``yc``; returns whether the controller is given it (a
    confirmed estimate), whether the filter had figures, the filter's status and the epoch."""
    est_status = ESTIMATOR_NO_INPUT  # no measurement delivered: no filter step (the node's code)
    if state_in:
        if y[Y_EPOCH] > delivered_epoch:
            delivered_epoch = y[Y_EPOCH]
            for i in range(4):
                ye[i] = y[i]
        for i in range(4, N_MEAS):
            ye[i] = y[i]
        est_status = mekf_step(eprm, t_stamp_s, ye, est_st, P, ework, eout)
    has_estimate = est_status != STATUS_NONE and est_status != ESTIMATOR_NO_INPUT and eout[EO_USABLE] >= 0.0  # (NaN: not initialised)
    # an estimate the filter has not confirmed is withheld: "no data" for the controller
    given = has_estimate and eout[EO_USABLE] == 1.0
    for i in range(4):
        yc[i] = eout[EO_Q + i]
    for i in range(3):
        yc[4 + i] = eout[EO_OMEGA + i]
    return given, has_estimate, est_status, delivered_epoch


@jit(inline="always")
def record_wheels(rw, x, G, wprm, wspeed, uw):
    """A sample's wheel record ``rw`` (W, 2) (:attr:`LoopRecord.wheels`): each wheel's speed
    relative to the body (from the state ``x``) and its motor torque ``uw``."""
    wheel_speeds_into(x, G, wprm, wspeed)
    for i in range(rw.shape[0]):
        rw[i, 0] = wspeed[i]
        rw[i, 1] = uw[i]


@jit(inline="always")
def record_estimate(e, has_estimate, state_in, eout, P, est_status, bias_k):
    """A sample's estimator record ``e`` (:data:`N_EST_RECORD`; the ``R_*`` columns)."""
    for i in range(N_EST_RECORD):
        e[i] = np.nan
    if has_estimate:  # the filter's figures (else the node's "no data")
        if state_in:  # the estimate itself, unless withheld
            for i in range(4):
                e[R_Q + i] = eout[EO_Q + i]
            for i in range(3):
                e[R_OMEGA + i] = eout[EO_OMEGA + i]
        for i in range(3):
            e[R_B + i] = eout[EO_B + i]
        for a in range(6):
            for b in range(6):
                e[R_P + 6 * a + b] = P[a, b]
        e[R_NIS] = eout[EO_NIS]
        e[R_MON_LEVEL] = eout[EO_MON_LEVEL]
        e[R_MON_NIS] = eout[EO_MON_NIS]
        e[R_MON_MEAN] = eout[EO_MON_MEAN]
        e[R_USABLE] = eout[EO_USABLE]
        e[R_N_RECOVER] = eout[EO_N_RECOVER]
    e[R_STATUS] = est_status
    for i in range(3):
        e[R_BTRUE + i] = bias_k[i]


@jit(inline="always")
def plant_step(x, u_last, uw, d, dt, max_torque, substeps, J, J_inv, G, wprm, wwork, wtmp, u):
    """The plant over ``[t_k, t_k+1]`` with its inputs held: without wheels the delivered torque
    ``u_last`` clipped to the actuator's ``max_torque`` plus the disturbance ``d`` (``u`` (3,)
    scratch), with wheels their motor torques ``uw`` and ``d``."""
    if wprm.shape[0] == 0:
        for i in range(3):  # control (clipped by the actuator) + disturbance, held over [t_k, t_k+1]
            u[i] = min(max(u_last[i], -max_torque), max_torque) + d[i]
        propagate(x, u, dt, substeps, J, J_inv)
    else:
        propagate_wheels_into(x, uw, d, dt, substeps, J, J_inv, G, wprm, wwork, wtmp)


@jit
def _run_one(n, r, probe, stride, k_lo, grid, ctrl, plant, act, sens, est, dist, faults, env, mm, md, rec, st):
    """The time loop of run ``n`` of the models' arrays (module docstring) over one block of samples,
    ``k = k_lo .. k_lo + B - 1`` (``B`` the block's samples, ``grid.t``'s length: the per-sample
    arrays of ``grid`` and of the models hold the block's rows), written at index ``r`` of ``rec``
    (:class:`LoopRecord`: the block's record), every ``stride`` samples (``stride = 0``: no
    histories; ``k_lo`` a multiple of ``stride``).  Everything the loop carries from one sample to
    the next is in row ``r`` of ``st`` (:class:`LoopState`): the block starting at ``k_lo = 0``
    initialises it, each later block continues it, so a run in blocks is the run in one block, bit
    for bit.

    Sensors (:func:`~spacecraft_sim.core.sensors.measure_run`): with draws, the controller's input
    is the star tracker's and the gyro's measurement of the true state, else the true state.
    Faults (:class:`~spacecraft_sim.core.kernels.FaultArrays`): the measurement and the reference go
    through :func:`~spacecraft_sim.core.kernels.fault_sensor` and ``fault_reference``, the answer
    through ``fault_actuator``.  Estimator (:class:`~sappc_estimator.core.mekf.EstimatorArrays` with
    parameters): a delivered measurement goes through
    :func:`~sappc_estimator.core.mekf.mekf_step` at the sample's stamp in seconds, and the
    controller's input is the estimate; a sample the filter gives no estimate for (no measurement,
    not initialised) reaches the controller as "no data", as the estimator node publishes it.

    The controller answers as the node does in lockstep (the ``ANSWER_*`` codes of
    :mod:`sappc_msgs_py.contract`).  A sample is valid when its five inputs arrived (a dropout
    delivers none of the state's two or the reference's three) and pass the node's input check
    (:func:`gnc_common.input_check.sample_verdicts` with ``ctrl.bounds``; each rejected
    input counted into ``rec.rejected``: invalid, implausible; the "no data" of a dropout or of the
    estimator is no rejected input, as on the node).  A valid sample is computed;
    without one, zero torque (the watchdog) when no valid state has been computed yet or the last
    one is more than ``ctrl.stale_ns`` older than the sample (stamps ``grid.t_ns``), else its last
    answer again (held).  The plant applies the delivered torque clipped to the actuator's limit.

    The run's start (docs/how-to/faults.md, "A run starts at the first valid sample"): the controller starts at its **first
    valid sample**, whose time is the performance function's time origin (``S_T0``) and whose error
    fixes ``ctrl.coef`` (:func:`sappc_controller.core.packing.start_coef`, in Python: the RPF's
    coefficients need scipy).  Everything before that sample is independent of ``coef``, so a first
    pass with ``probe`` true finds it: it returns at the first valid sample with ``rec.start[r]`` =
    (its index, its time, its error quaternion ``q_BR`` of the controller's input attitude against
    the reference, by the kernels' own formula), ``start[0] = -1`` when the run has none;
    :func:`_started` then computes ``coef``, and the second pass (``probe`` false) runs the loop.

    Recorded, as a bag of the same run records it: the *true* error quaternion and state (the
    metrics describe the real attitude), the delivered torque, and the controller's rows as last
    published (a zero answer publishes zero command and saturation and keeps the previous rows; a
    held answer repeats them; before the first computed sample the performance function, band,
    ``eps``, ``z`` and ``V`` rows are NaN: the controller has none yet, as the node publishes).

    Actuator (:class:`~spacecraft_sim.core.wheels.ActuatorArrays`): with no wheels the ideal one, the
    delivered torque clipped to ``act.max_torque_Nm`` per axis; with wheels (``x0`` then holds
    their momenta), the delivered torque is the wheels' command:
    :func:`~spacecraft_sim.core.wheels.wheel_torques` (allocation, motor and speed limits) and
    :func:`~spacecraft_sim.core.wheels.propagate_wheels_into`; ``rec.wheels`` records each wheel's
    speed relative to the body and its motor torque at every sample (the torque of the last sample
    computed, not applied).

    Orbit (:class:`~spacecraft_sim.core.environment.EnvironmentArrays` with an orbit): at each
    sample the true field ``B_B`` (:func:`~spacecraft_sim.core.environment.environment_field`); with
    momentum management (:class:`~sappc_momentum.core.law.MomentumArrays`) the flight software
    turns the wheels' speeds and the field (the magnetometer's,
    :func:`~spacecraft_sim.core.environment.environment_measure_field`, or the true one without a
    magnetometer) into the rods' dipoles and the wheels' torque, the controller's minus the rods'
    (:func:`~sappc_momentum.core.law.momentum_management_step`),
    which the wheels' torque path then delivers; the environment's torque (gravity gradient, rods:
    :func:`~spacecraft_sim.core.environment.environment_torque_B`) is held beside the disturbance.

    Flight modes (:class:`~sappc_modes.core.packing.ModeArrays` with guards; docs/design/modes.md):
    each sample, after the estimator, :func:`~sappc_modes.core.modes.mode_step` takes the gyro's
    rate magnitude (NaN when no measurement was delivered), the estimator's health level and the
    largest attitude 1-sigma of its covariance (NaN without figures; without an estimator OK and
    0 while measurements arrive), the largest wheel speed as a fraction of its limit, the
    scenario's ground requests (``ModeArrays.requests``); the loss of control and the ground's
    inhibits are not modelled offline (0, none).  The
    scenario's controller computes only in TRACK, where it starts at its first valid sample (the
    start above, whose probe runs the modes too); outside TRACK its answer is ``ANSWER_INACTIVE``
    and the mode's law commands: DETUMBLE zero torque on the wheels and B-dot
    (:func:`~sappc_modes.core.bdot.bdot_step`, on each new magnetometer sample, held between) on
    the rods through :func:`~sappc_momentum.core.law.dipole_mapping` instead of momentum
    management; HOLD the MRP feedback law on the controller's input (the estimate) towards the
    attitude of its first valid sample in HOLD, zero rate (or, ``hold_reference``, towards the
    scenario's reference with its rates: an acquisition; the mode manager then also reads the
    estimate's error against the reference, ``IN_ERROR``; the ground's requests of the scenario,
    ``IN_REQUEST``, each at the first sample at or after its time); SAFE the same law with no attitude gain
    on the gyro's rate (the attitude is not used).  Each entry into HOLD or SAFE restarts the law's
    state, each into DETUMBLE B-dot's.  Each later entry into TRACK **restarts** the controller (up
    to :data:`MAX_RESTARTS` times): its state afresh, its time origin and start constants from its
    first valid sample there, as at the run's start; those constants come from Python (the RPF
    needs scipy), so a run that meets a restart whose constants are not known yet pauses there: it
    records the restart in ``rec.start`` (its sample, time, error quaternion and the start's index)
    and returns, and :func:`_loop` computes them and runs the block again from its state before
    (:data:`MAX_RESTARTS`; ``ModeArrays.restart_coef``, ``starts_known``)."""
    # the controller
    kind, prm = ctrl.kind, ctrl.prm[n]
    start = rec.start[r]
    rejected = rec.rejected[r]
    if k_lo == 0:
        _initial_state(n, r, plant, sens, est, md, st, rec)
    elif probe and start[0] >= 0.0:  # its start found in an earlier block
        return
    # what the loop carries from one sample to the next: this run's rows of st (LoopState)
    flags, vec3 = st.flags[r], st.vec3[r]
    started = flags[L_STARTED] != 0  # the first valid sample fixes the time origin (S_T0)
    has_last = flags[L_HAS_LAST] != 0
    last_state_ns = flags[L_LAST_STATE_NS]
    has_estimate = flags[L_HAS_ESTIMATE] != 0  # whether the filter gave this sample its figures
    n_starts = flags[L_N_STARTS]  # the controller's starts so far: the first's constants are ctrl.coef's, a restart's md.restart_coef's
    coef = ctrl.coef[n] if n_starts <= 1 else md.restart_coef[n, n_starts - 2]
    delivered_epoch = st.epoch[r, 0]
    state, work, out, pub = st.ctrl[r], st.work[r], st.out[r], st.pub[r]
    cmd, u_cmd, u_last = vec3[V_CMD], vec3[V_U_CMD], vec3[V_U_LAST]  # the answer (what a held sample repeats), the delivered torque
    # the plant and its actuator
    x = st.x[r]  # (7,) or, with wheels, (7 + W,)
    J, J_inv = plant.J[n], plant.J_inv[n]
    G, G_pinv, wprm = act.G[n], act.G_pinv[n], act.params[n]
    nw = wprm.shape[0]
    uw, wspeed, wwork, wtmp = st.uw[r], st.wspeed[r], st.wwork[r], st.wtmp[r]  # the wheels' motor torques, speeds, scratch
    u, d = vec3[V_U], vec3[V_D]
    # the sensors
    y, held_q, bias = st.y[r], st.held_q[r], vec3[V_BIAS]  # the measured state and its epoch, the tracker's last quaternion and epoch, the gyro's bias
    # the estimator
    estimating = est.prm.shape[1] > 0
    eprm = est.prm[n]
    est_st, P, ework, eout = st.est[r], st.P[r], st.ework[r], st.eout[r]
    # what the filter is given: the gyro and the epoch of the sample, the quaternion of the tracker
    # sample of the latest new epoch delivered (the graph's sensors/star_tracker: a sample is
    # published once, when its epoch is new; sappc_estimator.node.TrackerSamples)
    ye = st.ye[r]
    yc = st.yc[r]  # the controller's input: the measurement, or the estimate
    bias_k = vec3[V_BIAS_K]  # the gyro's true bias in sample k's rate, faults included (measure walks its own on to k + 1)
    # the faults
    fkind, fwin, fprm, fint = faults.kind[n], faults.window[n], faults.params[n], faults.samples[n]
    nf = fkind.shape[0]
    fcount, fbuf = st.fcount[r], st.fbuf[r]  # a held sample: the measurement and its epoch (8), or a torque
    # the orbit's environment and momentum management (issue 36)
    orbiting = env.orbit.shape[1] > 0
    managing = mm.prm.shape[1] > 0
    nm = env.m_max.shape[1]
    r_N, B_N, B_B, L_env, d_tot = vec3[V_R_N], vec3[V_B_N], vec3[V_B_B], vec3[V_L_ENV], vec3[V_D_TOT]
    B_meas = vec3[V_B_MEAS]  # the flight software's field: the magnetometer's, or B_B
    r_B_tmp, L_mtb_tmp = vec3[V_R_B_TMP], vec3[V_L_MTB_TMP]
    m_cmd = st.m_cmd[r]  # the rods' dipole commands
    # the run's rows of the environment's and the law's arrays, taken once (not per sample)
    e_orbit, e_field, e_gravity, e_Gt, e_mmax, e_mag, e_draws = env.orbit[n], env.field[n], env.gravity[n], env.Gt[n], env.m_max[n], env.mag[n], env.mag_draws[n]
    x_q = x[:4]  # the attitude: x is integrated in place, so the view stays its first four rows
    mm_prm, mm_Gs, mm_Js, mm_Gs_pinv, mm_u_max, mm_Gt, mm_steering, mm_m_max = (mm.prm[n], mm.Gs[n], mm.Js[n], mm.Gs_pinv[n], mm.u_max[n], mm.Gt[n],
                                                                                  mm.steering[n], mm.m_max[n])
    mm_orbit, mm_field = mm.orbit[n], mm.field[n]
    mag_stride = int(e_mag[0]) if e_mag.shape[0] > 0 else 1
    mag_row0 = (k_lo + mag_stride - 1) // mag_stride  # the block's first magnetometer update: e_draws' first row
    tau_w = vec3[V_TAU_W]  # the wheels' body torque: the controller's minus the rods'
    mtmp = st.mtmp[r]
    mst = st.mst[r]  # the predictive law's state (sappc_momentum.core.predictive.new_state)
    q_ff = st.q_ff[r]  # the predictive law's attitude: the controller's attitude input of the last sample that delivered a
    # finite one, as for the rate below (NaN before the first: the cross-product law)
    omega_ff = vec3[V_OMEGA_FF]  # the gyroscopic feed-forward's body rate: the controller's rate input of the last sample that delivered a finite
    # one (sappc_momentum.node reads the same topic: a dropped or withheld sample is "no data", NaN, and keeps the previous rate)
    # the flight modes (issue 49): the manager's state, inputs and run summary, the hold law's rows, B-dot's state
    moding = md.prm.shape[1] > 0
    mode_st, mode_in, mode_run = st.mode[r], st.mode_in[r], rec.mode_run[r]
    hctrl, hwork, hout, q_hold, q_unit, bd_st = st.hctrl[r], st.hwork[r], st.hout[r], st.q_hold[r], st.q_unit[r], st.bdot[r]
    m_B, zero3 = vec3[V_M_B], vec3[V_ZERO]
    md_prm, md_bdot, md_hold, md_safe = md.prm[n], md.bdot[n], md.hold_prm[n], md.safe_prm[n]
    md_to_reference = md.hold_reference[n] != 0.0
    md_requests = md.requests[n]
    q_err = st.q_err[r]
    measuring = sens.draws.shape[1] > 0
    dt = grid.dt
    T = grid.n_samples
    for kb in range(grid.t.shape[0]):  # kb: the sample's row in the block's arrays; k: its index in the run
        k = k_lo + kb
        t = grid.t[kb]
        t_stamp_s = grid.t_ns[kb] / _NS_PER_S  # the sample's stamp in seconds (the estimator's and the controller's time)
        if estimating:
            for i in range(3):
                bias_k[i] = bias[i]
            if nf > 0:
                fault_rate_bias(t, fkind, fwin, fprm, bias_k)
        measure_sample(sens, n, k, kb, t, t_stamp_s, measuring, x, held_q, bias, y)
        state_in, reference_in = True, True
        if nf > 0:
            state_in = fault_sensor(t, fkind, fwin, fprm, fint, fcount, fbuf, faults.draws[min(kb, faults.draws.shape[0] - 1)], y)
            reference_in = fault_reference(t, fkind, fwin)
        gyro_in = moding and state_in and np.isfinite(y[4] + y[5] + y[6])  # the gyro's rate delivered (the mode manager's and SAFE's)
        est_status = ESTIMATOR_NO_INPUT  # no measurement delivered: no filter step (the node's code)
        if estimating:
            state_in, has_estimate, est_status, delivered_epoch = estimate_sample(eprm, t_stamp_s, state_in, y, delivered_epoch, ye, est_st, P,
                                                                                  ework, eout, yc)
        else:
            for i in range(7):
                yc[i] = y[i]
        valid = sample_verdicts(state_in, reference_in, yc[:4], yc[4:], grid.ref_q[kb], grid.ref_w[kb], grid.ref_wd[kb], ctrl.bounds, rejected)
        t_stamp = t_stamp_s  # the controller's time: its input's stamp in seconds, as the node computes it
        mode = TRACK  # without modes the controller flies every sample
        reason = R_NONE
        if moding:  # the mode manager's inputs (sappc_modes.core.modes.IN_*; docstring), then its step
            mode_in[IN_RATE] = math.sqrt((y[4] * y[4] + y[5] * y[5]) + y[6] * y[6]) if gyro_in else np.nan
            if estimating:
                mode_in[IN_HEALTH] = eout[EO_MON_LEVEL] if has_estimate else np.nan
                mode_in[IN_SIGMA] = sigma_of_covariance(P) if has_estimate else np.nan
            else:  # the measurements themselves: healthy while they arrive
                mode_in[IN_HEALTH] = HEALTH_OK if gyro_in else np.nan
                mode_in[IN_SIGMA] = 0.0 if gyro_in else np.nan
            mode_in[IN_LOST] = 0.0
            mode_in[IN_WHEEL] = np.nan
            if nw > 0:
                wheel_speeds_into(x, G, wprm, wspeed)  # the tachometers
                mode_in[IN_WHEEL] = wheel_speed_fraction(wspeed, wprm[:, _W_MAX_SPEED])
            mode_in[IN_REQUEST] = -1.0
            for j in range(md_requests.shape[0]):  # the ground's request of this sample: its first at or after the request's time
                if t >= md_requests[j, 0] and t - dt < md_requests[j, 0]:
                    mode_in[IN_REQUEST] = md_requests[j, 1]
            mode_in[IN_INHIBIT] = 0.0
            mode_in[IN_ERROR] = np.nan
            if valid:  # the estimate's error against the reference: its rotation angle
                mode_in[IN_ERROR] = attitude_error_angle(grid.ref_q[kb], yc[:4], q_err)
            reason = mode_step(mode_st, mode_in, md_prm)
            mode = int(mode_st[S_MODE])
            if reason != R_NONE:
                if mode == TRACK and started and n_starts <= md.restart_coef.shape[1]:
                    started = False  # a later entry into TRACK: the controller starts again at its first valid sample
                mode_run[MR_TRANSITIONS] += 1.0
                if np.isnan(mode_run[MR_ENTRY + mode]):
                    mode_run[MR_ENTRY + mode] = t
                if mode == HOLD or mode == SAFE:  # the hold law starts afresh, its attitude taken at its first valid sample
                    for i in range(hctrl.shape[0]):
                        hctrl[i] = 0.0
                    for i in range(4):
                        q_hold[i] = np.nan
                elif mode == DETUMBLE:
                    reset_bdot_state(bd_st)
            mode_run[MR_SAMPLES + mode] += 1.0
        if valid and not started and mode == TRACK:
            if n_starts >= md.starts_known[n]:  # its constants not known yet: the probe's start, or a restart's pause (docstring)
                if probe or n_starts > 0:
                    start[0] = k
                    start[1] = t_stamp
                    error_quaternion(grid.ref_q[kb], yc[:4], start[2:6])
                    start[6] = n_starts
                    return
            else:
                if n_starts > 0:  # a restart: the controller afresh, with its own constants
                    coef = md.restart_coef[n, n_starts - 1]
                    for i in range(state.shape[0]):
                        state[i] = 0.0
                state[S_T0] = t_stamp
                started = True
                n_starts += 1
        status = ANSWER_COMMANDED
        if mode != TRACK:  # the mode's own law (docstring); the controller is inactive
            status = ANSWER_INACTIVE
            law = False
            # the mode law's inputs: HOLD on the estimate, against the reference (an acquisition) or the
            # attitude of HOLD's first valid sample (an inertial hold); SAFE on the gyro alone: one call
            # of the law compiled on its own (an inlined step is compiled again at each call site).
            q_in, w_in, q_to, w_to, wd_to, m_prm = yc[:4], yc[4:], q_hold, zero3, zero3, md_hold
            if mode == HOLD and valid:
                if md_to_reference:
                    q_to, w_to, wd_to = grid.ref_q[kb], grid.ref_w[kb], grid.ref_wd[kb]
                elif np.isnan(q_hold[0]):
                    for i in range(4):
                        q_hold[i] = yc[i]
                law = True
            elif mode == SAFE and gyro_in:
                q_in, w_in, q_to, m_prm = q_unit, y[4:7], q_unit, md_safe
                law = True
            if law:
                mrp_feedback_step(t_stamp, dt, q_in, w_in, q_to, w_to, wd_to, m_prm, coef, hctrl, hwork, hout)
            law = law and np.isfinite(hout[O_TORQUE, 0] + hout[O_TORQUE, 1] + hout[O_TORQUE, 2])
            for i in range(3):
                cmd[i] = hout[O_TORQUE, i] if law else 0.0
        elif valid:
            controller_step(kind, t_stamp, dt, yc[:4], yc[4:], grid.ref_q[kb], grid.ref_w[kb], grid.ref_wd[kb], prm, coef, state, work, out)
            if not (np.isfinite(out[O_TORQUE, 0] + out[O_TORQUE, 1] + out[O_TORQUE, 2])
                    and np.isfinite(out[O_CMD, 0] + out[O_CMD, 1] + out[O_CMD, 2])):
                status = ANSWER_REFUSED
            else:
                has_last = True
                last_state_ns = grid.t_ns[kb]
        elif not has_last or grid.t_ns[kb] - last_state_ns > ctrl.stale_ns:  # no valid state yet, or too old
            status = ANSWER_WATCHDOG_ZERO
        else:
            status = ANSWER_HELD
        if status == ANSWER_COMMANDED:
            for row in range(N_OUT):
                for c in range(4):
                    pub[row, c] = out[row, c]
            for i in range(3):
                cmd[i] = out[O_TORQUE, i]
        elif status == ANSWER_INACTIVE:  # the mode's law: its command, the controller's rows kept
            for i in range(3):
                pub[O_CMD, i] = cmd[i]
                pub[O_SAT, i] = 0.0
        elif status != ANSWER_HELD:  # a zero answer: zero command and saturation, earlier rows
            for i in range(3):
                cmd[i] = 0.0
                pub[O_CMD, i] = 0.0
                pub[O_SAT, i] = 0.0
        # (held: the last command and rows again) the answer goes through the actuator link
        for i in range(3):
            u_cmd[i] = cmd[i]
        if nf > 0:
            fault_actuator(t, fkind, fwin, fprm, fint, fcount, fbuf, u_cmd, u_last)
        else:
            for i in range(3):
                u_last[i] = u_cmd[i]
        for i in range(3):
            pub[O_TORQUE, i] = u_last[i]
        if sens.draws.shape[1] > 0 or nf > 0 or estimating or status != ANSWER_COMMANDED:
            error_quaternion(grid.ref_q[kb], x[:4], pub[O_QBR])  # the true error (metrics)
        if dist.use_table:  # shared by every run: its table (disturbance_at: each run's own)
            for i in range(3):
                d[i] = dist.table[kb, i]
        else:
            disturbance_at(dist, n, kb, t, d)
        if orbiting:
            field_of(e_orbit, e_field, t, x_q, r_N, B_N, B_B)
            measured_field_of(e_mag, e_draws, k, mag_row0, B_B, B_meas)
        if managing:
            if state_in and np.isfinite(yc[4]) and np.isfinite(yc[5]) and np.isfinite(yc[6]):  # the rate delivered, as the node reads it
                for i in range(3):
                    omega_ff[i] = yc[4 + i]
            if state_in and np.isfinite(yc[0]) and np.isfinite(yc[1]) and np.isfinite(yc[2]) and np.isfinite(yc[3]):  # the attitude, the same
                for i in range(4):
                    q_ff[i] = yc[i]
            wheel_speeds_into(x, G, wprm, wspeed)  # the tachometers
            if mode == DETUMBLE:  # B-dot on the rods, on each new magnetometer sample (its update's time), nothing on the wheels
                bdot_step(md_bdot, B_meas, (k - k % mag_stride) * dt, bd_st, m_B)
                dipole_mapping(mm_steering, m_B, mm_m_max, m_cmd)
                for i in range(3):
                    tau_w[i] = 0.0
            else:
                momentum_management_step(mm_prm, mm_Gs, mm_Js, mm_Gs_pinv, mm_u_max, mm_Gt, mm_steering, mm_m_max, mm_orbit, mm_field, t_stamp_s,
                                         wspeed, B_meas, q_ff, omega_ff, u_last, m_cmd, tau_w, mtmp, mst)
            wheel_torques(tau_w, G_pinv, G, wprm, x, uw)
        elif nw > 0:
            wheel_torques(u_last, G_pinv, G, wprm, x, uw)
        if orbiting:
            torque_of(e_orbit, e_gravity, e_Gt, e_mmax, x_q, r_N, B_B, m_cmd, r_B_tmp, L_mtb_tmp, L_env)
            for i in range(3):
                d_tot[i] = d[i] + L_env[i]
        if stride > 0 and kb % stride == 0:
            j = kb // stride  # the block's record starts at its first sample (k_lo is a multiple of stride)
            for row in range(N_OUT):
                for c in range(4):
                    rec.out[r, j, row, c] = pub[row, c]
            for i in range(7):
                rec.x[r, j, i] = x[i]
            for i in range(3):
                rec.d[r, j, i] = d[i]
            rec.status[r, j] = status
            if moding:
                rec.mode[r, j, 0] = mode
                rec.mode[r, j, 1] = reason
            if orbiting:
                for i in range(3):
                    rec.env[r, j, i] = B_B[i]
                    rec.env[r, j, 3 + i] = B_meas[i]
                    rec.env[r, j, 6 + i] = L_env[i]
                for i in range(nm):
                    rec.env[r, j, 9 + i] = m_cmd[i]
            if nw > 0:
                record_wheels(rec.wheels[r, j], x, G, wprm, wspeed, uw)
            if estimating:
                record_estimate(rec.estimate[r, j], has_estimate, state_in, eout, P, est_status, bias_k)
        if k < T - 1:  # the disturbance with an orbit, and the environment's torque
            plant_step(x, u_last, uw, d_tot if orbiting else d, dt, act.max_torque_Nm, plant.substeps, J, J_inv, G, wprm, wwork, wtmp, u)
    # the block's end: the scalars back into st (the arrays are st's own rows)
    flags[L_STARTED] = 1 if started else 0
    flags[L_HAS_LAST] = 1 if has_last else 0
    flags[L_LAST_STATE_NS] = last_state_ns
    flags[L_HAS_ESTIMATE] = 1 if has_estimate else 0
    flags[L_N_STARTS] = n_starts
    st.epoch[r, 0] = delivered_epoch
    for i in range(7 + nw):
        rec.x_final[r, i] = x[i]


#: The column of the wheels' speed limit [rad/s] in their kernels' parameters
#: (:meth:`spacecraft_sim.core.wheels.ReactionWheels.params`): the mode manager's wheel guard.
_W_MAX_SPEED = 2


@jit
def _initial_state(n, r, plant, sens, est, md, st, rec):
    """Run ``n``'s state before its first sample into row ``r`` of ``st`` (:class:`LoopState`,
    allocated zero by :func:`_state`) and of ``rec``'s per-run arrays: what is not zero at the start."""
    pub = st.pub[r]
    for row in range(N_OUT):
        for c in range(4):
            pub[row, c] = np.nan  # the rows last published: no performance function yet
    for row in (O_TORQUE, O_CMD, O_SAT):
        for c in range(4):
            pub[row, c] = 0.0  # nothing commanded
    rec.start[r, 0] = -1.0  # no valid sample (yet)
    for i in range(rec.rejected.shape[1]):
        rec.rejected[r, i] = 0
    x0 = plant.x0[n]
    for i in range(x0.shape[0]):
        st.x[r, i] = x0[i]
    for i in range(3):
        st.vec3[r, V_BIAS, i] = sens.params[n, S_BIAS0 + i]  # the gyro's bias
    reset_state(st.est[r])
    st.epoch[r, 0] = -np.inf  # no tracker sample delivered yet
    st.mst[r, MS_TNEXT] = -np.inf
    st.mst[r, MS_TLAST] = np.nan
    for i in range(4):
        st.q_ff[r, i] = np.nan
    if md.prm.shape[1] > 0:  # the flight modes: the first mode entered at t = 0
        for i in range(st.mode.shape[1]):
            st.mode[r, i] = 0.0
        st.mode[r, S_MODE] = md.initial[n]
        for i in range(N_MODE_RUN):
            rec.mode_run[r, i] = np.nan if i < MR_SAMPLES else 0.0
        rec.mode_run[r, MR_ENTRY + int(md.initial[n])] = 0.0
        reset_bdot_state(st.bdot[r])
        for i in range(4):
            st.q_hold[r, i] = np.nan
            st.q_unit[r, i] = 0.0
        st.q_unit[r, 3] = 1.0


@jit_parallel
def run_batch_kernel(probe, stride, k_lo, grid, ctrl, plant, act, sens, est, dist, faults, env, mm, md, rec, st):
    """Every run of a batch over one block of samples, in parallel over runs (``prange``);
    ``probe``: the first pass of :func:`_run_one` (each run's first valid sample into ``rec.start``)."""
    for i in prange(plant.x0.shape[0]):
        n = np.int64(i)  # prange's index is unsigned: one signature of _run_one for every entry (one compile)
        _run_one(n, n, probe, stride, k_lo, grid, ctrl, plant, act, sens, est, dist, faults, env, mm, md, rec, st)


@jit
def probe_batch_kernel(stride, k_lo, grid, ctrl, plant, act, sens, est, dist, faults, env, mm, md, rec, st):
    """The start's probe (:func:`_run_one`'s first pass, each run's first valid sample into
    ``rec.start``) of every run of a batch over one block of samples, one run after the other on
    one thread: a probe ends at each run's first valid sample (most runs' first), so threads would
    gain little, and a kernel that is not parallel can be loaded by a campaign's parent before its
    workers fork (:func:`load_before_fork`), where each worker would otherwise load
    :func:`run_batch_kernel` for its first probe (0.05 to 0.08 s)."""
    for i in range(plant.x0.shape[0]):
        n = np.int64(i)
        _run_one(n, n, True, stride, k_lo, grid, ctrl, plant, act, sens, est, dist, faults, env, mm, md, rec, st)


def _run_alone(n: int, probe: bool, stride: int, inp: CompiledInputs, rec: LoopRecord, st: LoopState) -> None:
    """Run ``n`` of ``inp`` alone (its block of samples) into index 0 of ``rec`` and ``st``:
    :func:`_run_one` called from Python with :func:`run_batch_kernel`'s argument types (``int64``
    indices, not Python ints' literals: one signature, one compile)."""
    _run_one(np.int64(n), np.int64(0), bool(probe), np.int64(stride), np.int64(inp.k_lo), *inp.args(), rec, st)


def _runs(arrays: Any, lo: int, hi: int) -> Any:
    """A model's arrays for runs ``lo .. hi - 1``: each per-run field (``run_axes``) sliced along its
    run axis into a contiguous copy (the same argument types), the shared ones as they are."""
    axes: dict[str, int] = arrays.run_axes()
    return arrays._replace(**{name: np.ascontiguousarray(np.take(getattr(arrays, name), np.arange(lo, hi), axis=axis))
                              for name, axis in axes.items()})


class NoiseStreams:
    """Standard normals of a batch's runs, rows in order, drawn block after block: the sensors'
    (one generator per run, a campaign's; or one stream, ``n_runs = 1``, shared by every run of a
    batch: a scenario's ``sensors.seed``, every run measuring with the same draws) and the
    magnetometer's (one per run, keyed by the run).  A ``numpy.random.Generator`` fills
    ``standard_normal`` in order, so rows drawn in blocks are the rows of one call, bit for bit
    (``tests/tools/offline/test_blocks.py``).

    ``makers``: one function per run making its generator afresh: :meth:`open` starts the draws
    again from the run's first row (the start's probe, then the run itself)."""

    def __init__(self, makers: Sequence[Callable[[], np.random.Generator]], width: int) -> None:
        self.makers = tuple(makers)
        self.width = int(width)
        self._open: list[np.random.Generator] = []

    @property
    def n_runs(self) -> int:
        return len(self.makers)

    def runs(self, lo: int, hi: int) -> NoiseStreams:
        """The streams of runs ``lo .. hi - 1`` (not opened)."""
        return NoiseStreams(self.makers[lo:hi], self.width)

    def open(self) -> NoiseStreams:
        """Start every stream at its first row; returns ``self``."""
        self._open = [make() for make in self.makers]
        return self

    def take(self, rows: int) -> np.ndarray:
        """The next ``rows`` draws of every run, (N, rows, width) float64 C-contiguous (each run's
        drawn into its rows: the same values as drawn alone, without a copy)."""
        if not self._open:
            self.open()
        out = np.empty((self.n_runs, rows, self.width))
        for g, mine in zip(self._open, out):
            g.standard_normal(out=mine)
        return out


@dataclass
class SampleMaker:
    """How a batch's per-sample inputs are made for any block of its samples, in order: the grid
    (``k dt`` and the stamps), the reference (its RK4 carried from block to block:
    :meth:`~spacecraft_sim.core.reference.PaperReference.sample`), the disturbance's table or
    random draws (functions of the sample's time), the noise faults' draws (functions of the
    stamp) for the batch's ``n_runs`` runs.  The sensors' draws come from the inputs' own
    :class:`NoiseStreams`.  Every value is the one the whole run's arrays hold at that sample."""

    n_samples: int
    dt: float
    reference: Any
    disturbance: Any
    n_runs: int
    faults: tuple[Any, ...]
    fault_noise: bool
    #: The blocks made so far, up to :data:`MADE_BLOCKS_MAX_BYTES` of them: (k_lo, k_hi, the
    #: reference's carry before) -> (grid, disturbance, the carry after).  A campaign's sub-batches
    #: ask for the same blocks in the same order: made once, not once each.
    made: dict[tuple[int, int, bytes], tuple[LoopGrid, Any, np.ndarray]] = dataclasses.field(default_factory=dict, repr=False, compare=False)

    def times(self, k_lo: int, k_hi: int) -> tuple[np.ndarray, np.ndarray]:
        """Samples ``k_lo .. k_hi - 1``: their times ``k dt`` [s] (the products of
        :func:`~spacecraft_sim.core.reference.sample_times`) and the plant's stamps [ns]."""
        t = np.arange(k_lo, k_hi, dtype=np.float64) * self.dt  # k exact in float64: the same products as sample_times
        t_ns = seconds_to_ns_array(t)
        return t, t_ns

    def grid(self, k_lo: int, k_hi: int, carry: np.ndarray) -> LoopGrid:
        """The grid of samples ``k_lo .. k_hi - 1``, the reference continued from ``carry``
        (:meth:`~spacecraft_sim.core.reference.PaperReference.start`, advanced in place)."""
        t, t_ns = self.times(k_lo, k_hi)
        ref = self.reference.sample(t, carry)
        return LoopGrid(t, t_ns, self.dt, _f64(ref.q_RN), _f64(ref.omega_RN_R), _f64(ref.omegadot_RN_R), self.n_samples)

    def block(self, k_lo: int, k_hi: int, carry: np.ndarray) -> tuple[LoopGrid, Any]:
        """:meth:`grid` and the disturbance's arrays of samples ``k_lo .. k_hi - 1`` for every run
        (:func:`~spacecraft_sim.core.disturbance.pack_disturbance`), each block made once while
        the blocks kept stay within :data:`MADE_BLOCKS_MAX_BYTES` (their arrays shared: read
        only)."""
        key = (k_lo, k_hi, carry.tobytes())
        hit = self.made.get(key)
        if hit is not None:
            grid, made, after = hit
            carry[...] = after
            return grid, made
        grid = self.grid(k_lo, k_hi, carry)
        made = pack_disturbance(self.disturbance, grid.t, self.n_runs)
        size = sum(a.nbytes for a in (*grid, *made) if isinstance(a, np.ndarray))
        kept = sum(a.nbytes for g, m, _ in self.made.values() for a in (*g, *m) if isinstance(a, np.ndarray))
        if kept + size <= MADE_BLOCKS_MAX_BYTES:
            self.made[key] = (grid, made, carry.copy())
        return grid, made


#: What :class:`SampleMaker` keeps of the blocks it made, for the next sub-batch: 16 MiB, a whole
#: run of 50 s at 100 Hz many times over (the grid's 96 bytes a sample, a shared disturbance
#: table's 24 and its windows'); a long run's later blocks, or a disturbance drawn per run, are
#: made again for each sub-batch.
MADE_BLOCKS_MAX_BYTES = 16 << 20


#: Run-samples (samples times runs) of one block of :func:`run_blocks`: the block's inputs and
#: record take up to about 1.2 kB a run-sample (the orbit scenario's record 1009 bytes, its inputs
#: 194: docs/design/streaming.md), so 2**16 bounds a block to about 80 MB whatever the run's
#: length or the sub-batch's runs (a 60 s run's process, numba and the kernels loaded, is about
#: 190 MB), while a block still runs for about half a second of the orbit scenario (the call's
#: cost from Python, and the inputs made per block, stay below a percent).
BLOCK_RUN_SAMPLES = 1 << 16
#: Run-samples of one block of :func:`run_blocks` whose runs go in SIMD lanes that take the
#: metrics online and record only their answers: one byte a run-sample is written (and the block's
#: inputs, shared by its runs, about 200 bytes a sample; the record's other arrays are allocated
#: whole but written only for a run the lanes hand back, about 500 bytes a sample of that run).
#: 2**20 takes a campaign's sub-batch of 128 runs of 50 s in one block, where
#: :data:`BLOCK_RUN_SAMPLES` made ten, each with about 1 ms of Python (inputs, counts, the metrics'
#: state) around about 8 ms of lanes.
ONLINE_BLOCK_RUN_SAMPLES = 1 << 20


@dataclass
class CompiledInputs:
    """Everything a compiled batch needs: the shared grid and each model's arrays (module
    docstring), the controller's ``config`` and RPF policy ``on_infeasible`` (each run's start is
    computed from them: :func:`_started`), and the RPF's ``flat`` and ``clamped`` components
    (N, 3) in ``flags``.

    The per-sample arrays (the grid's, the sensors' draws, the disturbance's table and random
    draws, the noise faults' draws) are those of the block of samples from ``k_lo`` (the whole run
    after :func:`prepare`, none with ``prepare(..., whole=False)``); :meth:`blocks` gives the run's
    blocks in order, made by ``maker`` (for ``runs``, this batch's runs among the maker's) with
    the sensors' draws from ``noise`` and the magnetometer's from ``mag_noise`` (this batch's
    runs'; a block's ``environment.mag_draws`` are its updates' rows, from the first update at or
    after ``k_lo``).  ``lanes``: step the runs in SIMD lanes where :mod:`sappc.offline.lanes`
    covers them (a campaign's runs; their libm calls then libmvec's, docs/parity.md)."""

    grid: LoopGrid
    controller: ControllerArrays
    plant: PlantArrays
    actuator: ActuatorArrays
    sensors: SensorArrays
    estimator: EstimatorArrays
    disturbance: DisturbanceArrays
    faults: FaultArrays
    environment: EnvironmentArrays
    momentum: MomentumArrays
    modes: ModeArrays
    config: Any = None
    on_infeasible: str = "raise"
    flags: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)
    maker: SampleMaker | None = None
    noise: NoiseStreams | None = None
    mag_noise: NoiseStreams | None = None
    runs: tuple[int, int] | None = None
    k_lo: int = 0
    lanes: bool = False

    #: The models, in the kernels' argument order.
    MODELS = ("controller", "plant", "actuator", "sensors", "estimator", "disturbance", "faults", "environment", "momentum", "modes")

    @property
    def t(self) -> np.ndarray:
        """The sample times of the block held (T, the whole run, after :func:`prepare`) [s]."""
        return self.grid.t

    @property
    def n_samples(self) -> int:
        """The run's samples (all blocks)."""
        return int(self.grid.n_samples)

    @property
    def holds_whole(self) -> bool:
        """Whether the per-sample arrays held are the whole run's."""
        return self.k_lo == 0 and self.grid.t.size == self.n_samples

    @property
    def n_wheels(self) -> int:
        return int(self.actuator.params.shape[1])

    @property
    def n_runs(self) -> int:
        return int(self.plant.x0.shape[0])

    @property
    def n_env_record(self) -> int:
        """Columns of the environment's record: ``9 + M`` with an orbit (:class:`LoopRecord`), else 0."""
        return 9 + int(self.environment.m_max.shape[1]) if self.environment.orbit.shape[1] > 0 else 0

    @property
    def estimating(self) -> bool:
        """Whether an estimator sits between the sensors and the controller."""
        return bool(self.estimator.prm.shape[1] > 0)

    def args(self) -> tuple[Any, ...]:
        """The kernels' arguments after ``probe``, ``stride`` and ``k_lo``."""
        return (self.grid, *(getattr(self, m) for m in self.MODELS))

    def subset(self, lo: int, hi: int, noise: np.ndarray | NoiseStreams | None = None) -> CompiledInputs:
        """Runs ``lo .. hi - 1`` (contiguous copies: the same argument types), with ``noise`` as
        their sensor draws when given: (hi - lo, T, 6 or 9), or their :class:`NoiseStreams` (then
        drawn block by block, or whole when this batch holds the whole run); their starts are then
        computed again (new measurements may start a run elsewhere)."""
        models = {m: _runs(getattr(self, m), lo, hi) for m in self.MODELS}
        streams = self.noise if self.noise is None or self.noise.n_runs == 1 else None
        if isinstance(noise, NoiseStreams):
            streams = noise
            if self.holds_whole:
                noise = noise.open().take(self.n_samples)
        if isinstance(noise, np.ndarray):
            models["sensors"] = models["sensors"]._replace(draws=np.ascontiguousarray(noise, dtype=np.float64))
        base = (0, self.n_runs) if self.runs is None else self.runs
        sub = dataclasses.replace(self, **models, flags={k: v[lo:hi] for k, v in self.flags.items()}, noise=streams,
                                  mag_noise=None if self.mag_noise is None else self.mag_noise.runs(lo, hi), runs=(base[0] + lo, base[0] + hi))
        if noise is None:
            return sub
        try:
            return _started(sub)
        except SingularStartError as exc:  # name the run in the whole batch
            raise SingularStartError(exc.q_e0, exc.run + lo) from None

    def blocks(self, block_samples: int, stride: int = 1, first: int | None = None) -> Iterator[CompiledInputs]:
        """The run's blocks of ``block_samples`` samples (rounded down to a multiple of ``stride``,
        the record's: each block's record starts at a recorded sample), in order: these inputs with
        the per-sample arrays of each block.  A batch that holds the whole run gives it in one
        block when it fits, else slices of it; otherwise the blocks are made (``maker``, ``noise``),
        the first of ``first`` samples when given (the start's probe, which most runs end at their
        first sample: it then draws and makes no more; rounded as ``block_samples``)."""
        T = self.n_samples
        size = max(stride, block_samples // max(stride, 1) * max(stride, 1)) if stride > 0 else max(1, block_samples)
        if self.holds_whole and size >= T:
            yield self
            return
        if self.holds_whole:
            for k_lo in range(0, T, size):
                yield self._slice(k_lo, min(k_lo + size, T))
            return
        if self.maker is None:
            raise ValueError("these inputs hold a block of samples and no maker of the others")
        carry = self.maker.reference.start()
        for streams in (self.noise, self.mag_noise):
            if streams is not None:
                streams.open()
        head = size if first is None else (max(stride, first // max(stride, 1) * max(stride, 1)) if stride > 0 else max(1, first))
        for k_lo in [0, *range(min(head, T), T, size)] if head < T else [0]:
            yield self._made(k_lo, min(k_lo + (head if k_lo == 0 else size), T), carry)

    def whole(self) -> CompiledInputs:
        """These inputs with the whole run's per-sample arrays (one block)."""
        return self if self.holds_whole else next(self.blocks(self.n_samples))

    def _slice(self, k_lo: int, k_hi: int) -> CompiledInputs:
        """Samples ``k_lo .. k_hi - 1`` of the whole run held (contiguous copies)."""
        g, c = self.grid, np.ascontiguousarray
        d, f, s, e = self.disturbance, self.faults, self.sensors, self.environment
        r0, r1 = self._mag_rows(k_lo, k_hi)
        return dataclasses.replace(
            self, k_lo=k_lo, environment=e._replace(mag_draws=c(e.mag_draws[:, r0:r1])),
            grid=g._replace(t=c(g.t[k_lo:k_hi]), t_ns=c(g.t_ns[k_lo:k_hi]), ref_q=c(g.ref_q[k_lo:k_hi]), ref_w=c(g.ref_w[k_lo:k_hi]),
                            ref_wd=c(g.ref_wd[k_lo:k_hi])),
            sensors=s._replace(draws=c(s.draws[:, k_lo:k_hi]) if s.draws.shape[1] else s.draws),
            disturbance=d._replace(table=c(d.table[k_lo:k_hi]) if d.table.shape[0] else d.table,
                                   windows=c(d.windows[:, k_lo:k_hi])),
            faults=f._replace(draws=c(f.draws[k_lo:k_hi]) if f.draws.shape[0] > 1 else f.draws))

    def _made(self, k_lo: int, k_hi: int, carry: np.ndarray) -> CompiledInputs:
        """Samples ``k_lo .. k_hi - 1`` made by ``maker`` (the reference continued from ``carry``)."""
        m = self.maker
        assert m is not None
        grid, made = m.block(k_lo, k_hi, carry)
        lo, hi = (0, m.n_runs) if self.runs is None else self.runs
        dist = self.disturbance._replace(table=made.table, windows=made.windows,
                                         draws=made.draws if (lo, hi) == (0, m.n_runs) else np.ascontiguousarray(made.draws[:, lo:hi]))
        faults = self.faults._replace(draws=noise_draws(m.faults, grid.t_ns)) if m.fault_noise else self.faults
        sensors = self.sensors
        if self.noise is not None:
            draws = self.noise.take(k_hi - k_lo)
            if self.noise.n_runs != self.n_runs:  # a stream shared by every run: its rows for each
                draws = np.ascontiguousarray(np.broadcast_to(draws[:1], (self.n_runs,) + draws.shape[1:]))
            sensors = sensors._replace(draws=draws)
        env = self.environment
        if self.mag_noise is not None:
            r0, r1 = self._mag_rows(k_lo, k_hi)
            env = env._replace(mag_draws=self.mag_noise.take(r1 - r0))
        return dataclasses.replace(self, k_lo=k_lo, grid=grid, disturbance=dist, faults=faults, sensors=sensors, environment=env)

    def _mag_rows(self, k_lo: int, k_hi: int) -> tuple[int, int]:
        """The magnetometer's update rows of samples ``k_lo .. k_hi - 1`` (updates at ``k % stride == 0``)."""
        mag = self.environment.mag
        stride = int(mag[0, 0]) if mag.shape[1] > 0 and mag.shape[0] > 0 else 1
        return -(-k_lo // stride), -(-k_hi // stride)


@dataclass
class CompiledRun:
    """Histories of a batch (T_rec samples every ``stride``, ``t`` their times): the loop's
    :class:`LoopRecord`, read through the properties below and :meth:`history`."""

    t: np.ndarray
    record: LoopRecord
    #: (N,) bool: the runs whose metrics the loop computed online for this block (their record holds
    #: only their answers: :func:`run_blocks`' ``metrics``); ``None``: every run recorded.
    online: np.ndarray | None = None
    #: (K, M, 6) the first M runs' trajectory samples in this block (:func:`run_blocks`' ``keep_runs``:
    #: ``q_BR[:3]`` and ``rho``, every ``keep_stride``-th sample of the run), where the loop wrote them
    #: apart from the record; ``None``: read them from the record.
    trajectory: np.ndarray | None = None

    @property
    def out(self) -> np.ndarray:
        """(N, T_rec, N_OUT, 4) the controller's rows as published (:mod:`sappc_controller.core.kernels`)."""
        return self.record.out

    @property
    def x(self) -> np.ndarray:
        """(N, T_rec, 7) the true state."""
        return self.record.x

    @property
    def d(self) -> np.ndarray:
        """(N, T_rec, 3) the disturbance [N m]."""
        return self.record.d

    @property
    def status(self) -> np.ndarray:
        """(N, T_rec) int8 the contract's ``ANSWER_*`` codes."""
        return self.record.status

    @property
    def wheels(self) -> np.ndarray:
        """(N, T_rec, W, 2) each wheel's speed [rad/s] and motor torque [N m] (W = 0: ideal actuator)."""
        return self.record.wheels

    @property
    def env(self) -> np.ndarray:
        """(N, T_rec, 9 + M or 0) the true field ``B_B`` [T], the measured one [T], the environment's
        torque ``L_env_B`` [N m] and the rods' dipole commands [A m^2] (:class:`LoopRecord`)."""
        return self.record.env

    @property
    def x_final(self) -> np.ndarray:
        """(N, 7 + W) the final states."""
        return self.record.x_final

    @property
    def rejected(self) -> np.ndarray:
        """(N, 2) int64 the inputs the controller rejected, by reason (``invalid``, ``implausible``)."""
        return self.record.rejected

    @property
    def mode_run(self) -> np.ndarray:
        """(N, :data:`~sappc_modes.core.packing.N_MODE_RUN` or 0) each run's mode summary: each
        mode's first entry [s] (NaN: never), its samples, the transitions (``MR_*``)."""
        return self.record.mode_run

    def runs(self, rows: np.ndarray) -> CompiledRun:
        """Runs ``rows`` of the batch (copies of their rows of the record)."""
        return CompiledRun(self.t, LoopRecord(*(a[rows] for a in self.record)))

    def status_counts(self) -> dict[str, np.ndarray]:
        """Samples of each status per run (N,), by :data:`ANSWER_NAMES`."""
        return {name: np.count_nonzero(self.status == code, axis=1) for code, name in enumerate(ANSWER_NAMES)}

    def rejected_by_reason(self) -> dict[str, np.ndarray]:
        """Inputs rejected per run (N,), by every reason of
        :data:`~gnc_common.input_check.REJECT_REASONS` (the node's summary keys; the
        stamp checks never reject anything offline)."""
        n = self.rejected.shape[0]
        return {reason: (self.rejected[:, i] if i < self.rejected.shape[1] else np.zeros(n, dtype=np.int64))
                for i, reason in enumerate(REJECT_REASONS)}

    def estimates(self) -> EstimateHistory | None:
        """The estimator's record as an :class:`~sappc.evaluation.estimation.EstimateHistory`
        (arrays (T, N, ...)), ``None`` without an estimator."""
        e = self.record.estimate
        if e.shape[2] == 0:
            return None
        e = e.transpose(1, 0, 2)
        return EstimateHistory(q_BN=e[..., R_Q:R_Q + 4], omega_BN_B=e[..., R_OMEGA:R_OMEGA + 3], gyro_bias=e[..., R_B:R_B + 3],
                               covariance=e[..., R_P:R_P + 36].reshape(e.shape[:2] + (6, 6)), nis=e[..., R_NIS],
                               status=np.nan_to_num(e[..., R_STATUS]).astype(np.int8), gyro_bias_true=e[..., R_BTRUE:R_BTRUE + 3],
                               monitor_level=e[..., R_MON_LEVEL], monitor_nis_sum=e[..., R_MON_NIS], usable=e[..., R_USABLE],
                               recoveries=e[..., R_N_RECOVER])

    def history(self) -> History:
        """The runs as a :class:`~sappc.evaluation.history.History` (arrays (T, N, ...): views, no copy)."""
        o = self.out.transpose(1, 0, 2, 3)  # (T, N, N_OUT, 4)
        x = self.x.transpose(1, 0, 2)
        return History(
            t=self.t, q_BN=x[..., :4], omega_BN_B=x[..., 4:], q_BR=o[:, :, O_QBR, :], torque_B=o[:, :, O_TORQUE, :3],
            torque_cmd_B=o[:, :, O_CMD, :3], saturated=o[:, :, O_SAT, :3] != 0.0, disturbance_B=self.d.transpose(1, 0, 2),
            rho=o[:, :, O_RHO, :3], band_lower=o[:, :, O_BL, :3], band_upper=o[:, :, O_BU, :3], eps=o[:, :, O_EPS, :3],
            z=o[:, :, O_Z, :3], V=o[:, :, O_V, :3],
            wheel_speed_rad_s=self.wheels[..., 0].transpose(1, 0, 2) if self.wheels.shape[2] else None,
            wheel_torque_Nm=self.wheels[..., 1].transpose(1, 0, 2) if self.wheels.shape[2] else None,
            estimate=self.estimates(),
            orbit=self.env.transpose(1, 0, 2) if self.env.shape[2] else None,
            answer=self.status.T,
            mode=self.record.mode[..., 0].T if self.record.mode.shape[2] else None,
            mode_reason=self.record.mode[..., 1].T if self.record.mode.shape[2] else None,
        )


def _f64(a: Any, shape: tuple[int, ...] | None = None) -> np.ndarray:
    """A writable, C-contiguous float64 copy (one argument type for every call: no recompiles)."""
    arr = np.asarray(a, dtype=np.float64)
    return np.array(arr if shape is None else np.broadcast_to(arr, shape), dtype=np.float64, order="C", copy=True)


def prepare(scenario: Scenario, controller: Any = None, *, q_BN0: np.ndarray | None = None, omega_BN_B0: np.ndarray | None = None,
            inertia_kg_m2: np.ndarray | None = None, disturbance: Any = None, config: Any = None, gains: dict[str, np.ndarray] | None = None,
            on_infeasible: str = "raise", sensor_params: np.ndarray | None = None, sensor_outages: np.ndarray | None = None,
            faults: list[tuple[Any, ...]] | None = None, wheels: list[ReactionWheels] | None = None,
            estimator_params: np.ndarray | None = None, run_keys: list[tuple[int, ...]] | None = None,
            orbits: np.ndarray | None = None, whole: bool = True, started: bool = True, lanes: bool = False) -> CompiledInputs:
    """Arrays of a batch from a scenario (overrides as in :func:`sappc.offline.simulate.run_scenario`),
    with the start checks of the controller core (180 deg singularity, funnel, RPF feasibility).
    ``sensor_params``: the sensors' parameters ((13,) or one row per run), their draws then given
    per batch (:meth:`CompiledInputs.subset`); else the scenario's
    (:attr:`~sappc.scenario.Scenario.sensors`; none: exact measurements), every run with the draws
    of its ``seed``; ``sensor_outages`` (N, K, 2) [s]: each run's star-tracker outages (a
    campaign's dispersed ones), else the scenario's.  ``faults``: one fault list per run (a campaign's dispersed faults; the same
    kinds in the same slots), else the scenario's for every run.  ``wheels``: one wheel set per run
    (the same number of wheels), else the scenario's actuator (:attr:`~sappc.scenario.Scenario.wheels`;
    none: ideal).  ``estimator_params``: one row per run of the estimator's parameters (a campaign
    whose runs have dispersed sensors), else the scenario's estimator for every run (none: the
    controller is fed the measurements).  ``run_keys``: each run's key of the magnetometer's stream
    (a campaign's ``(run, seed)``), else ``(k,)`` for run ``k`` of the batch.  ``orbits``: one row
    per run of the orbit's parameters (:meth:`~spacecraft_sim.core.orbit.Orbit.params`: a campaign's
    dispersed orbit phase, node and field epoch), else the scenario's orbit for every run.
    ``whole``: the inputs hold the whole run's per-sample arrays (the reference, the draws, the
    disturbance's table: about 200 bytes a sample); else none, each block's made when it runs
    (:meth:`CompiledInputs.blocks`, :func:`run_blocks`).  With flight modes the RPF's policy is
    ``clamp`` whatever ``on_infeasible`` says: the controller starts at each entry into TRACK from
    whatever error the acquisition left, and a flight does not stop there.  ``started``: false, the
    inputs before the probe of each run's start (no loop runs, nothing compiles: the compile's leaf
    process takes its kernels' argument types from them, :func:`_compile_leaves`)."""
    if started:
        ensure_compiled()
    if scenario.modes is not None:  # a flight starts its controller at each TRACK entry, whatever the error: an infeasible l is clamped, counted
        on_infeasible = "clamp"
    cfg = scenario.controller_config(controller) if config is None else config
    q0 = _f64(np.atleast_2d(np.asarray(scenario.q_BN0 if q_BN0 is None else q_BN0, dtype=np.float64)))
    n = q0.shape[0]
    w0 = _f64(scenario.omega_BN_B0_rad_s if omega_BN_B0 is None else omega_BN_B0, (n, 3))
    per_run_wheels = ([] if scenario.wheels is None else [scenario.wheels] * n) if wheels is None else list(wheels)
    actuator = pack_actuator(scenario.actuator.max_torque_Nm, per_run_wheels, n)
    h0 = np.array([w.initial_momentum(w0[k]) for k, w in enumerate(per_run_wheels)]).reshape(n, -1)
    plant = pack_plant(np.concatenate((q0, w0, h0), axis=1), scenario.inertia_kg_m2 if inertia_kg_m2 is None else inertia_kg_m2,
                       scenario.rk4_substeps)
    T = SampleGrid.of_run(scenario.duration_s, scenario.control_period_s).n_samples  # sample_times' count, not its array (480 MB a week)
    per_run_faults = [scenario.faults] * n if faults is None else list(faults)
    if len(per_run_faults) != n:
        raise ValueError(f"faults must hold one list per run ({n}), got {len(per_run_faults)}")
    dist_model = scenario.disturbance if disturbance is None else disturbance
    maker = SampleMaker(T, float(scenario.control_period_s), scenario.reference, dist_model, n, tuple(per_run_faults[0]),
                        any(isinstance(f, SensorNoise) for fl in per_run_faults for f in fl))
    # the per-sample arrays: none here (each block's from the maker); the models' own packing on no samples
    t, t_ns = maker.times(0, 0)
    grid = LoopGrid(t, t_ns, maker.dt, np.zeros((0, 4)), np.zeros((0, 3)), np.zeros((0, 3)), T)
    own = scenario.sensors if sensor_params is None else None
    noise = None if own is None else NoiseStreams([lambda: np.random.default_rng(own.seed)], N_SENSOR_DRAWS)
    inp = CompiledInputs(
        grid=grid,
        controller=pack_controller(cfg, n, stale_timeout_ns=seconds_to_ns(scenario.controller_node.stale_timeout_s),
                                   input_bounds=scenario.controller_node.input_bounds().packed(), gains=gains),
        plant=plant,
        actuator=actuator,
        sensors=pack_sensors(scenario.sensors, n, 0, scenario.control_period_s, sensor_params, sensor_outages),
        estimator=pack_estimator(scenario.estimator, n, estimator_params),
        disturbance=pack_disturbance(dist_model, t, n),
        faults=pack_faults(per_run_faults, t_ns),
        environment=(env_arrays := _environment(scenario, n, run_keys, orbits, n_samples=0)),  # the magnetometer's draws per block
        momentum=_momentum(scenario, n, env_arrays),
        modes=_modes(scenario, n),
        config=cfg,
        on_infeasible=on_infeasible,
        maker=maker,
        noise=noise,
        mag_noise=_magnetometer_streams(scenario, n, run_keys),
        lanes=lanes,
    )
    inp = inp.whole() if whole else inp
    return _started(inp) if started else inp


def _environment(scenario: Scenario, n: int, run_keys: list[tuple[int, ...]] | None = None,
                 orbits: np.ndarray | None = None, n_samples: int | None = None) -> EnvironmentArrays:
    """The scenario's orbital environment for ``n`` runs (``run_keys``: each run's magnetometer
    stream, :func:`~spacecraft_sim.core.environment.pack_environment`; ``orbits``: each run's orbit
    parameters, else the scenario's; ``n_samples``: the samples whose magnetometer draws are
    packed, default the run's); the gravity gradient acts on the spacecraft with its wheels locked
    (:mod:`spacecraft_sim.core.environment`)."""
    w = scenario.wheels
    locked = locked_inertia(scenario.inertia_kg_m2) if w is None else locked_inertia(scenario.inertia_kg_m2, w.per_wheel("spin_inertia_kg_m2"), w.G)
    samples = int(round(scenario.duration_s / scenario.control_period_s)) + 1 if n_samples is None else n_samples
    env = pack_environment(scenario.environment, n, locked, n_samples=samples,
                           control_period_s=scenario.control_period_s, run_keys=run_keys)
    if orbits is None:
        return env
    rows = _f64(orbits)
    if rows.shape != env.orbit.shape:
        raise ValueError(f"orbits must be one row of orbit parameters per run, {env.orbit.shape}, got {rows.shape}")
    return env._replace(orbit=rows)


def _magnetometer_streams(scenario: Scenario, n: int, run_keys: list[tuple[int, ...]] | None) -> NoiseStreams | None:
    """The magnetometer's draws of ``n`` runs as streams (each run's key: ``run_keys``, else ``(k,)``;
    :func:`~spacecraft_sim.core.magnetometer.magnetometer_draws`' rows), ``None`` without one."""
    mag = None if scenario.environment is None else scenario.environment.magnetometer
    if mag is None:
        return None
    keys = [(k,) for k in range(n)] if run_keys is None else list(run_keys)
    return NoiseStreams([functools.partial(magnetometer_generator, mag, key) for key in keys], 3)


def _momentum(scenario: Scenario, n: int, env_arrays: EnvironmentArrays) -> MomentumArrays:
    """The scenario's momentum management for ``n`` runs, with the wheels and the rods as the
    flight software knows them (the scenario's: no misalignment) and, for the predictive law, each
    run's orbit and field (``env_arrays``': the onboard models are the plant's)."""
    env, w = scenario.environment, scenario.wheels
    if scenario.momentum is None or env is None or env.magnetorquers is None or w is None:
        return pack_momentum(None, n)
    rods = env.magnetorquers
    return pack_momentum(scenario.momentum, n, w.G, w.per_wheel("spin_inertia_kg_m2"), allocation_matrix(w.G), w.per_wheel("max_torque_Nm"),
                         rods.Gt, rods.steering_matrix(), rods.max_dipoles(), env_arrays.orbit, env_arrays.field)


def _modes(scenario: Scenario, n: int) -> ModeArrays:
    """The scenario's flight modes for ``n`` runs (none: every array empty): the guards, the first
    mode, the B-dot gain, and the MRP feedback rows of HOLD (``modes.hold_gains``, the scenario's
    inertia and actuator) and of SAFE (the same with no attitude gain: rate damping)."""
    modes = scenario.modes
    if modes is None:
        return pack_modes(None, n, scenario.control_period_s, coef_shape=(N_COEF, 3))
    hold, safe = hold_and_safe_params(scenario.inertia_kg_m2, modes.hold_gains, scenario.actuator)  # SAFE: no attitude gain
    return pack_modes(modes.transitions, n, scenario.control_period_s, initial_mode=modes.initial_mode,
                      bdot_gain_N_m_s=modes.detumble_gain_N_m_s, hold_prm=hold, safe_prm=safe, hold_on_reference=modes.hold_on_reference,
                      coef_shape=(N_COEF, 3), max_restarts=MAX_RESTARTS, requests=modes.requests)


#: Samples of the first block of the start's probe (:func:`_started`): most runs start at their
#: first sample (a valid input from the start), so the probe draws and makes the inputs of these
#: alone (a flight campaign's 84-run chunk drew 780 samples of sensor noise for its probe: 7 ms
#: of its 0.5 s); a run that starts later is probed on in blocks of the usual size.
PROBE_FIRST_SAMPLES = 16


def _started(inp: CompiledInputs) -> CompiledInputs:
    """``inp`` with each run's start (:func:`_run_one`'s docstring): the first pass of the loop
    (``probe``) finds each run's first valid sample and its error quaternion, block after block
    until every run has started, from which :func:`~sappc_controller.core.packing.start_coef` (the
    node's own start: the 180 deg check, the funnels, the RPF with ``inp.on_infeasible``) gives
    ``coef`` and ``flags``.  A run without a valid sample never starts (zero ``coef``, no flags set).

    Raises
    ------
    SingularStartError, ConfigError
        As the node's first step would, naming the run's index in ``inp``.
    """
    n = inp.n_runs
    inp = dataclasses.replace(inp, modes=inp.modes._replace(starts_known=np.zeros(n)))  # nothing known: the probe finds each first start
    rec = _record(inp, 0, n, 0)
    st = _state(inp, n)
    for block in inp.blocks(inp.n_samples if inp.holds_whole else BLOCK_RUN_SAMPLES // max(n, 1), 0, first=PROBE_FIRST_SAMPLES):
        _loop(True, 0, block, rec, st)
        if np.all(rec.start[:, 0] >= 0.0):
            break
    start = rec.start
    ok = start[:, 0] >= 0.0
    coef = np.zeros_like(inp.controller.coef)
    flags = {"flat": np.zeros((n, 3), bool), "clamped": np.zeros((n, 3), bool)}
    if ok.any():
        rows = np.flatnonzero(ok)
        try:
            c, f = start_coef(inp.config, start[rows, 2:6], on_infeasible=inp.on_infeasible)
        except SingularStartError as exc:  # its index among the runs that started: the run's in the batch
            raise SingularStartError(exc.q_e0, int(rows[exc.run])) from None
        coef[rows] = c
        for key in flags:
            flags[key][rows] = f[key]
    known = ok.astype(np.float64)  # the first start's constants known (a restart's: found as the run goes, _with_restarts)
    modes = inp.modes._replace(starts_known=known, restart_coef=np.zeros_like(inp.modes.restart_coef))
    return dataclasses.replace(inp, controller=inp.controller._replace(coef=_f64(coef)), flags=flags, modes=modes)


def _record(inp: CompiledInputs, stride: int, n: int, samples: int | None = None) -> LoopRecord:
    """A record of ``n`` runs for ``samples`` samples (default: the run's) every ``stride``."""
    T = inp.n_samples if samples is None else samples
    T_rec = 0 if stride == 0 else (T - 1) // stride + 1
    W = inp.n_wheels
    moding = inp.modes.active
    return LoopRecord(np.zeros((n, T_rec, N_OUT, 4)), np.zeros((n, T_rec, 7)), np.zeros((n, T_rec, 3)), np.zeros((n, T_rec), dtype=np.int8),
                      np.zeros((n, T_rec, W, 2)), np.zeros((n, T_rec, N_EST_RECORD if inp.estimating else 0)), np.zeros((n, 2), dtype=np.int64),
                      np.zeros((n, 7 + W)), np.zeros((n, 7)), np.zeros((n, T_rec, inp.n_env_record)),
                      np.zeros((n, T_rec, 2 if moding else 0), dtype=np.int8), np.zeros((n, N_MODE_RUN if moding else 0)))


def _state(inp: CompiledInputs, n: int) -> LoopState:
    """A zero :class:`LoopState` of ``n`` runs of ``inp``'s models (one pass of the loop: the run's
    first block initialises it, :func:`_initial_state`)."""
    W = inp.n_wheels
    nf, depth, nm = inp.faults.kind.shape[1], inp.faults.depth, inp.environment.m_max.shape[1]
    z = np.zeros
    return LoopState(z((n, N_LOOP_FLAGS), dtype=np.int64), z((n, 1)), z((n, N_LOOP_VEC3, 3)), z((n, N_STATE)), z((n, N_WORK, 4)),
                     z((n, N_OUT, 4)), z((n, N_OUT, 4)), z((n, 7 + W)), z((n, W)), z((n, W)), z((n, 5, 7 + W)), z((n, 3, 3)), z((n, N_MEAS)),
                     z((n, 5)), z((n, N_MEAS)), z((n, 7)), z((n, N_EST_STATE)), z((n, 6, 6)), z((n, N_EST_WORK, 6)), z((n, N_EST_OUT)),
                     z((n, nf), dtype=np.int64), z((n, nf, depth, N_FVALUE)), z((n, nm)), z((n, N_MM_WORK, 3)), z((n, N_MM_STATE)), z((n, 4)),
                     z((n, N_MODE_STATE)), z((n, N_MODE_INPUTS)), z((n, N_STATE)), z((n, N_WORK, 4)), z((n, N_OUT, 4)), z((n, 4)), z((n, 4)),
                     z((n, N_BDOT_STATE)), z((n, 4)))


def _check_noise(inp: CompiledInputs) -> None:
    noise = inp.sensors.draws
    if noise.shape[0] != inp.n_runs or noise.shape[1] not in (0, inp.t.size):
        raise ValueError(f"noise must be (N, 0 or T, 6 or 9) = ({inp.n_runs}, 0 or {inp.t.size}, 6 or 9), got {noise.shape}")


def run_batch(inp: CompiledInputs, stride: int = 0, into: CompiledRun | None = None) -> CompiledRun:
    """Every run of ``inp``, the whole run in one compiled call (its record over every sample), in
    parallel over runs (:func:`run_blocks` keeps one block's record at a time).

    ``into``: the result of an earlier call with the same number of runs and stride, whose arrays
    are overwritten (sub-batches of a campaign reuse one buffer: no new pages per sub-batch).
    """
    inp = inp.whole()
    _check_noise(inp)
    fresh = _record(inp, stride, 0)  # shapes only
    if into is not None and into.record.out.shape[0] == inp.n_runs and all(
            a.shape[1:] == b.shape[1:] for a, b in zip(into.record, fresh)):
        rec = into.record
    else:
        rec = _record(inp, stride, inp.n_runs)
    _loop(False, stride, inp, rec, _state(inp, inp.n_runs))
    return CompiledRun(inp.t[::stride] if stride else inp.t[:0], rec)


def run_blocks(inp: CompiledInputs, stride: int = 1, block_samples: int | None = None,
               metrics: MetricsAccumulator | None = None, keep_runs: int = 0, keep_stride: int = 1) -> Iterator[CompiledRun]:
    """Every run of ``inp``, block after block of samples (in parallel over runs): yields each
    block's :class:`CompiledRun` (its times and record, every ``stride`` samples), the same bits as
    :func:`run_batch`'s record over those samples.  Memory is one block's inputs and record,
    whatever the run's length: ``block_samples`` samples (default :data:`BLOCK_RUN_SAMPLES` over
    the runs, :data:`ONLINE_BLOCK_RUN_SAMPLES` where the lanes record only their answers).  The
    record is one buffer reused from block to block (its views are valid until the next block);
    its per-run arrays (``rejected``, ``x_final``, ``start``) are the run's so far.
    ``metrics``: where the runs go in SIMD lanes, the lanes feed it their metrics online, sample
    by sample (:meth:`~sappc.evaluation.metrics.MetricsAccumulator.online_state`: the same bits),
    and record only their answers (the other samples of the record are then not those of the
    block); a block's :attr:`CompiledRun.online` then says which runs, and the caller gives
    ``metrics`` the others' record
    (:meth:`~sappc.evaluation.metrics.MetricsAccumulator.add_online_block`) before the next block.
    ``keep_runs`` M > 0 with ``metrics`` (a campaign's trajectories): the first M runs' every
    ``keep_stride``-th sample of the run (``q_BR[:3]``, ``rho``), written apart from the record, into
    the block's :attr:`CompiledRun.trajectory` (the lanes' and the runs they hand back: every run's);
    where the lanes do not cover the runs, the record holds every sample and ``trajectory`` is
    ``None``."""
    n = inp.n_runs
    answers_only = metrics is not None and inp.lanes and lanes_refusal(inp) is None  # (the lanes then write no more)
    size = max(1, (ONLINE_BLOCK_RUN_SAMPLES if answers_only else BLOCK_RUN_SAMPLES) // max(n, 1)) if block_samples is None else int(block_samples)
    if stride > 0:
        size = max(stride, size // stride * stride)
    size = min(size, inp.n_samples)
    st = _state(inp, n)
    rec = _record(inp, stride, n, size)
    keep_runs = min(keep_runs, n) if answers_only else 0
    for block in inp.blocks(size, stride):
        _check_noise(block)
        traj = None
        if keep_runs > 0:
            kept = -(-(block.k_lo + block.t.size) // keep_stride) - -(-block.k_lo // keep_stride)  # multiples of keep_stride in the block
            traj = np.empty((kept, keep_runs, 6))
        online = _loop(False, stride, block, rec, st, metrics, keep_stride if traj is not None else 0, traj)
        b = block.t.size
        b_rec = 0 if stride == 0 else (b - 1) // stride + 1
        view = rec if b_rec == rec.out.shape[1] else LoopRecord(*(a[:, :b_rec] if a.ndim >= 2 and name not in _PER_RUN else a
                                                                 for name, a in zip(LoopRecord._fields, rec)))
        yield CompiledRun(block.t[::stride] if stride else block.t[:0], view, online, traj)


#: The fields of :class:`LoopRecord` that are per run, not per sample.
_PER_RUN = ("rejected", "x_final", "start", "mode_run")


def trajectory_samples(out: np.ndarray, k_lo: int, keep_stride: int) -> np.ndarray:
    """A campaign's trajectory samples of the record rows ``out`` (R, B, N_OUT, 4) of a block of B
    samples from sample ``k_lo``, recorded at every sample: each sample whose index in the run is a
    multiple of ``keep_stride``, (K, R, 6), the error quaternion's vector part ``q_BR[:3]`` and
    ``rho`` (3): what the lanes write apart from the record (:attr:`CompiledRun.trajectory`)."""
    kept = out[:, -k_lo % keep_stride::keep_stride]
    samples: np.ndarray = np.concatenate((kept[:, :, O_QBR, :3], kept[:, :, O_RHO, :3]), axis=2).swapaxes(0, 1)
    return samples


def _loop(probe: bool, stride: int, inp: CompiledInputs, rec: LoopRecord, st: LoopState,
          metrics: MetricsAccumulator | None = None, keep_stride: int = 0, trajectory: np.ndarray | None = None) -> np.ndarray | None:
    """Every run of ``inp`` (its block of samples) into ``rec`` and ``st``: in parallel over runs
    (:func:`run_batch_kernel`; the start's probe on one thread, :func:`probe_batch_kernel`), or,
    for one run, :func:`_run_one` alone (the same bits; a one-run command then never compiles the
    batch kernels).  ``metrics``: fed online by the SIMD lanes
    (:func:`run_blocks`, with ``keep_stride`` and ``trajectory``); returns the runs whose metrics
    were (None: none)."""
    if stride > 0 and inp.k_lo % stride != 0:
        raise ValueError(f"a block must start at a recorded sample: k_lo {inp.k_lo} is not a multiple of the stride {stride}")
    if inp.lanes and not probe and lanes_refusal(inp) is None:
        return _loop_lanes(stride, inp, rec, st, metrics, keep_stride, trajectory)
    if inp.n_runs == 1:
        _with_restarts(lambda: _run_alone(0, probe, stride, inp, rec, st), probe, inp, rec, st, np.zeros(1, dtype=np.int64))
    elif probe:
        probe_batch_kernel(np.int64(stride), np.int64(inp.k_lo), *inp.args(), rec, st)
    else:
        ensure_compiled(groups=("batches",))
        _with_restarts(lambda: run_batch_kernel(probe, stride, np.int64(inp.k_lo), *inp.args(), rec, st), probe, inp, rec, st,
                       np.arange(inp.n_runs))
    return None


def lanes_refusal(inp: CompiledInputs) -> str | None:
    """Why ``inp``'s runs cannot go in SIMD lanes, or None (:func:`sappc.offline.lanes.lanes_refusal`)."""
    return _lanes().lanes_refusal(inp)  # type: ignore[no-any-return]


def _lanes() -> Any:
    """:mod:`sappc.offline.lanes` (imported on first use: it imports this module)."""
    from sappc.offline import lanes

    return lanes


def _loop_lanes(stride: int, inp: CompiledInputs, rec: LoopRecord, st: LoopState, metrics: MetricsAccumulator | None,
                keep_stride: int = 0, trajectory: np.ndarray | None = None) -> np.ndarray | None:
    """:func:`_loop` in SIMD lanes (:func:`sappc.offline.lanes.run_lanes_kernel`), then each run the
    lanes handed back (an input rejected, a refused answer: the per-run loop's cases) run again over
    the block by :func:`_run_one`, from the state the block started with (which the lanes left in
    ``st``), into the record.  With ``metrics`` (fed every sample before the block's, and a record
    of every sample), the lanes feed it their runs' metrics online (and write the trajectories'
    samples into ``trajectory``, every ``keep_stride``-th, when not 0: a run handed back's from its
    record); returns those runs (the ones not handed back), else None."""
    ensure_compiled(groups=("lanes",))
    lanes = _lanes()
    handed_back = np.zeros(inp.n_runs, dtype=np.int8)
    online = metrics is not None
    flight = lanes.has_flight_stack(inp)
    if online:
        assert metrics is not None
        if stride != 1 or metrics.samples != inp.k_lo or metrics.finite.shape[0] != inp.n_runs:
            raise ValueError(f"online metrics need a record of every sample and an accumulator of the block's {inp.n_runs} runs fed "
                             f"its {inp.k_lo} samples before (stride {stride}, {metrics.finite.shape[0]} runs, {metrics.samples} samples)")
    ma, mc = lanes.online_metrics(metrics, keep_stride, trajectory) if metrics is not None else lanes.no_online_metrics()
    fa = lanes.flight_metrics(metrics if flight else None, inp)
    # the flight stack's lanes step the runs' own rows of st (the sensors, the filter, the true
    # state) and of its metrics: a run they hand back starts its block again from what is kept here
    per_run = [getattr(fa, name) for name in FLIGHT_METRICS_PER_RUN if getattr(fa, name).shape[0] == inp.n_runs]
    kept = [a.copy() for a in list(st) + per_run] if flight else None
    lanes.run_lanes_kernel(np.int64(stride), np.int64(inp.k_lo), *inp.args(), rec, st, handed_back, ma, mc, fa, lanes.group_kind(flight))
    back = np.flatnonzero(handed_back)
    if kept is not None and back.size:
        for a, b in zip(list(st) + per_run, kept):
            a[back] = b[back]
    for n in back:
        _run_one(np.int64(n), np.int64(n), False, np.int64(stride), np.int64(inp.k_lo), *inp.args(), rec, st)
        if trajectory is not None and n < trajectory.shape[1] and keep_stride > 0:  # its samples from its record (stride 1)
            trajectory[:, n] = trajectory_samples(rec.out[n:n + 1, :inp.t.size], inp.k_lo, keep_stride)[:, 0]
    return handed_back == 0 if online else None


def _with_restarts(call: Callable[[], None], probe: bool, inp: CompiledInputs, rec: LoopRecord, st: LoopState, runs: np.ndarray) -> None:
    """``call()`` (a block of the loop into ``rec`` and ``st``, whose row ``r`` is run ``runs[r]``
    of ``inp``), then, while a run paused at a restart whose constants are not known yet
    (:func:`_run_one`: flight modes, a later entry into TRACK), those constants computed
    (:func:`_restart_constants`) and the block run again from the state it started from: the same
    bits as if they had been known from the start (the loop is deterministic, and what it carries
    is all in ``st`` and the record's per-run fields)."""
    if probe or inp.modes.restart_coef.shape[1] == 0:  # the probe finds first starts; without modes there is no restart
        call()
        return
    while True:
        kept = [a.copy() for a in st] + [rec.rejected.copy(), rec.mode_run.copy()]
        rec.start[:, 0] = -1.0
        call()
        paused = np.flatnonzero(rec.start[:, 0] >= 0.0)
        if paused.size == 0:
            return
        _restart_constants(inp, rec.start, paused, runs)
        for a, b in zip(list(st) + [rec.rejected, rec.mode_run], kept):
            a[...] = b


def _restart_constants(inp: CompiledInputs, start: np.ndarray, rows: np.ndarray, runs: np.ndarray) -> None:
    """The start constants of the restarts at which record rows ``rows`` paused (``start``: each
    row's sample, time, error quaternion and start index) into ``inp.modes`` (in place: every block
    of the run shares its arrays), by the controller's own start (:func:`~sappc_controller.core.packing.start_coef`,
    the first start's checks and RPF policy)."""
    md = inp.modes
    try:
        c, _ = start_coef(inp.config, start[rows, 2:6], on_infeasible=inp.on_infeasible)
    except SingularStartError as exc:  # the run's index in inp
        raise SingularStartError(exc.q_e0, int(runs[rows[exc.run]])) from None
    for i, r in enumerate(rows):
        n, s = int(runs[r]), int(start[r, 6])
        md.restart_coef[n, s - 1] = c[i]
        md.starts_known[n] = s + 1


def run_single(inp: CompiledInputs, n: int = 0, stride: int = 1) -> CompiledRun:
    """Run ``n`` of ``inp`` alone (one thread), the whole run: histories with a leading axis of length 1."""
    inp = inp.whole()
    _check_noise(inp)
    rec = _record(inp, stride, 1)
    st = _state(inp, 1)
    _with_restarts(lambda: _run_alone(n, False, stride, inp, rec, st), False, inp, rec, st, np.array([n], dtype=np.int64))
    return CompiledRun(inp.t[::stride] if stride else inp.t[:0], rec)


def simulate_compiled(scenario: Scenario, controller: Any = None) -> CompiledRun:
    """The scenario as written, one run, full histories (the compiled ``sappc simulate`` loop)."""
    return run_single(prepare(scenario, controller), 0, 1)


# ============================================================================= compile once

#: The groups of :func:`warm_up`, each compilable in its own process: the one-run loop (``simulate``,
#: a batch of one run), the batch loop (campaigns, tuning: parallel over runs; it calls the one-run
#: loop's compiled ``_run_one``, so compiled after it, it adds only its own ~9 s), the SIMD lanes
#: (a campaign's runs where :mod:`sappc.offline.lanes` covers them) and the kernels the nodes and
#: ``sappc rerun`` call from Python.  A first ``sappc simulate`` compiles ``loops`` alone.
WARM_UP_GROUPS = ("loops", "batches", "lanes", "nodes")
#: The groups a campaign calls: the one-run loop (each run's start), the batch loop, the SIMD lanes
#: (:mod:`sappc.offline.lanes`: a group of its own, compiled beside the other two).
CAMPAIGN_GROUPS = ("loops", "batches", "lanes")
#: The groups that compile in one process, in this order, when :func:`warm_up` compiles in parallel.
_TOGETHER = {"batches": "loops"}
#: The groups this process has checked (:func:`ensure_compiled`).
_checked: set[str] = set()


def _entry_kernels(group: str) -> tuple[Any, ...]:
    """The kernels whose cache decides whether ``group`` must compile (its entry points, the last
    compiled of each group among them)."""
    if group == "loops":
        return (_run_one,)
    if group == "batches":
        return (run_batch_kernel,)
    if group == "lanes":
        return (_lanes().run_lanes_kernel,)
    from sappc_controller.core.kernels import controller_step_batch, controller_step_one
    from spacecraft_sim.core.kernels import fault_actuator_one, fault_sensor_one, propagate_runs

    return (controller_step_one, controller_step_batch, propagate_runs, fault_sensor_one, fault_actuator_one)


def cache_is_warm(groups: tuple[str, ...] = ("loops",)) -> bool:
    """Whether numba's on-disk cache holds the entry kernels of ``groups`` (:data:`WARM_UP_GROUPS`)
    for the current sources (no compile needed)."""
    for kernel in (k for g in groups for k in _entry_kernels(g)):
        try:
            if not kernel._cache._cache_file._load_index():  # empty when absent or stale (source stamp)
                return False
        except Exception:  # numba internals moved: assume warm, print nothing
            return True
    return True


def ensure_compiled(*, in_subprocess: bool = False, groups: tuple[str, ...] = ("loops",)) -> None:
    """Once per process, before the first kernel call: when the cache is cold for ``groups`` (first
    use after an install or a change of the sources), say so in one line on stderr and compile
    them now (:func:`warm_up`; by default the offline loops, what the offline commands call: a node
    compiles its own kernels at its start), so that later processes (campaign workers included)
    only load them.

    ``in_subprocess``: compile in child processes (a parent about to fork workers keeps numba's
    thread pool unstarted); several groups then compile at once when there are several CPUs."""
    todo = tuple(g for g in groups if g not in _checked)
    if not todo:
        return
    _checked.update(todo)
    cold = tuple(g for g in todo if not cache_is_warm((g,)))
    if not cold:
        return
    print(f"sappc: compiling the numerical core's {' and '.join(cold)} once (~30 s; later runs load them from the cache)...",
          file=sys.stderr, flush=True)
    if in_subprocess:
        parallel = (os.cpu_count() or 1) > 1  # warm_up runs one group in place
        _compile_in_children([(cold, parallel)])
    else:
        warm_up(cold)


#: Longest a compile child may take to end after SIGTERM before it is killed [s]: SIGTERM's default
#: action ends it at once, so this bounds only a child that something made ignore it (which would
#: otherwise keep compiling after the command ended).
COMPILE_CHILD_EXIT_S = 5.0
#: Whether this process is a compile child (:func:`_compile_child`): its own children then stay in
#: its process group, which its parent terminates as a whole.
_in_compile_child = False


def _compile_in_children(jobs: list[tuple[tuple[str, ...], bool]]) -> None:
    """Run :func:`warm_up` ``(groups, parallel)`` of each job in a child process, all at once, and
    wait for them.

    A child is in a process group of its own (a new session), so the terminal's Ctrl-C reaches
    this process alone and no child prints a ``KeyboardInterrupt`` traceback; when this process is
    interrupted (Ctrl-C, SIGTERM turned into an exception, any error) while they compile, it
    terminates each child's group (the child and the processes it started) and waits for them,
    :data:`COMPILE_CHILD_EXIT_S` at most before killing them, and only then re-raises: nothing
    compiles on after the command has ended.  Inside a compile child, its own children stay in
    its group instead (the group its parent terminates).

    Raises
    ------
    RuntimeError
        When a child fails (its output above says why).
    """
    import signal

    children = [_start_compile_child(f"_compile_child({groups!r}, parallel={parallel})") for groups, parallel in jobs]
    try:
        codes = [child.wait() for child in children]
    except BaseException:
        try:  # a second Ctrl-C does not cut the waiting short (the command's entry ignores it afterwards too)
            signal.signal(signal.SIGINT, signal.SIG_IGN)
        except ValueError:  # not the main thread: it cannot receive Ctrl-C anyway
            pass
        _end_compile_children(children)
        raise
    failed = [g for (groups, _), code in zip(jobs, codes) if code != 0 for g in groups]
    if failed:
        raise RuntimeError(f"compiling the numerical core's group(s) {failed} failed (exit statuses {codes}); the output above says why")


def _start_compile_child(call: str, env: dict[str, str] | None = None) -> Any:
    """A child process running ``call`` of this module (a new session unless this process is a
    compile child itself: :func:`_compile_in_children`), with ``env`` added to this process's
    environment."""
    import subprocess

    return subprocess.Popen([sys.executable, "-c", f"from sappc.offline.compiled_loop import {call.split('(')[0]}; {call}"],
                            start_new_session=not _in_compile_child, env={**os.environ, **env} if env else None)


def _end_compile_children(children: Sequence[Any]) -> None:
    """Terminate each compile child's group (or the child alone inside a compile child), wait
    :data:`COMPILE_CHILD_EXIT_S` at most, then kill what is left."""
    import signal
    import subprocess

    own_group = not _in_compile_child

    def stop(child: subprocess.Popen[bytes], sig: int) -> None:
        try:
            if own_group:
                os.killpg(child.pid, sig)
            else:
                os.kill(child.pid, sig)
        except ProcessLookupError:  # already gone
            pass

    for child in children:
        stop(child, signal.SIGTERM)
    for child in children:
        try:
            child.wait(timeout=COMPILE_CHILD_EXIT_S)
        except subprocess.TimeoutExpired:
            stop(child, signal.SIGKILL)
            child.wait()
        if own_group:  # what the child started in its group and left behind
            stop(child, signal.SIGKILL)


def _compile_child(groups: tuple[str, ...] | str, *, parallel: bool = False) -> None:
    """The entry of a compile child (:func:`_compile_in_children`): :func:`warm_up`, which SIGTERM
    or SIGINT ends at once and quietly (the signals' default action: an exception raised from a
    handler could land in a finalizer of numba's, be printed and ignored there, and the compile
    go on).  Nothing is lost: numba writes a cache file under a temporary name and renames it
    when complete, and the kernels of its own children, in its process group, end with it."""
    import signal

    global _in_compile_child
    _in_compile_child = True
    signal.signal(signal.SIGINT, signal.SIG_DFL)  # Python's own handler raises KeyboardInterrupt; SIGTERM's is the default already
    warm_up(groups, parallel=parallel)


def _leaf_calls(inp: CompiledInputs) -> list[tuple[Any, tuple[Any, ...]]]:
    """The kernels :func:`_run_one` calls out of line, in the order the compile's leaf process
    compiles them (:func:`_compile_leaves`), each with arguments of the types the loop gives it:
    the loop's own expressions on run 0's rows of ``inp``'s arrays and of a fresh
    :class:`LoopState` and :class:`LoopRecord` (numba types an array by its dtype, dimensions and
    layout, not its size, so the warm-up scenario's empty wheel, orbit and mode arrays type as a
    flight's).

    The order (measured on a cold cache, two cores, by numba's compile events in both processes):
    first the two the loop's typing reaches first, the run's initial state and the sensor fault,
    which the leaf process finishes while numba inlines and rewrites the loop's body (about 5 s
    before its typing begins); then the benchmark and mode laws (the HOLD/SAFE step is a copy of
    the law: 2 s); then the sample's second half, the last called first; the MEKF's step last:
    the loop's typing reaches it first, at about 6 s, and compiles it itself.  Each leaf is
    compiled by the first of the two processes to claim it (:func:`_leaf_process`): the loop's
    typing goes forward, the leaf process mostly backward, and they meet in the middle; numba
    loads each leaf the other compiled from the cache.  A call site changed
    in the loop and not here costs only time (the loop compiles that leaf itself); the loop's
    compile says so in one line (:func:`_leaf_mismatches`), which ``tests/test_install.py`` looks
    for."""
    from sappc_controller.core.kernels import blfppc_law, mrp_feedback_law, trappc_transform

    st, rec = _state(inp, 1), _record(inp, 1, 1, 1)
    n = r = 0
    ctrl, plant, act, faults, env, mm, md = inp.controller, inp.plant, inp.actuator, inp.faults, inp.environment, inp.momentum, inp.modes
    t, k, dt = 0.0, 0, inp.grid.dt
    vec3, x = st.vec3[r], st.x[r]
    x_q = x[:4]
    prm, coef, state, work, out = ctrl.prm[n], ctrl.coef[n], st.ctrl[r], st.work[r], st.out[r]
    J, J_inv, G, G_pinv, wprm = plant.J[n], plant.J_inv[n], act.G[n], act.G_pinv[n], act.params[n]
    uw, wspeed, wwork, wtmp = st.uw[r], st.wspeed[r], st.wwork[r], st.wtmp[r]
    e_orbit, e_field, e_gravity, e_Gt, e_mmax, e_mag, e_draws = env.orbit[n], env.field[n], env.gravity[n], env.Gt[n], env.m_max[n], env.mag[n], env.mag_draws[n]
    r_N, B_N, B_B, L_env, B_meas = vec3[V_R_N], vec3[V_B_N], vec3[V_B_B], vec3[V_L_ENV], vec3[V_B_MEAS]
    m_cmd, tau_w, m_B, u_cmd, u_last, d = st.m_cmd[r], vec3[V_TAU_W], vec3[V_M_B], vec3[V_U_CMD], vec3[V_U_LAST], vec3[V_D]
    mm_rows = (mm.prm[n], mm.Gs[n], mm.Js[n], mm.Gs_pinv[n], mm.u_max[n], mm.Gt[n], mm.steering[n], mm.m_max[n], mm.orbit[n], mm.field[n])
    return [
        (_initial_state, (n, r, plant, inp.sensors, inp.estimator, md, st, rec)),
        (fault_sensor, (t, faults.kind[n], faults.window[n], faults.params[n], faults.samples[n], st.fcount[r], st.fbuf[r], faults.draws[0], st.y[r])),
        (trappc_transform, (prm, coef, t, work, out)),
        (mrp_feedback_law, (prm, state, dt, work, out)),
        (blfppc_law, (prm, coef, state, t, dt, work, out)),
        (mrp_feedback_step, (t, dt, x_q, x_q, x_q, u_cmd, u_cmd, md.hold_prm[n], coef, st.hctrl[r], st.hwork[r], st.hout[r])),
        (wheel_torques, (tau_w, G_pinv, G, wprm, x, uw)),
        (torque_of, (e_orbit, e_gravity, e_Gt, e_mmax, x_q, r_N, B_B, m_cmd, vec3[V_R_B_TMP], vec3[V_L_MTB_TMP], L_env)),
        (propagate_wheels_into, (x, uw, d, dt, plant.substeps, J, J_inv, G, wprm, wwork, wtmp)),
        (momentum_management_step, (*mm_rows, t, wspeed, B_meas, st.q_ff[r], vec3[V_OMEGA_FF], u_last, m_cmd, tau_w, st.mtmp[r], st.mst[r])),
        (dipole_mapping, (mm.steering[n], m_B, mm.m_max[n], m_cmd)),
        (bdot_step, (md.bdot[n], B_meas, t, st.bdot[r], m_B)),
        (measured_field_of, (e_mag, e_draws, k, k, B_B, B_meas)),
        (field_of, (e_orbit, e_field, t, x_q, r_N, B_N, B_B)),
        (fault_actuator, (t, faults.kind[n], faults.window[n], faults.params[n], faults.samples[n], st.fcount[r], st.fbuf[r], u_cmd, u_last)),
        (mode_step, (st.mode[r], st.mode_in[r], md.prm[n])),
        (attitude_error_angle, (x_q, st.yc[r][:4], st.q_err[r])),
        (wheel_speeds_into, (x, G, wprm, wspeed)),
        (error_quaternion, (x_q, x_q, st.pub[r][O_QBR])),
        (mekf_step, (inp.estimator.prm[n], t, st.ye[r], st.est[r], st.P[r], st.ework[r], st.eout[r])),
    ]


def _leaf_signatures(inp: CompiledInputs) -> list[tuple[Any, tuple[Any, ...]]]:
    """:func:`_leaf_calls` as (kernel, numba argument types)."""
    from numba import typeof

    return [(kernel, tuple(typeof(a) for a in args)) for kernel, args in _leaf_calls(inp)]


def _leaf_inputs() -> CompiledInputs:
    """The warm-up's inputs before the probe (:func:`prepare` with ``started=False``)."""
    scenario = _warm_up_scenario()
    return prepare(scenario, on_infeasible="clamp", sensor_params=white_noise_params(1e-7, 1e-7), q_BN0=np.atleast_2d(scenario.q_BN0),
                   whole=False, started=False)


def _compile_leaves() -> None:
    """The entry of the compile's leaf process (:func:`_leaf_process`): compile (or load) each of
    :func:`_leaf_calls`' kernels in its order; SIGTERM ends it at once (the loop's compile
    has no use for it once done: :func:`_compile_child` says why nothing is lost)."""
    import signal

    global _in_compile_child
    _in_compile_child = True
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    claims = os.environ.get(_LEAF_CLAIMS_ENV, "")
    with collector.held():  # (a compile: gnc_common.collector)
        for kernel, sig in _leaf_signatures(_leaf_inputs()):
            if claims and not _claim(claims, kernel):
                continue  # the loop's compile has claimed it (compiled, or compiling it)
            kernel.compile(sig)
            if claims:
                _claim(claims, kernel, ".done")
        for kernel in _metrics_kernels():  # then what an offline command calls once the loop is done
            kernel.dispatcher  # noqa: B018  (made with its explicit signature: compiled, or loaded from the cache)


def _metrics_kernels() -> tuple[Any, ...]:
    """The metrics' kernels an offline command calls after the loop (explicit signatures): the
    compile's leaf process compiles them last, beside the loop's lowering, so that the command
    loads them instead of compiling them after its run (about 1.7 s for the record's metrics)."""
    from sappc.evaluation import metrics

    return (metrics._update_kernel, metrics._estimate_kernel)


#: The environment variable that turns the compile's leaf process off (``0``): a machine with one
#: CPU gains nothing from it (:func:`_leaf_process` starts it only with two or more).
LEAF_PROCESS_ENV = "SAPPC_COMPILE_LEAVES"
#: The environment variable that gives the compile's leaf process the folder of the leaves' claims
#: (:func:`_claim`).
_LEAF_CLAIMS_ENV = "SAPPC_COMPILE_LEAF_CLAIMS"
#: How often the loop's compile looks again whether a leaf it waits for is compiled [s].
_CLAIM_POLL_S = 0.01


#: The name of a claims folder (:func:`_leaf_process`): this prefix, the compiling process's id, a
#: dash and a random part; in numba's cache directory.
_CLAIMS_PREFIX = "leaf-claims-"


def _remove_stale_claims(cache_dir: str) -> None:
    """Remove the claims folders in ``cache_dir`` whose compiling process is gone: a compile
    ended by a signal (Ctrl-C ends a compile child at once: :func:`_compile_child`) leaves its
    folder behind, and the next compile removes it."""
    import shutil

    for entry in os.scandir(cache_dir):
        if not (entry.is_dir() and entry.name.startswith(_CLAIMS_PREFIX)):
            continue
        try:
            os.kill(int(entry.name[len(_CLAIMS_PREFIX):].split("-", 1)[0]), 0)
        except ProcessLookupError:  # its process is gone
            shutil.rmtree(entry.path, ignore_errors=True)
        except (ValueError, PermissionError):  # not a name of ours, or another user's live process
            continue


def _claim_path(folder: str, kernel: Any, suffix: str = "") -> str:
    """The file of ``kernel``'s claim in ``folder`` (``suffix`` ``.done``: its mark of done)."""
    return os.path.join(folder, f"{kernel.__module__}.{kernel.__qualname__}{suffix}")


def _claim(folder: str, kernel: Any, suffix: str = "") -> bool:
    """Create ``kernel``'s claim file in ``folder`` (with ``suffix`` ``.done``: its mark that the
    claim's compile is done) unless it exists (an exclusive create); whether this call created it.
    Of the loop's compile and the leaf process, the first to claim a leaf compiles it, and the
    other does not (:func:`_leaf_process`)."""
    try:
        os.close(os.open(_claim_path(folder, kernel, suffix), os.O_CREAT | os.O_EXCL | os.O_WRONLY))
    except FileExistsError:
        return False
    return True


def _claimed_load(load: Callable[..., Any], folder: str, kernel: Any, child: Any) -> Callable[..., Any]:
    """``kernel``'s cache lookup ``load`` (numba's ``load_overload``) in the loop's compile: a miss
    claims the leaf for this process (then compiles it), unless the leaf process has claimed it:
    then it waits for that compile (or for the leaf process's end) and looks again (a signature
    the leaf process did not compile is a miss again: this process compiles it)."""
    import time

    done = _claim_path(folder, kernel, ".done")
    mine: list[bool] = []  # whether this process holds the claim

    def claimed_load(sig: Any, target_context: Any) -> Any:
        cres = load(sig, target_context)
        if cres is not None or mine:
            return cres
        if _claim(folder, kernel):
            mine.append(True)
            return None
        while not os.path.exists(done) and child.poll() is None:
            time.sleep(_CLAIM_POLL_S)
        return load(sig, target_context)

    return claimed_load


@contextlib.contextmanager
def _leaf_process(leaves: CompiledInputs) -> Iterator[None]:
    """Around the loop's compile on a cold cache: a child process compiling the loop's leaves
    (:func:`_leaf_calls`; ``leaves`` their inputs here, :func:`_leaf_inputs`) while this one types the loop from its start, so that the two meet in
    the middle; ended (terminated, its group with it) when the loop is compiled,
    or when this process is interrupted.  Only with two or more CPUs and without
    ``SAPPC_COMPILE_LEAVES=0``.

    No leaf is compiled twice: each is claimed (:func:`_claim`, a file in a folder of numba's cache
    directory, removed afterwards; :func:`_remove_stale_claims` removes one a signal left) by
    the first of the two processes to need it; the leaf process passes over a leaf the loop's
    typing has claimed, and the loop's typing, at a leaf the leaf process is compiling, waits for
    it and loads it from the cache (numba's cache lookup of each leaf wrapped for the compile:
    :func:`_claimed_load`; where numba's internals have moved, no wait, only a compile twice)."""
    if (os.cpu_count() or 1) < 2 or os.environ.get(LEAF_PROCESS_ENV, "1") == "0":
        yield
        return
    import shutil
    import tempfile

    os.makedirs(CACHE_DIR, exist_ok=True)  # (numba makes it at its first save)
    _remove_stale_claims(CACHE_DIR)
    folder = tempfile.mkdtemp(prefix=f"{_CLAIMS_PREFIX}{os.getpid()}-", dir=CACHE_DIR)
    child = _start_compile_child("_compile_leaves()", {_LEAF_CLAIMS_ENV: folder})
    wrapped = []
    try:
        for kernel, _ in _leaf_calls(leaves):
            try:
                cache = kernel.dispatcher._cache
                cache.load_overload = _claimed_load(cache.load_overload, folder, kernel, child)
            except AttributeError:  # numba's internals moved: this leaf may be compiled twice
                continue
            wrapped.append(cache)
        yield
    finally:
        for cache in wrapped:
            del cache.load_overload  # (numba's own method again)
        _end_compile_children([child])
        shutil.rmtree(folder, ignore_errors=True)


def _leaf_mismatches(leaves: CompiledInputs) -> list[str]:
    """After the loop's compile in this process: the leaves whose argument types in
    :func:`_leaf_calls` (of ``leaves``, :func:`_leaf_inputs`) are not among those the loop called
    them with (so the leaf process compiled them in vain)."""
    names = []
    for kernel, sig in _leaf_signatures(leaves):
        if sig not in kernel.dispatcher.overloads:
            names.append(kernel.__qualname__)
    return names


def warm_up(groups: tuple[str, ...] | str = WARM_UP_GROUPS, *, parallel: bool = False) -> None:
    """Compile (or load) every kernel the offline runs, the campaigns and the nodes call, on a tiny
    scenario: the single-run and batch loops (every controller kind, every disturbance kind, sensor
    noise), the set-up kernels, and the nodes' kernels.  ``sappcw`` calls it once after building the
    venv.

    ``groups``: which of :data:`WARM_UP_GROUPS` (one name, or several).  ``parallel``: each group in
    its own child process, at the same time (numba compiles on one thread; the two groups share no
    entry point, and each child writes its kernels into the same cache): on two idle cores the
    compile takes the longer group's time instead of the sum."""
    names = (groups,) if isinstance(groups, str) else tuple(groups)
    unknown = [g for g in names if g not in WARM_UP_GROUPS]
    if unknown:
        raise ValueError(f"warm_up groups must be among {WARM_UP_GROUPS}, got {unknown}")
    if parallel and len(names) > 1:  # one child a chain of groups (a group after the one it calls)
        chains: dict[str, list[str]] = {}
        for g in names:
            chains.setdefault(_TOGETHER.get(g, g) if _TOGETHER.get(g) in names else g, []).append(g)
        _compile_in_children([(tuple(sorted(chain, key=WARM_UP_GROUPS.index)), False) for chain in chains.values()])
        return
    with collector.held():  # numba's compiler makes hundreds of thousands of lasting objects (gnc_common.collector)
        _warm_up_here(names)


def _warm_up_here(names: tuple[str, ...]) -> None:
    """:func:`warm_up` of ``names`` in this process."""
    import time

    started = time.monotonic()

    def compiled(group: str) -> None:  # progress: numba prints nothing while it compiles (about 40 s in all)
        print(f"sappc: numerical core: {group} ready ({time.monotonic() - started:.0f} s)", file=sys.stderr, flush=True)

    scenario = _warm_up_scenario()
    _checked.update(names)
    if "loops" in names:
        if cache_is_warm(("loops",)):
            _warm_up_loops(scenario, compiled)
        else:  # a cold loop: its late leaves compiled beside it
            leaves = _leaf_inputs()  # (once: the claims' kernels, then the check below)
            with _leaf_process(leaves):
                _warm_up_loops(scenario, compiled)
            mismatched = _leaf_mismatches(leaves)
            if mismatched:
                print(f"sappc: the compile's leaf process typed {', '.join(mismatched)} unlike the loop (_leaf_calls): "
                      "it compiled those in vain", file=sys.stderr, flush=True)
    if "batches" in names:
        _warm_up_batches(scenario, compiled)
    if "lanes" in names:
        _warm_up_lanes(scenario, compiled)
    if "nodes" in names:
        _warm_up_nodes(scenario, compiled)


def load_before_fork(scenario: Scenario) -> None:
    """Do here, once, what each of a campaign's workers would do first, before they are forked
    (they share this process's memory): numba's first use of its CPU target (which imports its
    array functions and, through them, scipy's linear algebra: about 0.4 s of CPU a process) and
    the start's kernels (the batch's probe :func:`probe_batch_kernel`,
    :func:`~sappc_controller.core.packing.start_coef`), by preparing two runs of ``scenario``.  The
    parallel kernels are left to the workers: loading one starts numba's thread pool, which a
    forked child cannot use (the workers would then come from a fork server, with nothing loaded).
    A scenario whose own run cannot start (a campaign may disperse it away from a singular start)
    leaves the rest to the workers."""
    with contextlib.suppress(ConfigError, SingularStartError):
        prepare(scenario, on_infeasible="clamp", q_BN0=np.broadcast_to(scenario.q_BN0, (PROBED_RUNS, 4)))


#: Runs :func:`load_before_fork` prepares: more than one, so that the start's probe is the batch's
#: (:func:`probe_batch_kernel`, what a worker's chunk calls), not the one-run loop's.
PROBED_RUNS = 2


def _warm_up_scenario() -> Scenario:
    """The tiny scenario :func:`warm_up` runs (every controller kind's config, two disturbance kinds)."""
    from sappc.scenario import scenario_from_mapping

    raw = {
        "name": "warm_up", "duration_s": 0.05, "control_period_s": 0.01,
        "plant": {"inertia_kg_m2": [[4.0, 0.0, 0.0], [0.0, 4.0, 0.0], [0.0, 0.0, 4.0]], "rk4_substeps": 1},
        "initial_state": {"q_BN": [0.1, 0.1, 0.1, 0.9848857801796104], "omega_BN_B_rad_s": [0.0, 0.0, 0.0]},
        "reference": {"q_RN0": [0.0, 0.0, 0.0, 1.0], "amplitude_deg_s": 0.573, "periods_s": [40.0, 30.0, 50.0]},
        "disturbances": [{"kind": "paper_periodic", "omega_p_rad_s": 0.01},
                         {"kind": "random", "sigma_Nm": [1e-3, 1e-3, 1e-3], "hold_s": 0.02, "seed": 1}],
        "actuator": {"max_torque_Nm": 0.5, "min_torque_Nm": 0.005},
        "metrics": {"steady_from_s": 0.02, "settle_threshold": 1e-3, "t2_s": 0.03},
        "controller": "sappc",
        "controllers": {
            "sappc": {"rpf": {"rho_e0": 0.4, "rho_einf": 1e-6, "l": 0.2, "t2_s": 20.0, "g_inf": 3e-5}, "B0": 0.016, "theta_deg": 10.0,
                      "gains": {"K_q": 0.3, "K_omega": 0.35, "D_m_Nm": 0.05, "mu_rad_s": 7e-5, "p": 0.1, "T1_s": 3.0, "T2_s": 3.0,
                                "T3_s": 2.0, "V_floor": 1e-12, "q0_floor": 1e-3}},
        },
    }
    return scenario_from_mapping(raw)


def _warm_up_cases(scenario: Scenario, n_runs: int) -> tuple[CompiledInputs, CompiledInputs]:
    """The warm-up's inputs of ``n_runs`` runs, without and with sensor noise."""
    q0 = np.broadcast_to(scenario.q_BN0, (n_runs, 4))
    inp = prepare(scenario, on_infeasible="clamp", sensor_params=white_noise_params(1e-7, 1e-7), q_BN0=q0)
    return inp, inp.subset(0, n_runs, noise=np.zeros((n_runs, inp.t.size, 6)))


def _warm_up_loops(scenario: Scenario, compiled: Any) -> None:
    """The one-run loop, with and without sensor noise, and the set-up kernels."""
    from spacecraft_sim.core.faults import noisy_measurement

    inp, noisy = _warm_up_cases(scenario, 1)
    compiled("the set-up kernels")
    for case in (inp, noisy):
        run_single(case, 0, 1)
        run_batch(case, 1)  # one run: the one-run kernel (run_batch)
        compiled("the offline loop (one run)" + (" with sensor noise" if case is noisy else ""))
    noisy_measurement(np.array([0.0, 0.0, 0.0, 1.0]), np.zeros(3), np.zeros(6), 1e-7, 1e-7)


def _warm_up_batches(scenario: Scenario, compiled: Any) -> None:
    """The batch loop (parallel over runs), with and without sensor noise."""
    for case in _warm_up_cases(scenario, 2):
        run_batch(case, 1)
        run_batch(case, 0)
    compiled("the offline loop (batches)")


def _warm_up_lanes(scenario: Scenario, compiled: Any) -> None:
    """The loop in SIMD lanes (:mod:`sappc.offline.lanes`; one compile whatever the disturbance:
    whether it is a table is a value of its arrays, not a type; two for the flight stack, with and
    without it: :func:`~sappc.offline.lanes.group_kind`), called directly on inputs before
    their start's probe (:func:`prepare` with ``started=False``): nothing of the one-run loop runs
    (its probe, a lane handed back), so this group compiles beside the loops', not after them (its
    numbers are meaningless: the start constants are zero)."""
    inp = prepare(scenario, on_infeasible="clamp", q_BN0=np.broadcast_to(scenario.q_BN0, (2, 4)), lanes=True, started=False)
    for flight in (False, True):  # both compiled versions (the flight stack's runs on these inputs' exact measurements)
        _lanes().run_lanes_kernel(np.int64(1), np.int64(0), *inp.args(), _record(inp, 1, inp.n_runs), _state(inp, inp.n_runs),
                                  np.zeros(inp.n_runs, dtype=np.int8), *_lanes().no_online_metrics(), _lanes().flight_metrics(None, inp),
                                  _lanes().group_kind(flight))
    compiled("the offline loop (SIMD lanes)")


def _warm_up_nodes(scenario: Scenario, compiled: Any) -> None:
    """The entry points the nodes and ``sappc rerun`` call from Python: the controller step (one run
    and a batch), the plant, the disturbances, the reference, the injector's fault kernels."""
    from spacecraft_sim.core.disturbance import ConstantTorque, DisturbanceSum, PaperPeriodic, PulseTorque, RandomTorque, StepTorque
    from spacecraft_sim.core.dynamics import RigidBody, initial_state
    from spacecraft_sim.core.faults import FAULT_KINDS, FaultSchedule, faults_from_list

    x = initial_state([0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 0.0])
    for J in (np.eye(3), np.stack((np.eye(3), np.eye(3)))):  # the plant node's calls, shared and per-run inertia
        body = RigidBody(J)
        body.propagate(x, np.zeros((1, 3)), 0.01)
        body.derivative(x, np.zeros((1, 3)))
    t2 = np.array([0.0, 0.01])  # every disturbance kind's torque_B (the injector node)
    DisturbanceSum((PaperPeriodic(), ConstantTorque((0.0, 0.0, 0.0)), StepTorque(0.0, (0.0, 0.0, 0.0)),
                    PulseTorque(0.0, 1.0, (0.0, 0.0, 0.0)), RandomTorque((0.0, 0.0, 0.0), 1.0))).torque_B(t2, 1)
    # the injector's per-message fault kernels (one schedule holding every kind)
    every_kind = [{"kind": k, **({"path": "sensor", "samples": 1} if k == "delay" else {}),
                   **({"effectiveness": [1.0, 1.0, 1.0]} if k == "actuator_effectiveness" else {}),
                   **({"bias_Nm": [0.0, 0.0, 0.0]} if k == "actuator_bias" else {})} for k in FAULT_KINDS]
    FaultSchedule(faults_from_list(every_kind)).warm_up()
    compiled("the nodes' plant, disturbance and fault kernels")
    ctrl = scenario.build_controller()
    for q in (scenario.q_BN0, np.stack((scenario.q_BN0, scenario.q_BN0))):
        ctrl.reset()
        ctrl.step(0.0, 0.01, q, np.zeros(q.shape[:-1] + (3,)), np.array([0.0, 0.0, 0.0, 1.0]), np.zeros(3), np.zeros(3))
    compiled("the controller's step")

"""The offline closed loop in SIMD lanes: :data:`LANES` runs of a campaign stepped together.

:func:`sappc.offline.compiled_loop._run_one` steps one run at a time: its SAPPC step is a long
chain of dependent operations and 16 libm calls (docs/performance.md, "SIMD lanes, the
groundwork").  Here a group of :data:`LANES` runs is stepped sample by sample, each stage of the
loop a loop over the group's lanes with the lane index innermost and every lane's values in a
structure of arrays (``(quantity, lane)``), which LLVM's loop vectorizer widens: one vector
instruction per operation for 4 (AVX2) or 8 lanes, and the libm calls to glibc's libmvec
(:mod:`gnc_common.libm`).

One code path: every quantity is computed by the scalar-in, scalar-out pieces the per-run loop
calls (:func:`~sappc_controller.core.kernels.error_state_of`,
:func:`~sappc_controller.core.kernels.sappc_axis_start`, the SMETF's
:func:`~sappc_controller.core.kernels.smetf_start` and
:func:`~sappc_controller.core.kernels.smetf_newton_step`,
:func:`~sappc_controller.core.kernels.sappc_axis_end`,
:func:`~sappc_controller.core.kernels.backstepping_of`,
:func:`~sappc_controller.core.kernels.actuator_of`, the input check's verdicts and the rigid
body's :func:`~spacecraft_sim.core.kernels.rk4_of`), in the per-run loop's order.  What the lanes
add is only their bookkeeping: the SMETF's Newton iterations run until every lane of the group has
converged, each lane frozen from its own convergence on (so each lane takes exactly its own
iterations), and the RPF's phases are per lane.

What the lanes cover (:func:`lanes_refusal` says why a batch is not covered; such a batch runs
per run, as before): the SAPPC law with its torque filter (not its rate filter), the ideal
actuator or reaction wheels (at most :data:`~spacecraft_sim.core.wheels.MAX_LANE_WHEELS`), exact
measurements or the star tracker and the gyro, with or without the MEKF, no fault, no orbit, no
momentum management, no flight modes; the disturbance shared by
every run (its table) or each run's own.  What the lanes cover depends on the scenario only,
never on the batch (one run's disturbance is a table, the batch's may not be), so a run re-run
alone goes the way it went in its campaign.

**The flight stack** (sensors, an estimator or wheels) is stepped run by run inside the lanes, by
the per-run loop's own pieces (:func:`~sappc.offline.compiled_loop.measure_sample`,
:func:`~sappc.offline.compiled_loop.estimate_sample`, :func:`~sappc.offline.compiled_loop.plant_step`,
the wheels' torques and the records' pieces), but for the plant with wheels, stepped in lanes by
the per-run RK4's own pieces (:func:`~spacecraft_sim.core.wheels.propagate_wheels_lanes`, its
bits): the true state lives in the run's rows of the
loop's state, the controller's input (the estimate, or the measurement) goes to the law's vector
stages, and the answer is the per-run loop's (stage 4): a sample whose input is not valid (the
filter gave no confirmed estimate: no data, as the estimator node publishes it) keeps the law's
state and rows, and is answered with the last answer held, or the watchdog's zero.  Its metrics
are online too (the wheels' and the estimator's per-sample pieces of
:mod:`sappc.evaluation.metrics`).  A lane that meets anything the per-run loop alone answers (an
input the controller's check rejects, a non-finite torque) is **handed back**: its record and
state for the block are computed again by :func:`~sappc.offline.compiled_loop._run_one` from the
state the block started with (kept by the caller for the flight stack, whose lanes step the
run's rows in place).

A campaign's metrics are computed here too, as the lanes go (:func:`online_metrics`): after each
sample's answer a fourth stage feeds each lane's metric state (rows of the scratch array) to
:func:`~sappc.evaluation.metrics.metric_sample_of`, the per-sample piece the record's metrics
kernel calls, and the record keeps only the answers (and, ``keep_stride``, the first runs'
trajectories, every ``keep_stride``-th sample of the run, go to an array of their own); a lane handed back leaves its
metrics to its record.

Parity (docs/parity.md, "Campaign runs in SIMD lanes"): with the libm calls vectorised, a lane's
libm results are libmvec's (within 3 ulps of the scalar glibc functions'), everything else the
same IEEE operations in the same order as the per-run loop (``fastmath`` off: no contraction, no
reassociation).  A lane's result does not depend on the other lanes of its group, so run ``K`` of a
campaign is reproduced bit for bit by the lanes alone (``sappc simulate --from-campaign DIR --run
K``, a group of one run), on the same host.  ``sappc simulate``, the graph and the nodes keep the
scalar path.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numba import prange

from gnc_common.compiled import error_quaternion, jit, jit_parallel, matvec3_flat_of
from gnc_common.input_check import B_NORM, B_RATE, B_REFERENCE_ACCELERATION, B_REFERENCE_RATE, INPUT_OK, quaternion_verdict, vector_verdict
from sappc_controller.core.kernels import _MAX_NEWTON_ITERATIONS, C_A, C_A1, C_L, C_SIGN, C_T1, KIND_SAPPC, N_OUT, N_PARAMS
from sappc_controller.core.kernels import O_BL, O_BU, O_CMD, O_EPS, O_QBR, O_RHO, O_SAT, O_TORQUE, O_V, O_Z, P_B0, P_RATE_WC, P_TANTH, P_TORQUE_WC, P_UMAX, P_UMIN
from sappc_controller.core.kernels import N_STATE, S_FILTER_ON, S_HAS_PREV, S_PREV, S_SD, S_T0, S_TORQUE_F, S_TORQUE_F_ON
from sappc_controller.core.kernels import actuator_of, backstepping_of, error_state_of, filtered_actuator_of, low_pass_gain, sappc_axis_end
from sappc_controller.core.kernels import sappc_axis_start, smetf_newton_step, smetf_start
from sappc_msgs_py.contract import ANSWER_COMMANDED, ANSWER_HELD, ANSWER_WATCHDOG_ZERO
from spacecraft_sim.core.kernels import disturbance_at, rk4_of
from spacecraft_sim.core.wheels import LANE_L, LANE_U, LANE_X, MAX_LANE_WHEELS, N_WHEEL_LANE_ROWS, propagate_wheels_lanes, wheel_lane_params, wheel_torques

from sappc.evaluation.metrics import N_METRIC_STATE, FlightMetricArrays, MetricArrays, MetricConstants, MetricsAccumulator, SampleGrid
from sappc.evaluation.metrics import estimate_metric_sample, metric_sample_of, metric_state_load, metric_state_store, wheel_metric_sample
from sappc_estimator.core.mekf import EO_B, EO_MON_LEVEL, EO_N_RECOVER, EO_Q, EO_USABLE, MON_ERROR
from spacecraft_sim.core.wheels import wheel_speeds_into
from sappc.offline.compiled_loop import _NS_PER_S, L_HAS_ESTIMATE, L_HAS_LAST, L_LAST_STATE_NS, L_N_STARTS, L_STARTED, V_BIAS, V_BIAS_K, V_CMD, V_U
from sappc.offline.compiled_loop import V_U_CMD, V_U_LAST, _initial_state, estimate_sample, measure_sample, plant_step, record_estimate, record_wheels

if TYPE_CHECKING:
    from sappc.offline.compiled_loop import CompiledInputs

__all__ = ["LANES", "flight_metrics", "group_kind", "has_flight_stack", "lanes_refusal", "no_online_metrics", "online_metrics", "run_lanes_kernel"]

#: Runs per lane group: a multiple of every libmvec width (2, 4 and 8 float64), so that LLVM's
#: vectorised loops have no scalar remainder (which would call the scalar libm for some lanes).
LANES = 8
#: Columns of the lane state kept as (column, lane) arrays: the controller's state rows (the SAPPC
#: law's ``S_SD .. S_T0``, the torque filter's).
_N_CTRL = N_STATE
assert N_PARAMS == 29, "_lane_prm lists the 29 parameters of sappc_controller.core.kernels by index"
assert N_METRIC_STATE == 34, "_metric_rows lists the 34 values of sappc.evaluation.metrics.metric_sample_of's state"


def lanes_refusal(inp: CompiledInputs) -> str | None:
    """Why ``inp``'s runs cannot be stepped in lanes (module docstring), or None when they can."""
    ctrl = inp.controller
    if ctrl.kind != KIND_SAPPC:
        return "the controller is not SAPPC"
    if ctrl.prm.shape[0] and np.any(ctrl.prm[:, P_RATE_WC] > 0.0):
        return "the rate filter is on"
    reasons = [(inp.faults.kind.shape[1] > 0, "faults"), (inp.environment.orbit.shape[1] > 0, "an orbit"),
               (inp.momentum.prm.shape[1] > 0, "momentum management"), (inp.modes.prm.shape[1] > 0, "flight modes"),
               (inp.n_wheels > MAX_LANE_WHEELS, f"more than {MAX_LANE_WHEELS} reaction wheels")]
    for bad, why in reasons:
        if bad:
            return why
    return None


def has_flight_stack(inp: CompiledInputs) -> bool:
    """Whether ``inp``'s runs have the flight stack the lanes step run by run (module docstring):
    sensors, an estimator or reaction wheels."""
    return inp.n_wheels > 0 or inp.sensors.draws.shape[1] > 0 or inp.noise is not None or bool(inp.estimating)  # (noise: drawn per block)


# The rows of a lane group's one scratch array (row, lane): every lane quantity in one array, so
# that LLVM sees one base pointer and constant distances between rows (no aliasing to rule out).
_R_X = 0  # 7: the true state (q_BN, omega_BN_B)
_R_CS = _R_X + 7  # the controller's state rows S_SD .. S_T0
_R_PUB = _R_CS + _N_CTRL  # N_OUT x 4: the rows last published, row major
_R_OUT3 = _R_PUB + 4 * N_OUT  # N_OUT: the per-run loop's out[:, 3] (no law writes it but q_BR's)
_R_PL = _R_OUT3 + N_OUT  # N_PARAMS: the controller's parameters
_R_CF = _R_PL + N_PARAMS  # 5 x 3: the start constants (coef), row major
_R_JL = _R_CF + 15  # 9: J, row major
_R_JI = _R_JL + 9  # 9: J^-1
_R_U = _R_JI + 9  # 3: the torque delivered, clipped to the actuator's limit
_R_D = _R_U + 3  # 3: the disturbance
_R_STARTED = _R_D + 3  # 1.0 once the controller has started
_R_NSTARTS = _R_STARTED + 1  # the controller's starts so far
_R_BAD = _R_NSTARTS + 1  # 1.0 once the lane is handed back
_R_Q = _R_BAD + 1  # 4: q_BR
_R_WBR = _R_Q + 4  # 3 each: omega_e, C_e omega_d, C_e omegadot_d, rho, rho_dot, delta, z
_R_CWD = _R_WBR + 3
_R_CWDD = _R_CWD + 3
_R_RHO = _R_CWDD + 3
_R_RHOD = _R_RHO + 3
_R_DELTA = _R_RHOD + 3
_R_Z = _R_DELTA + 3
_R_EPS = _R_Z + 3  # 3 each: the SMETF's iterate, lower bound, |w|, a, w, a arctan(eps), converged (1.0)
_R_LOW = _R_EPS + 3
_R_ABSW = _R_LOW + 3
_R_A = _R_ABSW + 3
_R_WW = _R_A + 3
_R_ATAN = _R_WW + 3
_R_DONE = _R_ATAN + 3
_R_M = _R_DONE + 3  # N_METRIC_STATE: the run's metric state (online metrics: sappc.evaluation.metrics.metric_sample_of's)
_R_MC = _R_M + N_METRIC_STATE  # 3: the run's metric constants: its steady window's start less the tolerance, its origin, t2's sample
_R_VALID = _R_MC + 3  # 1.0 when the sample is valid (its inputs delivered: the flight stack's estimate confirmed)
_R_STATUS = _R_VALID + 1  # the sample's answer (ANSWER_*)
_R_HASLAST = _R_STATUS + 1  # 1.0 once the controller has answered a valid sample (the watchdog's)
_R_HASEST = _R_HASLAST + 1  # 1.0 when the filter gave the sample its figures
_R_ESTST = _R_HASEST + 1  # the filter's status at the sample
_R_CMD = _R_ESTST + 1  # 3: the answer (what a held sample repeats)
_R_Y = _R_CMD + 3  # 7: the controller's input: the true state (exact measurements), or the flight stack's (the estimate, the measurement)
_R_GAIN = _R_Y + 7  # the torque filter's gain (low_pass_gain of the run's cut-off and the grid's step: the same every sample)
_R_SAVE = _R_GAIN + 1  # the controller's state and published rows before the sample (a sample without a valid input keeps them)
_N_SAVE = _N_CTRL + 4 * N_OUT  # (rows _R_CS ..: the state, then the published rows)
_N_ROWS = _R_SAVE + _N_SAVE
assert _R_PUB == _R_CS + _N_CTRL


def online_metrics(acc: MetricsAccumulator, keep_stride: int = 0, trajectory: np.ndarray | None = None) -> tuple[MetricArrays, MetricConstants]:
    """The lanes' metrics arguments that have them compute ``acc``'s metrics online, sample by
    sample (:func:`run_lanes_kernel`): ``acc``'s per-run arrays and constants
    (:meth:`~sappc.evaluation.metrics.MetricsAccumulator.online_state`), ``acc`` fed every sample
    before the block's; ``keep_stride`` ``s`` > 0: the lanes write every sample whose index in the
    run is a multiple of ``s`` of the first runs into ``trajectory`` (K, M, 6) too
    (:class:`~sappc.evaluation.metrics.MetricConstants`)."""
    return acc.online_state(keep_stride, trajectory)


def group_kind(flight: bool) -> np.ndarray:
    """The lanes' kernel's last argument: an empty array of two dimensions for runs with the flight
    stack (:func:`has_flight_stack`), of one without; its type picks the kernel's compiled version."""
    return np.zeros((0, 0)) if flight else np.zeros(0)


def flight_metrics(acc: MetricsAccumulator | None, inp: CompiledInputs) -> FlightMetricArrays:
    """The lanes' flight-stack metrics argument: ``acc``'s wheel and estimator arrays for ``inp``'s
    block (:meth:`~sappc.evaluation.metrics.MetricsAccumulator.online_flight_state`; ``acc`` None:
    none, the same types)."""
    if acc is None:
        acc = MetricsAccumulator(SampleGrid(1, 1.0), 0, steady_from_s=0.0, settle_threshold=0.0, t2_s=0.0, fault_windows=[])
        return acc.online_flight_state(0, wheels=False, estimating=False)
    return acc.online_flight_state(inp.t.size, wheels=inp.n_wheels > 0, estimating=bool(inp.estimating))


def no_online_metrics() -> tuple[MetricArrays, MetricConstants]:
    """The lanes' metrics arguments for a loop that records its samples instead (the same types as
    :func:`online_metrics`': one compiled kernel)."""
    arrays, consts = MetricsAccumulator(SampleGrid(1, 1.0), 0, steady_from_s=0.0, settle_threshold=0.0, t2_s=0.0, fault_windows=[]).online_state()
    return arrays, consts._replace(on=np.int64(0))


@jit(inline="always")
def _metric_rows(S, w):
    """Lane ``w``'s metric state (rows ``_R_M ..``) as the tuple :func:`metric_sample_of` takes."""
    r = _R_M
    return ((S[r, w], S[r + 1, w], S[r + 2, w], S[r + 3, w], S[r + 4, w], S[r + 5, w], S[r + 6, w], S[r + 7, w], S[r + 8, w], S[r + 9, w],
             S[r + 10, w], S[r + 11, w], S[r + 12, w], S[r + 13, w], S[r + 14, w], S[r + 15, w], S[r + 16, w])
            + (S[r + 17, w], S[r + 18, w], S[r + 19, w], S[r + 20, w], S[r + 21, w], S[r + 22, w], S[r + 23, w], S[r + 24, w], S[r + 25, w],
               S[r + 26, w], S[r + 27, w], S[r + 28, w], S[r + 29, w], S[r + 30, w], S[r + 31, w], S[r + 32, w], S[r + 33, w]))


@jit(inline="always")
def _set_metric_rows(S, w, m):
    """Lane ``w``'s metric state rows set to ``m`` (each item by a constant index: a loop over the
    tuple would index it by a switch, which stops the lane loop's vectorisation)."""
    r = _R_M
    S[r, w], S[r + 1, w], S[r + 2, w], S[r + 3, w], S[r + 4, w], S[r + 5, w] = m[0], m[1], m[2], m[3], m[4], m[5]
    S[r + 6, w], S[r + 7, w], S[r + 8, w], S[r + 9, w], S[r + 10, w], S[r + 11, w] = m[6], m[7], m[8], m[9], m[10], m[11]
    S[r + 12, w], S[r + 13, w], S[r + 14, w], S[r + 15, w], S[r + 16, w], S[r + 17, w] = m[12], m[13], m[14], m[15], m[16], m[17]
    S[r + 18, w], S[r + 19, w], S[r + 20, w], S[r + 21, w], S[r + 22, w], S[r + 23, w] = m[18], m[19], m[20], m[21], m[22], m[23]
    S[r + 24, w], S[r + 25, w], S[r + 26, w], S[r + 27, w], S[r + 28, w], S[r + 29, w] = m[24], m[25], m[26], m[27], m[28], m[29]
    S[r + 30, w], S[r + 31, w], S[r + 32, w], S[r + 33, w] = m[30], m[31], m[32], m[33]


@jit(inline="always")
def _lane_prm(S, w):
    """Lane ``w``'s controller parameters as the tuple the law's pieces index like a parameter row
    (``prm[P_*]``)."""
    r = _R_PL
    return (S[r, w], S[r + 1, w], S[r + 2, w], S[r + 3, w], S[r + 4, w], S[r + 5, w], S[r + 6, w], S[r + 7, w], S[r + 8, w], S[r + 9, w],
            S[r + 10, w], S[r + 11, w], S[r + 12, w], S[r + 13, w], S[r + 14, w], S[r + 15, w], S[r + 16, w], S[r + 17, w], S[r + 18, w],
            S[r + 19, w], S[r + 20, w], S[r + 21, w], S[r + 22, w], S[r + 23, w], S[r + 24, w], S[r + 25, w], S[r + 26, w], S[r + 27, w],
            S[r + 28, w])


@jit(inline="always")
def _nine(S, r, w):
    """Lane ``w``'s 3x3 matrix in rows ``r .. r + 8`` of ``S``, row major, as a 9-tuple."""
    return (S[r, w], S[r + 1, w], S[r + 2, w], S[r + 3, w], S[r + 4, w], S[r + 5, w], S[r + 6, w], S[r + 7, w], S[r + 8, w])


@jit
def _lane_group(g0, stride, k_lo, grid, ctrl, plant, act, sens, est, dist, faults, env, mm, md, rec, st, handed_back, ma, mc, fa, kind):
    """Runs ``g0 .. g0 + LANES - 1`` (the last group's missing lanes repeat its last run, written
    nowhere) over one block of samples, from and into their rows of ``st`` and ``rec`` (row = run,
    as :func:`~sappc.offline.compiled_loop.run_batch_kernel`); a lane handed back (module docstring)
    leaves its rows of ``st`` as they were and sets ``handed_back[run]``.  ``ma``, ``mc``: with
    ``mc.on`` 1 (:func:`online_metrics`), each run's metrics sample by sample into its rows of the
    accumulator's arrays (a lane handed back leaves them as they were), and the record only its
    answers (``rec.status``), and the first runs' samples whose index ``k`` in the run is a
    multiple of ``mc.keep_stride`` (when not 0) into ``mc.trajectory``."""
    W = LANES
    N = plant.x0.shape[0]
    rows = np.empty(W, dtype=np.int64)
    for w in range(W):
        rows[w] = min(g0 + w, N - 1)
    n_real = min(W, N - g0)  # the group's lanes that are runs (the others repeat the last, and compute nothing of the flight stack)
    measuring = sens.draws.shape[1] > 0
    estimating = est.prm.shape[1] > 0
    nw = act.params.shape[1]
    # the flight stack: the true state in st, stepped run by run.  A constant of the compiled
    # function (``kind``'s number of dimensions, :func:`group_kind`): the kernel is compiled twice,
    # and the one without the flight stack has none of its code (fused into the vector stages'
    # function, it slowed them by 8 to 15 %)
    flight = kind.ndim == 2
    if not flight and (measuring or estimating or nw > 0):
        raise ValueError("a batch with the flight stack in the lanes' kernel compiled without it")
    filtered = False  # a lane with the torque filter
    for w in range(W):
        filtered = filtered or ctrl.prm[rows[w], P_TORQUE_WC] > 0.0
    last_ns_w = np.empty(W, dtype=np.int64)  # each lane's last valid sample's stamp [ns]
    qe = np.empty(4)  # the true error quaternion (a flight lane's record)
    qh, m_dq, m_a, m_err, m_A = np.empty(4), np.empty(4), np.empty(3), np.empty(6), np.empty((6, 7))  # the estimation metrics' scratch
    if k_lo == 0:  # the runs' first block: their state before the first sample, as the per-run loop makes it
        for w in range(W):
            if g0 + w < N:
                _initial_state(rows[w], rows[w], plant, sens, est, md, st, rec)
    S = np.empty((_N_ROWS, W))
    D = np.empty((W, 3))  # a run's own disturbance (disturbance_at's output)
    for w in range(W):
        r = rows[w]
        for i in range(7):
            S[_R_X + i, w] = st.x[r, i]
        for i in range(_N_CTRL):
            S[_R_CS + i, w] = st.ctrl[r, i]
        for row in range(N_OUT):
            for c in range(4):
                S[_R_PUB + 4 * row + c, w] = st.pub[r, row, c]
            S[_R_OUT3 + row, w] = st.out[r, row, 3]
        for i in range(N_PARAMS):
            S[_R_PL + i, w] = ctrl.prm[r, i]
        for a in range(5):
            for i in range(3):
                S[_R_CF + 3 * a + i, w] = ctrl.coef[r, a, i]
        for i in range(3):
            for j in range(3):
                S[_R_JL + 3 * i + j, w] = plant.J[r, i, j]
                S[_R_JI + 3 * i + j, w] = plant.J_inv[r, i, j]
        S[_R_STARTED, w] = 1.0 if st.flags[r, L_STARTED] != 0 else 0.0
        S[_R_NSTARTS, w] = st.flags[r, L_N_STARTS]
        S[_R_BAD, w] = 0.0
        S[_R_VALID, w] = 1.0 if (w < n_real or not flight) else 0.0  # (a lane that is no run: no input, no Newton iterations)
        S[_R_STATUS, w] = ANSWER_COMMANDED
        S[_R_HASLAST, w] = 1.0 if st.flags[r, L_HAS_LAST] != 0 else 0.0
        S[_R_HASEST, w] = 1.0 if st.flags[r, L_HAS_ESTIMATE] != 0 else 0.0
        S[_R_ESTST, w] = 0.0
        last_ns_w[w] = st.flags[r, L_LAST_STATE_NS]
        for i in range(3):
            S[_R_CMD + i, w] = st.vec3[r, V_CMD, i]
        for i in range(7):
            S[_R_Y + i, w] = 0.0
        wc = ctrl.prm[r, P_TORQUE_WC]
        S[_R_GAIN, w] = low_pass_gain(wc, grid.dt) if wc > 0.0 else 0.0  # (the actuator computes it at each sample: the same bits)
    # the wheels' lanes (propagate_wheels_lanes: one array, its rows at constant offsets)
    FL = np.zeros((N_WHEEL_LANE_ROWS if flight else 0, W))  # (none in the version without the flight stack: its code is then dead)
    for w in range(W if (flight and nw > 0) else 0):
        r = rows[w]
        wheel_lane_params(plant.J[r], plant.J_inv[r], act.G[r], act.params[r], FL, w)
    online = mc.on != 0
    if online:
        for w in range(W):
            _set_metric_rows(S, w, metric_state_load(ma, rows[w]))
            for i in range(3):
                S[_R_MC + i, w] = mc.per_run[rows[w], i]
    settle_threshold, loss_bound, fault_from = mc.settle_threshold, mc.loss_bound, mc.fault_from
    # The lane loops' trip count, LANES, as a value LLVM cannot fold: a constant count of 8 is
    # unrolled whole before the loop vectorizer sees the loop (and the SMETF's stage is then not
    # vectorised); at run time it is LANES, a multiple of every vector width, so the vectorised
    # loops leave no lane to their scalar remainder.
    nl = W if handed_back.shape[0] >= 0 else 0
    dt = grid.dt
    T = grid.n_samples
    umax = act.max_torque_Nm
    b_norm, b_rate = ctrl.bounds[B_NORM], ctrl.bounds[B_RATE]
    last_ns = 0
    for kb in range(grid.t.shape[0]):
        k = k_lo + kb
        t_ns = grid.t_ns[kb]
        t_stamp = t_ns / _NS_PER_S  # the controller's time (the per-run loop's t_stamp_s)
        rq = (grid.ref_q[kb, 0], grid.ref_q[kb, 1], grid.ref_q[kb, 2], grid.ref_q[kb, 3])
        rw = (grid.ref_w[kb, 0], grid.ref_w[kb, 1], grid.ref_w[kb, 2])
        rwd = (grid.ref_wd[kb, 0], grid.ref_wd[kb, 1], grid.ref_wd[kb, 2])
        ref_ok = (quaternion_verdict(rq[0], rq[1], rq[2], rq[3], b_norm) == INPUT_OK
                  and vector_verdict(rw[0], rw[1], rw[2], ctrl.bounds[B_REFERENCE_RATE]) == INPUT_OK
                  and vector_verdict(rwd[0], rwd[1], rwd[2], ctrl.bounds[B_REFERENCE_ACCELERATION]) == INPUT_OK)
        ref_bad = 0.0 if ref_ok else 1.0
        if dist.use_table:  # shared by every run: its table
            for w in range(W):
                for i in range(3):
                    S[_R_D + i, w] = dist.table[kb, i]
        else:  # each run's own (the per-run loop's disturbance_at)
            for w in range(W):
                disturbance_at(dist, rows[w], kb, grid.t[kb], D[w])
                for i in range(3):
                    S[_R_D + i, w] = D[w, i]
        if not flight:  # the controller's input: the true state (rows at constant distances: a row chosen at run time would
            for w in range(nl):  # keep LLVM from vectorising the stages that read it)
                for i in range(7):
                    S[_R_Y + i, w] = S[_R_X + i, w]
        else:  # stage 0: the sensors and the estimator, run by run (the per-run loop's pieces), into the controller's input
            for w in range(n_real):
                r = rows[w]
                x = st.x[r]
                if estimating:
                    for i in range(3):
                        st.vec3[r, V_BIAS_K, i] = st.vec3[r, V_BIAS, i]
                measure_sample(sens, r, k, kb, grid.t[kb], t_stamp, measuring, x, st.held_q[r], st.vec3[r, V_BIAS], st.y[r])
                given = True
                yc = st.yc[r]
                if estimating:
                    given, has_est, est_status, epoch = estimate_sample(est.prm[r], t_stamp, True, st.y[r], st.epoch[r, 0], st.ye[r], st.est[r],
                                                                        st.P[r], st.ework[r], st.eout[r], yc)
                    st.epoch[r, 0] = epoch
                    S[_R_HASEST, w] = 1.0 if has_est else 0.0
                    S[_R_ESTST, w] = est_status
                else:
                    for i in range(7):
                        yc[i] = st.y[r, i]
                for i in range(7):
                    S[_R_Y + i, w] = yc[i]
                    S[_R_X + i, w] = x[i]  # the true state before the step (the record's)
                S[_R_VALID, w] = 1.0 if given else 0.0
                if not given:  # the law's state and rows, which this sample keeps (stage 4)
                    for i in range(_N_SAVE):
                        S[_R_SAVE + i, w] = S[_R_CS + i, w]
        # stage 1: the input check, the start, the error state, each axis up to the SMETF's solve
        for w in range(nl):
            x = (S[_R_Y, w], S[_R_Y + 1, w], S[_R_Y + 2, w], S[_R_Y + 3, w], S[_R_Y + 4, w], S[_R_Y + 5, w], S[_R_Y + 6, w])
            valid = S[_R_VALID, w] != 0.0  # (a sample without a valid input: its results are dropped, stage 4)
            q_ok = quaternion_verdict(x[0], x[1], x[2], x[3], b_norm) == INPUT_OK
            w_ok = vector_verdict(x[4], x[5], x[6], b_rate) == INPUT_OK
            S[_R_BAD, w] = max(max(S[_R_BAD, w], ref_bad), 0.0 if ((q_ok and w_ok) or not valid) else 1.0)
            kept = S[_R_STARTED, w] != 0.0 or not valid
            T0 = S[_R_CS + S_T0, w] if kept else t_stamp  # the first valid sample fixes the time origin
            S[_R_CS + S_T0, w] = T0
            S[_R_NSTARTS, w] = S[_R_NSTARTS, w] if kept else S[_R_NSTARTS, w] + 1.0
            S[_R_STARTED, w] = 1.0 if (S[_R_STARTED, w] != 0.0 or valid) else 0.0
            q, wbr, cwd, cwdd = error_state_of((x[0], x[1], x[2], x[3]), (x[4], x[5], x[6]), rq, rw, rwd)
            S[_R_Q, w] = q[0]
            S[_R_Q + 1, w] = q[1]
            S[_R_Q + 2, w] = q[2]
            S[_R_Q + 3, w] = q[3]
            S[_R_WBR, w], S[_R_WBR + 1, w], S[_R_WBR + 2, w] = wbr
            S[_R_CWD, w], S[_R_CWD + 1, w], S[_R_CWD + 2, w] = cwd
            S[_R_CWDD, w], S[_R_CWDD + 1, w], S[_R_CWDD + 2, w] = cwdd
            prm = _lane_prm(S, w)
            tau = t_stamp - T0
            has_prev = S[_R_CS + S_HAS_PREV, w] != 0.0
            for i in range(3):
                p = _R_CS + S_PREV + i
                c = _R_CF + i
                rho, rho_dot, delta, z, guess = sappc_axis_start(prm, tau, S[c + 3 * C_SIGN, w], S[c + 3 * C_T1, w], S[c + 3 * C_A1, w],
                                                                 S[c + 3 * C_L, w], S[c + 3 * C_A, w], S[_R_Q + i, w], has_prev, S[p, w],
                                                                 S[p + 3, w], S[p + 6, w], S[p + 9, w], S[p + 12, w])
                eps, lower, abs_w, a, ww = smetf_start(z, delta, prm[P_TANTH], has_prev, guess)
                S[_R_RHO + i, w] = rho
                S[_R_RHOD + i, w] = rho_dot
                S[_R_DELTA + i, w] = delta
                S[_R_Z + i, w] = z
                S[_R_EPS + i, w] = eps
                S[_R_LOW + i, w] = lower
                S[_R_ABSW + i, w] = abs_w
                S[_R_A + i, w] = a
                S[_R_WW + i, w] = ww
                S[_R_ATAN + i, w] = 0.0
                S[_R_DONE + i, w] = 0.0 if valid else 1.0
        # stage 2: the SMETF's Newton iterations, until every lane's solve has converged; each lane
        # frozen from its own convergence on: its iterates are its scalar solve's
        for _ in range(_MAX_NEWTON_ITERATIONS):
            active = 0
            for i in range(3):
                for w in range(nl):
                    a_atan, done, eps_next = smetf_newton_step(S[_R_EPS + i, w], S[_R_LOW + i, w], S[_R_ABSW + i, w], S[_R_A + i, w],
                                                               S[_R_PL + P_TANTH, w])
                    was_done = S[_R_DONE + i, w] != 0.0
                    S[_R_ATAN + i, w] = S[_R_ATAN + i, w] if was_done else a_atan
                    S[_R_EPS + i, w] = S[_R_EPS + i, w] if (was_done or done) else eps_next
                    S[_R_DONE + i, w] = 1.0 if (was_done or done) else 0.0
                    active += 0 if (was_done or done) else 1
            if active == 0:
                break
        # stage 3: the transformation's end, the backstepping law, the actuator, the answer, the plant's input
        for w in range(nl):
            prm = _lane_prm(S, w)
            k_tan = prm[P_TANTH]
            B0 = prm[P_B0]
            e0 = np.copysign(S[_R_EPS, w], S[_R_WW, w])
            e1 = np.copysign(S[_R_EPS + 1, w], S[_R_WW + 1, w])
            e2 = np.copysign(S[_R_EPS + 2, w], S[_R_WW + 2, w])
            P_s0, dd0, psi0, eta0 = sappc_axis_end(k_tan, e0, np.copysign(S[_R_ATAN, w], S[_R_WW, w]), S[_R_DELTA, w], S[_R_RHO, w],
                                                   S[_R_RHOD, w])
            P_s1, dd1, psi1, eta1 = sappc_axis_end(k_tan, e1, np.copysign(S[_R_ATAN + 1, w], S[_R_WW + 1, w]), S[_R_DELTA + 1, w],
                                                   S[_R_RHO + 1, w], S[_R_RHOD + 1, w])
            P_s2, dd2, psi2, eta2 = sappc_axis_end(k_tan, e2, np.copysign(S[_R_ATAN + 2, w], S[_R_WW + 2, w]), S[_R_DELTA + 2, w],
                                                   S[_R_RHO + 2, w], S[_R_RHOD + 2, w])
            p = _R_CS + S_PREV
            S[p, w], S[p + 1, w], S[p + 2, w] = e0, e1, e2
            S[p + 3, w], S[p + 4, w], S[p + 5, w] = P_s0, P_s1, P_s2
            S[p + 6, w], S[p + 7, w], S[p + 8, w] = S[_R_Z, w], S[_R_Z + 1, w], S[_R_Z + 2, w]
            S[p + 9, w], S[p + 10, w], S[p + 11, w] = dd0, dd1, dd2
            S[p + 12, w], S[p + 13, w], S[p + 14, w] = S[_R_DELTA, w], S[_R_DELTA + 1, w], S[_R_DELTA + 2, w]
            S[_R_CS + S_HAS_PREV, w] = 1.0
            q = (S[_R_Q, w], S[_R_Q + 1, w], S[_R_Q + 2, w], S[_R_Q + 3, w])
            sd = _R_CS + S_SD
            cmd, V, S_next = backstepping_of(prm, dt, q, (S[_R_WBR, w], S[_R_WBR + 1, w], S[_R_WBR + 2, w]),
                                             (S[_R_CWD, w], S[_R_CWD + 1, w], S[_R_CWD + 2, w]),
                                             (S[_R_CWDD, w], S[_R_CWDD + 1, w], S[_R_CWDD + 2, w]), (S[_R_Y + 4, w], S[_R_Y + 5, w], S[_R_Y + 6, w]),
                                             (e0, e1, e2), (psi0, psi1, psi2), (eta0, eta1, eta2), S[_R_CS + S_FILTER_ON, w] != 0.0,
                                             (S[sd, w], S[sd + 1, w], S[sd + 2, w]))
            S[_R_CS + S_FILTER_ON, w] = 1.0
            S[sd, w], S[sd + 1, w], S[sd + 2, w] = S_next
            tq0, sat0 = actuator_of(prm[P_UMAX], prm[P_UMIN], cmd[0])
            tq1, sat1 = actuator_of(prm[P_UMAX], prm[P_UMIN], cmd[1])
            tq2, sat2 = actuator_of(prm[P_UMAX], prm[P_UMIN], cmd[2])
            # the per-run loop's test of a refused answer
            finite = np.isfinite(tq0 + tq1 + tq2) and np.isfinite(cmd[0] + cmd[1] + cmd[2])
            S[_R_BAD, w] = max(S[_R_BAD, w], 0.0 if (finite or S[_R_VALID, w] == 0.0) else 1.0)
            # the answer, published (the per-run loop's pub = out; no fault: delivered = commanded)
            for row in range(N_OUT):
                S[_R_PUB + 4 * row + 3, w] = S[_R_OUT3 + row, w]
            S[_R_PUB + 4 * O_TORQUE, w], S[_R_PUB + 4 * O_TORQUE + 1, w], S[_R_PUB + 4 * O_TORQUE + 2, w] = tq0, tq1, tq2
            S[_R_PUB + 4 * O_CMD, w], S[_R_PUB + 4 * O_CMD + 1, w], S[_R_PUB + 4 * O_CMD + 2, w] = cmd
            S[_R_PUB + 4 * O_SAT, w], S[_R_PUB + 4 * O_SAT + 1, w], S[_R_PUB + 4 * O_SAT + 2, w] = sat0, sat1, sat2
            for i in range(3):
                rho = S[_R_RHO + i, w]
                S[_R_PUB + 4 * O_RHO + i, w] = rho
                S[_R_PUB + 4 * O_BL + i, w] = rho - B0
                S[_R_PUB + 4 * O_BU + i, w] = rho + B0
                S[_R_PUB + 4 * O_Z + i, w] = S[_R_Z + i, w]
            S[_R_PUB + 4 * O_EPS, w], S[_R_PUB + 4 * O_EPS + 1, w], S[_R_PUB + 4 * O_EPS + 2, w] = e0, e1, e2
            S[_R_PUB + 4 * O_V, w], S[_R_PUB + 4 * O_V + 1, w], S[_R_PUB + 4 * O_V + 2, w] = V
            S[_R_PUB + 4 * O_QBR, w], S[_R_PUB + 4 * O_QBR + 1, w], S[_R_PUB + 4 * O_QBR + 2, w], S[_R_PUB + 4 * O_QBR + 3, w] = q
            # control (clipped by the actuator), held over [t_k, t_k+1] with the disturbance
            S[_R_U, w] = min(max(tq0, -umax), umax)
            S[_R_U + 1, w] = min(max(tq1, -umax), umax)
            S[_R_U + 2, w] = min(max(tq2, -umax), umax)
        if filtered:  # stage 3b: the torque filter (the actuator's filtered branch), where a lane has it
            for w in range(nl):
                wc = S[_R_PL + P_TORQUE_WC, w]
                if wc > 0.0:
                    lane_umax, lane_umin = S[_R_PL + P_UMAX, w], S[_R_PL + P_UMIN, w]
                    g = S[_R_GAIN, w]
                    first = S[_R_CS + S_TORQUE_F_ON, w] == 0.0
                    S[_R_CS + S_TORQUE_F_ON, w] = 1.0
                    for i in range(3):
                        torque, sat, f = filtered_actuator_of(lane_umax, lane_umin, g, first, S[_R_CS + S_TORQUE_F + i, w], S[_R_PUB + 4 * O_CMD + i, w])
                        S[_R_CS + S_TORQUE_F + i, w] = f
                        S[_R_PUB + 4 * O_TORQUE + i, w] = torque
                        S[_R_PUB + 4 * O_SAT + i, w] = sat
                        S[_R_U + i, w] = min(max(torque, -umax), umax)
                    finite = np.isfinite(S[_R_PUB + 4 * O_TORQUE, w] + S[_R_PUB + 4 * O_TORQUE + 1, w] + S[_R_PUB + 4 * O_TORQUE + 2, w])
                    S[_R_BAD, w] = max(S[_R_BAD, w], 0.0 if (finite or S[_R_VALID, w] == 0.0) else 1.0)
        if flight:  # stage 4: the answer as the per-run loop gives it (a sample without a valid input: held, or the watchdog's zero)
            for w in range(n_real):
                r = rows[w]
                if S[_R_VALID, w] != 0.0:
                    status = ANSWER_COMMANDED
                    S[_R_HASLAST, w] = 1.0
                    last_ns_w[w] = t_ns
                    for i in range(3):
                        S[_R_CMD + i, w] = S[_R_PUB + 4 * O_TORQUE + i, w]
                else:  # the law did not run: its state and rows as they were
                    for i in range(_N_SAVE):
                        S[_R_CS + i, w] = S[_R_SAVE + i, w]
                    if S[_R_HASLAST, w] == 0.0 or t_ns - last_ns_w[w] > ctrl.stale_ns:  # no valid state yet, or too old
                        status = ANSWER_WATCHDOG_ZERO
                        for i in range(3):
                            S[_R_CMD + i, w] = 0.0
                            S[_R_PUB + 4 * O_CMD + i, w] = 0.0
                            S[_R_PUB + 4 * O_SAT + i, w] = 0.0
                    else:
                        status = ANSWER_HELD
                S[_R_STATUS, w] = status
                for i in range(3):  # the answer through the actuator link (no fault: delivered as commanded)
                    c = S[_R_CMD + i, w]
                    st.vec3[r, V_CMD, i] = c
                    st.vec3[r, V_U_CMD, i] = c
                    st.vec3[r, V_U_LAST, i] = c
                    S[_R_PUB + 4 * O_TORQUE + i, w] = c
                if measuring or estimating or status != ANSWER_COMMANDED:  # the true error (metrics)
                    error_quaternion(grid.ref_q[kb], st.x[r, :4], qe)
                    for i in range(4):
                        S[_R_PUB + 4 * O_QBR + i, w] = qe[i]
                if nw > 0:
                    wheel_torques(st.vec3[r, V_U_LAST], act.G_pinv[r], act.G[r], act.params[r], st.x[r], st.uw[r])
        last_ns = t_ns
        if online:  # stage 5: the sample's metrics (the record's quantities at this sample: the state before the step, the answer)
            k_f = float(k)
            t_k = grid.t[kb]
            for w in range(nl):
                ok = True
                for i in range(7):
                    ok = ok and np.isfinite(S[_R_X + i, w])
                for i in range(3):
                    ok = ok and np.isfinite(S[_R_PUB + 4 * O_TORQUE + i, w])
                qb, tb, rb = _R_PUB + 4 * O_QBR, _R_PUB + 4 * O_TORQUE, _R_PUB + 4 * O_RHO
                lb, ub, sb = _R_PUB + 4 * O_BL, _R_PUB + 4 * O_BU, _R_PUB + 4 * O_SAT
                sat = S[sb, w] != 0.0 or S[sb + 1, w] != 0.0 or S[sb + 2, w] != 0.0
                _set_metric_rows(S, w, metric_sample_of(
                    _metric_rows(S, w), k_f, t_k, ok, S[qb, w], S[qb + 1, w], S[qb + 2, w], S[tb, w], S[tb + 1, w], S[tb + 2, w], S[rb, w],
                    S[rb + 1, w], S[rb + 2, w], sat, S[lb, w], S[lb + 1, w], S[lb + 2, w], S[ub, w], S[ub + 1, w], S[ub + 2, w], 0.0, False,
                    S[_R_MC, w], S[_R_MC + 1, w], S[_R_MC + 2, w], settle_threshold, loss_bound, fault_from))
            for w in range(n_real if flight else 0):  # the wheels' and the estimator's metrics, run by run (the record's pieces)
                r = rows[w]
                if fa.wheels != 0:
                    wheel_speeds_into(st.x[r], act.G[r], act.params[r], st.wspeed[r])
                    wheel_metric_sample(r, st.wspeed[r], st.uw[r], fa.dt, fa.wheel_speed_max, fa.wheel_torque_max, fa.wheel_energy)
                if fa.estimating != 0:  # what the record holds (compiled_loop.record_estimate): NaN where the filter had no figures
                    has_est = S[_R_HASEST, w] != 0.0
                    eo = st.eout[r]
                    for i in range(4):
                        qh[i] = eo[EO_Q + i] if (has_est and S[_R_VALID, w] != 0.0) else np.nan
                    v, counted = estimate_metric_sample(r, t_k, mc.per_run[r, 0], fa.nees_from, True, qh, st.x[r], eo[EO_B:EO_B + 3],
                                                        st.vec3[r, V_BIAS_K], st.P[r], fa.att_max, fa.att_sq, fa.att_n, fa.bias_last, fa.nees_sum,
                                                        fa.nees_n, m_dq, m_a, m_err, m_A)
                    if counted:
                        fa.nees_out[kb, r] = v
                        fa.counted[kb, r] = True
                    code = int(S[_R_ESTST, w])
                    if 0 <= code < fa.status_counts.shape[1]:
                        fa.status_counts[r, code] += 1
                    if has_est:
                        level = eo[EO_MON_LEVEL]
                        fa.mon_n[r] += 1 if np.isfinite(level) else 0
                        fa.mon_error[r] += 1 if level == MON_ERROR else 0
                        fa.withheld[r] += 1 if eo[EO_USABLE] == 0.0 else 0
                        if np.isfinite(eo[EO_N_RECOVER]):
                            fa.recoveries[r] = max(fa.recoveries[r], np.int64(eo[EO_N_RECOVER]))
        if stride > 0 and kb % stride == 0:
            j = kb // stride
            for w in range(W):
                r = rows[w]
                if g0 + w >= N:
                    continue
                rec.status[r, j] = ANSWER_COMMANDED if not flight else np.int8(S[_R_STATUS, w])
                if online:  # the metrics are taken: the record keeps only the answers (and the trajectories their samples)
                    if mc.keep_stride > 0 and k % mc.keep_stride == 0 and r < mc.trajectory.shape[1]:
                        _keep_trajectory_sample(mc.trajectory, k, k_lo, mc.keep_stride, r, S, w)
                    continue
                for row in range(N_OUT):
                    for c in range(4):
                        rec.out[r, j, row, c] = S[_R_PUB + 4 * row + c, w]
                for i in range(7):
                    rec.x[r, j, i] = S[_R_X + i, w]
                for i in range(3):
                    rec.d[r, j, i] = S[_R_D + i, w]
                if nw > 0:
                    record_wheels(rec.wheels[r, j], st.x[r], act.G[r], act.params[r], st.wspeed[r], st.uw[r])
                if estimating:
                    record_estimate(rec.estimate[r, j], S[_R_HASEST, w] != 0.0, S[_R_VALID, w] != 0.0, st.eout[r], st.P[r], S[_R_ESTST, w],
                                    st.vec3[r, V_BIAS_K])
        if k < T - 1 and flight and nw > 0:  # the plant with wheels in lanes (the per-run loop's pieces, its bits)
            for w in range(n_real):
                r = rows[w]
                for i in range(7 + nw):
                    FL[LANE_X + i, w] = st.x[r, i]
                for i in range(nw):
                    FL[LANE_U + i, w] = st.uw[r, i]
                for i in range(3):
                    FL[LANE_L + i, w] = S[_R_D + i, w]
            propagate_wheels_lanes(FL, nw, dt, plant.substeps, nl)
            for w in range(n_real):
                r = rows[w]
                for i in range(7 + nw):
                    st.x[r, i] = FL[LANE_X + i, w]
        elif k < T - 1 and flight:  # the plant run by run (the per-run loop's piece: the ideal actuator)
            for w in range(n_real):
                r = rows[w]
                for i in range(3):
                    D[w, i] = S[_R_D + i, w]
                plant_step(st.x[r], st.vec3[r, V_U_LAST], st.uw[r], D[w], dt, umax, plant.substeps, plant.J[r], plant.J_inv[r], act.G[r],
                           act.params[r], st.wwork[r], st.wtmp[r], st.vec3[r, V_U])
        elif k < T - 1:
            h = dt / plant.substeps
            for _ in range(plant.substeps):
                for w in range(nl):
                    Jinv = _nine(S, _R_JI, w)
                    u0, u1, u2 = S[_R_U, w] + S[_R_D, w], S[_R_U + 1, w] + S[_R_D + 1, w], S[_R_U + 2, w] + S[_R_D + 2, w]
                    a0, a1, a2 = matvec3_flat_of(Jinv, 0, u0, u1, u2)  # J^-1 torque (spacecraft_sim.core.kernels.propagate's)
                    y = rk4_of((S[_R_X, w], S[_R_X + 1, w], S[_R_X + 2, w], S[_R_X + 3, w], S[_R_X + 4, w], S[_R_X + 5, w], S[_R_X + 6, w]),
                               a0, a1, a2, h, _nine(S, _R_JL, w), Jinv)
                    S[_R_X, w], S[_R_X + 1, w], S[_R_X + 2, w], S[_R_X + 3, w], S[_R_X + 4, w], S[_R_X + 5, w], S[_R_X + 6, w] = y
    # the block's end: each lane's state back into its rows of st (a lane handed back keeps the block's start)
    for w in range(W):
        r = rows[w]
        if g0 + w >= N:
            continue
        if S[_R_BAD, w] != 0.0:
            handed_back[r] = 1
            continue
        if flight:  # (the true state is st's own row)
            for i in range(st.x.shape[1]):
                rec.x_final[r, i] = st.x[r, i]
        else:
            for i in range(7):
                st.x[r, i] = S[_R_X + i, w]
                rec.x_final[r, i] = S[_R_X + i, w]
        for i in range(_N_CTRL):
            st.ctrl[r, i] = S[_R_CS + i, w]
        if online:
            metric_state_store(ma, r, _metric_rows(S, w))
        for row in range(N_OUT):
            for c in range(4):
                st.pub[r, row, c] = S[_R_PUB + 4 * row + c, w]
                st.out[r, row, c] = S[_R_PUB + 4 * row + c, w]
        if grid.t.shape[0] > 0 and flight:
            st.flags[r, L_STARTED] = 1 if S[_R_STARTED, w] != 0.0 else 0
            st.flags[r, L_HAS_LAST] = 1 if S[_R_HASLAST, w] != 0.0 else 0
            st.flags[r, L_LAST_STATE_NS] = last_ns_w[w]
            st.flags[r, L_HAS_ESTIMATE] = 1 if S[_R_HASEST, w] != 0.0 else 0
            st.flags[r, L_N_STARTS] = int(S[_R_NSTARTS, w])
        elif grid.t.shape[0] > 0:
            st.flags[r, L_STARTED] = 1
            st.flags[r, L_HAS_LAST] = 1
            st.flags[r, L_LAST_STATE_NS] = last_ns
            st.flags[r, L_N_STARTS] = int(S[_R_NSTARTS, w])
            for i in range(3):
                torque = S[_R_PUB + 4 * O_TORQUE + i, w]
                st.vec3[r, V_CMD, i] = torque
                st.vec3[r, V_U_CMD, i] = torque
                st.vec3[r, V_U_LAST, i] = torque


@jit
def _keep_trajectory_sample(trajectory, k, k_lo, ks, r, S, w):
    """Lane ``w``'s sample ``k`` of run ``r``'s trajectory (a multiple of ``ks``) into its row of
    ``trajectory`` (:class:`~sappc.evaluation.metrics.MetricConstants`): the error quaternion's
    vector part and ``rho``, as the record holds them.  Out of line: inlined, it changed LLVM's code
    for the rest of the lanes' function (the paper campaign's lanes 7 to 10 % slower, measured)."""
    jt = k // ks - (k_lo + ks - 1) // ks  # the block's kept samples start at its first multiple of ks
    for i in range(3):
        trajectory[jt, r, i] = S[_R_PUB + 4 * O_QBR + i, w]
        trajectory[jt, r, 3 + i] = S[_R_PUB + 4 * O_RHO + i, w]


@jit_parallel
def run_lanes_kernel(stride, k_lo, grid, ctrl, plant, act, sens, est, dist, faults, env, mm, md, rec, st, handed_back, ma, mc, fa, kind):
    """Every run of a batch over one block of samples in groups of :data:`LANES` (module
    docstring), the groups in parallel (``prange``); ``handed_back`` (N,) int8 marks the runs to
    compute per run; ``ma``, ``mc`` (:func:`online_metrics` or :func:`no_online_metrics`): whether
    the lanes compute the runs' metrics online instead of recording their samples; ``fa``
    (:func:`flight_metrics`): the flight stack's metrics; ``kind`` (:func:`group_kind`): whether the
    runs have the flight stack."""
    n_groups = (plant.x0.shape[0] + LANES - 1) // LANES
    for g in prange(n_groups):
        _lane_group(np.int64(g) * LANES, stride, k_lo, grid, ctrl, plant, act, sens, est, dist, faults, env, mm, md, rec, st, handed_back, ma, mc, fa,
                    kind)

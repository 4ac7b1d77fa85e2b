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
per run, as before): the SAPPC law without its noise filters, the ideal actuator, exact
measurements (no sensors, no estimator), no fault, no orbit, no momentum management, no flight
modes, a disturbance shared by every run (the table).  In that loop every sample of a healthy run
is valid and commanded; a lane that meets anything else (an input the controller's check
rejects, a non-finite torque) is **handed back**: its record and state for the block are
computed again by :func:`~sappc.offline.compiled_loop._run_one` from the state the block started
with (the loop's answers, the watchdog, the held samples: one implementation).

Parity (docs/parity.md, "Campaign runs in SIMD lanes"): with the libm calls vectorised, a lane's
libm results are libmvec's (within 3 ulps of the scalar glibc functions'), everything else the
same IEEE operations in the same order as the per-run loop (``fastmath`` off: no contraction, no
reassociation).  A lane's result does not depend on the other lanes of its group, so run ``K`` of a
campaign is reproduced bit for bit by the lanes alone (``sappc simulate --from-campaign DIR --run
K``, a group of one run), on the same host.  ``sappc simulate``, the graph and the nodes keep the
scalar path.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from numba import prange

from gnc_common.compiled import jit, jit_parallel
from gnc_common.input_check import B_NORM, B_RATE, B_REFERENCE_ACCELERATION, B_REFERENCE_RATE, INPUT_OK, quaternion_verdict, vector_verdict
from sappc_controller.core.kernels import _MAX_NEWTON_ITERATIONS, C_A, C_A1, C_L, C_SIGN, C_T1, KIND_SAPPC, N_OUT, N_PARAMS, N_STATE
from sappc_controller.core.kernels import O_BL, O_BU, O_CMD, O_EPS, O_QBR, O_RHO, O_SAT, O_TORQUE, O_V, O_Z, P_B0, P_RATE_WC, P_TANTH, P_TORQUE_WC, P_UMAX, P_UMIN
from sappc_controller.core.kernels import S_FILTER_ON, S_HAS_PREV, S_PREV, S_SD, S_T0
from sappc_controller.core.kernels import actuator_of, backstepping_of, error_state_of, sappc_axis_end, sappc_axis_start, smetf_newton_step, smetf_start
from sappc_msgs_py.contract import ANSWER_COMMANDED
from spacecraft_sim.core.kernels import rk4_of

from sappc.offline.compiled_loop import L_HAS_LAST, L_LAST_STATE_NS, L_N_STARTS, L_STARTED, V_CMD, V_U_CMD, V_U_LAST, _initial_state

if TYPE_CHECKING:
    from sappc.offline.compiled_loop import CompiledInputs

__all__ = ["LANES", "lanes_refusal", "run_lanes_kernel"]

#: Runs per lane group: a multiple of every libmvec width (2, 4 and 8 float64), so that LLVM's
#: vectorised loops have no scalar remainder (which would call the scalar libm for some lanes).
LANES = 8
#: The per-run loop's stamp arithmetic (:data:`sappc.offline.compiled_loop._NS_PER_S`).
_NS_PER_S = 1_000_000_000
#: Columns of the lane state kept as (column, lane) arrays: the controller's state rows the SAPPC
#: law reads (``S_SD .. S_T0``).
_N_CTRL = S_T0 + 1
assert N_PARAMS == 29, "_lane_prm lists the 29 parameters of sappc_controller.core.kernels by index"


def lanes_refusal(inp: CompiledInputs) -> str | None:
    """Why ``inp``'s runs cannot be stepped in lanes (module docstring), or None when they can."""
    ctrl = inp.controller
    if ctrl.kind != KIND_SAPPC:
        return "the controller is not SAPPC"
    if ctrl.prm.shape[0] and (np.any(ctrl.prm[:, P_RATE_WC] > 0.0) or np.any(ctrl.prm[:, P_TORQUE_WC] > 0.0)):
        return "a noise filter is on"
    reasons = [(inp.n_wheels > 0, "reaction wheels"), (inp.sensors.draws.shape[1] > 0, "sensor noise"), (inp.estimating, "an estimator"),
               (inp.faults.kind.shape[1] > 0, "faults"), (inp.environment.orbit.shape[1] > 0, "an orbit"),
               (inp.momentum.prm.shape[1] > 0, "momentum management"), (inp.modes.prm.shape[1] > 0, "flight modes"),
               (not inp.disturbance.use_table, "a disturbance that differs by run")]
    for bad, why in reasons:
        if bad:
            return why
    return None


@jit(inline="always")
def _lane_prm(PL, w):
    """Lane ``w``'s controller parameters (``PL``: (N_PARAMS, LANES)) as the tuple the law's pieces
    index like a parameter row (``prm[P_*]``)."""
    return (PL[0, w], PL[1, w], PL[2, w], PL[3, w], PL[4, w], PL[5, w], PL[6, w], PL[7, w], PL[8, w], PL[9, w], PL[10, w], PL[11, w],
            PL[12, w], PL[13, w], PL[14, w], PL[15, w], PL[16, w], PL[17, w], PL[18, w], PL[19, w], PL[20, w], PL[21, w], PL[22, w],
            PL[23, w], PL[24, w], PL[25, w], PL[26, w], PL[27, w], PL[28, w])


@jit(inline="always")
def _nine(M, w):
    """Lane ``w``'s 3x3 matrix of ``M`` (9, LANES), row major, as a 9-tuple."""
    return (M[0, w], M[1, w], M[2, w], M[3, w], M[4, w], M[5, w], M[6, w], M[7, w], M[8, w])


@jit
def _lane_group(g0, stride, k_lo, grid, ctrl, plant, act, sens, est, dist, faults, env, mm, md, rec, st, handed_back):
    """Runs ``g0 .. g0 + LANES - 1`` (the last group's missing lanes repeat its last run, written
    nowhere) over one block of samples, from and into their rows of ``st`` and ``rec`` (row = run,
    as :func:`~sappc.offline.compiled_loop.run_batch_kernel`); a lane handed back (module docstring)
    leaves its rows of ``st`` as they were and sets ``handed_back[run]``."""
    W = LANES
    N = plant.x0.shape[0]
    rows = np.empty(W, dtype=np.int64)
    for w in range(W):
        rows[w] = min(g0 + w, N - 1)
    if k_lo == 0:  # the runs' first block: their state before the first sample, as the per-run loop makes it
        for w in range(W):
            if g0 + w < N:
                _initial_state(rows[w], rows[w], plant, sens, est, md, st, rec)
    # the lanes' state, (quantity, lane)
    X = np.empty((7, W))
    CS = np.empty((_N_CTRL, W))
    PUB = np.empty((N_OUT, 4, W))
    OUT3 = np.empty((N_OUT, W))  # the per-run loop's out[:, 3]: no law writes it but q_BR's (published whole)
    PL = np.empty((N_PARAMS, W))
    CF = np.empty((5, 3, W))
    JL = np.empty((9, W))
    JI = np.empty((9, W))
    U = np.empty((3, W))
    started = np.empty(W, dtype=np.bool_)
    n_starts = np.empty(W, dtype=np.int64)
    bad = np.zeros(W, dtype=np.bool_)
    for w in range(W):
        r = rows[w]
        for i in range(7):
            X[i, w] = st.x[r, i]
        for i in range(_N_CTRL):
            CS[i, w] = st.ctrl[r, i]
        for row in range(N_OUT):
            for c in range(4):
                PUB[row, c, w] = st.pub[r, row, c]
            OUT3[row, w] = st.out[r, row, 3]
        for i in range(N_PARAMS):
            PL[i, w] = ctrl.prm[r, i]
        for a in range(5):
            for i in range(3):
                CF[a, i, w] = ctrl.coef[r, a, i]
        for i in range(3):
            for j in range(3):
                JL[3 * i + j, w] = plant.J[r, i, j]
                JI[3 * i + j, w] = plant.J_inv[r, i, j]
        started[w] = st.flags[r, L_STARTED] != 0
        n_starts[w] = st.flags[r, L_N_STARTS]
    # the law's per-sample values, (quantity, lane): error state, per-axis transformation, Newton
    Q = np.empty((4, W))
    WBR = np.empty((3, W))
    CWD = np.empty((3, W))
    CWDD = np.empty((3, W))
    RHO = np.empty((3, W))
    RHOD = np.empty((3, W))
    DELTA = np.empty((3, W))
    Z = np.empty((3, W))
    EPS = np.empty((3, W))
    LOW = np.empty((3, W))
    ABSW = np.empty((3, W))
    A = np.empty((3, W))
    WW = np.empty((3, W))
    ATAN = np.empty((3, W))
    DONE = np.empty((3, W), dtype=np.bool_)
    dt = grid.dt
    T = grid.n_samples
    umax = act.max_torque_Nm
    bounds = ctrl.bounds
    last_ns = 0
    for kb in range(grid.t.shape[0]):
        k = k_lo + kb
        t_ns = grid.t_ns[kb]
        t_stamp = t_ns / _NS_PER_S  # the controller's time (the per-run loop's t_stamp_s)
        rq = (grid.ref_q[kb, 0], grid.ref_q[kb, 1], grid.ref_q[kb, 2], grid.ref_q[kb, 3])
        rw = (grid.ref_w[kb, 0], grid.ref_w[kb, 1], grid.ref_w[kb, 2])
        rwd = (grid.ref_wd[kb, 0], grid.ref_wd[kb, 1], grid.ref_wd[kb, 2])
        ref_ok = (quaternion_verdict(rq[0], rq[1], rq[2], rq[3], bounds[B_NORM]) == INPUT_OK
                  and vector_verdict(rw[0], rw[1], rw[2], bounds[B_REFERENCE_RATE]) == INPUT_OK
                  and vector_verdict(rwd[0], rwd[1], rwd[2], bounds[B_REFERENCE_ACCELERATION]) == INPUT_OK)
        d0, d1, d2 = dist.table[kb, 0], dist.table[kb, 1], dist.table[kb, 2]
        # stage 1: the input check, the start, the error state, each axis up to the SMETF's solve
        for w in range(W):
            ok = (ref_ok and quaternion_verdict(X[0, w], X[1, w], X[2, w], X[3, w], bounds[B_NORM]) == INPUT_OK
                  and vector_verdict(X[4, w], X[5, w], X[6, w], bounds[B_RATE]) == INPUT_OK)
            bad[w] = bad[w] or not ok
            T0 = CS[S_T0, w] if started[w] else t_stamp  # the first valid sample fixes the time origin
            CS[S_T0, w] = T0
            n_starts[w] = n_starts[w] if started[w] else n_starts[w] + 1
            started[w] = True
            q, wbr, cwd, cwdd = error_state_of((X[0, w], X[1, w], X[2, w], X[3, w]), (X[4, w], X[5, w], X[6, w]), rq, rw, rwd)
            for i in range(4):
                Q[i, w] = q[i]
            for i in range(3):
                WBR[i, w] = wbr[i]
                CWD[i, w] = cwd[i]
                CWDD[i, w] = cwdd[i]
            prm = _lane_prm(PL, w)
            tau = t_stamp - T0
            has_prev = CS[S_HAS_PREV, w] != 0.0
            for i in range(3):
                rho, rho_dot, delta, z, guess = sappc_axis_start(prm, tau, CF[C_SIGN, i, w], CF[C_T1, i, w], CF[C_A1, i, w], CF[C_L, i, w],
                                                                 CF[C_A, i, w], q[i], has_prev, CS[S_PREV + i, w], CS[S_PREV + 3 + i, w],
                                                                 CS[S_PREV + 6 + i, w], CS[S_PREV + 9 + i, w], CS[S_PREV + 12 + i, w])
                eps, lower, abs_w, a, ww = smetf_start(z, delta, prm[P_TANTH], has_prev, guess)
                RHO[i, w] = rho
                RHOD[i, w] = rho_dot
                DELTA[i, w] = delta
                Z[i, w] = z
                EPS[i, w] = eps
                LOW[i, w] = lower
                ABSW[i, w] = abs_w
                A[i, w] = a
                WW[i, w] = ww
                ATAN[i, w] = 0.0
                DONE[i, w] = False
        # stage 2: the SMETF's Newton iterations, until every lane's solve has converged; each lane
        # frozen from its own convergence on: its iterates are its scalar solve's
        for _ in range(_MAX_NEWTON_ITERATIONS):
            active = 0
            for i in range(3):
                for w in range(W):
                    a_atan, done, eps_next = smetf_newton_step(EPS[i, w], LOW[i, w], ABSW[i, w], A[i, w], PL[P_TANTH, w])
                    was_done = DONE[i, w]
                    ATAN[i, w] = ATAN[i, w] if was_done else a_atan
                    EPS[i, w] = EPS[i, w] if (was_done or done) else eps_next
                    DONE[i, w] = was_done or done
                    active += 0 if (was_done or done) else 1
            if active == 0:
                break
        # stage 3: the transformation's end, the backstepping law, the actuator, the answer, the plant's input
        for w in range(W):
            prm = _lane_prm(PL, w)
            k_tan = prm[P_TANTH]
            B0 = prm[P_B0]
            e_s = (np.copysign(EPS[0, w], WW[0, w]), np.copysign(EPS[1, w], WW[1, w]), np.copysign(EPS[2, w], WW[2, w]))
            P_s0, dd0, psi0, eta0 = sappc_axis_end(k_tan, e_s[0], np.copysign(ATAN[0, w], WW[0, w]), DELTA[0, w], RHO[0, w], RHOD[0, w])
            P_s1, dd1, psi1, eta1 = sappc_axis_end(k_tan, e_s[1], np.copysign(ATAN[1, w], WW[1, w]), DELTA[1, w], RHO[1, w], RHOD[1, w])
            P_s2, dd2, psi2, eta2 = sappc_axis_end(k_tan, e_s[2], np.copysign(ATAN[2, w], WW[2, w]), DELTA[2, w], RHO[2, w], RHOD[2, w])
            P_s = (P_s0, P_s1, P_s2)
            dd = (dd0, dd1, dd2)
            for i in range(3):
                CS[S_PREV + i, w] = e_s[i]
                CS[S_PREV + 3 + i, w] = P_s[i]
                CS[S_PREV + 6 + i, w] = Z[i, w]
                CS[S_PREV + 9 + i, w] = dd[i]
                CS[S_PREV + 12 + i, w] = DELTA[i, w]
            CS[S_HAS_PREV, w] = 1.0
            q = (Q[0, w], Q[1, w], Q[2, w], Q[3, w])
            cmd, V, S_next = backstepping_of(prm, dt, q, (WBR[0, w], WBR[1, w], WBR[2, w]), (CWD[0, w], CWD[1, w], CWD[2, w]),
                                             (CWDD[0, w], CWDD[1, w], CWDD[2, w]), (X[4, w], X[5, w], X[6, w]), e_s, (psi0, psi1, psi2),
                                             (eta0, eta1, eta2), CS[S_FILTER_ON, w] != 0.0, (CS[S_SD, w], CS[S_SD + 1, w], CS[S_SD + 2, w]))
            CS[S_FILTER_ON, w] = 1.0
            torques = (actuator_of(prm[P_UMAX], prm[P_UMIN], cmd[0]), actuator_of(prm[P_UMAX], prm[P_UMIN], cmd[1]),
                       actuator_of(prm[P_UMAX], prm[P_UMIN], cmd[2]))
            # the per-run loop's test of a refused answer
            finite = np.isfinite(torques[0][0] + torques[1][0] + torques[2][0]) and np.isfinite(cmd[0] + cmd[1] + cmd[2])
            for row in range(N_OUT):
                PUB[row, 3, w] = OUT3[row, w]
            for i in range(3):
                CS[S_SD + i, w] = S_next[i]
                torque, sat = torques[i]
                # the answer, published (the per-run loop's pub = out; nf = 0: delivered = commanded)
                PUB[O_TORQUE, i, w] = torque
                PUB[O_CMD, i, w] = cmd[i]
                PUB[O_SAT, i, w] = sat
                PUB[O_RHO, i, w] = RHO[i, w]
                PUB[O_BL, i, w] = RHO[i, w] - B0
                PUB[O_BU, i, w] = RHO[i, w] + B0
                PUB[O_EPS, i, w] = e_s[i]
                PUB[O_Z, i, w] = Z[i, w]
                PUB[O_V, i, w] = V[i]
                U[i, w] = min(max(torque, -umax), umax)  # control (clipped by the actuator) + disturbance, held over [t_k, t_k+1]
            for i in range(4):
                PUB[O_QBR, i, w] = q[i]
            bad[w] = bad[w] or not finite
        U_d = (d0, d1, d2)
        last_ns = t_ns
        if stride > 0 and kb % stride == 0:
            j = kb // stride
            for w in range(W):
                r = rows[w]
                if g0 + w >= N:
                    continue
                for row in range(N_OUT):
                    for c in range(4):
                        rec.out[r, j, row, c] = PUB[row, c, w]
                for i in range(7):
                    rec.x[r, j, i] = X[i, w]
                for i in range(3):
                    rec.d[r, j, i] = U_d[i]
                rec.status[r, j] = ANSWER_COMMANDED
        if k < T - 1:
            h = dt / plant.substeps
            for _ in range(plant.substeps):
                for w in range(W):
                    Jinv = _nine(JI, w)
                    u0, u1, u2 = U[0, w] + d0, U[1, w] + d1, U[2, w] + d2
                    a0 = (Jinv[0] * u0 + Jinv[1] * u1) + Jinv[2] * u2  # J^-1 torque (spacecraft_sim.core.kernels.propagate)
                    a1 = (Jinv[3] * u0 + Jinv[4] * u1) + Jinv[5] * u2
                    a2 = (Jinv[6] * u0 + Jinv[7] * u1) + Jinv[8] * u2
                    y = rk4_of((X[0, w], X[1, w], X[2, w], X[3, w], X[4, w], X[5, w], X[6, w]), a0, a1, a2, h, _nine(JL, w), Jinv)
                    for i in range(7):
                        X[i, w] = y[i]
    # the block's end: each lane's state back into its rows of st (a lane handed back keeps the block's start)
    for w in range(W):
        r = rows[w]
        if g0 + w >= N:
            continue
        if bad[w]:
            handed_back[r] = 1
            continue
        for i in range(7):
            st.x[r, i] = X[i, w]
            rec.x_final[r, i] = X[i, w]
        for i in range(_N_CTRL):
            st.ctrl[r, i] = CS[i, w]
        for row in range(N_OUT):
            for c in range(4):
                st.pub[r, row, c] = PUB[row, c, w]
                st.out[r, row, c] = PUB[row, c, w]
        if grid.t.shape[0] > 0:
            st.flags[r, L_STARTED] = 1
            st.flags[r, L_HAS_LAST] = 1
            st.flags[r, L_LAST_STATE_NS] = last_ns
            st.flags[r, L_N_STARTS] = n_starts[w]
            for i in range(3):
                torque = PUB[O_TORQUE, i, w]
                st.vec3[r, V_CMD, i] = torque
                st.vec3[r, V_U_CMD, i] = torque
                st.vec3[r, V_U_LAST, i] = torque


@jit_parallel
def run_lanes_kernel(stride, k_lo, grid, ctrl, plant, act, sens, est, dist, faults, env, mm, md, rec, st, handed_back):
    """Every run of a batch over one block of samples in groups of :data:`LANES` (module
    docstring), the groups in parallel (``prange``); ``handed_back`` (N,) int8 marks the runs to
    compute per run."""
    n_groups = (plant.x0.shape[0] + LANES - 1) // LANES
    for g in prange(n_groups):
        _lane_group(np.int64(g) * LANES, stride, k_lo, grid, ctrl, plant, act, sens, est, dist, faults, env, mm, md, rec, st, handed_back)

"""The offline closed loop in compiled code: whole runs, one at a time or many in parallel.

Timing (the same as :mod:`sappc.offline.closed_loop` and the lockstep ROS 2 graph): at
``t_k = k dt`` the plant's state is sampled, the controller computes the torque from it and the
reference at ``t_k``, the disturbance is sampled at ``t_k``, and the plant integrates over
``[t_k, t_k+1]`` with both held (zero-order hold).  Samples ``k = 0 .. n_steps``; the torque of
the last sample is recorded but not applied.

One code path: :func:`_run_one` is the whole time loop of one run (controller kernel
:func:`sappc_controller.core.kernels.controller_step`, plant kernel
:func:`spacecraft_sim.core.kernels.propagate`, reference tables, disturbance kernel).
:func:`run_batch_kernel` calls it for every run in a ``prange`` (runs are independent: each has
its own parameters, state and scratch arrays), :func:`run_single_kernel` for one run, with the
same argument types, so run ``k`` of a batch is the run alone, bit for bit.

What every run shares (reference, and the disturbance when no run changes it) is computed
once before the loop: the reference quaternion is integrated by
:meth:`spacecraft_sim.core.reference.PaperReference.sample` (DOP853) and its rates by the rate
kernel; a shared disturbance becomes a (T, 3) table.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import prange

from gnc_common.compiled import jit, jit_parallel
from gnc_common.validation import ConfigError
from sappc_controller.core.kernels import N_COEF, N_OUT, N_STATE, N_WORK, O_TORQUE, S_T0, controller_step, error_quaternions
from sappc_controller.core.kernels import kind_of, pack_params, start_coef
from spacecraft_sim.core.kernels import N_PLANT_WORK, disturbance_sample, disturbance_table, encode_disturbance, propagate
from spacecraft_sim.core.kernels import random_draws, reference_rate_tables
from spacecraft_sim.core.reference import sample_times

from sappc.scenario import Scenario

__all__ = ["CompiledInputs", "CompiledRun", "prepare", "run_batch", "run_single", "simulate_compiled"]


@jit
def _run_one(kind, prm, coef, x0, J, J_inv, substeps, dt, t_grid, ref_q, ref_w, ref_wd, use_table, d_table,
             kinds, dparams, dscale, dphase, rand_draws, rand_win, stride, hist, x_hist, d_hist, x_final):
    """The whole time loop of one run (module docstring); histories every ``stride`` samples
    (``stride = 0``: none), final state into ``x_final``."""
    state = np.zeros(N_STATE)
    state[S_T0] = t_grid[0]  # the first sample fixes the time origin
    work = np.zeros((N_WORK, 4))
    out = np.zeros((N_OUT, 4))
    pwork = np.zeros((N_PLANT_WORK, 7))
    x = x0.copy()
    d = np.zeros(3)
    u = np.zeros(3)
    T = t_grid.shape[0]
    for k in range(T):
        t = t_grid[k]
        controller_step(kind, t, dt, x[:4], x[4:], ref_q[k], ref_w[k], ref_wd[k], prm, coef, state, work, out)
        if use_table:
            for i in range(3):
                d[i] = d_table[k, i]
        else:
            disturbance_sample(k, t, kinds, dparams, dscale, dphase, rand_draws, rand_win, d)
        if stride > 0 and k % stride == 0:
            j = k // stride
            for r in range(N_OUT):
                for c in range(4):
                    hist[j, r, c] = out[r, c]
            for i in range(7):
                x_hist[j, i] = x[i]
            for i in range(3):
                d_hist[j, i] = d[i]
        if k < T - 1:
            for i in range(3):
                u[i] = out[O_TORQUE, i] + d[i]  # control + disturbance, held over [t_k, t_k+1]
            propagate(x, u, dt, substeps, J, J_inv, pwork)
    for i in range(7):
        x_final[i] = x[i]


@jit_parallel
def run_batch_kernel(kind, prm, coef, x0, J, J_inv, substeps, dt, t_grid, ref_q, ref_w, ref_wd, use_table, d_table,
                     kinds, dparams, dscale, dphase, rand_draws, rand_win, stride, hist, x_hist, d_hist, x_final):
    """Every run of a batch, in parallel over runs (``prange``); per-run arrays have a leading axis N."""
    for n in prange(x0.shape[0]):
        _run_one(kind, prm[n], coef[n], x0[n], J[n], J_inv[n], substeps, dt, t_grid, ref_q, ref_w, ref_wd, use_table,
                 d_table, kinds, dparams, dscale[n], dphase[n], rand_draws[:, n], rand_win, stride, hist[n], x_hist[n],
                 d_hist[n], x_final[n])


@jit
def run_single_kernel(n, kind, prm, coef, x0, J, J_inv, substeps, dt, t_grid, ref_q, ref_w, ref_wd, use_table, d_table,
                      kinds, dparams, dscale, dphase, rand_draws, rand_win, stride, hist, x_hist, d_hist, x_final):
    """Run ``n`` of the batch arrays alone (same argument types as in :func:`run_batch_kernel`); outputs
    (leading axis 1) at index 0."""
    _run_one(kind, prm[n], coef[n], x0[n], J[n], J_inv[n], substeps, dt, t_grid, ref_q, ref_w, ref_wd, use_table,
             d_table, kinds, dparams, dscale[n], dphase[n], rand_draws[:, n], rand_win, stride, hist[0], x_hist[0],
             d_hist[0], x_final[0])


@dataclass
class CompiledInputs:
    """Everything a compiled batch needs, as arrays (see :func:`prepare`)."""

    kind: int
    prm: np.ndarray
    coef: np.ndarray
    x0: np.ndarray
    J: np.ndarray
    J_inv: np.ndarray
    substeps: int
    dt: float
    t: np.ndarray
    ref_q: np.ndarray
    ref_w: np.ndarray
    ref_wd: np.ndarray
    use_table: bool
    d_table: np.ndarray
    kinds: np.ndarray
    dparams: np.ndarray
    dscale: np.ndarray
    dphase: np.ndarray
    rand_draws: np.ndarray
    rand_win: np.ndarray
    flags: dict[str, np.ndarray]

    @property
    def n_runs(self) -> int:
        return int(self.x0.shape[0])

    def args(self) -> tuple[Any, ...]:
        return (self.kind, self.prm, self.coef, self.x0, self.J, self.J_inv, self.substeps, self.dt, self.t, self.ref_q,
                self.ref_w, self.ref_wd, self.use_table, self.d_table, self.kinds, self.dparams, self.dscale, self.dphase,
                self.rand_draws, self.rand_win)


@dataclass
class CompiledRun:
    """Histories of a batch (T_rec samples every ``stride``): ``out`` (N, T_rec, N_OUT, 4) rows as in
    :mod:`sappc_controller.core.kernels`, ``x`` (N, T_rec, 7), ``d`` (N, T_rec, 3), final states (N, 7)."""

    t: np.ndarray
    out: np.ndarray
    x: np.ndarray
    d: np.ndarray
    x_final: np.ndarray


def prepare(scenario: Scenario, controller: Any = None, *, q_BN0: np.ndarray | None = None, omega_BN_B0: np.ndarray | None = None,
            inertia_kg_m2: np.ndarray | None = None, disturbance: Any = None, config: Any = None, gains: dict[str, np.ndarray] | None = None,
            on_infeasible: str = "raise") -> CompiledInputs:
    """Arrays of a batch from a scenario (overrides as in :func:`sappc.offline.simulate.run_scenario`),
    with the start checks of the numpy core (180 deg singularity, funnel, RPF feasibility)."""
    if scenario.faults:
        raise ConfigError(f"scenario {scenario.name!r} has faults: the compiled loop does not model them yet (run it with `sappc run`)")
    cfg = scenario.controller_config(controller) if config is None else config
    q0 = np.atleast_2d(np.asarray(scenario.q_BN0 if q_BN0 is None else q_BN0, dtype=np.float64))
    n = q0.shape[0]
    w0 = np.broadcast_to(np.asarray(scenario.omega_BN_B0_rad_s if omega_BN_B0 is None else omega_BN_B0, dtype=np.float64), (n, 3))
    x0 = np.ascontiguousarray(np.concatenate((q0, w0), axis=1))
    J = np.asarray(scenario.inertia_kg_m2 if inertia_kg_m2 is None else inertia_kg_m2, dtype=np.float64)
    J = np.ascontiguousarray(np.broadcast_to(J, (n, 3, 3)))
    J_inv = np.ascontiguousarray(np.linalg.inv(J))
    t = sample_times(scenario.duration_s, scenario.control_period_s)
    ref = scenario.reference.sample(t)
    ref_w, ref_wd = reference_rate_tables(scenario.reference, t)
    ref_q = np.ascontiguousarray(ref.q_RN)
    q_BR0 = error_quaternions(ref_q[0], q0)
    coef, flags = start_coef(cfg, q_BR0, on_infeasible=on_infeasible)
    prm = pack_params(cfg, n, gains)
    model = scenario.disturbance if disturbance is None else disturbance
    kinds, dparams, dscale, dphase = encode_disturbance(model, n)
    rand_draws, rand_win = random_draws(model, t, n)
    use_table = rand_draws.shape[0] == 0 and bool(np.all(dscale == dscale[:1]) and np.all(dphase == dphase[:1]))
    d_table = (disturbance_table(t, kinds, dparams, dscale[0], dphase[0], rand_draws[:, 0], rand_win) if use_table
               else np.zeros((0, 3)))
    return CompiledInputs(kind_of(cfg), prm, coef, x0, J, J_inv, int(scenario.rk4_substeps), float(scenario.control_period_s), t,
                          ref_q, np.ascontiguousarray(ref_w), np.ascontiguousarray(ref_wd), use_table, d_table, kinds, dparams,
                          dscale, dphase, rand_draws, rand_win, flags)


def _outputs(inp: CompiledInputs, stride: int, n: int) -> tuple[np.ndarray, ...]:
    T = inp.t.size
    T_rec = 0 if stride == 0 else (T - 1) // stride + 1
    return (np.zeros((n, T_rec, N_OUT, 4)), np.zeros((n, T_rec, 7)), np.zeros((n, T_rec, 3)), np.zeros((n, 7)))


def run_batch(inp: CompiledInputs, stride: int = 0) -> CompiledRun:
    """Every run of ``inp`` in one compiled call, in parallel over runs."""
    hist, x_hist, d_hist, x_final = _outputs(inp, stride, inp.n_runs)
    run_batch_kernel(*inp.args(), stride, hist, x_hist, d_hist, x_final)
    return CompiledRun(inp.t[::stride] if stride else inp.t[:0], hist, x_hist, d_hist, x_final)


def run_single(inp: CompiledInputs, n: int = 0, stride: int = 1) -> CompiledRun:
    """Run ``n`` of ``inp`` alone (one thread): histories with a leading axis of length 1."""
    hist, x_hist, d_hist, x_final = _outputs(inp, stride, 1)
    run_single_kernel(n, *inp.args(), stride, hist, x_hist, d_hist, x_final)
    return CompiledRun(inp.t[::stride] if stride else inp.t[:0], hist, x_hist, d_hist, x_final)


def simulate_compiled(scenario: Scenario, controller: Any = None) -> CompiledRun:
    """The scenario as written, one run, full histories (the compiled ``sappc simulate`` loop)."""
    return run_single(prepare(scenario, controller), 0, 1)

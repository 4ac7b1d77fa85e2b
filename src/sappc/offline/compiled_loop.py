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

import dataclasses
import sys
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numba import prange

from gnc_common.compiled import error_quaternion, inverse3_stack, jit, jit_parallel
from sappc_controller.core.kernels import N_COEF, N_OUT, N_STATE, N_WORK, O_BL, O_BU, O_CMD, O_EPS, O_QBR, O_RHO, O_SAT, O_TORQUE, O_V, O_Z, S_T0
from sappc_controller.core.kernels import controller_step
from sappc_controller.core.kernels import kind_of, pack_params, start_coef
from sappc_controller.core.base import SingularStartError
from sappc_controller.core.input_check import REJECT_REASONS, InputBounds, sample_verdicts
from spacecraft_sim.core.kernels import N_PLANT_WORK, disturbance_sample, disturbance_table, encode_disturbance, propagate
from spacecraft_sim.core.kernels import fault_actuator, fault_reference, fault_sensor, random_draws, reference_rate_tables
from spacecraft_sim.core.sensors import N_SENSOR_DRAWS, N_SENSOR_PARAMS, S_BIAS0, measure, white_noise_params
from spacecraft_sim.core.wheels import ReactionWheels, allocation_matrix, propagate_wheels_into, wheel_speeds_into, wheel_torques
from spacecraft_sim.core.faults import encode_faults, noise_draws
from sappc_msgs_py.contract import ANSWER_COMMANDED, ANSWER_NAMES, ANSWER_HELD, ANSWER_REFUSED, ANSWER_WATCHDOG_ZERO
from sappc_msgs_py.convert import seconds_to_ns
from spacecraft_sim.core.reference import sample_times

from sappc.evaluation.history import History
from sappc.scenario import Scenario

__all__ = ["CompiledInputs", "CompiledRun", "cache_is_warm", "ensure_compiled", "prepare", "run_batch", "run_single",
           "simulate_compiled", "warm_up"]


@jit
def _run_one(kind, prm, coef, x0, J, J_inv, substeps, dt, t_grid, ref_q, ref_w, ref_wd, use_table, d_table,
             kinds, dparams, dscale, dphase, rand_draws, rand_win, noise, sprm, souts,
             t_ns, stale_ns, u_max, fkind, fwin, fprm, fint, fdepth, fdraws, wG, wGp, wprm, ibounds,
             probe, start, stride, hist, x_hist, d_hist, s_hist, w_hist, rejected, x_final):
    """The whole time loop of one run (module docstring); histories every ``stride`` samples
    (``stride = 0``: none), final state into ``x_final``.

    Sensors: with rows in ``noise`` (T, 6 or 9) (standard normals) the controller sees the star
    tracker's and the gyro's measurement of the true state,
    :func:`spacecraft_sim.core.sensors.measure` with the parameters ``sprm``
    (:data:`~spacecraft_sim.core.sensors.N_SENSOR_PARAMS`,) and the tracker's outages ``souts`` (K, 2).

    Faults (``fkind`` (F,) ... as :func:`spacecraft_sim.core.faults.encode_faults`, ``fdraws``
    (T or 1, F, 6) the noise faults' draws): the measurement and the reference go through
    :func:`~spacecraft_sim.core.kernels.fault_sensor` and ``fault_reference``, the answer through
    ``fault_actuator``, and the controller answers as the node does in lockstep (the ``ANSWER_*``
    codes of :mod:`sappc_msgs_py.contract`, into ``s_hist``).  A sample is valid when its five
    inputs arrived (a dropout delivers none of the state's two or the reference's three) and pass
    the node's input check (:func:`sappc_controller.core.input_check.sample_verdicts` with the
    bounds ``ibounds``; each rejected input counted into ``rejected`` (2,): invalid, implausible).
    A valid sample is computed; without one, zero torque (the watchdog) when no valid state
    has been computed yet or the last one is more than ``stale_ns`` [ns] older than the sample
    (stamps ``t_ns``), else its last answer again (held).  The plant applies the delivered torque
    clipped to ``u_max`` per axis.

    The run's start (README, "What the controller answers"): the controller starts at its
    **first valid sample**, whose time is the performance function's time origin (``S_T0``) and
    whose error fixed ``coef`` (:func:`sappc_controller.core.kernels.start_coef`, in Python: the
    RPF's coefficients need scipy).  Everything before that sample is independent of ``coef``, so
    a first pass with ``probe`` true finds it: it returns at the first valid sample with
    ``start`` (6,) = (its index, its time, its error quaternion ``q_BR`` of the measured attitude
    against the reference, by the kernels' own formula), ``start[0] = -1`` when the run has none;
    :func:`_started` then computes ``coef``, and the second pass (``probe`` false) runs the loop.

    Recorded, as a bag of the same run records it: the *true* error quaternion and state (the
    metrics describe the real attitude), the delivered torque, and the controller's rows as last
    published (a zero answer publishes zero command and saturation and keeps the previous rows; a
    held answer repeats them; before the first computed sample the performance function, band,
    ``eps``, ``z`` and ``V`` rows are NaN: the controller has none yet, as the node publishes).

    Actuator: with no wheels (``wprm`` (0, 6)) the ideal one, the delivered torque clipped to
    ``u_max`` per axis.  With ``N`` reaction wheels (spin axes ``wG`` (3, N), allocation ``wGp``
    (N, 3), parameters ``wprm`` (N, 6) as :meth:`spacecraft_sim.core.wheels.ReactionWheels.params`;
    ``x0`` then holds their momenta, (7 + N)), the delivered torque is the wheels' command:
    :func:`~spacecraft_sim.core.wheels.wheel_torques` (allocation, motor and speed limits) and
    :func:`~spacecraft_sim.core.wheels.propagate_wheels_into`; ``w_hist`` (T_rec, N, 2) records
    each wheel's speed relative to the body [rad/s] and its motor torque [N m] at every sample
    (the torque of the last sample computed, not applied)."""
    state = np.zeros(N_STATE)
    started = False  # the first valid sample fixes the time origin (S_T0)
    work = np.zeros((N_WORK, 4))
    out = np.zeros((N_OUT, 4))
    pub = np.full((N_OUT, 4), np.nan)  # the rows last published: no performance function yet
    for r in (O_TORQUE, O_CMD, O_SAT):
        for c in range(4):
            pub[r, c] = 0.0  # nothing commanded
    start[0] = -1.0  # no valid sample (yet)
    pwork = np.zeros((N_PLANT_WORK, 7))
    x = x0.copy()  # (7,) or, with wheels, (7 + N,)
    nw = wprm.shape[0]
    uw = np.zeros(nw)  # the wheels' motor torques
    wspeed = np.zeros(nw)
    wwork = np.zeros((5, 7 + nw))
    wtmp = np.zeros((3, 3))
    y = np.zeros(7)  # the measured state
    noisy = noise.shape[0] > 0
    held_q = np.zeros(4)  # the star tracker's last quaternion
    bias = sprm[S_BIAS0:S_BIAS0 + 3].copy()  # the gyro's bias
    nf = fkind.shape[0]
    fcount = np.zeros(nf, dtype=np.int64)
    fbuf = np.zeros((nf, fdepth, 7))
    u_last = np.zeros(3)  # the last delivered torque (what the plant holds)
    has_last = False
    last_state_ns = 0
    d = np.zeros(3)
    u = np.zeros(3)
    cmd = np.zeros(3)  # the controller's last answer (what a held sample repeats)
    u_cmd = np.zeros(3)
    T = t_grid.shape[0]
    for k in range(T):
        t = t_grid[k]
        if noisy:
            measure(k, t, x[:4], x[4:7], noise[k], sprm, souts, held_q, bias, y)
        else:
            for i in range(7):
                y[i] = x[i]
        state_in, reference_in = True, True
        if nf > 0:
            state_in = fault_sensor(t, fkind, fwin, fprm, fint, fcount, fbuf, fdraws[min(k, fdraws.shape[0] - 1)], y)
            reference_in = fault_reference(t, fkind, fwin)
        valid = sample_verdicts(state_in, reference_in, y[:4], y[4:], ref_q[k], ref_w[k], ref_wd[k], ibounds, rejected)
        if valid and not started:
            if probe:  # the first valid sample: what starts the controller (docstring)
                start[0] = k
                start[1] = t
                error_quaternion(ref_q[k], y[:4], start[2:6])
                return
            state[S_T0] = t
            started = True
        status = ANSWER_COMMANDED
        if valid:
            controller_step(kind, t, dt, y[:4], y[4:], ref_q[k], ref_w[k], ref_wd[k], prm, coef, state, work, out)
            if not (np.isfinite(out[O_TORQUE, 0] + out[O_TORQUE, 1] + out[O_TORQUE, 2])
                    and np.isfinite(out[O_CMD, 0] + out[O_CMD, 1] + out[O_CMD, 2])):
                status = ANSWER_REFUSED
            else:
                has_last = True
                last_state_ns = t_ns[k]
        elif not has_last or t_ns[k] - last_state_ns > stale_ns:  # no valid state yet, or too old
            status = ANSWER_WATCHDOG_ZERO
        else:
            status = ANSWER_HELD
        if status == ANSWER_COMMANDED:
            for r in range(N_OUT):
                for c in range(4):
                    pub[r, c] = out[r, c]
            for i in range(3):
                cmd[i] = out[O_TORQUE, i]
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
        if noisy or nf > 0 or status != ANSWER_COMMANDED:
            error_quaternion(ref_q[k], x[:4], pub[O_QBR])  # the true error (metrics)
        if use_table:
            for i in range(3):
                d[i] = d_table[k, i]
        else:
            disturbance_sample(k, t, kinds, dparams, dscale, dphase, rand_draws, rand_win, d)
        if nw > 0:
            wheel_torques(u_last, wGp, wG, wprm, x, uw)
        if stride > 0 and k % stride == 0:
            j = k // stride
            for r in range(N_OUT):
                for c in range(4):
                    hist[j, r, c] = pub[r, c]
            for i in range(7):
                x_hist[j, i] = x[i]
            for i in range(3):
                d_hist[j, i] = d[i]
            s_hist[j] = status
            if nw > 0:
                wheel_speeds_into(x, wG, wprm, wspeed)
                for i in range(nw):
                    w_hist[j, i, 0] = wspeed[i]
                    w_hist[j, i, 1] = uw[i]
        if k < T - 1:
            if nw == 0:
                for i in range(3):  # control (clipped by the actuator) + disturbance, held over [t_k, t_k+1]
                    u[i] = min(max(u_last[i], -u_max), u_max) + d[i]
                propagate(x, u, dt, substeps, J, J_inv, pwork)
            else:  # the wheels' motor torques and the disturbance, held
                propagate_wheels_into(x, uw, d, dt, substeps, J, J_inv, wG, wprm, wwork, wtmp)
    for i in range(7 + nw):
        x_final[i] = x[i]


@jit_parallel
def run_batch_kernel(kind, prm, coef, x0, J, J_inv, substeps, dt, t_grid, ref_q, ref_w, ref_wd, use_table, d_table,
                     kinds, dparams, dscale, dphase, rand_draws, rand_win, noise, sprm, souts,
                     t_ns, stale_ns, u_max, fkind, fwin, fprm, fint, fdepth, fdraws, wG, wGp, wprm, ibounds,
                     probe, start, stride, hist, x_hist, d_hist, s_hist, w_hist, rejected, x_final):
    """Every run of a batch, in parallel over runs (``prange``); per-run arrays have a leading axis N
    (the faults' and the wheels' too: a campaign may disperse them); ``probe``: the first pass of
    :func:`_run_one` (each run's first valid sample into ``start`` (N, 6))."""
    for n in prange(x0.shape[0]):
        _run_one(kind, prm[n], coef[n], x0[n], J[n], J_inv[n], substeps, dt, t_grid, ref_q, ref_w, ref_wd, use_table,
                 d_table, kinds, dparams, dscale[n], dphase[n], rand_draws[:, n], rand_win, noise[n], sprm[n], souts,
                 t_ns, stale_ns, u_max, fkind[n], fwin[n], fprm[n], fint[n], fdepth, fdraws, wG[n], wGp[n], wprm[n], ibounds,
                 probe, start[n], stride, hist[n], x_hist[n], d_hist[n], s_hist[n], w_hist[n], rejected[n], x_final[n])


@jit
def run_single_kernel(n, kind, prm, coef, x0, J, J_inv, substeps, dt, t_grid, ref_q, ref_w, ref_wd, use_table, d_table,
                      kinds, dparams, dscale, dphase, rand_draws, rand_win, noise, sprm, souts,
                      t_ns, stale_ns, u_max, fkind, fwin, fprm, fint, fdepth, fdraws, wG, wGp, wprm, ibounds,
                      probe, start, stride, hist, x_hist, d_hist, s_hist, w_hist, rejected, x_final):
    """Run ``n`` of the batch arrays alone (same argument types as in :func:`run_batch_kernel`); outputs
    (leading axis 1) at index 0."""
    _run_one(kind, prm[n], coef[n], x0[n], J[n], J_inv[n], substeps, dt, t_grid, ref_q, ref_w, ref_wd, use_table,
             d_table, kinds, dparams, dscale[n], dphase[n], rand_draws[:, n], rand_win, noise[n], sprm[n], souts,
             t_ns, stale_ns, u_max, fkind[n], fwin[n], fprm[n], fint[n], fdepth, fdraws, wG[n], wGp[n], wprm[n], ibounds,
             probe, start[0], stride, hist[0], x_hist[0], d_hist[0], s_hist[0], w_hist[0], rejected[0], x_final[0])


#: Per-run fields of :class:`CompiledInputs` (leading axis N); ``rand_draws`` has it second.
_PER_RUN = ("prm", "coef", "x0", "J", "J_inv", "dscale", "dphase", "noise", "sprm", "fkind", "fwin", "fprm", "fint", "wG", "wGp", "wprm")


@dataclass
class CompiledInputs:
    """Everything a compiled batch needs, as arrays (see :func:`prepare`).

    ``noise`` (N, T or 0, 6 or 9): each run's sensor draws (standard normals; no rows: the state
    is measured exactly), ``sprm`` (N, :data:`~spacecraft_sim.core.sensors.N_SENSOR_PARAMS`) each
    run's sensor parameters, ``souts`` (K, 2) the star tracker's outages [s].  ``flags``: the RPF's ``flat`` and
    ``clamped`` components (N, 3).  ``t_ns`` (T,): the samples' stamps [ns]; ``stale_ns``: the
    controller's stale-input timeout [ns]; ``u_max``: the actuator's limit [N m]; ``fkind`` (N, F),
    ``fwin`` (N, F, 2), ``fprm`` (N, F, P), ``fint`` (N, F): each run's faults
    (:func:`spacecraft_sim.core.faults.encode_faults`), ``fdepth`` their delay rings' slots,
    ``fdraws`` (T or 1, F, 6) the noise faults' draws.  Reaction wheels (none: ``W = 0``, the ideal
    actuator): ``wG`` (N, 3, W) spin axes, ``wGp`` (N, W, 3) their minimum-norm allocation, ``wprm``
    (N, W, 6) :meth:`~spacecraft_sim.core.wheels.ReactionWheels.params`; ``x0`` is then (N, 7 + W).
    ``ibounds``: the controller's input bounds (:meth:`~sappc_controller.core.input_check.InputBounds.packed`).
    ``coef`` and ``flags`` are each run's start (:func:`_started`) for the controller ``config`` with
    the RPF policy ``on_infeasible``; :meth:`subset` with new sensor draws computes them again."""

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
    noise: np.ndarray = field(default_factory=lambda: np.zeros((1, 0, 6)))
    sprm: np.ndarray = field(default_factory=lambda: np.zeros((1, N_SENSOR_PARAMS)))
    souts: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    t_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    stale_ns: int = 0
    u_max: float = np.inf
    fkind: np.ndarray = field(default_factory=lambda: np.zeros((1, 0), dtype=np.int64))
    fwin: np.ndarray = field(default_factory=lambda: np.zeros((1, 0, 2)))
    fprm: np.ndarray = field(default_factory=lambda: np.zeros((1, 0, 7)))
    fint: np.ndarray = field(default_factory=lambda: np.zeros((1, 0), dtype=np.int64))
    fdepth: int = 1
    fdraws: np.ndarray = field(default_factory=lambda: np.zeros((1, 0, 6)))
    wG: np.ndarray = field(default_factory=lambda: np.zeros((1, 3, 0)))
    wGp: np.ndarray = field(default_factory=lambda: np.zeros((1, 0, 3)))
    wprm: np.ndarray = field(default_factory=lambda: np.zeros((1, 0, 6)))
    ibounds: np.ndarray = field(default_factory=lambda: InputBounds().packed())
    config: Any = None
    on_infeasible: str = "raise"

    @property
    def n_wheels(self) -> int:
        return int(self.wprm.shape[1])

    @property
    def n_runs(self) -> int:
        return int(self.x0.shape[0])

    def args(self) -> tuple[Any, ...]:
        return (self.kind, self.prm, self.coef, self.x0, self.J, self.J_inv, self.substeps, self.dt, self.t, self.ref_q,
                self.ref_w, self.ref_wd, self.use_table, self.d_table, self.kinds, self.dparams, self.dscale, self.dphase,
                self.rand_draws, self.rand_win, self.noise, self.sprm, self.souts, self.t_ns, self.stale_ns, self.u_max,
                self.fkind, self.fwin, self.fprm, self.fint, self.fdepth, self.fdraws, self.wG, self.wGp, self.wprm, self.ibounds)

    def subset(self, lo: int, hi: int, noise: np.ndarray | None = None) -> CompiledInputs:
        """Runs ``lo .. hi - 1`` (contiguous copies: the same argument types), with ``noise``
        (hi - lo, T, 6 or 9) as their sensor draws when given."""
        per_run: dict[str, Any] = {name: np.ascontiguousarray(getattr(self, name)[lo:hi]) for name in _PER_RUN if name != "noise"}
        per_run["noise"] = np.ascontiguousarray(self.noise[lo:hi])
        if noise is not None:
            per_run["noise"] = np.ascontiguousarray(noise, dtype=np.float64)
        sub = dataclasses.replace(self, **per_run, rand_draws=np.ascontiguousarray(self.rand_draws[:, lo:hi]),
                                  flags={k: v[lo:hi] for k, v in self.flags.items()})
        if noise is None:
            return sub
        try:  # new measurements: each run's first valid sample, and so its start, may differ
            return _started(sub)
        except SingularStartError as exc:  # name the run in the whole batch
            raise SingularStartError(exc.q_e0, exc.run + lo) from None


@dataclass
class CompiledRun:
    """Histories of a batch (T_rec samples every ``stride``): ``out`` (N, T_rec, N_OUT, 4) rows as in
    :mod:`sappc_controller.core.kernels` (as published: see :func:`_run_one`), ``x`` (N, T_rec, 7),
    ``d`` (N, T_rec, 3), ``status`` (N, T_rec) int8 (the contract's ``ANSWER_*`` codes), ``wheels``
    (N, T_rec, W, 2) each wheel's speed [rad/s] and motor torque [N m] (W = 0: the ideal actuator),
    final states (N, 7 + W), ``rejected`` (N, 2) int64 the inputs the controller rejected, by reason
    (``invalid``, ``implausible``: :data:`~sappc_controller.core.input_check.REJECT_REASONS`)."""

    t: np.ndarray
    out: np.ndarray
    x: np.ndarray
    d: np.ndarray
    status: np.ndarray
    wheels: np.ndarray
    x_final: np.ndarray
    rejected: np.ndarray

    def status_counts(self) -> dict[str, np.ndarray]:
        """Samples of each status per run (N,), by :data:`ANSWER_NAMES`."""
        return {name: np.count_nonzero(self.status == code, axis=1) for code, name in enumerate(ANSWER_NAMES)}

    def rejected_by_reason(self) -> dict[str, np.ndarray]:
        """Inputs rejected per run (N,), by every reason of
        :data:`~sappc_controller.core.input_check.REJECT_REASONS` (the node's summary keys; the
        stamp checks never reject anything offline)."""
        n = self.rejected.shape[0]
        return {reason: (self.rejected[:, i] if i < self.rejected.shape[1] else np.zeros(n, dtype=np.int64))
                for i, reason in enumerate(REJECT_REASONS)}

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
        )


def _f64(a: Any, shape: tuple[int, ...] | None = None) -> np.ndarray:
    """A writable, C-contiguous float64 copy (one argument type for every call: no recompiles)."""
    arr = np.asarray(a, dtype=np.float64)
    return np.array(arr if shape is None else np.broadcast_to(arr, shape), dtype=np.float64, order="C", copy=True)


def prepare(scenario: Scenario, controller: Any = None, *, q_BN0: np.ndarray | None = None, omega_BN_B0: np.ndarray | None = None,
            inertia_kg_m2: np.ndarray | None = None, disturbance: Any = None, config: Any = None, gains: dict[str, np.ndarray] | None = None,
            on_infeasible: str = "raise", sensor_params: np.ndarray | None = None, faults: list[tuple[Any, ...]] | None = None,
            wheels: list[ReactionWheels] | None = None) -> CompiledInputs:
    """Arrays of a batch from a scenario (overrides as in :func:`sappc.offline.simulate.run_scenario`),
    with the start checks of the controller core (180 deg singularity, funnel, RPF feasibility).
    ``sensor_params``: the sensors' parameters ((13,) or one row per run), their draws then given
    per batch (:meth:`CompiledInputs.subset`); else the scenario's
    (:attr:`~sappc.scenario.Scenario.sensors`; none: exact measurements), every run with the draws
    of its ``seed``.  ``faults``:
    one fault list per run (a campaign's dispersed faults; the same kinds in the same slots), else
    the scenario's for every run.  ``wheels``: one wheel set per run (the same number of wheels),
    else the scenario's actuator (:attr:`~sappc.scenario.Scenario.wheels`; none: ideal)."""
    ensure_compiled()
    cfg = scenario.controller_config(controller) if config is None else config
    q0 = _f64(np.atleast_2d(np.asarray(scenario.q_BN0 if q_BN0 is None else q_BN0, dtype=np.float64)))
    n = q0.shape[0]
    w0 = _f64(scenario.omega_BN_B0_rad_s if omega_BN_B0 is None else omega_BN_B0, (n, 3))
    per_run_wheels = ([] if scenario.wheels is None else [scenario.wheels] * n) if wheels is None else list(wheels)
    if per_run_wheels and (len(per_run_wheels) != n or any(w.n != per_run_wheels[0].n for w in per_run_wheels)):
        raise ValueError(f"wheels must hold one wheel set per run ({n}), each with the same number of wheels")
    h0 = np.array([w.initial_momentum(w0[k]) for k, w in enumerate(per_run_wheels)]).reshape(n, -1)
    x0 = _f64(np.concatenate((q0, w0, h0), axis=1))
    W = h0.shape[1]
    wG = _f64(np.array([w.G for w in per_run_wheels]).reshape(n, 3, W))
    wGp = _f64(np.array([allocation_matrix(w.G) for w in per_run_wheels]).reshape(n, W, 3))
    wprm = _f64(np.array([w.params() for w in per_run_wheels]).reshape(n, W, 6))
    J = _f64(scenario.inertia_kg_m2 if inertia_kg_m2 is None else inertia_kg_m2, (n, 3, 3))
    J_inv = inverse3_stack(J)  # written out, not LAPACK: the same bits on every host (docs/parity.md)
    t = _f64(sample_times(scenario.duration_s, scenario.control_period_s))
    ref = scenario.reference.sample(t)
    ref_w, ref_wd = reference_rate_tables(scenario.reference, t)
    ref_q = _f64(ref.q_RN)
    prm = _f64(pack_params(cfg, n, gains))
    model = scenario.disturbance if disturbance is None else disturbance
    kinds, dparams, dscale, dphase = encode_disturbance(model, n)
    rand_draws, rand_win = random_draws(model, t, n)
    use_table = rand_draws.shape[0] == 0 and bool(np.all(dscale == dscale[:1]) and np.all(dphase == dphase[:1]))
    d_table = (disturbance_table(t, kinds, dparams, dscale[0], dphase[0], rand_draws[:, 0], rand_win) if use_table
               else np.zeros((0, 3)))
    sensors = scenario.sensors
    sprm = (np.zeros(N_SENSOR_PARAMS) if sensors is None else sensors.params(scenario.control_period_s)) if sensor_params is None else sensor_params
    souts = np.zeros((0, 2)) if sensors is None else sensors.outages()
    noise = np.zeros((n, 0, 6)) if sensors is None or sensor_params is not None else _f64(sensors.draws(t.size), (n, t.size, N_SENSOR_DRAWS))
    t_ns = np.array([seconds_to_ns(float(tk)) for tk in t], dtype=np.int64)  # the plant's stamps
    per_run_faults = [scenario.faults] * n if faults is None else list(faults)
    if len(per_run_faults) != n:
        raise ValueError(f"faults must hold one list per run ({n}), got {len(per_run_faults)}")
    enc = [encode_faults(tuple(f)) for f in per_run_faults]
    if any(e.kind.shape != enc[0].kind.shape for e in enc):
        raise ValueError("every run's faults must have the same number of entries")
    fkind = np.ascontiguousarray(np.stack([e.kind for e in enc]), dtype=np.int64)
    fint = np.ascontiguousarray(np.stack([e.samples for e in enc]), dtype=np.int64)
    fdraws = noise_draws(tuple(per_run_faults[0]), t_ns) if any(e.has_noise for e in enc) else np.zeros((1, enc[0].n, 6))
    inp = CompiledInputs(kind_of(cfg), prm, np.zeros((n, N_COEF, 3)), x0, J, J_inv, int(scenario.rk4_substeps), float(scenario.control_period_s), t,
                          ref_q, _f64(ref_w), _f64(ref_wd), use_table, _f64(d_table), np.ascontiguousarray(kinds, dtype=np.int64),
                          _f64(dparams), _f64(dscale), _f64(dphase), _f64(rand_draws), np.ascontiguousarray(rand_win, dtype=np.int64),
                          {}, noise, _f64(sprm, (n, N_SENSOR_PARAMS)), _f64(souts), t_ns,
                          seconds_to_ns(scenario.controller_node.stale_timeout_s), float(scenario.actuator.max_torque_Nm),
                          fkind, _f64(np.stack([e.window for e in enc])), _f64(np.stack([e.params for e in enc])), fint,
                          max(e.depth for e in enc), _f64(fdraws), wG, wGp, wprm, _f64(scenario.controller_node.input_bounds().packed()),
                          cfg, on_infeasible)
    return _started(inp)


def _started(inp: CompiledInputs) -> CompiledInputs:
    """``inp`` with each run's start (:func:`_run_one`'s docstring): the first pass of the loop
    (``probe``) finds each run's first valid sample and its error quaternion, from which
    :func:`~sappc_controller.core.kernels.start_coef` (the node's own start: the 180 deg check, the
    funnels, the RPF with ``inp.on_infeasible``) gives ``coef`` and ``flags``.  A run without a valid
    sample never starts (zero ``coef``, no flags set).

    Raises
    ------
    SingularStartError, ConfigError
        As the node's first step would, naming the run's index in ``inp``.
    """
    n = inp.n_runs
    start = np.zeros((n, 6))
    hist, x_hist, d_hist, s_hist, w_hist, rejected, x_final = _outputs(inp, 0, n)
    run_batch_kernel(*inp.args(), True, start, 0, hist, x_hist, d_hist, s_hist, w_hist, rejected, x_final)
    ok = start[:, 0] >= 0.0
    coef = np.zeros((n, N_COEF, 3))
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
    return dataclasses.replace(inp, coef=_f64(coef), flags=flags)


def _outputs(inp: CompiledInputs, stride: int, n: int) -> tuple[np.ndarray, ...]:
    T = inp.t.size
    T_rec = 0 if stride == 0 else (T - 1) // stride + 1
    return (np.zeros((n, T_rec, N_OUT, 4)), np.zeros((n, T_rec, 7)), np.zeros((n, T_rec, 3)), np.zeros((n, T_rec), dtype=np.int8),
            np.zeros((n, T_rec, inp.n_wheels, 2)), np.zeros((n, 2), dtype=np.int64), np.zeros((n, 7 + inp.n_wheels)))


def _check_noise(inp: CompiledInputs) -> None:
    if inp.noise.shape[0] != inp.n_runs or inp.noise.shape[1] not in (0, inp.t.size):
        raise ValueError(f"noise must be (N, 0 or T, 6 or 9) = ({inp.n_runs}, 0 or {inp.t.size}, 6 or 9), got {inp.noise.shape}")


def run_batch(inp: CompiledInputs, stride: int = 0, into: CompiledRun | None = None) -> CompiledRun:
    """Every run of ``inp`` in one compiled call, in parallel over runs.

    ``into``: the result of an earlier call with the same number of runs and stride, whose arrays
    are overwritten (sub-batches of a campaign reuse one buffer: no new pages per sub-batch).
    """
    _check_noise(inp)
    if into is not None and into.out.shape[0] == inp.n_runs and into.wheels.shape[2] == inp.n_wheels and into.x.shape[1] == (0 if stride == 0 else (inp.t.size - 1) // stride + 1):
        hist, x_hist, d_hist, s_hist, w_hist, rejected, x_final = into.out, into.x, into.d, into.status, into.wheels, into.rejected, into.x_final
        rejected[...] = 0  # counts: start again
    else:
        hist, x_hist, d_hist, s_hist, w_hist, rejected, x_final = _outputs(inp, stride, inp.n_runs)
    run_batch_kernel(*inp.args(), False, np.zeros((inp.n_runs, 6)), stride, hist, x_hist, d_hist, s_hist, w_hist, rejected, x_final)
    return CompiledRun(inp.t[::stride] if stride else inp.t[:0], hist, x_hist, d_hist, s_hist, w_hist, x_final, rejected)


def run_single(inp: CompiledInputs, n: int = 0, stride: int = 1) -> CompiledRun:
    """Run ``n`` of ``inp`` alone (one thread): histories with a leading axis of length 1."""
    _check_noise(inp)
    hist, x_hist, d_hist, s_hist, w_hist, rejected, x_final = _outputs(inp, stride, 1)
    run_single_kernel(n, *inp.args(), False, np.zeros((1, 6)), stride, hist, x_hist, d_hist, s_hist, w_hist, rejected, x_final)
    return CompiledRun(inp.t[::stride] if stride else inp.t[:0], hist, x_hist, d_hist, s_hist, w_hist, x_final, rejected)


def simulate_compiled(scenario: Scenario, controller: Any = None) -> CompiledRun:
    """The scenario as written, one run, full histories (the compiled ``sappc simulate`` loop)."""
    return run_single(prepare(scenario, controller), 0, 1)


# ============================================================================= compile once

#: The kernels whose cache decides whether a process must compile (the entry points).
_ENTRY_KERNELS = (run_single_kernel, run_batch_kernel)
_checked = False


def cache_is_warm() -> bool:
    """Whether numba's on-disk cache holds the entry kernels for the current sources (no compile needed)."""
    for kernel in _ENTRY_KERNELS:
        try:
            if not kernel._cache._cache_file._load_index():  # empty when absent or stale (source stamp)
                return False
        except Exception:  # numba internals moved: assume warm, print nothing
            return True
    return True


def ensure_compiled(*, in_subprocess: bool = False) -> None:
    """Once per process, before the first kernel call: when the cache is cold (first use after an
    install or a change of the sources), say so in one line on stderr and compile every kernel
    now (:func:`warm_up`), so that later processes (campaign workers included) only load them.

    ``in_subprocess``: compile in a child process (a parent about to fork workers keeps numba's
    thread pool unstarted)."""
    global _checked
    if _checked:
        return
    _checked = True
    if cache_is_warm():
        return
    print("sappc: compiling the numerical core once (~1 min; later runs load it from the cache)...", file=sys.stderr, flush=True)
    if in_subprocess:
        import subprocess

        subprocess.run([sys.executable, "-c", "from sappc.offline.compiled_loop import warm_up; warm_up()"], check=True)
    else:
        warm_up()


def warm_up() -> None:
    """Compile (or load) every kernel the offline runs and campaigns call, on a tiny scenario: the
    single-run and batch loops (every controller kind, every disturbance kind, sensor noise), and the
    set-up kernels.  ``sappcw`` calls it once after building the venv."""
    global _checked
    _checked = True
    from sappc.scenario import scenario_from_mapping

    from spacecraft_sim.core.faults import noisy_measurement

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
    scenario = scenario_from_mapping(raw)
    inp = prepare(scenario, on_infeasible="clamp", sensor_params=white_noise_params(1e-7, 1e-7))
    noisy = inp.subset(0, 1, noise=np.zeros((1, inp.t.size, 6)))
    for case in (inp, noisy):
        run_single(case, 0, 1)
        run_batch(case, 1)
        run_batch(case, 0)
    noisy_measurement(np.array([0.0, 0.0, 0.0, 1.0]), np.zeros(3), np.zeros(6), 1e-7, 1e-7)
    # the entry points the nodes and `sappc rerun` call from Python: the controller step (one run and
    # a batch), the plant, the disturbances, the reference
    from spacecraft_sim.core import kernels as plant_kernels
    from spacecraft_sim.core.faults import FAULT_KINDS, FaultSchedule, faults_from_list

    plant_kernels.warm_up()
    # the injector's per-message fault kernels (one schedule holding every kind)
    every_kind = [{"kind": k, **({"path": "sensor", "samples": 1} if k == "delay" else {}),
                   **({"effectiveness": [1.0, 1.0, 1.0]} if k == "actuator_effectiveness" else {}),
                   **({"bias_Nm": [0.0, 0.0, 0.0]} if k == "actuator_bias" else {})} for k in FAULT_KINDS]
    FaultSchedule(faults_from_list(every_kind)).warm_up()
    ctrl = scenario.build_controller()
    for q in (scenario.q_BN0, np.stack((scenario.q_BN0, scenario.q_BN0))):
        ctrl.reset()
        ctrl.step(0.0, 0.01, q, np.zeros(q.shape[:-1] + (3,)), np.array([0.0, 0.0, 0.0, 1.0]), np.zeros(3), np.zeros(3))


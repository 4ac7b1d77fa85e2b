"""Run a scenario offline: the scenario's arrays into the compiled whole-run loop
(:mod:`sappc.offline.compiled_loop`), its history into the metrics (:mod:`sappc.evaluation.metrics`).

No Python runs per time step: one compiled call runs a whole run (``sappc simulate``) or a
sub-batch of runs in parallel (campaigns); the metrics are computed from each sub-batch's stored
history (views of the loop's record, in blocks of bounded size), or, for a campaign's runs in SIMD
lanes, by the lanes themselves as they go (nothing recorded but the answers), by the one
definition of every metric (:func:`~sappc.evaluation.metrics.metric_sample_of`: the same bits)."""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import numpy as np

from spacecraft_sim.core.disturbance import DisturbanceModel

from sappc.evaluation.history import History
from sappc.evaluation.metrics import MetricsAccumulator, SampleGrid
from sappc.offline import compiled_loop
from sappc_msgs_py.contract import ANSWER_NAMES
from gnc_common.input_check import REJECT_REASONS
from sappc.scenario import ControllerKind, Scenario, check_run_fits_in_memory, scenario_bytes_per_sample

__all__ = ["HISTORY_KINDS", "ScenarioRun", "SimulationResult", "metrics_accumulator", "run_scenario", "simulate"]

#: Runs per compiled call in a batch: their full histories (~2 MB a run for 50 s at 100 Hz) are
#: kept for the metrics block, then dropped; the buffer is reused from one sub-batch to the next.
SUB_BATCH = 32
#: Runs per compiled call when the runs go in SIMD lanes (:mod:`sappc.offline.lanes`, which covers
#: only scenarios without sensor draws): 16 lane groups.  Each sub-batch makes the run's per-block
#: inputs (sample times, reference, disturbance table) again, which at 32 runs cost as much as a
#: third of the lanes' own time; at 128 runs a 1000-run campaign takes 1.07 s instead of 1.29 s
#: (one thread; 512 runs: 1.12 s).
LANES_SUB_BATCH = 128
#: Run-samples (samples times runs) the metrics take from a sub-batch's history at a time
#: (:meth:`~sappc.evaluation.metrics.MetricsAccumulator.add_history`'s ``block_samples``): their
#: temporaries are a few hundred bytes a run-sample (the estimator's NEES solves a copy of each
#: 6 x 6 covariance), so 2**15 bounds them to tens of MB whatever the run's length (the whole 6 h
#: record at once took 1.1 GB more than the record, issue 47); a sub-batch of 32 runs of 50 s
#: (160,032 run-samples) takes five blocks.  The metrics are the same bits for any block.
METRICS_BLOCK = 1 << 15


@dataclass(frozen=True)
class SimulationResult:
    """A finished offline run: its history (``None`` when not kept), metrics and the parameters that produced it."""

    scenario: Scenario
    controller: ControllerKind
    history: History | None
    metrics: dict[str, Any]
    controller_summary: dict[str, Any] = dataclasses.field(default_factory=dict)
    #: In orbit, the metrics of each orbit (:meth:`~sappc.evaluation.metrics.MetricsAccumulator.orbit_metrics`); else empty.
    per_orbit: list[dict[str, Any]] = dataclasses.field(default_factory=list)

    def report(self) -> dict[str, Any]:
        """JSON-ready summary: metrics, controller, and every parameter used."""
        config = self.scenario.controller_config(self.controller)
        return {
            "scenario": self.scenario.name,
            "controller": self.controller.value,
            "metrics": self.metrics,
            **({"per_orbit": self.per_orbit} if self.per_orbit else {}),
            "controller_summary": self.controller_summary,
            "parameters": {
                "scenario": self.scenario.raw,
                "controller": _jsonable(dataclasses.asdict(config)),
            },
        }


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


@dataclass
class ScenarioRun:
    """What :func:`run_scenario` gives besides the metrics.

    ``flags``: the RPF's ``flat`` and ``clamped`` components (N, 3); ``history``: every sample of
    every run (``keep_history``), else ``None``; ``trajectory``: ``(t, q_ev, rho)`` of the first
    runs every ``stride`` samples (float32 (T_s, n, 3)), else ``None``; ``x_final`` (N, 7 + W) (W wheel momenta);
    ``status``: per run (N,), the samples the controller answered in each way
    (:data:`~sappc_msgs_py.contract.ANSWER_NAMES`); ``rejected``: per run (N,), the inputs it
    rejected, by reason (:data:`~gnc_common.input_check.REJECT_REASONS`)."""

    flags: dict[str, np.ndarray]
    history: History | None
    trajectory: tuple[np.ndarray, np.ndarray, np.ndarray] | None
    x_final: np.ndarray
    status: dict[str, np.ndarray]
    rejected: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)

    def controller_summary(self, k: int = 0) -> dict[str, Any]:
        """What the controller did in run ``k``: samples answered in each way (``commanded``,
        ``watchdog_zero``, ``held``, ``refused``), ``samples``, and the input messages it rejected
        (``rejected_inputs``, and ``rejected_by_reason``), as ``sappc run`` reports them."""
        counts = {name: int(v[k]) for name, v in self.status.items()}
        by_reason = {reason: int(v[k]) for reason, v in self.rejected.items()}
        return {"samples": sum(counts.values()), **counts, "rejected_inputs": sum(by_reason.values()), "rejected_by_reason": by_reason}


def run_scenario(
    scenario: Scenario,
    *,
    controller: ControllerKind | str | None = None,
    controller_config: Any = None,
    on_infeasible: str = "raise",
    q_BN0: np.ndarray | None = None,
    omega_BN_B0_rad_s: np.ndarray | None = None,
    inertia_kg_m2: np.ndarray | None = None,
    disturbance: DisturbanceModel | None = None,
    gains: dict[str, np.ndarray] | None = None,
    faults: list[tuple[Any, ...]] | None = None,
    sensors: tuple[np.ndarray, Callable[[int, int], np.ndarray | compiled_loop.NoiseStreams], np.ndarray | None] | None = None,
    wheels: list[Any] | None = None,
    keep_history: bool = False,
    trajectory: tuple[int, int] | None = None,
    sub_batch: int = SUB_BATCH,
    progress: Callable[[int], None] | None = None,
    run_keys: list[tuple[int, ...]] | None = None,
    orbits: np.ndarray | None = None,
    per_orbit: bool = True,
    sinks: Sequence[Callable[[History], None]] = (),
    sample_progress: Callable[[int], None] | None = None,
    lanes: bool = False,
) -> tuple[MetricsAccumulator, ScenarioRun]:
    """Run the scenario's closed loop, for one run or a batch: the one place that assembles it.

    Every argument overrides the scenario's own value; the batch size is that of ``q_BN0``
    (shape (N, 4)) or 1.  Used by :func:`simulate` (one run, the scenario as written) and by
    Monte Carlo campaigns (dispersed initial states, inertias, disturbances, ``gains`` (N,) per
    name, sensor noise).  The start checks (180 deg singularity, funnel, RPF feasibility with
    ``on_infeasible``) are made for every run before any runs, on each run's first valid sample
    (:func:`~sappc.offline.compiled_loop.prepare`); with ``sensors`` draws given per sub-batch,
    again on that sub-batch's measurements before it runs.

    The runs go through the compiled loop ``sub_batch`` at a time (in parallel over runs); each
    sub-batch's full history feeds the metrics (:data:`METRICS_BLOCK` run-samples at a time: views
    of the loop's record, no copy) and is dropped unless ``keep_history``; in SIMD lanes (without
    ``keep_history`` or ``sinks``) the lanes feed the metrics online and record only the answers,
    or every sample of a sub-batch whose trajectories are kept.  ``sensors = (params, draws, outages)``: the sensors' parameters
    (:meth:`spacecraft_sim.core.sensors.Sensors.params`, (13,) or one row per run),
    ``draws(lo, hi)`` the standard normals (hi - lo, T, 6 or 9) of runs ``lo .. hi - 1`` and the
    tracker's outages (N, K, 2) [s] per run (``None``: the scenario's for every run); by
    default the scenario's ``sensors``, every run with the draws of its ``seed``
    (:func:`~sappc.offline.compiled_loop.prepare`).  ``wheels``: one
    :class:`~spacecraft_sim.core.wheels.ReactionWheels` per run (dispersed), else the scenario's.
    ``trajectory = (n, stride)`` keeps q_ev and rho of the first ``n`` runs every ``stride``
    samples.  ``progress(n)`` is called after each sub-batch with its number of runs.  ``run_keys``:
    each run's key of its magnetometer's stream (a campaign's ``(run, seed)``; default ``(k,)``).
    ``orbits``: each run's orbit parameters (a campaign's dispersed orbit), else the scenario's.
    ``per_orbit``: in orbit, also the per-orbit metrics (0.9 s of CPU a 6 h run; a campaign, which
    does not report them, leaves them out).  ``sinks``: each called with every block of a one-run
    batch's history, in order (views of a buffer reused for the next block: a sink copies what it
    keeps): the figures' envelope (:class:`~sappc.evaluation.envelope.HistoryEnvelope`'s ``add``),
    a recorder.  ``sample_progress(k)``: called after
    each block of the first sub-batch with its samples run so far (a long run's progress).
    ``lanes``: the runs in SIMD lanes where :mod:`sappc.offline.lanes` covers the scenario (a
    campaign's runs: their libm calls libmvec's; docs/parity.md), else one at a time.

    Raises
    ------
    ConfigError
        With ``keep_history``, when the whole record would not fit in this machine's memory
        (:func:`~sappc.scenario.check_run_fits_in_memory`): a run in blocks holds nothing of its length.

    Returns
    -------
    metrics : MetricsAccumulator
        Filled with every sample of every run.
    run : ScenarioRun
        RPF flags, the history when kept, trajectories, final states.
    """
    config = scenario.controller_config(controller) if controller_config is None else controller_config
    if keep_history:  # the whole record of every run, before anything is allocated
        runs = 1 if q_BN0 is None else np.atleast_2d(q_BN0).shape[0]
        check_run_fits_in_memory(scenario.duration_s, scenario.control_period_s, scenario_bytes_per_sample(scenario) * runs)
    if sinks and q_BN0 is not None and np.atleast_2d(q_BN0).shape[0] != 1:
        raise ValueError("a sink takes the history of one run")
    inp = compiled_loop.prepare(
        scenario, config=config, q_BN0=q_BN0, omega_BN_B0=omega_BN_B0_rad_s, inertia_kg_m2=inertia_kg_m2,
        disturbance=disturbance, gains=gains, on_infeasible=str(getattr(on_infeasible, "value", on_infeasible)),
        sensor_params=None if sensors is None else sensors[0], sensor_outages=None if sensors is None else sensors[2],
        faults=faults, wheels=wheels, run_keys=run_keys, orbits=orbits, whole=keep_history, lanes=lanes,
    )
    draws = None if sensors is None else sensors[1]

    n, T = inp.n_runs, inp.n_samples
    in_lanes = lanes and compiled_loop.lanes_refusal(inp) is None
    if in_lanes and sub_batch == SUB_BATCH:
        sub_batch = LANES_SUB_BATCH
    step = n if keep_history else max(1, min(sub_batch, n))
    n_traj, traj_stride = trajectory if trajectory is not None else (0, 1)
    parts: list[MetricsAccumulator] = []
    histories: list[History] = []
    traj_t = np.zeros(0)
    traj_q: list[np.ndarray] = []  # per sub-batch with trajectories, (T_s, m, 3)
    traj_rho: list[np.ndarray] = []
    x_final = np.empty((n, 7 + inp.n_wheels))
    status = {name: np.zeros(n, dtype=np.int64) for name in ANSWER_NAMES}
    rejected = {reason: np.zeros(n, dtype=np.int64) for reason in REJECT_REASONS}
    flags = {k: np.zeros_like(v) for k, v in inp.flags.items()}
    buffer: compiled_loop.CompiledRun | None = None
    for lo in range(0, n, step):
        hi = min(lo + step, n)
        sub = inp.subset(lo, hi, None if draws is None else draws(lo, hi)) if step < n or draws is not None else inp
        for key, value in sub.flags.items():  # each run's start (computed again with its sensor draws)
            flags[key][lo:hi] = value
        acc = metrics_accumulator(scenario, T, float(scenario.control_period_s), hi - lo, per_orbit=per_orbit)
        m = min(n_traj, hi) - lo  # runs of this sub-batch whose trajectories are kept
        if keep_history:  # the whole record, one block
            buffer = compiled_loop.run_batch(sub, 1, into=buffer)
            blocks: Iterator[compiled_loop.CompiledRun] = iter((buffer,))
        elif in_lanes and not sinks:  # the lanes take the metrics online: only the answers recorded, and the trajectories' samples
            blocks = compiled_loop.run_blocks(sub, 1, metrics=acc, keep_runs=max(m, 0), keep_stride=traj_stride)
        else:  # a block of samples at a time: memory flat in the run's length
            blocks = compiled_loop.run_blocks(sub, 1)
        del sub
        if hi == n:  # the last sub-batch has started: its whole inputs (reference tables, sensor draws) go before the metrics
            del inp
        pieces: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        k_lo = 0
        block = None
        for block in blocks:
            h = block.history() if block.online is None else None  # what the metrics and sinks read
            if block.online is None:
                assert h is not None
                acc.add_history(h, block_samples=max(1, METRICS_BLOCK // (hi - lo)))
            else:  # the lanes' runs' metrics were taken online; the runs they handed back are in the record
                recorded = np.flatnonzero(~block.online)
                acc.add_online_block(block.runs(recorded).history(), recorded.tolist(), block_samples=METRICS_BLOCK)
            for sink in sinks:  # a batch with sinks is recorded (the lanes take no metrics online then)
                assert h is not None
                sink(h)
            for name, count in block.status_counts().items():
                status[name][lo:hi] += count
            if m > 0:  # the trajectories' samples k = 0, stride, 2 stride, ... that fall in this block
                # written apart from the record by the lanes, else the record's (every sample)
                tr = block.trajectory if block.trajectory is not None else compiled_loop.trajectory_samples(block.out[:m], k_lo, traj_stride)
                first = -k_lo % traj_stride
                pieces.append((block.t[first::traj_stride].copy(), tr[:, :, :3].astype(np.float32), tr[:, :, 3:].astype(np.float32)))
            k_lo += block.t.size
            if sample_progress is not None and lo == 0:
                sample_progress(k_lo)
            if keep_history:
                assert h is not None
                histories.append(h)
        assert block is not None
        if pieces:
            traj_t = np.concatenate([p[0] for p in pieces])
            traj_q.append(np.concatenate([p[1] for p in pieces]))
            traj_rho.append(np.concatenate([p[2] for p in pieces]))
        x_final[lo:hi] = block.x_final
        for reason, count in block.rejected_by_reason().items():
            rejected[reason][lo:hi] = count
        parts.append(acc)
        if progress is not None:
            progress(hi - lo)
    metrics = parts[0] if len(parts) == 1 else MetricsAccumulator.concatenate(parts)
    trajectories = (traj_t, np.concatenate(traj_q, axis=1), np.concatenate(traj_rho, axis=1)) if traj_q else None
    return metrics, ScenarioRun(flags, histories[0] if keep_history else None, trajectories, x_final, status, rejected)


#: What :func:`simulate` keeps of a run's samples: all of them, the figures' bounded envelope
#: (:class:`~sappc.evaluation.envelope.HistoryEnvelope`: the whole run up to its full-rate
#: threshold), or none.
HISTORY_KINDS = ("full", "envelope", "none")


def simulate(scenario: Scenario, controller: ControllerKind | str | None = None, *, history: str = "full",
             progress: Callable[[int], None] | None = None, sinks: Sequence[Callable[[History], None]] = ()) -> SimulationResult:
    """Run ``scenario`` with ``controller`` (default: the scenario's) and compute its metrics.

    ``history`` (:data:`HISTORY_KINDS`): ``"full"`` keeps every sample (one block: memory linear in
    the run's length); ``"envelope"`` (``sappc simulate --out``: the figures) and ``"none"`` run a
    block of samples at a time (:func:`~sappc.offline.compiled_loop.run_blocks`), their memory flat
    in the run's length, the result's ``history`` the figures' envelope or ``None``.  The metrics
    are the same bits in every case.  ``progress(samples)``: called after each block with the
    samples run so far; ``sinks``: each given every block's history (:func:`run_scenario`).  ``metrics["wall_time_s"]`` is the wall time of the run
    (reference generation, start checks and the metrics included, file output excluded).
    """
    if history not in HISTORY_KINDS:
        raise ValueError(f"history must be one of {HISTORY_KINDS}, got {history!r}")
    kind = scenario.resolve_controller(controller)
    start = time.perf_counter()
    envelope = None
    if history == "envelope":
        from sappc.evaluation.envelope import HistoryEnvelope

        envelope = HistoryEnvelope((SampleGrid.of_run(scenario.duration_s, scenario.control_period_s).n_samples - 1) * scenario.control_period_s,
                                   wheels=scenario.wheels)
    metrics, run = run_scenario(scenario, controller=kind, keep_history=history == "full", sinks=(*sinks, *(() if envelope is None else (envelope.add,))),
                                sample_progress=progress)
    result = metrics.run_metrics(0)
    result["wall_time_s"] = time.perf_counter() - start
    kept = run.history if envelope is None else envelope.history()
    return SimulationResult(scenario=scenario, controller=kind, history=kept, metrics=result, controller_summary=run.controller_summary(0),
                            per_orbit=metrics.orbit_metrics(0))


def metrics_accumulator(scenario: Scenario, n_samples: int, dt: float, n_runs: int, *, per_orbit: bool = True) -> MetricsAccumulator:
    """A :class:`MetricsAccumulator` of ``n_runs`` runs on the grid ``k dt``, ``k = 0 .. n_samples - 1``,
    with the scenario's metric settings and fault windows, and in orbit its per-orbit bins unless
    ``per_orbit`` is false."""
    ms = scenario.metrics
    return MetricsAccumulator(
        SampleGrid(n_samples, dt),  # k dt, sample_times' products, held as a description (nothing of the run's length)
        n_runs,
        steady_from_s=ms.steady_from_s,
        settle_threshold=ms.settle_threshold,
        t2_s=ms.t2_s,
        fault_windows=scenario.event_windows(),
        orbit_bins=scenario.orbit_bins() if per_orbit else None,
        origin=ms.origin,
    )

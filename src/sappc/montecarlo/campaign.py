"""Monte Carlo campaigns: thousands of dispersed runs in compiled code, locally or on Dask.

A campaign is a scenario file with a ``montecarlo`` section (see
``config/scenarios/paper_montecarlo.yaml``).  Runs are simulated in chunks (one task each, on a
local process or a Dask worker); inside a chunk, :func:`sappc.offline.simulate.run_scenario`
runs sub-batches of runs in parallel (``prange``) through the same compiled loop and metrics
as `sappc simulate`, each sub-batch reporting its progress.

Reproducibility
---------------
Every random input of run ``k`` comes from ``SeedSequence(seed, spawn_key=(k,))``:
its first child draws the dispersed values, its second the sensor noise (the whole run's,
before the loop); a magnetometer (an orbit scenario's) draws from its own stream keyed
``(k, seed)`` (:func:`spacecraft_sim.core.magnetometer.magnetometer_draws`).  A
run therefore depends only on ``(seed, k)``, not on the chunk size, the number
of workers or the scheduler, and since a run inside a batch is bit for bit the
run alone (one compiled loop, :func:`sappc.offline.compiled_loop._run_one`), the per-run results are
identical however the campaign is split.  ``sappc simulate --from-campaign DIR
--run K`` re-runs run ``K`` alone with the same function.

Files in the output directory
-----------------------------
``manifest.json``   the scenario, seed, number of runs and chunk size
``chunks/*.npz``    per-run results, one file per finished chunk (what ``--resume`` keeps)
``runs.csv``        the per-run table
``summary.json``    the campaign summary (also written by ``--json``)
``*.png``           the paper's figures
"""

from __future__ import annotations

import copy
import json
import os
import re
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from gnc_common import collector
from gnc_common.validation import ConfigError
from gnc_common.validation import InputError
from sappc.montecarlo.config import CampaignConfig, campaign_config
from spacecraft_sim.core.sensors import N_SENSOR_DRAWS, white_noise_params
from sappc.montecarlo.results import ESTIMATOR_COLUMNS, MODE_COLUMNS, WHEEL_COLUMNS
from sappc.montecarlo.draws import dispersed_disturbance, draw_inputs, run_faults, run_hardware, run_orbits, sensor_noise_streams
from sappc.montecarlo.results import FORMAT_VERSION, assemble, chunk_path, chunks, save_chunk
from sappc.offline import compiled_loop
from sappc.offline.compiled_loop import NoiseStreams
from sappc.offline.simulate import run_scenario
from sappc.scenario import ControllerKind, Scenario, scenario_from_mapping

__all__ = ["ChunkExecutor", "load_campaign_run", "run_campaign", "run_chunk", "simulate_runs"]

Array = NDArray[np.float64]


#: Where sub-batches report finished runs: a callable in this process, a queue given to the local
#: workers, or ``None`` (Dask workers: progress per chunk).
_progress_sink: Any = None


def _report_progress(n: int) -> None:
    sink = _progress_sink
    if sink is None:
        return
    if callable(sink):
        sink(n)
    else:
        sink.put(n)


def run_chunk(scenario_raw: dict[str, Any], seed: int, runs: list[int], keep_trajectories: int) -> dict[str, NDArray[Any]]:
    """Simulate ``runs`` of a campaign; return the per-run results (a worker task).

    Takes the parsed scenario mapping (not objects) so that it can run in any process or on
    any Dask worker.  A run whose state becomes non-finite is reported with ``finite = False``;
    the other runs are unaffected (every operation is per run).
    """
    return simulate_runs(scenario_raw, seed, runs, keep_trajectories, progress=_report_progress)[0]


#: The last scenario this process parsed (:func:`_parsed`): its mapping (a copy), the scenario and
#: its campaign settings.
_last_parsed: tuple[dict[str, Any], Scenario, CampaignConfig] | None = None


def _parsed(raw: dict[str, Any]) -> tuple[Scenario, CampaignConfig]:
    """The scenario of the mapping ``raw`` and its campaign settings, parsed once per process for
    the chunks that share it (every chunk of a campaign: 13 ms of a flight chunk's 0.5 s, every
    controller's configuration validated again); :func:`run_campaign` leaves its own here before
    its workers fork, so that they start with it.  A mapping not equal to the last one's is parsed
    (the objects are frozen: the chunks share them)."""
    global _last_parsed
    if _last_parsed is not None:
        try:
            same = bool(_last_parsed[0] == raw)
        except (TypeError, ValueError):  # a mapping made in Python may hold arrays, whose == is not a truth value
            same = False
        if same:
            return _last_parsed[1], _last_parsed[2]
    scenario = scenario_from_mapping(raw)
    cfg = campaign_config(scenario)
    _last_parsed = (copy.deepcopy(raw), scenario, cfg)
    return scenario, cfg


def _remember(scenario: Scenario, cfg: CampaignConfig) -> None:
    """``scenario`` (parsed by the caller) as :func:`_parsed`'s last, for the chunks of its mapping."""
    global _last_parsed
    _last_parsed = (copy.deepcopy(scenario.raw), scenario, cfg)


def simulate_runs(
    scenario_raw: dict[str, Any], seed: int, runs: list[int], keep_trajectories: int, *, with_history: bool = False,
    progress: Callable[[int], None] | None = None,
) -> tuple[dict[str, NDArray[Any]], Any, Any]:
    """:func:`run_chunk`, also returning the metrics accumulator and the :class:`~sappc.offline.simulate.ScenarioRun`
    (with the history of every run when ``with_history``: for a single run)."""
    scenario, cfg = _parsed(scenario_raw)
    inputs = draw_inputs(cfg, seed, runs)
    n = len(runs)
    J = scenario.inertia_kg_m2
    if cfg.dispersions.inertia_relative is not None:
        S = np.sqrt(1.0 + inputs.inertia_relative)  # (n, 3)
        J = S[:, :, None] * J[None] * S[:, None, :]
    config = scenario.controller_config()
    if inputs.gains and (not hasattr(config, "gains") or not hasattr(config.gains, "K_q")):
        raise ConfigError(f"montecarlo.dispersions.gains needs a SAPPC or TraPPC controller, not {scenario.controller.value!r}")
    noise = cfg.dispersions.sensor_noise

    if noise.enabled and scenario.sensors is not None:
        raise ConfigError("montecarlo.dispersions.sensor_noise and the scenario's sensors section are two sensor models: keep one")
    width = 6 if noise.enabled else N_SENSOR_DRAWS

    def noise_draws(lo: int, hi: int) -> NoiseStreams:  # each run's stream, drawn block by block while it runs
        return sensor_noise_streams(seed, inputs.runs[lo:hi], width)

    run_wheels, run_sensor_params, run_outages = run_hardware(scenario, inputs)
    sensors: tuple[NDArray[np.float64], Callable[[int, int], NoiseStreams], NDArray[np.float64] | None] | None = None
    if noise.enabled:
        sensors = (white_noise_params(noise.attitude_sigma_rad, noise.rate_sigma_rad_s), noise_draws, None)
    elif scenario.sensors is not None:  # each run draws its sensors' noise from its own stream
        sensors = (scenario.sensors.params(scenario.control_period_s) if run_sensor_params is None else run_sensor_params, noise_draws,
                   run_outages)

    with np.errstate(all="ignore"):  # a diverging run is reported, not raised
        try:
            metrics, run = run_scenario(
                scenario,
                controller_config=config,
                on_infeasible="clamp" if scenario.controller == ControllerKind.SAPPC else "raise",
                q_BN0=inputs.q_BN0 if cfg.initial_attitude is not None else np.tile(scenario.q_BN0, (n, 1)),
                omega_BN_B0_rad_s=inputs.omega_BN_B0,
                inertia_kg_m2=J,
                disturbance=dispersed_disturbance(scenario, inputs),
                gains=inputs.gains or None,
                faults=run_faults(scenario, cfg, inputs),
                sensors=sensors,
                wheels=run_wheels,
                keep_history=with_history,
                trajectory=(min(keep_trajectories, n), cfg.trajectory_stride) if keep_trajectories > 0 else None,
                progress=progress,
                run_keys=[(int(k), seed) for k in inputs.runs],  # the magnetometer's draws: the run's own, whatever its chunk
                orbits=run_orbits(scenario, inputs),
                per_orbit=False,  # not in the campaign's table
                lanes=True,  # every run of a campaign in SIMD lanes where they cover it, --from-campaign's too (docs/parity.md)
            )
        except InputError as exc:  # name the campaign's run, not its place in this chunk
            message = re.sub(r"\(run (\d+)\)", lambda m: f"(run {int(inputs.runs[int(m.group(1))])})", str(exc), count=1)
            raise InputError(message) from None
    crit = metrics.criteria_arrays()
    traj = run.trajectory
    return {
        "run": inputs.runs,
        "euler_deg": inputs.euler_deg,
        "omega_BN_B0_rad_s": inputs.omega_BN_B0,
        "inertia_relative": inputs.inertia_relative,
        "disturbance_scale": inputs.disturbance_scale,
        "disturbance_phase_rad": inputs.disturbance_phase_rad,
        **{f"gain_{name}": values for name, values in inputs.gains.items()},
        "rpf_error_at_t2_per_axis": crit["rpf_error_at_t2_per_axis"],
        "steady_mean_abs_qev_per_axis": crit["steady_mean_abs_qev_per_axis"],
        "steady_max_abs_qev": crit["steady_max_abs_qev"],
        "max_abs_torque_Nm": crit["max_abs_torque_Nm"],
        "torque_sign_changes_per_s": crit["torque_sign_changes_per_s"],
        "torque_reversals_per_s": crit["torque_reversals_per_s"],
        "settling_time_s": crit["settling_time_s"],
        "control_lost_at_s": crit["control_lost_at_s"],
        "finite": crit["finite"],
        **{k: crit[k] for k in WHEEL_COLUMNS if k in crit},  # with reaction wheels
        **{k: crit[k] for k in ESTIMATOR_COLUMNS if k in crit},  # with an estimator
        **{k: crit[k] for k in MODE_COLUMNS if k in crit},  # with flight modes
        # with an estimator: the NEES summed over this chunk's runs at every sample, and how many
        # runs had one there (summed over chunks, not concatenated: the campaign's consistency test)
        **({"tsum_nees": metrics.nees_sum_t, "tsum_nees_runs": metrics.nees_runs_t}
           if metrics.nees_sum_t is not None and metrics.nees_runs_t is not None else {}),
        "fault_choice": inputs.fault_choice,
        "fault_start_s": inputs.fault_start_s,
        "fault_duration_s": inputs.fault_duration_s,
        **{f"hw_{name}": values for name, values in inputs.hardware.items()},
        **{f"answers_{name}": count for name, count in run.status.items()},
        "rpf_clamped": run.flags["clamped"],
        "rpf_flat": run.flags["flat"],
        "traj_t": traj[0] if traj is not None else np.zeros(0),
        "traj_q_ev": traj[1] if traj is not None else np.zeros((0, 0, 3), np.float32),
        "traj_rho": traj[2] if traj is not None else np.zeros((0, 0, 3), np.float32),
    }, metrics, run


class _Progress:
    """A one-line progress report on stderr: runs done, runs/s, ETA."""

    def __init__(self, total: int, done: int, enabled: bool) -> None:
        self.total, self.done, self.enabled = total, done, enabled
        self.start_done, self.t0 = done, time.perf_counter()
        self.tty = sys.stderr.isatty()
        self.last_print = 0.0

    #: Seconds between two lines (a terminal's line is rewritten in place; a log gets new lines).
    TTY_PERIOD_S, LOG_PERIOD_S = 0.2, 1.0

    def update(self, n: int) -> None:
        """``n`` more runs finished (sub-batches report a few tens of runs each, several times a second)."""
        if n <= 0 and self.last_print > 0.0:
            return
        self.done = min(self.done + n, self.total)
        if not self.enabled:
            return
        now = time.perf_counter()
        finished = self.done == self.total
        if now - self.last_print < (self.TTY_PERIOD_S if self.tty else self.LOG_PERIOD_S) and not finished:
            return
        self.last_print = now
        rate = (self.done - self.start_done) / max(now - self.t0, 1e-9)
        eta = (self.total - self.done) / rate if rate > 0 else float("inf")
        line = f"runs {self.done}/{self.total} ({100 * self.done / self.total:.0f} %)  {rate:.0f} runs/s  ETA {eta:.0f} s"
        if self.tty:
            print("\r" + line, end="\n" if finished else "", file=sys.stderr, flush=True)
        else:
            print(line, file=sys.stderr, flush=True)


def _init_worker(threads: int, progress_queue: Any) -> None:
    """Local worker initialiser: Ctrl-C is handled by the main process, which then terminates the
    workers; the compiled loop runs on ``threads`` threads (the CPUs shared among the workers);
    sub-batches report to ``progress_queue``."""
    import signal

    import numba

    global _progress_sink
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    numba.set_num_threads(max(1, min(threads, int(getattr(numba.config, "NUMBA_NUM_THREADS")))))
    _progress_sink = progress_queue


def _start_method() -> str:
    """``fork`` (fast) unless this process has started numba's thread pool, which a forked child
    cannot use (OpenMP hangs): then ``forkserver`` (a clean process forks the workers)."""
    try:
        from numba.np.ufunc import parallel

        launched = bool(getattr(parallel, "_is_initialized", True))
    except ImportError:
        launched = True
    return "forkserver" if launched else "fork"


def _call(task: tuple[int, Callable[..., Any], tuple[Any, ...]]) -> tuple[int, Any]:
    index, fn, args = task
    return index, fn(*args)


class ChunkExecutor:
    """Runs chunk tasks in this process (``workers == 1``), in a pool of local processes, or on a
    Dask cluster, yielding ``(index, result)`` as tasks complete; :meth:`abort` stops at once."""

    def __init__(self, workers: int, scheduler: str | None) -> None:
        self.pool: Any = None
        self.client: Any = None
        self.queue: Any = None  # sub-batch progress of local workers
        self.futures: list[Any] = []
        if scheduler is not None:
            from distributed import Client

            self.client = Client(scheduler)
        elif workers > 1:
            import multiprocessing

            ctx = multiprocessing.get_context(_start_method())
            if ctx.get_start_method() == "forkserver":
                ctx.set_forkserver_preload(["sappc.montecarlo.campaign"])
            self.queue = ctx.SimpleQueue()
            self.pool = ctx.Pool(workers, initializer=_init_worker, initargs=(max(1, (os.cpu_count() or 1) // workers), self.queue))

    def progress(self) -> int:
        """Runs reported finished by local workers since the last call."""
        n = 0
        while self.queue is not None and not self.queue.empty():
            n += int(self.queue.get())
        return n

    def run(self, tasks: list[tuple[int, Callable[..., Any], tuple[Any, ...]]]) -> Iterator[tuple[int, Any]]:
        """Submit every task now (workers start at once) and iterate over the results as they complete."""
        if self.client is not None:
            from distributed import as_completed as dask_as_completed

            self.futures = [self.client.submit(_call, task, pure=False) for task in tasks]
            done: Iterator[tuple[int, Any]] = (fut.result() for fut in dask_as_completed(self.futures))
            return done
        if self.pool is not None:
            return self._poll(self.pool.imap_unordered(_call, tasks))
        return map(_call, tasks)  # in this process: one chunk at a time, each saved before the next starts

    def _poll(self, results: Any) -> Iterator[tuple[int, Any]]:
        """Pool results as they complete, waking up every 0.1 s (``None``) to read the workers' progress."""
        import multiprocessing

        while True:
            try:
                yield results.next(timeout=0.1)
            except multiprocessing.TimeoutError:
                yield None  # type: ignore[misc]  # a tick: no result yet
            except StopIteration:
                return

    def abort(self) -> None:
        if self.pool is not None:
            self.pool.terminate()
        if self.client is not None:
            self.client.cancel(self.futures)

    def close(self) -> None:
        if self.pool is not None:
            self.pool.close()
            self.pool.join()
        if self.client is not None:
            self.client.close()


def _dask_threads(scheduler: str) -> int:
    """The worker threads of the Dask cluster at ``scheduler`` now (at least 1)."""
    from distributed import Client

    with Client(scheduler) as client:
        return max(1, int(sum(client.nthreads().values())))


def balanced_chunk_runs(runs: int, most: int, parallel: int) -> int:
    """The runs per chunk (at most ``most``, the scenario's ``chunk_runs``) for ``parallel`` workers:
    ``most`` for one; for more, chunks of equal size whose count is a multiple of ``parallel``
    where one up to twice the fewest chunks allows (500 runs of at most 100 on two workers: six
    chunks of 84 and 80 runs, where five of 100 left one worker alone with the fifth, 1.1 s of a
    6.4 s command), else the fewest chunks of equal size (the count rounded up to a multiple)."""
    if parallel <= 1:
        return min(most, runs)
    fewest = -(-runs // most)  # chunks of at most ``most``
    rounds = -(-fewest // parallel)  # the fewest rounds of ``parallel`` chunks
    for m in range(rounds, 2 * rounds + 1):
        size = -(-runs // (m * parallel))
        if -(-runs // size) % parallel == 0:
            return size
    return -(-runs // (rounds * parallel))


def run_campaign(
    scenario_path: str | Path,
    *,
    runs: int,
    seed: int,
    out_dir: str | Path,
    workers: int = 1,
    scheduler: str | None = None,
    resume: bool = False,
    progress: bool = True,
    figure_worker: Any = None,
) -> dict[str, Any]:
    """Run (or resume) a campaign and write its results; return the summary.

    Everything is validated before the first run.  Finished chunks are written as they
    complete; an interrupt (Ctrl-C) keeps them and ``resume=True`` continues from them.
    ``figure_worker``: a :class:`sappc.analysis.plots.FigureWorker` started before numba was
    imported (``sappc montecarlo`` forks it first), which imports matplotlib while the runs go and
    then draws the figures; without one (or once it is used) they are drawn in this process.

    Raises
    ------
    ConfigError
        Bad scenario or ``montecarlo`` section (naming the key), bad arguments, or an
        output directory that holds a different campaign.
    """
    from sappc.scenario import load_scenario

    if not isinstance(runs, int) or runs < 1:
        raise ConfigError(f"--runs must be a positive integer, got {runs!r}")
    if not isinstance(seed, int) or seed < 0:
        raise ConfigError(f"--seed must be a non-negative integer, got {seed!r}")
    if workers < 1:
        raise ConfigError(f"--workers must be >= 1, got {workers!r}")
    scenario = load_scenario(scenario_path)
    cfg = campaign_config(scenario)
    _remember(scenario, cfg)  # (the chunks run here or in workers forked from here parse it no more)
    out = Path(out_dir)
    # Enough chunks to keep every worker busy (on a Dask cluster two per worker thread, for the
    # load balance and the progress line, which moves per chunk there), as many for each; the
    # results do not depend on the chunking.
    parallel = workers if scheduler is None else 2 * _dask_threads(scheduler)
    chunk_runs = balanced_chunk_runs(runs, cfg.chunk_runs, parallel)
    manifest = {
        "format": FORMAT_VERSION,
        "scenario_file": str(scenario_path),
        "scenario": scenario.raw,
        "seed": seed,
        "runs": runs,
        "chunk_runs": chunk_runs,
    }
    manifest_path = out / "manifest.json"
    if manifest_path.exists():
        old = json.loads(manifest_path.read_text())
        if not resume:
            raise ConfigError(f"{out} already holds a campaign; pass --resume to continue it or choose another --out")
        same = ("format", "scenario", "seed", "runs")
        if any(old.get(k) != manifest[k] for k in same):
            raise ConfigError(f"{out} holds a campaign with another scenario, seed or run count; cannot resume it")
        chunk_runs = manifest["chunk_runs"] = old["chunk_runs"]  # the finished chunks fix the chunking
    elif resume:
        raise ConfigError(f"--resume: {out} holds no campaign (no manifest.json)")
    (out / "chunks").mkdir(parents=True, exist_ok=True)
    manifest_path.write_text(json.dumps(manifest, indent=2) + "\n")

    todo = [(i, r) for i, r in chunks(runs, chunk_runs) if not chunk_path(out, i).exists()]
    if todo and scheduler is None:
        compiled_loop.ensure_compiled(in_subprocess=workers > 1, groups=compiled_loop.CAMPAIGN_GROUPS)  # compile once, here, not in every worker
        if workers > 1:
            compiled_loop.load_before_fork(scenario)  # once here, not in every worker
    bar = _Progress(runs, runs - sum(len(r) for _, r in todo), progress)  # after compiling: the rate is the runs'
    collector.settle()  # `sappc montecarlo`'s start-up ends here: what it made is frozen before the workers fork (gnc_common.collector)
    executor = ChunkExecutor(workers, scheduler)
    global _progress_sink
    t0 = time.perf_counter()
    sizes = dict(todo)
    tasks = [(i, run_chunk, (scenario.raw, seed, r, max(0, min(cfg.trajectory_runs - r[0], len(r))))) for i, r in todo]
    if executor.pool is None and executor.client is None:
        _progress_sink = bar.update  # sub-batches in this process report directly
    try:
        results = executor.run(tasks)
        if (executor.pool is not None or executor.client is not None) and not (figure_worker is not None and figure_worker.alive):
            import matplotlib.pyplot  # noqa: F401  (the figures need it; import it while the workers compute)
        for item in results:
            if executor.queue is not None:
                bar.update(executor.progress())
            if item is None:
                continue
            i, result = item
            save_chunk(out, i, result)
            if executor.client is not None:  # Dask workers report per chunk
                bar.update(len(sizes[i]))
    except KeyboardInterrupt:
        executor.abort()
        done = len(list((out / "chunks").glob("chunk_*.npz")))
        print(f"\ninterrupted: {done} chunk(s) kept in {out}; continue with --resume", file=sys.stderr)
        raise
    finally:
        _progress_sink = None
        executor.close()
    return assemble(out, scenario, cfg, manifest, wall_s=time.perf_counter() - t0, figure_worker=figure_worker)


def load_campaign_run(campaign_dir: str | Path, run: int, *, with_history: bool = False) -> tuple[Scenario, dict[str, Array], dict[str, Any], Any]:
    """Re-run run ``run`` of a campaign alone (for ``sappc simulate --from-campaign``).

    Returns the scenario, the run's campaign results (identical to its row of the campaign's
    table), its full metrics, and its :class:`~sappc.evaluation.history.History` when ``with_history``
    (else ``None``).  The same compiled loop as the campaign's: the same numbers, bit for bit.
    """
    out = Path(campaign_dir)
    try:
        manifest = json.loads((out / "manifest.json").read_text())
    except OSError as exc:
        raise ConfigError(f"{out} is not a campaign directory: {exc.strerror}") from None
    if not isinstance(run, int) or not 0 <= run < manifest["runs"]:
        raise ConfigError(f"--run must be in [0, {manifest['runs'] - 1}], got {run!r}")
    scenario = scenario_from_mapping(manifest["scenario"])
    row, metrics, result = simulate_runs(manifest["scenario"], manifest["seed"], [run], 0, with_history=with_history)
    return scenario, row, metrics.run_metrics(0), result.history

"""Monte Carlo campaigns: thousands of dispersed runs as vectorised batches, locally or on Dask.

A campaign is a scenario file with a ``montecarlo`` section (see
``config/scenarios/paper_montecarlo.yaml``).  Runs are simulated in chunks, each
chunk one batch through the same closed loop and metrics as `sappc simulate`.

Reproducibility
---------------
Every random input of run ``k`` comes from ``SeedSequence(seed, spawn_key=(k,))``:
its first child draws the dispersed values, its second the sensor noise.  A
run therefore depends only on ``(seed, k)``, not on the chunk size, the number
of workers or the scheduler, and since a run inside a batch is bit for bit the
run alone (see ``gnc_common.attitude``), the per-run results are
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

import dataclasses
import json
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from gnc_common.validation import ConfigError
from sappc_controller.core.base import SingularStartError
from sappc_controller.core.rpf import InfeasiblePolicy
from sappc.evaluation.history import both
from sappc.montecarlo.config import campaign_config
from sappc.montecarlo.draws import NoisySensor, dispersed_disturbance, draw_inputs
from sappc.montecarlo.results import FORMAT_VERSION, assemble, chunk_path, chunks, save_chunk
from sappc.offline.closed_loop import step_times
from sappc.offline.simulate import run_scenario
from sappc.scenario import ControllerKind, Scenario, scenario_from_mapping

__all__ = ["load_campaign_run", "run_campaign", "run_chunk", "simulate_runs"]

Array = NDArray[np.float64]


class _Trajectories:
    """Observer keeping a down-sampled copy of q_ev and rho for the first few runs of a chunk."""

    def __init__(self, n_keep: int, stride: int) -> None:
        self.n, self.stride = n_keep, stride
        self.t: list[float] = []
        self.q_ev: list[Array] = []
        self.rho: list[Array] = []

    def __call__(self, k: int, t: float, x: Array, out: Any, d: Array) -> None:
        if self.n and k % self.stride == 0:
            self.t.append(t)
            self.q_ev.append(out.q_BR[: self.n, :3].astype(np.float32))
            self.rho.append(out.rho[: self.n].astype(np.float32))


def run_chunk(scenario_raw: dict[str, Any], seed: int, runs: list[int], keep_trajectories: int) -> dict[str, NDArray[Any]]:
    """Simulate ``runs`` of a campaign as one batch; return the per-run results (a worker task).

    Takes the parsed scenario mapping (not objects) so that it can run in any process or on
    any Dask worker.  A run whose state becomes non-finite is reported with ``finite = False``;
    the other runs of the batch are unaffected (every operation is per run).
    """
    return simulate_runs(scenario_raw, seed, runs, keep_trajectories)[0]


def simulate_runs(
    scenario_raw: dict[str, Any], seed: int, runs: list[int], keep_trajectories: int, observer: Any = None
) -> tuple[dict[str, NDArray[Any]], Any]:
    """:func:`run_chunk` with an optional extra observer; also returns the metrics accumulator."""
    scenario = scenario_from_mapping(scenario_raw)
    cfg = campaign_config(scenario)
    inputs = draw_inputs(cfg, seed, runs)
    n = len(runs)
    J = scenario.inertia_kg_m2
    if cfg.dispersions.inertia_relative is not None:
        S = np.sqrt(1.0 + inputs.inertia_relative)  # (n, 3)
        J = S[:, :, None] * J[None] * S[:, None, :]
    config = scenario.controller_config()
    if inputs.gains:
        if not hasattr(config, "gains") or not hasattr(config.gains, "K_q"):
            raise ConfigError(f"montecarlo.dispersions.gains needs a SAPPC or TraPPC controller, not {scenario.controller.value!r}")
        config = dataclasses.replace(config, gains=dataclasses.replace(config.gains, **inputs.gains))
    traj = _Trajectories(min(keep_trajectories, n), cfg.trajectory_stride)
    with np.errstate(all="ignore"):  # a diverging run is reported, not raised
        try:
            metrics, controller = run_scenario(
                scenario,
                controller_config=config,
                controller_options={"on_infeasible": InfeasiblePolicy.CLAMP} if scenario.controller == ControllerKind.SAPPC else {},
                q_BN0=inputs.q_BN0,
                omega_BN_B0_rad_s=inputs.omega_BN_B0,
                inertia_kg_m2=J,
                disturbance=dispersed_disturbance(scenario, inputs),
                measure=NoisySensor(cfg.dispersions.sensor_noise, seed, inputs.runs) if cfg.dispersions.sensor_noise.enabled else None,
                observer=traj if observer is None else both(traj, observer),
            )
        except SingularStartError as exc:  # name the campaign's run, not its place in this chunk
            raise SingularStartError(exc.q_e0, int(inputs.runs[exc.run])) from None
    crit = metrics.criteria_arrays()
    rpf = getattr(getattr(controller, "transformation", None), "rpf", None)
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
        "settling_time_s": crit["settling_time_s"],
        "finite": crit["finite"],
        "rpf_clamped": rpf.clamped if rpf is not None else np.zeros((n, 3), dtype=bool),
        "rpf_flat": rpf.flat if rpf is not None else np.zeros((n, 3), dtype=bool),
        "traj_t": np.asarray(traj.t),
        "traj_q_ev": np.stack(traj.q_ev, axis=0) if traj.q_ev and traj.n else np.zeros((0, 0, 3), np.float32),
        "traj_rho": np.stack(traj.rho, axis=0) if traj.rho and traj.n else np.zeros((0, 0, 3), np.float32),
    }, metrics


class _Progress:
    """A one-line progress report on stderr: runs done, runs/s, ETA."""

    def __init__(self, total: int, done: int, enabled: bool) -> None:
        self.total, self.done, self.enabled = total, done, enabled
        self.start_done, self.t0 = done, time.perf_counter()
        self.tty = sys.stderr.isatty()
        self.last_print = 0.0

    def update(self, n: int) -> None:
        self.done += n
        if not self.enabled:
            return
        now = time.perf_counter()
        rate = (self.done - self.start_done) / max(now - self.t0, 1e-9)
        eta = (self.total - self.done) / rate if rate > 0 else float("inf")
        line = f"runs {self.done}/{self.total} ({100 * self.done / self.total:.0f} %)  {rate:.0f} runs/s  ETA {eta:.0f} s"
        if self.tty:
            print("\r" + line, end="" if self.done < self.total else "\n", file=sys.stderr, flush=True)
        elif now - self.last_print > 5.0 or self.done == self.total:
            print(line, file=sys.stderr, flush=True)
            self.last_print = now


def _ignore_sigint() -> None:
    """Worker initialiser: Ctrl-C is handled by the main process, which then terminates the workers."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _call(task: tuple[int, Callable[..., Any], tuple[Any, ...]]) -> tuple[int, Any]:
    index, fn, args = task
    return index, fn(*args)


class _Executor:
    """Runs chunk tasks in this process (``workers == 1``), in a pool of local processes, or on a
    Dask cluster, yielding ``(index, result)`` as tasks complete; :meth:`abort` stops at once."""

    def __init__(self, workers: int, scheduler: str | None) -> None:
        self.pool: Any = None
        self.client: Any = None
        self.futures: list[Any] = []
        if scheduler is not None:
            from distributed import Client

            self.client = Client(scheduler)
        elif workers > 1:
            import multiprocessing

            self.pool = multiprocessing.get_context("fork").Pool(workers, initializer=_ignore_sigint)

    def run(self, tasks: list[tuple[int, Callable[..., Any], tuple[Any, ...]]]) -> Iterator[tuple[int, Any]]:
        """Submit every task now (workers start at once) and iterate over the results as they complete."""
        if self.client is not None:
            from distributed import as_completed as dask_as_completed

            self.futures = [self.client.submit(_call, task, pure=False) for task in tasks]
            done: Iterator[tuple[int, Any]] = (fut.result() for fut in dask_as_completed(self.futures))
            return done
        if self.pool is not None:
            unordered: Iterator[tuple[int, Any]] = self.pool.imap_unordered(_call, tasks)
            return unordered
        return map(_call, tasks)  # in this process: one chunk at a time, each saved before the next starts

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
) -> dict[str, Any]:
    """Run (or resume) a campaign and write its results; return the summary.

    Everything is validated before the first run.  Finished chunks are written as they
    complete; an interrupt (Ctrl-C) keeps them and ``resume=True`` continues from them.

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
    out = Path(out_dir)
    # Enough chunks to keep every worker busy; the results do not depend on the chunking.
    chunk_runs = min(cfg.chunk_runs, -(-runs // (workers if scheduler is None else 1)))
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
    bar = _Progress(runs, runs - sum(len(r) for _, r in todo), progress)
    executor = _Executor(workers, scheduler)
    t0 = time.perf_counter()
    sizes = dict(todo)
    tasks = [(i, run_chunk, (scenario.raw, seed, r, max(0, min(cfg.trajectory_runs - r[0], len(r))))) for i, r in todo]
    try:
        results = executor.run(tasks)
        if executor.pool is not None or executor.client is not None:
            import matplotlib.pyplot  # noqa: F401  (the figures need it; import it while the workers compute)
        for i, result in results:
            save_chunk(out, i, result)
            bar.update(len(sizes[i]))
    except KeyboardInterrupt:
        executor.abort()
        done = len(list((out / "chunks").glob("chunk_*.npz")))
        print(f"\ninterrupted: {done} chunk(s) kept in {out}; continue with --resume", file=sys.stderr)
        raise
    finally:
        executor.close()
    return assemble(out, scenario, cfg, manifest, wall_s=time.perf_counter() - t0)


def load_campaign_run(campaign_dir: str | Path, run: int, *, with_history: bool = False) -> tuple[Scenario, dict[str, Array], dict[str, Any], Any]:
    """Re-run run ``run`` of a campaign alone (for ``sappc simulate --from-campaign``).

    Returns the scenario, the run's campaign results (identical to its row of the campaign's
    table), its full metrics, and its :class:`~sappc.offline.closed_loop.History` when ``with_history``
    (else ``None``).
    """
    from sappc.evaluation.history import HistoryRecorder

    out = Path(campaign_dir)
    try:
        manifest = json.loads((out / "manifest.json").read_text())
    except OSError as exc:
        raise ConfigError(f"{out} is not a campaign directory: {exc.strerror}") from None
    if not isinstance(run, int) or not 0 <= run < manifest["runs"]:
        raise ConfigError(f"--run must be in [0, {manifest['runs'] - 1}], got {run!r}")
    scenario = scenario_from_mapping(manifest["scenario"])
    recorder = HistoryRecorder(step_times(scenario.duration_s, scenario.control_period_s), 1) if with_history else None
    row, metrics = simulate_runs(manifest["scenario"], manifest["seed"], [run], 0, recorder)
    return scenario, row, metrics.run_metrics(0), recorder.history() if recorder is not None else None

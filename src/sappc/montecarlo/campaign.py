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

import csv
import dataclasses
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from collections.abc import Callable, Iterable, Iterator
from typing import Any

import numpy as np
from numpy.typing import NDArray

from gnc_common.attitude import euler_to_quaternion, quat_multiply, quat_normalize
from spacecraft_sim.core.disturbance import DisturbanceSum, PaperPeriodic
from gnc_common.validation import ConfigError, check_positive, from_mapping

from sappc.evaluation.history import both
from sappc.offline.closed_loop import step_times
from sappc.scenario import ControllerKind, Scenario, scenario_from_mapping
from sappc.offline.simulate import run_scenario

__all__ = ["CampaignConfig", "Distribution", "run_campaign", "run_chunk", "load_campaign_run"]

Array = NDArray[np.float64]


# ----------------------------------------------------------------------------- configuration


@dataclass(frozen=True)
class Distribution:
    """A scalar or per-axis distribution.

    ``distribution: uniform`` with ``low`` and ``high`` (``low <= high``), or
    ``distribution: normal`` with ``mean`` and ``sigma`` (``sigma >= 0``);
    each value a number or a list of 3 (per axis).
    """

    distribution: str
    low: float | tuple[float, ...] | None = None
    high: float | tuple[float, ...] | None = None
    mean: float | tuple[float, ...] | None = None
    sigma: float | tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        if self.distribution == "uniform":
            if self.low is None or self.high is None or self.mean is not None or self.sigma is not None:
                raise ConfigError("a uniform distribution takes exactly 'low' and 'high'")
            lo, hi = np.asarray(self.low, dtype=float), np.asarray(self.high, dtype=float)
            if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))) or np.any(hi < lo):
                raise ConfigError(f"needs finite low <= high, got low = {self.low!r}, high = {self.high!r}")
        elif self.distribution == "normal":
            if self.mean is None or self.sigma is None or self.low is not None or self.high is not None:
                raise ConfigError("a normal distribution takes exactly 'mean' and 'sigma'")
            sig = np.asarray(self.sigma, dtype=float)
            if not np.all(np.isfinite(sig)) or np.any(sig < 0) or not np.all(np.isfinite(np.asarray(self.mean, dtype=float))):
                raise ConfigError(f"needs finite mean and sigma >= 0, got mean = {self.mean!r}, sigma = {self.sigma!r}")
        else:
            raise ConfigError(f"unknown distribution {self.distribution!r}; expected 'uniform' or 'normal'")

    def _params(self) -> tuple[Array, Array]:
        a, b = (self.low, self.high) if self.distribution == "uniform" else (self.mean, self.sigma)
        return np.asarray(a, dtype=float), np.asarray(b, dtype=float)

    def check_shape(self, name: str, shape: tuple[int, ...]) -> None:
        """Raise unless the parameters broadcast to ``shape`` (``()`` scalar, ``(3,)`` per axis)."""
        a, b = self._params()
        try:
            if np.broadcast_shapes(a.shape, b.shape, shape) != shape:
                raise ValueError
        except ValueError:
            raise ConfigError(f"{name} must have {'scalar' if not shape else f'scalar or {shape[0]}-vector'} parameters, got {self!r}") from None

    def draw(self, rng: np.random.Generator, shape: tuple[int, ...]) -> Array:
        """Independent draws of the given shape (``(3,)``: one per axis)."""
        a, b = self._params()
        if self.distribution == "uniform":
            return a + (b - a) * rng.random(shape)
        return a + b * rng.standard_normal(shape)


@dataclass(frozen=True)
class InitialAttitude:
    """Initial attitude from Euler angles, each uniform in ``[low_deg, high_deg]``, applied in ``sequence``
    (upper case: intrinsic rotations about body axes, scipy's convention)."""

    sequence: str = "ZYX"
    low_deg: float = -85.0
    high_deg: float = 85.0

    def __post_init__(self) -> None:
        if len(self.sequence) != 3 or not (self.sequence.isupper() or self.sequence.islower()) or set(self.sequence.upper()) - set("XYZ"):
            raise ConfigError(f"sequence must be three axis letters like 'ZYX' (intrinsic) or 'zyx' (extrinsic), got {self.sequence!r}")
        if not (np.isfinite(self.low_deg) and np.isfinite(self.high_deg)) or self.high_deg < self.low_deg:
            raise ConfigError(f"needs low_deg <= high_deg, got {self.low_deg!r}, {self.high_deg!r}")


@dataclass(frozen=True)
class SensorNoise:
    """White measurement noise, a new draw every control period: a small rotation of the measured
    attitude (standard deviation per axis [rad]) and an additive rate error [rad/s]."""

    attitude_sigma_rad: float = 0.0
    rate_sigma_rad_s: float = 0.0

    def __post_init__(self) -> None:
        check_positive("attitude_sigma_rad", self.attitude_sigma_rad, allow_zero=True)
        check_positive("rate_sigma_rad_s", self.rate_sigma_rad_s, allow_zero=True)

    @property
    def enabled(self) -> bool:
        return self.attitude_sigma_rad > 0.0 or self.rate_sigma_rad_s > 0.0


#: SAPPC/TraPPC gains a campaign may disperse (per run; the law broadcasts them).
DISPERSIBLE_GAINS = ("K_q", "K_omega", "D_m_Nm", "mu_rad_s")


@dataclass(frozen=True)
class GainDispersions:
    """Per-run controller gains of the backstepping law (SAPPC, TraPPC); each a uniform
    distribution with ``low > 0`` (a normal one could draw non-positive gains)."""

    K_q: Distribution | None = None
    K_omega: Distribution | None = None
    D_m_Nm: Distribution | None = None
    mu_rad_s: Distribution | None = None

    def __post_init__(self) -> None:
        for name in DISPERSIBLE_GAINS:
            d = getattr(self, name)
            if d is not None:
                d.check_shape(name, ())
                if d.distribution != "uniform" or not np.min(d.low) > 0.0:
                    raise ConfigError(f"{name} must be a uniform distribution with low > 0, got {d!r}")

    def items(self) -> list[tuple[str, Distribution]]:
        return [(n, getattr(self, n)) for n in DISPERSIBLE_GAINS if getattr(self, n) is not None]


@dataclass(frozen=True)
class Dispersions:
    """What varies from run to run besides the initial attitude (all optional).

    Attributes
    ----------
    initial_rate_rad_s : Distribution
        Initial body rate, per axis [rad/s].
    inertia_relative : Distribution
        ``u`` per axis: the plant's inertia is ``S J S`` with ``S = diag(sqrt(1 + u))``,
        symmetric positive definite for ``u > -1`` (a congruence).  The controller keeps the
        nominal ``J`` (what flight software knows).
    disturbance_scale, disturbance_phase_rad : Distribution
        Scale and phase of the paper's periodic disturbance (scalar per run).
    sensor_noise : SensorNoise
    gains : GainDispersions
        Per-run controller gains (``K_q``, ``K_omega``, ``D_m_Nm``, ``mu_rad_s``).
    """

    initial_rate_rad_s: Distribution | None = None
    inertia_relative: Distribution | None = None
    disturbance_scale: Distribution | None = None
    disturbance_phase_rad: Distribution | None = None
    sensor_noise: SensorNoise = SensorNoise()
    gains: GainDispersions = GainDispersions()


@dataclass(frozen=True)
class Criteria:
    """Pass criteria of a run (the paper's experiment 4)."""

    rpf_error_at_t2_max: float = 1e-4
    steady_mean_abs_qev_max: float = 5e-5


@dataclass(frozen=True)
class CampaignConfig:
    """The ``montecarlo`` section of a scenario file.

    Attributes
    ----------
    initial_attitude : InitialAttitude
    dispersions : Dispersions
    criteria : Criteria
    chunk_runs : int
        Runs per batch (a unit of work and of resumption); results do not depend on it.
    trajectory_runs : int
        How many runs (the first ones) keep a down-sampled trajectory for the overlay figure.
    trajectory_stride : int
        Keep every ``trajectory_stride``-th sample of those trajectories.
    """

    initial_attitude: InitialAttitude = InitialAttitude()
    dispersions: Dispersions = Dispersions()
    criteria: Criteria = Criteria()
    chunk_runs: int = 500
    trajectory_runs: int = 300
    trajectory_stride: int = 10

    def __post_init__(self) -> None:
        for name in ("chunk_runs", "trajectory_stride"):
            v = getattr(self, name)
            if not isinstance(v, int) or v < 1:
                raise ConfigError(f"{name} must be a positive integer, got {v!r}")
        if not isinstance(self.trajectory_runs, int) or self.trajectory_runs < 0:
            raise ConfigError(f"trajectory_runs must be a non-negative integer, got {self.trajectory_runs!r}")
        d = self.dispersions
        for name, shape in (("initial_rate_rad_s", (3,)), ("inertia_relative", (3,)), ("disturbance_scale", ()), ("disturbance_phase_rad", ())):
            dist = getattr(d, name)
            if dist is not None:
                dist.check_shape(f"dispersions.{name}", shape)
        inertia = self.dispersions.inertia_relative
        if inertia is not None:
            lowest = np.min(inertia.low) if inertia.distribution == "uniform" else -np.inf
            if inertia.distribution == "normal" and np.all(np.asarray(inertia.sigma) == 0):
                lowest = np.min(inertia.mean)
            if not lowest > -1.0:
                raise ConfigError(
                    "dispersions.inertia_relative must stay above -1 (S J S with S = diag(sqrt(1 + u)) is positive "
                    f"definite only then); got {inertia!r}" + (" (a normal distribution is unbounded)" if inertia.distribution == "normal" else "")
                )


def campaign_config(scenario: Scenario) -> CampaignConfig:
    """Parse and validate the scenario's ``montecarlo`` section (before any run starts)."""
    section = scenario.raw.get("montecarlo")
    if section is None:
        raise ConfigError(f"scenario {scenario.name!r} has no 'montecarlo' section")
    return from_mapping(CampaignConfig, section, "montecarlo")


# ----------------------------------------------------------------------------- one chunk


@dataclass(frozen=True)
class RunInputs:
    """Dispersed inputs of a set of runs, arrays with a leading axis of runs."""

    runs: NDArray[np.int64]
    euler_deg: Array
    q_BN0: Array
    omega_BN_B0: Array
    inertia_relative: Array
    disturbance_scale: Array
    disturbance_phase_rad: Array
    gains: dict[str, Array]


def _run_rngs(seed: int, run: int) -> tuple[np.random.Generator, np.random.Generator]:
    dispersion, noise = np.random.SeedSequence(seed, spawn_key=(run,)).spawn(2)
    return np.random.default_rng(dispersion), np.random.default_rng(noise)


def draw_inputs(cfg: CampaignConfig, seed: int, runs: Iterable[int]) -> RunInputs:
    """The dispersed values of ``runs``: each run's from its own generator, in a fixed order."""
    runs_arr = np.fromiter(runs, dtype=np.int64)
    d = cfg.dispersions
    rows = []
    for k in runs_arr:
        rng, _ = _run_rngs(seed, int(k))
        ia = cfg.initial_attitude
        euler = rng.uniform(ia.low_deg, ia.high_deg, 3)
        rate = d.initial_rate_rad_s.draw(rng, (3,)) if d.initial_rate_rad_s else np.zeros(3)
        inertia = d.inertia_relative.draw(rng, (3,)) if d.inertia_relative else np.zeros(3)
        scale = float(d.disturbance_scale.draw(rng, ())) if d.disturbance_scale else 1.0
        phase = float(d.disturbance_phase_rad.draw(rng, ())) if d.disturbance_phase_rad else 0.0
        gains = {name: float(dist.draw(rng, ())) for name, dist in d.gains.items()}
        rows.append((euler, rate, inertia, scale, phase, gains))
    euler = np.array([r[0] for r in rows]).reshape(-1, 3)
    return RunInputs(
        runs=runs_arr,
        euler_deg=euler,
        q_BN0=euler_to_quaternion(np.radians(euler), cfg.initial_attitude.sequence).reshape(-1, 4),
        omega_BN_B0=np.array([r[1] for r in rows]).reshape(-1, 3),
        inertia_relative=np.array([r[2] for r in rows]).reshape(-1, 3),
        disturbance_scale=np.array([r[3] for r in rows]),
        disturbance_phase_rad=np.array([r[4] for r in rows]),
        gains={name: np.array([r[5][name] for r in rows]) for name, _ in d.gains.items()},
    )


class _NoisySensor:
    """Measured state = true state with the campaign's sensor noise, drawn per run from its own stream."""

    #: Samples of noise drawn per run at once.
    BLOCK = 256

    def __init__(self, noise: SensorNoise, seed: int, runs: NDArray[np.int64]) -> None:
        self.noise = noise
        self.rngs = [_run_rngs(seed, int(k))[1] for k in runs]
        self.block: Array | None = None

    def __call__(self, k: int, x: Array) -> Array:
        if k % self.BLOCK == 0:
            self.block = np.stack([rng.standard_normal((self.BLOCK, 6)) for rng in self.rngs], axis=1)  # (BLOCK, n, 6)
        assert self.block is not None
        z = self.block[k % self.BLOCK]
        half = 0.5 * self.noise.attitude_sigma_rad * z[:, :3]
        dq = np.concatenate((half, np.ones((z.shape[0], 1))), axis=1)
        y = np.array(x, order="F")
        y[:, :4] = quat_normalize(quat_multiply(x[:, :4], dq))  # body-frame small rotation error
        y[:, 4:] = x[:, 4:] + self.noise.rate_sigma_rad_s * z[:, 3:]
        return y


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


def run_chunk(scenario_raw: dict[str, Any], seed: int, runs: list[int], keep_trajectories: int) -> dict[str, Array]:
    """Simulate ``runs`` of a campaign as one batch; return the per-run results (a worker task).

    Takes the parsed scenario mapping (not objects) so that it can run in any process or on
    any Dask worker.  A run whose state becomes non-finite is reported with ``finite = False``;
    the other runs of the batch are unaffected (every operation is per run).
    """
    return simulate_runs(scenario_raw, seed, runs, keep_trajectories)[0]


def simulate_runs(
    scenario_raw: dict[str, Any], seed: int, runs: list[int], keep_trajectories: int, observer: Any = None
) -> tuple[dict[str, Array], Any]:
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
        metrics, controller = run_scenario(
            scenario,
            controller_config=config,
            controller_options={"on_infeasible": "clamp"} if scenario.controller == ControllerKind.SAPPC else {},
            q_BN0=inputs.q_BN0,
            omega_BN_B0_rad_s=inputs.omega_BN_B0,
            inertia_kg_m2=J,
            disturbance=_dispersed_disturbance(scenario, inputs),
            measure=_NoisySensor(cfg.dispersions.sensor_noise, seed, inputs.runs) if cfg.dispersions.sensor_noise.enabled else None,
            observer=traj if observer is None else both(traj, observer),
        )
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


def _dispersed_disturbance(scenario: Scenario, inputs: RunInputs) -> DisturbanceSum:
    """The scenario's disturbances with the paper model's scale and phase set per run."""
    models = []
    for m in scenario.disturbance.models:
        if isinstance(m, PaperPeriodic):
            m = dataclasses.replace(
                m,
                scale=tuple(inputs.disturbance_scale * np.asarray(m.scale, dtype=float)),
                phase_rad=tuple(inputs.disturbance_phase_rad + np.asarray(m.phase_rad, dtype=float)),
            )
        models.append(m)
    return DisturbanceSum(tuple(models))


# ----------------------------------------------------------------------------- the campaign

#: Version of the chunk/manifest format (bumped when their contents change).
FORMAT_VERSION = 1
#: Per-axis columns of the run table.
_AXES = (1, 2, 3)


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


def _chunks(n_runs: int, chunk_runs: int) -> list[tuple[int, list[int]]]:
    return [(i, list(range(s, min(s + chunk_runs, n_runs)))) for i, s in enumerate(range(0, n_runs, chunk_runs))]


def _chunk_path(out: Path, index: int) -> Path:
    return out / "chunks" / f"chunk_{index:06d}.npz"


def _save_chunk(out: Path, index: int, result: dict[str, Array]) -> None:
    path = _chunk_path(out, index)
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, **result)
    tmp.replace(path)  # atomic: a chunk file is either complete or absent


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
            return (fut.result() for fut in dask_as_completed(self.futures))
        if self.pool is not None:
            return self.pool.imap_unordered(_call, tasks)
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

    todo = [(i, r) for i, r in _chunks(runs, chunk_runs) if not _chunk_path(out, i).exists()]
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
            _save_chunk(out, i, result)
            bar.update(len(sizes[i]))
    except KeyboardInterrupt:
        executor.abort()
        done = len(list((out / "chunks").glob("chunk_*.npz")))
        print(f"\ninterrupted: {done} chunk(s) kept in {out}; continue with --resume", file=sys.stderr)
        raise
    finally:
        executor.close()
    return _assemble(out, scenario, cfg, manifest, wall_s=time.perf_counter() - t0)


def _load_chunks(out: Path, n_chunks: int) -> dict[str, Any]:
    parts = [dict(np.load(_chunk_path(out, i), allow_pickle=False)) for i in range(n_chunks)]
    keys = [k for k in parts[0] if not k.startswith("traj_")]
    table = {k: np.concatenate([p[k] for p in parts]) for k in keys}
    traj = [p for p in parts if p["traj_q_ev"].size]
    table["traj_t"] = traj[0]["traj_t"] if traj else np.zeros(0)
    table["traj_q_ev"] = np.concatenate([p["traj_q_ev"] for p in traj], axis=1) if traj else np.zeros((0, 0, 3))
    table["traj_rho"] = np.concatenate([p["traj_rho"] for p in traj], axis=1) if traj else np.zeros((0, 0, 3))
    return table


def _percentiles(x: Array) -> dict[str, float | None]:
    x = x[np.isfinite(x)]
    if not x.size:
        return {"p50": None, "p90": None, "p99": None, "max": None}
    p = np.percentile(x, [50, 90, 99])
    return {"p50": float(p[0]), "p90": float(p[1]), "p99": float(p[2]), "max": float(x.max())}


def _assemble(out: Path, scenario: Scenario, cfg: CampaignConfig, manifest: dict[str, Any], *, wall_s: float) -> dict[str, Any]:
    runs, seed = manifest["runs"], manifest["seed"]
    tab = _load_chunks(out, len(_chunks(runs, manifest["chunk_runs"])))
    crit = cfg.criteria
    t2 = tab["rpf_error_at_t2_per_axis"].max(axis=1)
    steady = tab["steady_mean_abs_qev_per_axis"].max(axis=1)
    finite = tab["finite"].astype(bool)
    ok_t2 = finite & (t2 < crit.rpf_error_at_t2_max)
    ok_steady = finite & (steady < crit.steady_mean_abs_qev_max)
    passed = ok_t2 & ok_steady

    gain_keys = [k for k in tab if k.startswith("gain_")]
    with (out / "runs.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(
            ["run", "seed", "passed", "finite"]
            + [f"euler_deg_{i}" for i in _AXES] + [f"omega0_rad_s_{i}" for i in _AXES] + [f"inertia_relative_{i}" for i in _AXES]
            + ["disturbance_scale", "disturbance_phase_rad"] + gain_keys
            + [f"rpf_error_at_t2_{i}" for i in _AXES] + ["rpf_error_at_t2"]
            + [f"steady_mean_abs_qev_{i}" for i in _AXES] + ["steady_mean_abs_qev", "steady_max_abs_qev", "settling_time_s",
                                                           "max_abs_torque_Nm", "rpf_clamped_components", "rpf_flat_components"]
        )
        for k in range(runs):
            w.writerow(
                [int(tab["run"][k]), seed, bool(passed[k]), bool(finite[k])]
                + [f"{v:.17g}" for v in tab["euler_deg"][k]] + [f"{v:.17g}" for v in tab["omega_BN_B0_rad_s"][k]]
                + [f"{v:.17g}" for v in tab["inertia_relative"][k]]
                + [f"{tab['disturbance_scale'][k]:.17g}", f"{tab['disturbance_phase_rad'][k]:.17g}"]
                + [f"{tab[g][k]:.17g}" for g in gain_keys]
                + [f"{v:.17g}" for v in tab["rpf_error_at_t2_per_axis"][k]] + [f"{t2[k]:.17g}"]
                + [f"{v:.17g}" for v in tab["steady_mean_abs_qev_per_axis"][k]]
                + [f"{steady[k]:.17g}", f"{tab['steady_max_abs_qev'][k]:.17g}", f"{tab['settling_time_s'][k]:.17g}",
                   f"{tab['max_abs_torque_Nm'][k]:.17g}", int(tab["rpf_clamped"][k].sum()), int(tab["rpf_flat"][k].sum())]
            )

    def run_ref(k: int) -> dict[str, Any]:
        return {"run": int(k), "seed_sequence": {"entropy": seed, "spawn_key": [int(k)]},
                "rpf_error_at_t2": float(t2[k]), "steady_mean_abs_qev": float(steady[k]), "finite": bool(finite[k])}

    failing = np.flatnonzero(~passed)
    reasons = []
    for k in failing[:100]:
        why = [] if finite[k] else ["non-finite state"]
        if finite[k] and not ok_t2[k]:
            why.append(f"rpf_error_at_t2 {t2[k]:.3g} >= {crit.rpf_error_at_t2_max:g}")
        if finite[k] and not ok_steady[k]:
            why.append(f"steady_mean_abs_qev {steady[k]:.3g} >= {crit.steady_mean_abs_qev_max:g}")
        reasons.append({**run_ref(int(k)), "why": "; ".join(why)})
    worst_t2 = int(np.nanargmax(np.where(finite, t2, -np.inf)))
    worst_steady = int(np.nanargmax(np.where(finite, steady, -np.inf)))
    summary: dict[str, Any] = {
        "scenario": scenario.name,
        "runs": runs,
        "seed": seed,
        "criteria": dataclasses.asdict(crit),
        "passed": int(passed.sum()),
        "pass_fraction": float(passed.mean()),
        "failed_runs": reasons,
        "failed_runs_listed": len(reasons),
        "non_finite_runs": int((~finite).sum()),
        "rpf_clamped_components": int(tab["rpf_clamped"].sum()),
        "rpf_flat_components": int(tab["rpf_flat"].sum()),
        "worst_rpf_error_at_t2": run_ref(worst_t2),
        "worst_steady_mean_abs_qev": run_ref(worst_steady),
        "rpf_error_at_t2": _percentiles(t2),
        "steady_mean_abs_qev": _percentiles(steady),
        "settling_time_s": _percentiles(tab["settling_time_s"]),
        "max_abs_torque_Nm": _percentiles(tab["max_abs_torque_Nm"]),
        "wall_time_s": wall_s,
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    from sappc.analysis.plots import plot_campaign

    plot_campaign(tab, out, criteria=(crit.rpf_error_at_t2_max, crit.steady_mean_abs_qev_max), title=scenario.name)
    return summary


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

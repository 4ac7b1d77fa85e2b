"""``sappc tune``: the controller's free gains found with a Monte Carlo campaign in the loop.

The paper leaves ``B0``, ``K_q``, ``K_omega``, ``mu`` and ``D_m`` free.  A study proposes gains
(Optuna's TPE sampler), runs each proposal on a whole dispersed campaign (the scenario's
``montecarlo`` section, :func:`sappc.montecarlo.campaign.simulate_runs`: the compiled loop, in
this process or in chunks on local workers or a Dask cluster as a campaign runs), checks every
run against the requirements, and keeps the best feasible proposal.

The ``tuning`` section of a scenario (:class:`TuningConfig`, validated before any trial):

.. code-block:: yaml

    tuning:
      parameters:                 # paths under controllers.<controller>, each a range
        gains.K_q: {low: 0.05, high: 2.0, log: true}
        B0: {low: 0.005, high: 0.03}
      requirements:               # every run of a trial's campaign must meet each one given
        settle_by_t2: true                    # max |q_ev,i| < metrics.settle_threshold from metrics.t2_s on
        overshoot_max: 1.0e-4                 # the metrics' overshoot (excursion past zero)
        steady_max_abs_qev_max: 5.0e-5        # max |q_ev,i| over the steady window
        torque_sign_changes_per_s_max: 1.0    # no chattering
        max_abs_wheel_speed_rad_s_max: 500.0  # with reaction wheels: the fastest wheel's speed [rad/s]
      objective: {metric: steady_max_abs_qev, percentile: 99}   # minimised over the campaign
      baselines:                  # named gain sets confirmed beside the result (e.g. the flight gains)
        hand_tuned: {B0: 0.016, gains.K_q: 0.3}
      trials: 60
      runs_per_trial: 32
      confirmation_runs: 256
      seed: 0

Why TPE: it handles constraints (``Trial.set_constraint``: a trial whose campaign breaks a
requirement is infeasible, and the sampler learns where the feasible region is), mixes
log-uniform and uniform ranges, needs no derivative and no extra dependency.  Optuna's CMA-ES
sampler takes no constraints, and its Gaussian-process sampler needs PyTorch.

Common random numbers: every trial runs the same runs ``0 .. runs_per_trial - 1`` of the seed
(each run's inputs from ``SeedSequence(seed, spawn_key=(k,))``, as a campaign draws them), so
trials differ only by their gains.  The confirmation campaign runs the best gains, and the
scenario's own ones for comparison, on runs the study never saw (:data:`CONFIRMATION_FIRST_RUN`
onwards), with every gain set of ``baselines``: each is also run on the scenario's own case
(undispersed), and the summary has one table of them all.

Resumable and reproducible: the study is an Optuna journal file (``study.journal``: an
append-only log, safe to interrupt at any point) in the output directory.  Trial ``i``'s sampler
is seeded from ``(seed, i)``, ``i`` counting the trials that finished, so an interrupted study
continued with ``--resume`` proposes exactly what the uninterrupted one would have, and ends with
the same trials (a trial interrupted half-way is marked failed and not counted).
"""

from __future__ import annotations

import copy
import json
import math
import sys
import time
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from gnc_common.validation import ConfigError, from_mapping
from sappc.analysis.plots import house_style
from sappc.montecarlo.campaign import ChunkExecutor, simulate_runs
from sappc.montecarlo.config import campaign_config
from sappc.montecarlo.results import chunks
from sappc.scenario import ControllerKind, Scenario, load_scenario, scenario_from_mapping

__all__ = ["CONFIRMATION_FIRST_RUN", "OBJECTIVE_METRICS", "ParameterRange", "Requirements", "Objective", "TuningConfig",
           "evaluate_runs", "run_tuning", "tuning_config"]

Array = NDArray[np.float64]

#: The first run index of confirmation campaigns: far beyond any trial's runs, so the confirmation
#: draws are new ones (a run's inputs depend only on ``(seed, run index)``).
CONFIRMATION_FIRST_RUN = 1_000_000_000
#: Metrics a study may minimise (a percentile over the campaign), with the value a run that has
#: none (diverged, or never settled) counts as: the worst a quaternion error can be, or the run's length.
OBJECTIVE_METRICS = ("steady_max_abs_qev", "steady_mean_abs_qev", "rpf_error_at_t2", "settling_time_s")
#: Name of the study in the journal.
STUDY_NAME = "sappc-tune"
#: Trials drawn at random (uniform or log-uniform in the ranges) before TPE models the results:
#: Optuna's default.  A constant, not a fraction of ``--trials``: a study continued with more
#: trials must propose what it would have proposed in one go.
STARTUP_TRIALS = 10
#: Runs per chunk of a trial's campaign (a task on a worker); results do not depend on it.
CHUNK_RUNS = 64


@dataclass(frozen=True)
class ParameterRange:
    """The range a gain is searched in; ``log``: log-uniform (a gain spanning decades)."""

    low: float
    high: float
    log: bool = False

    def __post_init__(self) -> None:
        for name in ("low", "high"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ConfigError(f"{name} must be a finite number, got {v!r}")
        if not self.low < self.high:
            raise ConfigError(f"is an empty range: low ({self.low!r}) must be below high ({self.high!r})")
        if self.log and not self.low > 0.0:
            raise ConfigError(f"log: true needs low > 0, got {self.low!r}")


@dataclass(frozen=True)
class Requirements:
    """What every run of a trial's campaign must meet (``None``: not required).

    Attributes
    ----------
    settle_by_t2 : bool
        Settled by ``metrics.t2_s``: ``max_i |q_ev,i| < metrics.settle_threshold`` from then on
        (the metrics' ``settling_time_s <= t2_s``).
    overshoot_max : float or None
        Largest excursion of an error component past zero (the metrics' ``overshoot``).
    steady_max_abs_qev_max : float or None
        Largest ``|q_ev,i|`` over the steady window (``metrics.steady_from_s`` on).
    torque_sign_changes_per_s_max : float or None [1/s]
        Chattering: the metrics' ``torque_sign_changes_per_s`` over the steady window.
    max_abs_wheel_speed_rad_s_max : float or None [rad/s]
        The metrics' ``max_abs_wheel_speed_rad_s`` (the fastest reaction wheel's speed relative to
        the body over the run); only for a scenario with reaction wheels.
    """

    settle_by_t2: bool = True
    overshoot_max: float | None = None
    steady_max_abs_qev_max: float | None = None
    torque_sign_changes_per_s_max: float | None = None
    max_abs_wheel_speed_rad_s_max: float | None = None


#: Each bounded requirement of :class:`Requirements` and the metric it bounds (a campaign's per-run column).
BOUNDED_REQUIREMENTS = {"overshoot_max": "overshoot", "steady_max_abs_qev_max": "steady_max_abs_qev",
                        "torque_sign_changes_per_s_max": "torque_sign_changes_per_s",
                        "max_abs_wheel_speed_rad_s_max": "max_abs_wheel_speed_rad_s"}


@dataclass(frozen=True)
class Objective:
    """The value a study minimises: the ``percentile``-th percentile of ``metric`` over the campaign."""

    metric: str = "steady_max_abs_qev"
    percentile: float = 99.0


@dataclass(frozen=True)
class TuningConfig:
    """The scenario's ``tuning`` section (module docstring); ``parameters`` by path under
    ``controllers.<controller>``."""

    parameters: dict[str, ParameterRange] = field(default_factory=dict)
    baselines: dict[str, dict[str, float]] = field(default_factory=dict)
    requirements: Requirements = Requirements()
    objective: Objective = Objective()
    trials: int = 60
    runs_per_trial: int = 32
    confirmation_runs: int = 256
    seed: int = 0


def _positive_int(key: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ConfigError(f"{key} must be a positive integer, got {value!r}")
    return value


def tuning_config(scenario: Scenario, controller: str | None = None) -> tuple[TuningConfig, str]:
    """Parse and check the scenario's ``tuning`` section for ``controller`` (default: the
    scenario's); return it and the controller's name.

    Raises
    ------
    ConfigError
        Naming the key: no section, an unknown key, a parameter that is not a number of the
        controller's parameters, an empty range, an unknown objective, an infeasible requirement
        (a bound no run can meet, or one the run cannot measure: ``t2_s`` or the steady window
        beyond ``duration_s``), or no ``montecarlo`` section to draw the campaign from.
    """
    from sappc_controller.params import parameters_from_config

    kind = ControllerKind(controller).value if controller is not None else scenario.controller.value
    section = scenario.raw.get("tuning")
    if section is None:
        raise ConfigError(f"scenario {scenario.name!r} has no 'tuning' section")
    if not isinstance(section, dict):
        raise ConfigError(f"tuning must be a mapping, got {section!r}")
    data = dict(section)
    params_section = data.pop("parameters", None)
    baselines_section = data.pop("baselines", None) or {}
    cfg: TuningConfig = from_mapping(TuningConfig, data, "tuning")
    if not isinstance(params_section, dict) or not params_section:
        raise ConfigError("tuning.parameters must be a non-empty mapping of parameter path to {low, high, log}")
    if kind not in scenario.controllers:
        raise ConfigError(f"tuning: the scenario has no controllers.{kind} to tune")
    flat = parameters_from_config(kind, scenario.controller_config(kind))
    ranges: dict[str, ParameterRange] = {}
    for path, spec in params_section.items():
        key = f"tuning.parameters.{path}"
        value = flat.get(f"{kind}.{path}")
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            numeric = sorted(k.removeprefix(f"{kind}.") for k, v in flat.items()
                             if k.startswith(f"{kind}.") and isinstance(v, (int, float)) and not isinstance(v, bool))
            raise ConfigError(f"unknown key {key}: not a number of controllers.{kind} (tunable: {', '.join(numeric)})")
        try:
            ranges[str(path)] = from_mapping(ParameterRange, spec, key)
        except ConfigError as exc:
            raise ConfigError(f"{key} {exc}" if not str(exc).startswith(("unknown key", "missing key", key)) else str(exc)) from None
    if not isinstance(baselines_section, dict):
        raise ConfigError(f"tuning.baselines must be a mapping of name to gain values, got {baselines_section!r}")
    baselines: dict[str, dict[str, float]] = {}
    for name, gains in baselines_section.items():
        key = f"tuning.baselines.{name}"
        if str(name) in ("start", "tuned"):
            raise ConfigError(f"{key}: 'start' and 'tuned' name the study's own gain sets; choose another name")
        if not isinstance(gains, dict) or not gains:
            raise ConfigError(f"{key} must be a non-empty mapping of tuned parameter path to value, got {gains!r}")
        for path, value in gains.items():
            if path not in ranges:
                raise ConfigError(f"unknown key {key}.{path}: not one of tuning.parameters ({', '.join(ranges)})")
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ConfigError(f"{key}.{path} must be a finite number, got {value!r}")
        baselines[str(name)] = {str(k): float(v) for k, v in gains.items()}
    for key in ("trials", "runs_per_trial", "confirmation_runs"):
        _positive_int(f"tuning.{key}", getattr(cfg, key))
    if isinstance(cfg.seed, bool) or not isinstance(cfg.seed, int) or cfg.seed < 0:
        raise ConfigError(f"tuning.seed must be a non-negative integer, got {cfg.seed!r}")
    obj = cfg.objective
    if obj.metric not in OBJECTIVE_METRICS:
        raise ConfigError(f"tuning.objective.metric must be one of {', '.join(OBJECTIVE_METRICS)}, got {obj.metric!r}")
    if isinstance(obj.percentile, bool) or not isinstance(obj.percentile, (int, float)) or not 0.0 < obj.percentile <= 100.0:
        raise ConfigError(f"tuning.objective.percentile must be in (0, 100], got {obj.percentile!r}")
    _check_requirements(cfg.requirements, scenario)
    ms = scenario.metrics
    if obj.metric.startswith("steady") and ms.steady_from_s >= scenario.duration_s:
        raise ConfigError(f"tuning.objective.metric: {obj.metric} needs a steady window, but metrics.steady_from_s "
                          f"({ms.steady_from_s}) is not before duration_s ({scenario.duration_s})")
    if obj.metric == "rpf_error_at_t2" and ms.t2_s > scenario.duration_s:
        raise ConfigError(f"tuning.objective.metric: rpf_error_at_t2 needs metrics.t2_s ({ms.t2_s}) within duration_s ({scenario.duration_s})")
    if scenario.raw.get("montecarlo") is None:
        raise ConfigError(f"scenario {scenario.name!r}: tuning needs a 'montecarlo' section (the dispersed campaign each trial runs)")
    campaign_config(scenario)  # its errors now, before any trial
    return TuningConfig(**{**asdict(cfg), "parameters": ranges, "baselines": baselines, "requirements": cfg.requirements, "objective": obj}), kind


def _check_requirements(req: Requirements, scenario: Scenario) -> None:
    ms = scenario.metrics
    if not isinstance(req.settle_by_t2, bool):
        raise ConfigError(f"tuning.requirements.settle_by_t2 must be true or false, got {req.settle_by_t2!r}")
    if req.settle_by_t2 and ms.t2_s > scenario.duration_s:
        raise ConfigError(f"tuning.requirements.settle_by_t2 is infeasible: metrics.t2_s ({ms.t2_s}) is after the run's end "
                          f"(duration_s {scenario.duration_s})")
    bounds = {"overshoot_max": (req.overshoot_max, 0.0, "an overshoot is never negative"),
              "steady_max_abs_qev_max": (req.steady_max_abs_qev_max, None, "no error is below 0"),
              "torque_sign_changes_per_s_max": (req.torque_sign_changes_per_s_max, 0.0, "a rate of sign changes is never negative"),
              "max_abs_wheel_speed_rad_s_max": (req.max_abs_wheel_speed_rad_s_max, 0.0, "a wheel speed's magnitude is never negative")}
    for name, (value, lowest, why) in bounds.items():
        if value is None:
            continue
        key = f"tuning.requirements.{name}"
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ConfigError(f"{key} must be a finite number, got {value!r}")
        if (value < lowest) if lowest is not None else (value <= 0.0):
            raise ConfigError(f"{key} = {value!r} is infeasible: {why}")
    if req.max_abs_wheel_speed_rad_s_max is not None and scenario.wheels is None:
        raise ConfigError("tuning.requirements.max_abs_wheel_speed_rad_s_max needs reaction wheels (actuator.kind: reaction_wheels): "
                          "the scenario's ideal actuator has no wheel speed to bound")
    if (req.steady_max_abs_qev_max is not None or req.torque_sign_changes_per_s_max is not None) and ms.steady_from_s >= scenario.duration_s:
        raise ConfigError(f"tuning.requirements: the steady requirements are infeasible: metrics.steady_from_s ({ms.steady_from_s}) "
                          f"is not before duration_s ({scenario.duration_s})")


def candidate_mapping(raw: dict[str, Any], kind: str, values: dict[str, float]) -> dict[str, Any]:
    """The scenario mapping with ``values`` (by path under ``controllers.<kind>``) and ``controller: kind``."""
    out = copy.deepcopy(raw)
    out["controller"] = kind
    for path, value in values.items():
        node = out["controllers"][kind]
        *parents, leaf = path.split(".")
        for p in parents:
            node = node.setdefault(p, {})
        node[leaf] = float(value)
    return out


def evaluate_runs(scenario_raw: dict[str, Any], seed: int, runs: list[int]) -> dict[str, NDArray[Any]]:
    """The requirement and objective metrics of ``runs`` of the campaign (a worker task)."""
    table, metrics, _ = simulate_runs(scenario_raw, seed, runs, 0)
    crit = metrics.criteria_arrays()
    wheels = {"max_abs_wheel_speed_rad_s": np.asarray(crit["max_abs_wheel_speed_rad_s"], dtype=np.float64)} \
        if "max_abs_wheel_speed_rad_s" in crit else {}
    return {
        **wheels,
        "run": np.asarray(table["run"]),
        "finite": np.asarray(crit["finite"], dtype=bool),
        "settling_time_s": np.asarray(crit["settling_time_s"], dtype=np.float64),
        "overshoot": np.maximum(np.asarray(metrics.overshoot, dtype=np.float64), 0.0),
        "steady_max_abs_qev": np.asarray(crit["steady_max_abs_qev"], dtype=np.float64),
        "steady_mean_abs_qev": np.asarray(crit["steady_mean_abs_qev"], dtype=np.float64),
        "rpf_error_at_t2": np.asarray(crit["rpf_error_at_t2"], dtype=np.float64),
        "torque_sign_changes_per_s": np.asarray(crit["torque_sign_changes_per_s"], dtype=np.float64),
    }


def _evaluate(executor: ChunkExecutor, raw: dict[str, Any], seed: int, runs: list[int]) -> dict[str, NDArray[Any]]:
    """:func:`evaluate_runs` over ``runs`` in chunks on ``executor``, in run order."""
    parts: dict[int, dict[str, NDArray[Any]]] = {}
    offset = runs[0]
    tasks = [(i, evaluate_runs, (raw, seed, [offset + k for k in r])) for i, r in chunks(len(runs), CHUNK_RUNS)]
    for item in executor.run(tasks):
        if item is not None:
            parts[item[0]] = item[1]
    return {k: np.concatenate([parts[i][k] for i in sorted(parts)]) for k in parts[0]}


@dataclass
class Score:
    """A campaign against the requirements: the objective, one constraint value per requirement
    (<= 0: every run meets it; else the worst run's relative violation), why runs failed, and each
    requirement's worst run (its value and the bound: how close the campaign came)."""

    value: float
    constraints: dict[str, float]
    failures: dict[str, dict[str, Any]]  # requirement -> {"runs": how many failed, "first": (run, value), "bound"}
    failed_runs: NDArray[np.bool_]  # (runs,) a run that broke any requirement
    worst: dict[str, dict[str, float | None]] = field(default_factory=dict)  # requirement -> {"value": worst run's (None: none), "bound"}

    @property
    def feasible(self) -> bool:
        return all(c <= 0.0 for c in self.constraints.values())


def score(table: dict[str, NDArray[Any]], cfg: TuningConfig, scenario: Scenario) -> Score:
    """The objective and the requirement margins of a campaign's per-run ``table``."""
    ms, req = scenario.metrics, cfg.requirements
    finite = table["finite"]
    checks: dict[str, tuple[Array, float]] = {}  # requirement -> (per-run values, bound)
    if req.settle_by_t2:
        checks["settle_by_t2"] = (np.where(np.isfinite(table["settling_time_s"]), table["settling_time_s"], np.inf), ms.t2_s)
    for name, metric in BOUNDED_REQUIREMENTS.items():
        bound = getattr(req, name)
        if bound is not None:
            checks[name] = (np.where(np.isfinite(table[metric]), table[metric], np.inf), float(bound))
    constraints = {"finite": float(np.count_nonzero(~finite))}
    worst_runs: dict[str, dict[str, float | None]] = {"finite": {"value": float(np.count_nonzero(~finite)), "bound": 0.0}}
    failures: dict[str, dict[str, Any]] = {}
    any_failed = ~finite
    if (~finite).any():
        failures["finite"] = {"runs": int(np.count_nonzero(~finite)), "first": [int(table["run"][np.argmax(~finite)]), None]}
    for name, (values, bound) in checks.items():
        excess = values - bound
        # relative to the bound where it has a scale; a graded margin guides the sampler
        margin = excess / bound if bound > 0 else excess
        worst = float(np.max(np.where(finite, margin, np.inf)))
        constraints[name] = min(worst, 1e6) if math.isfinite(worst) else 1e6
        failed = (values > bound) | ~finite
        w = float(np.max(np.where(finite, values, np.inf)))
        worst_runs[name] = {"value": w if math.isfinite(w) else None, "bound": bound}  # None: a run never settled, or diverged
        any_failed = any_failed | failed
        if failed.any():
            k = int(np.argmax(failed))
            failures[name] = {"runs": int(np.count_nonzero(failed)), "first": [int(table["run"][k]), float(values[k])], "bound": bound}
    metric = cfg.objective.metric
    worst_value = scenario.duration_s if metric == "settling_time_s" else 2.0  # |q_ev - rho| <= 2
    values = np.where(np.isfinite(table[metric]) & finite, table[metric], worst_value)
    return Score(float(np.percentile(values, cfg.objective.percentile)), constraints, failures, any_failed, worst_runs)


def _trial_seed(seed: int, i: int) -> int:
    return int(np.random.SeedSequence((seed, i)).generate_state(1)[0])


def _counted(study: Any) -> list[Any]:
    """The trials that finished (complete, or failed on an invalid candidate; not interrupted)."""
    from optuna.trial import TrialState

    return [t for t in study.get_trials(deepcopy=False)
            if t.state == TrialState.COMPLETE or (t.state == TrialState.FAIL and not t.user_attrs.get("interrupted"))]


def _feasible(trial: Any) -> bool:
    """A complete trial whose campaign met every requirement (its constraints all <= 0)."""
    from optuna.trial import TrialState

    return bool(trial.state == TrialState.COMPLETE and trial.constraints and all(c <= 0.0 for c in trial.constraints.values()))


def _best(study: Any) -> Any | None:
    from optuna.trial import TrialState

    feasible = [t for t in study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
                if _feasible(t)]
    return min(feasible, key=lambda t: (t.value, t.number)) if feasible else None


class _Progress:
    """One line on stderr: trials done, trials/s, the best feasible value so far."""

    def __init__(self, total: int, done: int, enabled: bool) -> None:
        self.total, self.start, self.t0, self.enabled = total, done, time.perf_counter(), enabled
        self.tty = sys.stderr.isatty()

    def update(self, done: int, best: Any, feasible: int) -> None:
        if not self.enabled:
            return
        rate = (done - self.start) / max(time.perf_counter() - self.t0, 1e-9)
        best_txt = f"best {best.value:.4g} (trial {best.number})" if best is not None else "no feasible trial yet"
        line = f"trials {done}/{self.total}  {rate:.2f} trials/s  {best_txt}  feasible {feasible}"
        print(("\r" if self.tty else "") + line, end="\n" if (not self.tty or done == self.total) else "", file=sys.stderr, flush=True)


def _study(storage: Any, sampler: Any = None) -> Any:
    import optuna

    return optuna.load_study(study_name=STUDY_NAME, storage=storage, sampler=sampler)


def run_tuning(
    scenario_path: str | Path,
    *,
    out_dir: str | Path,
    controller: str | None = None,
    trials: int | None = None,
    runs_per_trial: int | None = None,
    seed: int | None = None,
    workers: int = 1,
    scheduler: str | None = None,
    resume: bool = False,
    progress: bool = True,
    confirm: bool = True,
) -> dict[str, Any]:
    """Run (or resume) a study and write its results in ``out_dir``; return the summary.

    Raises
    ------
    ConfigError
        Bad ``tuning`` or ``montecarlo`` section (naming the key), bad arguments, or an output
        directory that holds another study.
    """
    import optuna
    from optuna.samplers import TPESampler
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend
    from optuna.trial import TrialState

    scenario = load_scenario(scenario_path)
    cfg, kind = tuning_config(scenario, controller)
    overrides = {"trials": trials, "runs_per_trial": runs_per_trial, "seed": seed}
    for key in ("trials", "runs_per_trial"):
        if overrides[key] is not None:
            _positive_int(f"--{key.replace('_', '-')}", overrides[key])
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int) or seed < 0):
        raise ConfigError(f"--seed must be a non-negative integer, got {seed!r}")
    cfg = TuningConfig(**{**cfg.__dict__, **{k: v for k, v in overrides.items() if v is not None}})
    if workers < 1:
        raise ConfigError(f"--workers must be >= 1, got {workers!r}")
    out = Path(out_dir)
    manifest = {"scenario": scenario.raw, "controller": kind, "seed": cfg.seed, "runs_per_trial": cfg.runs_per_trial}
    manifest_path = out / "tune.json"
    if manifest_path.exists():
        if not resume:
            raise ConfigError(f"{out} already holds a study; pass --resume to continue it or choose another --out")
        if json.loads(manifest_path.read_text()) != json.loads(json.dumps(manifest)):
            raise ConfigError(f"{out} holds a study of another scenario, controller, seed or run count; cannot resume it")
    elif resume:
        raise ConfigError(f"--resume: {out} holds no study (no tune.json)")
    out.mkdir(parents=True, exist_ok=True)
    manifest_path.write_text(json.dumps(manifest, indent=1) + "\n")

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    warnings.filterwarnings("ignore", category=optuna.exceptions.ExperimentalWarning)
    storage = JournalStorage(JournalFileBackend(str(out / "study.journal")))
    optuna.create_study(study_name=STUDY_NAME, storage=storage, direction="minimize", load_if_exists=True)
    study = _study(storage)
    for t in study.get_trials(deepcopy=False, states=(TrialState.RUNNING,)):  # interrupted before: failed, not counted
        storage.set_trial_user_attr(t._trial_id, "interrupted", True)
        storage.set_trial_state_values(t._trial_id, TrialState.FAIL)

    from sappc.offline import compiled_loop

    if scheduler is None:
        compiled_loop.ensure_compiled(in_subprocess=workers > 1, groups=compiled_loop.CAMPAIGN_GROUPS)
    executor = ChunkExecutor(workers, scheduler)
    tuning_runs = list(range(cfg.runs_per_trial))
    done = len(_counted(study))
    bar = _Progress(cfg.trials, done, progress)
    t0 = time.perf_counter()
    try:
        while done < cfg.trials:
            sampler = TPESampler(seed=_trial_seed(cfg.seed, done), multivariate=True, n_startup_trials=STARTUP_TRIALS)
            study = _study(storage, sampler)
            trial = study.ask()
            values = {path: trial.suggest_float(path, r.low, r.high, log=r.log) for path, r in cfg.parameters.items()}
            try:
                candidate = candidate_mapping(scenario.raw, kind, values)
                scenario_from_mapping(candidate, source=f"trial {trial.number}")
            except ConfigError as exc:  # e.g. gains the law's validation refuses
                trial.set_user_attr("invalid", str(exc))
                study.tell(trial, state=TrialState.FAIL)
            else:
                try:
                    s = score(_evaluate(executor, candidate, cfg.seed, tuning_runs), cfg, scenario)
                except KeyboardInterrupt:
                    trial.set_user_attr("interrupted", True)
                    study.tell(trial, state=TrialState.FAIL)
                    raise
                for name, value in s.constraints.items():  # TPE reads them (Trial.set_constraint, Optuna 5)
                    trial.set_constraint(name, value)
                trial.set_user_attr("failures", s.failures)
                trial.set_user_attr("worst", s.worst)
                study.tell(trial, s.value)
            done += 1
            bar.update(done, _best(study), sum(1 for t in _counted(study) if t.state == TrialState.COMPLETE
                                             and _feasible(t)))
    except KeyboardInterrupt:
        executor.abort()
        print(f"\ninterrupted: {done} trial(s) kept in {out}; continue with --resume", file=sys.stderr)
        raise
    finally:
        executor.close()
    wall_s = time.perf_counter() - t0
    return _finish(out, scenario, cfg, kind, _study(storage), workers, scheduler, wall_s, confirm)


def _finish(out: Path, scenario: Scenario, cfg: TuningConfig, kind: str, study: Any, workers: int, scheduler: str | None,
            wall_s: float, confirm: bool) -> dict[str, Any]:
    """The best gains as files, the confirmation campaign, figures and the summary."""
    import yaml

    from sappc.scenario import controller_params_yaml
    from sappc.offline.simulate import run_scenario

    trials = _counted(study)
    best = _best(study)
    summary: dict[str, Any] = {
        "scenario": scenario.name, "controller": kind, "seed": cfg.seed, "trials": len(trials), "runs_per_trial": cfg.runs_per_trial,
        "objective": asdict(cfg.objective), "requirements": asdict(cfg.requirements),
        "parameters": {p: asdict(r) for p, r in cfg.parameters.items()}, "wall_time_s": wall_s,
        "feasible_trials": sum(1 for t in trials if _feasible(t)),
        "invalid_trials": sum(1 for t in trials if "invalid" in t.user_attrs),
        "blocking": blocking(trials),
        "best": None,
    }
    _figures(out, study, cfg)
    if best is None:
        (out / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
        return summary
    values = {p: float(best.params[p]) for p in cfg.parameters}
    tuned = candidate_mapping(scenario.raw, kind, values)
    text = yaml.safe_dump(tuned, sort_keys=False)
    (out / "best_scenario.yaml").write_text(f"# {scenario.name} with the gains found by sappc tune (trial {best.number}); "
                                            f"loads through the same validation as every scenario\n" + text)
    best_scenario = load_scenario(out / "best_scenario.yaml")
    (out / "controller_params.yaml").write_text(controller_params_yaml(best_scenario, kind))
    start = {p: float(_lookup(scenario.raw["controllers"][kind], p)) for p in cfg.parameters}
    gain_sets = {"start": start, **{name: {**start, **g} for name, g in cfg.baselines.items()}, "tuned": values}
    mappings = {name: candidate_mapping(scenario.raw, kind, g) for name, g in gain_sets.items()}
    nominal = {name: run_scenario(scenario_from_mapping(raw))[0].run_metrics(0) for name, raw in mappings.items()}  # the scenario's own case
    summary["best"] = {"trial": best.number, "value": best.value, "parameters": values, "gain_sets": gain_sets,
                       "scenario_file": str(out / "best_scenario.yaml"), "controller_params_file": str(out / "controller_params.yaml"),
                       "nominal_run": {k: {m: v[m] for m in ("steady_max_abs_qev", "settling_time_s", "overshoot", "torque_sign_changes_per_s")}
                                       for k, v in nominal.items()}}
    if confirm:
        runs = list(range(CONFIRMATION_FIRST_RUN, CONFIRMATION_FIRST_RUN + cfg.confirmation_runs))
        executor = ChunkExecutor(workers, scheduler)
        try:
            confirmation = {}
            for name, raw in mappings.items():
                s = score(_evaluate(executor, raw, cfg.seed, runs), cfg, scenario)
                failed = int(np.count_nonzero(s.failed_runs))
                confirmation[name] = {"objective": s.value, "feasible": s.feasible, "pass_fraction": 1.0 - failed / len(runs),
                                      "runs_failing": {k: v["runs"] for k, v in s.failures.items()}, "constraints": s.constraints}
        finally:
            executor.close()
        summary["confirmation"] = {"runs": len(runs), "first_run": runs[0], **confirmation}
    (out / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
    return summary


def blocking(trials: list[Any]) -> dict[str, dict[str, Any]]:
    """Per requirement, over the complete trials: how many it blocked (its constraint > 0: a run
    of the trial's campaign broke it), the closest any trial came (the smallest worst-run value,
    and the first trial that came that close) and the bound: what stops a study that finds no feasible trial."""
    from optuna.trial import TrialState

    out: dict[str, dict[str, Any]] = {}
    complete = [t for t in trials if t.state == TrialState.COMPLETE and t.constraints]
    for t in complete:
        for name, c in t.constraints.items():
            entry = out.setdefault(name, {"trials_blocked": 0, "trials": 0, "best_value": None, "best_trial": None, "bound": None})
            entry["trials"] += 1
            entry["trials_blocked"] += int(c > 0.0)
            w = t.user_attrs.get("worst", {}).get(name)
            if w is None:
                continue
            entry["bound"] = w["bound"]
            if w["value"] is not None and (entry["best_value"] is None or w["value"] < entry["best_value"]):
                entry["best_value"], entry["best_trial"] = w["value"], t.number
    return out


def _lookup(node: Any, path: str) -> Any:
    for p in path.split("."):
        node = node[p]
    return node


@house_style
def _figures(out: Path, study: Any, cfg: TuningConfig) -> None:
    """``history.png`` (each trial's objective, feasible or not, and the best feasible so far) and
    ``tradeoff.png`` (the objective against each tuned parameter)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from optuna.trial import TrialState

    trials = [t for t in study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))]
    if not trials:
        return
    n = np.array([t.number for t in trials])
    v = np.array([t.value for t in trials])
    ok = np.array([_feasible(t) for t in trials])
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.semilogy(n[~ok], v[~ok], "x", color="tab:red", label="infeasible (a run breaks a requirement)")
    ax.semilogy(n[ok], v[ok], "o", color="tab:blue", label="feasible")
    if ok.any():
        best = np.minimum.accumulate(np.where(ok, v, np.inf))
        ax.step(n[np.isfinite(best)], best[np.isfinite(best)], where="post", color="k", label="best feasible so far")
    ax.set_xlabel("trial")
    ax.set_ylabel(f"p{cfg.objective.percentile:g} {cfg.objective.metric}")
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(out / "history.png", dpi=110)
    plt.close(fig)
    k = len(cfg.parameters)
    fig, axes = plt.subplots(1, k, figsize=(3.2 * k, 3.4), squeeze=False)
    for ax, (path, r) in zip(axes[0], cfg.parameters.items()):
        x = np.array([t.params.get(path, np.nan) for t in trials])
        ax.plot(x[~ok], v[~ok], "x", color="tab:red")
        ax.plot(x[ok], v[ok], "o", color="tab:blue")
        ax.set_yscale("log")
        if r.log:
            ax.set_xscale("log")
        ax.set_xlabel(path)
        ax.grid(True, which="both", alpha=0.3)
    axes[0][0].set_ylabel(cfg.objective.metric)
    fig.tight_layout()
    fig.savefig(out / "tradeoff.png", dpi=110)
    plt.close(fig)

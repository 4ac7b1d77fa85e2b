"""``sappc tune`` (sappc.montecarlo.tuning): the tuning section's errors name the key; a study
interrupted and resumed ends with the same trials as one run straight through; the score of a
campaign against the requirements; the command's files load through the project's validation."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from gnc_common.validation import ConfigError
from sappc.montecarlo import tuning
from sappc.montecarlo.tuning import CONFIRMATION_FIRST_RUN, run_tuning, score, tuning_config
from sappc.scenario import load_scenario, scenario_from_mapping

from conftest import ROOT, SAPPC, SCENARIOS
from figure_checks import NO_EMPTY_LOG_AXES

pytestmark = NO_EMPTY_LOG_AXES  # studies draw their figures in-process
#: ``PYTHONWARNINGS`` of a command that draws figures: an empty log axis fails it.
EMPTY_LOG_AXES_ERROR = "error:Data has no positive values"

TUNE = SCENARIOS / "paper_tracking_tune.yaml"


def _small(tmp_path: Path, **tuning_changes: Any) -> Path:
    """The tuning scenario, short (12 s, steady from 8 s, t2 at 10 s), with few trials and runs."""
    raw = yaml.safe_load(TUNE.read_text())
    raw["duration_s"] = 12.0
    raw["metrics"].update(steady_from_s=8.0, t2_s=10.0)
    raw["tuning"].update({"trials": 6, "runs_per_trial": 3, "confirmation_runs": 4, **tuning_changes})
    path = tmp_path / "small.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


def _trials(out: Path) -> list[tuple[Any, ...]]:
    """What a study decided: each counted trial's proposal, value and constraints, in order."""
    import optuna

    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend

    storage = JournalStorage(JournalFileBackend(str(out / "study.journal")))
    study = optuna.load_study(study_name=tuning.STUDY_NAME, storage=storage)
    return [(t.state.name, t.params, t.value, t.constraints) for t in tuning._counted(study)]


def test_an_interrupted_study_resumed_ends_with_the_trials_of_an_uninterrupted_one(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """14 trials: the first 10 random (tuning.STARTUP_TRIALS), then TPE on what came before; the
    interruption falls in TPE's part, so the resumed sampler must see the same history."""
    path = _small(tmp_path, trials=14)
    straight = run_tuning(path, out_dir=tmp_path / "straight", progress=False, confirm=False)
    expected = _trials(tmp_path / "straight")
    assert len(expected) == 14 and straight["trials"] == 14 and tuning.STARTUP_TRIALS == 10
    assert len({json.dumps(p, sort_keys=True) for _, p, _, _ in expected}) == 14  # all different proposals

    # stopped after 2 trials, continued to 11, then Ctrl-C inside the 12th trial's campaign, then resumed
    run_tuning(path, out_dir=tmp_path / "resumed", trials=2, progress=False, confirm=False)
    run_tuning(path, out_dir=tmp_path / "resumed", trials=11, resume=True, progress=False, confirm=False)
    real = tuning._evaluate

    def interrupted(*args: Any, **kwargs: Any) -> Any:
        raise KeyboardInterrupt

    monkeypatch.setattr(tuning, "_evaluate", interrupted)
    with pytest.raises(KeyboardInterrupt):
        run_tuning(path, out_dir=tmp_path / "resumed", resume=True, progress=False, confirm=False)
    monkeypatch.setattr(tuning, "_evaluate", real)
    assert len(_trials(tmp_path / "resumed")) == 11  # the interrupted trial is not counted
    resumed = run_tuning(path, out_dir=tmp_path / "resumed", resume=True, progress=False, confirm=False)
    assert _trials(tmp_path / "resumed") == expected
    assert resumed["best"]["parameters"] == straight["best"]["parameters"] if straight["best"] else resumed["best"] is None


def test_the_output_directory_refuses_another_study_and_a_resume_of_nothing(tmp_path: Path) -> None:
    path = _small(tmp_path, trials=1)
    run_tuning(path, out_dir=tmp_path / "s", progress=False, confirm=False)
    with pytest.raises(ConfigError, match="already holds a study"):
        run_tuning(path, out_dir=tmp_path / "s", progress=False, confirm=False)
    with pytest.raises(ConfigError, match="another scenario, controller, seed or run count"):
        run_tuning(path, out_dir=tmp_path / "s", seed=7, resume=True, progress=False, confirm=False)
    with pytest.raises(ConfigError, match="holds no study"):
        run_tuning(path, out_dir=tmp_path / "t", resume=True, progress=False, confirm=False)


@pytest.mark.parametrize(("change", "key"), [
    ({"surprise": 1}, "tuning.surprise"),
    ({"parameters": {"gains.K_q": {"low": 0.3, "high": 0.3}}}, "tuning.parameters.gains.K_q"),
    ({"parameters": {"gains.K_q": {"low": 0.0, "high": 1.0, "log": True}}}, "tuning.parameters.gains.K_q"),
    ({"parameters": {"gains.K_q": {"low": 0.1, "high": 1.0, "step": 2}}}, "tuning.parameters.gains.K_q.step"),
    ({"parameters": {"gains.K_qq": {"low": 0.1, "high": 1.0}}}, "tuning.parameters.gains.K_qq"),
    ({"parameters": {"rpf": {"low": 0.1, "high": 1.0}}}, "tuning.parameters.rpf"),
    ({"requirements": {"steady_max_abs_qev_max": 0.0}}, "tuning.requirements.steady_max_abs_qev_max"),
    ({"requirements": {"torque_sign_changes_per_s_max": -1.0}}, "tuning.requirements.torque_sign_changes_per_s_max"),
    ({"requirements": {"wheel_speed_max": 1.0}}, "tuning.requirements.wheel_speed_max"),
    ({"objective": {"metric": "happiness"}}, "tuning.objective.metric"),
    ({"objective": {"percentile": 0}}, "tuning.objective.percentile"),
    ({"runs_per_trial": 0}, "tuning.runs_per_trial"),
    ({"baselines": {"mine": {"gains.K_z": 1.0}}}, "tuning.baselines.mine.gains.K_z"),
])
def test_a_bad_tuning_section_stops_with_an_error_naming_the_key(change: dict[str, Any], key: str) -> None:
    raw = yaml.safe_load(TUNE.read_text())
    raw["tuning"].update(change)
    with pytest.raises(ConfigError) as err:
        tuning_config(scenario_from_mapping(raw))
    assert key in str(err.value), str(err.value)


def test_requirements_the_run_cannot_measure_are_infeasible() -> None:
    raw = yaml.safe_load(TUNE.read_text())
    raw["metrics"]["t2_s"] = 70.0  # after the run's end (60 s)
    with pytest.raises(ConfigError, match="tuning.requirements.settle_by_t2 is infeasible"):
        tuning_config(scenario_from_mapping(raw))
    raw = yaml.safe_load(TUNE.read_text())
    del raw["montecarlo"]
    with pytest.raises(ConfigError, match="tuning needs a 'montecarlo' section"):
        tuning_config(scenario_from_mapping(raw))


def test_score_is_the_percentile_of_the_objective_and_each_requirements_worst_relative_margin() -> None:
    raw = yaml.safe_load(TUNE.read_text())
    scenario = scenario_from_mapping(raw)
    cfg, _ = tuning_config(scenario)
    table = {
        "run": np.array([0, 1, 2, 3]),
        "finite": np.array([True, True, True, True]),
        "settling_time_s": np.array([12.0, 19.0, np.nan, 15.0]),  # run 2 never settles
        "overshoot": np.array([0.0, 2e-4, 0.0, 0.0]),  # run 1 overshoots twice the bound
        "steady_max_abs_qev": np.array([3e-5, 4e-5, 1e-3, 2e-5]),
        "steady_mean_abs_qev": np.zeros(4),
        "rpf_error_at_t2": np.zeros(4),
        "torque_sign_changes_per_s": np.array([0.0, 0.0, 0.0, 0.5]),
    }
    s = score(table, cfg, scenario)
    assert s.value == float(np.percentile([3e-5, 4e-5, 1e-3, 2e-5], 99))
    assert s.constraints["finite"] == 0.0
    assert s.constraints["settle_by_t2"] == 1e6  # a run that never settles: the cap
    assert s.constraints["overshoot_max"] == pytest.approx(1.0)  # (2e-4 - 1e-4) / 1e-4
    assert s.constraints["steady_max_abs_qev_max"] == pytest.approx(19.0)  # (1e-3 - 5e-5) / 5e-5
    assert s.constraints["torque_sign_changes_per_s_max"] == pytest.approx(-0.5)  # met with a margin
    assert s.failures["settle_by_t2"]["first"][0] == 2 and s.failures["overshoot_max"]["runs"] == 1
    assert "torque_sign_changes_per_s_max" not in s.failures and not s.feasible
    assert s.failed_runs.tolist() == [False, True, True, False]


def test_the_command_writes_gains_that_load_through_the_project_validation(tmp_path: Path) -> None:
    from sappc_controller.params import controller_from_parameters_file

    path = _small(tmp_path, requirements={"settle_by_t2": False})  # every proposal feasible: a best exists
    out = tmp_path / "study"
    proc = subprocess.run([*SAPPC, "tune", str(path), "--out", str(out), "--json", str(tmp_path / "t.json"), "--no-progress"],
                          capture_output=True, text=True, cwd=ROOT, timeout=600, env={**os.environ, "PYTHONWARNINGS": EMPTY_LOG_AXES_ERROR})
    assert proc.returncode == 0, proc.stdout + proc.stderr
    summary = json.loads((tmp_path / "t.json").read_text())
    best = summary["best"]
    tuned = load_scenario(out / "best_scenario.yaml")
    config = tuned.controller_config("sappc")
    assert config.gains.K_q == best["parameters"]["gains.K_q"] and config.B0 == best["parameters"]["B0"]
    kind, params, _ = controller_from_parameters_file((out / "controller_params.yaml").read_text(), source="tuned")
    assert kind == "sappc" and params.gains.mu_rad_s == best["parameters"]["gains.mu_rad_s"]
    assert set(best["gain_sets"]) == {"start", "hand_tuned", "tuned"}
    conf = summary["confirmation"]
    assert conf["first_run"] == CONFIRMATION_FIRST_RUN and conf["runs"] == 4  # runs the study never saw
    assert conf["tuned"]["feasible"] and conf["tuned"]["pass_fraction"] == 1.0
    assert (out / "history.png").stat().st_size > 0 and (out / "tradeoff.png").stat().st_size > 0


def test_a_study_on_a_dask_cluster_or_local_workers_decides_as_one_in_this_process(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Each trial's campaign in chunks of 2 runs on two Dask workers, or on two local worker
    processes: the same proposals, values and constraints as in this process (a run depends only
    on (seed, run), and the chunks are put back in run order)."""
    from distributed import LocalCluster

    path = _small(tmp_path, trials=3)
    run_tuning(path, out_dir=tmp_path / "here", progress=False, confirm=False)
    monkeypatch.setattr(tuning, "CHUNK_RUNS", 2)
    run_tuning(path, out_dir=tmp_path / "workers", workers=2, progress=False, confirm=False)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        run_tuning(path, out_dir=tmp_path / "dask", scheduler=cluster.scheduler_address, progress=False, confirm=False)
    assert _trials(tmp_path / "dask") == _trials(tmp_path / "workers") == _trials(tmp_path / "here")


def test_a_study_without_a_feasible_trial_says_which_requirement_blocked_and_how_close(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Issue 25, 2.8: a bound no gains can meet (steady max |q_ev| <= 1e-9) blocks every trial; the
    command says so per requirement (trials blocked, the closest trial's worst run against the
    bound), in its output and in summary.json, and exits 1.  The closest value is checked against
    each trial's campaign evaluated again here; the requirements every trial met are not listed."""
    path = _small(tmp_path, trials=3, requirements={"settle_by_t2": False, "steady_max_abs_qev_max": 1e-9})
    out = tmp_path / "study"
    proc = subprocess.run([*SAPPC, "tune", str(path), "--out", str(out), "--json", str(tmp_path / "t.json"), "--no-progress"],
                          capture_output=True, text=True, cwd=ROOT, timeout=600, env={**os.environ, "PYTHONWARNINGS": EMPTY_LOG_AXES_ERROR})
    assert proc.returncode == 1, proc.stdout + proc.stderr
    summary = json.loads((tmp_path / "t.json").read_text())
    assert summary["best"] is None and summary["feasible_trials"] == 0
    raw = yaml.safe_load(path.read_text())
    worst = [float(tuning.evaluate_runs(tuning.candidate_mapping(raw, "sappc", params), 0, [0, 1, 2])["steady_max_abs_qev"].max())
             for _, params, _, _ in _trials(out)]
    b = summary["blocking"]["steady_max_abs_qev_max"]
    assert b["trials_blocked"] == b["trials"] == 3 and b["bound"] == 1e-9
    assert b["best_value"] == min(worst) and b["best_trial"] == int(np.argmin(worst))
    line = f"steady_max_abs_qev_max blocked 3 of 3 trials; closest: trial {b['best_trial']}, worst run {min(worst):.4g} against the bound 1e-09"
    assert line in proc.stdout, proc.stdout
    assert summary["blocking"]["finite"]["trials_blocked"] == 0 and "finite blocked" not in proc.stdout


def _wheel_tuning(requirement: float | None) -> dict[str, Any]:
    """The wheel scenario (12 s) with the tuning scenario's campaign and tuning sections."""
    raw = yaml.safe_load((SCENARIOS / "paper_tracking_wheels.yaml").read_text())
    tune = yaml.safe_load(TUNE.read_text())
    raw["duration_s"] = 12.0
    raw["metrics"].update(steady_from_s=8.0, t2_s=10.0)
    raw["montecarlo"], raw["tuning"] = tune["montecarlo"], tune["tuning"]
    raw["tuning"]["requirements"] = {"settle_by_t2": False, **({"max_abs_wheel_speed_rad_s_max": requirement} if requirement else {})}
    return raw


def test_the_wheel_speed_requirement_is_usable_in_tuning() -> None:
    """Issue 25, 2.8: the documented ``max_abs_wheel_speed_rad_s_max`` (docs/tutorials/tuning.md) in a tuning section is accepted
    with reaction wheels (refused, naming it, with the ideal actuator), each trial's campaign
    measures it, and a run whose fastest wheel exceeds it breaks the requirement."""
    raw = _wheel_tuning(5.0)
    scenario = scenario_from_mapping(raw)
    cfg, _ = tuning_config(scenario)
    assert cfg.requirements.max_abs_wheel_speed_rad_s_max == 5.0
    table = tuning.evaluate_runs(raw, 0, [0, 1])
    from sappc.montecarlo.campaign import simulate_runs

    _, metrics, _ = simulate_runs(raw, 0, [0, 1], 0)  # the campaign's own metrics of the same runs
    overshoot = np.asarray(metrics.overshoot, dtype=np.float64)
    assert np.array_equal(table["overshoot"], np.where(overshoot > 0.0, overshoot, 0.0))  # an excursion past zero, or none
    speeds = table["max_abs_wheel_speed_rad_s"]
    assert speeds.shape == (2,) and np.all(speeds > 5.0)  # the slew spins the wheels past 5 rad/s
    s = score(table, cfg, scenario)
    assert not s.feasible and s.failures["max_abs_wheel_speed_rad_s_max"]["runs"] == 2
    assert s.constraints["max_abs_wheel_speed_rad_s_max"] == pytest.approx((speeds.max() - 5.0) / 5.0)
    assert s.worst["max_abs_wheel_speed_rad_s_max"] == {"value": speeds.max(), "bound": 5.0}
    loose = score(table, tuning_config(scenario_from_mapping(_wheel_tuning(float(speeds.max()))))[0], scenario)
    assert loose.feasible  # at the bound: met
    ideal = yaml.safe_load(TUNE.read_text())
    ideal["tuning"]["requirements"]["max_abs_wheel_speed_rad_s_max"] = 500.0
    with pytest.raises(ConfigError, match="tuning.requirements.max_abs_wheel_speed_rad_s_max needs reaction wheels"):
        tuning_config(scenario_from_mapping(ideal))
    negative = _wheel_tuning(-1.0)
    with pytest.raises(ConfigError, match="tuning.requirements.max_abs_wheel_speed_rad_s_max = -1.0 is infeasible"):
        tuning_config(scenario_from_mapping(negative))

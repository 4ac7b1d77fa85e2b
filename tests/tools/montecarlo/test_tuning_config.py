"""The tuning section's checks (sappc.montecarlo.tuning.tuning_config): every refusal names its key
and says what is wrong, each at the edge of what is accepted, and the limits themselves are
accepted (a percentile of 100, a bound of 0 where a metric can be 0, t2 at the run's end, a
single trial of a single run, seed 0)."""

from __future__ import annotations

from typing import Any

import pytest
import yaml

from gnc_common.validation import ConfigError
from sappc.montecarlo import tuning
from sappc.scenario import scenario_from_mapping

from conftest import SCENARIOS

TUNE = SCENARIOS / "paper_tracking_tune.yaml"


def _tune(metrics: dict[str, Any] | None = None, **tuning_changes: Any) -> dict[str, Any]:
    """The tuning scenario (60 s) with ``metrics`` and ``tuning`` entries replaced."""
    raw = yaml.safe_load(TUNE.read_text())
    raw["metrics"].update(metrics or {})
    if "tuning" in tuning_changes:
        raw["tuning"] = tuning_changes.pop("tuning")
    else:
        raw["tuning"].update(tuning_changes)
    return raw


_NOT_SETTLED = {"requirements": {"settle_by_t2": False}}  # no settling requirement: the objective's own check speaks
_NO_SECTION = object()


@pytest.mark.parametrize(("raw", "controller", "message"), [
    (_tune(tuning=_NO_SECTION), None, "scenario 'paper_tracking_tune' has no 'tuning' section"),
    (_tune(tuning=5), None, "tuning must be a mapping, got 5"),
    (_tune(parameters={}), None, "tuning.parameters must be a non-empty mapping of parameter path to {low, high, log}"),
    (_tune(parameters=[1]), None, "tuning.parameters must be a non-empty mapping"),
    (_tune(), "trappc", "tuning: the scenario has no controllers.trappc to tune"),
    (_tune(parameters={"gains": {"low": 0.1, "high": 1.0}}), None, "unknown key tuning.parameters.gains: not a number of controllers.sappc (tunable: "),
    (_tune(parameters={"gains.K_q": {"low": float("nan"), "high": 1.0}}), None, "tuning.parameters.gains.K_q: low must be a finite number, got nan"),
    (_tune(parameters={"gains.K_q": {"low": 0.1, "high": float("inf")}}), None, "tuning.parameters.gains.K_q: high must be a finite number, got inf"),
    (_tune(parameters={"gains.K_q": {"low": True, "high": 1.0}}), None, "tuning.parameters.gains.K_q.low must be a number, got True (a boolean is not a number)"),
    (_tune(parameters={"gains.K_q": {"low": "0.1", "high": 1.0}}), None, "tuning.parameters.gains.K_q: low must be a finite number, got '0.1'"),
    (_tune(parameters={"gains.K_q": {"low": 0.2, "high": 0.1}}), None,
     "tuning.parameters.gains.K_q: is an empty range: low (0.2) must be below high (0.1)"),
    (_tune(parameters={"gains.K_q": {"low": -0.1, "high": 0.1, "log": True}}), None, "tuning.parameters.gains.K_q: log: true needs low > 0, got -0.1"),
    (_tune(baselines=[1]), None, "tuning.baselines must be a mapping of name to gain values, got [1]"),
    (_tune(baselines={"start": {"gains.K_q": 0.5}}), None, "tuning.baselines.start: 'start' and 'tuned' name the study's own gain sets"),
    (_tune(baselines={"tuned": {"gains.K_q": 0.5}}), None, "tuning.baselines.tuned: 'start' and 'tuned' name the study's own gain sets"),
    (_tune(baselines={"mine": {}}), None, "tuning.baselines.mine must be a non-empty mapping of tuned parameter path to value, got {}"),
    (_tune(baselines={"mine": 0.3}), None, "tuning.baselines.mine must be a non-empty mapping of tuned parameter path to value, got 0.3"),
    (_tune(baselines={"mine": {"gains.K_q": float("nan")}}), None, "tuning.baselines.mine.gains.K_q must be a finite number, got nan"),
    (_tune(baselines={"mine": {"gains.K_q": True}}), None, "tuning.baselines.mine.gains.K_q must be a finite number, got True"),
    (_tune(baselines={"mine": {"gains.K_q": "0.5"}}), None, "tuning.baselines.mine.gains.K_q must be a finite number, got '0.5'"),
    (_tune(trials=0), None, "tuning.trials must be a positive integer, got 0"),
    (_tune(trials=True), None, "tuning.trials must be a number, got True (a boolean is not a number)"),
    (_tune(runs_per_trial=2.5), None, "tuning.runs_per_trial must be a positive integer, got 2.5"),
    (_tune(confirmation_runs=-3), None, "tuning.confirmation_runs must be a positive integer, got -3"),
    (_tune(seed=-1), None, "tuning.seed must be a non-negative integer, got -1"),
    (_tune(seed=1.5), None, "tuning.seed must be a non-negative integer, got 1.5"),
    (_tune(seed=True), None, "tuning.seed must be a number, got True (a boolean is not a number)"),
    (_tune(objective={"percentile": 100.5}), None, "tuning.objective.percentile must be in (0, 100], got 100.5"),
    (_tune(objective={"percentile": -5}), None, "tuning.objective.percentile must be in (0, 100], got -5"),
    (_tune(objective={"percentile": "99"}), None, "tuning.objective.percentile must be in (0, 100], got '99'"),
    (_tune({"steady_from_s": 60.0}, **_NOT_SETTLED), None,
     "tuning.objective.metric: steady_max_abs_qev needs a steady window, but metrics.steady_from_s (60.0) is not before duration_s (60.0)"),
    (_tune({"t2_s": 60.5}, objective={"metric": "rpf_error_at_t2"}, **_NOT_SETTLED), None,
     "tuning.objective.metric: rpf_error_at_t2 needs metrics.t2_s (60.5) within duration_s (60.0)"),
    (_tune(requirements={"settle_by_t2": 1}), None, "tuning.requirements.settle_by_t2 must be true or false, got 1"),
    (_tune({"t2_s": 60.5}), None, "tuning.requirements.settle_by_t2 is infeasible: metrics.t2_s (60.5) is after the run's end"),
    (_tune(requirements={"overshoot_max": -1e-9}), None, "tuning.requirements.overshoot_max = -1e-09 is infeasible: an overshoot is never negative"),
    (_tune(requirements={"overshoot_max": float("inf")}), None, "tuning.requirements.overshoot_max must be a finite number, got inf"),
    (_tune(requirements={"overshoot_max": True}), None, "tuning.requirements.overshoot_max must be a number, got True (a boolean is not a number)"),
    (_tune(requirements={"overshoot_max": "1e-4"}), None, "tuning.requirements.overshoot_max must be a finite number, got '1e-4'"),
    (_tune(requirements={"steady_max_abs_qev_max": -1e-5}), None, "tuning.requirements.steady_max_abs_qev_max = -1e-05 is infeasible: no error is below 0"),
    (_tune(requirements={"max_abs_wheel_speed_rad_s_max": -0.5}), None,
     "tuning.requirements.max_abs_wheel_speed_rad_s_max = -0.5 is infeasible: a wheel speed's magnitude is never negative"),
    (_tune({"steady_from_s": 60.0}, requirements={"settle_by_t2": False, "torque_sign_changes_per_s_max": 1.0}), None,
     "tuning.requirements: the steady requirements are infeasible: metrics.steady_from_s (60.0) is not before duration_s (60.0)"),
    (_tune({"steady_from_s": 60.0}, requirements={"settle_by_t2": False, "steady_max_abs_qev_max": 1e-4}), None,
     "tuning.requirements: the steady requirements are infeasible"),
])
def test_every_refusal_of_the_tuning_section_names_its_key_and_what_is_wrong(raw: dict[str, Any], controller: str | None, message: str) -> None:
    if raw["tuning"] is _NO_SECTION:
        del raw["tuning"]
    with pytest.raises(ConfigError) as err:
        tuning.tuning_config(scenario_from_mapping(raw), controller)
    assert str(err.value).startswith(message), str(err.value)


@pytest.mark.parametrize(("metrics", "changes"), [
    ({"t2_s": 60.0}, {}),  # settled by the run's last sample: measurable
    ({"t2_s": 60.0}, {"objective": {"metric": "rpf_error_at_t2"}, **_NOT_SETTLED}),
    ({"steady_from_s": 59.9}, {"objective": {"metric": "steady_mean_abs_qev"}}),  # a steady window of the last 0.1 s
    ({}, {"objective": {"percentile": 100}}),
    ({}, {"objective": {"percentile": 0.001}}),
    ({}, {"requirements": {"overshoot_max": 0.0, "torque_sign_changes_per_s_max": 0.0}}),  # no overshoot, no chattering at all
    ({}, {"trials": 1, "runs_per_trial": 1, "confirmation_runs": 1, "seed": 0}),
    ({}, {"baselines": {"mine": {"gains.K_q": 1}}}),  # an integer gain is a number
])
def test_the_limits_of_the_tuning_section_are_accepted(metrics: dict[str, Any], changes: dict[str, Any]) -> None:
    cfg, kind = tuning.tuning_config(scenario_from_mapping(_tune(metrics, **changes)))
    assert kind == "sappc"
    for key in ("trials", "runs_per_trial", "confirmation_runs", "seed"):
        if key in changes:
            assert getattr(cfg, key) == changes[key]
    if "baselines" in changes:
        assert cfg.baselines == {"mine": {"gains.K_q": 1.0}} and isinstance(cfg.baselines["mine"]["gains.K_q"], float)


def test_a_wheel_speed_bound_of_zero_is_accepted_and_a_negative_one_refused() -> None:
    """A wheel speed's magnitude can be 0 (a wheel that never spins): the bound 0 is feasible, below it is not."""
    raw = yaml.safe_load((SCENARIOS / "paper_tracking_wheels.yaml").read_text())
    tune = yaml.safe_load(TUNE.read_text())
    raw["montecarlo"], raw["tuning"] = tune["montecarlo"], tune["tuning"]
    raw["tuning"]["requirements"] = {"max_abs_wheel_speed_rad_s_max": 0.0}
    cfg, _ = tuning.tuning_config(scenario_from_mapping(raw))
    assert cfg.requirements.max_abs_wheel_speed_rad_s_max == 0.0
    raw["tuning"]["requirements"] = {"max_abs_wheel_speed_rad_s_max": -1e-9}
    with pytest.raises(ConfigError, match="max_abs_wheel_speed_rad_s_max = -1e-09 is infeasible"):
        tuning.tuning_config(scenario_from_mapping(raw))


def test_the_sections_defaults_are_the_documented_ones() -> None:
    """docs/tutorials/tuning.md: the 99th percentile of steady_max_abs_qev, 60 trials of 32 runs, 256
    confirmation runs, seed 0, settled by t2 required; a section that gives only parameters gets them."""
    raw = _tune()
    raw["tuning"] = {"parameters": raw["tuning"]["parameters"]}
    cfg, _ = tuning.tuning_config(scenario_from_mapping(raw))
    assert (cfg.trials, cfg.runs_per_trial, cfg.confirmation_runs, cfg.seed) == (60, 32, 256, 0)
    assert (cfg.objective.metric, cfg.objective.percentile) == ("steady_max_abs_qev", 99.0)
    assert cfg.requirements == tuning.Requirements(settle_by_t2=True)

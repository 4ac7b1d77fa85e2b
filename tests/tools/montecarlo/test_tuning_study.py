"""``sappc tune``'s study (:func:`sappc.montecarlo.tuning.run_tuning`) on a stand-in campaign:
what the study decides from the campaigns' results, without simulating them.

Each trial's campaign is replaced by :func:`stand_in`, a closed-form function of the trial's
gains and of the run index (the real campaign's metrics are tested in ``test_tuning.py`` and
``test_montecarlo.py``), so the study's own rules are checked on values known here: every trial
runs the same runs 0 .. runs_per_trial - 1; a trial's value is the objective's percentile over
them and its constraints each requirement's worst relative margin; the best trial is the
feasible one of least value; gains the law refuses are invalid trials; the confirmation runs
are runs the study never saw; a study with no feasible trial says which requirement blocked it
and how close it came; an interrupted study resumed decides as one run straight through."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from gnc_common.validation import ConfigError
from sappc.montecarlo import tuning
from sappc.montecarlo.tuning import CONFIRMATION_FIRST_RUN, run_tuning
from sappc.scenario import load_scenario

from conftest import SCENARIOS

TUNE = SCENARIOS / "paper_tracking_tune.yaml"
#: The tuning scenario's requirements (paper_tracking_tune.yaml) and the short run of ``_small``.
T2_S, OVERSHOOT_MAX, STEADY_MAX, SWITCHING_MAX = 10.0, 1e-4, 5e-5, 1.0


def stand_in(raw: dict[str, Any], seed: int, runs: list[int]) -> dict[str, np.ndarray]:
    """A campaign's per-run metrics as closed-form functions of the gains and of the run index:
    settled by t2 for K_q near 0.3; a steady error growing with B0's distance from 0.016 (run
    k's 1 + (k mod 7)/7 times); an overshoot when K_omega < 0.1; chattering when mu < 1e-4 on
    every third run; non-finite when D_m > 0.19 on run 5."""
    g = raw["controllers"]["sappc"]
    kq, kw, dm, mu, b0 = (float(g["gains"]["K_q"]), float(g["gains"]["K_omega"]), float(g["gains"]["D_m_Nm"]),
                          float(g["gains"]["mu_rad_s"]), float(g["B0"]))
    k = np.asarray(runs)
    spread = 1.0 + (k % 7) / 7.0
    finite = ~((dm > 0.19) & (k == 5))
    settling = np.where(finite, 9.0 + 0.8 * abs(math.log(kq / 0.3)) + 0.01 * (k % 3), np.nan)
    steady = 1e-5 * (1.0 + 2.0 * abs(math.log(b0 / 0.016))) * spread
    return {
        "run": k, "finite": finite, "settling_time_s": settling,
        "overshoot": np.full(k.size, 2e-4 if kw < 0.1 else 0.0),
        "steady_max_abs_qev": steady, "steady_mean_abs_qev": steady / 3.0, "rpf_error_at_t2": np.zeros(k.size),
        "torque_sign_changes_per_s": np.where((mu < 1e-4) & (k % 3 == 0), 4.0, 0.0),
    }


class Campaigns:
    """:func:`stand_in` in the place of each trial's campaign; the runs each campaign asked for."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch, interrupt_at: int | None = None) -> None:
        self.calls: list[tuple[dict[str, float], list[int]]] = []
        self.interrupt_at = interrupt_at
        monkeypatch.setattr(tuning, "evaluate_runs", self)
        monkeypatch.setattr(tuning, "_figures", lambda *args: None)  # drawn and checked by test_tuning.py's command tests

    def __call__(self, raw: dict[str, Any], seed: int, runs: list[int]) -> dict[str, np.ndarray]:
        if self.interrupt_at is not None and len(self.calls) == self.interrupt_at:
            raise KeyboardInterrupt
        g = raw["controllers"]["sappc"]
        self.calls.append(({"B0": g["B0"], **{f"gains.{k}": v for k, v in g["gains"].items()}}, list(runs)))
        assert seed == 0
        return stand_in(raw, seed, runs)


def _small(tmp_path: Path, **tuning_changes: Any) -> Path:
    """The tuning scenario, 12 s long (steady from 8 s, t2 at 10 s), 4 runs a trial."""
    raw = yaml.safe_load(TUNE.read_text())
    raw["duration_s"] = 12.0
    raw["metrics"].update(steady_from_s=8.0, t2_s=T2_S)
    raw["tuning"].update({"trials": 12, "runs_per_trial": 4, "confirmation_runs": 7, **tuning_changes})
    path = tmp_path / "small.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


def _study(out: Path) -> list[Any]:
    import optuna
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend

    storage = JournalStorage(JournalFileBackend(str(out / "study.journal")))
    return optuna.load_study(study_name=tuning.STUDY_NAME, storage=storage).get_trials(deepcopy=False)


def _expected_score(raw: dict[str, Any], params: dict[str, float], runs: list[int]) -> tuple[float, dict[str, float]]:
    """A trial's value and constraints by the documented rules (module docstring of tuning and
    :class:`~sappc.montecarlo.tuning.Score`), computed here from :func:`stand_in`."""
    t = stand_in(tuning.candidate_mapping(raw, "sappc", params), 0, runs)
    ok = t["finite"]

    def margin(values: np.ndarray, bound: float) -> float:
        worst = max(((v - bound) / bound if bound > 0 else v - bound) if f else math.inf for v, f in zip(values, ok))
        return min(worst, 1e6)

    settling = np.where(np.isfinite(t["settling_time_s"]), t["settling_time_s"], np.inf)
    constraints = {"finite": float(np.sum(~ok)), "settle_by_t2": margin(settling, T2_S), "overshoot_max": margin(t["overshoot"], OVERSHOOT_MAX),
                   "steady_max_abs_qev_max": margin(t["steady_max_abs_qev"], STEADY_MAX),
                   "torque_sign_changes_per_s_max": margin(t["torque_sign_changes_per_s"], SWITCHING_MAX)}
    objective = np.where(ok, t["steady_max_abs_qev"], 2.0)  # a run that diverged counts as the worst error
    return float(np.percentile(objective, 99)), constraints


def test_the_study_scores_every_trial_on_the_same_runs_and_keeps_the_best_feasible_one(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = _small(tmp_path)
    raw = yaml.safe_load(path.read_text())
    campaigns = Campaigns(monkeypatch)
    out = tmp_path / "study"
    summary = run_tuning(path, out_dir=out, progress=False, confirm=False)
    trials = _study(out)
    assert len(trials) == 12 and summary["trials"] == 12 and summary["invalid_trials"] == 0
    assert [runs for _, runs in campaigns.calls] == [[0, 1, 2, 3]] * 12  # common random numbers
    feasible = []
    for t, (params, _) in zip(trials, campaigns.calls):
        assert t.params == {p: params[p] for p in t.params}
        value, constraints = _expected_score(raw, t.params, [0, 1, 2, 3])
        assert t.value == pytest.approx(value, rel=1e-12) and t.constraints == pytest.approx(constraints, rel=1e-12), t.number
        if all(c <= 0.0 for c in constraints.values()):
            feasible.append((value, t.number))
    assert summary["feasible_trials"] == len(feasible) >= 1
    best = trials[min(feasible)[1]]
    assert summary["best"]["trial"] == best.number and summary["best"]["value"] == best.value
    assert summary["best"]["parameters"] == best.params
    tuned = load_scenario(out / "best_scenario.yaml").controller_config("sappc")
    assert (tuned.B0, tuned.gains.K_q, tuned.gains.mu_rad_s) == (best.params["B0"], best.params["gains.K_q"], best.params["gains.mu_rad_s"])
    start = {p: float(tuning._lookup(raw["controllers"]["sappc"], p)) for p in best.params}
    assert summary["best"]["gain_sets"] == {"start": start, "hand_tuned": {**start, **raw["tuning"]["baselines"]["hand_tuned"]},
                                            "tuned": best.params}
    assert set(summary["best"]["nominal_run"]) == {"start", "hand_tuned", "tuned"}
    assert json.loads((out / "summary.json").read_text()) == json.loads(json.dumps(summary))
    assert "confirmation" not in summary


def test_gains_the_law_refuses_are_invalid_trials_that_run_no_campaign(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A range that reaches into gains the law's validation refuses (mu <= 0): those proposals
    are invalid trials, counted among the trials, never run, never the best."""
    raw = yaml.safe_load(TUNE.read_text())
    ranges = {**raw["tuning"]["parameters"], "gains.mu_rad_s": {"low": -1e-3, "high": 1e-3}}
    campaigns = Campaigns(monkeypatch)
    out = tmp_path / "study"
    summary = run_tuning(_small(tmp_path, parameters=ranges), out_dir=out, progress=False, confirm=False)
    trials = _study(out)
    invalid = [t for t in trials if "invalid" in t.user_attrs]
    assert invalid and all(t.state.name == "FAIL" and t.params["gains.mu_rad_s"] <= 0.0 for t in invalid)
    assert summary["invalid_trials"] == len(invalid) and summary["trials"] == 12 == len(trials)
    assert len(campaigns.calls) == 12 - len(invalid)
    assert summary["best"] is None or summary["best"]["parameters"]["gains.mu_rad_s"] > 0.0


def test_the_confirmation_campaign_runs_runs_the_study_never_saw(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The best gains, the scenario's and each baseline's, on ``confirmation_runs`` runs from
    :data:`CONFIRMATION_FIRST_RUN` on: each set's objective, whether every run met every
    requirement, the fraction that did and the runs failing each requirement."""
    path = _small(tmp_path)
    raw = yaml.safe_load(path.read_text())
    campaigns = Campaigns(monkeypatch)
    summary = run_tuning(path, out_dir=tmp_path / "study", progress=False)
    confirmation_runs = list(range(10**9, 10**9 + 7))  # docs/tutorials/tuning.md: runs 1e9 .. of the same seed
    assert [runs for _, runs in campaigns.calls[12:]] == [confirmation_runs] * 3
    conf = summary["confirmation"]
    assert conf["runs"] == 7 and conf["first_run"] == CONFIRMATION_FIRST_RUN == 10**9
    for name, gains in summary["best"]["gain_sets"].items():
        t = stand_in(tuning.candidate_mapping(raw, "sappc", gains), 0, confirmation_runs)
        failing = {"settle_by_t2": int(np.sum(~(t["settling_time_s"] <= T2_S))), "overshoot_max": int(np.sum(t["overshoot"] > OVERSHOOT_MAX)),
                   "steady_max_abs_qev_max": int(np.sum(t["steady_max_abs_qev"] > STEADY_MAX)),
                   "torque_sign_changes_per_s_max": int(np.sum(t["torque_sign_changes_per_s"] > SWITCHING_MAX))}
        failed_runs = ~(t["settling_time_s"] <= T2_S) | (t["overshoot"] > OVERSHOOT_MAX) | (t["steady_max_abs_qev"] > STEADY_MAX) \
            | (t["torque_sign_changes_per_s"] > SWITCHING_MAX)
        c = conf[name]
        assert c["objective"] == pytest.approx(float(np.percentile(t["steady_max_abs_qev"], 99)), rel=1e-12), name
        assert c["runs_failing"] == {k: v for k, v in failing.items() if v}, name
        assert c["pass_fraction"] == 1.0 - np.sum(failed_runs) / 7 and c["feasible"] == (not failed_runs.any()), name
    assert not conf["hand_tuned"]["feasible"] and 0.0 < conf["hand_tuned"]["pass_fraction"] < 1.0  # its mu (7e-5) chatters on every third run


def test_a_study_without_a_feasible_trial_says_which_requirement_blocked_it_and_how_close(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = _small(tmp_path, requirements={"settle_by_t2": False, "steady_max_abs_qev_max": 1e-9})
    raw = yaml.safe_load(path.read_text())
    campaigns = Campaigns(monkeypatch)
    out = tmp_path / "study"
    summary = run_tuning(path, out_dir=out, progress=False)
    assert summary["best"] is None and summary["feasible_trials"] == 0 and not (out / "best_scenario.yaml").exists()
    worst = [float(stand_in(tuning.candidate_mapping(raw, "sappc", p), 0, runs)["steady_max_abs_qev"].max()) for p, runs in campaigns.calls]
    b = summary["blocking"]["steady_max_abs_qev_max"]
    assert b == {"trials_blocked": 12, "trials": 12, "best_value": min(worst), "best_trial": int(np.argmin(worst)), "bound": 1e-9}
    assert summary["blocking"]["finite"]["trials_blocked"] == 0 and summary["blocking"]["finite"]["trials"] == 12
    assert set(summary["blocking"]) == {"finite", "steady_max_abs_qev_max"}
    assert json.loads((out / "summary.json").read_text()) == json.loads(json.dumps(summary))


def test_blocking_counts_only_complete_trials_and_keeps_the_closest_measured_value() -> None:
    """A trial whose worst run was never measured (None: a run that never settled) blocks but
    sets no closest value; a failed (invalid) trial is not counted."""
    from types import SimpleNamespace

    from optuna.trial import TrialState

    def trial(number: int, state: TrialState, c: float, worst: float | None) -> Any:
        return SimpleNamespace(number=number, state=state, constraints={"settle_by_t2": c},
                               user_attrs={"worst": {"settle_by_t2": {"value": worst, "bound": 10.0}}})

    trials = [trial(0, TrialState.COMPLETE, 0.5, 15.0), trial(1, TrialState.COMPLETE, 1e6, None), trial(2, TrialState.FAIL, 0.1, 11.0),
              trial(3, TrialState.COMPLETE, 0.2, 12.0), trial(4, TrialState.COMPLETE, 0.0, 10.0), trial(5, TrialState.COMPLETE, 0.0, 10.0)]
    # the closest value, and the first trial that came that close
    assert tuning.blocking(trials) == {"settle_by_t2": {"trials_blocked": 3, "trials": 5, "best_value": 10.0, "best_trial": 4, "bound": 10.0}}
    both = SimpleNamespace(number=6, state=TrialState.COMPLETE, constraints={"settle_by_t2": 1e6, "overshoot_max": -0.5},
                           user_attrs={"worst": {"overshoot_max": {"value": 5e-5, "bound": 1e-4}}})
    # a requirement with no worst run recorded for a trial does not hide the trial's other requirements
    assert tuning.blocking([both])["overshoot_max"] == {"trials_blocked": 0, "trials": 1, "best_value": 5e-5, "best_trial": 6, "bound": 1e-4}


def test_an_interrupted_study_resumed_decides_as_one_run_straight_through(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """14 trials (10 random, then TPE on what came before); stopped after 2, continued to 11, a
    Ctrl-C inside the 12th trial's campaign (that trial not counted), resumed: the same trials."""
    path = _small(tmp_path, trials=14)
    Campaigns(monkeypatch)
    straight = run_tuning(path, out_dir=tmp_path / "straight", progress=False, confirm=False)
    expected = [(t.state, t.params, t.value, t.constraints) for t in _study(tmp_path / "straight")]
    assert len(expected) == 14 and len({json.dumps(p, sort_keys=True) for _, p, _, _ in expected}) == 14
    out = tmp_path / "resumed"
    run_tuning(path, out_dir=out, trials=2, progress=False, confirm=False)
    run_tuning(path, out_dir=out, trials=11, resume=True, progress=False, confirm=False)
    Campaigns(monkeypatch, interrupt_at=0)
    with pytest.raises(KeyboardInterrupt):
        run_tuning(path, out_dir=out, resume=True, progress=False, confirm=False)
    assert [t.state.name for t in _study(out)][-1] == "FAIL" and _study(out)[-1].user_attrs["interrupted"] is True
    Campaigns(monkeypatch)
    resumed = run_tuning(path, out_dir=out, resume=True, progress=False, confirm=False)
    assert [(t.state, t.params, t.value, t.constraints) for t in _study(out) if not t.user_attrs.get("interrupted")] == expected
    assert resumed["trials"] == 14 and (resumed["best"] or {}).get("parameters") == (straight["best"] or {}).get("parameters")


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"trials": 0}, "--trials must be a positive integer, got 0"),
    ({"runs_per_trial": -1}, "--runs-per-trial must be a positive integer, got -1"),
    ({"seed": -1}, "--seed must be a non-negative integer, got -1"),
    ({"seed": True}, "--seed must be a non-negative integer, got True"),
    ({"workers": 0}, "--workers must be >= 1, got 0"),
])
def test_bad_arguments_stop_the_study_before_it_starts(tmp_path: Path, kwargs: dict[str, Any], message: str) -> None:
    with pytest.raises(ConfigError, match=message.replace("-", r"\-")):
        run_tuning(_small(tmp_path), out_dir=tmp_path / "study", progress=False, confirm=False, **kwargs)
    assert not (tmp_path / "study").exists()


def test_overrides_replace_the_sections_trials_runs_and_seed(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    campaigns = Campaigns(monkeypatch)
    with pytest.raises(AssertionError):  # the stand-in checks the seed: 3 reaches the campaigns
        run_tuning(_small(tmp_path), out_dir=tmp_path / "s", trials=3, runs_per_trial=2, seed=3, progress=False, confirm=False)
    assert json.loads((tmp_path / "s" / "tune.json").read_text())["seed"] == 3
    summary = run_tuning(_small(tmp_path), out_dir=tmp_path / "t", trials=3, runs_per_trial=2, progress=False, confirm=False)
    assert summary["trials"] == 3 and summary["runs_per_trial"] == 2 and campaigns.calls[-1][1] == [0, 1]
    assert json.loads((tmp_path / "t" / "tune.json").read_text())["runs_per_trial"] == 2
    nested = tmp_path / "runs" / "tune" / "small"  # the command's default --out is nested: made with its parents
    summary = run_tuning(_small(tmp_path, seed=5), out_dir=nested, trials=1, runs_per_trial=1, seed=0, progress=False, confirm=False)
    assert summary["seed"] == 0 and json.loads((nested / "tune.json").read_text())["seed"] == 0  # seed 0 is a seed


def test_a_trial_left_running_by_a_killed_study_is_failed_on_resume_and_not_counted(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A study killed hard (SIGKILL: no KeyboardInterrupt) leaves its trial RUNNING in the journal;
    resumed, that trial is marked failed and interrupted, and the study still ends with the
    section's number of counted trials."""
    import optuna
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend

    Campaigns(monkeypatch)
    path, out = _small(tmp_path, trials=3), tmp_path / "study"
    run_tuning(path, out_dir=out, trials=2, progress=False, confirm=False)
    storage = JournalStorage(JournalFileBackend(str(out / "study.journal")))
    optuna.load_study(study_name=tuning.STUDY_NAME, storage=storage).ask()  # the killed study's trial, never told
    assert [t.state.name for t in _study(out)] == ["COMPLETE", "COMPLETE", "RUNNING"]
    summary = run_tuning(path, out_dir=out, resume=True, progress=False, confirm=False)
    trials = _study(out)
    assert [t.state.name for t in trials] == ["COMPLETE", "COMPLETE", "FAIL", "COMPLETE"]
    assert trials[2].user_attrs.get("interrupted") is True and summary["trials"] == 3


def test_a_run_without_the_objectives_value_counts_as_the_worst_one() -> None:
    """The objective of a run that never settled, or diverged, is the worst it can be: the run's
    length for settling_time_s, 2 (the largest |q_ev - rho|) for an error."""
    raw = yaml.safe_load(TUNE.read_text())
    raw["tuning"]["requirements"] = {"settle_by_t2": False}
    n = 3
    table = {"run": np.arange(n), "finite": np.array([True, True, False]), "settling_time_s": np.array([5.0, np.nan, 4.0]),
             "overshoot": np.zeros(n), "steady_max_abs_qev": np.array([1e-5, 2e-5, 1e-5]), "steady_mean_abs_qev": np.zeros(n),
             "rpf_error_at_t2": np.zeros(n), "torque_sign_changes_per_s": np.zeros(n)}
    duration = float(raw["duration_s"])
    for metric, values in (("settling_time_s", [5.0, duration, duration]), ("steady_max_abs_qev", [1e-5, 2e-5, 2.0])):
        raw["tuning"]["objective"] = {"metric": metric, "percentile": 100}
        scenario = tuning.scenario_from_mapping(raw)
        cfg, _ = tuning.tuning_config(scenario)
        assert tuning.score(table, cfg, scenario).value == max(values), metric


def test_a_bound_of_zero_is_met_at_zero_and_broken_by_the_excess_itself() -> None:
    """A requirement bounded by 0 (no overshoot at all) has no scale: its margin is the worst run's
    excess itself, 0 when every run is at 0 (feasible)."""
    raw = yaml.safe_load(TUNE.read_text())
    raw["tuning"]["requirements"] = {"settle_by_t2": False, "overshoot_max": 0.0}
    scenario = tuning.scenario_from_mapping(raw)
    cfg, _ = tuning.tuning_config(scenario)
    n = 3
    table = {"run": np.arange(n), "finite": np.ones(n, dtype=bool), "settling_time_s": np.full(n, 5.0), "overshoot": np.zeros(n),
             "steady_max_abs_qev": np.full(n, 1e-5), "steady_mean_abs_qev": np.zeros(n), "rpf_error_at_t2": np.zeros(n),
             "torque_sign_changes_per_s": np.zeros(n)}
    met = tuning.score(table, cfg, scenario)
    assert met.constraints["overshoot_max"] == 0.0 and met.feasible and met.failures == {}  # a run at the bound meets it
    assert met.worst == {"finite": {"value": 0.0, "bound": 0.0}, "overshoot_max": {"value": 0.0, "bound": 0.0}}
    broken = tuning.score({**table, "overshoot": np.array([0.0, 3e-5, 1e-5])}, cfg, scenario)
    assert broken.constraints["overshoot_max"] == 3e-5 and not broken.feasible and broken.failures["overshoot_max"]["runs"] == 2
    assert broken.failed_runs.tolist() == [False, True, True]


def test_a_finite_margin_is_capped_at_a_million() -> None:
    """A requirement broken by more than a million times its bound counts as 1e6, as a run that never
    settled does (one scale for the sampler)."""
    raw = yaml.safe_load(TUNE.read_text())
    raw["tuning"]["requirements"] = {"settle_by_t2": False, "steady_max_abs_qev_max": 1e-6}
    scenario = tuning.scenario_from_mapping(raw)
    cfg, _ = tuning.tuning_config(scenario)
    table = {"run": np.arange(2), "finite": np.ones(2, dtype=bool), "settling_time_s": np.full(2, 5.0), "overshoot": np.zeros(2),
             "steady_max_abs_qev": np.array([1e-7, 1.5]), "steady_mean_abs_qev": np.zeros(2), "rpf_error_at_t2": np.zeros(2),
             "torque_sign_changes_per_s": np.zeros(2)}
    s = tuning.score(table, cfg, scenario)
    assert s.constraints["steady_max_abs_qev_max"] == 1e6 and s.worst["steady_max_abs_qev_max"] == {"value": 1.5, "bound": 1e-6}
    table["steady_max_abs_qev"] = np.array([1e-7, 0.5])  # (0.5 - 1e-6) / 1e-6: under the cap
    assert tuning.score(table, cfg, scenario).constraints["steady_max_abs_qev_max"] == pytest.approx(499_999.0)


def test_the_progress_line_counts_trials_and_feasible_ones_and_the_summary_the_studys_time(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """Not on a terminal: one line a trial on stderr, ``trials i/N``, the best so far and how many
    trials were feasible so far (the last line: the summary's count)."""
    import time

    Campaigns(monkeypatch)
    t0 = time.perf_counter()
    summary = run_tuning(_small(tmp_path, requirements={"settle_by_t2": False, "overshoot_max": OVERSHOOT_MAX}), out_dir=tmp_path / "study",
                         trials=6, confirm=False)  # progress by default
    assert 0.0 < summary["wall_time_s"] <= time.perf_counter() - t0  # the study's own time, as the command prints it
    lines = [line for line in capsys.readouterr().err.splitlines() if line.startswith("trials ")]
    assert [line.split()[1] for line in lines] == [f"{i}/6" for i in range(1, 7)]
    feasible = [int(line.rsplit("feasible ", 1)[1]) for line in lines]
    assert feasible == sorted(feasible) and feasible[-1] == summary["feasible_trials"] and 0 < summary["feasible_trials"] < 6, lines


def test_a_trials_campaign_is_put_back_in_run_order_whatever_order_its_chunks_complete(monkeypatch: pytest.MonkeyPatch) -> None:
    """Chunks of 2 runs of runs 40..44 completing last first, with the pool's empty ticks between."""
    monkeypatch.setattr(tuning, "CHUNK_RUNS", 2)
    monkeypatch.setattr(tuning, "evaluate_runs", lambda raw, seed, runs: {"run": np.asarray(runs), "x": np.asarray(runs) * 10.0})

    class Reversed:
        def run(self, tasks: list[Any]) -> Any:
            for index, fn, args in reversed(tasks):
                yield None
                yield index, fn(*args)

    got = tuning._evaluate(Reversed(), {}, 0, [40, 41, 42, 43, 44])  # type: ignore[arg-type]
    assert got["run"].tolist() == [40, 41, 42, 43, 44] and got["x"].tolist() == [400.0, 410.0, 420.0, 430.0, 440.0]


def test_a_candidate_is_the_scenario_with_the_trials_gains_and_controller() -> None:
    raw = yaml.safe_load(TUNE.read_text())
    before = json.dumps(raw, sort_keys=True)
    raw["controller"] = "blfppc"
    cand = tuning.candidate_mapping(raw, "sappc", {"gains.K_q": 1, "extra.depth.value": 2.5, "B0": 0.02})
    assert cand["controller"] == "sappc" and cand["controllers"]["sappc"]["gains"]["K_q"] == 1.0
    assert cand["controllers"]["sappc"]["extra"] == {"depth": {"value": 2.5}} and cand["controllers"]["sappc"]["B0"] == 0.02
    assert isinstance(cand["controllers"]["sappc"]["gains"]["K_q"], float)
    before = json.dumps(raw, sort_keys=True)
    assert json.dumps(raw, sort_keys=True) == before  # the scenario itself untouched


def test_the_first_ten_trials_are_random_draws_then_tpe_proposes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """docs/tutorials/tuning.md: TPE starts with 10 random trials, and trial i's sampler is seeded
    from (seed, i): trials 0-9 are exactly what a random sampler seeded so draws in the ranges;
    trial 10 is not (TPE proposes it from the first ten)."""
    import optuna
    from optuna.samplers import RandomSampler

    Campaigns(monkeypatch)
    path = _small(tmp_path, trials=11)
    run_tuning(path, out_dir=tmp_path / "study", progress=False, confirm=False)
    cfg, _ = tuning.tuning_config(load_scenario(path))
    trials = _study(tmp_path / "study")
    assert [t.number for t in trials] == list(range(11))
    for t in trials:
        trial = optuna.create_study(sampler=RandomSampler(seed=tuning._trial_seed(0, t.number))).ask()
        drawn = {p: trial.suggest_float(p, r.low, r.high, log=r.log) for p, r in cfg.parameters.items()}
        assert (t.params == drawn) == (t.number < 10), t.number

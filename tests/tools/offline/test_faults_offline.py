"""Faults in the offline loop (issue 14): the controller node's lockstep answers, modelled sample
by sample, the scenario's watchdog setting, the run summary and the requirements' exit status.

The fault models themselves are the compiled kernels the injector calls (``tests/sim/test_faults.py``);
the graph against this loop is ``tests/tools/graph/test_faults_graph.py``.
"""

from __future__ import annotations

import copy
import json
import subprocess

import numpy as np
import pytest
import yaml

from gnc_common.validation import ConfigError
from sappc.offline import compiled_loop
from sappc_msgs_py.contract import ANSWER_COMMANDED, ANSWER_HELD, ANSWER_WATCHDOG_ZERO
from sappc.offline.simulate import simulate
from sappc.scenario import scenario_from_mapping

from conftest import ROOT, SAPPC, SCENARIOS

DT_S = 0.01
BASE = yaml.safe_load((SCENARIOS / "paper_tracking.yaml").read_text())


def _scenario(duration_s: float = 2.0, **extra: object) -> dict:  # type: ignore[type-arg]
    raw = copy.deepcopy(BASE)
    raw["duration_s"] = duration_s
    raw.update(extra)
    return raw


def _run(raw: dict) -> compiled_loop.CompiledRun:  # type: ignore[type-arg]
    return compiled_loop.run_single(compiled_loop.prepare(scenario_from_mapping(raw)), 0, 1)


def test_a_dropout_is_ridden_through_then_answered_with_zero_then_control_resumes() -> None:
    """State lost for [1.0, 1.5) s with the default 0.1 s stale timeout: the controller holds its
    last torque for the ten samples 1.00 .. 1.09 (t - 0.99 <= 0.1 s), the watchdog answers
    1.10 .. 1.49 with zero, and the first sample back (1.50) is computed and commanded."""
    run = _run(_scenario(faults=[{"kind": "sensor_dropout", "start_s": 1.0, "end_s": 1.5}]))
    status, torque = run.status[0], run.out[0, :, compiled_loop.O_TORQUE, :3]
    k = np.arange(status.size)
    np.testing.assert_array_equal(status[(k >= 100) & (k < 110)], ANSWER_HELD)
    np.testing.assert_array_equal(status[(k >= 110) & (k < 150)], ANSWER_WATCHDOG_ZERO)
    np.testing.assert_array_equal(status[(k < 100) | (k >= 150)], ANSWER_COMMANDED)
    np.testing.assert_array_equal(torque[100:110], np.repeat(torque[99:100], 10, axis=0))  # held
    np.testing.assert_array_equal(torque[110:150], 0.0)
    assert np.all(np.abs(torque[150]) > 0.0)  # computed again at once
    assert run.status_counts()["watchdog_zero"][0] == 40 and run.status_counts()["held"][0] == 10


def test_a_dropout_shorter_than_the_stale_timeout_is_only_held_and_the_scenario_sets_the_timeout() -> None:
    short = _run(_scenario(faults=[{"kind": "reference_dropout", "start_s": 1.0, "end_s": 1.05}]))
    assert short.status_counts()["held"][0] == 5 and short.status_counts()["watchdog_zero"][0] == 0
    tight = _run(_scenario(faults=[{"kind": "reference_dropout", "start_s": 1.0, "end_s": 1.05}], controller_node={"stale_timeout_s": 0.02}))
    # 1.00 and 1.01 are within 0.02 s of the last state (0.99): held; 1.02 .. 1.04 answered with zero
    assert tight.status_counts()["held"][0] == 2 and tight.status_counts()["watchdog_zero"][0] == 3


def test_a_dropped_command_is_held_by_the_actuator_and_the_controller_never_stops() -> None:
    """(At 15 s, after the transient: the torque is no longer saturated and changes every sample.)"""
    run = _run(_scenario(16.0, faults=[{"kind": "actuator_dropout", "start_s": 15.0, "end_s": 15.2}]))
    torque = run.out[0, :, compiled_loop.O_TORQUE, :3]
    np.testing.assert_array_equal(torque[1500:1520], np.repeat(torque[1499:1500], 20, axis=0))
    np.testing.assert_array_equal(run.status[0], ANSWER_COMMANDED)
    assert not np.array_equal(torque[1520], torque[1499])


def test_without_faults_the_loop_is_the_one_it_was() -> None:
    """No fault: every sample commanded, the delivered torque is the law's (bit for bit)."""
    run = _run(_scenario())
    np.testing.assert_array_equal(run.status[0], ANSWER_COMMANDED)
    assert run.status_counts()["commanded"][0] == 201


@pytest.mark.parametrize(("requirements", "message"), [
    ({"steady_max_qev_max": 1.0}, "unknown key metrics.requirements.steady_max_qev_max"),
    ({"settling_time_s_max": -1.0}, "metrics.requirements.settling_time_s_max must be a finite number >= 0"),
    ({"overshoot_max": float("nan")}, "metrics.requirements.overshoot_max must be a finite number >= 0"),
])
def test_bad_requirements_name_the_key(requirements: dict, message: str) -> None:  # type: ignore[type-arg]
    raw = _scenario(metrics={**BASE["metrics"], "requirements": requirements})
    with pytest.raises(ConfigError, match=message.replace(".", r"\.")):
        scenario_from_mapping(raw)


def test_a_no_chattering_requirement_bounds_the_torque_sign_changes() -> None:
    """``torque_sign_changes_per_s_max``: experiment 1 holds the disturbance with a torque that never
    switches over [25, 60] s (it meets a bound of 0); without the disturbance the 5 mN m deadband
    makes it switch some 28 times a second on its busiest axis, almost never reversing."""
    from sappc.evaluation.requirements import failed_requirements

    bound = {"torque_sign_changes_per_s_max": 0.0}
    with_disturbance = simulate(scenario_from_mapping(_scenario(60.0, metrics={**BASE["metrics"], "requirements": bound})))
    assert with_disturbance.metrics["torque_sign_changes_per_s"] == 0.0 and with_disturbance.metrics["torque_reversals_per_s"] == 0.0
    assert failed_requirements(with_disturbance.metrics, with_disturbance.scenario.metrics.requirements) == []
    calm = simulate(scenario_from_mapping(_scenario(60.0, disturbances=[])))
    rate = calm.metrics["torque_sign_changes_per_s"]
    assert 20.0 < rate < 35.0 and calm.metrics["torque_reversals_per_s"] < 1.0
    assert failed_requirements(calm.metrics, bound) == [f"torque_sign_changes_per_s = {rate:.6g} > 0"]


def test_simulate_reports_what_the_controller_did_and_exits_4_on_a_broken_requirement(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """The dropout of docs/how-to/faults.md through `sappc simulate`: the summary line counts the answers, and a
    requirement the run breaks (steady max |q_ev| over [25, 60] s <= 1e-4: the dropout's transient
    reaches 2.7e-4) gives exit status 4 naming it; without the requirement the run exits 0."""
    raw = copy.deepcopy(BASE)
    raw["faults"] = [{"kind": "sensor_dropout", "start_s": 30.0, "end_s": 30.5}]
    raw["metrics"] = {**BASE["metrics"], "requirements": {"steady_max_abs_qev_max": 1e-4}}
    path = tmp_path / "dropout.yaml"
    path.write_text(yaml.safe_dump(raw))
    proc = subprocess.run([*SAPPC, "simulate", str(path), "--json", str(tmp_path / "m.json")], capture_output=True, text=True, cwd=ROOT,
                          timeout=300)
    assert proc.returncode == 4, proc.stdout + proc.stderr
    assert "computed the torque of 5951 of 6001 samples; not commanded: watchdog zero 40, held 10" in proc.stdout
    assert "FAILED: steady_max_abs_qev = 0.000270054 > 0.0001" in proc.stdout
    report = json.loads((tmp_path / "m.json").read_text())
    assert report["controller_summary"]["held"] == 10 and report["failed_requirements"]
    del raw["metrics"]["requirements"]
    path.write_text(yaml.safe_dump(raw))
    assert subprocess.run([*SAPPC, "simulate", str(path)], capture_output=True, cwd=ROOT, timeout=300).returncode == 0
    offline = simulate(scenario_from_mapping(raw))
    assert offline.metrics["returned_to_constraint"] is True

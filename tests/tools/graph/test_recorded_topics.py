"""What ``sappc run`` asks the recorder to record: exactly the topics the run's nodes publish, so a
bag lists no empty channel (a fault-free run with the ideal actuator used to list the fault
relays, ``joint_states``, ``truth/*`` and the estimator's topics, all empty).  The bags
themselves are checked in test_graph.py (every recorded channel holds what was published)."""

from __future__ import annotations

from typing import Any, cast

import pytest
import yaml

from conftest import SCENARIOS
from sappc.graph.launch import node_parameters
from sappc.scenario import Scenario, load_scenario, scenario_from_mapping
from sappc_msgs_py.contract import FAULT_TOPICS, TOPICS
from sappc_msgs_py.runtime import parse_expected

PATHS = {"scenario": "scenario.yaml", "bag": "bag", "counts": "counts", "params": "params.yaml", "end": "end_reached"}
#: Experiment 1 in lockstep: the contract's topics without wheels, sensor models, an estimator or a fault relay.
EXPERIMENT_1 = ["state/attitude", "state/rate", "reference/attitude", "reference/rate", "reference/acceleration", "control/torque",
                "disturbance/torque", "controller/diagnostics", "/clock", "state/tf", "reference/tf"]


def _params(scenario: Scenario, *, realtime: bool = False, external: bool = False) -> dict[str, Any]:
    return node_parameters(scenario, scenario.resolve_controller(None), realtime=realtime, paths=PATHS, external_plant=external)


def _recorded(params: dict[str, Any]) -> list[str]:
    return cast("list[str]", params["/recorder"]["ros__parameters"]["topics"])


def _published(params: dict[str, Any]) -> set[str]:
    """Every topic a node of the run publishes: those it lists in its expected_subscribers."""
    return {t for name, node in params.items() if name != "/recorder"
            for t in parse_expected(node["ros__parameters"]["expected_subscribers"])}


def test_a_fault_free_run_with_the_ideal_actuator_records_its_eleven_topics() -> None:
    assert _recorded(_params(load_scenario("paper_tracking"))) == EXPERIMENT_1
    assert _recorded(_params(load_scenario("paper_tracking"), realtime=True)) == [t for t in EXPERIMENT_1 if t != "/clock"]


@pytest.mark.parametrize("name", sorted(p.stem for p in SCENARIOS.glob("*.yaml")))
@pytest.mark.parametrize("mode", ["lockstep", "realtime", "external"])
def test_the_recorder_records_what_the_nodes_publish_in_the_contracts_order(name: str, mode: str) -> None:
    params = _params(load_scenario(name), realtime=mode == "realtime", external=mode == "external")
    recorded = _recorded(params)
    assert set(recorded) == _published(params) and len(recorded) == len(set(recorded))
    order = [t.name for t in TOPICS + FAULT_TOPICS]
    assert recorded == sorted(recorded, key=order.index)


def test_the_optional_topics_come_with_what_publishes_them() -> None:
    flight = _recorded(_params(load_scenario("paper_tracking_flight")))
    assert {"joint_states", "truth/attitude", "truth/gyro_bias", "estimate/attitude", "estimator/covariance"} <= set(flight)
    wheels = _recorded(_params(load_scenario("paper_tracking_wheels")))
    assert "joint_states" in wheels and not any(t.startswith(("truth/", "estimate", "fault/")) for t in wheels)
    raw = yaml.safe_load((SCENARIOS / "paper_tracking.yaml").read_text())
    raw["faults"] = [{"kind": "sensor_dropout", "start_s": 30.0, "end_s": 30.5}]
    relayed = _recorded(_params(scenario_from_mapping(raw)))
    assert [t for t in relayed if t.startswith("fault/")] == ["fault/state/attitude", "fault/state/rate"]

"""Every run has a verdict (issue 46, item 1): the bundled scenarios state their requirements and
meet them (or, the two failure cases, break them on purpose), and a lost spacecraft fails whatever
its scenario states (:mod:`sappc.evaluation.requirements`), through ``sappc simulate``: its exit
status and its last line."""

from __future__ import annotations

import copy
import re
from pathlib import Path
from typing import Any

import pytest
import yaml

from conftest import SCENARIOS
from sappc.cli import EXIT_REQUIREMENT_FAILED, main
from sappc.files import bundled_scenarios
from sappc.scenario import load_scenario, read_scenario_mapping

#: The bundled scenarios that show a failure and exit 4 on purpose (docs/how-to/faults.md).
FAILING_ON_PURPOSE = {"paper_tracking_wheels_saturation", "paper_tracking_orbit_no_management"}
#: The 6 h scenarios (a run each costs about 15 s and 3.5 GB): only the failure case below flies one.
LONG = {"paper_tracking_orbit", "paper_tracking_orbit_no_management", "paper_tracking_orbit_800km",
        "paper_tracking_orbit_800km_sso"}


def test_every_bundled_scenario_states_its_requirements() -> None:
    for b in bundled_scenarios():
        requirements = load_scenario(b.path).metrics.requirements
        assert requirements, f"{b.name} states no metrics.requirements"


@pytest.mark.parametrize("name", sorted(b.name for b in bundled_scenarios() if b.name not in LONG))
def test_a_bundled_scenario_meets_its_requirements_or_fails_on_purpose(name: str, capsys: pytest.CaptureFixture[str]) -> None:
    status = main(["simulate", name])
    last = capsys.readouterr().out.splitlines()[-1]
    if name in FAILING_ON_PURPOSE:
        assert status == EXIT_REQUIREMENT_FAILED and last.startswith("FAILED: "), last
    else:
        assert status == 0 and last.startswith("met every requirement of the scenario ("), last


def _experiment_1(tmp_path: Path, **changes: Any) -> Path:
    raw = copy.deepcopy(read_scenario_mapping(SCENARIOS / "paper_tracking.yaml"))
    raw["metrics"].pop("requirements")
    raw.update(changes)
    path = tmp_path / "case.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


def test_a_lost_attitude_fails_a_scenario_without_requirements(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The actuator stuck from 30 s: the periodic disturbance turns the spacecraft away, and the run
    fails with one line naming the loss, though its scenario states no requirement; without the
    fault the same scenario passes with "kept control"."""
    assert main(["simulate", str(_experiment_1(tmp_path))]) == 0
    assert capsys.readouterr().out.splitlines()[-1] == "kept control (the scenario states no requirements)"
    stuck = _experiment_1(tmp_path, faults=[{"kind": "actuator_stuck", "start_s": 30.0}])
    assert main(["simulate", str(stuck)]) == EXIT_REQUIREMENT_FAILED
    last = capsys.readouterr().out.splitlines()[-1]
    assert last.startswith("FAILED: control lost: max |q_ev,i| above 0.01 (10 x the settling band) from "), last
    assert "; " not in last  # one failure: the controller computed every sample


def test_a_controller_starved_of_inputs_fails_as_a_loss_of_control(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The state lost from 10 s to 59 s: the watchdog answers 4900 of 6001 samples with zero torque."""
    starved = _experiment_1(tmp_path, faults=[{"kind": "sensor_dropout", "start_s": 10.0, "end_s": 59.0}])
    assert main(["simulate", str(starved)]) == EXIT_REQUIREMENT_FAILED
    lines = capsys.readouterr().out.splitlines()
    assert "control lost: the controller computed the torque of 1101 of 6001 samples (18%, fewer than 50%)" in lines[-1], lines[-1]


@pytest.mark.slow
def test_the_800_km_orbit_with_the_cross_product_law_loses_control_and_fails(tmp_path: Path,
                                                                               capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 46's case: the 6 h scenario in an 800 km, 51.6 deg orbit with the cross-product law
    loses its attitude; ``simulate`` exits 4 with one line naming the loss (both rules: the error,
    and the 41 % of samples the controller computed)."""
    raw = copy.deepcopy(read_scenario_mapping(SCENARIOS / "paper_tracking_orbit.yaml"))
    raw["orbit"].update(altitude_m=800_000.0, inclination_deg=51.6)
    raw["momentum_management"]["law"] = "cross_product"
    path = tmp_path / "orbit800.yaml"
    path.write_text(yaml.safe_dump(raw))
    assert main(["simulate", str(path)]) == EXIT_REQUIREMENT_FAILED
    last = capsys.readouterr().out.splitlines()[-1]
    assert last.startswith("FAILED: control lost: max |q_ev,i| above 0.01 (10 x the settling band) from "), last
    # how many samples a tumbling spacecraft's controller computes is chaotic (41 % when measured): the rule's verdict is not
    assert re.search(r"; control lost: the controller computed the torque of \d+ of 2160001 samples \(\d+%, fewer than 50%\); ", last), last

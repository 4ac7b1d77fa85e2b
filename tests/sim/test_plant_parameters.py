"""The plant node's parameters go through the checks the scenario loader uses
(:mod:`gnc_common.validation`): the same rule gives the same words in both, and a bad parameter
stops the node at start-up with one line naming it (exit status 2)."""

from __future__ import annotations

import copy
import subprocess
import sys

import numpy as np
import pytest

from sappc.scenario import load_scenario, scenario_from_mapping
from gnc_common.validation import ConfigError, check_initial_quaternion, check_positive_int, inertia_from_row_major

from conftest import ROOT, SCENARIOS


def test_an_initial_quaternion_within_rounding_is_normalised_and_a_typo_is_refused() -> None:
    q = check_initial_quaternion("q", [0.3254, 0.4068, -0.3254, 0.7891])  # the paper's q_s(0), 4 decimals
    assert abs(np.linalg.norm(q) - 1.0) < 1e-15
    with pytest.raises(ConfigError, match=r"^q = \[0.0, 0.0, 0.0, 1.1\] has norm 1.1; expected a unit quaternion"):
        check_initial_quaternion("q", [0.0, 0.0, 0.0, 1.1])


@pytest.mark.parametrize("bad", [0, -1, 1.0, True, "2"])
def test_a_count_must_be_a_positive_int(bad: object) -> None:
    with pytest.raises(ConfigError, match="^n must be a positive integer"):
        check_positive_int("n", bad)
    assert check_positive_int("n", 3) == 3


def test_an_inertia_parameter_has_nine_values() -> None:
    assert inertia_from_row_major("J", range(9)).shape == (3, 3)
    with pytest.raises(ConfigError, match=r"^J must have 9 values \(row major 3x3\), got 8"):
        inertia_from_row_major("J", [1.0] * 8)


def test_the_loader_and_the_node_say_the_same_about_a_bad_initial_quaternion() -> None:
    raw = copy.deepcopy(load_scenario(SCENARIOS / "paper_tracking.yaml").raw)
    raw["initial_state"]["q_BN"] = [0.0, 0.0, 0.0, 2.0]
    with pytest.raises(ConfigError) as loader:
        scenario_from_mapping(raw)
    proc = subprocess.run([sys.executable, "-m", "spacecraft_sim", "--ros-args", "-p", "q_BN0:=[0.0, 0.0, 0.0, 2.0]"],
                          capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: q_BN0 = [0.0, 0.0, 0.0, 2.0] has norm 2"), proc.stderr
    assert lines[0].removeprefix("error: q_BN0") == str(loader.value).removeprefix("initial_state.q_BN")


@pytest.mark.parametrize(("param", "words"), [
    ("rk4_substeps:=0", "error: rk4_substeps must be a positive integer, got 0"),
    ("inertia_kg_m2:=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]", "error: inertia_kg_m2 must have 9 values (row major 3x3), got 8"),
    # the wheel set (JSON, quoted as a YAML string) goes through the scenario's own checks, each key named in full
    ("""wheels:='{"spin_inertia_kg_m2": -1, "max_torque_Nm": 0.2, "max_speed_rad_s": 600}'""",
     "error: wheels.spin_inertia_kg_m2 must be > 0, got -1"),
    ("""wheels:='{"spin_axes_B": [[1, 0, 0], [0, 1, 0], [1, 1, 0]], "spin_inertia_kg_m2": 0.1, "max_torque_Nm": 0.2, "max_speed_rad_s": 600}'""",
     "error: wheels.spin_axes_B must span three dimensions (a torque about every axis), got ((1, 0, 0), (0, 1, 0), (1, 1, 0))"),
])
def test_a_bad_plant_parameter_stops_the_node_with_one_line_naming_it(param: str, words: str) -> None:
    proc = subprocess.run([sys.executable, "-m", "spacecraft_sim", "--ros-args", "-p", param], capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert proc.returncode == 2 and proc.stderr.strip() == words, proc.stderr

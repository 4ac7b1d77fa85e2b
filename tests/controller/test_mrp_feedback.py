"""The MRP feedback controller's configuration (issue 34): every bad gain is refused with an error
that names the parameter and its value, on each road a gain comes in by (the config class, a
scenario file, the node's ROS parameters, a change during a run); and the law's defining
properties without Basilisk (its parity with Basilisk's ``mrpFeedback`` is
``test_mrp_feedback_basilisk.py``)."""

from __future__ import annotations

import copy
import dataclasses
import math
from typing import Any

import numpy as np
import pytest

from gnc_common.validation import ConfigError
from sappc.files import scenario_path
from sappc.scenario import read_scenario_mapping, scenario_from_mapping
from sappc_controller.core.common import ActuatorConfig
from sappc_controller.core.mrp_feedback import MrpFeedbackConfig, MrpFeedbackController, MrpFeedbackGains
from sappc_controller.core.packing import pack_params
from sappc_controller.params import config_from_parameters, config_parameters, parameters_from_config

J = ((4.0, 0.0, 0.0), (0.0, 4.0, 0.0), (0.0, 0.0, 4.0))
GOOD = {"K_Nm": 240.0, "P_Nms": 100.0, "Ki_per_kg_m2": 0.01, "integralLimit_Nms": 0.06}

BAD = [
    ("K_Nm", 0.0, r"gains\.K_Nm must be finite and > 0, got 0\.0"),
    ("K_Nm", -3.0, r"gains\.K_Nm must be finite and > 0, got -3\.0"),
    ("P_Nms", math.nan, r"gains\.P_Nms must be finite and > 0, got nan"),
    ("P_Nms", math.inf, r"gains\.P_Nms must be finite and > 0, got inf"),
    ("Ki_per_kg_m2", -1.0, r"gains\.Ki_per_kg_m2 must be finite and >= 0, got -1\.0 \(0 turns the integral term off"),
    ("integralLimit_Nms", 0.0, r"gains\.integralLimit_Nms must be finite and > 0, got 0\.0"),
    ("K_Nm", True, r"gains\.K_Nm must be a number, got True"),
    ("P_Nms", "fast", r"gains\.P_Nms must be a number, got 'fast'"),
]


@pytest.mark.parametrize(("name", "value", "message"), BAD)
def test_a_bad_gain_is_refused_naming_it_and_its_value(name: str, value: Any, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        MrpFeedbackGains(**{**GOOD, name: value})


@pytest.mark.parametrize(("name", "value", "message"), BAD[:6])
def test_a_scenario_with_a_bad_gain_names_the_key(name: str, value: float, message: str) -> None:
    raw = copy.deepcopy(read_scenario_mapping(scenario_path("paper_tracking")))
    raw["controllers"]["mrp_feedback"]["gains"][name] = value
    with pytest.raises(ConfigError, match=message):
        scenario_from_mapping(raw)


def test_a_scenario_with_an_unknown_gain_names_it() -> None:
    raw = copy.deepcopy(read_scenario_mapping(scenario_path("paper_tracking")))
    raw["controllers"]["mrp_feedback"]["gains"]["Kp"] = 1.0
    with pytest.raises(ConfigError, match=r"Kp"):
        scenario_from_mapping(raw)


def test_the_node_parameters_round_trip_and_refuse_a_negative_gain_by_name() -> None:
    config = MrpFeedbackConfig(inertia_kg_m2=J, gains=MrpFeedbackGains(**GOOD))
    flat = parameters_from_config("mrp_feedback", config)
    assert flat["mrp_feedback.gains.K_Nm"] == 240.0 and flat["controller"] == "mrp_feedback"
    values = {k: v for k, v in flat.items() if k != "controller"}
    assert config_from_parameters("mrp_feedback", values) == config
    with pytest.raises(ConfigError, match=r"parameter mrp_feedback\.gains\.Ki_per_kg_m2 = -1\.0 is outside its range"):
        config_from_parameters("mrp_feedback", {**values, "mrp_feedback.gains.Ki_per_kg_m2": -1.0})
    with pytest.raises(ConfigError, match=r"gains\.P_Nms must be finite and > 0, got 0\.0"):
        config_from_parameters("mrp_feedback", {**values, "mrp_feedback.gains.P_Nms": 0.0})


def test_the_declared_parameters_carry_their_units_and_may_change_during_a_run() -> None:
    declared = {p.name: p for p in config_parameters("mrp_feedback")}
    units = {name: declared[f"mrp_feedback.gains.{name}"].unit for name in GOOD}
    assert units == {"K_Nm": "N m", "P_Nms": "N m s", "Ki_per_kg_m2": "1/(kg m^2)", "integralLimit_Nms": "N m s"}
    assert all(declared[f"mrp_feedback.gains.{name}"].changeable for name in GOOD)


def test_reconfigure_takes_new_gains_from_the_next_step_and_keeps_the_integral() -> None:
    config = MrpFeedbackConfig(inertia_kg_m2=J, gains=MrpFeedbackGains(**GOOD), actuator=ActuatorConfig(max_torque_Nm=1e3, min_torque_Nm=0.0))
    controller = MrpFeedbackController(config)
    q_RN, zero = np.array([0.0, 0.0, 0.0, 1.0]), np.zeros(3)
    q_BN = np.array([0.0, 0.01, 0.0, math.sqrt(1.0 - 1e-4)])
    for k in range(3):
        z_before = controller.step(0.01 * k, 0.01, q_BN, zero, q_RN, zero, zero).z[1]
    controller.reconfigure(dataclasses.replace(config, gains=MrpFeedbackGains(**{**GOOD, "K_Nm": 480.0})))
    out = controller.step(0.03, 0.01, q_BN, zero, q_RN, zero, zero)
    sigma = 0.01 / (1.0 + q_BN[3])
    assert out.z[1] == z_before + 480.0 * 0.01 * sigma  # the integral carried over, the new K applied from this step


def test_per_run_gain_dispersions_are_refused_for_mrp_feedback() -> None:
    config = MrpFeedbackConfig(inertia_kg_m2=J, gains=MrpFeedbackGains(**GOOD))
    with pytest.raises(ConfigError, match=r"per-run gains \['K_q'\] are for SAPPC and TraPPC"):
        pack_params(config, 2, {"K_q": np.array([0.1, 0.2])})


def test_at_rest_on_the_reference_the_torque_is_zero_and_the_outputs_say_what_they_hold() -> None:
    """On the reference at its rate: no error term, and the gyroscopic term ``omega x J omega`` the law
    then commands is zero for this spherical ``J``.  The outputs: ``eps`` is ``sigma_BR``, no
    performance function (``rho = 0``, the target) and no constraint (an unbounded band)."""
    controller = MrpFeedbackController(MrpFeedbackConfig(inertia_kg_m2=J, gains=MrpFeedbackGains(**GOOD)))
    q = np.array([0.1, -0.2, 0.3, 0.9]) / np.linalg.norm([0.1, -0.2, 0.3, 0.9])
    w = np.array([0.01, -0.02, 0.005])
    out = controller.step(0.0, 0.01, q, w, q, w, np.zeros(3))
    assert np.all(np.abs(out.torque_cmd_B) <= 1e-16)  # J w x w rounds to ~1e-18, not 0 exactly
    assert np.array_equal(out.rho, np.zeros(3)) and np.all(out.band_lower == -np.inf) and np.all(out.band_upper == np.inf)
    q_err = np.array([0.0, 0.0, 0.1, math.sqrt(0.99)])
    out = controller.step(0.01, 0.01, q_err, np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]), np.zeros(3), np.zeros(3))
    assert out.eps[2] == pytest.approx(0.1 / (1.0 + math.sqrt(0.99)), rel=1e-15)  # sigma_BR
    assert out.torque_cmd_B[2] < 0.0  # it turns the body back towards the reference

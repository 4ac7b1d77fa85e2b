"""The mode node (``python -m sappc_modes``, issue 49): its parameters as ``sappc run`` writes them,
the ground's commands through ordinary parameters (a request taken at the next sample, once;
inhibits; bad values refused naming them), the mode in words on ``diagnostics``, bad settings
stopping the node naming the parameter.  Samples are fed to the node's step directly (the
graph's pairing by stamp is tested through ``sappc run``, tests/tools/graph/test_modes_graph.py)."""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import pytest
from rclpy.parameter import Parameter

from gnc_common.validation import ConfigError
from sappc.graph.launch import _mode_parameters
from sappc.scenario import load_scenario
from sappc_modes.core.modes import DETUMBLE, HOLD, R_NONE, R_REQUEST, S_MODE, S_REASON, SAFE, TRACK
from sappc_modes.node import INPUTS, ModeNode
from sappc_msgs_py import contract as c
from sappc_msgs_py import wire

from conftest import ROOT

QUICK_FLIGHT = ROOT / "tests" / "modes" / "quick_flight.yaml"
DT_NS = 10_000_000


def overrides(**extra: Any) -> list[Parameter]:
    """The node's parameters for quick_flight.yaml (as ``sappc run`` writes them), nothing waited for."""
    values = {k: v for k, v in _mode_parameters(load_scenario(QUICK_FLIGHT), "lockstep", "").items() if k not in ("counts_file", "expected_subscribers")}
    values["expected_subscribers"] = [f"{c.MODE_STATUS.name}=0", f"{c.ESTIMATOR_HEALTH.name}=0"]  # no subscriber here: publish at once
    values.update(extra)
    return [Parameter(k, value=v) for k, v in values.items()]


def sample(*, rate_rad_s: float = 0.001, sigma_rad: float = 1e-5, level: float = 0.0, estimate: bool = True) -> dict[str, tuple[float, ...]]:
    """One sample's inputs as the node's codecs read them: a slow gyro, a healthy estimate at the
    reference (identity), wheels at rest."""
    gyro = wire.gyro_values([rate_rad_s, 0.0, 0.0], 1e-12)
    q = (0.0, 0.0, 0.0, 1.0) if estimate else (np.nan,) * 4
    w = (0.0, 0.0, 0.0) if estimate else (np.nan,) * 3
    P = (np.eye(6) * sigma_rad ** 2).ravel() if estimate else np.full(36, np.nan)
    diag = [0.0] * len(c.ESTIMATOR_DIAGNOSTICS_LAYOUT)
    diag[c.ESTIMATOR_DIAGNOSTICS_LAYOUT.index("monitor_level")] = level
    return {c.SENSOR_GYRO.name: tuple(gyro), c.ESTIMATE_ATTITUDE.name: q, c.ESTIMATE_RATE.name: w,
            c.ESTIMATOR_COVARIANCE.name: (0.0, *P.tolist()), c.ESTIMATOR_DIAGNOSTICS.name: tuple(diag),
            c.REFERENCE_ATTITUDE.name: (0.0, 0.0, 0.0, 1.0), c.REFERENCE_RATE.name: (0.0, 0.0, 0.0),
            c.REFERENCE_ACCELERATION.name: (0.0, 0.0, 0.0), c.STATE_WHEEL_SPEED.name: (0.0, 0.0, 0.0, 0.0)}


def test_a_sample_has_every_input_the_node_subscribes(ros_context: Any) -> None:
    assert set(sample()) == {t.name for t in INPUTS}


def test_a_ground_request_is_taken_at_the_next_sample_once(ros_context: Any) -> None:
    """``request_mode`` (an ordinary parameter): the next sample goes to the mode requested, for the
    reason ``request``; the parameter then reads '' and the sample after takes no transition."""
    node = ModeNode(context=ros_context, parameter_overrides=overrides())
    try:
        assert node._state[S_MODE] == DETUMBLE
        node._step(0, sample())
        result = node.set_parameters([Parameter("request_mode", value="SAFE")])[0]
        assert result.successful, result.reason
        node._step(DT_NS, sample())
        assert (node._state[S_MODE], node._state[S_REASON]) == (SAFE, R_REQUEST)
        assert node.get_parameter("request_mode").value == ""
        assert node._health_msg.status[0].name == c.MODE_HEALTH_NAME and node._health_msg.status[0].level == bytes([2])  # SAFE: ERROR
        keys = {kv.key: kv.value for kv in node._health_msg.status[0].values}
        assert tuple(keys) == c.MODE_HEALTH_KEYS and keys["mode"] == "SAFE" and keys["reason"] == "request"
        node._step(2 * DT_NS, sample())
        assert node._state[S_MODE] == SAFE and node.transitions == 1
    finally:
        node.destroy_node()


def test_an_inhibit_stops_its_transition_and_a_request_still_goes_through(ros_context: Any) -> None:
    """quick_flight's HOLD goes to TRACK after 0.5 s of health; ``inhibit: [acquired]`` keeps it in
    HOLD; a request for TRACK still goes through."""
    node = ModeNode(context=ros_context, parameter_overrides=overrides(initial_mode="HOLD", inhibit=["acquired"]))
    try:
        for k in range(100):
            node._step(k * DT_NS, sample())
        assert node._state[S_MODE] == HOLD and node.transitions == 0
        assert node.set_parameters([Parameter("inhibit", value=[""])])[0].successful
        for k in range(100, 200):
            node._step(k * DT_NS, sample())
        assert node._state[S_MODE] == TRACK and node.transitions == 1
        assert node.set_parameters([Parameter("inhibit", value=["acquired"])])[0].successful
        assert node.set_parameters([Parameter("request_mode", value="HOLD")])[0].successful
        node._step(200 * DT_NS, sample())
        assert node._state[S_MODE] == HOLD
    finally:
        node.destroy_node()


@pytest.mark.parametrize("name, value, message", [
    ("request_mode", "SLEEP", "request_mode: 'SLEEP' is not a mode"),
    ("inhibit", ["tracked"], "inhibit: 'tracked' is not an automatic transition"),
])
def test_a_bad_ground_command_is_refused_naming_it(ros_context: Any, name: str, value: Any, message: str) -> None:
    node = ModeNode(context=ros_context, parameter_overrides=overrides())
    try:
        result = node.set_parameters([Parameter(name, value=value)])[0]
        assert not result.successful and message in result.reason
        node._step(0, sample())
        assert node._state[S_MODE] == DETUMBLE and node._state[S_REASON] == R_NONE
    finally:
        node.destroy_node()


def test_no_estimate_meets_no_condition(ros_context: Any) -> None:
    """The estimator's "no data" (NaN estimate, covariance): health and 1-sigma unknown, HOLD never
    goes to TRACK (the offline loop's rule)."""
    node = ModeNode(context=ros_context, parameter_overrides=overrides(initial_mode="HOLD"))
    try:
        for k in range(200):
            node._step(k * DT_NS, sample(estimate=False))
        assert node._state[S_MODE] == HOLD
    finally:
        node.destroy_node()


@pytest.mark.parametrize("name, value, message", [
    ("transitions", "{not json", "transitions must be a JSON mapping"),
    ("transitions", json.dumps({"detumbled_rate": 1.0}), "transitions"),
    ("requests_mode", ["SAFE", "HOLD"], "requests_at_s"),
    ("requests_mode", ["SLEEP"], "requests_mode: 'SLEEP' is not a mode"),
    ("wheel_max_speed_rad_s", [0.0, 1.0, 1.0, 1.0], "wheel_max_speed_rad_s"),
    ("mode", "realtime", "lockstep only"),
])
def test_a_bad_setting_stops_the_node_naming_it(ros_context: Any, name: str, value: Any, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        ModeNode(context=ros_context, parameter_overrides=overrides(**{name: value}))

"""The controller's input check (:mod:`gnc_common.input_check`, issue 25, 2.3): one
compiled verdict for the node's messages and the offline loop's samples, configurable plausibility
bounds, one-line errors naming the value and the bound, and the scenario's ``controller_node``
section reaching the offline loop (the graph's node gets the same values: ``sappc.graph.launch``)."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
import yaml

from gnc_common.validation import QUATERNION_NORM_TOL, ConfigError, InputError
from sappc.graph.launch import node_parameters
from sappc.offline import compiled_loop
from sappc.scenario import ControllerKind, scenario_from_mapping
from gnc_common.input_check import (
    DEFAULT_MAX_BODY_RATE_RAD_S,
    INPUT_IMPLAUSIBLE,
    INPUT_INVALID,
    INPUT_OK,
    ImplausibleInputError,
    InputBounds,
    check_input,
    input_verdict,
)
from sappc_msgs_py.contract import ANSWER_COMMANDED, ANSWER_WATCHDOG_ZERO

from conftest import SCENARIOS

#: Input slots (the step's order).
ATT, RATE, REF_ATT, REF_RATE, REF_ACC = range(5)
BOUNDS = InputBounds()
PACKED = BOUNDS.packed()


def _v(*x: float) -> np.ndarray:
    return np.array(x, dtype=np.float64)


@pytest.mark.parametrize(("slot", "value", "verdict"), [
    (RATE, _v(0.0, 0.0, 10.0), INPUT_OK),  # at the bound: accepted
    (RATE, _v(0.0, 0.0, np.nextafter(10.0, 11.0)), INPUT_IMPLAUSIBLE),  # one ulp above
    (RATE, _v(6.0, 8.0, 0.1), INPUT_IMPLAUSIBLE),  # the magnitude counts, not each component
    (RATE, _v(1e12, 0.0, 0.0), INPUT_IMPLAUSIBLE),  # the rate
    (RATE, _v(1e300, 1e300, 0.0), INPUT_IMPLAUSIBLE),  # a finite magnitude beyond the squares' range
    (RATE, _v(math.nan, 0.0, 0.0), INPUT_INVALID),
    (RATE, _v(0.0, -math.inf, 0.0), INPUT_INVALID),
    (REF_RATE, _v(0.0, 10.5, 0.0), INPUT_IMPLAUSIBLE),
    (REF_RATE, _v(0.0, 9.5, 0.0), INPUT_OK),
    (REF_ACC, _v(0.0, 0.0, -10.5), INPUT_IMPLAUSIBLE),
    (REF_ACC, _v(0.0, 0.0, -9.5), INPUT_OK),
    (ATT, _v(0.0, 0.0, 0.0, 1.0), INPUT_OK),
    (ATT, _v(0.0, 0.0, 0.0, 1.0 + 0.9 * QUATERNION_NORM_TOL), INPUT_OK),
    (ATT, _v(0.0, 0.0, 0.0, 1.0 + 1.1 * QUATERNION_NORM_TOL), INPUT_INVALID),
    (ATT, _v(0.0, 0.0, 0.0, 0.0), INPUT_INVALID),
    (REF_ATT, _v(math.nan, 0.0, 0.0, 1.0), INPUT_INVALID),
])
def test_each_input_gets_its_verdict_at_the_bounds(slot: int, value: np.ndarray, verdict: int) -> None:
    assert input_verdict(slot, value, PACKED) == verdict


def test_the_errors_are_one_line_naming_the_value_and_the_bound() -> None:
    with pytest.raises(ImplausibleInputError) as exc:
        check_input(RATE, "state/rate", _v(1e12, 0.0, 0.0), BOUNDS)
    text = str(exc.value)
    assert "\n" not in text and "1e+12" in text and "max_body_rate_rad_s = 10 rad/s" in text and "state/rate" in text
    with pytest.raises(ImplausibleInputError, match=r"max_reference_acceleration_rad_s2 = 10 rad/s\^2"):
        check_input(REF_ACC, "reference/acceleration", _v(0.0, 20.0, 0.0), BOUNDS)
    with pytest.raises(InputError, match="non-finite") as invalid:
        check_input(RATE, "state/rate", _v(math.nan, 0.0, 0.0), BOUNDS)
    assert not isinstance(invalid.value, ImplausibleInputError)
    with pytest.raises(InputError, match=r"state/attitude quaternion must be a unit quaternion .* norm 1\.1"):
        check_input(ATT, "state/attitude quaternion", _v(0.0, 0.0, 0.0, 1.1), BOUNDS)
    check_input(RATE, "state/rate", _v(0.0, 0.0, 1.0), BOUNDS)  # accepted: no error


def test_the_bounds_are_configurable_and_checked_naming_the_key() -> None:
    tight = InputBounds(max_body_rate_rad_s=0.5, max_attitude_norm_error=1e-9)
    assert input_verdict(RATE, _v(0.0, 0.6, 0.0), tight.packed()) == INPUT_IMPLAUSIBLE
    assert input_verdict(ATT, _v(0.0, 0.0, 0.0, 1.0 + 1e-8), tight.packed()) == INPUT_INVALID
    for kwargs, fragment in (({"max_body_rate_rad_s": 0.0}, "max_body_rate_rad_s must be finite and > 0"),
                             ({"max_reference_rate_rad_s": math.inf}, "max_reference_rate_rad_s must be finite"),
                             ({"max_reference_acceleration_rad_s2": True}, "max_reference_acceleration_rad_s2 must be a number"),
                             ({"max_attitude_norm_error": 1e-3}, "max_attitude_norm_error must be in (0, 1e-06]")):
        with pytest.raises(ConfigError, match=fragment.replace("(", r"\(").replace(")", r"\)")):
            InputBounds(**kwargs)  # type: ignore[arg-type]
    assert BOUNDS.max_body_rate_rad_s == DEFAULT_MAX_BODY_RATE_RAD_S


def _raw(**node: float) -> dict:  # type: ignore[type-arg]
    raw = yaml.safe_load((SCENARIOS / "paper_tracking.yaml").read_text())
    raw["duration_s"] = 1.0
    raw["faults"] = [{"kind": "sensor_bias", "start_s": 0.0, "end_s": 0.5, "rate_bias_rad_s": [1.0e3, 0.0, 0.0]}]
    if node:
        raw["controller_node"] = dict(node)
    return raw


def test_the_scenarios_controller_node_section_sets_the_bounds_of_both_paths() -> None:
    """A measured rate of 1e3 rad/s (a sensor bias on [0, 0.5) s): rejected by the default bound, so
    the controller starts at 0.5 s; with ``controller_node.max_body_rate_rad_s: 1.0e4`` it is
    accepted (and commanded: a saturated torque), and the graph's controller gets that value."""
    default = compiled_loop.run_single(compiled_loop.prepare(scenario_from_mapping(_raw())), 0, 1)
    np.testing.assert_array_equal(default.status[0, :50], ANSWER_WATCHDOG_ZERO)
    assert default.rejected_by_reason()["implausible"][0] == 50 and default.rejected_by_reason()["invalid"][0] == 0
    lifted = scenario_from_mapping(_raw(max_body_rate_rad_s=1.0e4))
    run = compiled_loop.run_single(compiled_loop.prepare(lifted), 0, 1)
    np.testing.assert_array_equal(run.status[0], ANSWER_COMMANDED)
    assert np.all(np.abs(run.out[0, 1:50, compiled_loop.O_TORQUE, 0]) == 0.5) and run.rejected_by_reason()["implausible"][0] == 0
    params = node_parameters(lifted, ControllerKind.SAPPC, realtime=False, paths={"scenario": "s", "bag": "b", "counts": "c", "params": "p"})
    controller = params["/controller"]["ros__parameters"]
    assert controller["max_body_rate_rad_s"] == 1.0e4 and controller["max_reference_rate_rad_s"] == 10.0


@pytest.mark.parametrize(("key", "value", "fragment"), [
    ("max_body_rate_rad_s", -1.0, "controller_node.max_body_rate_rad_s must be finite and > 0"),
    ("max_body_rate_rad_s", True, "controller_node.max_body_rate_rad_s"),
    ("max_attitude_norm_error", 0.01, "controller_node.max_attitude_norm_error must be in"),
    ("max_reference_rate_rad_s", "fast", "controller_node.max_reference_rate_rad_s"),
])
def test_bad_bounds_in_a_scenario_name_the_key(key: str, value: object, fragment: str) -> None:
    raw = copy.deepcopy(_raw())
    raw["controller_node"] = {key: value}
    with pytest.raises(ConfigError, match=fragment):
        scenario_from_mapping(raw)


def test_the_nodes_interpreted_verdict_is_the_compiled_one() -> None:
    """The node's :func:`input_verdict` runs the verdict kernels' source interpreted; the offline
    loop runs them compiled.  Same operations on the same doubles, so the same verdict on every
    value, including values one unit in the last place either side of each bound and non-finite
    ones (the compiled kernels called directly here)."""
    from gnc_common import input_check as ic

    rng = np.random.default_rng(11)
    tol, rate = PACKED[ic.B_NORM], PACKED[ic.B_RATE]
    quats = [rng.standard_normal(4) for _ in range(200)] + [q / np.linalg.norm(q) for q in rng.standard_normal((200, 4))]
    quats += [np.array([0.0, 0.0, 0.0, s]) for s in (1.0 + tol, np.nextafter(1.0 + tol, 2.0), 1.0 - tol, np.nextafter(1.0 - tol, 0.0),
                                                    math.nan, math.inf, 0.0)]
    for q in quats:
        assert input_verdict(ATT, q, PACKED) == ic.quaternion_verdict(q[0], q[1], q[2], q[3], tol), q
    vecs = [rng.standard_normal(3) * s for s in (1e-3, 1.0, 10.0, 1e300) for _ in range(50)]
    vecs += [np.array([b, 0.0, 0.0]) for b in (rate, np.nextafter(rate, 0.0), np.nextafter(rate, 1e9), math.nan, -math.inf, 0.0)]
    vecs += [np.array([rate, rate, rate]) / math.sqrt(3.0)]
    for v in vecs:
        assert input_verdict(RATE, v, PACKED) == ic.vector_verdict(v[0], v[1], v[2], rate), v

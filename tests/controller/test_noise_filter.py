"""The noise filters in the control path (issue 34, :class:`sappc_controller.core.common.NoiseFilterConfig`):
each against its analytic response through the controller's own step, their absence (bit for bit)
when off, and every bad cut-off refused naming the key and its value on each road a value comes
in by (the config class, a scenario file, the node's parameters)."""

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
from sappc_controller.core import kernels as K
from sappc_controller.core.common import ActuatorConfig, NoiseFilterConfig
from sappc_controller.core.mrp_feedback import MrpFeedbackConfig, MrpFeedbackController, MrpFeedbackGains
from sappc_controller.params import config_from_parameters, config_parameters, parameters_from_config

J = ((4.0, 0.0, 0.0), (0.0, 4.0, 0.0), (0.0, 0.0, 4.0))
#: MRP feedback without its integral: at rest on a fixed reference (``sigma = 0``, ``omega_r = 0``)
#: the law is ``u = -P omega``, linear in the rate it is given: a plant-free probe of both filters.
P_NMS = 100.0
GAINS = MrpFeedbackGains(K_Nm=1.0, P_Nms=P_NMS, integralLimit_Nms=1.0)
#: An actuator that neither saturates nor drops anything the probe commands.
WIDE = ActuatorConfig(max_torque_Nm=10.0, min_torque_Nm=0.0)
DT_S = 0.01
IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])
ZERO3 = np.zeros(3)


def _probe(noise_filter: NoiseFilterConfig, rates: np.ndarray, actuator: ActuatorConfig = WIDE) -> tuple[np.ndarray, np.ndarray, Any]:
    """The produced and the commanded torques (N, 3) of MRP feedback at rest on the identity, fed
    the body rates ``rates`` (N, 3), one sample every :data:`DT_S`; and the controller."""
    ctrl = MrpFeedbackController(MrpFeedbackConfig(inertia_kg_m2=J, gains=GAINS, actuator=actuator, noise_filter=noise_filter))
    produced, commanded = np.empty_like(rates), np.empty_like(rates)
    for k, w in enumerate(rates):
        out = ctrl.step(k * DT_S, DT_S, IDENTITY, np.ascontiguousarray(w), IDENTITY, ZERO3, ZERO3)
        produced[k], commanded[k] = out.torque_B, out.torque_cmd_B
    return produced, commanded, ctrl


def _step_rates(n: int, amplitude: np.ndarray) -> np.ndarray:
    """Zero at the first sample (the filters start there), ``amplitude`` from the second on."""
    rates = np.tile(amplitude, (n, 1))
    rates[0] = 0.0
    return rates


@pytest.mark.parametrize("which", ["rate_cutoff_hz", "torque_cutoff_hz"])
@pytest.mark.parametrize("cutoff_hz", [0.5, 3.0, 40.0])
def test_a_filter_answers_a_step_as_the_sampled_first_order_low_pass(which: str, cutoff_hz: float) -> None:
    """A step of the rate at sample 1 gives ``u[k] = -P w (1 - exp(-2 pi f_c k dt))``: the step
    response of ``dy/dt = 2 pi f_c (x - y)``, sampled exactly (relative 1e-13: the rounding of a
    recursion of k steps against one exponential)."""
    n = 400
    w = np.array([1e-3, -2e-3, 5e-4])
    produced, commanded, _ = _probe(NoiseFilterConfig(**{which: cutoff_hz}), _step_rates(n, w))
    k = np.arange(n)[:, None]
    expected = -P_NMS * w[None, :] * -np.expm1(-2.0 * np.pi * cutoff_hz * k * DT_S)
    np.testing.assert_allclose(produced, expected, rtol=1e-13, atol=1e-18)
    if which == "torque_cutoff_hz":  # the law's command is published unfiltered
        np.testing.assert_allclose(commanded[1:], np.tile(-P_NMS * w, (n - 1, 1)), rtol=1e-15)
    else:  # the rate filter is ahead of the law: the law commands what it produces
        np.testing.assert_array_equal(commanded, produced)


@pytest.mark.parametrize("which", ["rate_cutoff_hz", "torque_cutoff_hz"])
def test_a_filter_passes_a_sinusoid_with_the_gain_and_phase_of_its_transfer_function(which: str) -> None:
    """At steady state a sinusoid comes out scaled by ``H(e^{j w dt}) = g / (1 - (1 - g) e^{-j w dt})``,
    ``g = 1 - exp(-2 pi f_c dt)``, the transfer function of the recursion (1e-9: after 40 time
    constants the start transient is below 1e-17)."""
    f_c, f = 2.0, 5.0
    n = 3000
    t = np.arange(n) * DT_S
    w = np.outer(np.sin(2.0 * np.pi * f * t), [1e-3, 0.0, 0.0])
    produced, _, _ = _probe(NoiseFilterConfig(**{which: f_c}), w)
    g = -math.expm1(-2.0 * math.pi * f_c * DT_S)
    H = g / (1.0 - (1.0 - g) * np.exp(-1j * 2.0 * np.pi * f * DT_S))
    expected = -P_NMS * 1e-3 * np.imag(H * np.exp(1j * 2.0 * np.pi * f * t))
    np.testing.assert_allclose(produced[-500:, 0], expected[-500:], rtol=0, atol=1e-9 * P_NMS * 1e-3)


def test_the_torque_filter_holds_only_what_the_actuator_delivers() -> None:
    """A command far beyond the saturation is clipped before the filter: when the law's command
    comes back inside, the filter leaves from the limit (no wind-up); ``saturated`` is the law's."""
    act = ActuatorConfig(max_torque_Nm=0.1, min_torque_Nm=0.0)
    f_c = 1.0
    rates = np.zeros((300, 3))
    rates[1:100, 0] = -1.0  # the law asks +100 N m
    rates[100:, 0] = 1e-4  # then -0.01 N m
    ctrl = MrpFeedbackController(MrpFeedbackConfig(inertia_kg_m2=J, gains=GAINS, actuator=act, noise_filter=NoiseFilterConfig(torque_cutoff_hz=f_c)))
    produced, saturated = [], []
    for k, w in enumerate(rates):
        out = ctrl.step(k * DT_S, DT_S, IDENTITY, np.ascontiguousarray(w), IDENTITY, ZERO3, ZERO3)
        produced.append(out.torque_B[0])
        saturated.append(bool(out.saturated[0]))
    produced_a = np.array(produced)
    g = -math.expm1(-2.0 * math.pi * f_c * DT_S)
    assert np.all(produced_a[:100] <= 0.1) and saturated[1:100] == [True] * 99 and not any(saturated[100:])
    u99 = produced_a[99]
    k = np.arange(1, 201)
    expected = -0.01 + (u99 + 0.01) * (1.0 - g) ** k  # from where it was, towards the new command
    np.testing.assert_allclose(produced_a[100:], expected, rtol=1e-12)


def test_the_torque_filter_rises_to_the_limit_as_the_low_pass_of_the_saturated_command() -> None:
    """The filter's input is the saturated command: a command far beyond the limit from rest gives
    ``u_f[k] = max (1 - (1 - g)^k)``, the filter's step response to the limit, never the limit at
    once. A filter of the law's own command, saturated after (its state clamped to the limit: no
    wind-up either), would jump to the limit at the first sample, ``sat(g 100 N m)`` (issue 46: that
    mutant survived every controller test)."""
    act = ActuatorConfig(max_torque_Nm=0.1, min_torque_Nm=0.0)
    f_c = 1.0
    rates = np.zeros((60, 3))
    rates[1:, 0] = -1.0  # the law asks +100 N m on x from sample 1 on, 1000 times the limit
    produced, commanded, _ = _probe(NoiseFilterConfig(torque_cutoff_hz=f_c), rates, act)
    g = -math.expm1(-2.0 * math.pi * f_c * DT_S)
    k = np.arange(60)
    np.testing.assert_allclose(produced[:, 0], 0.1 * -np.expm1(np.log1p(-g) * k), rtol=1e-13, atol=1e-18)
    assert np.all(commanded[1:, 0] == pytest.approx(100.0)) and produced[1, 0] == pytest.approx(0.1 * g) and produced[1, 0] < 0.01


def test_the_deadband_acts_on_the_filtered_torque() -> None:
    """The minimum output drops the filtered torque while it is below the minimum, not the law's command."""
    act = ActuatorConfig(max_torque_Nm=1.0, min_torque_Nm=0.005)
    produced, commanded, _ = _probe(NoiseFilterConfig(torque_cutoff_hz=1.0), _step_rates(100, np.array([-1e-4, 0.0, 0.0])), act)
    g = -math.expm1(-2.0 * math.pi * 1.0 * DT_S)
    filtered = 0.01 * -np.expm1(np.log1p(-g) * np.arange(100))
    assert np.all(commanded[1:, 0] == pytest.approx(0.01))
    np.testing.assert_array_equal(produced[:, 0] == 0.0, filtered < 0.005)


def test_off_the_filters_leave_no_trace() -> None:
    """Cut-offs of 0 (the default): the same torques bit for bit as a config without the section,
    and the filters' state rows never written."""
    rng = np.random.default_rng(34)
    rates = rng.normal(0.0, 1e-3, (200, 3))
    a, _, ctrl = _probe(NoiseFilterConfig(), rates)
    b, _, _ = _probe(NoiseFilterConfig(rate_cutoff_hz=0.0, torque_cutoff_hz=0.0), rates)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(a, np.clip(-P_NMS * rates, -10.0, 10.0))
    assert not np.any(ctrl._state[:, K.S_RATE_F:K.S_TORQUE_F_ON + 1])


def test_a_new_run_starts_the_filters_afresh() -> None:
    """After reset, the filters start again at their first input (no memory of the last run)."""
    rates = _step_rates(50, np.array([1e-3, 0.0, 0.0]))
    ctrl = MrpFeedbackController(MrpFeedbackConfig(inertia_kg_m2=J, gains=GAINS, actuator=WIDE, noise_filter=NoiseFilterConfig(torque_cutoff_hz=1.0)))
    for k, w in enumerate(rates):
        ctrl.step(k * DT_S, DT_S, IDENTITY, np.ascontiguousarray(w), IDENTITY, ZERO3, ZERO3)
    ctrl.reset()
    first = ctrl.step(0.0, DT_S, IDENTITY, np.array([1e-3, 0.0, 0.0]), IDENTITY, ZERO3, ZERO3)
    assert first.torque_B[0] == -P_NMS * 1e-3


BAD = [
    ("rate_cutoff_hz", -1.0, r"noise_filter\.rate_cutoff_hz must be finite and >= 0, got -1\.0 \(0 turns the filter off\)"),
    ("torque_cutoff_hz", math.nan, r"noise_filter\.torque_cutoff_hz must be finite and >= 0, got nan"),
    ("torque_cutoff_hz", math.inf, r"noise_filter\.torque_cutoff_hz must be finite and >= 0, got inf"),
    ("rate_cutoff_hz", True, r"noise_filter\.rate_cutoff_hz must be a number, got True"),
    ("torque_cutoff_hz", "fast", r"noise_filter\.torque_cutoff_hz must be a number, got 'fast'"),
]


@pytest.mark.parametrize(("name", "value", "message"), BAD)
def test_a_bad_cutoff_is_refused_naming_it_and_its_value(name: str, value: Any, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        NoiseFilterConfig(**{name: value})


@pytest.mark.parametrize("controller", ["sappc", "trappc", "blfppc", "mrp_feedback"])
@pytest.mark.parametrize(("name", "value", "message"), BAD[:3])
def test_a_scenario_with_a_bad_cutoff_names_the_key(controller: str, name: str, value: float, message: str) -> None:
    raw = copy.deepcopy(read_scenario_mapping(scenario_path("paper_tracking")))
    raw["controllers"][controller]["noise_filter"] = {name: value}
    with pytest.raises(ConfigError, match=message):
        scenario_from_mapping(raw).controller_config(controller)


def test_a_scenario_with_an_unknown_filter_key_names_it() -> None:
    raw = copy.deepcopy(read_scenario_mapping(scenario_path("paper_tracking")))
    raw["controllers"]["sappc"]["noise_filter"] = {"cutoff_hz": 1.0}
    with pytest.raises(ConfigError, match=r"cutoff_hz"):
        scenario_from_mapping(raw).controller_config("sappc")


def test_the_node_parameters_carry_the_cutoffs_in_hz_round_trip_and_refuse_a_negative_one() -> None:
    config = MrpFeedbackConfig(inertia_kg_m2=J, gains=GAINS, noise_filter=NoiseFilterConfig(torque_cutoff_hz=2.5))
    flat = parameters_from_config("mrp_feedback", config)
    assert flat["mrp_feedback.noise_filter.torque_cutoff_hz"] == 2.5 and flat["mrp_feedback.noise_filter.rate_cutoff_hz"] == 0.0
    values = {k: v for k, v in flat.items() if k != "controller"}
    assert config_from_parameters("mrp_feedback", values) == config
    with pytest.raises(ConfigError, match=r"parameter mrp_feedback\.noise_filter\.rate_cutoff_hz = -1\.0 is outside its range"):
        config_from_parameters("mrp_feedback", {**values, "mrp_feedback.noise_filter.rate_cutoff_hz": -1.0})
    for kind in ("sappc", "trappc", "blfppc", "mrp_feedback"):
        declared = {p.name: p for p in config_parameters(kind)}
        for leaf in ("rate_cutoff_hz", "torque_cutoff_hz"):
            p = declared[f"{kind}.noise_filter.{leaf}"]
            assert p.unit == "Hz" and p.default == 0.0 and p.changeable


def test_reconfigure_changes_a_cutoff_from_the_next_step_and_keeps_the_filter_output() -> None:
    rates = _step_rates(20, np.array([1e-3, 0.0, 0.0]))
    config = MrpFeedbackConfig(inertia_kg_m2=J, gains=GAINS, actuator=WIDE, noise_filter=NoiseFilterConfig(torque_cutoff_hz=1.0))
    ctrl = MrpFeedbackController(config)
    last = 0.0
    for k, w in enumerate(rates):
        last = float(ctrl.step(k * DT_S, DT_S, IDENTITY, np.ascontiguousarray(w), IDENTITY, ZERO3, ZERO3).torque_B[0])
    ctrl.reconfigure(dataclasses.replace(config, noise_filter=NoiseFilterConfig(torque_cutoff_hz=4.0)))
    nxt = float(ctrl.step(20 * DT_S, DT_S, IDENTITY, np.array([1e-3, 0.0, 0.0]), IDENTITY, ZERO3, ZERO3).torque_B[0])
    g = -math.expm1(-2.0 * math.pi * 4.0 * DT_S)
    assert nxt == pytest.approx(last + g * (-P_NMS * 1e-3 - last), rel=1e-14)

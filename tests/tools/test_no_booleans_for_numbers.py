"""Booleans where numbers are expected are refused everywhere in a scenario (issue 25, 2.3).

YAML reads ``true`` as a boolean, and Python's ``bool`` is an ``int``: ``duration_s: true`` was a
1 s run.  Every number of every shipped scenario file (each section: plant, initial state,
reference, disturbances, faults, actuator and wheels, sensors, metrics, controller node, every
controller's parameters, the Monte Carlo and tuning sections) is replaced by ``true`` in turn, and
the file must be refused with a :class:`ConfigError` naming that key.  An independent walk of
the files finds the numbers; the validation is the project's (``scenario_from_mapping``, then the
``montecarlo`` and ``tuning`` sections' own parsers, as ``sappc montecarlo`` and ``sappc tune``
run them before any run)."""

from __future__ import annotations

import copy
from collections.abc import Iterator
from typing import Any

import pytest
import yaml

from gnc_common.validation import ConfigError
from sappc.montecarlo.config import campaign_config
from sappc.montecarlo.tuning import tuning_config
from sappc.scenario import read_scenario_mapping, scenario_from_mapping

from conftest import SCENARIOS

#: The shipped scenarios, and one with a number in every fault kind and the controller node's
#: section (no shipped file has faults).
FILES = sorted(SCENARIOS.glob("*.yaml"))
_EXTRA = yaml.safe_load((SCENARIOS / "paper_tracking.yaml").read_text())
_EXTRA["name"] = "every_fault"
_EXTRA["faults"] = [
    {"kind": "actuator_effectiveness", "start_s": 1.0, "end_s": 2.0, "effectiveness": [0.5, 0.5, 1.0]},
    {"kind": "actuator_bias", "start_s": 1.0, "bias_Nm": [0.01, 0.0, 0.0]},
    {"kind": "actuator_stuck", "start_s": 3.0, "end_s": 3.5},
    {"kind": "actuator_dropout", "start_s": 4.0, "end_s": 4.5},
    {"kind": "sensor_noise", "start_s": 0.0, "attitude_std_rad": 1e-5, "rate_std_rad_s": 1e-6, "seed": 3},
    {"kind": "sensor_bias", "start_s": 0.0, "attitude_bias_rad": [1e-4, 0.0, 0.0], "rate_bias_rad_s": [0.0, 1e-5, 0.0]},
    {"kind": "sensor_dropout", "start_s": 5.0, "end_s": 5.2},
    {"kind": "sensor_freeze", "start_s": 6.0, "end_s": 6.2},
    {"kind": "reference_dropout", "start_s": 7.0, "end_s": 7.2},
    {"kind": "delay", "path": "sensor", "samples": 2, "start_s": 8.0, "end_s": 8.5},
]
_EXTRA["controller_node"] = {"stale_timeout_s": 0.2, "max_attitude_norm_error": 1e-7, "max_body_rate_rad_s": 5.0,
                             "max_reference_rate_rad_s": 5.0, "max_reference_acceleration_rad_s2": 5.0}
#: Each file's own numbers (a file that ``extends`` another states only what it changes: the base's
#: numbers are the base file's cases), and the whole scenario it resolves to, which is validated.
OWN = {f.stem: yaml.safe_load(f.read_text()) for f in FILES} | {"every_fault": _EXTRA}
RAWS = {f.stem: read_scenario_mapping(f) for f in FILES} | {"every_fault": _EXTRA}


def _numbers(node: Any, path: tuple[Any, ...] = ()) -> Iterator[tuple[Any, ...]]:
    """Paths (keys and list indices) to every int or float leaf (not a bool) of a parsed YAML tree."""
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _numbers(v, (*path, k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _numbers(v, (*path, i))
    elif isinstance(node, (int, float)) and not isinstance(node, bool):
        yield path


def _validate(raw: dict[str, Any]) -> None:
    scenario = scenario_from_mapping(raw)
    if raw.get("montecarlo") is not None:
        campaign_config(scenario)
    if raw.get("tuning") is not None:
        tuning_config(scenario)


def _set(raw: dict[str, Any], path: tuple[Any, ...], value: Any) -> None:
    node: Any = raw
    for p in path[:-1]:
        node = node[p]
    node[path[-1]] = value


CASES = [(name, p) for name, raw in OWN.items() for p in _numbers(raw)]


def test_every_file_validates_as_written_and_has_numbers_in_every_section() -> None:
    sections = set()
    for raw in RAWS.values():
        _validate(copy.deepcopy(raw))
        sections |= {p[0] for p in _numbers(raw)}
    assert {"duration_s", "control_period_s", "plant", "initial_state", "reference", "disturbances", "faults", "actuator", "sensors",
            "metrics", "controller_node", "controllers", "montecarlo", "tuning"} <= sections


@pytest.mark.parametrize(("name", "key"), CASES, ids=[f"{n}:{'.'.join(map(str, p))}" for n, p in CASES])
def test_true_in_place_of_a_number_is_refused_naming_the_key(name: str, key: tuple[Any, ...]) -> None:
    raw = copy.deepcopy(RAWS[name])
    _set(raw, key, True)
    with pytest.raises(ConfigError) as exc:
        _validate(raw)
    name = next(str(k) for k in reversed(key) if isinstance(k, str))  # the nearest mapping key
    assert name in str(exc.value) and "\n" not in str(exc.value), str(exc.value)

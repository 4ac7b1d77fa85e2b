"""ROS parameters <-> the controllers' validated config dataclasses (no rclpy here).

A controller's parameters are its config's fields flattened with dots under the controller's
name, plus the plant-level ones shared by all kinds::

    controller: sappc               # sappc | trappc | blfppc | mrp_feedback
    inertia_kg_m2: [4.0, 0, 0, 0, 4.0, 0, 0, 0, 4.0]   # row major, the known J
    actuator.max_torque_Nm: 0.5
    actuator.min_torque_Nm: 0.005
    sappc.rpf.rho_e0: 0.4
    sappc.gains.K_q: 0.3
    ...

In a ROS YAML file the dotted names are nested mappings under ``ros__parameters``
(``config/controller_sappc.yaml``).  :func:`config_from_parameters` turns the flat values into
the config, validated by the same code as a scenario file, so every error names the parameter.
"""

from __future__ import annotations

import dataclasses
import math
import typing
from collections.abc import Callable
from typing import Any

import numpy as np

from gnc_common.validation import ConfigError, check_positive, from_mapping, safe_load_yaml
from sappc_msgs_py.parameters import REQUIRED, Param, field_docs, unit_of
from sappc_msgs_py.inputs import DEFAULT_MAX_STAMP_AHEAD_S, WATCHDOG_RANGE_S, check_watchdog_seconds

from sappc_controller.core.base import AttitudeController
from sappc_controller.core.blfppc import BlfppcConfig, BlfppcController
from sappc_controller.core.common import ActuatorConfig, NoiseFilterConfig
from sappc_controller.core.mrp_feedback import MrpFeedbackConfig, MrpFeedbackController
from sappc_controller.core.sappc import SappcConfig, SappcController
from sappc_controller.core.trappc import TrappcConfig, TrappcController

__all__ = [
    "PARAMETER_MAX",
    "parameter_range",
    "DEFAULT_LOCKSTEP_GRACE_S",
    "DEFAULT_MAX_STAMP_AHEAD_S",
    "DEFAULT_STALE_TIMEOUT_S",
    "WATCHDOG_RANGE_S",
    "check_watchdog_seconds",
    "CONFIG_CLASSES",
    "CONTROLLER_CLASSES",
    "config_from_parameters",
    "config_parameter_names",
    "config_parameters",
    "controller_from_parameters_file",
    "parameters_from_config",
    "parameters_from_yaml",
    "runtime_parameter_names",
    "unflatten",
]

#: The config dataclass of each controller kind.
CONFIG_CLASSES: dict[str, type] = {"sappc": SappcConfig, "trappc": TrappcConfig, "blfppc": BlfppcConfig, "mrp_feedback": MrpFeedbackConfig}
#: The controller class of each kind, built from a config of that kind (SAPPC also takes
#: ``on_infeasible``).  Typed by what they build: ``type[AttitudeController]`` would check the
#: calls against the base class's ``(inertia_kg_m2, actuator)`` constructor, which no caller uses.
CONTROLLER_CLASSES: dict[str, Callable[..., AttitudeController]] = {"sappc": SappcController, "trappc": TrappcController, "blfppc": BlfppcController,
                                                                    "mrp_feedback": MrpFeedbackController}

#: The node's ``control_period_s`` when a parameters file does not set it [s] (100 Hz, the paper's).
DEFAULT_CONTROL_PERIOD_S = 0.01
#: Default ``stale_timeout_s`` [s]: zero torque when no valid state is newer than this at a
#: control instant (ten samples at the default period: a short outage is ridden through).
DEFAULT_STALE_TIMEOUT_S = 0.1
#: Default ``lockstep_grace_s`` [s]: how long a lockstep tick waits for an input that never arrives
#: (a message lost on the network) before it is answered; half the plant's default
#: ``lockstep_timeout_s`` (2 s), so the controller answers first, and 100 times a control period,
#: so a loaded machine's latency is not taken for a loss.
DEFAULT_LOCKSTEP_GRACE_S = 1.0
# DEFAULT_MAX_STAMP_AHEAD_S, WATCHDOG_RANGE_S and check_watchdog_seconds: the input checks every
# consumer of the loop's samples shares (sappc_msgs_py.inputs), re-exported here.

#: Config fields that are plant-level parameters, not under the controller's name.
_SHARED = ("inertia_kg_m2", "actuator")


def _is_dataclass_type(hint: Any) -> type | None:
    options = [h for h in typing.get_args(hint) if h is not type(None)] or [hint]
    return next((h for h in options if isinstance(h, type) and dataclasses.is_dataclass(h)), None)


def _leaf_fields(cls: type, prefix: str) -> list[tuple[str, dataclasses.Field[Any], type, Any]]:
    """(dotted name, field, the dataclass that declares it, its type hint) of every leaf field of
    config class ``cls``: the one walk of the nested configs behind :func:`_leaves` and :func:`_leaf_docs`."""
    hints = typing.get_type_hints(cls)
    out: list[tuple[str, dataclasses.Field[Any], type, Any]] = []
    for f in dataclasses.fields(cls):
        sub = _is_dataclass_type(hints[f.name])
        name = f"{prefix}.{f.name}" if prefix else f.name
        if sub is not None:
            out.extend(_leaf_fields(sub, name))
        else:
            out.append((name, f, cls, hints[f.name]))
    return out


def _leaves(cls: type, prefix: str) -> list[tuple[str, Any]]:
    """(dotted name, default or MISSING) of every leaf field of config class ``cls``."""
    return [(name, f.default) for name, f, _, _ in _leaf_fields(cls, prefix)]


def config_parameter_names(kind: str) -> list[tuple[str, Any]]:
    """Every parameter of controller ``kind``: (name, default or ``dataclasses.MISSING``)."""
    cls = _config_class(kind)
    names = [(n, d) for n, d in _leaves(cls, kind) if n.split(".")[1] not in _SHARED]
    return [("inertia_kg_m2", dataclasses.MISSING)] + [(f"actuator.{n}", d) for n, d in _leaves(ActuatorConfig, "")] + names


def _leaf_docs(cls: type, prefix: str) -> dict[str, tuple[str, str]]:
    """(description, ROS type) of every leaf field of config class ``cls``, by dotted name, from
    the ``Attributes`` sections of the dataclasses' docstrings and their type hints."""
    out: dict[str, tuple[str, str]] = {}
    docs: dict[type, dict[str, str]] = {}
    for name, f, owner, hint in _leaf_fields(cls, prefix):
        scalar = [h for h in typing.get_args(hint) if h is not type(None)] or [hint]
        described = docs.setdefault(owner, field_docs(owner))
        out[name] = (described.get(f.name, ""), "integer" if scalar[0] is int else "double")
    return out


def runtime_parameter_names(kind: str) -> set[str]:
    """The parameters of controller ``kind`` that may change during a run (applied at the next
    step by :meth:`~sappc_controller.core.base.AttitudeController.reconfigure`): the gains of
    :data:`~sappc_controller.core.base.AttitudeController.RUNTIME_GAINS`, the actuator limits and
    the noise filters' cut-offs."""
    return ({f"{kind}.gains.{g}" for g in AttitudeController.RUNTIME_GAINS} | {f"actuator.{n}" for n, _ in _leaves(ActuatorConfig, "")}
            | {f"{kind}.noise_filter.{n}" for n, _ in _leaves(NoiseFilterConfig, "")})


def config_parameters(kind: str) -> tuple[Param, ...]:
    """The declared parameters of controller ``kind`` (:func:`config_parameter_names`), each with
    its type, unit, range and description from the config dataclasses: what the node declares
    and what ``python -m sappc_controller --help`` lists.  Every one is writable at run time;
    the node applies the gains of :data:`~sappc_controller.core.base.AttitudeController.RUNTIME_GAINS`
    and the actuator limits, and refuses a change of any other with the reason."""
    docs = {**_leaf_docs(_config_class(kind), kind), **{f"actuator.{n}": d for n, d in _leaf_docs(ActuatorConfig, "").items()}}
    runtime = runtime_parameter_names(kind)
    out = []
    for name, default in config_parameter_names(kind):
        if name == "inertia_kg_m2":
            description, ros_type = "the known inertia J the law uses, 9 values row major (symmetric positive definite) [kg m^2]", "double[]"
        else:
            description, ros_type = docs[name]
        out.append(Param(name, REQUIRED if default is dataclasses.MISSING else default, " ".join(description.split()) or name,
                         unit_of(name, description), range=parameter_range(name, default), type=ros_type, read_only=False,
                         dynamic_typing=True, changeable=name in runtime))
    return tuple(out)


def _config_class(kind: str) -> type:
    if kind not in CONFIG_CLASSES:
        raise ConfigError(f"controller must be one of {sorted(CONFIG_CLASSES)}, got {kind!r}")
    return CONFIG_CLASSES[kind]


def flatten(tree: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """``{"a": {"b": 1}}`` -> ``{"a.b": 1}`` (the inverse of :func:`unflatten`; lists are values)."""
    out: dict[str, Any] = {}
    for key, value in tree.items():
        name = f"{prefix}.{key}" if prefix else str(key)
        if isinstance(value, dict):
            out.update(flatten(value, name))
        else:
            out[name] = value
    return out


def parameters_from_yaml(text: str, node: str = "controller", *, source: str = "<parameters>") -> dict[str, Any]:
    """The flat parameters of node ``node`` in a ROS parameters YAML text, as ``--params-file``
    applies them: the ``/**`` entry first, then ``node`` or ``/node`` over it.

    Raises
    ------
    ConfigError
        If the text is not YAML or has no ``ros__parameters`` for the node.
    """
    data = safe_load_yaml(text, source=source)
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: a ROS parameters file is a mapping of node names to ros__parameters")
    values: dict[str, Any] = {}
    found = False
    for key in ("/**", node, f"/{node}"):
        entry = data.get(key)
        if isinstance(entry, dict) and isinstance(entry.get("ros__parameters"), dict):
            values.update(flatten(entry["ros__parameters"]))
            found = True
    if not found:
        raise ConfigError(f"{source}: no ros__parameters for node {node!r} (keys: {sorted(map(str, data))})")
    return values


def controller_from_parameters_file(text: str, node: str = "controller", *, source: str = "<parameters>") -> tuple[str, Any, float]:
    """(kind, validated config, control period [s]) of the controller node configured by a ROS
    parameters file (``config/controller_*.yaml``, or the ``params.yaml`` of a run).

    Parameters of the node that are not the controller's config (``mode``, timeouts...) are
    ignored; a parameter under the controller's name or ``actuator.`` that the config does not
    know is an error, as the node would refuse it.
    """
    values = parameters_from_yaml(text, node, source=source)
    kind = str(values.get("controller", "sappc"))
    names = [n for n, _ in config_parameter_names(kind)]
    unknown = sorted(n for n in values if n.startswith((f"{kind}.", "actuator.")) and n not in names)
    if unknown:
        raise ConfigError(f"{source}: unknown parameter {unknown[0]!r} for the {kind} controller")
    try:
        config = config_from_parameters(kind, {n: values.get(n) for n in names})
        period = check_positive("control_period_s", values.get("control_period_s", DEFAULT_CONTROL_PERIOD_S))
    except ConfigError as exc:
        raise ConfigError(f"{source}: {exc}") from None
    return kind, config, period


def unflatten(values: dict[str, Any]) -> dict[str, Any]:
    """``{"a.b": 1}`` -> ``{"a": {"b": 1}}``."""
    out: dict[str, Any] = {}
    for name, value in values.items():
        node = out
        *parents, leaf = name.split(".")
        for p in parents:
            node = node.setdefault(p, {})
        node[leaf] = value
    return out


#: Largest value of any scalar controller parameter (gains [1/s, N m, rad/s], times [s], bounds):
#: a gain of 1e6 1/s moves the virtual control by a million times the error each second, far
#: beyond any actuator at any control rate the nodes run (a period >= 1e-4 s); a larger value is a
#: typo (``1e300`` once was accepted).  Every scalar parameter of the four configs is >= 0
#: (MRP feedback's gains [N m, N m s, 1/(kg m^2)] included: ``Ki = 0`` is its "off").
PARAMETER_MAX = 1e6
#: Range of the integer parameters (BLFPPC's odd/even exponents of its performance function).
INTEGER_PARAMETER_RANGE = (1, 99)


def parameter_range(name: str, default: Any) -> tuple[float, float] | tuple[int, int] | None:
    """The range of scalar parameter ``name`` (for its ROS descriptor and the start-up check):
    integers :data:`INTEGER_PARAMETER_RANGE`, floats ``[0, PARAMETER_MAX]``; ``None`` for arrays."""
    if name == "inertia_kg_m2" or name.rsplit(".", 1)[-1] in UNSET_NAN:  # (NaN: "none"; the config checks a number given)
        return None
    if isinstance(default, int) and not isinstance(default, bool):
        return INTEGER_PARAMETER_RANGE
    return (0.0, PARAMETER_MAX)


def check_parameter_ranges(values: dict[str, Any], names: list[tuple[str, Any]]) -> None:
    """Raise :class:`ConfigError` naming the first parameter outside :func:`parameter_range`."""
    for name, default in names:
        value = values.get(name)
        bounds = parameter_range(name, default)
        if bounds is None or value is None or isinstance(value, bool) or not isinstance(value, (int, float)):
            continue
        lo, hi = bounds
        if not lo <= value <= hi:
            raise ConfigError(f"parameter {name} = {value!r} is outside its range [{lo:g}, {hi:g}]")


def config_from_parameters(kind: str, values: dict[str, Any]) -> Any:
    """The validated config of controller ``kind`` from flat parameter values (``None``: not set).

    Raises
    ------
    ConfigError
        Naming the parameter (``sappc.rpf.l``, ``inertia_kg_m2``...) that is missing or invalid.
    """
    cls = _config_class(kind)
    # NaN: a setting given as "none" (UNSET_NAN: rpf.rho_e0 from the initial error), kept as None
    unset = [k for k, v in values.items() if isinstance(v, float) and math.isnan(v)]
    given = {k: (list(v) if isinstance(v, (tuple, np.ndarray)) else v) for k, v in values.items() if v is not None and k not in unset}
    check_parameter_ranges(given, config_parameter_names(kind))
    given.update(dict.fromkeys(unset))
    J = given.pop("inertia_kg_m2", None)
    if J is None:
        raise ConfigError("missing parameter inertia_kg_m2 (9 values, row major)")
    if len(J) != 9:
        raise ConfigError(f"inertia_kg_m2 must have 9 values (row major 3x3), got {len(J)}")
    tree = unflatten(given)
    actuator = from_mapping(ActuatorConfig, tree.pop("actuator", {}), "actuator")
    data = tree.pop(kind, {})
    for key in _SHARED:
        if key in data:
            raise ConfigError(f"{kind}.{key} is a plant-level parameter: use {key}")
    data["inertia_kg_m2"] = [J[0:3], J[3:6], J[6:9]]
    config = from_mapping(cls, data, kind)
    return dataclasses.replace(config, actuator=actuator)


#: The settings whose ``None`` has a meaning (``rpf.rho_e0``: the RPF starts at each component's
#: initial error, the paper's Monte Carlo form): as a ROS parameter, which cannot be null, NaN.
UNSET_NAN = ("rho_e0",)


def parameters_from_config(kind: str, config: Any) -> dict[str, Any]:
    """Flat parameter values of a config (the inverse of :func:`config_from_parameters`)."""
    flat: dict[str, Any] = {"controller": kind}

    def walk(obj: Any, prefix: str) -> None:
        for f in dataclasses.fields(obj):
            value = getattr(obj, f.name)
            name = f"{prefix}.{f.name}" if prefix else f.name
            if dataclasses.is_dataclass(value):
                walk(value, name)
            elif value is not None:
                flat[name] = np.asarray(value, dtype=np.float64).ravel().tolist() if isinstance(value, (tuple, list)) else value
            elif f.name in UNSET_NAN:  # a ROS parameter cannot be null: NaN says "none" (config_from_parameters)
                flat[name] = math.nan

    walk(config, kind)
    flat["inertia_kg_m2"] = flat.pop(f"{kind}.inertia_kg_m2")
    for key in [k for k in flat if k.startswith(f"{kind}.actuator.")]:
        flat[key.replace(f"{kind}.actuator.", "actuator.")] = flat.pop(key)
    return flat

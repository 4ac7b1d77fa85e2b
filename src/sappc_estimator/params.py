"""ROS parameters <-> the estimator's validated config (:class:`~sappc_estimator.core.config.MekfConfig`); no rclpy here.

The filter's parameters are the config's fields, one parameter each, under the same names; a
per-axis quantity is 3 doubles ``[x, y, z]`` (one number is taken for all three axes)::

    tracker_noise_rad: [9.7e-6, 9.7e-6, 7.3e-5]          # required: the star tracker's 1-sigma
    gyro_angle_random_walk_rad_sqrt_s: [1.45e-6, 1.45e-6, 1.45e-6]
    gyro_bias_random_walk_rad_s_sqrt_s: [8.1e-10, 8.1e-10, 8.1e-10]
    initial_q_BN: []                                     # []: start from the first tracker sample
    gate_false_alarm: 1.0e-4
    ...

:func:`config_from_parameters` turns the values into the config, validated by the config's own
checks (the same as a scenario's ``estimator`` section), so every error names the parameter and
its value; :func:`parameters_from_config` is its inverse (``sappc params --estimator``).
"""

from __future__ import annotations

import dataclasses
import re
from typing import Any

import numpy as np

from gnc_common.validation import ConfigError, InputError
from sappc_msgs_py.parameters import REQUIRED, Param, field_docs

from sappc_estimator.core.config import MekfConfig

__all__ = ["DEFAULT_CONTROL_PERIOD_S", "FILTER_PARAMETERS", "config_from_parameters", "parameters_from_config"]

#: The node's ``control_period_s`` when not set [s] (100 Hz, the paper's): in real time the
#: deadline of a step (a step later than this is counted late); lockstep takes its time from the stamps.
DEFAULT_CONTROL_PERIOD_S = 0.01

#: Unit and ROS type of each config field (the config's docstring says what each is).
_FIELDS: dict[str, tuple[str, str]] = {
    "tracker_noise_rad": ("rad", "double[]"),
    "gyro_angle_random_walk_rad_sqrt_s": ("rad/sqrt(s)", "double[]"),
    "gyro_bias_random_walk_rad_s_sqrt_s": ("rad/s/sqrt(s)", "double[]"),
    "initial_bias_rad_s": ("rad/s", "double[]"),
    "initial_bias_sigma_rad_s": ("rad/s", "double[]"),
    "initial_q_BN": ("", "double[]"),
    "initial_attitude_sigma_rad": ("rad", "double[]"),
    "gate_false_alarm": ("", "double"),
    "max_consecutive_rejections": ("", "integer"),
    "max_body_rate_rad_s": ("rad/s", "double"),
    "max_attitude_norm_error": ("", "double"),
    "monitor_window_samples": ("", "integer"),
    "monitor_warn_probability": ("", "double"),
    "monitor_error_probability": ("", "double"),
    "monitor_mean_error_probability": ("", "double"),
    "monitor_persistence": ("", "integer"),
    "monitor_drift_shift_sigma": ("", "double"),
    "monitor_drift_false_alarm": ("", "double"),
    "bias_recovery_sigma_rad_s": ("rad/s", "double[]"),
    "tracker_stale_s": ("s", "double"),
}
#: The config's optional fields whose ``None`` is an empty array parameter.
_EMPTY_IS_NONE = ("initial_q_BN", "initial_attitude_sigma_rad", "bias_recovery_sigma_rad_s")
#: What the node checks for each (the config's rule, in words, for ``--help``).
_CHECKS = {
    "tracker_noise_rad": "> 0 per axis",
    "gyro_angle_random_walk_rad_sqrt_s": ">= 0 per axis",
    "gyro_bias_random_walk_rad_s_sqrt_s": ">= 0 per axis",
    "initial_bias_sigma_rad_s": "> 0 per axis",
    "initial_q_BN": "[] or a unit quaternion (x, y, z, w)",
    "initial_attitude_sigma_rad": "[] or > 0 per axis; given with initial_q_BN",
    "gate_false_alarm": "in [0, 1)",
    "max_consecutive_rejections": "an integer >= 1",
    "max_body_rate_rad_s": "> 0",
    "max_attitude_norm_error": "in (0, 1e-6]",
    "monitor_window_samples": "an integer in [1, 100]",
    "monitor_warn_probability": "in (0, 1)",
    "monitor_error_probability": "in [monitor_warn_probability, 1)",
    "monitor_mean_error_probability": "in [monitor_warn_probability, 1)",
    "monitor_persistence": "an integer in [1, monitor_window_samples]",
    "monitor_drift_shift_sigma": "> 0",
    "monitor_drift_false_alarm": "in [0, 1) (0: no drift test)",
    "bias_recovery_sigma_rad_s": "[] or >= 0 per axis",
    "tracker_stale_s": "> 0 (inf: never)",
}


def _default(f: dataclasses.Field[Any]) -> Any:
    """A config field's default as a parameter value: 3 doubles for a per-axis number, ``[]`` for None."""
    if f.default is dataclasses.MISSING:
        return REQUIRED
    if f.default is None:
        return []
    if _FIELDS[f.name][1] == "double[]":
        return [float(f.default)] * 3
    return f.default


def _filter_parameters() -> tuple[Param, ...]:
    docs = field_docs(MekfConfig)
    # dynamic typing: [0, 0, 0] in a YAML file (integers) or one number for three axes is accepted;
    # the config's checks say what is wrong with a value, naming it
    def describe(name: str) -> str:  # the config's None is the parameter's []: the help names the value one writes
        text = " ".join(docs[name].split())
        return re.sub(r"\bNone\b", "[]", text) if name in _EMPTY_IS_NONE else text

    return tuple(Param(f.name, _default(f), describe(f.name), _FIELDS[f.name][0], check=_CHECKS.get(f.name, ""),
                       type=_FIELDS[f.name][1], dynamic_typing=True) for f in dataclasses.fields(MekfConfig))


#: The filter's parameters, one per :class:`~sappc_estimator.core.config.MekfConfig` field, in its
#: order (what the node declares and ``python -m sappc_estimator --help`` lists).
FILTER_PARAMETERS = _filter_parameters()


def _value(name: str, value: Any) -> Any:
    """A parameter value as the config takes it: a list as a tuple, an empty array as ``None``
    (for the optional fields), bytes (rclpy's type of an empty array default) as an empty array."""
    if isinstance(value, (bytes, bytearray)):
        value = list(value)
    if isinstance(value, (list, tuple, np.ndarray)):
        items = list(value)
        if not items and name in _EMPTY_IS_NONE:
            return None
        return tuple(items)
    return value


def config_from_parameters(values: dict[str, Any]) -> MekfConfig:
    """The validated filter config from parameter values by name (a name missing or ``None``: its default).

    Raises
    ------
    ConfigError
        Naming the parameter and its value (``tracker_noise_rad must be > 0, got (...)``), for a
        missing required one, or one the config does not know.
    """
    known = {p.name for p in FILTER_PARAMETERS}
    unknown = sorted(set(values) - known)
    if unknown:
        raise ConfigError(f"unknown estimator parameter {unknown[0]!r}; known: {sorted(known)}")
    given = {name: _value(name, v) for name, v in values.items() if v is not None}
    if "tracker_noise_rad" not in given:
        raise ConfigError("missing parameter tracker_noise_rad (the star tracker's 1-sigma per body axis [rad], 3 values)")
    try:
        return MekfConfig(**given)
    except InputError as exc:  # a quaternion check's words ("initial_q_BN must be numeric, got 'x'"): a parameter's error
        raise ConfigError(str(exc)) from None


def parameters_from_config(config: MekfConfig) -> dict[str, Any]:
    """Parameter values of a config (the inverse of :func:`config_from_parameters`): per-axis
    quantities as 3 doubles, ``None`` as ``[]``."""
    out: dict[str, Any] = {}
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        if value is None:
            out[f.name] = []
        elif _FIELDS[f.name][1] == "double[]":
            v = np.asarray(value, dtype=np.float64)
            out[f.name] = (np.full(3, float(v)) if v.ndim == 0 else v).tolist()
        else:
            out[f.name] = value
    return out

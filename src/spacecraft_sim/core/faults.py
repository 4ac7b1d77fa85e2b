"""Actuator, sensor and link faults, applied to samples travelling between plant and controller.

The injector node relays the controller's torque to the plant and the plant's state to the
controller through these models (README, "Faults"); they are pure numpy, so any other
caller gets the same faulty samples.  Each fault acts in a window ``start_s <= t < end_s``
(``end_s`` omitted: until the end), compared with
:data:`~spacecraft_sim.core.disturbance.TIME_TOLERANCE_S`, where ``t`` is the sample's stamp.

Kinds (a scenario's ``faults:`` list, ``{kind: ..., <fields>}``):

=========================  =====================================================================
``actuator_effectiveness``  ``effectiveness`` (3 values in [0, 1]): applied torque = e * command
``actuator_bias``           ``bias_Nm`` (3): applied torque = command + bias
``actuator_stuck``          the torque commanded at the window's first sample is held
``sensor_noise``            ``attitude_std_rad``, ``rate_std_rad_s``, ``seed``: white noise, a
                            small rotation on the attitude and an additive rate error, drawn
                            from ``default_rng([seed, stamp_ns])`` (a pure function of the
                            sample, whatever order samples are asked in)
``sensor_bias``             ``attitude_bias_rad`` (a rotation vector), ``rate_bias_rad_s``
``sensor_dropout``          samples are not delivered
``sensor_freeze``           the sample at the window's start is delivered again and again
``delay``                   ``path`` (``sensor`` or ``actuator``), ``samples`` n: the content of
                            the sample n steps earlier is delivered with the current stamp
                            (the first n samples of the window deliver the window's first one)
=========================  =====================================================================

Sensor faults compose in list order; the attitude stays a unit quaternion.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from enum import Enum
from typing import Any

import numpy as np
from numpy.typing import NDArray

from gnc_common.attitude import quat_multiply, quat_normalize, rotation_vector_to_quaternion
from spacecraft_sim.core import kernels
from spacecraft_sim.core.disturbance import TIME_TOLERANCE_S
from gnc_common.validation import ConfigError, as_finite_array, check_positive, from_kind_list

__all__ = ["FAULT_KINDS", "FaultPath", "FaultSchedule", "faults_from_list", "noisy_measurement"]

Array = NDArray[np.float64]


def _window_check(f: Any) -> None:
    check_positive(f"{type(f).__name__}.start_s", f.start_s, allow_zero=True)
    if f.end_s is not None and f.end_s <= f.start_s:
        raise ConfigError(f"end_s ({f.end_s!r}) must be after start_s ({f.start_s!r})")


class _Windowed:
    start_s: float
    end_s: float | None

    def active(self, t: float) -> bool:
        end = np.inf if self.end_s is None else self.end_s
        return bool(self.start_s - TIME_TOLERANCE_S <= t < end - TIME_TOLERANCE_S)

    def events(self) -> list[tuple[float, float]]:
        return [(self.start_s, np.inf if self.end_s is None else self.end_s)]


@dataclass(frozen=True)
class ActuatorEffectiveness(_Windowed):
    effectiveness: tuple[float, float, float]
    start_s: float = 0.0
    end_s: float | None = None

    def __post_init__(self) -> None:
        e = as_finite_array("effectiveness", self.effectiveness, shape_tail=(3,))
        if np.any((e < 0.0) | (e > 1.0)):
            raise ConfigError(f"effectiveness must be in [0, 1] per axis, got {list(self.effectiveness)}")
        _window_check(self)


@dataclass(frozen=True)
class ActuatorBias(_Windowed):
    bias_Nm: tuple[float, float, float]
    start_s: float = 0.0
    end_s: float | None = None

    def __post_init__(self) -> None:
        as_finite_array("bias_Nm", self.bias_Nm, shape_tail=(3,))
        _window_check(self)


@dataclass(frozen=True)
class ActuatorStuck(_Windowed):
    start_s: float = 0.0
    end_s: float | None = None

    def __post_init__(self) -> None:
        _window_check(self)


@dataclass(frozen=True)
class SensorNoise(_Windowed):
    attitude_std_rad: float = 0.0
    rate_std_rad_s: float = 0.0
    seed: int = 0
    start_s: float = 0.0
    end_s: float | None = None

    def __post_init__(self) -> None:
        check_positive("attitude_std_rad", self.attitude_std_rad, allow_zero=True)
        check_positive("rate_std_rad_s", self.rate_std_rad_s, allow_zero=True)
        if int(self.seed) != self.seed or self.seed < 0:
            raise ConfigError(f"seed must be a non-negative integer, got {self.seed!r}")
        _window_check(self)


@dataclass(frozen=True)
class SensorBias(_Windowed):
    attitude_bias_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rate_bias_rad_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    start_s: float = 0.0
    end_s: float | None = None

    def __post_init__(self) -> None:
        as_finite_array("attitude_bias_rad", self.attitude_bias_rad, shape_tail=(3,))
        as_finite_array("rate_bias_rad_s", self.rate_bias_rad_s, shape_tail=(3,))
        _window_check(self)


@dataclass(frozen=True)
class SensorDropout(_Windowed):
    start_s: float = 0.0
    end_s: float | None = None

    def __post_init__(self) -> None:
        _window_check(self)


@dataclass(frozen=True)
class SensorFreeze(_Windowed):
    start_s: float = 0.0
    end_s: float | None = None

    def __post_init__(self) -> None:
        _window_check(self)


class FaultPath(str, Enum):
    """The link a delay acts on."""

    SENSOR = "sensor"  #: plant -> controller (the measured state)
    ACTUATOR = "actuator"  #: controller -> plant (the torque command)


@dataclass(frozen=True)
class Delay(_Windowed):
    path: FaultPath
    samples: int
    start_s: float = 0.0
    end_s: float | None = None

    def __post_init__(self) -> None:
        try:
            object.__setattr__(self, "path", FaultPath(self.path))
        except ValueError:
            raise ConfigError(f"delay.path must be 'sensor' or 'actuator', got {self.path!r}") from None
        if not isinstance(self.samples, int) or isinstance(self.samples, bool) or self.samples < 1:
            raise ConfigError(f"delay.samples must be a positive integer, got {self.samples!r}")
        _window_check(self)


FAULT_KINDS: dict[str, type] = {
    "actuator_effectiveness": ActuatorEffectiveness,
    "actuator_bias": ActuatorBias,
    "actuator_stuck": ActuatorStuck,
    "sensor_noise": SensorNoise,
    "sensor_bias": SensorBias,
    "sensor_dropout": SensorDropout,
    "sensor_freeze": SensorFreeze,
    "delay": Delay,
}

_ACTUATOR = (ActuatorEffectiveness, ActuatorBias, ActuatorStuck)
_SENSOR = (SensorNoise, SensorBias, SensorDropout, SensorFreeze)


def faults_from_list(entries: object, prefix: str = "faults") -> tuple[Any, ...]:
    """Validate a ``faults:`` list (see the module docstring); errors name the entry and key."""
    return from_kind_list(entries, FAULT_KINDS, prefix)


def noisy_measurement(q_BN: Array, omega_BN_B: Array, n: Array, attitude_std_rad: float, rate_std_rad_s: float) -> tuple[Array, Array]:
    """The sensor-noise model (:func:`spacecraft_sim.core.kernels.noisy_measurement`, the one
    implementation) for one sample: ``q_BN`` (4,), ``omega_BN_B`` (3,), standard normal draws ``n`` (6,)."""
    q = np.empty(4)
    w = np.empty(3)
    kernels.noisy_measurement(np.ascontiguousarray(q_BN, dtype=np.float64), np.ascontiguousarray(omega_BN_B, dtype=np.float64),
                              np.ascontiguousarray(n, dtype=np.float64), float(attitude_std_rad), float(rate_std_rad_s), q, w)
    return q, w


class _History:
    """The last ``n + 1`` samples delivered to a delay, and the sample held by a freeze/stuck."""

    def __init__(self) -> None:
        self.held: dict[int, Any] = {}
        self.queues: dict[int, deque[Any]] = {}


class FaultSchedule:
    """The faults of one run, applied sample by sample (stateful: delays, freezes, stuck).

    Parameters
    ----------
    faults : tuple
        As returned by :func:`faults_from_list`.
    """

    def __init__(self, faults: tuple[Any, ...] = ()) -> None:
        self.faults = tuple(faults)
        self._h = _History()

    @property
    def has_sensor_faults(self) -> bool:
        return any(isinstance(f, _SENSOR) or (isinstance(f, Delay) and f.path is FaultPath.SENSOR) for f in self.faults)

    @property
    def has_actuator_faults(self) -> bool:
        return any(isinstance(f, _ACTUATOR) or (isinstance(f, Delay) and f.path is FaultPath.ACTUATOR) for f in self.faults)

    def events(self) -> list[tuple[float, float]]:
        """Windows of every fault (for marking plots and metrics)."""
        return sorted(e for f in self.faults for e in f.events())

    def reset(self) -> None:
        self._h = _History()

    def _delayed(self, i: int, f: Any, t: float, value: Any) -> Any:
        if not f.active(t):
            self._h.queues.pop(i, None)
            self._h.held.pop(i, None)
            return value
        if isinstance(f, Delay):
            q = self._h.queues.setdefault(i, deque([value] * f.samples, maxlen=f.samples + 1))
            q.append(value)
            return q[0]
        return self._h.held.setdefault(i, value)  # freeze / stuck: the window's first sample

    def actuator(self, t: float, torque_B: Array) -> Array:
        """Torque applied [N m] for the command ``torque_B`` (3,) stamped ``t``."""
        out = np.array(torque_B, dtype=np.float64)
        for i, f in enumerate(self.faults):
            if isinstance(f, ActuatorEffectiveness) and f.active(t):
                out = np.asarray(f.effectiveness) * out
            elif isinstance(f, ActuatorBias) and f.active(t):
                out = out + np.asarray(f.bias_Nm)
            elif isinstance(f, ActuatorStuck) or (isinstance(f, Delay) and f.path is FaultPath.ACTUATOR):
                out = np.array(self._delayed(i, f, t, out))
        return out

    def sensor(self, t: float, stamp_ns: int, q_BN: Array, omega_BN_B: Array) -> tuple[Array, Array] | None:
        """The measurement delivered for the true sample ``(q_BN, omega_BN_B)`` stamped ``t``
        (``stamp_ns`` in nanoseconds, the noise key), or ``None`` when it is dropped."""
        q = np.array(q_BN, dtype=np.float64)
        w = np.array(omega_BN_B, dtype=np.float64)
        for i, f in enumerate(self.faults):
            if isinstance(f, SensorNoise) and f.active(t):
                n = np.random.default_rng([int(f.seed), int(stamp_ns)]).standard_normal(6)
                q, w = noisy_measurement(q, w, n, f.attitude_std_rad, f.rate_std_rad_s)
            elif isinstance(f, SensorBias) and f.active(t):
                q = quat_normalize(quat_multiply(q[None], rotation_vector_to_quaternion(np.asarray(f.attitude_bias_rad, dtype=np.float64))[None]))[0]
                w = w + np.asarray(f.rate_bias_rad_s)
            elif isinstance(f, SensorDropout) and f.active(t):
                return None
            elif isinstance(f, SensorFreeze) or (isinstance(f, Delay) and f.path is FaultPath.SENSOR):
                q, w = (np.array(v) for v in self._delayed(i, f, t, (q, w)))
        return q, w

"""Actuator, sensor and link faults, applied to samples travelling between plant and controller.

One implementation, two callers: the injector node relays the plant's state, the reference and
the controller's torque through :class:`FaultSchedule` one message at a time (docs/how-to/faults.md),
and the offline loop (:mod:`sappc.offline.compiled_loop`) applies the same compiled kernels
(:func:`spacecraft_sim.core.kernels.fault_sensor`, ``fault_reference``, ``fault_actuator``) to
its arrays, so a fault scenario gives the same run offline, in a campaign and through the
lockstep graph.  Each fault acts in a window ``start_s <= t < end_s`` (``end_s`` omitted: until
the end), compared with :data:`~spacecraft_sim.core.disturbance.TIME_TOLERANCE_S`, where ``t``
is the sample's stamp.

Kinds (a scenario's ``faults:`` list, ``{kind: ..., <fields>}``):

=========================  =====================================================================
``actuator_effectiveness``  ``effectiveness`` (3 values in [0, 1]): applied torque = e * command
``actuator_bias``           ``bias_Nm`` (3): applied torque = command + bias
``actuator_stuck``          the torque commanded at the window's first sample is held
``actuator_dropout``        commands are lost on the link: the actuator holds the last
                            delivered torque
``sensor_noise``            ``attitude_std_rad``, ``rate_std_rad_s``, ``seed``: white noise, a
                            small rotation on the attitude and an additive rate error, drawn
                            from ``default_rng([seed, stamp_ns])`` (a pure function of the
                            sample, whatever order samples are asked in)
``sensor_bias``             ``attitude_bias_rad`` (a rotation vector), ``rate_bias_rad_s``
``sensor_dropout``          state samples are not delivered
``sensor_freeze``           the sample at the window's start is delivered again and again
``reference_dropout``       reference samples are not delivered
``delay``                   ``path`` (``sensor`` or ``actuator``), ``samples`` n: the content of
                            the sample n steps earlier is delivered with the current stamp
                            (the first n samples of the window deliver the window's first one)
=========================  =====================================================================

Faults on one path compose in list order (a dropout hides the sample from the faults after it);
the attitude stays a unit quaternion.  What the controller does without inputs (the stale-input
watchdog) is the controller node's rule, modelled offline by the compiled loop.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from typing import Any

import numpy as np
from numpy.typing import NDArray

from gnc_common.attitude import rotation_vector_to_quaternion
from spacecraft_sim.core import kernels
from spacecraft_sim.core.disturbance import TIME_TOLERANCE_S
from gnc_common.validation import ConfigError, as_finite_array, check_positive, from_kind_list

__all__ = ["FAULT_KINDS", "EncodedFaults", "FaultPath", "FaultSchedule", "encode_faults", "faults_from_list", "noise_draws", "noisy_measurement", "pack_faults"]

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


@dataclass(frozen=True)
class ReferenceDropout(_Windowed):
    start_s: float = 0.0
    end_s: float | None = None

    def __post_init__(self) -> None:
        _window_check(self)


@dataclass(frozen=True)
class ActuatorDropout(_Windowed):
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
    "actuator_dropout": ActuatorDropout,
    "sensor_noise": SensorNoise,
    "sensor_bias": SensorBias,
    "sensor_dropout": SensorDropout,
    "sensor_freeze": SensorFreeze,
    "reference_dropout": ReferenceDropout,
    "delay": Delay,
}


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


@dataclass(frozen=True)
class EncodedFaults:
    """A fault list as the kernels take it (:func:`encode_faults`).

    ``kind`` (F,) int64 (``kernels.F_*``), ``window`` (F, 2) start and end [s] (``inf``: open),
    ``params`` (F, N_FPARAMS), ``samples`` (F,) int64 (a delay's samples, 0 otherwise), ``depth``:
    the slots of the largest delay ring (``max(samples) + 1``)."""

    kind: NDArray[np.int64]
    window: Array
    params: Array
    samples: NDArray[np.int64]
    depth: int

    @property
    def n(self) -> int:
        return int(self.kind.size)

    @property
    def has_noise(self) -> bool:
        """Whether a noise fault needs draws (:func:`noise_draws`)."""
        return bool(np.any(self.kind == kernels.F_SENSOR_NOISE))

    def new_state(self) -> tuple[NDArray[np.int64], Array]:
        """Fresh delay/freeze state of one run: ``fcount`` (F,), ``fbuf`` (F, depth, N_FVALUE)."""
        return np.zeros(self.n, dtype=np.int64), np.zeros((self.n, self.depth, kernels.N_FVALUE))


def _kind_code(f: Any) -> int:
    if isinstance(f, Delay):
        return kernels.F_DELAY_SENSOR if f.path is FaultPath.SENSOR else kernels.F_DELAY_ACTUATOR
    return _KIND_CODES[type(f)]


def encode_faults(faults: tuple[Any, ...]) -> EncodedFaults:
    """The faults of :func:`faults_from_list` as arrays for the kernels (list order kept)."""
    n = len(faults)
    kind = np.zeros(n, dtype=np.int64)
    window = np.zeros((n, 2))
    params = np.zeros((n, kernels.N_FPARAMS))
    samples = np.zeros(n, dtype=np.int64)
    for i, f in enumerate(faults):
        kind[i] = _kind_code(f)
        window[i] = (f.start_s, np.inf if f.end_s is None else f.end_s)
        if isinstance(f, ActuatorEffectiveness):
            params[i, :3] = f.effectiveness
        elif isinstance(f, ActuatorBias):
            params[i, :3] = f.bias_Nm
        elif isinstance(f, SensorNoise):
            params[i, :2] = (f.attitude_std_rad, f.rate_std_rad_s)
        elif isinstance(f, SensorBias):
            params[i, :4] = rotation_vector_to_quaternion(np.asarray(f.attitude_bias_rad, dtype=np.float64))
            params[i, 4:7] = f.rate_bias_rad_s
        elif isinstance(f, Delay):
            samples[i] = f.samples
    return EncodedFaults(kind, window, params, samples, int(samples.max(initial=0)) + 1)


def noise_draws(faults: tuple[Any, ...], stamps_ns: NDArray[np.int64]) -> Array:
    """The standard normals (T, F, 6) of every noise fault at every stamp (zeros for the other
    faults): ``default_rng([seed, stamp_ns]).standard_normal(6)``, a pure function of the
    sample's stamp [ns], so the injector (one sample at a time) and the offline loop (every sample,
    before the loop; the kernel uses those inside the window) draw the same values.  About 10 us
    a sample and noise fault."""
    out = np.zeros((stamps_ns.size, len(faults), 6))
    for i, f in enumerate(faults):
        if isinstance(f, SensorNoise):
            for k, ns in enumerate(stamps_ns.tolist()):
                out[k, i] = np.random.default_rng([int(f.seed), int(ns)]).standard_normal(6)
    return out


def pack_faults(per_run: list[tuple[Any, ...]], stamps_ns: NDArray[np.int64]) -> kernels.FaultArrays:
    """A batch's faults for the whole-run loop (:class:`~.kernels.FaultArrays`): one fault list per
    run (a campaign's dispersed faults: the same kinds in the same slots), the noise faults' draws
    at the samples' stamps (those of the first run's list: the draws depend on the seed and the
    stamp only).  Each list is encoded once however many runs share it (a campaign without
    dispersed faults: every run's list is the scenario's)."""
    encoded: dict[int, EncodedFaults] = {}  # by the list's identity (per_run holds them all while this runs)
    for f in per_run:
        if id(f) not in encoded:
            encoded[id(f)] = encode_faults(tuple(f))
    enc = [encoded[id(f)] for f in per_run]
    if any(e.kind.shape != enc[0].kind.shape for e in encoded.values()):
        raise ValueError("every run's faults must have the same number of entries")
    draws = noise_draws(tuple(per_run[0]), stamps_ns) if any(e.has_noise for e in encoded.values()) else np.zeros((1, enc[0].n, 6))
    return kernels.FaultArrays(np.ascontiguousarray(np.stack([e.kind for e in enc]), dtype=np.int64),
                               np.ascontiguousarray(np.stack([e.window for e in enc]), dtype=np.float64),
                               np.ascontiguousarray(np.stack([e.params for e in enc]), dtype=np.float64),
                               np.ascontiguousarray(np.stack([e.samples for e in enc]), dtype=np.int64),
                               max(e.depth for e in enc), np.ascontiguousarray(draws, dtype=np.float64))


class FaultSchedule:
    """The faults of one run, applied sample by sample through the fault kernels
    (:func:`spacecraft_sim.core.kernels.fault_sensor` and friends: the offline loop calls the same
    ones on arrays).  Stateful: delays, freezes, a stuck actuator, the last delivered torque.

    Parameters
    ----------
    faults : tuple
        As returned by :func:`faults_from_list`.
    """

    def __init__(self, faults: tuple[Any, ...] = ()) -> None:
        self.faults = tuple(faults)
        self.encoded = encode_faults(self.faults)
        self.reset()

    def _has(self, codes: tuple[int, ...]) -> bool:
        return bool(np.isin(self.encoded.kind, codes).any())

    def acts_on(self, path: str) -> bool:
        """Whether a fault acts on link ``path``: ``"sensor"`` (the measured state), ``"reference"``
        or ``"actuator"`` (the torque command); that link is then relayed."""
        return self._has(_PATH_CODES[path])

    @property
    def has_sensor_faults(self) -> bool:
        """Faults acting on the measured state (the state is relayed)."""
        return self.acts_on("sensor")

    @property
    def has_reference_faults(self) -> bool:
        """Faults acting on the reference (the reference is relayed)."""
        return self.acts_on("reference")

    @property
    def has_actuator_faults(self) -> bool:
        """Faults acting on the torque command (the command is relayed)."""
        return self.acts_on("actuator")

    def events(self) -> list[tuple[float, float]]:
        """Windows of every fault (for marking plots and metrics)."""
        return sorted(e for f in self.faults for e in f.events())

    def warm_up(self) -> None:
        """Load the fault kernels now (numba's cache), not at the first relayed sample, then
        forget the sample used (a node calls this before its first message)."""
        self.sensor(0.0, 0, np.array([0.0, 0.0, 0.0, 1.0]), np.zeros(3))
        self.reference(0.0)
        self.actuator(0.0, np.zeros(3))
        self.reset()

    def reset(self) -> None:
        """Forget every held sample (a new run)."""
        self._count, self._buf = self.encoded.new_state()
        self._u_last = np.zeros(3)
        self._y = np.zeros(kernels.N_FVALUE)
        self._u = np.zeros(3)
        self._draws = np.zeros((self.encoded.n, 6))

    def actuator(self, t: float, torque_B: Array) -> Array:
        """Torque the actuator applies [N m] for the command ``torque_B`` (3,) stamped ``t``
        (while the command link drops commands: the last delivered torque, held)."""
        e, u = self.encoded, self._u
        u[:] = torque_B
        kernels.fault_actuator_one(float(t), e.kind, e.window, e.params, e.samples, self._count, self._buf, u, self._u_last)
        delivered: Array = u.copy()
        return delivered

    def reference(self, t: float) -> bool:
        """Whether the reference stamped ``t`` is delivered."""
        return bool(kernels.fault_reference_one(float(t), self.encoded.kind, self.encoded.window))

    def sensor(self, t: float, stamp_ns: int, q_BN: Array, omega_BN_B: Array, epoch_s: float | None = None) -> tuple[Array, Array, float] | None:
        """The measurement delivered for the true sample ``(q_BN, omega_BN_B)`` stamped ``t``
        (``stamp_ns`` in nanoseconds, the noise key), whose tracker quaternion was measured at
        ``epoch_s`` (``None``: at ``t``), as ``(q_BN, omega_BN_B, epoch_s)`` (a held or delayed sample
        keeps its epoch), or ``None`` when it is dropped."""
        e, y = self.encoded, self._y
        y[:4] = q_BN
        y[4:7] = omega_BN_B
        y[7] = t if epoch_s is None else epoch_s
        if e.has_noise:
            self._draws[:] = noise_draws(self.faults, np.array([stamp_ns], dtype=np.int64))[0]
        if not kernels.fault_sensor_one(float(t), e.kind, e.window, e.params, e.samples, self._count, self._buf, self._draws, y):
            return None
        return y[:4].copy(), y[4:7].copy(), float(y[7])

    def gyro_bias_fault(self, t: float) -> Array:
        """The rate bias [rad/s] (3,) the sensor faults active at ``t`` add to the gyro's
        (:func:`spacecraft_sim.core.kernels.fault_rate_bias`: the truth's share of the faults)."""
        out = np.zeros(3)
        kernels.fault_rate_bias_one(float(t), self.encoded.kind, self.encoded.window, self.encoded.params, out)
        return out


_KIND_CODES: dict[type, int] = {
    ActuatorEffectiveness: kernels.F_ACT_EFFECTIVENESS,
    ActuatorBias: kernels.F_ACT_BIAS,
    ActuatorStuck: kernels.F_ACT_STUCK,
    ActuatorDropout: kernels.F_ACT_DROPOUT,
    SensorNoise: kernels.F_SENSOR_NOISE,
    SensorBias: kernels.F_SENSOR_BIAS,
    SensorDropout: kernels.F_SENSOR_DROPOUT,
    SensorFreeze: kernels.F_SENSOR_FREEZE,
    ReferenceDropout: kernels.F_REFERENCE_DROPOUT,
}
_SENSOR_CODES = (kernels.F_SENSOR_NOISE, kernels.F_SENSOR_BIAS, kernels.F_SENSOR_DROPOUT, kernels.F_SENSOR_FREEZE, kernels.F_DELAY_SENSOR)
_ACTUATOR_CODES = (kernels.F_ACT_EFFECTIVENESS, kernels.F_ACT_BIAS, kernels.F_ACT_STUCK, kernels.F_ACT_DROPOUT, kernels.F_DELAY_ACTUATOR)
_PATH_CODES = {"sensor": _SENSOR_CODES, "reference": (kernels.F_REFERENCE_DROPOUT,), "actuator": _ACTUATOR_CODES}

"""Scenario files: one YAML file holds every parameter of an experiment.

A scenario names the plant, the initial state, the reference, the
disturbances and faults, the actuator, the metric settings, and the
parameters of each controller it can be run with.  Loading is strict: unknown
keys, missing keys and invalid values raise :class:`ConfigError` naming the
dotted key.  See ``config/scenarios/paper_tracking.yaml`` (bundled as ``paper_tracking``:
:mod:`sappc.files`) for the annotated format.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray

from sappc_controller.core.base import AttitudeController
from sappc_controller.core.common import ActuatorConfig
from sappc_estimator.core.config import MekfConfig
from sappc_estimator.params import parameters_from_config as estimator_parameters_from_config
from gnc_common.input_check import InputBounds
from sappc_controller.params import CONFIG_CLASSES, CONTROLLER_CLASSES, DEFAULT_STALE_TIMEOUT_S, check_watchdog_seconds, parameters_from_config, unflatten
from spacecraft_sim.core.disturbance import DisturbanceSum, disturbances_from_list
from spacecraft_sim.core.faults import FaultSchedule, faults_from_list
from spacecraft_sim.core.reference import PaperReference
from spacecraft_sim.core.sensors import Sensors, sensors_from_mapping
from spacecraft_sim.core.wheels import ReactionWheels, wheels_from_mapping
from spacecraft_sim.core.environment import Environment, environment_from_mapping
from sappc_momentum.core.law import MomentumManagement
from gnc_common.ephemeris import dcm_PN_of
from sappc_controller.core.mrp_feedback import MrpFeedbackGains
from sappc_modes.core.bdot import detumble_gain, geomagnetic_inclination_rad
from sappc_modes.core.modes import DETUMBLE, MODE_NAMES, ModeConfig
from sappc.controllers import ControllerKind
from sappc.files import SCENARIOS_DIR, scenario_path
from gnc_common.validation import (
    quoted,
    safe_load_yaml,
    ConfigError,
    did_you_mean,
    InputError,
    as_finite_array,
    check_initial_quaternion,
    check_positive,
    check_positive_int,
    check_spd_inertia,
    from_mapping,
    read_text_file,
)

__all__ = ["ACTUATOR_KINDS", "BOUNDED_METRICS", "MAX_SCENARIO_BYTES", "ControllerKind", "ControllerNodeSettings", "FlightModes", "controller_node_parameters", "MetricSettings", "OrbitBins", "Scenario", "controller_kind", "controller_params_yaml", "estimator_params_yaml", "load_scenario", "read_scenario_mapping", "scenario_from_mapping"]

Array = NDArray[np.float64]


#: The largest scenario file read [bytes], 4 MiB: the largest bundled scenario is under 11 kB (the
#: flight tuning study's), so a file a hundred times that is not a scenario written by hand; a YAML
#: parser takes about sixty times a file's size in memory (3.2 GB and a minute for a 50 MB file of
#: keys, issue 35; at this limit about 250 MB and a few seconds), so the size is checked before the
#: file is read.
MAX_SCENARIO_BYTES = 4 << 20
#: Memory one control sample of a run takes while it is simulated and analysed, without the
#: flight features [bytes]: at the end of the compiled loop, the run's peak (issue 47, measured by
#: ``benchmarks/bench_memory.py --breakdown``), its inputs (the sample's time and stamp, the
#: reference and its two rates, a shared disturbance's table: 15 float64) and its record (the
#: controller's rows as published, 40 float64, the true state, 7, the disturbance, 3, and the
#: answer's int8 code), each held once; the metrics then read the record a block at a time, as
#: views, after the inputs are freed (:func:`sappc.offline.simulate.run_scenario`).
RUN_BYTES_PER_SAMPLE = 8 * (15 + 40 + 7 + 3) + 1
#: What the flight features add to a sample [bytes] (:func:`run_bytes_per_sample`): the sensors'
#: standard normal draws (9 float64), the estimator's record (56 float64:
#: ``sappc.offline.compiled_loop.N_EST_RECORD``), a wheel's speed and motor torque (2 float64 each),
#: the orbit's record (the true and the measured field and the environment's torque, 9 float64,
#: and one per rod), a noise fault's draws (6 float64); a random disturbance's window index (an
#: int64) and its draws (3 float64 a window), in place of the shared table (3 float64).
RUN_BYTES_SENSORS = 8 * 9
RUN_BYTES_ESTIMATOR = 8 * 56
RUN_BYTES_PER_WHEEL = 8 * 2
RUN_BYTES_ORBIT = 8 * 9
RUN_BYTES_PER_ROD = 8
RUN_BYTES_NOISE_FAULT = 8 * 6
RUN_BYTES_RANDOM_INDEX = 8
RUN_BYTES_DISTURBANCE_TABLE = 8 * 3
#: Share of the machine's memory one run may take.
RUN_MEMORY_SHARE = 0.5


def machine_memory_bytes() -> int:
    """Physical memory of this machine [bytes]."""
    import os

    return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))


def run_bytes_per_sample(*, sensors: bool = False, estimator: bool = False, wheels: int = 0, orbit: bool = False, rods: int = 0,
                         magnetometer_rate_hz: float = 0.0, control_period_s: float = 1.0, noise_fault: bool = False,
                         random_hold_s: tuple[float, ...] = ()) -> int:
    """The memory one control sample of a run with these features takes at its peak [bytes]:
    :data:`RUN_BYTES_PER_SAMPLE` and what each feature adds (``RUN_BYTES_*``; the magnetometer's
    draws, 3 float64 at its rate; ``random_hold_s``: each random disturbance's hold, its draws 3
    float64 a window)."""
    extra = (RUN_BYTES_SENSORS * sensors + RUN_BYTES_ESTIMATOR * estimator + RUN_BYTES_PER_WHEEL * wheels
             + (RUN_BYTES_ORBIT + RUN_BYTES_PER_ROD * rods) * orbit + RUN_BYTES_NOISE_FAULT * noise_fault
             + 24 * magnetometer_rate_hz * control_period_s)
    if random_hold_s:
        extra += sum(RUN_BYTES_RANDOM_INDEX + 24 * min(1.0, control_period_s / h) for h in random_hold_s) - RUN_BYTES_DISTURBANCE_TABLE
    return RUN_BYTES_PER_SAMPLE + math.ceil(extra)


def check_run_fits_in_memory(duration_s: float, control_period_s: float, bytes_per_sample: int = RUN_BYTES_PER_SAMPLE) -> int:
    """The number of control samples of a run, after checking that its histories (``bytes_per_sample``
    a sample: :func:`run_bytes_per_sample`) fit in :data:`RUN_MEMORY_SHARE` of this machine's memory
    (before anything is allocated).  Only a run that keeps its whole record needs it
    (:func:`sappc.offline.simulate.run_scenario` with ``keep_history``): a run in blocks of samples,
    what ``sappc simulate`` and the campaigns fly, holds nothing of its length (docs/design/streaming.md).

    Raises
    ------
    ConfigError
        Naming ``duration_s``, the memory needed and the longest duration that fits.
    """
    samples = round(duration_s / control_period_s) + 1
    limit = RUN_MEMORY_SHARE * machine_memory_bytes()
    if samples * bytes_per_sample > limit:
        longest = (limit / bytes_per_sample - 1) * control_period_s
        raise ConfigError(
            f"duration_s = {duration_s!r} at control_period_s = {control_period_s!r} is {samples:.3g} control samples, whose "
            f"histories need {samples * bytes_per_sample / 2**30:.3g} GiB; this machine allows a run "
            f"{limit / 2**30:.3g} GiB ({RUN_MEMORY_SHARE:.0%} of its memory): duration_s <= {longest:.6g} s at this period"
        )
    return int(samples)


_CONFIG_CLASSES = {k: (CONFIG_CLASSES[k.value], CONTROLLER_CLASSES[k.value]) for k in ControllerKind}


_TOP_KEYS = {
    "name",
    "description",
    "duration_s",
    "control_period_s",
    "plant",
    "initial_state",
    "reference",
    "disturbances",
    "actuator",
    "metrics",
    "controller",
    "controllers",
    "montecarlo",  # validated by sappc.montecarlo.campaign.campaign_config
    "tuning",  # validated by sappc.montecarlo.tuning.tuning_config (sappc tune)
    "faults",  # actuator, sensor and link faults (offline, in campaigns and on the ROS 2 graph)
    "controller_node",  # the controller node's input watchdog (both paths model it)
    "sensors",  # the plant's star tracker and gyro (spacecraft_sim.core.sensors); none: exact measurements
    "estimator",  # attitude determination between the sensors and the controller (sappc_estimator); none: the measurements
    "orbit",  # the orbit, the Earth's field and the gravity gradient (spacecraft_sim.core.environment); none: the paper's inertial setting
    "magnetorquers",  # the torque rods (spacecraft_sim.core.magnetorquers); needs orbit
    "momentum_management",  # the rods' dumping law and the wheels' feed-forward (sappc_momentum); needs magnetorquers and wheels
    "magnetometer",  # what the flight software reads the field with (spacecraft_sim.core.magnetometer); needs orbit; none: exactly
    "modes",  # the flight modes (sappc_modes): DETUMBLE, HOLD, TRACK, SAFE; needs momentum_management; none: TRACK from the start
}


@dataclass(frozen=True)
class ControllerNodeSettings:
    """How the controller checks its inputs and answers when they stop (:mod:`sappc_controller.node`,
    the node parameters of the same names), modelled by the offline loop too.

    Attributes
    ----------
    stale_timeout_s : float
        Zero torque when no valid state is newer than this at a control instant [s]; within
        :data:`~sappc_controller.params.WATCHDOG_RANGE_S` (the node parameter's range).
    max_attitude_norm_error, max_body_rate_rad_s, max_reference_rate_rad_s, max_reference_acceleration_rad_s2 : float
        The plausibility bounds on the inputs (:class:`~gnc_common.input_check.InputBounds`,
        whose defaults and reasons they take): an input beyond one is rejected.
    """

    stale_timeout_s: float = DEFAULT_STALE_TIMEOUT_S
    max_attitude_norm_error: float = InputBounds.max_attitude_norm_error
    max_body_rate_rad_s: float = InputBounds.max_body_rate_rad_s
    max_reference_rate_rad_s: float = InputBounds.max_reference_rate_rad_s
    max_reference_acceleration_rad_s2: float = InputBounds.max_reference_acceleration_rad_s2

    def __post_init__(self) -> None:
        check_watchdog_seconds("controller_node.stale_timeout_s", self.stale_timeout_s)
        try:
            self.input_bounds()
        except ConfigError as exc:
            raise ConfigError(f"controller_node.{exc}") from None

    def input_bounds(self) -> InputBounds:
        """The plausibility bounds of the controller's inputs."""
        return InputBounds(**{f.name: getattr(self, f.name) for f in dataclasses.fields(InputBounds)})


#: Metrics a requirement may bound from above (``<name>_max``).
BOUNDED_METRICS = (
    "settling_time_s",
    "steady_max_abs_qev",
    "steady_mean_abs_qev",
    "rpf_error_at_t2",
    "overshoot",
    "max_abs_torque_Nm",
    "torque_sign_changes_per_s",
    "torque_reversals_per_s",
    "saturation_fraction",
    "time_outside_constraint_s",
    "max_abs_wheel_speed_rad_s",  # only with reaction wheels: unknown (a failure) with the ideal actuator
    "time_to_track_s",  # only with flight modes: unknown (a failure) when the flight never reached TRACK
    "filter_inconsistent_fraction",  # only with an estimator: unknown (a failure) without one
)


def check_requirements(requirements: object, prefix: str = "metrics.requirements") -> dict[str, float]:
    """Validate a ``requirements`` mapping: every key ``<metric>_max`` of :data:`BOUNDED_METRICS`,
    every bound a finite number >= 0; errors name the key."""
    if requirements is None:
        return {}
    if not isinstance(requirements, Mapping):
        raise ConfigError(f"{prefix} must be a mapping of <metric>_max to a bound, got {requirements!r}")
    known = {f"{m}_max" for m in BOUNDED_METRICS}
    out: dict[str, float] = {}
    for key, bound in requirements.items():
        if key not in known:
            raise ConfigError(f"unknown key {prefix}.{key}; expected one of {sorted(known)}")
        if isinstance(bound, bool) or not isinstance(bound, (int, float)) or not math.isfinite(bound) or bound < 0:
            raise ConfigError(f"{prefix}.{key} must be a finite number >= 0, got {bound!r}")
        out[str(key)] = float(bound)
    return out


@dataclass(frozen=True)
class OrbitBins:
    """What the per-orbit metrics need of a scenario in orbit (:meth:`Scenario.orbit_bins`,
    :meth:`sappc.evaluation.metrics.MetricsAccumulator.orbit_metrics`): orbit ``j`` holds the samples
    with ``j T <= t < (j + 1) T``.

    Attributes
    ----------
    period_s : float
        The orbit's period ``T`` [s].
    wheel_spin_inertia_kg_m2 : ndarray (W,) or None
        Each wheel's spin inertia (``None``: no wheels).
    wheel_axes_B : ndarray (3, W) or None
        The wheels' spin axes in the body frame (``G_s``).
    rod_max_dipole_Am2 : ndarray (M,) or None
        Each rod's largest dipole (``None``: no rods).
    """

    period_s: float
    wheel_spin_inertia_kg_m2: np.ndarray | None = None
    wheel_axes_B: np.ndarray | None = None
    rod_max_dipole_Am2: np.ndarray | None = None


@dataclass(frozen=True)
class MetricSettings:
    """How run metrics are computed (see :mod:`sappc.evaluation.metrics`).

    Attributes
    ----------
    steady_from_s : float
        Start of the steady-state window [s] (the paper's Monte Carlo uses [25, 50] s).
    settle_threshold : float
        ``settling_time_s`` is the first time after which ``max_i |q_ev,i|`` stays below this (experiment 1: 1e-3).
    t2_s : float
        Time at which ``rpf_error_at_t2`` is taken [s].
    requirements : dict
        Upper bounds ``<metric>_max`` that a run must meet (:mod:`sappc.evaluation.requirements`);
        a run that breaks one exits with status 4.
    origin : str
        With flight modes, where a run's tracking metrics count from: ``first_track`` (default) its
        first entry into TRACK, ``last_track`` its last (the tracking a recovery came back to:
        after a SAFE, the accuracy regained); without modes, the run's first sample either way.
    """

    steady_from_s: float = 25.0
    settle_threshold: float = 1e-3
    t2_s: float = 20.0
    requirements: dict[str, float] = field(default_factory=dict)
    origin: str = "first_track"

    def __post_init__(self) -> None:
        object.__setattr__(self, "requirements", check_requirements(self.requirements))
        check_positive("metrics.steady_from_s", self.steady_from_s, allow_zero=True)
        check_positive("metrics.settle_threshold", self.settle_threshold)
        check_positive("metrics.t2_s", self.t2_s, allow_zero=True)
        if self.origin not in METRIC_ORIGINS:
            raise ConfigError(f"metrics.origin must be one of {', '.join(METRIC_ORIGINS)}, got {quoted(self.origin)}")


#: Where a run's tracking metrics count from with flight modes (``metrics.origin``).
METRIC_ORIGINS = ("first_track", "last_track")
#: The keys of the ``modes`` section.
MODES_KEYS = ("initial_mode", "transitions", "detumble_gain_N_m_s", "hold_gains", "hold_attitude", "requests")
#: ``modes.hold_attitude``: HOLD holds the attitude of its entry (an inertial hold), or points at the
#: scenario's reference (an acquisition: TRACK then starts near it, with ``transitions.acquired_error_rad``).
HOLD_ATTITUDES = ("entry", "reference")
#: ``modes.detumble_gain_N_m_s: criterion``: the gain of Avanzini and Giulietti's criterion from the
#: scenario's orbit, field and inertia (:func:`detumble_criterion_gain`).
GAIN_CRITERION = "criterion"


@dataclass(frozen=True)
class FlightModes:
    """The ``modes`` section: the mode manager's guards, its first mode, and its laws outside TRACK
    (docs/design/modes.md).

    Attributes
    ----------
    transitions : ModeConfig
        The guards' thresholds and persistences (``modes.transitions``, :class:`~sappc_modes.core.modes.ModeConfig` keys).
    initial_mode : int
        The first mode (``modes.initial_mode``: a name of :data:`~sappc_modes.core.modes.MODE_NAMES`;
        default DETUMBLE, a flight after separation).
    detumble_gain_N_m_s : float
        The B-dot gain ``k`` [N m s] (:mod:`sappc_modes.core.bdot`).
    detumble_gain_source : str
        ``criterion`` when the gain is the criterion's (:func:`detumble_criterion_gain`), else ``given``.
    hold_gains : MrpFeedbackGains
        The MRP feedback gains of HOLD (on the estimate) and of SAFE (``P_Nms`` alone: rate
        damping on the gyro).
    hold_on_reference : bool
        ``modes.hold_attitude: reference``: HOLD points at the scenario's reference; ``entry``
        (default): it holds the attitude of its entry.
    requests : tuple of (float, int)
        ``modes.requests``: the ground's mode requests, each ``{at_s: <time [s]>, mode: <name>}``,
        executed at the first sample at or after its time (an operator's command: at once, from any
        mode; docs/design/modes.md).
    """

    transitions: ModeConfig
    initial_mode: int
    detumble_gain_N_m_s: float
    detumble_gain_source: str
    hold_gains: MrpFeedbackGains
    hold_on_reference: bool = False
    requests: tuple[tuple[float, int], ...] = ()


def detumble_criterion_gain(environment: Environment, inertia_kg_m2: Array) -> tuple[float, float]:
    """The B-dot gain of the criterion ``k* = 2 n (1 + sin xi_m) J_min``
    (:func:`sappc_modes.core.bdot.detumble_gain`) for the scenario's orbit (its mean motion ``n``),
    the geomagnetic inclination ``xi_m`` at ``t = 0`` (the orbit's normal against the dipole's
    axis, which turns with the Earth: the value at the run's start, as flight software sets its
    gain once) and the inertia's smallest principal moment; returns ``(k*, xi_m)`` [N m s, rad]."""
    orbit, field = environment.orbit, environment.magnetic_field
    i, raan = math.radians(orbit.inclination_deg), math.radians(orbit.raan_deg)
    normal_N = np.array([math.sin(i) * math.sin(raan), -math.sin(i) * math.cos(raan), math.cos(i)])  # h / |h| of the orbit
    m_P = np.array([field.g11_nT, field.h11_nT, field.g10_nT])  # the dipole's axis in the Earth-fixed frame (magnetic_field's m)
    c, s = dcm_PN_of.py_func(orbit.params(), 0.0)  # the Earth's rotation at t = 0, as the plant's field turns it
    m_N = np.array([c * m_P[0] - s * m_P[1], s * m_P[0] + c * m_P[1], m_P[2]])  # [PN]^T m_P
    xi_m = geomagnetic_inclination_rad(normal_N, m_N)
    J_min = float(np.linalg.eigvalsh(np.asarray(inertia_kg_m2, dtype=np.float64))[0])
    return detumble_gain(orbit.mean_motion_rad_s, xi_m, J_min), xi_m


def _modes_from_mapping(data: Any, environment: Environment | None, momentum: MomentumManagement | None,
                        inertia_kg_m2: Array) -> FlightModes | None:
    """The ``modes`` section (:data:`MODES_KEYS`): it needs the rods and the wheels' momentum
    management (B-dot commands the rods; HOLD and TRACK fly on the wheels).  Errors name the key."""
    if data is None:
        return None
    if not isinstance(data, dict):
        raise ConfigError(f"modes must be a mapping, got {quoted(data)}")
    unknown = sorted(set(data) - set(MODES_KEYS), key=str)
    if unknown:
        raise ConfigError(f"unknown key modes.{unknown[0]}{did_you_mean(str(unknown[0]), list(MODES_KEYS))}; "
                          f"modes accepts {', '.join(MODES_KEYS)}")
    if environment is None or environment.magnetorquers is None or momentum is None:
        raise ConfigError("modes needs an orbit, magnetorquers and momentum_management: DETUMBLE commands the rods, "
                          "HOLD and TRACK fly on the wheels whose momentum the rods dump")
    name = data.get("initial_mode", MODE_NAMES[DETUMBLE])
    if name not in MODE_NAMES:
        raise ConfigError(f"modes.initial_mode must be one of {', '.join(MODE_NAMES)}, got {quoted(name)}{did_you_mean(str(name), list(MODE_NAMES))}")
    try:
        transitions: ModeConfig = from_mapping(ModeConfig, data.get("transitions", {}) or {}, "modes.transitions")
    except ConfigError as exc:
        raise _named("modes.transitions", exc) from None
    gain = data.get("detumble_gain_N_m_s", GAIN_CRITERION)
    if gain == GAIN_CRITERION:
        k, source = detumble_criterion_gain(environment, inertia_kg_m2)[0], GAIN_CRITERION
    else:
        k, source = check_positive("modes.detumble_gain_N_m_s", gain), "given"
        if not isinstance(k, float):
            raise ConfigError(f"modes.detumble_gain_N_m_s must be a number or {GAIN_CRITERION!r}, got {quoted(gain)}")
    if "hold_gains" not in data:
        raise ConfigError("modes.hold_gains is required: the MRP feedback gains of HOLD and SAFE (K_Nm, P_Nms, integralLimit_Nms)")
    try:
        hold: MrpFeedbackGains = from_mapping(MrpFeedbackGains, data["hold_gains"], "modes.hold_gains")
    except ConfigError as exc:
        raise _named("modes.hold_gains", exc) from None
    attitude = data.get("hold_attitude", HOLD_ATTITUDES[0])
    if attitude not in HOLD_ATTITUDES:
        raise ConfigError(f"modes.hold_attitude must be one of {', '.join(HOLD_ATTITUDES)}, got {quoted(attitude)}")
    return FlightModes(transitions, MODE_NAMES.index(name), float(k), source, hold, attitude == "reference",
                       _mode_requests(data.get("requests")))


def _mode_requests(data: Any) -> tuple[tuple[float, int], ...]:
    """``modes.requests``: a list of ``{at_s, mode}`` (a time >= 0 [s] and a mode's name); errors name the item."""
    if data is None:
        return ()
    if not isinstance(data, list):
        raise ConfigError(f"modes.requests must be a list of {{at_s: <s>, mode: <name>}}, got {quoted(data)}")
    out = []
    for i, item in enumerate(data):
        if not isinstance(item, dict) or set(item) != {"at_s", "mode"}:
            raise ConfigError(f"modes.requests[{i}] must be a mapping with exactly at_s and mode, got {quoted(item)}")
        at_s = check_positive(f"modes.requests[{i}].at_s", item["at_s"], allow_zero=True)
        if not isinstance(at_s, float):
            raise ConfigError(f"modes.requests[{i}].at_s must be one number, got {quoted(item['at_s'])}")
        if item["mode"] not in MODE_NAMES:
            raise ConfigError(f"modes.requests[{i}].mode must be one of {', '.join(MODE_NAMES)}, got {quoted(item['mode'])}")
        out.append((at_s, MODE_NAMES.index(item["mode"])))
    return tuple(sorted(out))


@dataclass(frozen=True)
class Scenario:
    """A loaded, validated scenario.

    Attributes
    ----------
    name, description : str
    duration_s, control_period_s : float
        Simulated duration and control period ``dt`` [s].
    rk4_substeps : int
        Plant RK4 steps per control period.
    inertia_kg_m2 : ndarray (3, 3)
        Plant inertia; also the controllers' known ``J`` (Assumption 1).
    q_BN0 : ndarray (4,)
        Initial attitude, normalised.
    omega_BN_B0_rad_s : ndarray (3,)
    reference : PaperReference
    disturbance : DisturbanceSum
    actuator : ActuatorConfig
        The controller's actuator model (per-axis saturation, minimum output).
    wheels : ReactionWheels or None
        The plant's actuator: ``None`` for ``actuator.kind: ideal`` (the commanded torque,
        clipped per axis to ``actuator.max_torque_Nm``, acts on the body exactly), else the
        reaction-wheel set of ``actuator.kind: reaction_wheels`` (``actuator.wheels``).
    sensors : Sensors or None
        The plant's star tracker and gyro (the controller sees their measurements, the metrics
        the true state); ``None``: the state is measured exactly.
    estimator : MekfConfig or None
        The attitude estimator between the sensors and the controller (``estimator: {kind:
        mekf}``; settings not given come from ``sensors``); ``None``: the controller is fed the
        measurements.
    environment : Environment or None
        The orbit, the Earth's field, the gravity gradient and the magnetorquers (sections
        ``orbit`` and ``magnetorquers``); ``None``: no orbit (the paper's setting).
    momentum : MomentumManagement or None
        The flight software's momentum management (section ``momentum_management``).
    modes : FlightModes or None
        The flight modes (section ``modes``); ``None``: the scenario's controller flies from the
        first sample (TRACK alone).
    metrics : MetricSettings
    controller : ControllerKind
        Default controller.
    faults : tuple
        Actuator, sensor and link faults (:mod:`spacecraft_sim.core.faults`): applied by the
        offline loop, and by relaying topics on the ROS 2 graph.
    controller_node : ControllerNodeSettings
        The controller's input watchdog.
    controllers : dict
        Raw parameter mappings per controller kind, validated by :meth:`controller_config`.
    raw : dict
        The parsed file, for provenance.
    """

    name: str
    description: str
    duration_s: float
    control_period_s: float
    rk4_substeps: int
    inertia_kg_m2: Array
    q_BN0: Array
    omega_BN_B0_rad_s: Array
    reference: PaperReference
    disturbance: DisturbanceSum
    actuator: ActuatorConfig
    metrics: MetricSettings
    controller: ControllerKind
    faults: tuple[Any, ...]
    controllers: dict[str, Any] = field(repr=False)
    raw: dict[str, Any] = field(repr=False)
    controller_node: ControllerNodeSettings = ControllerNodeSettings()
    wheels: ReactionWheels | None = None
    sensors: Sensors | None = None
    estimator: MekfConfig | None = None
    environment: Environment | None = None
    momentum: MomentumManagement | None = None
    modes: FlightModes | None = None

    def controller_config(self, kind: ControllerKind | str | None = None) -> Any:
        """The validated config dataclass of controller ``kind`` (default: the scenario's)."""
        k = self.resolve_controller(kind)
        if k.value not in self.controllers:
            raise ConfigError(f"scenario {self.name!r} has no parameters for controller {k.value!r} (controllers.{k.value})")
        config_cls, _ = _CONFIG_CLASSES[k]
        data = dict(self.controllers[k.value])
        for key in ("inertia_kg_m2", "actuator"):
            if key in data:
                raise ConfigError(f"controllers.{k.value}.{key} is set by the scenario's plant/actuator sections, not per controller")
        params = from_mapping(config_cls, {**data, "inertia_kg_m2": self.inertia_kg_m2.tolist()}, f"controllers.{k.value}")
        return dataclasses.replace(params, actuator=self.actuator)

    def build_controller(self, kind: ControllerKind | str | None = None, *, config: Any = None, **options: Any) -> AttitudeController:
        """A fresh controller of ``kind`` with this scenario's parameters, or with ``config``
        (a config of that kind, e.g. this scenario's with dispersed gains)."""
        k = self.resolve_controller(kind)
        _, controller_cls = _CONFIG_CLASSES[k]
        return controller_cls(self.controller_config(k) if config is None else config, **options)

    def event_windows(self) -> list[tuple[float, float]]:
        """Windows (start, end) [s] of every injected disturbance event and fault, sorted: for
        marking figures and for the fault metrics."""
        return sorted(self.disturbance.events() + FaultSchedule(self.faults).events())

    def orbit_bins(self) -> OrbitBins | None:
        """The per-orbit metrics' settings of a scenario in orbit; ``None`` without an orbit."""
        if self.environment is None:
            return None
        w, rods = self.wheels, self.environment.magnetorquers
        return OrbitBins(self.environment.orbit.period_s, None if w is None else w.per_wheel("spin_inertia_kg_m2"), None if w is None else w.G,
                         None if rods is None else rods.max_dipoles())

    def resolve_controller(self, kind: ControllerKind | str | None) -> ControllerKind:
        """``kind`` parsed, or the scenario's default controller when ``None``."""
        return self.controller if kind is None else controller_kind(kind)


def controller_kind(name: ControllerKind | str, *, key: str | None = None) -> ControllerKind:
    """Parse a controller name, raising :class:`ConfigError` naming the accepted ones and the
    closest of them to a misspelt name (``controller: sapc``: "did you mean 'sappc'?"); ``key``,
    the scenario key the name came from, opens the message."""
    try:
        return ControllerKind(name)
    except ValueError:
        kinds = [c.value for c in ControllerKind]
        raise ConfigError(f"{key + ': ' if key else ''}unknown controller {name!r}{did_you_mean(str(name), kinds)} "
                          f"(choose from {', '.join(kinds)})") from None


def scenario_from_mapping(data: Any, *, source: str = "<mapping>") -> Scenario:
    """Validate a parsed scenario mapping (see :func:`load_scenario`)."""
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: a scenario must be a mapping at the top level")
    unknown = sorted(set(data) - _TOP_KEYS)
    if unknown:
        raise ConfigError(f"{source}: unknown key {unknown[0]}; a scenario accepts {', '.join(sorted(_TOP_KEYS))}")
    for key in ("name", "duration_s", "control_period_s", "plant", "initial_state", "controllers"):
        if key not in data:
            raise ConfigError(f"{source}: missing key {key}")
    try:
        return _scenario_from_mapping(data, source)
    except InputError as exc:  # a non-finite or malformed number in the file
        raise ConfigError(str(exc)) from None


def _scenario_from_mapping(data: dict[str, Any], source: str) -> Scenario:
    duration = check_positive("duration_s", data["duration_s"])
    dt = check_positive("control_period_s", data["control_period_s"])
    if duration < dt:
        raise ConfigError(f"duration_s ({duration!r}) must be at least control_period_s ({dt!r})")

    plant = data["plant"]
    if not isinstance(plant, dict) or set(plant) - {"inertia_kg_m2", "rk4_substeps"} or "inertia_kg_m2" not in plant:
        raise ConfigError(f"plant must be a mapping with inertia_kg_m2 and optional rk4_substeps, got {plant!r}")
    J = check_spd_inertia("plant.inertia_kg_m2", plant["inertia_kg_m2"])
    substeps = check_positive_int("plant.rk4_substeps", plant.get("rk4_substeps", 1))

    init = data["initial_state"]
    if not isinstance(init, dict) or set(init) != {"q_BN", "omega_BN_B_rad_s"}:
        raise ConfigError(f"initial_state must have exactly q_BN and omega_BN_B_rad_s, got {init!r}")
    q0 = check_initial_quaternion("initial_state.q_BN", init["q_BN"])  # normalised
    w0 = as_finite_array("initial_state.omega_BN_B_rad_s", init["omega_BN_B_rad_s"], shape_tail=(3,))

    reference = from_mapping(PaperReference, dict(data.get("reference", {})), "reference") if data.get("reference") is not None else PaperReference()
    disturbance = disturbances_from_list(data.get("disturbances"))
    faults = faults_from_list(data.get("faults"))
    actuator, wheels = _actuator_from_mapping(data.get("actuator", {}) or {})
    sensors = None if data.get("sensors") is None else sensors_from_mapping(data["sensors"], "sensors", dt)
    estimator = _estimator_from_mapping(data.get("estimator"), sensors)
    environment = _environment_from_mapping(data.get("orbit"), data.get("magnetorquers"), data.get("magnetometer"), dt)
    momentum = _momentum_from_mapping(data.get("momentum_management"), environment, wheels)
    modes = _modes_from_mapping(data.get("modes"), environment, momentum, J)
    metrics = from_mapping(MetricSettings, data.get("metrics", {}) or {}, "metrics")
    node_settings = from_mapping(ControllerNodeSettings, data.get("controller_node", {}) or {}, "controller_node")

    controllers = data["controllers"]
    if not isinstance(controllers, dict) or not controllers:
        raise ConfigError("controllers must be a non-empty mapping of controller name to parameters")
    for name in controllers:
        if name not in {c.value for c in ControllerKind}:
            raise ConfigError(f"unknown key controllers.{name}; expected one of {[c.value for c in ControllerKind]}")
    scenario = Scenario(
        name=str(data["name"]),
        description=str(data.get("description", "")),
        duration_s=duration,
        control_period_s=dt,
        rk4_substeps=substeps,
        inertia_kg_m2=J,
        q_BN0=q0,
        omega_BN_B0_rad_s=w0,
        reference=reference,
        disturbance=disturbance,
        actuator=actuator,
        metrics=metrics,
        controller=controller_kind(data.get("controller", ControllerKind.SAPPC.value), key="controller"),
        faults=faults,
        controllers=controllers,
        raw=data,
        controller_node=node_settings,
        wheels=wheels,
        sensors=sensors,
        estimator=estimator,
        environment=environment,
        momentum=momentum,
        modes=modes,
    )
    for name in controllers:  # validate every controller's parameters now, not at run time
        scenario.controller_config(name)
    return scenario


def scenario_bytes_per_sample(scenario: Scenario) -> int:
    """:func:`run_bytes_per_sample` of ``scenario``'s features: the memory a sample of its run takes
    at its peak [bytes]."""
    from spacecraft_sim.core.disturbance import RandomTorque
    from spacecraft_sim.core.faults import SensorNoise

    env = scenario.environment
    mag = None if env is None else env.magnetometer
    return run_bytes_per_sample(
        sensors=scenario.sensors is not None, estimator=scenario.estimator is not None,
        wheels=0 if scenario.wheels is None else scenario.wheels.n, orbit=env is not None,
        rods=0 if env is None or env.magnetorquers is None else env.magnetorquers.n,
        magnetometer_rate_hz=0.0 if mag is None else float(mag.rate_hz), control_period_s=scenario.control_period_s,
        noise_fault=any(isinstance(f, SensorNoise) for f in scenario.faults),
        random_hold_s=tuple(float(m.hold_s) for m in scenario.disturbance.models if isinstance(m, RandomTorque)),
    )


#: The plant's actuator kinds (``actuator.kind``).
ACTUATOR_KINDS = ("ideal", "reaction_wheels")


def _actuator_from_mapping(data: Any) -> tuple[ActuatorConfig, ReactionWheels | None]:
    """The ``actuator`` section: the controller's limits (:class:`ActuatorConfig`) and the plant's
    actuator, ``kind: ideal`` (default) or ``kind: reaction_wheels`` with a ``wheels`` mapping
    (:class:`~spacecraft_sim.core.wheels.ReactionWheels`); errors name the key."""
    if not isinstance(data, dict):
        raise ConfigError(f"actuator must be a mapping, got {quoted(data)}")
    rest = dict(data)
    kind = rest.pop("kind", "ideal")
    wheels_raw = rest.pop("wheels", None)
    if kind not in ACTUATOR_KINDS:
        raise ConfigError(f"actuator.kind must be one of {', '.join(ACTUATOR_KINDS)}, got {kind!r}")
    actuator = from_mapping(ActuatorConfig, rest, "actuator")
    if kind == "ideal":
        if wheels_raw is not None:
            raise ConfigError("actuator.wheels is only for actuator.kind: reaction_wheels")
        return actuator, None
    if wheels_raw is None:
        raise ConfigError("missing key actuator.wheels (actuator.kind: reaction_wheels)")
    wheels = wheels_from_mapping(wheels_raw, "actuator.wheels")
    return actuator, wheels


def _named(prefix: str, exc: ConfigError) -> ConfigError:
    """``exc`` with a model's bare key (``<prefix>: key ...``) named in full (``<prefix>.key ...``)."""
    msg = str(exc)
    return ConfigError(f"{prefix}.{msg[len(prefix) + 2:]}" if msg.startswith(f"{prefix}: ") else msg)


def _environment_from_mapping(orbit: Any, rods: Any, magnetometer: Any = None, control_period_s: float = 0.01) -> Environment | None:
    """The ``orbit``, ``magnetorquers`` and ``magnetometer`` sections:
    :func:`spacecraft_sim.core.environment.environment_from_mapping` (the plant node reads its
    parameters with the same function).  All absent: ``None``.  Errors name the key."""
    return environment_from_mapping(orbit, rods, magnetometer, control_period_s)


def _momentum_from_mapping(data: Any, environment: Environment | None, wheels: ReactionWheels | None) -> MomentumManagement | None:
    """The ``momentum_management`` section (:class:`~sappc_momentum.core.law.MomentumManagement`
    keys): it needs the rods (``magnetorquers``) and the wheels (``actuator.kind: reaction_wheels``).
    Errors name the key."""
    if data is None:
        return None
    if environment is None or environment.magnetorquers is None:
        raise ConfigError("momentum_management needs a magnetorquers section (and an orbit): the rods are what dump the momentum")
    if wheels is None:
        raise ConfigError("momentum_management needs actuator.kind: reaction_wheels (the momentum it manages is the wheels')")
    try:
        config: MomentumManagement = from_mapping(MomentumManagement, data, "momentum_management")
    except ConfigError as exc:
        raise _named("momentum_management", exc) from None
    return config


#: The estimator kinds (``estimator.kind``): none (the controller is fed the sensors' measurements)
#: or the multiplicative EKF (:mod:`sappc_estimator.core.mekf`).
ESTIMATOR_KINDS = ("none", "mekf")


def _estimator_from_mapping(data: Any, sensors: Sensors | None) -> MekfConfig | None:
    """The ``estimator`` section: ``kind: none`` (default) or ``kind: mekf`` with optional
    :class:`~sappc_estimator.core.config.MekfConfig` keys; the filter's noise figures default to
    the ``sensors`` section's data sheet (docs/estimator.md).  Errors name the key."""
    if data is None:
        return None
    if not isinstance(data, dict):
        raise ConfigError(f"estimator must be a mapping, got {data!r}")
    rest = dict(data)
    kind = rest.pop("kind", "none")
    if kind not in ESTIMATOR_KINDS:
        raise ConfigError(f"estimator.kind must be one of {', '.join(ESTIMATOR_KINDS)}, got {kind!r}")
    if kind == "none":
        if rest:
            raise ConfigError(f"estimator.{sorted(rest)[0]} is only for estimator.kind: mekf")
        return None
    tracker = None if sensors is None else sensors.star_tracker
    if tracker is None and "tracker_noise_rad" not in rest:
        raise ConfigError("estimator.kind: mekf needs sensors.star_tracker (its measurement) or estimator.tracker_noise_rad")
    gyro = None if sensors is None else sensors.gyro
    spec: dict[str, Any] = {} if tracker is None else {"tracker_noise_rad": tracker.noise_rad}
    if gyro is not None:
        spec.update(gyro_angle_random_walk_rad_sqrt_s=gyro.angle_random_walk_rad_sqrt_s,
                    gyro_bias_random_walk_rad_s_sqrt_s=gyro.bias_random_walk_rad_s_sqrt_s)
    merged = {k: (list(v) if isinstance(v, tuple) else v) for k, v in {**spec, **rest}.items()}
    try:
        config: MekfConfig = from_mapping(MekfConfig, merged, "estimator")
    except ConfigError as exc:  # the config's own checks name the bare key: name it in full
        msg = str(exc)
        raise ConfigError(f"estimator.{msg[len('estimator: '):]}" if msg.startswith("estimator: ") else msg) from None
    return config


#: The key of a scenario file that names the file it extends (its own keys override the base's).
EXTENDS_KEY = "extends"
#: The key of an extending file that lists the mappings it gives whole (:func:`read_scenario_mapping`).
REPLACE_KEY = "replace"


def _merged(base: Any, over: Any) -> Any:
    """``over`` laid on ``base``: mappings merged key by key (recursively), anything else replaced."""
    if isinstance(base, dict) and isinstance(over, dict):
        return {**base, **{k: _merged(base[k], v) if k in base else v for k, v in over.items()}}
    return over


def read_scenario_mapping(path: str | Path, _seen: tuple[Path, ...] = ()) -> dict[str, Any]:
    """The mapping of a scenario file, with ``extends: <file>`` resolved: the named file (relative
    to this one's directory; a bare file name that is not there but names a bundled scenario, e.g.
    ``paper_tracking_flight.yaml``, is the bundled one) is read the same way and this file's keys
    are laid over it (mappings merged key by key, lists and values replaced), so a variant of a
    scenario states only what it changes.  ``replace: [<dotted key>, ...]`` (with ``extends``) names
    the mappings this file gives whole instead of merged (``replace: [metrics.requirements]``: the
    base's requirements dropped, this file's alone).

    Raises
    ------
    ConfigError
        If a file is missing, is not UTF-8 text or YAML, is not a mapping, or the chain of
        ``extends`` comes back to a file already in it.
    """
    p = Path(path)
    data = safe_load_yaml(read_text_file(p, "scenario", max_bytes=MAX_SCENARIO_BYTES), source=str(p))
    if not isinstance(data, dict) or EXTENDS_KEY not in data:
        return data  # scenario_from_mapping names a non-mapping
    base_name = data.pop(EXTENDS_KEY)
    if not isinstance(base_name, str) or not base_name:
        raise ConfigError(f"{p}: {EXTENDS_KEY} must name a scenario file, got {base_name!r}")
    base_path = (p.parent / base_name).resolve()
    bundled = SCENARIOS_DIR / base_name
    if not base_path.exists() and Path(base_name).name == base_name and bundled.is_file():
        base_path = bundled.resolve()  # a bundled scenario by its file name, from a file anywhere
    if base_path in _seen or base_path == p.resolve():
        raise ConfigError(f"{p}: {EXTENDS_KEY}: {base_name} comes back to a file already extended ({base_path})")
    base = read_scenario_mapping(base_path, (*_seen, p.resolve()))
    if not isinstance(base, dict):
        raise ConfigError(f"{base_path}: a scenario must be a mapping at the top level")
    for dotted in _replaced_keys(p, data.pop(REPLACE_KEY, [])):
        *parents, leaf = dotted.split(".")
        node: Any = base
        for key in parents:
            node = node.get(key) if isinstance(node, dict) else None
        if isinstance(node, dict):
            node.pop(leaf, None)  # the base's value gone: this file's alone is laid
    merged: dict[str, Any] = _merged(base, data)
    return merged


def _replaced_keys(path: Path, keys: Any) -> list[str]:
    """The ``replace`` list of a file that extends another: dotted keys (``metrics.requirements``)."""
    if not isinstance(keys, list) or not all(isinstance(k, str) and k and all(k.split(".")) for k in keys):
        raise ConfigError(f"{path}: {REPLACE_KEY} must be a list of dotted keys (e.g. [metrics.requirements]), got {quoted(keys)}")
    return keys


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario YAML file (``extends`` resolved: :func:`read_scenario_mapping`),
    or the bundled scenario of that name (``"paper_tracking"``: :func:`sappc.files.scenario_path`).

    Raises
    ------
    ConfigError
        If the file is missing (and no bundled scenario has that name), is not UTF-8 text, is not
        YAML, or any value is invalid (the message names the key).
    """
    p = scenario_path(path)
    data = read_scenario_mapping(p)
    try:
        return scenario_from_mapping(data, source=str(p))
    except ConfigError as exc:  # every message names the file, once
        raise type(exc)(str(exc) if str(exc).startswith(f"{p}: ") else f"{p}: {exc}") from None


def controller_node_parameters(scenario: Scenario, kind: ControllerKind | str | None = None, *, mode: str = "lockstep") -> dict[str, Any]:
    """The controller node's ROS parameters for a run of ``scenario``: the law's configuration, the
    period and ``mode``, the watchdog and the input bounds, and with flight modes HOLD's and SAFE's
    gains (``flight_modes``, ``hold_*``), flat names nested as a parameters file has them; not the
    graph's plumbing (expected subscribers, counts and timing files, a real-time end).  The one set
    ``sappc run`` gives the node (:func:`sappc.graph.launch.node_parameters`) and an offline bag
    records (:func:`sappc.bag.write_offline.controller_parameters`)."""
    k = scenario.resolve_controller(kind)
    flight = scenario.modes
    return {
        **unflatten(parameters_from_config(k.value, scenario.controller_config(k))),
        "control_period_s": scenario.control_period_s,
        "mode": mode,
        "stale_timeout_s": scenario.controller_node.stale_timeout_s,
        **dataclasses.asdict(scenario.controller_node.input_bounds()),  # the input plausibility bounds (offline too)
        **({"flight_modes": True, "hold_K_Nm": flight.hold_gains.K_Nm, "hold_P_Nms": flight.hold_gains.P_Nms,
            "hold_integralLimit_Nms": flight.hold_gains.integralLimit_Nms, "hold_Ki_per_kg_m2": flight.hold_gains.Ki_per_kg_m2,
            "hold_attitude": "reference" if flight.hold_on_reference else "entry"} if flight is not None else {}),
    }


def controller_params_yaml(scenario: Scenario, kind: ControllerKind | str | None = None, node_name: str = "controller") -> str:
    """A ROS parameters file for ``python -m sappc_controller`` with the scenario's controller
    parameters (``sappc params``; the files in ``config/`` are made this way)."""
    k = scenario.resolve_controller(kind)
    params = unflatten(parameters_from_config(k.value, scenario.controller_config(k)))
    params["control_period_s"] = scenario.control_period_s
    header = f"# Parameters of python -m sappc_controller ({k.value}), from scenario {scenario.name!r}.\n# Made by: sappc params <scenario> --controller {k.value}\n"
    return header + yaml.safe_dump({f"/{node_name}": {"ros__parameters": params}}, sort_keys=False)


#: Where ``estimator_params_yaml`` says a filter setting comes from when the scenario's
#: ``estimator`` section does not state it: the sensors' data sheet (docs/estimator.md).
_ESTIMATOR_SOURCES = {
    "tracker_noise_rad": "sensors.star_tracker.noise_rad (R = its square)",
    "gyro_angle_random_walk_rad_sqrt_s": "sensors.gyro.angle_random_walk_rad_sqrt_s",
    "gyro_bias_random_walk_rad_s_sqrt_s": "sensors.gyro.bias_random_walk_rad_s_sqrt_s",
    "initial_bias_rad_s": "default: no calibration (sensors.gyro.initial_bias_rad_s is the truth the filter estimates)",
    "initial_q_BN": "default: [] = start at the first tracker sample",
    "initial_attitude_sigma_rad": "default: [] = the tracker's noise",
}


def estimator_params_yaml(scenario: Scenario, node_name: str = "estimator") -> str:
    """A ROS parameters file for ``python -m sappc_estimator`` (``sappc params --estimator``): the
    scenario's ``estimator`` section, else the MEKF its ``sensors`` section gives
    (``estimator: {kind: mekf}``), each value commented with its source.

    Raises
    ------
    ConfigError
        When the scenario has neither (no star tracker to take the filter's noise from).
    """
    config = scenario.estimator
    stated: dict[str, Any] = {}
    if config is None:
        try:
            config = _estimator_from_mapping({"kind": "mekf"}, scenario.sensors)
        except ConfigError as exc:
            raise ConfigError(f"scenario {scenario.name!r} has no estimator section, and no MEKF from its sensors: {exc}") from None
    else:
        stated = dict(scenario.raw.get("estimator") or {})
    assert config is not None  # kind: mekf gives a config or raises
    values = estimator_parameters_from_config(config)
    values["control_period_s"] = scenario.control_period_s
    lines = [f"# Parameters of python -m sappc_estimator (the MEKF, docs/estimator.md), from scenario {scenario.name!r}.",
             "# Made by: sappc params <scenario> --estimator",
             "# Use: python -m sappc_estimator --ros-args --params-file <this file>; docs/estimator.md, \"The node\"",
             f"/{node_name}:", "  ros__parameters:"]
    for name, value in values.items():
        if name == "control_period_s":
            source = "control_period_s (real time: a step later than this is counted late)"
        elif name in stated:
            source = f"estimator.{name}"
        elif name.startswith("gyro_") and (scenario.sensors is None or scenario.sensors.gyro is None):
            source = "default: 0 (the scenario's sensors have no gyro model)"
        else:
            source = _ESTIMATOR_SOURCES.get(name, "default (docs/estimator.md)")
        flow = yaml.safe_dump(value, default_flow_style=True, width=1000).split("\n")[0]
        lines.append(f"    {name}: {flow}  # {source}")
    return "\n".join(lines) + "\n"

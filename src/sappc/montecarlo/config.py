"""The ``montecarlo`` section of a scenario file: distributions, dispersions, pass criteria.

Everything is validated when the section is parsed (:func:`campaign_config`), before any run.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from enum import Enum
from typing import Any

import numpy as np
from numpy.typing import NDArray

from gnc_common.validation import ConfigError, check_positive, from_mapping
from sappc.scenario import Scenario
from spacecraft_sim.core.faults import faults_from_list

__all__ = ["CampaignConfig", "Criteria", "Dispersions", "Distribution", "DistributionKind", "FaultDispersion", "GainDispersions",
           "HardwareDispersions", "InitialAttitude", "OrbitDispersions", "SensorNoise", "campaign_config"]

Array = NDArray[np.float64]


class DistributionKind(str, Enum):
    """The distributions a dispersion may take."""

    UNIFORM = "uniform"
    NORMAL = "normal"


@dataclass(frozen=True)
class Distribution:
    """A scalar or per-axis distribution.

    ``distribution: uniform`` with ``low`` and ``high`` (``low <= high``), or
    ``distribution: normal`` with ``mean`` and ``sigma`` (``sigma >= 0``);
    each value a number or a list of 3 (per axis).
    """

    distribution: DistributionKind
    low: float | tuple[float, ...] | None = None
    high: float | tuple[float, ...] | None = None
    mean: float | tuple[float, ...] | None = None
    sigma: float | tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        try:
            object.__setattr__(self, "distribution", DistributionKind(self.distribution))
        except ValueError:
            raise ConfigError(f"unknown distribution {self.distribution!r}; expected 'uniform' or 'normal'") from None
        if self.distribution is DistributionKind.UNIFORM:
            if self.low is None or self.high is None or self.mean is not None or self.sigma is not None:
                raise ConfigError("a uniform distribution takes exactly 'low' and 'high'")
            lo, hi = np.asarray(self.low, dtype=float), np.asarray(self.high, dtype=float)
            if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))) or np.any(hi < lo):
                raise ConfigError(f"needs finite low <= high, got low = {self.low!r}, high = {self.high!r}")
        elif self.distribution is DistributionKind.NORMAL:
            if self.mean is None or self.sigma is None or self.low is not None or self.high is not None:
                raise ConfigError("a normal distribution takes exactly 'mean' and 'sigma'")
            sig = np.asarray(self.sigma, dtype=float)
            if not np.all(np.isfinite(sig)) or np.any(sig < 0) or not np.all(np.isfinite(np.asarray(self.mean, dtype=float))):
                raise ConfigError(f"needs finite mean and sigma >= 0, got mean = {self.mean!r}, sigma = {self.sigma!r}")
        else:
            raise ConfigError(f"unknown distribution {self.distribution!r}; expected 'uniform' or 'normal'")

    def _params(self) -> tuple[Array, Array]:
        a, b = (self.low, self.high) if self.distribution is DistributionKind.UNIFORM else (self.mean, self.sigma)
        return np.asarray(a, dtype=float), np.asarray(b, dtype=float)

    def check_shape(self, name: str, shape: tuple[int, ...]) -> None:
        """Raise unless the parameters broadcast to ``shape`` (``()`` scalar, ``(3,)`` per axis)."""
        a, b = self._params()
        try:
            if np.broadcast_shapes(a.shape, b.shape, shape) != shape:
                raise ValueError
        except ValueError:
            raise ConfigError(f"{name} must have {'scalar' if not shape else f'scalar or {shape[0]}-vector'} parameters, got {self!r}") from None

    def draw(self, rng: np.random.Generator, shape: tuple[int, ...]) -> Array:
        """Independent draws of the given shape (``(3,)``: one per axis)."""
        a, b = self._params()
        if self.distribution is DistributionKind.UNIFORM:
            return a + (b - a) * rng.random(shape)
        return a + b * rng.standard_normal(shape)


@dataclass(frozen=True)
class InitialAttitude:
    """Initial attitude from Euler angles, each uniform in ``[low_deg, high_deg]``, applied in ``sequence``
    (upper case: intrinsic rotations about body axes, scipy's convention)."""

    sequence: str = "ZYX"
    low_deg: float = -85.0
    high_deg: float = 85.0

    def __post_init__(self) -> None:
        if len(self.sequence) != 3 or not (self.sequence.isupper() or self.sequence.islower()) or set(self.sequence.upper()) - set("XYZ"):
            raise ConfigError(f"sequence must be three axis letters like 'ZYX' (intrinsic) or 'zyx' (extrinsic), got {self.sequence!r}")
        if not (np.isfinite(self.low_deg) and np.isfinite(self.high_deg)) or self.high_deg < self.low_deg:
            raise ConfigError(f"needs low_deg <= high_deg, got {self.low_deg!r}, {self.high_deg!r}")


@dataclass(frozen=True)
class SensorNoise:
    """White measurement noise, a new draw every control period: a small rotation of the measured
    attitude (standard deviation per axis [rad]) and an additive rate error [rad/s]."""

    attitude_sigma_rad: float = 0.0
    rate_sigma_rad_s: float = 0.0

    def __post_init__(self) -> None:
        check_positive("attitude_sigma_rad", self.attitude_sigma_rad, allow_zero=True)
        check_positive("rate_sigma_rad_s", self.rate_sigma_rad_s, allow_zero=True)

    @property
    def enabled(self) -> bool:
        return self.attitude_sigma_rad > 0.0 or self.rate_sigma_rad_s > 0.0


#: SAPPC/TraPPC gains a campaign may disperse (per run; the law broadcasts them).
DISPERSIBLE_GAINS = ("K_q", "K_omega", "D_m_Nm", "mu_rad_s")


@dataclass(frozen=True)
class GainDispersions:
    """Per-run controller gains of the backstepping law (SAPPC, TraPPC); each a uniform
    distribution with ``low > 0`` (a normal one could draw non-positive gains)."""

    K_q: Distribution | None = None
    K_omega: Distribution | None = None
    D_m_Nm: Distribution | None = None
    mu_rad_s: Distribution | None = None

    def __post_init__(self) -> None:
        for name in DISPERSIBLE_GAINS:
            d = getattr(self, name)
            if d is not None:
                d.check_shape(name, ())
                if d.distribution is not DistributionKind.UNIFORM or not np.min(d.low) > 0.0:
                    raise ConfigError(f"{name} must be a uniform distribution with low > 0, got {d!r}")

    def items(self) -> list[tuple[str, Distribution]]:
        return [(n, getattr(self, n)) for n in DISPERSIBLE_GAINS if getattr(self, n) is not None]


@dataclass(frozen=True)
class FaultDispersion:
    """One fault per run, drawn: which (one of ``choices``, uniformly), when (``start_s``) and for
    how long (``duration_s``; omitted: to the end of the run).  The fault is added to the
    scenario's own ``faults`` list for that run.

    ``choices`` are fault entries as in a scenario's ``faults:`` list, without ``start_s`` and
    ``end_s`` (e.g. ``{kind: sensor_dropout}``, ``{kind: actuator_effectiveness, effectiveness:
    [0.5, 0.5, 0.5]}``); at most one ``sensor_noise`` entry (its draws are shared by the runs).
    ``duration_s`` must be a uniform distribution with ``low > 0``."""

    choices: tuple[dict[str, Any], ...]
    start_s: Distribution
    duration_s: Distribution | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.choices, tuple) or not self.choices:
            raise ConfigError(f"dispersions.faults.choices must be a non-empty list of fault entries, got {self.choices!r}")
        for i, entry in enumerate(self.choices):
            if not isinstance(entry, dict) or {"start_s", "end_s"} & set(entry):
                raise ConfigError(f"dispersions.faults.choices[{i}] must be a fault entry without start_s/end_s (they are drawn), got {entry!r}")
        faults_from_list([dict(e) for e in self.choices], "dispersions.faults.choices")
        if sum(1 for e in self.choices if e.get("kind") == "sensor_noise") > 1:
            raise ConfigError("dispersions.faults.choices may hold one sensor_noise entry at most (its draws are shared by the runs)")
        self.start_s.check_shape("dispersions.faults.start_s", ())
        if self.duration_s is not None:
            self.duration_s.check_shape("dispersions.faults.duration_s", ())
            if self.duration_s.distribution is not DistributionKind.UNIFORM or not np.min(np.asarray(self.duration_s.low, dtype=float)) > 0.0:
                raise ConfigError(f"dispersions.faults.duration_s must be a uniform distribution with low > 0, got {self.duration_s!r}")

    def draw(self, rng: np.random.Generator) -> tuple[int, float, float]:
        """``(choice, start_s, duration_s)`` of one run (``duration_s = inf``: to the end); a start
        drawn below 0 starts at 0."""
        choice = int(rng.integers(len(self.choices)))
        start = max(0.0, float(self.start_s.draw(rng, ())))
        duration = float(self.duration_s.draw(rng, ())) if self.duration_s is not None else float("inf")
        return choice, start, duration

    def fault(self, choice: int, start_s: float, duration_s: float) -> Any:
        """The drawn fault, validated as a scenario's."""
        entry = {**self.choices[choice], "start_s": start_s, **({"end_s": start_s + duration_s} if np.isfinite(duration_s) else {})}
        return faults_from_list([entry], "dispersions.faults")[0]


@dataclass(frozen=True)
class HardwareDispersions:
    """Per-run draws of the scenario's reaction wheels and sensors (each needs the section it
    disperses: ``actuator.kind: reaction_wheels``, ``sensors.star_tracker``, ``sensors.gyro``).
    Scalar distributions, drawn independently per wheel or per axis; a ``*_relative`` draw ``u``
    multiplies the nominal value by ``1 + u`` (``u > -1`` for an inertia, a torque limit or a
    sigma: uniform with ``low > -1``, or normal, whose rare draws below -1 stop the run's set-up).

    Attributes
    ----------
    wheel_spin_inertia_relative, wheel_max_torque_relative, wheel_friction_relative : Distribution
        Per wheel: ``Js``, the motor torque limit, and both friction coefficients.
    wheel_initial_speed_rad_s : Distribution
        Per wheel, added to the initial speed [rad/s].
    star_tracker_noise_relative : Distribution
        Per axis, the tracker's sigma.
    gyro_initial_bias_rad_s : Distribution
        Per axis, added to the gyro's initial bias [rad/s].
    star_tracker_outage_start_s, star_tracker_outage_duration_s : Distribution
        One tracker outage per run (added to the scenario's): its start [s] (a draw below 0 starts
        at 0) and its duration [s] (uniform with ``low > 0``); given together.
    """

    wheel_spin_inertia_relative: Distribution | None = None
    wheel_max_torque_relative: Distribution | None = None
    wheel_friction_relative: Distribution | None = None
    wheel_initial_speed_rad_s: Distribution | None = None
    star_tracker_noise_relative: Distribution | None = None
    gyro_initial_bias_rad_s: Distribution | None = None
    star_tracker_outage_start_s: Distribution | None = None
    star_tracker_outage_duration_s: Distribution | None = None
    #: Wheels of the scenario (set by :func:`campaign_config`): how many per-wheel values a run draws.
    n_wheels: int = dataclasses.field(default=0, init=False)

    def __post_init__(self) -> None:
        for name, dist in self.items():
            dist.check_shape(f"dispersions.hardware.{name}", ())
        start, duration = self.star_tracker_outage_start_s, self.star_tracker_outage_duration_s
        if (start is None) != (duration is None):
            raise ConfigError("dispersions.hardware.star_tracker_outage_start_s and star_tracker_outage_duration_s go together")
        if duration is not None and (duration.distribution is not DistributionKind.UNIFORM
                                     or not np.min(np.asarray(duration.low, dtype=float)) > 0.0):
            raise ConfigError(f"dispersions.hardware.star_tracker_outage_duration_s must be a uniform distribution with low > 0, "
                              f"got {duration!r}")

    def items(self) -> list[tuple[str, Distribution]]:
        return [(f.name, getattr(self, f.name)) for f in dataclasses.fields(self) if f.init and getattr(self, f.name) is not None]

    def check_against(self, scenario: Scenario) -> None:
        """Each dispersion needs the section it disperses; records the scenario's wheel count."""
        for name, _ in self.items():
            missing = (("actuator.kind: reaction_wheels" if name.startswith("wheel_") and scenario.wheels is None else None)
                       or ("sensors.star_tracker" if name.startswith("star_tracker_") and (scenario.sensors is None or scenario.sensors.star_tracker is None)
                           else None)
                       or ("sensors.gyro" if name.startswith("gyro_") and (scenario.sensors is None or scenario.sensors.gyro is None) else None))
            if missing:
                raise ConfigError(f"montecarlo.dispersions.hardware.{name} needs the scenario's {missing}")
        object.__setattr__(self, "n_wheels", 0 if scenario.wheels is None else scenario.wheels.n)

    def draw(self, rng: np.random.Generator) -> dict[str, Array]:
        """One run's draws: (n_wheels,) per wheel, (3,) per axis, (1,) per outage, in the order of the fields."""
        return {name: dist.draw(rng, (self.n_wheels,) if name.startswith("wheel_") else (1,) if "outage" in name else (3,))
                for name, dist in self.items()}


@dataclass(frozen=True)
class OrbitDispersions:
    """Per-run draws of the scenario's orbit (needs its ``orbit`` section), each scalar and added to
    the scenario's value: where the spacecraft is on its orbit at ``t = 0`` and where the Earth, and
    with it the field's dipole, has turned to (the field's epoch: the dipole is fixed to the Earth,
    so the epoch of a run is its Earth rotation angle at ``t = 0``).

    Attributes
    ----------
    mean_anomaly_deg : Distribution
        The orbit's phase at ``t = 0`` [deg].
    raan_deg : Distribution
        The ascending node's right ascension [deg] (the orbit plane's angle to the Earth's
        dipole at ``t = 0``).
    earth_rotation_angle_deg : Distribution
        The Earth's rotation angle at ``t = 0`` [deg]: the field's epoch.
    """

    mean_anomaly_deg: Distribution | None = None
    raan_deg: Distribution | None = None
    earth_rotation_angle_deg: Distribution | None = None

    def __post_init__(self) -> None:
        for name, dist in self.items():
            dist.check_shape(f"dispersions.orbit.{name}", ())

    def items(self) -> list[tuple[str, Distribution]]:
        return [(f.name, getattr(self, f.name)) for f in dataclasses.fields(self) if getattr(self, f.name) is not None]

    def check_against(self, scenario: Scenario) -> None:
        """An orbit dispersion needs the scenario's orbit."""
        if self.items() and scenario.environment is None:
            raise ConfigError(f"montecarlo.dispersions.orbit.{self.items()[0][0]} needs the scenario's orbit section")

    def draw(self, rng: np.random.Generator) -> dict[str, Array]:
        """One run's draws, (1,) each, in the order of the fields (none unless dispersed: no draw taken)."""
        return {f"orbit_{name}": dist.draw(rng, (1,)) for name, dist in self.items()}


@dataclass(frozen=True)
class Dispersions:
    """What varies from run to run besides the initial attitude (all optional).

    Attributes
    ----------
    initial_rate_rad_s : Distribution
        Initial body rate, per axis [rad/s].
    inertia_relative : Distribution
        ``u`` per axis: the plant's inertia is ``S J S`` with ``S = diag(sqrt(1 + u))``,
        symmetric positive definite for ``u > -1`` (a congruence).  The controller keeps the
        nominal ``J`` (what flight software knows).
    disturbance_scale, disturbance_phase_rad : Distribution
        Scale and phase of the paper's periodic disturbance (scalar per run).
    sensor_noise : SensorNoise
    gains : GainDispersions
        Per-run controller gains (``K_q``, ``K_omega``, ``D_m_Nm``, ``mu_rad_s``).
    faults : FaultDispersion
        One drawn fault per run (kind, start, duration), added to the scenario's faults.
    hardware : HardwareDispersions
        The scenario's reaction wheels and sensors, per run.
    orbit : OrbitDispersions
        The scenario's orbit phase, node and field epoch, per run.
    """

    initial_rate_rad_s: Distribution | None = None
    inertia_relative: Distribution | None = None
    disturbance_scale: Distribution | None = None
    disturbance_phase_rad: Distribution | None = None
    sensor_noise: SensorNoise = SensorNoise()
    gains: GainDispersions = GainDispersions()
    faults: FaultDispersion | None = None
    hardware: HardwareDispersions = HardwareDispersions()
    orbit: OrbitDispersions = OrbitDispersions()


@dataclass(frozen=True)
class Criteria:
    """Pass criteria of a run (the paper's experiment 4)."""

    rpf_error_at_t2_max: float = 1e-4
    steady_mean_abs_qev_max: float = 5e-5


@dataclass(frozen=True)
class CampaignConfig:
    """The ``montecarlo`` section of a scenario file.

    Attributes
    ----------
    initial_attitude : InitialAttitude or None
        ``null``: every run starts from the scenario's ``initial_state.q_BN`` (a campaign about a
        nominal case, e.g. ``sappc tune`` on experiment 1).
    dispersions : Dispersions
    criteria : Criteria
    chunk_runs : int
        Runs per batch (a unit of work and of resumption); results do not depend on it.
    trajectory_runs : int
        How many runs (the first ones) keep a down-sampled trajectory for the overlay figure.
    trajectory_stride : int
        Keep every ``trajectory_stride``-th sample of those trajectories.
    """

    initial_attitude: InitialAttitude | None = InitialAttitude()
    dispersions: Dispersions = Dispersions()
    criteria: Criteria = Criteria()
    chunk_runs: int = 500
    trajectory_runs: int = 300
    trajectory_stride: int = 10

    def __post_init__(self) -> None:
        for name in ("chunk_runs", "trajectory_stride"):
            v = getattr(self, name)
            if not isinstance(v, int) or v < 1:
                raise ConfigError(f"{name} must be a positive integer, got {v!r}")
        if not isinstance(self.trajectory_runs, int) or self.trajectory_runs < 0:
            raise ConfigError(f"trajectory_runs must be a non-negative integer, got {self.trajectory_runs!r}")
        d = self.dispersions
        for name, shape in (("initial_rate_rad_s", (3,)), ("inertia_relative", (3,)), ("disturbance_scale", ()), ("disturbance_phase_rad", ())):
            dist = getattr(d, name)
            if dist is not None:
                dist.check_shape(f"dispersions.{name}", shape)
        inertia = self.dispersions.inertia_relative
        if inertia is not None:
            low, _ = inertia._params()
            lowest = float(np.min(low)) if inertia.distribution is DistributionKind.UNIFORM else -np.inf
            if inertia.distribution is DistributionKind.NORMAL and np.all(np.asarray(inertia.sigma) == 0):
                lowest = float(np.min(low))  # mean (the first parameter of a normal)
            if not lowest > -1.0:
                raise ConfigError(
                    "dispersions.inertia_relative must stay above -1 (S J S with S = diag(sqrt(1 + u)) is positive "
                    f"definite only then); got {inertia!r}" + (" (a normal distribution is unbounded)" if inertia.distribution is DistributionKind.NORMAL else "")
                )


def campaign_config(scenario: Scenario) -> CampaignConfig:
    """Parse and validate the scenario's ``montecarlo`` section (before any run starts)."""
    section = scenario.raw.get("montecarlo")
    if section is None:
        raise ConfigError(f"scenario {scenario.name!r} has no 'montecarlo' section")
    config: CampaignConfig = from_mapping(CampaignConfig, section, "montecarlo")
    config.dispersions.hardware.check_against(scenario)
    config.dispersions.orbit.check_against(scenario)
    return config

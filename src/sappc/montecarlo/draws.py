"""The random inputs of each run of a campaign, from its own seed.

Every random input of run ``k`` comes from ``SeedSequence(seed, spawn_key=(k,))``: its first
child draws the dispersed values (:func:`draw_inputs`), its second the sensor noise
(:func:`sensor_noise_draws`, the whole run's before the loop).  A run therefore depends only on
``(seed, k)``.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from gnc_common.attitude import euler_to_quaternion
from gnc_common.validation import ConfigError
from spacecraft_sim.core.disturbance import DisturbanceSum, PaperPeriodic
from spacecraft_sim.core.sensors import S_BIAS0, ST_SIGMA
from spacecraft_sim.core.wheels import ReactionWheels
from sappc.montecarlo.config import CampaignConfig
from sappc.scenario import Scenario

if TYPE_CHECKING:
    from sappc.offline.compiled_loop import NoiseStreams

__all__ = ["NOISE_BLOCK", "RunInputs", "dispersed_disturbance", "draw_inputs", "run_faults", "run_generators", "run_hardware", "run_orbits", "sensor_noise_draws",
           "sensor_noise_streams"]

#: Samples of sensor noise drawn per call of the run's noise generator (``standard_normal((NOISE_BLOCK, 6))``,
#: block after block): the sequence campaigns have always used.
NOISE_BLOCK = 256

Array = NDArray[np.float64]


@dataclass(frozen=True)
class RunInputs:
    """Dispersed inputs of a set of runs, arrays with a leading axis of runs."""

    runs: NDArray[np.int64]
    euler_deg: Array
    q_BN0: Array
    omega_BN_B0: Array
    inertia_relative: Array
    disturbance_scale: Array
    disturbance_phase_rad: Array
    gains: dict[str, Array]
    fault_choice: NDArray[np.int64]  # index into dispersions.faults.choices (-1: no fault dispersion)
    fault_start_s: Array
    fault_duration_s: Array  # inf: to the end
    hardware: dict[str, Array] = dataclasses.field(default_factory=dict)  # per name (n, W or 3): HardwareDispersions; (n, 1) orbit_*: OrbitDispersions


def run_generators(seed: int, run: int) -> tuple[np.random.Generator, np.random.Generator]:
    """Run ``run``'s two generators: its dispersions' and its sensor noise's, the two children of
    ``SeedSequence(seed, spawn_key=(run,))`` (:func:`_run_generator`)."""
    return _run_generator(seed, run, 0), _run_generator(seed, run, 1)


def _run_generator(seed: int, run: int, child: int) -> np.random.Generator:
    """Child ``child`` of run ``run``'s seed sequence, made alone: ``SeedSequence(seed,
    spawn_key=(run,)).spawn(2)[child]`` is ``SeedSequence(seed, spawn_key=(run, child))`` (numpy's
    ``spawn``), so a campaign's draws need not make the other (0.02 s of 1500 runs' draws)."""
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(run, child)))


def draw_inputs(cfg: CampaignConfig, seed: int, runs: Iterable[int]) -> RunInputs:
    """The dispersed values of ``runs``: each run's from its own generator, in a fixed order."""
    runs_arr = np.fromiter(runs, dtype=np.int64)
    d = cfg.dispersions
    rows = []
    for k in runs_arr:
        rng = _run_generator(seed, int(k), 0)  # the dispersions'
        ia = cfg.initial_attitude
        euler = rng.uniform(ia.low_deg, ia.high_deg, 3) if ia is not None else np.full(3, np.nan)  # None: the scenario's own
        rate = d.initial_rate_rad_s.draw(rng, (3,)) if d.initial_rate_rad_s else np.zeros(3)
        inertia = d.inertia_relative.draw(rng, (3,)) if d.inertia_relative else np.zeros(3)
        scale = float(d.disturbance_scale.draw(rng, ())) if d.disturbance_scale else 1.0
        phase = float(d.disturbance_phase_rad.draw(rng, ())) if d.disturbance_phase_rad else 0.0
        gains = {name: float(dist.draw(rng, ())) for name, dist in d.gains.items()}
        fault = d.faults.draw(rng) if d.faults is not None else (-1, np.nan, np.nan)  # after the older ones: older campaigns keep their draws
        hardware = d.hardware.draw(rng)  # (none unless dispersed: no draw taken)
        hardware.update(d.orbit.draw(rng))  # after the hardware: older campaigns keep their draws
        rows.append((euler, rate, inertia, scale, phase, gains, fault, hardware))
    euler = np.array([r[0] for r in rows]).reshape(-1, 3)
    return RunInputs(
        runs=runs_arr,
        euler_deg=euler,
        q_BN0=(euler_to_quaternion(np.radians(euler), cfg.initial_attitude.sequence).reshape(-1, 4) if cfg.initial_attitude is not None
               else np.full((len(rows), 4), np.nan)),  # NaN: the scenario's initial attitude (the caller's)
        omega_BN_B0=np.array([r[1] for r in rows]).reshape(-1, 3),
        inertia_relative=np.array([r[2] for r in rows]).reshape(-1, 3),
        disturbance_scale=np.array([r[3] for r in rows]),
        disturbance_phase_rad=np.array([r[4] for r in rows]),
        gains={name: np.array([r[5][name] for r in rows]) for name, _ in d.gains.items()},
        fault_choice=np.array([r[6][0] for r in rows], dtype=np.int64),
        fault_start_s=np.array([r[6][1] for r in rows], dtype=np.float64),
        fault_duration_s=np.array([r[6][2] for r in rows], dtype=np.float64),
        hardware={name: np.array([r[7][name] for r in rows]).reshape(len(rows), -1)
                  for name in [n for n, _ in d.hardware.items()] + [f"orbit_{n}" for n, _ in d.orbit.items()]},
    )


def run_hardware(scenario: Scenario, inputs: RunInputs) -> tuple[list[ReactionWheels] | None, Array | None, Array | None]:
    """Each run's wheel set, sensor parameters (``Sensors.params`` rows) and tracker outages (n, K,
    2) [s] with its hardware dispersions applied; ``None`` where nothing of that kind is dispersed
    (the scenario's)."""
    hw, n = inputs.hardware, inputs.runs.size
    wheels = None
    if scenario.wheels is not None and any(k.startswith("wheel_") for k in hw):
        w0 = scenario.wheels
        one = np.ones((n, w0.n))

        def scaled(attr: str, key: str) -> Array:
            return w0.per_wheel(attr)[None] * (1.0 + hw[key] if key in hw else one)

        speed = w0.per_wheel("initial_speed_rad_s")[None] + hw.get("wheel_initial_speed_rad_s", 0.0 * one)
        cols = {"spin_inertia_kg_m2": scaled("spin_inertia_kg_m2", "wheel_spin_inertia_relative"),
                "max_torque_Nm": scaled("max_torque_Nm", "wheel_max_torque_relative"),
                "coulomb_friction_Nm": scaled("coulomb_friction_Nm", "wheel_friction_relative"),
                "viscous_friction_Nm_s": scaled("viscous_friction_Nm_s", "wheel_friction_relative"), "initial_speed_rad_s": speed}
        wheels = []
        for k in range(n):
            try:
                changes: dict[str, Any] = {a: tuple(float(v) for v in c[k]) for a, c in cols.items()}
                wheels.append(dataclasses.replace(w0, **changes))
            except ConfigError as exc:
                raise ConfigError(f"montecarlo.dispersions.hardware: run {int(inputs.runs[k])} drew an invalid wheel set: {exc}") from None
    sensors = None
    if scenario.sensors is not None and ("star_tracker_noise_relative" in hw or "gyro_initial_bias_rad_s" in hw):
        sensors = np.tile(scenario.sensors.params(scenario.control_period_s), (n, 1))
        if "star_tracker_noise_relative" in hw:
            if np.any(hw["star_tracker_noise_relative"] < -1.0):
                raise ConfigError("montecarlo.dispersions.hardware.star_tracker_noise_relative drew a value below -1 (a negative sigma)")
            sensors[:, ST_SIGMA:ST_SIGMA + 3] *= 1.0 + hw["star_tracker_noise_relative"]
        if "gyro_initial_bias_rad_s" in hw:
            sensors[:, S_BIAS0:S_BIAS0 + 3] += hw["gyro_initial_bias_rad_s"]
    outages = None
    if scenario.sensors is not None and "star_tracker_outage_start_s" in hw:
        start = np.maximum(hw["star_tracker_outage_start_s"][:, 0], 0.0)
        drawn = np.stack((start, start + hw["star_tracker_outage_duration_s"][:, 0]), axis=1)[:, None, :]  # (n, 1, 2)
        own = np.broadcast_to(scenario.sensors.outages()[None], (n, scenario.sensors.outages().shape[0], 2))
        outages = np.ascontiguousarray(np.concatenate((own, drawn), axis=1))
    return wheels, sensors, outages


def run_orbits(scenario: Scenario, inputs: RunInputs) -> Array | None:
    """Each run's orbit parameters (n, ``N_ORBIT_PARAMS``) (:meth:`~spacecraft_sim.core.orbit.Orbit.params`)
    with its orbit dispersions added to the scenario's values; ``None`` when the orbit is not
    dispersed (every run has the scenario's)."""
    drawn = {k[len("orbit_"):]: v[:, 0] for k, v in inputs.hardware.items() if k.startswith("orbit_")}
    if not drawn or scenario.environment is None:
        return None
    orbit = scenario.environment.orbit
    return np.array([dataclasses.replace(orbit, **{name: float(getattr(orbit, name) + values[k]) for name, values in drawn.items()}).params()
                     for k in range(inputs.runs.size)]).reshape(inputs.runs.size, -1)


def run_faults(scenario: Scenario, cfg: CampaignConfig, inputs: RunInputs) -> list[tuple[Any, ...]] | None:
    """Each run's faults: the scenario's plus its drawn one; ``None`` without a fault dispersion
    (every run has the scenario's)."""
    disp = cfg.dispersions.faults
    if disp is None:
        return None
    return [tuple(scenario.faults) + (disp.fault(int(c), float(s), float(d)),)
            for c, s, d in zip(inputs.fault_choice, inputs.fault_start_s, inputs.fault_duration_s)]


def sensor_noise_draws(seed: int, runs: Iterable[int], n_samples: int, width: int = 6) -> Array:
    """Standard normals (n, n_samples, width) of the sensors of ``runs``: each run's from its own
    second generator, drawn in blocks of :data:`NOISE_BLOCK` samples as the campaign has always
    drawn them, sample ``k`` of the run in row ``k`` (the compiled loop's
    :func:`spacecraft_sim.core.sensors.measure` reads them).  ``width`` 6: the white-noise model
    (``dispersions.sensor_noise``), as earlier campaigns drew it; 9: the scenario's sensors (the
    gyro's bias walk too)."""
    runs_list = [int(k) for k in runs]
    n_blocks = -(-n_samples // NOISE_BLOCK)
    out = np.empty((len(runs_list), n_blocks * NOISE_BLOCK, width))
    for i, k in enumerate(runs_list):
        rng = _run_generator(seed, k, 1)  # the sensor noise's
        for b in range(n_blocks):
            out[i, b * NOISE_BLOCK : (b + 1) * NOISE_BLOCK] = rng.standard_normal((NOISE_BLOCK, width))
    return out[:, :n_samples]


def sensor_noise_streams(seed: int, runs: Iterable[int], width: int = 6) -> NoiseStreams:
    """The draws of :func:`sensor_noise_draws` as streams, drawn block by block while the runs run
    (:class:`~sappc.offline.compiled_loop.NoiseStreams`): each run's second generator, whose rows
    in blocks of any size are the rows of :func:`sensor_noise_draws` (a ``Generator`` fills in
    order), without the whole run's (T, width) array."""
    from sappc.offline.compiled_loop import NoiseStreams

    return NoiseStreams([functools.partial(_noise_generator, seed, int(k)) for k in runs], width)


def _noise_generator(seed: int, run: int) -> np.random.Generator:
    """Run ``run``'s sensor-noise generator (its second: :func:`run_generators`)."""
    return _run_generator(seed, run, 1)


def dispersed_disturbance(scenario: Scenario, inputs: RunInputs) -> DisturbanceSum:
    """The scenario's disturbances with the paper model's scale and phase set per run."""
    models = []
    for m in scenario.disturbance.models:
        if isinstance(m, PaperPeriodic):
            m = dataclasses.replace(
                m,
                scale=tuple(inputs.disturbance_scale * np.asarray(m.scale, dtype=float)),
                phase_rad=tuple(inputs.disturbance_phase_rad + np.asarray(m.phase_rad, dtype=float)),
            )
        models.append(m)
    return DisturbanceSum(tuple(models))

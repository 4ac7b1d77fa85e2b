"""The per-run seeding of a campaign (:mod:`sappc.montecarlo.draws`), pinned by golden values.

The recipe that ``summary.json`` and ``runs.csv`` document (``seed_sequence: {entropy: S,
spawn_key: [k]}``, docs/tutorials/monte-carlo.md, "Reproducible at any scale"): every random input of run ``k`` of seed ``S`` comes
from ``SeedSequence(S, spawn_key=(k,)).spawn(2)``; the first child's ``default_rng`` draws, in
this order, the three Euler angles (``uniform(low_deg, high_deg, 3)``), the initial rate, the
relative inertia (3 each), the disturbance scale, the disturbance phase, then the dispersed gains
in :data:`~sappc.montecarlo.config.DISPERSIBLE_GAINS` order (a uniform ``low + (high - low) U``, a
normal ``mean + sigma N``); the second child's draws the sensor noise, ``standard_normal((256,
6))`` block after block.  The golden numbers below were computed from that recipe with numpy
alone (not with the module), and equal the module's output.  They pin the recipe: a campaign's
``--seed S`` names the same runs forever, so a change to it must be deliberate (and these values
regenerated with it), never a side effect.

Tolerances: exact.  The values are float64 arithmetic on PCG64's output with the pinned numpy; no
transcendental function is involved, so the bits are the same on every IEEE-754 machine.  Only
the initial quaternion (trigonometric functions of the angles) is compared at 4e-16.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest
import yaml

from conftest import SCENARIOS
from sappc.montecarlo.config import campaign_config
from sappc.montecarlo.draws import dispersed_disturbance, draw_inputs, run_faults, run_generators, sensor_noise_draws
from sappc.scenario import scenario_from_mapping
from spacecraft_sim.core.disturbance import ConstantTorque, PaperPeriodic
from spacecraft_sim.core.faults import SensorDropout, faults_from_list

BASE = yaml.safe_load((SCENARIOS / "paper_montecarlo.yaml").read_text())
#: Every dispersion on, per-axis sigmas distinct (an axis mix-up shows); the gains listed in the
#: reverse of their draw order (the order is DISPERSIBLE_GAINS', not the file's).
DISPERSIONS = {
    "initial_rate_rad_s": {"distribution": "normal", "mean": 0.0, "sigma": [1e-3, 2e-3, 3e-3]},
    "inertia_relative": {"distribution": "uniform", "low": -0.05, "high": 0.05},
    "disturbance_scale": {"distribution": "uniform", "low": 0.8, "high": 1.2},
    "disturbance_phase_rad": {"distribution": "uniform", "low": 0.0, "high": 6.283185307179586},
    "sensor_noise": {"attitude_sigma_rad": 1e-6, "rate_sigma_rad_s": 1e-6},
    "gains": {"mu_rad_s": {"distribution": "uniform", "low": 6e-5, "high": 8e-5},
              "K_q": {"distribution": "uniform", "low": 0.25, "high": 0.35}},
}
SEED, RUN = 2026, 41

# Run 41 of seed 2026, from SeedSequence(2026, spawn_key=(41,)).spawn(2) (module docstring).
GOLDEN_EULER_DEG = [-68.34319843661866, 57.25845600010129, -5.94464972910265]
GOLDEN_RATE_RAD_S = [0.00032963644441411305, 0.0012265645248160145, -0.0025384649412802545]
GOLDEN_INERTIA_RELATIVE = [0.03358791414228664, -0.04075254766009348, 0.013078543639938295]
GOLDEN_DISTURBANCE_SCALE = 1.0216235860040395
GOLDEN_DISTURBANCE_PHASE_RAD = 4.207633237212429
GOLDEN_GAINS = {"K_q": 0.3256094445464557, "mu_rad_s": 7.643653777810698e-05}
#: ZYX intrinsic Euler angles above as (x, y, z, w).
GOLDEN_Q_BN0 = [0.23110159294028856, 0.42145120591439345, -0.4717833390048177, 0.7391829379870924]
#: The run's sensor-noise standard normals: sample 0 and sample 299 (in the second block).
GOLDEN_NOISE_0 = [0.9785698173558448, 0.6581981989474438, 2.2550546138318324, -2.4303548881187766, -0.29972677917173124, -0.9173990175988236]
GOLDEN_NOISE_299 = [0.08533640197435517, 2.33391497747242, 1.0048930385311097, 0.29576756744699184, 1.7239658212472628, 1.2928612234270487]


def _config(dispersions: dict, disturbances: list | None = None):  # type: ignore[no-untyped-def,type-arg]
    raw = copy.deepcopy(BASE)
    raw["montecarlo"]["dispersions"] = copy.deepcopy(dispersions)
    if disturbances is not None:
        raw["disturbances"] = disturbances
    scenario = scenario_from_mapping(raw)
    return scenario, campaign_config(scenario)


def test_run_k_of_seed_s_draws_the_documented_golden_values() -> None:
    _, cfg = _config(DISPERSIONS)
    d = draw_inputs(cfg, SEED, [RUN])
    assert d.runs.tolist() == [RUN]
    assert d.euler_deg.tolist() == [GOLDEN_EULER_DEG]
    assert d.omega_BN_B0.tolist() == [GOLDEN_RATE_RAD_S]
    assert d.inertia_relative.tolist() == [GOLDEN_INERTIA_RELATIVE]
    assert d.disturbance_scale.tolist() == [GOLDEN_DISTURBANCE_SCALE]
    assert d.disturbance_phase_rad.tolist() == [GOLDEN_DISTURBANCE_PHASE_RAD]
    assert {name: v.tolist() for name, v in d.gains.items()} == {name: [v] for name, v in GOLDEN_GAINS.items()}
    np.testing.assert_allclose(d.q_BN0, [GOLDEN_Q_BN0], rtol=0, atol=4e-16)


def test_run_k_draws_the_same_values_alone_or_among_other_runs() -> None:
    """The values of a run depend on (seed, run) only: the same in any set or order of runs."""
    _, cfg = _config(DISPERSIONS)
    d = draw_inputs(cfg, SEED, iter([7, RUN, 0]))  # any iterable of run numbers
    assert d.runs.tolist() == [7, RUN, 0] and d.euler_deg.shape == (3, 3) and d.q_BN0.shape == (3, 4)
    assert d.euler_deg[1].tolist() == GOLDEN_EULER_DEG and d.omega_BN_B0[1].tolist() == GOLDEN_RATE_RAD_S
    assert d.gains["K_q"][1] == GOLDEN_GAINS["K_q"] and d.disturbance_phase_rad[1] == GOLDEN_DISTURBANCE_PHASE_RAD
    assert d.euler_deg[0].tolist() != d.euler_deg[2].tolist()


def test_the_euler_angles_are_drawn_first_and_nothing_else_without_dispersions() -> None:
    """Without dispersions a run still draws its three Euler angles first (the same values as
    with them); rate and relative inertia are zero, scale one, phase zero, no gains."""
    _, cfg = _config({})
    d = draw_inputs(cfg, SEED, [RUN, 3, 4])
    assert d.euler_deg[0].tolist() == GOLDEN_EULER_DEG
    assert d.omega_BN_B0.shape == d.inertia_relative.shape == (3, 3)
    assert not np.any(d.omega_BN_B0) and not np.any(d.inertia_relative)
    assert d.disturbance_scale.tolist() == [1.0, 1.0, 1.0] and d.disturbance_phase_rad.tolist() == [0.0, 0.0, 0.0]
    assert d.gains == {}


def test_the_sensor_noise_of_run_k_is_its_second_generators_stream() -> None:
    """Sample 0 and sample 299 (past the first 256-sample block) of run k's noise are golden; the
    first generator (dispersions) and the second (noise) are the two children of its seed sequence."""
    draws = sensor_noise_draws(SEED, [RUN], 300)
    assert draws.shape == (1, 300, 6)
    assert draws[0, 0].tolist() == GOLDEN_NOISE_0 and draws[0, 299].tolist() == GOLDEN_NOISE_299
    dispersion, noise = run_generators(SEED, RUN)
    assert dispersion.uniform(-85.0, 85.0, 3).tolist() == GOLDEN_EULER_DEG
    assert noise.standard_normal(6).tolist() == GOLDEN_NOISE_0


@pytest.mark.parametrize("n_samples", [1, 255, 256, 257])
def test_sensor_noise_has_exactly_the_requested_samples_at_block_edges(n_samples: int) -> None:
    draws = sensor_noise_draws(SEED, [RUN, 2], n_samples)
    assert draws.shape == (2, n_samples, 6)
    assert draws[0, 0].tolist() == GOLDEN_NOISE_0
    _, noise = run_generators(SEED, 2)
    assert np.array_equal(draws[1], noise.standard_normal((n_samples, 6)))


def test_the_paper_disturbance_is_scaled_and_shifted_per_run_and_the_others_kept() -> None:
    """``dispersed_disturbance``: the paper model's ``scale`` times the run's scale and its
    ``phase_rad`` plus the run's phase, per run; other models unchanged, in list order."""
    scenario, cfg = _config(DISPERSIONS, [{"kind": "constant", "torque_Nm": [1e-3, 0.0, 0.0]},
                                          {"kind": "paper_periodic", "omega_p_rad_s": 0.01, "scale": 2.0, "phase_rad": 0.5}])
    d = draw_inputs(cfg, SEED, [RUN, 5])
    models = dispersed_disturbance(scenario, d).models
    assert isinstance(models[0], ConstantTorque) and models[0] == scenario.disturbance.models[0]
    paper = models[1]
    assert isinstance(paper, PaperPeriodic) and paper.omega_p_rad_s == 0.01
    assert paper.scale == (2.0 * GOLDEN_DISTURBANCE_SCALE, 2.0 * float(d.disturbance_scale[1]))
    assert paper.phase_rad == (GOLDEN_DISTURBANCE_PHASE_RAD + 0.5, float(d.disturbance_phase_rad[1]) + 0.5)


def test_the_drawn_inputs_are_an_immutable_record() -> None:
    """A campaign's drawn inputs are read by every chunk and stored with the results: a frozen record."""
    import dataclasses

    _, cfg = _config(DISPERSIONS)
    d = draw_inputs(cfg, SEED, [RUN])
    with pytest.raises(dataclasses.FrozenInstanceError):
        d.euler_deg = np.zeros((1, 3))  # type: ignore[misc]


#: ``dispersions.faults`` of the fault tests: drawn after the gains, in this order, from the same
#: generator: the choice (``integers(3)``), the start (``10 + 5 U``), the length (``0.2 + 0.8 U``).
FAULTS = {"choices": [{"kind": "sensor_dropout"}, {"kind": "actuator_dropout"}, {"kind": "actuator_effectiveness", "effectiveness": [0.5, 0.5, 0.5]}],
          "start_s": {"distribution": "uniform", "low": 10.0, "high": 15.0},
          "duration_s": {"distribution": "uniform", "low": 0.2, "high": 1.0}}
# Run 41 of seed 2026 with DISPERSIONS and FAULTS, from the recipe with numpy alone.
GOLDEN_FAULT = (0, 10.294127039853574, 0.745639740665532)


def test_the_fault_of_run_k_is_drawn_last_and_golden() -> None:
    """A fault dispersion draws (choice, start, length) after every other value: run k's other
    values are the golden ones of the campaign without it; its fault is golden."""
    _, cfg = _config({**DISPERSIONS, "faults": FAULTS})
    d = draw_inputs(cfg, SEED, [RUN])
    assert (int(d.fault_choice[0]), float(d.fault_start_s[0]), float(d.fault_duration_s[0])) == GOLDEN_FAULT
    assert d.fault_choice.dtype == np.int64 and d.fault_start_s.dtype == d.fault_duration_s.dtype == np.float64
    assert d.euler_deg.tolist() == [GOLDEN_EULER_DEG] and d.gains["mu_rad_s"].tolist() == [GOLDEN_GAINS["mu_rad_s"]]


def test_without_a_fault_dispersion_no_fault_is_drawn_and_every_run_has_the_scenarios() -> None:
    """No ``dispersions.faults``: choice -1 and NaN times in the record; ``run_faults`` is None (each
    run takes the scenario's own ``faults``)."""
    scenario, cfg = _config(DISPERSIONS)
    d = draw_inputs(cfg, SEED, [RUN, 3])
    assert d.fault_choice.tolist() == [-1, -1] and np.isnan(d.fault_start_s).all() and np.isnan(d.fault_duration_s).all()
    assert run_faults(scenario, cfg, d) is None


def test_each_runs_faults_are_the_scenarios_then_its_drawn_one() -> None:
    """``run_faults``: per run, the scenario's faults in order, then the drawn fault with
    ``start_s`` and ``end_s = start_s + length``; a different run draws its own."""
    raw_faults = [{"kind": "sensor_bias", "start_s": 5.0, "rate_bias_rad_s": [1e-4, 0.0, 0.0]}]
    raw = copy.deepcopy(BASE)
    raw["montecarlo"]["dispersions"] = {**copy.deepcopy(DISPERSIONS), "faults": FAULTS}
    raw["faults"] = raw_faults
    scenario = scenario_from_mapping(raw)
    cfg = campaign_config(scenario)
    d = draw_inputs(cfg, SEED, [RUN, 3])
    per_run = run_faults(scenario, cfg, d)
    assert per_run is not None and len(per_run) == 2
    for k, faults in enumerate(per_run):
        assert len(faults) == 2 and faults[0] == scenario.faults[0]
        start = float(d.fault_start_s[k])
        expected = {**FAULTS["choices"][int(d.fault_choice[k])], "start_s": start, "end_s": start + float(d.fault_duration_s[k])}
        assert faults[1] == faults_from_list([expected])[0]
    assert isinstance(per_run[0][1], SensorDropout) and per_run[0][1].start_s == GOLDEN_FAULT[1]
    assert per_run[0][1] != per_run[1][1]

"""The orbit, the magnetorquers and momentum management in the offline loop (issue 36): the
scenario sections and their errors, the rods dumping the wheels' momentum and the attitude
tracked again, and a batch's run equal to the run alone bit for bit.  (The models against Basilisk:
tests/sim/test_momentum_basilisk.py; the paper scenarios without an orbit stay bit for bit: the
golden tests of tests/tools/offline/test_paper_experiments.py.)"""

from __future__ import annotations

import copy
import dataclasses
from typing import Any

import numpy as np
import pytest

from gnc_common.validation import ConfigError
from sappc.files import bundled_scenarios
from sappc.offline.compiled_loop import prepare, run_batch, run_single
from sappc.scenario import load_scenario, read_scenario_mapping, scenario_from_mapping
from sappc.files import scenario_path

#: Seconds simulated by the loop tests: 10 minutes, a tenth of an orbit.
DURATION_S = 600.0


def _base() -> dict[str, Any]:
    """paper_tracking_wheels (the HR16-class pyramid, the state measured exactly) in the bundled
    orbit, without disturbance, the wheels holding 8 N m s at the start (wheel 1 at 100 rad/s)."""
    raw = read_scenario_mapping(scenario_path("paper_tracking_wheels"))
    orbit = read_scenario_mapping(scenario_path("paper_tracking_orbit"))
    raw = copy.deepcopy(raw)
    raw.update(duration_s=DURATION_S, disturbances=[], orbit=orbit["orbit"], magnetorquers={"axes_B": "orthogonal", "max_dipole_Am2": 5000.0})
    raw["actuator"]["wheels"]["initial_speed_rad_s"] = [100.0, 0.0, 0.0, 0.0]
    return raw


def _wheel_momentum_B(sc: Any, run: Any) -> np.ndarray:
    """|G_s J_s Omega| (T,) [N m s] of a single run's record."""
    h = run.wheels[0, :, :, 0] * sc.wheels.per_wheel("spin_inertia_kg_m2")
    return np.asarray(np.linalg.norm(h @ sc.wheels.G.T, axis=1))


#: The bundled scenarios with momentum management: the 6 h scenario and its orbits of the momentum
#: page's campaign (docs/how-to/momentum.md, "Across orbits").
MANAGED = {"paper_tracking_orbit", "paper_tracking_orbit_800km", "paper_tracking_orbit_800km_sso", "flight_separation", "flight_blinded_tracker"}
#: The bundled scenarios in orbit: the orbit ones, and the separations (issue 49: their modes detumble on the rods).
IN_ORBIT = {"flight_separation", "flight_blinded_tracker"}


def test_no_bundled_scenario_but_the_orbit_ones_has_an_environment() -> None:
    for bundled in bundled_scenarios():
        sc = load_scenario(bundled.path)
        assert (sc.environment is not None) == ("orbit" in sc.name or sc.name in IN_ORBIT), sc.name
        assert (sc.momentum is not None) == (sc.name in MANAGED), sc.name


def test_the_campaigns_other_orbits_change_only_the_orbit() -> None:
    """The 800 km scenarios fly the 500 km scenario's spacecraft, rods, magnetometer and law: every
    key but the orbit's altitude and inclination (and the name, description, requirements stated
    again) is the same, so the momentum page's campaign compares orbits, not settings."""
    base = load_scenario("paper_tracking_orbit")
    for name, altitude_m, inclination_deg in (("paper_tracking_orbit_800km", 800_000.0, 51.6),
                                              ("paper_tracking_orbit_800km_sso", 800_000.0, 98.6)):
        sc = load_scenario(name)
        assert sc.environment is not None and base.environment is not None
        assert (sc.environment.orbit.altitude_m, sc.environment.orbit.inclination_deg) == (altitude_m, inclination_deg), name
        at_500km = dataclasses.replace(sc.environment.orbit, altitude_m=500_000.0, inclination_deg=97.4)
        assert at_500km == base.environment.orbit, name
        assert sc.momentum == base.momentum and sc.metrics.requirements == base.metrics.requirements, name
        same = {k: v for k, v in sc.raw.items() if k not in ("name", "description", "orbit", "metrics")}
        assert same == {k: v for k, v in base.raw.items() if k not in ("name", "description", "orbit", "metrics")}, name


@pytest.mark.parametrize(("change", "message"), [
    ({"orbit": {"eccentricity": 2.0}}, r"orbit\.eccentricity must be in \[0, 0\.9\], got 2\.0"),
    ({"orbit": {"altitude_m": -7e6}}, r"orbit\.altitude_m = -7000000\.0 .* below the Earth's equatorial radius"),
    ({"orbit": {"inclination_deg": 200.0}}, r"orbit\.inclination_deg must be in \[0, 180\], got 200\.0"),
    ({"orbit": {"altitud_m": 5e5}}, r"unknown key orbit\.altitud_m"),
    ({"orbit": {"gravity_gradient": "yes"}}, r"orbit\.gravity_gradient must be true or false, got 'yes'"),
    ({"orbit": {"magnetic_field": {"g10_nT": 0.0, "g11_nT": 0.0, "h11_nT": 0.0}}}, r"orbit\.magnetic_field\.g10_nT, g11_nT and h11_nT are all zero"),
    ({"magnetorquers": {"max_dipole_Am2": 10.0}}, r"magnetorquers needs an orbit section"),
    ({"orbit": {}, "magnetorquers": {"max_dipole_Am2": [1.0, 2.0]}}, r"magnetorquers\.max_dipole_Am2 must be one number > 0 or 3 .* got \(1\.0, 2\.0\)"),
    ({"orbit": {}, "magnetorquers": {"axes_B": [[1, 0, 0], [2, 0, 0], [0, 0, 1]], "max_dipole_Am2": 1.0}}, r"magnetorquers\.axes_B must span three dimensions"),
    ({"orbit": {}, "momentum_management": {"gain_per_s": 0.01}}, r"momentum_management needs a magnetorquers section"),
    ({"magnetometer": {"noise_T": 1e-8}}, r"magnetometer needs an orbit section"),
    ({"orbit": {}, "magnetometer": {"noise_T": -1e-8}}, r"magnetometer\.noise_T must be one number >= 0 or three, got -1e-08"),
    ({"orbit": {}, "magnetometer": {"rate_hz": 30.0}}, r"magnetometer\.rate_hz = 30\.0 must divide the control rate 100 Hz"),
    ({"orbit": {}, "magnetometer": {"bias_T": [1e-7]}}, r"magnetometer\.bias_T must be 3 finite numbers"),
    ({"orbit": {}, "magnetorquers": {"max_dipole_Am2": 1.0}, "momentum_management": {"gain_per_s": -1.0}},
     r"momentum_management\.gain_per_s must be a finite number > 0, got -1\.0"),
    ({"orbit": {}, "magnetorquers": {"max_dipole_Am2": 1.0}, "momentum_management": {"gain_per_s": 0.01, "target_momentum_B_Nms": [1.0]}},
     r"momentum_management\.target_momentum_B_Nms must be 3 finite numbers"),
    ({"orbit": {}, "magnetorquers": {"max_dipole_Am2": 1.0}, "momentum_management": {"gain_per_s": 0.01, "law": "lqr"}},
     r"momentum_management\.law must be one of cross_product, predictive, got 'lqr'"),
    ({"orbit": {}, "magnetorquers": {"max_dipole_Am2": 1.0}, "momentum_management": {"gain_per_s": 0.01, "horizon_s": 0.0}},
     r"momentum_management\.horizon_s must be a finite number > 0 \[s\], got 0\.0"),
    ({"orbit": {}, "magnetorquers": {"max_dipole_Am2": 1.0}, "momentum_management": {"gain_per_s": 0.01, "replan_s": 5000.0}},
     r"momentum_management\.the predictive law needs plan_step_s <= replan_s <= horizon_s, got 10\.0, 5000\.0, 3000\.0"),
    ({"orbit": {}, "magnetorquers": {"max_dipole_Am2": 1.0}, "momentum_management": {"gain_per_s": 0.01, "plan_step_s": 0.01, "replan_s": 0.01}},
     r"momentum_management\.horizon_s / plan_step_s must be at most 10000 steps, got 3000\.0 / 0\.01"),
])
def test_a_bad_orbit_rod_or_law_value_stops_with_its_key(change: dict[str, Any], message: str) -> None:
    raw = read_scenario_mapping(scenario_path("paper_tracking_wheels"))
    with pytest.raises(ConfigError, match=message):
        scenario_from_mapping({**raw, **change})


def test_management_needs_reaction_wheels() -> None:
    raw = read_scenario_mapping(scenario_path("paper_tracking"))
    with pytest.raises(ConfigError, match=r"momentum_management needs actuator\.kind: reaction_wheels"):
        scenario_from_mapping({**raw, "orbit": {}, "magnetorquers": {"max_dipole_Am2": 1.0}, "momentum_management": {"gain_per_s": 0.01}})


@pytest.mark.slow
def _total_momentum(sc: Any, run: Any) -> np.ndarray:
    """|J omega + G h| (T,) [N m s]: the body's and the wheels' angular momentum of a single run's
    record (its norm, the same in the body and the inertial frame)."""
    w = run.x[0, :, 4:7]
    h = sc.wheels.per_wheel("spin_inertia_kg_m2") * (run.wheels[0, :, :, 0] + w @ sc.wheels.G)  # Js (Omega + g . omega)
    return np.asarray(np.linalg.norm(w @ np.asarray(sc.inertia_kg_m2).T + h @ sc.wheels.G.T, axis=1))


def test_the_rods_dump_the_wheels_momentum_and_the_attitude_is_tracked_again() -> None:
    """Without disturbance, starting with 8 N m s in the wheels: without management nothing leaves
    the spacecraft (friction is internal, the gravity gradient zero to rounding for this isotropic
    locked inertia), so its total angular momentum stays 7.96 N m s to RK4's error at 10 ms (about
    1e-13 of it a step at the 0.7 rad/s this run reaches, 1e-8 over its 60,000 steps; measured
    4e-10); the wheels' part of it swings as the body turns, and SAPPC, a rigid-body law, does not
    hold the attitude against the load (|q_ev| up to 0.99: a tumbling run, whose details a change
    of the last bits anywhere moves).  With management the rods take the momentum out: the part
    normal to the field decays at the rate ``K_p`` and what is left lies along B: over these 600 s
    (a tenth of an orbit) the field turns by about 80 deg, so the part along it is dumped only as it
    turns, and the part normal to it settles near ``nu |h_par| / K_p`` (``nu``: the field
    direction's turning rate); the attitude is tracked again once the load is gone (its last 300 s
    within 1e-4, measured 4e-5)."""
    raw = _base()
    idle = scenario_from_mapping(raw)
    managed = scenario_from_mapping({**raw, "momentum_management": {"gain_per_s": 0.01}})
    runs = {name: run_single(prepare(sc), 0, 1) for name, sc in (("idle", idle), ("managed", managed))}
    H_idle, H_managed = _total_momentum(idle, runs["idle"]), _total_momentum(managed, runs["managed"])
    assert abs(H_idle[0] - 7.96) < 1e-12 and np.max(np.abs(H_idle - H_idle[0])) < 1e-8 * H_idle[0]  # nothing leaves
    assert H_managed[-1] < 0.5 * H_managed[0]  # measured 0.35
    h_managed = _wheel_momentum_B(managed, runs["managed"])
    assert h_managed[-1] < 0.5 * h_managed[0]  # measured 0.35
    h_end = runs["managed"].wheels[0, -1, :, 0] * managed.wheels.per_wheel("spin_inertia_kg_m2") @ managed.wheels.G.T
    b = runs["managed"].env[0, :, :3] / np.linalg.norm(runs["managed"].env[0, :, :3], axis=1)[:, None]
    nu = float(np.linalg.norm(b[-1] - b[-101]))  # [rad/s]: the last second's turn (100 samples)
    h_par = abs(float(h_end @ b[-1]))
    h_perp = float(np.linalg.norm(h_end - (h_end @ b[-1]) * b[-1]))
    assert h_perp < 2.0 * nu * h_par / 0.01, (h_perp, nu, h_par)  # the steady lag of a first-order loop chasing a turning field
    assert np.abs(runs["idle"].env[0, :, 9:]).max() == 0.0 and np.abs(runs["managed"].env[0, :, 9:]).max() > 0.0
    assert np.array_equal(runs["managed"].env[0, :, 3:6], runs["managed"].env[0, :, :3])  # no magnetometer: the field read exactly
    late = runs["managed"].t >= 300.0
    q_managed = np.abs(runs["managed"].out[0, late, 3, :3]).max()
    assert q_managed < 1e-4, q_managed


@pytest.mark.slow
@pytest.mark.parametrize("law", ["cross_product", "predictive"])
def test_a_batch_run_in_orbit_equals_the_run_alone_bit_for_bit(law: str) -> None:
    """Two runs of a batch (the predictive law: each its own orbit, plans every 5 s) equal each run alone."""
    raw = {**_base(), "duration_s": 60.0, "momentum_management": {"gain_per_s": 0.01, "gyroscopic_feedforward": True, "law": law,
                                                                    "replan_s": 5.0, "plan_step_s": 5.0, "horizon_s": 600.0}}
    sc = scenario_from_mapping(raw)
    q0 = np.stack((sc.q_BN0, np.array([0.1, -0.2, 0.3, 0.9]) / np.linalg.norm([0.1, -0.2, 0.3, 0.9])))
    assert sc.environment is not None
    orbits = np.stack((sc.environment.orbit.params(), sc.environment.orbit.params()))
    orbits[1, 5] += 1.0  # run 1 a radian further along its orbit
    inp = prepare(sc, q_BN0=q0, orbits=orbits)
    batch = run_batch(inp, 1)
    for k in range(2):
        alone = run_single(inp, k, 1)
        for a, b in zip(alone.record, batch.record):
            assert np.array_equal(a[0], b[k], equal_nan=True)


#: Run 5 of the 100-run campaign of the cross-product law (seed 0): its orbit's phase and field epoch at
#: t = 0 [deg], where that law loses the attitude at 1725 s (docs/how-to/momentum.md).
RUN5_PHASE_DEG, RUN5_EPOCH_DEG = 197.854307, 319.884878


@pytest.mark.slow
def test_where_the_cross_product_law_loses_the_attitude_the_predictive_law_holds_it() -> None:
    """The bundled 6 h scenario's first 2500 s at run 5's orbit, the nominal hardware: the
    cross-product law stores the momentum along the field (above 20 N m s), the motors cannot carry
    its gyroscopic load and the attitude is lost (max |q_ev| > 1e-3 after 25 s); the predictive law
    keeps the wheels below 15 N m s (measured 12.9 over the whole 6 h) and the steady max |q_ev|
    below 5e-5 (the one-minute flight run's is 4.3e-5)."""
    raw = read_scenario_mapping(scenario_path("paper_tracking_orbit"))
    raw.update(duration_s=2500.0)
    raw["orbit"].update(mean_anomaly_deg=RUN5_PHASE_DEG, earth_rotation_angle_deg=RUN5_EPOCH_DEG)
    results = {}
    for law in ("cross_product", "predictive"):
        raw["momentum_management"]["law"] = law
        sc = scenario_from_mapping(copy.deepcopy(raw))
        run = run_single(prepare(sc), 0, 10)
        steady = run.t >= sc.metrics.steady_from_s
        results[law] = (float(np.abs(run.out[0, steady, 3, :3]).max()), float(_wheel_momentum_B(sc, run).max()))
    print(f"\nrun 5's orbit, 2500 s: (steady max |q_ev|, largest |h_B| [N m s]) {results}")
    assert results["cross_product"][0] > 1e-3 and results["cross_product"][1] > 20.0
    assert results["predictive"][0] < 5e-5 and results["predictive"][1] < 15.0


def test_the_graph_refuses_an_orbit_on_a_plant_without_one() -> None:
    """``sappc run --plant basilisk`` of a scenario with an orbit stops with exit status 2 and says
    why, before any process starts (the Basilisk plant has no orbit: flying without one would be
    another run; the native plant flies it: tests/tools/graph/test_orbit_graph.py)."""
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-m", "sappc", "run", "paper_tracking_orbit", "--plant", "basilisk"], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert "lockstep on the native plant only, got --plant basilisk" in proc.stderr


def test_a_campaign_runs_magnetometer_draws_are_its_own_whatever_its_chunk() -> None:
    """The magnetometer's draws of a campaign's run ``k`` come from its key ``(k, seed)``, not from
    its place in a chunk: run 2 packed alone and packed third of three get the same draws, and the
    three runs' draws differ (they repeated chunk to chunk before: docs/how-to/momentum.md)."""
    from sappc.offline.compiled_loop import _environment

    sc = load_scenario(scenario_path("paper_tracking_orbit"))
    seed = 7
    chunk = _environment(sc, 3, [(k, seed) for k in (0, 1, 2)]).mag_draws
    alone = _environment(sc, 1, [(2, seed)]).mag_draws
    assert chunk.shape[1] == 216_001  # 6 h of 10 Hz updates, sample 0 included
    assert np.array_equal(chunk[2], alone[0])
    assert not np.array_equal(chunk[0], chunk[1]) and not np.array_equal(chunk[1], chunk[2])
    assert not np.array_equal(_environment(sc, 1, [(2, seed + 1)]).mag_draws[0], alone[0])  # another campaign seed, other draws
    assert np.array_equal(_environment(sc, 1).mag_draws[0], _environment(sc, 1, [(0,)]).mag_draws[0])  # sappc simulate's, as before


@pytest.mark.slow
def test_the_magnetometer_measures_the_field_with_its_bias_and_noise_at_its_rate() -> None:
    """The flight software's field (the record's columns 3 to 5) against the true one (0 to 2): held
    between updates, and at the updates the bias plus white noise of the data sheet (mean within 4
    standard errors of the bias, standard deviation within 5 % of sigma over 6000 updates)."""
    raw = {**_base(), "magnetometer": {"noise_T": 5e-8, "bias_T": [2e-7, -1.5e-7, 1e-7], "rate_hz": 10.0, "seed": 3}}
    sc = scenario_from_mapping(raw)
    run = run_single(prepare(sc), 0, 1)
    true, meas = run.env[0, :, :3], run.env[0, :, 3:6]
    held = np.arange(meas.shape[0]) % 10 != 0
    assert np.array_equal(meas[held], meas[np.flatnonzero(held) - np.flatnonzero(held) % 10])  # the last update's value
    err = (meas - true)[::10]
    assert np.all(np.abs(err.mean(axis=0) - [2e-7, -1.5e-7, 1e-7]) <= 4 * 5e-8 / np.sqrt(err.shape[0]))
    assert np.all(np.abs(err.std(axis=0) / 5e-8 - 1.0) <= 0.05)


def _orbit_campaign(orbit_dispersions: dict[str, Any] | None) -> dict[str, Any]:
    """The bundled 6 h orbit scenario cut to 1 s, its campaign's dispersions with ``orbit_dispersions``
    for its orbit's (``None``: none)."""
    raw = copy.deepcopy(read_scenario_mapping(scenario_path("paper_tracking_orbit")))
    raw["duration_s"] = 1.0
    del raw["montecarlo"]["dispersions"]["orbit"]
    if orbit_dispersions is not None:
        raw["montecarlo"]["dispersions"]["orbit"] = orbit_dispersions
    return raw


ORBIT_DISPERSIONS = {"mean_anomaly_deg": {"distribution": "uniform", "low": 0.0, "high": 360.0},
                     "earth_rotation_angle_deg": {"distribution": "uniform", "low": 0.0, "high": 360.0},
                     "raan_deg": {"distribution": "normal", "mean": 0.0, "sigma": 10.0}}


def test_a_campaign_disperses_the_orbit_phase_node_and_field_epoch_after_every_older_draw() -> None:
    """``montecarlo.dispersions.orbit``: each run's drawn phase, node and Earth rotation angle (the
    field's epoch) are added to the scenario's orbit, drawn after every other value of the run (the
    runs' other draws are those of the campaign without them), and a run flies exactly the orbit it
    drew: its history equals, bit for bit, that of the scenario with its orbit set to those values."""
    from sappc.montecarlo.campaign import simulate_runs
    from sappc.montecarlo.config import campaign_config
    from sappc.montecarlo.draws import draw_inputs, run_orbits
    from sappc.offline.simulate import run_scenario

    seed, runs = 3, [0, 5]
    raw = _orbit_campaign(ORBIT_DISPERSIONS)
    sc = scenario_from_mapping(raw)
    inputs = draw_inputs(campaign_config(sc), seed, runs)
    plain = draw_inputs(campaign_config(scenario_from_mapping(_orbit_campaign(None))), seed, runs)
    drawn = {k: v[:, 0] for k, v in inputs.hardware.items() if k.startswith("orbit_")}
    assert sorted(drawn) == ["orbit_earth_rotation_angle_deg", "orbit_mean_anomaly_deg", "orbit_raan_deg"]
    assert all(v[0] != v[1] for v in drawn.values())  # each run its own
    assert 0.0 <= drawn["orbit_mean_anomaly_deg"].min() and drawn["orbit_mean_anomaly_deg"].max() < 360.0
    for name, values in plain.hardware.items():  # the older draws unchanged
        assert np.array_equal(inputs.hardware[name], values)
    assert np.array_equal(inputs.omega_BN_B0, plain.omega_BN_B0) and np.array_equal(inputs.euler_deg, plain.euler_deg, equal_nan=True)

    rows = run_orbits(sc, inputs)
    assert rows is not None and rows.shape == (2, 10)
    assert run_orbits(scenario_from_mapping(_orbit_campaign(None)), plain) is None  # not dispersed: the scenario's

    table = simulate_runs(raw, seed, runs, 0)[0]
    assert np.array_equal(table["hw_orbit_mean_anomaly_deg"][:, 0], drawn["orbit_mean_anomaly_deg"])  # in runs.csv

    k = 1  # run 5: its drawn orbit through run_scenario's ``orbits`` against the scenario written with it
    own = copy.deepcopy(raw)
    del own["montecarlo"]
    for name, values in drawn.items():
        key = name[len("orbit_"):]
        own["orbit"][key] = own["orbit"].get(key, 0.0) + float(values[k])
    written = scenario_from_mapping(own)
    _, alone = run_scenario(written, keep_history=True)
    _, dispersed = run_scenario(scenario_from_mapping({**own, "orbit": raw["orbit"]}), keep_history=True, orbits=rows[k:k + 1])
    assert alone.history is not None and dispersed.history is not None
    for f in dataclasses.fields(alone.history):
        a, b = getattr(alone.history, f.name), getattr(dispersed.history, f.name)
        if isinstance(a, np.ndarray):
            assert np.array_equal(a, b, equal_nan=True), f.name
    assert alone.history.orbit is not None and dispersed.history.orbit is not None
    _, base = run_scenario(scenario_from_mapping({**own, "orbit": raw["orbit"]}), keep_history=True)
    assert base.history is not None and base.history.orbit is not None
    assert not np.array_equal(base.history.orbit[:, :, :3], dispersed.history.orbit[:, :, :3])  # the draw matters: another field


def test_an_orbit_dispersion_needs_the_scenarios_orbit() -> None:
    from sappc.montecarlo.config import campaign_config

    raw = copy.deepcopy(read_scenario_mapping(scenario_path("paper_tracking_flight")))
    raw["montecarlo"]["dispersions"]["orbit"] = {"mean_anomaly_deg": {"distribution": "uniform", "low": 0.0, "high": 360.0}}
    with pytest.raises(ConfigError, match=r"montecarlo.dispersions.orbit.mean_anomaly_deg needs the scenario's orbit section"):
        campaign_config(scenario_from_mapping(raw))

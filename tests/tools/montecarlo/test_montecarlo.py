"""Monte Carlo campaigns: dispersions, determinism across chunkings and executors, re-runs,
failures, resumption, rejection of bad dispersions before any run, the numpy core's table
reproduced, the sensor-noise sequence, progress."""

from __future__ import annotations

import copy
import csv
import json
import os
import pathlib
import subprocess
import sys

import numpy as np
import pytest
import yaml

from conftest import ROOT, SCENARIOS
from figure_checks import NO_EMPTY_LOG_AXES, assert_every_axes_shows_data, capture_figures, points_in_view
from sappc.montecarlo import campaign as mc
from sappc.montecarlo.campaign import load_campaign_run, run_campaign
from sappc.montecarlo.config import campaign_config
from sappc.montecarlo.draws import NOISE_BLOCK, draw_inputs, run_generators, sensor_noise_draws
from sappc.offline import compiled_loop
from sappc.offline import simulate as offline_simulate
from sappc.scenario import scenario_from_mapping
from gnc_common.validation import ConfigError
from spacecraft_sim.core.faults import faults_from_list

GOLDEN_TABLE = ROOT / "tests" / "data" / "golden_numpy_core_mc24_seed7.csv"

pytestmark = NO_EMPTY_LOG_AXES  # campaigns draw their figures in-process

BASE = yaml.safe_load((SCENARIOS / "paper_montecarlo.yaml").read_text())


def _short(tmp_path, chunk_runs: int = 5, **dispersions) -> str:  # type: ignore[no-untyped-def]
    """A 21 s campaign scenario (steady window [20.5, 21] s) with every dispersion switched on."""
    raw = copy.deepcopy(BASE)
    raw["duration_s"] = 21.0
    raw["metrics"]["steady_from_s"] = 20.5
    raw["montecarlo"]["chunk_runs"] = chunk_runs
    raw["montecarlo"]["trajectory_runs"] = 4
    raw["montecarlo"]["dispersions"] = dispersions or {
        "initial_rate_rad_s": {"distribution": "normal", "mean": 0.0, "sigma": [1e-3, 1e-3, 1e-3]},
        "inertia_relative": {"distribution": "uniform", "low": -0.05, "high": 0.05},
        "disturbance_scale": {"distribution": "uniform", "low": 0.8, "high": 1.2},
        "disturbance_phase_rad": {"distribution": "uniform", "low": 0.0, "high": 6.283185307179586},
        "sensor_noise": {"attitude_sigma_rad": 1e-7, "rate_sigma_rad_s": 1e-7},
        "gains": {"K_q": {"distribution": "uniform", "low": 0.25, "high": 0.35}, "mu_rad_s": {"distribution": "uniform", "low": 6e-5, "high": 8e-5}},
    }
    path = tmp_path / f"short_{chunk_runs}.yaml"
    path.write_text(yaml.safe_dump(raw))
    return str(path)


def test_dispersion_statistics_and_per_run_reproducibility(tmp_path) -> None:
    cfg = campaign_config(scenario_from_mapping(yaml.safe_load(open(_short(tmp_path)).read())))
    n = 4000
    d = draw_inputs(cfg, seed=3, runs=range(n))
    # Euler angles uniform on [-85, 85] deg: mean 0 (sd of the mean 49.1/sqrt(n) = 0.78 deg), sd 170/sqrt(12) = 49.07 deg
    assert np.all(np.abs(d.euler_deg) <= 85.0)
    assert np.all(np.abs(d.euler_deg.mean(axis=0)) < 4 * 0.78)
    assert np.all(np.abs(d.euler_deg.std(axis=0) - 49.07) < 1.5)  # sd of the sd ~ 0.55 deg at n = 4000
    # normal initial rate, sigma 1e-3 per axis
    assert np.all(np.abs(d.omega_BN_B0.std(axis=0) - 1e-3) < 0.05e-3)
    assert np.all(np.abs(d.omega_BN_B0.mean(axis=0)) < 4 * 1e-3 / np.sqrt(n))
    assert np.all((d.inertia_relative >= -0.05) & (d.inertia_relative <= 0.05))
    assert np.all((d.disturbance_scale >= 0.8) & (d.disturbance_scale <= 1.2))
    assert np.all((d.gains["K_q"] >= 0.25) & (d.gains["K_q"] <= 0.35)) and abs(d.gains["K_q"].mean() - 0.3) < 4 * 0.1 / np.sqrt(12 * n)
    # components are independent: correlation between axes ~ 0 (sd 1/sqrt(n) = 0.016)
    c = np.corrcoef(d.euler_deg.T)
    assert np.all(np.abs(c[np.triu_indices(3, 1)]) < 0.064)
    # a run's draws depend only on (seed, run)
    alone = draw_inputs(cfg, seed=3, runs=[1234])
    np.testing.assert_array_equal(alone.euler_deg[0], d.euler_deg[1234])
    np.testing.assert_array_equal(alone.omega_BN_B0[0], d.omega_BN_B0[1234])
    assert not np.array_equal(draw_inputs(cfg, seed=4, runs=[1234]).euler_deg, alone.euler_deg)


def _sub_batch(monkeypatch, runs: int) -> None:  # type: ignore[no-untyped-def]
    """Make the in-process sub-batches (the units of progress inside a chunk) ``runs`` runs long."""
    monkeypatch.setattr(offline_simulate, "SUB_BATCH", runs)
    monkeypatch.setattr(offline_simulate, "LANES_SUB_BATCH", runs)  # the runs of these scenarios go in lanes
    monkeypatch.setattr(offline_simulate.run_scenario, "__kwdefaults__", {**offline_simulate.run_scenario.__kwdefaults__, "sub_batch": runs})


@pytest.mark.parametrize("runs, most, parallel", [(500, 100, 2), (3000, 3000, 2), (10, 2, 2), (7, 500, 2), (100_000, 3000, 2), (96, 10, 3)])
def test_each_worker_gets_as_many_chunks_of_at_most_chunk_runs(runs: int, most: int, parallel: int) -> None:
    """Several workers: chunks of equal size, at most the scenario's ``chunk_runs``, as many for each
    worker (500 flight runs of at most 100 on two workers: six of 84 and 80, not five of 100 with one
    worker left alone with the fifth); the chunks cover every run once."""
    size = mc.balanced_chunk_runs(runs, most, parallel)
    count = -(-runs // size)
    assert 1 <= size <= most and count % parallel == 0 and count * size - runs < size
    assert mc.balanced_chunk_runs(runs, most, 1) == min(most, runs)  # one process: the scenario's chunks


def test_a_processs_chunks_parse_their_scenario_once(tmp_path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """A worker's chunks share their scenario's mapping: it is parsed once per process (the
    campaign's own parse, before its workers fork, counts), a mapping that differs is parsed again,
    and the chunks' results are those of a fresh parse."""
    raw = yaml.safe_load(pathlib.Path(_short(tmp_path, chunk_runs=4)).read_text())
    parses = []
    real = mc.scenario_from_mapping
    monkeypatch.setattr(mc, "scenario_from_mapping", lambda data, **kw: parses.append(1) or real(data, **kw))
    monkeypatch.setattr(mc, "_last_parsed", None)
    first = mc.run_chunk(copy.deepcopy(raw), 7, [0, 1], 0)
    again = mc.run_chunk(copy.deepcopy(raw), 7, [0, 1], 0)  # (a copy, as a task's pickled mapping)
    assert len(parses) == 1
    for key in first:
        assert np.array_equal(first[key], again[key], equal_nan=True), key
    other = copy.deepcopy(raw)
    other["duration_s"] = raw["duration_s"] / 2
    mc.run_chunk(other, 7, [0, 1], 0)
    assert len(parses) == 2
    scenario = real(raw)
    mc._remember(scenario, campaign_config(scenario))  # what run_campaign leaves before forking its workers
    mc.run_chunk(copy.deepcopy(raw), 7, [0, 1], 0)
    assert len(parses) == 2


def test_results_are_identical_for_any_chunking_and_executor(tmp_path, monkeypatch) -> None:
    a = run_campaign(_short(tmp_path, chunk_runs=5), runs=12, seed=7, out_dir=tmp_path / "a", progress=False)
    b = run_campaign(_short(tmp_path, chunk_runs=3), runs=12, seed=7, out_dir=tmp_path / "b", workers=2, progress=False)
    assert (tmp_path / "a" / "runs.csv").read_bytes() == (tmp_path / "b" / "runs.csv").read_bytes()
    assert a["passed"] == b["passed"] == 12
    # one worker, one chunk of every run, reporting progress every 2 runs: the same bytes
    _sub_batch(monkeypatch, 2)
    run_campaign(_short(tmp_path, chunk_runs=12), runs=12, seed=7, out_dir=tmp_path / "c", workers=1, progress=True)
    assert (tmp_path / "c" / "runs.csv").read_bytes() == (tmp_path / "a" / "runs.csv").read_bytes()
    assert json.loads((tmp_path / "c" / "manifest.json").read_text())["chunk_runs"] == 12
    # a run of the campaign re-run alone gives its row exactly
    _, row, metrics, _ = load_campaign_run(tmp_path / "a", 9)
    table = np.genfromtxt(tmp_path / "a" / "runs.csv", delimiter=",", names=True)
    assert row["rpf_error_at_t2_per_axis"][0].max() == table["rpf_error_at_t2"][9]
    assert metrics["steady_mean_abs_qev"] == table["steady_mean_abs_qev"][9]
    assert metrics["max_abs_torque_Nm"] == table["max_abs_torque_Nm"][9]
    assert metrics["torque_sign_changes_per_s"] == table["torque_sign_changes_per_s"][9] == row["torque_sign_changes_per_s"][0]
    assert metrics["torque_reversals_per_s"] == table["torque_reversals_per_s"][9]
    summary = json.loads((tmp_path / "a" / "summary.json").read_text())
    assert summary["torque_sign_changes_per_s"]["max"] == table["torque_sign_changes_per_s"].max()


def test_local_dask_cluster_gives_the_same_results(tmp_path) -> None:
    from distributed import LocalCluster

    path = _short(tmp_path, chunk_runs=4)
    run_campaign(path, runs=8, seed=11, out_dir=tmp_path / "local", progress=False)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        run_campaign(path, runs=8, seed=11, out_dir=tmp_path / "dask", scheduler=cluster.scheduler_address, progress=False)
    assert (tmp_path / "local" / "runs.csv").read_bytes() == (tmp_path / "dask" / "runs.csv").read_bytes()
    # two chunks per worker thread (2 x 1): the campaign is spread over the cluster, not one task
    assert len(list((tmp_path / "dask" / "chunks").glob("chunk_*.npz"))) == 4


def test_a_run_that_goes_non_finite_is_marked_failed_and_the_campaign_continues(tmp_path, monkeypatch) -> None:
    real = compiled_loop.prepare
    calls = {"n": 0}

    def poisoned(*args, **kwargs):  # type: ignore[no-untyped-def]
        inp = real(*args, **kwargs)
        calls["n"] += 1
        if calls["n"] == 1:  # run 2 of the first chunk: an infinite initial rate
            inp.plant.x0[2, 4] = np.inf
        return inp

    monkeypatch.setattr(offline_simulate.compiled_loop, "prepare", poisoned)
    s = run_campaign(_short(tmp_path, chunk_runs=5), runs=8, seed=1, out_dir=tmp_path / "f", progress=False)
    assert s["non_finite_runs"] == 1 and s["passed"] == 7
    (failed,) = s["failed_runs"]
    assert failed["run"] == 2 and failed["seed_sequence"] == {"entropy": 1, "spawn_key": [2]}
    assert "non-finite" in failed["why"]


def test_a_run_that_loses_control_fails_and_is_counted(tmp_path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """Run 3 starts tumbling at 5 rad/s about x (20 N m s against 0.5 N m of torque: 40 s to stop it,
    the run lasts 21 s): it ends with its attitude lost, fails the campaign whatever its criteria
    say, is counted in ``runs_lost_control`` and its row and reason say from when."""
    real = compiled_loop.prepare
    calls = {"n": 0}

    def tumbling(*args, **kwargs):  # type: ignore[no-untyped-def]
        inp = real(*args, **kwargs)
        calls["n"] += 1
        if calls["n"] == 1:  # the first chunk (runs 0 to 4): run 3
            inp.plant.x0[3, 4] = 5.0
        return inp

    monkeypatch.setattr(offline_simulate.compiled_loop, "prepare", tumbling)
    s = run_campaign(_short(tmp_path, chunk_runs=5), runs=6, seed=1, out_dir=tmp_path / "lost", progress=False)
    assert s["runs_lost_control"] == 1 and s["passed"] == 5 and s["non_finite_runs"] == 0
    (failed,) = s["failed_runs"]
    assert failed["run"] == 3 and "control lost from 20.5 s to the end" in failed["why"], failed
    rows = list(csv.DictReader((tmp_path / "lost" / "runs.csv").open()))
    assert [r["control_lost_at_s"] for r in rows] == ["nan", "nan", "nan", "20.5", "nan", "nan"]


def test_interrupted_campaign_resumes_to_the_same_results(tmp_path, monkeypatch) -> None:
    path = _short(tmp_path, chunk_runs=3)
    run_campaign(path, runs=9, seed=5, out_dir=tmp_path / "full", progress=False)
    real_save = mc.save_chunk
    saved = {"n": 0}

    def save_then_interrupt(out, index, result):  # type: ignore[no-untyped-def]
        real_save(out, index, result)
        saved["n"] += 1
        if saved["n"] == 2:
            raise KeyboardInterrupt

    monkeypatch.setattr(mc, "save_chunk", save_then_interrupt)
    with pytest.raises(KeyboardInterrupt):
        run_campaign(path, runs=9, seed=5, out_dir=tmp_path / "cut", progress=False)
    assert len(list((tmp_path / "cut" / "chunks").glob("chunk_*.npz"))) == 2
    monkeypatch.setattr(mc, "save_chunk", real_save)
    with pytest.raises(ConfigError, match="--resume"):
        run_campaign(path, runs=9, seed=5, out_dir=tmp_path / "cut", progress=False)
    with pytest.raises(ConfigError, match="another scenario, seed"):
        run_campaign(path, runs=9, seed=6, out_dir=tmp_path / "cut", resume=True, progress=False)
    run_campaign(path, runs=9, seed=5, out_dir=tmp_path / "cut", resume=True, workers=2, progress=False)  # any worker count
    assert (tmp_path / "cut" / "runs.csv").read_bytes() == (tmp_path / "full" / "runs.csv").read_bytes()


@pytest.mark.parametrize(
    "dispersions, fragment",
    [
        ({"disturbance_scale": {"distribution": "uniform", "low": 1.2, "high": 0.8}}, r"dispersions.disturbance_scale: needs finite low <= high"),
        ({"initial_rate_rad_s": {"distribution": "cauchy", "low": 0, "high": 1}}, "montecarlo.dispersions.initial_rate_rad_s.distribution must be one of 'uniform', 'normal', got 'cauchy'"),
        ({"initial_rate_rad_s": {"distribution": "normal", "mean": 0.0, "sigma": -1e-3}}, "sigma >= 0"),
        ({"inertia_relative": {"distribution": "uniform", "low": -1.5, "high": 0.1}}, "inertia_relative must stay above -1"),
        ({"inertia_relative": {"distribution": "normal", "mean": 0.0, "sigma": 0.01}}, "normal distribution is unbounded"),
        ({"disturbance_scale": {"distribution": "uniform", "low": [0.8, 0.8, 0.8], "high": 1.2}}, "disturbance_scale must have scalar"),
        ({"wind": {"distribution": "uniform", "low": 0, "high": 1}}, "unknown key montecarlo.dispersions.wind"),
        ({"gains": {"K_q": {"distribution": "normal", "mean": 0.3, "sigma": 0.1}}}, "K_q must be a uniform distribution with low > 0"),
        ({"gains": {"T1_s": {"distribution": "uniform", "low": 1, "high": 2}}}, "unknown key montecarlo.dispersions.gains.T1_s"),
    ],
)
def test_bad_dispersions_are_rejected_before_any_run(tmp_path, dispersions, fragment) -> None:
    with pytest.raises(ConfigError, match=fragment):
        run_campaign(_short(tmp_path, **dispersions), runs=3, seed=0, out_dir=tmp_path / "x", progress=False)
    assert not (tmp_path / "x").exists()


def test_the_campaign_figures_show_every_run_and_trajectory(tmp_path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """The four campaign figures, each axes with data in view; the steady-state trajectories (log
    axes from 15 s) show every positive point of every kept run's |q_ev| and |rho| (issue 25, 2.5:
    three empty log axes and "Data has no positive values", which this module makes an error)."""
    figures = capture_figures(monkeypatch)
    run_campaign(_short(tmp_path, chunk_runs=4), runs=4, seed=2, out_dir=tmp_path / "c", progress=False)
    names = {f._suptitle.get_text(): f for f in figures}
    assert len(figures) == 4, list(names)
    assert_every_axes_shows_data(figures)
    steady = next(f for title, f in names.items() if title.endswith("steady state"))
    for i, ax in enumerate(steady.axes):
        assert ax.get_yscale() == "log"
        segments = [seg for c in ax.collections for seg in c.get_segments()]
        assert len(segments) == 2 * 4  # each kept run's |q_ev| and its |rho|
        drawn = sum(int(np.count_nonzero(np.isfinite(seg[:, 1]) & (seg[:, 1] > 0))) for seg in segments)
        assert drawn > 0 and points_in_view(ax) == drawn, (i, drawn, points_in_view(ax))  # all of it in view
        assert min(seg[:, 0].min() for seg in segments) >= 15.0 - 1e-9


def test_cli_end_to_end(tmp_path) -> None:
    env = {**os.environ, "PYTHONWARNINGS": "error:Data has no positive values"}  # an empty log axis fails the command
    out = subprocess.run(
        [sys.executable, "-m", "sappc", "montecarlo", _short(tmp_path, chunk_runs=3), "--runs", "4", "--seed", "2",
         "--out", str(tmp_path / "cli"), "--json", str(tmp_path / "s.json"), "--no-progress"],
        capture_output=True, text=True, cwd=ROOT, env=env,
    )
    assert out.returncode == 0, out.stderr
    assert "4/4 runs pass" in out.stdout
    summary = json.loads((tmp_path / "s.json").read_text())
    assert summary["runs"] == 4 and summary["pass_fraction"] == 1.0
    for name in ("runs.csv", "summary.json", "montecarlo_t2_error.png", "montecarlo_steady_error.png", "montecarlo_trajectories.png",
                 "montecarlo_trajectories_steady.png"):
        assert (tmp_path / "cli" / name).exists()
    rerun = subprocess.run([sys.executable, "-m", "sappc", "simulate", "--from-campaign", str(tmp_path / "cli"), "--run", "3",
                            "--out", str(tmp_path / "run3")], capture_output=True, text=True, cwd=ROOT, env=env)
    assert rerun.returncode == 0 and "run 3" in rerun.stdout and (tmp_path / "run3" / "qev.png").exists()
    nodir = subprocess.run([sys.executable, "-m", "sappc", "simulate", "--from-campaign", str(tmp_path / "nope"), "--run", "0", "--out", str(tmp_path / "p")],
                           capture_output=True, text=True, cwd=ROOT)
    assert nodir.returncode == 2 and "is not a campaign directory" in nodir.stderr and "Traceback" not in nodir.stderr
    bad = subprocess.run([sys.executable, "-m", "sappc", "simulate", "--from-campaign", str(tmp_path / "cli"), "--run", "9"],
                         capture_output=True, text=True, cwd=ROOT)
    assert bad.returncode == 2 and "--run must be in [0, 3]" in bad.stderr


#: Bounds of the 24-run table against the numpy core's (docs/parity.md, "bounded": another code
#: path).  The histories behind it agree to 1e-12 in q_ev and 1e-12 N m in torque
#: (``test_compiled_run_reproduces_numpy_golden``, where the bound is derived).  Each metric of a
#: unit-quaternion component (a max, a time-mean or a difference with the same ``rho``) moves by at
#: most what its samples move (Lipschitz constant 1), so it inherits 1e-12 *absolute*: a relative
#: bound would be conditioning-blind, since a component of 1e-6 carries the absolute rounding of
#: the O(1) numbers it is computed from (``rpf_error_at_t2_1`` of run 0, 7.9e-7, differs by 1.4e-17
#: on an AVX-512 host: 1.8e-11 relative).
TABLE_QUATERNION_ATOL = 1e-12
TABLE_TORQUE_ATOL_NM = 1e-12
#: Columns drawn from the seed (PCG64 bits and float64 arithmetic): exact on every host.
TABLE_EXACT_PREFIXES = ("run", "seed", "euler_deg", "omega0", "inertia_relative", "disturbance", "rpf_clamped", "rpf_flat", "finite")


def test_the_numpy_cores_24_run_table_is_reproduced(tmp_path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """``paper_montecarlo.yaml --runs 24 --seed 7`` against the table the numpy core wrote, with the
    reference it was recorded with (scipy's DOP853, rebuilt by the oracle: see
    ``test_compiled_run_reproduces_numpy_golden``): draws exactly, quaternion metrics to
    :data:`TABLE_QUATERNION_ATOL`, torque to :data:`TABLE_TORQUE_ATOL_NM`.  The discrete results
    (settling time, pass flag) are equal wherever their margin to the threshold exceeds that bound
    (checked on each run's history); within it they may move by one sample."""
    from sim import oracle as sim_oracle
    from spacecraft_sim.core.reference import PaperReference, ReferenceSamples

    def recorded_reference(self: PaperReference, t: np.ndarray, carry: np.ndarray | None = None) -> ReferenceSamples:
        times = np.asarray(t, dtype=np.float64).reshape(-1)  # the oracle integrates from q_RN0 at t = 0 for any block: carry unused
        q = sim_oracle.reference_quaternions_dop853(times, np.array(self.q_RN0), self.amplitude_deg_s, self.periods_s)
        return ReferenceSamples(times, q, *self.rates(times))

    monkeypatch.setattr(PaperReference, "sample", recorded_reference)
    run_campaign(SCENARIOS / "paper_montecarlo.yaml", runs=24, seed=7, out_dir=tmp_path / "mc", progress=False)
    new = np.genfromtxt(tmp_path / "mc" / "runs.csv", delimiter=",", names=True, dtype=None, encoding="utf-8")
    old = np.genfromtxt(GOLDEN_TABLE, delimiter=",", names=True, dtype=None, encoding="utf-8")
    assert set(old.dtype.names) <= set(new.dtype.names) and new.shape == old.shape == (24,)  # columns added since: answers_*
    scenario = scenario_from_mapping(BASE)
    threshold, dt = scenario.metrics.settle_threshold, scenario.control_period_s
    for name in old.dtype.names:
        if name.startswith(TABLE_EXACT_PREFIXES):
            assert np.array_equal(new[name], old[name]), name
        elif name.startswith(("rpf_error_at_t2", "steady_")):
            assert np.max(np.abs(new[name] - old[name])) <= TABLE_QUATERNION_ATOL, name
        elif name == "max_abs_torque_Nm":
            assert np.max(np.abs(new[name] - old[name])) <= TABLE_TORQUE_ATOL_NM, name
        else:
            assert name in ("settling_time_s", "passed"), f"{name}: a column this test does not know how to compare"
    # the pass flag: the criteria (1e-4 and 5e-5) are far from every run's values, beyond the bound
    limits = {"rpf_error_at_t2": 1e-4, "steady_mean_abs_qev": 5e-5}
    assert all(np.min(np.abs(old[m] - lim)) > TABLE_QUATERNION_ATOL for m, lim in limits.items())
    assert np.array_equal(new["passed"], old["passed"])
    # the settling time: equal where the crossing's margin exceeds the bound (else one sample at most)
    for k in range(24):
        _, _, _, history = load_campaign_run(tmp_path / "mc", k, with_history=True)
        err = np.max(np.abs(history.q_BR[:, 0, :3]), axis=1)
        i = int(round(float(new["settling_time_s"][k]) / dt))
        margin = min(float(err[i - 1]) - threshold if i > 0 else np.inf, float(threshold - np.max(err[i:])))
        assert margin > 0.0
        if margin > TABLE_QUATERNION_ATOL:
            assert new["settling_time_s"][k] == old["settling_time_s"][k], k
        else:
            assert abs(new["settling_time_s"][k] - old["settling_time_s"][k]) <= dt * (1 + 1e-9), k


def test_sensor_noise_draws_are_the_campaigns_block_sequence() -> None:
    """Each run's noise: its second generator's ``standard_normal((256, 6))`` block after block (the
    numpy core's per-block draws), drawn whole before the loop."""
    n_samples = 2 * NOISE_BLOCK + 17
    draws = sensor_noise_draws(5, [3, 11], n_samples)
    assert draws.shape == (2, n_samples, 6)
    for i, k in enumerate((3, 11)):
        _, rng = run_generators(5, k)
        blocks = np.concatenate([rng.standard_normal((NOISE_BLOCK, 6)) for _ in range(3)])
        assert np.array_equal(draws[i], blocks[:n_samples])
    # a sub-range of runs draws the same values
    assert np.array_equal(sensor_noise_draws(5, [11], n_samples)[0], draws[1])


def test_sensor_noise_moves_the_torque_not_the_recorded_true_error(tmp_path) -> None:
    """With sensor noise the controller sees a noisy state (other torques), the metrics the true error;
    a noisy run in a campaign equals the run alone bit for bit (``load_campaign_run``)."""
    path = _short(tmp_path, chunk_runs=3, sensor_noise={"attitude_sigma_rad": 1e-6, "rate_sigma_rad_s": 1e-6})
    run_campaign(path, runs=3, seed=2, out_dir=tmp_path / "n", progress=False)
    _, row, metrics, history = load_campaign_run(tmp_path / "n", 1, with_history=True)
    table = np.genfromtxt(tmp_path / "n" / "runs.csv", delimiter=",", names=True)
    assert metrics["steady_mean_abs_qev"] == table["steady_mean_abs_qev"][1]
    assert row["rpf_error_at_t2_per_axis"][0].max() == table["rpf_error_at_t2"][1]
    # the recorded error quaternion is the true one: q_BR from the true attitude and the reference
    from gnc_common.attitude import error_quaternion

    sc = scenario_from_mapping(yaml.safe_load(open(path).read()))
    q_RN = sc.reference.sample(history.t).q_RN
    np.testing.assert_allclose(history.q_BR[:, 0], error_quaternion(q_RN, history.q_BN[:, 0]), rtol=0, atol=1e-15)


def test_a_campaign_with_the_scenarios_sensors_and_wheels_draws_each_runs_sensors_and_matches_the_run_alone(tmp_path) -> None:
    """Scenario sensors (tracker, gyro with bias walk) and reaction wheels in a campaign: each run
    draws its sensor noise from its own stream (runs differ beyond their dispersions), run k re-run
    alone equals its row bit for bit, and the white-noise dispersion cannot be added on top."""
    raw = yaml.safe_load(open(_short(tmp_path, chunk_runs=2, initial_rate_rad_s={"distribution": "normal", "mean": 0.0,
                                                                                   "sigma": [1e-3, 1e-3, 1e-3]})).read())
    wheels = yaml.safe_load((SCENARIOS / "paper_tracking_wheels.yaml").read_text())["actuator"]
    raw["actuator"] = {**wheels, "max_torque_Nm": raw["actuator"]["max_torque_Nm"]}
    raw["sensors"] = {"star_tracker": {"noise_rad": [5e-6, 5e-6, 3e-5], "rate_hz": 10.0},
                      "gyro": {"angle_random_walk_rad_sqrt_s": 1.5e-6, "bias_random_walk_rad_s_sqrt_s": 1e-9}, "seed": 3}
    uniform = {"distribution": "uniform", "low": -0.1, "high": 0.1}
    raw["montecarlo"]["dispersions"]["hardware"] = {
        "wheel_spin_inertia_relative": uniform, "wheel_max_torque_relative": uniform, "wheel_friction_relative": uniform,
        "wheel_initial_speed_rad_s": {"distribution": "normal", "mean": 0.0, "sigma": 5.0}, "star_tracker_noise_relative": uniform,
        "gyro_initial_bias_rad_s": {"distribution": "normal", "mean": 0.0, "sigma": 2e-6}}
    path = tmp_path / "sensors.yaml"
    path.write_text(yaml.safe_dump(raw))
    run_campaign(str(path), runs=3, seed=2, out_dir=tmp_path / "s", progress=False)
    table = np.genfromtxt(tmp_path / "s" / "runs.csv", delimiter=",", names=True)
    assert "max_abs_wheel_speed_rad_s" in table.dtype.names and np.all(table["max_abs_wheel_speed_rad_s"] > 0)
    assert {"wheel_spin_inertia_relative_4", "gyro_initial_bias_rad_s_3"} <= set(table.dtype.names)  # the draws, per wheel and axis
    assert len(set(table["wheel_initial_speed_rad_s_1"])) == 3 and np.all(np.abs(table["wheel_friction_relative_2"]) <= 0.1)
    _, row, metrics, _ = load_campaign_run(tmp_path / "s", 1)
    assert metrics["steady_mean_abs_qev"] == table["steady_mean_abs_qev"][1]
    assert metrics["max_abs_wheel_speed_rad_s"] == table["max_abs_wheel_speed_rad_s"][1]
    no_wheels = copy.deepcopy(raw)
    no_wheels["actuator"] = {"max_torque_Nm": 0.5, "min_torque_Nm": 0.005}
    with pytest.raises(ConfigError, match="hardware.wheel_spin_inertia_relative needs the scenario's actuator.kind: reaction_wheels"):
        campaign_config(scenario_from_mapping(no_wheels))
    raw["montecarlo"]["dispersions"]["sensor_noise"] = {"attitude_sigma_rad": 1e-7, "rate_sigma_rad_s": 1e-7}
    path.write_text(yaml.safe_dump(raw))
    with pytest.raises(ConfigError, match="sensor_noise and the scenario's sensors"):
        run_campaign(str(path), runs=2, seed=2, out_dir=tmp_path / "t", progress=False)


def test_progress_moves_during_a_chunk(tmp_path, monkeypatch) -> None:
    """One worker, one chunk: the progress line reports sub-batches as they finish, not only the chunk."""
    reports: list[int] = []
    real_update = mc._Progress.update

    def spy(self, n):  # type: ignore[no-untyped-def]
        reports.append(n)
        real_update(self, n)

    monkeypatch.setattr(mc._Progress, "update", spy)
    _sub_batch(monkeypatch, 4)
    run_campaign(_short(tmp_path, chunk_runs=12), runs=12, seed=3, out_dir=tmp_path / "p", workers=1, progress=False)
    assert reports == [4, 4, 4]


def test_a_one_worker_campaign_reports_progress_several_times_before_its_chunk_ends(tmp_path, monkeypatch, capsys) -> None:
    """``--workers 1`` (in this process), the default sub-batches, one chunk of 70 runs: the progress
    callback is called after each sub-batch of 32 runs, twice before the chunk is saved and the
    campaign ends, and each report prints a line.  The progress clock starts after the kernels are
    compiled (a first campaign's minute of compiling is not in its runs/s and ETA)."""
    events: list[object] = []
    real_init, real_update, real_save = mc._Progress.__init__, mc._Progress.update, mc.save_chunk

    def init(self, *args):  # type: ignore[no-untyped-def]
        events.append("clock")
        real_init(self, *args)

    def spy(self, n):  # type: ignore[no-untyped-def]
        events.append(n)
        real_update(self, n)

    def save(out, index, result):  # type: ignore[no-untyped-def]
        events.append("saved")
        real_save(out, index, result)

    monkeypatch.setattr(mc._Progress, "__init__", init)
    monkeypatch.setattr(mc._Progress, "update", spy)
    monkeypatch.setattr(mc, "save_chunk", save)
    monkeypatch.setattr(mc.compiled_loop, "ensure_compiled", lambda **kw: events.append("compiled") if "in_subprocess" in kw else None)  # the campaign's call
    monkeypatch.setattr(mc._Progress, "LOG_PERIOD_S", 0.0)  # print every report (stderr is not a terminal here)
    monkeypatch.setattr(offline_simulate, "LANES_SUB_BATCH", offline_simulate.SUB_BATCH)  # these runs go in lanes: 32-run sub-batches too
    run_campaign(_short(tmp_path, chunk_runs=70), runs=70, seed=3, out_dir=tmp_path / "p", workers=1, progress=True)
    assert offline_simulate.SUB_BATCH == 32 and events == ["compiled", "clock", 32, 32, 6, "saved"]
    lines = capsys.readouterr().err.splitlines()
    assert [line.split()[1] for line in lines if line.startswith("runs ")] == ["32/70", "64/70", "70/70"]


def test_a_campaign_disperses_fault_kinds_times_and_lengths_and_run_k_is_the_fault_alone(tmp_path) -> None:
    """``dispersions.faults``: one fault per run, its kind, start and length drawn from the run's
    own generator; the table records them with the controller's answers, and run k equals
    `sappc simulate` of the scenario with run k's fault written out (one fault implementation)."""
    faults = {"choices": [{"kind": "sensor_dropout"}, {"kind": "actuator_dropout"}, {"kind": "actuator_effectiveness", "effectiveness": [0.5, 0.5, 0.5]}],
              "start_s": {"distribution": "uniform", "low": 10.0, "high": 15.0},
              "duration_s": {"distribution": "uniform", "low": 0.2, "high": 1.0}}
    path = _short(tmp_path, chunk_runs=4, faults=faults)
    run_campaign(path, runs=8, seed=9, out_dir=tmp_path / "f", progress=False)
    table = np.genfromtxt(tmp_path / "f" / "runs.csv", delimiter=",", names=True, dtype=None, encoding="utf-8")
    assert set(table["fault_kind"]) <= {"sensor_dropout", "actuator_dropout", "actuator_effectiveness"} and len(set(table["fault_kind"])) >= 2
    assert np.all((table["fault_start_s"] >= 10.0) & (table["fault_start_s"] <= 15.0))
    length = table["fault_end_s"] - table["fault_start_s"]
    assert np.all((length >= 0.2 - 1e-12) & (length <= 1.0 + 1e-12))
    dropouts = table["fault_kind"] == "sensor_dropout"
    assert np.all(table["answers_watchdog_zero"][dropouts] > 0) and np.all(table["answers_watchdog_zero"][~dropouts] == 0)
    assert np.all(table["answers_held"][dropouts] == 10)  # the default 0.1 s stale timeout at 100 Hz
    k = int(np.flatnonzero(dropouts)[0])
    raw = yaml.safe_load(open(path).read())
    scenario = scenario_from_mapping(raw)
    cfg = campaign_config(scenario)
    inputs = draw_inputs(cfg, 9, [k])
    entry = {"kind": "sensor_dropout", "start_s": float(inputs.fault_start_s[0]), "end_s": float(inputs.fault_start_s[0] + inputs.fault_duration_s[0])}
    assert faults_from_list([entry])[0].end_s > faults_from_list([entry])[0].start_s
    explicit = copy.deepcopy(raw)
    explicit["faults"] = [entry]
    del explicit["montecarlo"]["dispersions"]["faults"]
    # the fault is drawn after every other value of the run, so the others do not move without it
    again, _, _ = mc.simulate_runs(explicit, 9, [k], 0)
    same, _, _ = mc.simulate_runs(raw, 9, [k], 0)
    for key in ("steady_max_abs_qev", "max_abs_torque_Nm", "answers_watchdog_zero", "answers_held"):
        np.testing.assert_array_equal(again[key], same[key], err_msg=key)
    assert int(table["answers_watchdog_zero"][k]) == int(same["answers_watchdog_zero"][0])


@NO_EMPTY_LOG_AXES
def test_a_campaign_with_the_estimator_reports_its_errors_and_its_consistency(tmp_path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """``paper_tracking_flight.yaml`` (the MEKF between sensors and controller), 6 runs of 8 s: each
    run's estimation metrics are columns of runs.csv equal to the run alone, summary.json holds the
    NEES averaged over the runs against its chi-square band, and montecarlo_nees.png draws it."""
    from sappc.scenario import read_scenario_mapping

    raw = read_scenario_mapping(SCENARIOS / "paper_tracking_flight.yaml")
    raw["duration_s"] = 8.0
    raw["metrics"]["steady_from_s"] = 6.0
    raw["montecarlo"]["chunk_runs"] = 4  # two chunks: the per-sample NEES sums add up across them
    path = tmp_path / "flight.yaml"
    path.write_text(yaml.safe_dump(raw))
    saved = capture_figures(monkeypatch)
    summary = run_campaign(path, runs=6, seed=3, out_dir=tmp_path / "f", progress=False)
    nees = summary["estimator"]["nees_consistency"]
    assert nees["runs"] == 6 and nees["from_s"] == 5.0 and nees["samples"] == 301  # [5, 8] s at 100 Hz
    lo, hi = nees["band_95"]
    assert lo < 6.0 < hi and nees["min"] <= nees["mean_over_time"] <= nees["max"]
    table = np.genfromtxt(tmp_path / "f" / "runs.csv", delimiter=",", names=True)
    for k in (1, 4):  # one from each chunk
        _, _, metrics, _ = load_campaign_run(tmp_path / "f", k)
        for name in ("steady_max_abs_attitude_estimation_error_rad", "final_abs_bias_estimation_error_rad_s", "mean_nees"):
            assert metrics[name] == table[name][k], name
    # the campaign's per-sample mean NEES is the mean of the runs' NEES, recomputed from their histories
    from sappc.evaluation.estimation import attitude_errors, nees as nees_of

    per_run = []
    for k in range(6):
        _, _, _, h = load_campaign_run(tmp_path / "f", k, with_history=True)
        e = h.estimate
        err = np.concatenate((attitude_errors(e.q_BN[:, 0], h.q_BN[:, 0]), e.gyro_bias_true[:, 0] - e.gyro_bias[:, 0]), axis=1)
        per_run.append(nees_of(err, e.covariance[:, 0]))
    mean = np.mean(per_run, axis=0)[h.t >= 5.0 - 1e-9]
    assert nees["min"] == pytest.approx(mean.min(), rel=1e-12) and nees["max"] == pytest.approx(mean.max(), rel=1e-12)
    figure = next(f for f in saved if "consistency" in f.texts[0].get_text())
    assert_every_axes_shows_data([figure])


def test_dispersed_tracker_outages_are_each_runs_own_and_in_its_row(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """``dispersions.hardware.star_tracker_outage_start_s`` / ``_duration_s``: one outage per run,
    added to the scenario's; the draws are columns of runs.csv, run k alone equals its row, and in
    each run the estimator only propagates (no tracker update) inside its own outage."""
    from sappc.scenario import read_scenario_mapping
    from sappc_estimator.core.mekf import STATUS_UPDATED

    raw = read_scenario_mapping(SCENARIOS / "paper_tracking_flight.yaml")
    raw["duration_s"] = 8.0
    raw["metrics"]["steady_from_s"] = 6.0
    raw["montecarlo"]["dispersions"]["hardware"].update(
        star_tracker_outage_start_s={"distribution": "uniform", "low": 2.0, "high": 4.0},
        star_tracker_outage_duration_s={"distribution": "uniform", "low": 1.0, "high": 2.0})
    path = tmp_path / "flight.yaml"
    path.write_text(yaml.safe_dump(raw))
    run_campaign(path, runs=3, seed=5, out_dir=tmp_path / "o", progress=False)
    table = np.genfromtxt(tmp_path / "o" / "runs.csv", delimiter=",", names=True)
    starts, durations = table["star_tracker_outage_start_s_1"], table["star_tracker_outage_duration_s_1"]
    assert np.all((starts >= 2.0) & (starts <= 4.0)) and np.all((durations >= 1.0) & (durations <= 2.0))
    assert len(set(starts.tolist())) == 3
    for k in range(3):
        _, _, metrics, h = load_campaign_run(tmp_path / "o", k, with_history=True)
        assert metrics["mean_nees"] == table["mean_nees"][k]
        updated = h.t[h.estimate.status[:, 0] == STATUS_UPDATED]
        inside = (updated >= starts[k] + 0.01) & (updated < starts[k] + durations[k])
        assert not inside.any() and np.any(updated > starts[k] + durations[k])  # none in its outage, some after

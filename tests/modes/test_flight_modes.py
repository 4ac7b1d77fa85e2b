"""The flight modes in the offline closed loop (issue 49): the ``modes`` section, the loop's laws in
each mode, the start of the controller at TRACK's entry, the mode metrics and verdict, and the
separation scenario from tip-off to tracking."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import pytest

from gnc_common.validation import ConfigError
from sappc.evaluation.requirements import failed_requirements
from sappc.files import scenario_path
from sappc.offline.compiled_loop import prepare, run_batch, run_blocks, run_single
from sappc.offline.simulate import simulate
from sappc.scenario import load_scenario, read_scenario_mapping, scenario_from_mapping
from sappc_controller.core.kernels import O_RHO, O_TORQUE
from sappc_modes.core.bdot import detumble_gain
from sappc_modes.core.modes import DETUMBLE, HOLD, R_ACQUIRED, R_DETUMBLED, R_NONE, TRACK
from sappc_modes.core.packing import MR_ENTRY, MR_SAMPLES, MR_TRANSITIONS
from sappc_msgs_py.contract import ANSWER_COMMANDED, ANSWER_INACTIVE


def _separation(duration_s: float, **modes: Any) -> Any:
    """The bundled separation scenario, ``duration_s`` long, its ``modes`` keys replaced."""
    raw = read_scenario_mapping(scenario_path("flight_separation"))
    raw["duration_s"] = duration_s
    raw["modes"] = {**raw["modes"], **modes}
    return scenario_from_mapping(raw)


#: Guards quick enough for a few seconds of flight: DETUMBLE for 0.5 s whatever the rate, HOLD for
#: 0.5 s of a healthy estimate (any 1-sigma below 1 rad), then TRACK.
QUICK = {"transitions": {"detumbled_rate_rad_s": 10.0, "detumbled_for_s": 0.5, "healthy_for_s": 0.5, "converged_sigma_rad": 1.0}}


# ---------------------------------------------------------------------------- the modes section


@pytest.mark.parametrize("change, message", [
    ({"initial_mode": "SLEEP"}, "modes.initial_mode must be one of DETUMBLE, HOLD, TRACK, SAFE"),
    ({"hold_gain": 1.0}, "unknown key modes.hold_gain"),
    ({"detumble_gain_N_m_s": -1.0}, "modes.detumble_gain_N_m_s"),
    ({"detumble_gain_N_m_s": "criteria"}, "modes.detumble_gain_N_m_s"),
    ({"transitions": {"detumbled_rate_rad_s": 0.0}}, "detumbled_rate_rad_s"),
    ({"hold_gains": {"K_Nm": 0.16}}, "modes.hold_gains"),
])
def test_the_modes_section_names_a_bad_key_or_value(change: dict[str, Any], message: str) -> None:
    raw = read_scenario_mapping(scenario_path("flight_separation"))
    raw["modes"] = {**raw["modes"], **change}
    with pytest.raises(ConfigError, match=message.replace(".", r"\.")):
        scenario_from_mapping(raw)


def test_modes_need_the_rods_and_momentum_management() -> None:
    raw = read_scenario_mapping(scenario_path("flight_separation"))
    raw["momentum_management"] = None
    with pytest.raises(ConfigError, match="modes needs an orbit, magnetorquers and momentum_management"):
        scenario_from_mapping(raw)
    raw = read_scenario_mapping(scenario_path("flight_separation"))
    del raw["modes"]["hold_gains"]
    with pytest.raises(ConfigError, match="modes.hold_gains is required"):
        scenario_from_mapping(raw)


def test_the_criterion_gain_is_computed_from_the_orbit_field_and_inertia() -> None:
    """``criterion``: k* = 2 n (1 + sin xi_m) J_min with xi_m the angle between the orbit's normal
    and the dipole's axis at t = 0, computed here from the file's numbers by hand."""
    sc = load_scenario(scenario_path("flight_separation"))
    raw = read_scenario_mapping(scenario_path("flight_separation"))
    orbit, field = raw["orbit"], raw["orbit"]["magnetic_field"]
    i = math.radians(orbit["inclination_deg"])  # raan 0, Earth rotation angle 0 in the file
    assert orbit["raan_deg"] == 0.0 and orbit["earth_rotation_angle_deg"] == 0.0
    normal = np.array([0.0, -math.sin(i), math.cos(i)])
    m = np.array([field["g11_nT"], field["h11_nT"], field["g10_nT"]])
    xi = math.acos(abs(normal @ m) / np.linalg.norm(m))
    n = sc.environment.orbit.mean_motion_rad_s
    assert sc.modes is not None and sc.modes.detumble_gain_source == "criterion"
    expected = detumble_gain(n, min(xi, math.pi - xi), 4.0)  # J = diag(4, 4, 4)
    assert sc.modes.detumble_gain_N_m_s == pytest.approx(expected, rel=1e-12)  # the same formula, operands rounded alike
    assert sc.modes.detumble_gain_N_m_s == pytest.approx(2 * n * (1 + math.sin(xi)) * 4.0, rel=1e-12)
    given = _separation(1.0, detumble_gain_N_m_s=0.02)
    assert given.modes is not None and given.modes.detumble_gain_N_m_s == 0.02 and given.modes.detumble_gain_source == "given"


# ---------------------------------------------------------------------------- the loop in each mode


@pytest.fixture(scope="module")
def detumbling() -> Any:
    """Twenty seconds of the separation: DETUMBLE throughout (its rate is far above the guard's)."""
    sc = _separation(20.0)
    return sc, run_single(prepare(sc), 0, 1)


def test_detumble_commands_b_dot_on_the_rods_and_nothing_on_the_wheels(detumbling: Any) -> None:
    sc, run = detumbling
    mode = run.record.mode[0, :, 0]
    assert np.all(mode == DETUMBLE) and np.all(run.record.mode[0, :, 1] == R_NONE)
    assert np.all(run.status[0] == ANSWER_INACTIVE)
    assert np.all(run.wheels[0, :, :, 1] == 0.0)  # no motor torque
    B_meas, m_rods = run.env[0, :, 3:6], run.env[0, :, 9:12]
    k_gain, dt = sc.modes.detumble_gain_N_m_s, sc.control_period_s
    stride = int(round(1.0 / (sc.environment.magnetometer.rate_hz * dt)))  # the magnetometer's update every 10 samples
    m_max = sc.environment.magnetorquers.max_dipoles()
    checked = 0
    for k in range(stride, run.t.size, stride):
        B, B_prev = B_meas[k], B_meas[k - stride]
        m_B = -(k_gain / (B @ B)) * (B - B_prev) / (stride * dt)  # the law, with the rods along the body axes
        expected = np.clip(m_B, -m_max, m_max)
        # the kernel's operations in another order: a few ulps of the dipole (the field's difference
        # is exact, its norm and the quotients round once or twice each)
        np.testing.assert_allclose(m_rods[k], expected, rtol=1e-12, atol=0.0)
        np.testing.assert_array_equal(m_rods[k:k + stride], np.broadcast_to(m_rods[k], (min(stride, run.t.size - k), 3)))  # held
        checked += 1
    assert checked == run.t.size // stride - (run.t.size % stride == 0)
    assert np.all(m_rods[:stride] == 0.0)  # the first sample only primes the law
    # dissipative on average: the rods' torque m x B_true against the body rate (a sample's power may
    # be positive: the law differences the magnetometer's noisy samples, 50 nT against a change of
    # about 200 nT a sample at this rate), and the kinetic energy falls
    w = run.x[0, :, 4:]
    torque = np.cross(m_rods[stride:], run.env[0, stride:, 0:3])
    power = np.einsum("ij,ij->i", torque, w[stride:])
    assert power.mean() < 0.0 and np.count_nonzero(power < 0.0) > 0.9 * power.size
    assert w[-1] @ w[-1] < w[0] @ w[0]


def test_the_controller_starts_at_tracks_entry_and_hold_flies_before() -> None:
    sc = _separation(3.0, **QUICK)
    inp = prepare(sc)
    run = run_single(inp, 0, 1)
    mode, reason = run.record.mode[0, :, 0], run.record.mode[0, :, 1]
    k_hold = int(np.flatnonzero(mode == HOLD)[0])
    k_track = int(np.flatnonzero(mode == TRACK)[0])
    assert 0 < k_hold < k_track and np.all(mode[:k_hold] == DETUMBLE) and np.all(mode[k_hold:k_track] == HOLD) and np.all(mode[k_track:] == TRACK)
    assert reason[k_hold] == R_DETUMBLED and reason[k_track] == R_ACQUIRED
    assert np.count_nonzero(reason) == 2
    assert k_hold == 49  # 0.5 s is 50 samples meeting the guard: the 50th (k = 49) takes the transition and flies HOLD
    # the controller: inactive until TRACK, then it computes from its first valid sample there
    assert np.all(run.status[0, :k_track] == ANSWER_INACTIVE) and np.all(run.status[0, k_track:] == ANSWER_COMMANDED)
    assert np.all(np.isnan(run.out[0, :k_track, O_RHO, :3])) and np.all(np.isfinite(run.out[0, k_track:, O_RHO, :3]))
    # HOLD: the wheels carry the hold law's torque (pointing at the reference: the scenario's hold_attitude)
    assert np.any(run.out[0, k_hold:k_track, O_TORQUE, :3] != 0.0)
    # the run's summary
    mr = run.record.mode_run[0]
    assert mr[MR_ENTRY + DETUMBLE] == 0.0 and mr[MR_ENTRY + HOLD] == run.t[k_hold] and mr[MR_ENTRY + TRACK] == run.t[k_track]
    assert np.isnan(mr[MR_ENTRY + 3])
    assert mr[MR_SAMPLES + DETUMBLE] == k_hold and mr[MR_SAMPLES + HOLD] == k_track - k_hold and mr[MR_SAMPLES + TRACK] == run.t.size - k_track
    assert mr[MR_TRANSITIONS] == 2


def test_a_moded_run_in_blocks_and_in_a_batch_is_the_run_alone_bit_for_bit() -> None:
    sc = _separation(3.0, **QUICK)
    inp = prepare(sc)
    alone = run_single(inp, 0, 1)
    for block in (7, 128):
        parts = list((r.record.mode.copy(), r.record.out.copy()) for r in run_blocks(inp, 1, block))
        assert np.array_equal(np.concatenate([p[0] for p in parts], axis=1), alone.record.mode), block
        assert np.array_equal(np.concatenate([p[1] for p in parts], axis=1).view(np.uint8), alone.record.out.view(np.uint8)), block
    q0 = np.stack([sc.q_BN0, sc.q_BN0])
    batch = run_batch(prepare(sc, q_BN0=q0), 1)
    # run 0 of the batch is the run alone (run 1 draws its own magnetometer noise: its key (1,))
    assert np.array_equal(batch.record.mode[0], alone.record.mode[0])
    assert np.array_equal(batch.record.x[0].view(np.uint8), alone.record.x[0].view(np.uint8))
    assert np.array_equal(batch.record.mode_run[0], alone.record.mode_run[0], equal_nan=True)


def test_the_mode_metrics_and_a_flight_that_never_tracks_fails() -> None:
    sc = _separation(3.0, **QUICK)
    result = simulate(sc, history="none")
    m = result.metrics
    assert m["mode_sequence"] == ["DETUMBLE", "HOLD", "TRACK"]
    assert m["mode_transitions"] == 2
    times = m["time_in_mode_s"]
    assert sum(times.values()) == pytest.approx(301 * 0.01, abs=1e-9)  # every sample held dt
    assert times["DETUMBLE"] == pytest.approx(0.49, abs=1e-9) and times["SAFE"] == 0.0  # k = 0 .. 48 (test above)
    assert m["time_to_track_s"] == pytest.approx(0.49 + times["HOLD"], abs=1e-9)
    assert result.controller_summary["inactive"] == round((times["DETUMBLE"] + times["HOLD"]) / 0.01)
    # a flight that stays in DETUMBLE (the default guards: 1 s is far too short to detumble)
    stuck = simulate(_separation(1.0), history="none")
    assert stuck.metrics["mode_sequence"] == ["DETUMBLE"] and stuck.metrics["time_to_track_s"] is None
    failed = failed_requirements(stuck.metrics, {}, stuck.controller_summary)
    assert "the flight never reached TRACK (modes flown: DETUMBLE)" in failed
    assert not any("computed the torque" in line for line in failed)  # its inactive samples are not the controller's


# ---------------------------------------------------------------------------- the separation


def test_the_separation_detumbles_acquires_and_tracks_to_the_flight_figures() -> None:
    """The bundled separation scenario, whole (an orbit): DETUMBLE, HOLD (the acquisition), TRACK;
    its metrics, from TRACK's start, meet the flight scenario's figures (settling within 20 s, the
    steady error within 5e-5, no overshoot) and TRACK comes within 30 min: its requirements."""
    sc = load_scenario(scenario_path("flight_separation"))
    result = simulate(sc, history="none")
    m = result.metrics
    assert m["mode_sequence"] == ["DETUMBLE", "HOLD", "TRACK"]
    assert m["finite"] and m["control_lost_at_s"] is None
    assert set(sc.metrics.requirements) >= {"settling_time_s_max", "steady_max_abs_qev_max", "overshoot_max", "time_to_track_s_max"}
    assert failed_requirements(m, sc.metrics.requirements, result.controller_summary, settle_threshold=sc.metrics.settle_threshold) == []
    assert m["settling_time_s"] <= 20.0 and m["steady_max_abs_qev"] <= 5.0e-5


def test_replace_gives_a_mapping_whole_instead_of_merged(tmp_path: Any) -> None:
    """``replace: [metrics.requirements]`` drops the base's requirements (the separation's are its
    own: not the flight scenario's switching rate, which its base requires); without it a file's
    requirements are merged into the base's."""
    sc = load_scenario(scenario_path("flight_separation"))
    assert "torque_sign_changes_per_s_max" in load_scenario(scenario_path("paper_tracking_orbit")).metrics.requirements
    assert set(sc.metrics.requirements) == {"settling_time_s_max", "steady_max_abs_qev_max", "overshoot_max", "max_abs_wheel_speed_rad_s_max",
                                            "time_to_track_s_max"}
    merged = tmp_path / "merged.yaml"
    merged.write_text("extends: flight_separation.yaml\nmetrics:\n  requirements: {torque_reversals_per_s_max: 1.0}\n")
    assert set(load_scenario(merged).metrics.requirements) == set(sc.metrics.requirements) | {"torque_reversals_per_s_max"}
    bad = tmp_path / "bad.yaml"
    bad.write_text("extends: flight_separation.yaml\nreplace: metrics.requirements\n")
    with pytest.raises(ConfigError, match="replace must be a list of dotted keys"):
        load_scenario(bad)


def _moded(t: np.ndarray, q_ev: np.ndarray, mode: np.ndarray, rng: np.random.Generator) -> Any:
    """A history of runs (T, N) with switching torques, RPFs, saturations and bands of their own, and a mode record."""
    import dataclasses as dc

    from sappc.evaluation.history import History

    T, N, _ = q_ev.shape
    q_BR = np.concatenate((q_ev, np.sqrt(1.0 - np.sum(q_ev**2, axis=2, keepdims=True))), axis=2)
    torque = 0.1 * rng.standard_normal((T, N, 3))
    torque[np.abs(torque) < 0.05] = 0.0
    zeros = np.zeros((T, N, 3))
    h = History(t=t, q_BN=q_BR.copy(), omega_BN_B=zeros.copy(), q_BR=q_BR, torque_B=torque, torque_cmd_B=torque.copy(),
                saturated=rng.random((T, N, 3)) < 0.1, disturbance_B=zeros.copy(), rho=0.02 * rng.standard_normal((T, N, 3)),
                band_lower=np.full((T, N, 3), -0.05), band_upper=np.full((T, N, 3), 0.04), eps=zeros.copy(), z=zeros.copy(), V=zeros.copy())
    return dc.replace(h, mode=mode.astype(np.int8), mode_reason=np.zeros((T, N), dtype=np.int8))


@pytest.mark.parametrize("origin", ["first_track", "last_track"])
def test_a_moded_runs_metrics_are_those_of_its_samples_from_track_on(origin: str) -> None:
    """The metrics' origin (sappc.evaluation.metrics): a run with modes is measured from its first
    TRACK sample, as the same run's samples from there would be measured alone with their times
    from zero, bit for bit (an exact binary grid: the times' differences are exact), whatever the
    blocks it is fed in; a run that never tracks has no tracking metrics; without modes, nothing
    changes (the rest of the suite)."""
    from sappc.evaluation.metrics import MetricsAccumulator

    rng = np.random.default_rng(49)
    dt, T = 0.125, 96
    t = np.arange(T) * dt
    q_ev = 0.2 * np.exp(-0.5 * t)[:, None, None] * rng.uniform(-1.0, 1.0, (1, 3, 3)) + 1e-3 * rng.standard_normal((T, 3, 3))
    q_ev[:20] += 0.3  # far from the reference before TRACK
    starts = (20, 0, None)  # run 0 enters TRACK at sample 20 (an early block's end), run 1 starts in it, run 2 never does
    mode = np.full((T, 3), HOLD)
    for n, k in enumerate(starts):
        if k is not None:
            mode[k:, n] = TRACK
    mode[40:47, 0] = 3  # run 0 leaves TRACK for SAFE, and enters it again at 47 (last_track: its origin); run 1 at 33
    mode[30:33, 1] = HOLD
    if origin == "last_track":
        starts = (47, 33, None)
    h = _moded(t, q_ev, mode, rng)
    settings = {"steady_from_s": 4.0, "settle_threshold": 0.02, "t2_s": 2.5, "fault_windows": [], "origin": origin}
    keys = ("settling_time_s", "steady_max_abs_qev", "steady_mean_abs_qev", "rpf_error_at_t2", "overshoot", "max_abs_torque_Nm",
            "torque_sign_changes_per_s", "torque_reversals_per_s", "time_outside_constraint_s")
    for block in (T, 7, 1):
        acc = MetricsAccumulator(t, 3, **settings)  # type: ignore[arg-type]
        for lo in range(0, T, block):
            acc.add_history(h.samples(lo, lo + block))
        for n, k in enumerate(starts):
            got = acc.run_metrics(n)
            if k is None:
                assert got["settling_time_s"] is None and got["steady_max_abs_qev"] is None and got["rpf_error_at_t2"] is None, block
                assert got["time_to_track_s"] is None and got["max_abs_torque_Nm"] == 0.0 and got["time_outside_constraint_s"] == 0.0
                continue
            tail = dataclasses.replace(h.samples(k, T), t=t[k:] - t[k], mode=None, mode_reason=None)
            alone = MetricsAccumulator(tail.t, 1, **{**settings, "origin": "first_track"})  # type: ignore[arg-type]
            alone.add_history(dataclasses.replace(tail, **{f: getattr(tail, f)[:, n:n + 1] for f in (
                "q_BN", "omega_BN_B", "q_BR", "torque_B", "torque_cmd_B", "saturated", "disturbance_B", "rho", "band_lower", "band_upper",
                "eps", "z", "V")}))
            want = alone.run_metrics(0)
            for key in keys:
                assert got[key] == want[key], (block, n, key, got[key], want[key])
            assert got["time_to_track_s"] == t[20 if n == 0 else 0]  # the first entry, whatever the origin
        # the split matters nowhere: every block size gives these numbers (checked against the run alone above)


def test_every_per_run_metric_says_whether_a_new_origin_restarts_it() -> None:
    """``origin: last_track`` restarts the tracking metrics at each TRACK entry
    (``MetricsAccumulator._restart_origin``): every per-run field is either restarted, to the fresh
    value ``__init__`` gives it, or kept, never both, never neither (a new metric must choose)."""
    from sappc.evaluation.metrics import MetricsAccumulator, SampleGrid

    restarted = [name for name, _ in MetricsAccumulator._RESTARTED_AT_ORIGIN]
    kept = list(MetricsAccumulator._KEPT_AT_ORIGIN)
    assert sorted(restarted + kept) == sorted(MetricsAccumulator._PER_RUN) and len(set(restarted) | set(kept)) == len(restarted) + len(kept)
    sc = load_scenario(scenario_path("flight_separation"))
    fresh = MetricsAccumulator(SampleGrid.of_run(1.0, 0.01), 2, steady_from_s=0.5, settle_threshold=1e-3, t2_s=0.5, fault_windows=[],
                               orbit_bins=sc.orbit_bins(), origin="last_track")
    for name, value in MetricsAccumulator._RESTARTED_AT_ORIGIN:
        a = getattr(fresh, name)
        assert a is None or np.array_equal(a, np.full_like(a, value), equal_nan=True), name  # (None: allocated with the first block)


def test_a_campaign_of_separations_reports_the_time_to_track(tmp_path: Any) -> None:
    """A campaign with modes: each run's time to TRACK and transitions in its table and runs.csv,
    their distribution and the runs that never tracked in the summary, and such a run's reason."""
    import csv
    import json

    from sappc.montecarlo.campaign import run_campaign

    quick = tmp_path / "quick.yaml"
    quick.write_text("extends: flight_separation.yaml\nduration_s: 3.0\nmetrics:\n  steady_from_s: 1.0\n  t2_s: 0.5\n"
                     "modes:\n  transitions: {detumbled_rate_rad_s: 10.0, detumbled_for_s: 0.5, healthy_for_s: 0.5, converged_sigma_rad: 1.0,"
                     " acquired_error_rad: null}\n"
                     "montecarlo:\n  chunk_runs: 2\n")
    summary = run_campaign(quick, runs=3, seed=7, out_dir=tmp_path / "out", progress=False)
    modes = summary["modes"]
    assert modes["runs_never_tracked"] == 0 and modes["time_to_track_s"]["max"] <= 3.0
    assert modes["time_to_track_s"]["p50"] <= modes["time_to_track_s"]["p95"] <= modes["time_to_track_s"]["max"]
    rows = list(csv.DictReader((tmp_path / "out" / "runs.csv").open()))
    assert len(rows) == 3 and all(0.49 <= float(r["time_to_track_s"]) <= 3.0 and float(r["mode_transitions"]) == 2.0 for r in rows)
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["modes"] == modes
    # a campaign whose runs never reach TRACK (the default guards: 3 s is far too short to detumble)
    slow = tmp_path / "slow.yaml"
    slow.write_text("extends: flight_separation.yaml\nduration_s: 3.0\nmontecarlo:\n  chunk_runs: 2\n")
    summary = run_campaign(slow, runs=2, seed=7, out_dir=tmp_path / "out_slow", progress=False)
    assert summary["modes"]["runs_never_tracked"] == 2 and summary["passed"] == 0
    assert all("never reached TRACK" in f["why"] for f in summary["failed_runs"])


def _requested(duration_s: float, requests: list[dict[str, Any]]) -> Any:
    """A few seconds of the separation with quick guards (a 1 s recovery from SAFE) and the ground's ``requests``."""
    return _separation(duration_s, transitions={**QUICK["transitions"], "recover_for_s": 1.0}, requests=requests)


def test_each_later_entry_into_track_restarts_the_controller_afresh() -> None:
    """Ground requests send a tracking spacecraft to SAFE twice; it recovers, acquires and tracks
    again each time: each later TRACK entry restarts the controller (its state afresh, its time
    origin and start constants from its first valid sample there), so that sample's answer is the
    one of a controller started fresh on its inputs (the kernel called alone: the same compiled
    operations, bit for bit); the run in blocks and in a batch is the run alone, bit for bit (a
    restart's constants, computed when the run meets it, replay the block)."""
    from gnc_common.compiled import error_quaternion
    from sappc.offline.compiled_loop import R_OMEGA, R_Q
    from sappc_controller.core.kernels import N_WORK, controller_step_one, new_state
    from sappc_controller.core.packing import start_coef
    from sappc_modes.core.modes import R_RECOVERED, R_REQUEST, SAFE

    sc = _requested(20.0, [{"at_s": 12.0, "mode": "SAFE"}, {"at_s": 5.0, "mode": "SAFE"}])  # given out of order: sorted
    inp = prepare(sc)
    run = run_single(inp, 0, 1)
    mode, reason = run.record.mode[0, :, 0], run.record.mode[0, :, 1]
    k_safe = np.flatnonzero(reason == R_REQUEST)
    assert run.t[k_safe].tolist() == [5.0, 12.0] and np.all(mode[k_safe] == SAFE)
    entries = np.flatnonzero((reason == R_ACQUIRED) & (mode == TRACK))
    assert entries.size == 3 and np.count_nonzero(reason == R_RECOVERED) == 2
    assert inp.modes.starts_known[0] == 3  # the first start and two restarts
    grid = inp.whole().grid
    for k in entries[1:]:  # each restart: the first valid sample in TRACK is the entry's own sample here
        assert run.status[0, k] == ANSWER_COMMANDED
        e = run.record.estimate[0, k]
        q, w = np.ascontiguousarray(e[R_Q:R_Q + 4]), np.ascontiguousarray(e[R_OMEGA:R_OMEGA + 3])
        q_e0 = np.empty(4)
        error_quaternion(grid.ref_q[k], q, q_e0)
        coef, _ = start_coef(inp.config, q_e0[None], on_infeasible=inp.on_infeasible)
        t_k = grid.t_ns[k] / 1_000_000_000
        out = np.zeros((1,) + run.out.shape[2:])
        controller_step_one(inp.controller.kind, t_k, sc.control_period_s, q, w, grid.ref_q[k], grid.ref_w[k], grid.ref_wd[k],
                            inp.controller.prm[:1], np.ascontiguousarray(coef), new_state(1, t_k), np.zeros((N_WORK, 4)), out, np.zeros((1, 3), bool))
        assert np.array_equal(run.out[0, k, :3].view(np.uint8), out[0, :3].view(np.uint8)), k  # torque, command, saturation
        assert np.array_equal(run.out[0, k, 4:].view(np.uint8), out[0, 4:].view(np.uint8)), k  # rho, the band, eps, z, V
    for block in (7, 1000):
        parts = [(r.record.mode.copy(), r.record.out.copy()) for r in run_blocks(prepare(sc), 1, block)]
        assert np.array_equal(np.concatenate([p[0] for p in parts], axis=1), run.record.mode), block
        assert np.array_equal(np.concatenate([p[1] for p in parts], axis=1).view(np.uint8), run.record.out.view(np.uint8)), block
    batch = run_batch(prepare(sc, q_BN0=np.stack([sc.q_BN0, sc.q_BN0])), 1)
    assert np.array_equal(batch.record.out[0].view(np.uint8), run.record.out[0].view(np.uint8))


def test_mode_requests_are_checked() -> None:
    for requests, message in (([{"at_s": -1.0, "mode": "SAFE"}], "modes.requests\\[0\\].at_s"),
                              ([{"at_s": 1.0, "mode": "OFF"}], "modes.requests\\[0\\].mode must be one of"),
                              ([{"at": 1.0, "mode": "SAFE"}], "modes.requests\\[0\\] must be a mapping with exactly at_s and mode"),
                              ({"at_s": 1.0}, "modes.requests must be a list")):
        with pytest.raises(ConfigError, match=message):
            _requested(1.0, requests)  # type: ignore[arg-type]


def test_the_blinded_tracker_goes_safe_on_the_gyro_and_tracks_again_to_the_flight_figures() -> None:
    """The bundled blinded-tracker scenario: the tracker silent from 2000 s to 2120 s while
    tracking; the health STALE once its last sample (1999.9 s) is 2 s old, SAFE after 5 s of it
    (the guard's persistence in whole samples), SAFE's torque the rate damping of the gyro alone
    (the estimate is not used), HOLD once healthy again, TRACK again with the controller restarted,
    and from that restart the flight scenario's figures: its requirements (metrics.origin:
    last_track), and the loss-of-control rule."""
    from sappc.offline.compiled_loop import R_B, R_MON_LEVEL, R_OMEGA
    from sappc_controller.core.kernels import KIND_MRP_FEEDBACK, N_OUT, N_WORK, O_CMD, controller_step_one, new_state
    from sappc_controller.core.kernels import O_TORQUE as O_TORQUE_ROW
    from sappc_estimator.core.mekf import MON_STALE
    from sappc_modes.core.modes import R_ESTIMATOR_ERROR, R_RECOVERED, SAFE, samples_for

    sc = load_scenario(scenario_path("flight_blinded_tracker"))
    inp = prepare(sc)
    run = run_single(inp, 0, 1)
    mode, reason = run.record.mode[0, :, 0], run.record.mode[0, :, 1]
    events = [(int(k), int(mode[k]), int(reason[k])) for k in np.flatnonzero(reason)]
    assert [e[1:] for e in events] == [(HOLD, R_DETUMBLED), (TRACK, R_ACQUIRED), (SAFE, R_ESTIMATOR_ERROR), (HOLD, R_RECOVERED),
                                       (TRACK, R_ACQUIRED)]
    level = run.record.estimate[0, :, R_MON_LEVEL]
    stale = np.flatnonzero(level == MON_STALE)
    dt = sc.control_period_s
    # the last tracker sample at 1999.9 s (10 Hz): STALE at the first sample more than 2 s later, to the tracker's return
    assert run.t[stale[0]] == pytest.approx(1999.9 + 2.0 + dt, abs=1e-9) and run.t[stale[-1] + 1] == pytest.approx(2120.0, abs=1e-9)
    assert np.all(np.diff(stale) == 1)
    k_safe = events[2][0]
    assert k_safe - stale[0] == samples_for(5.0, dt) - 1  # the guard's 500th sample of STALE takes SAFE
    assert events[3][0] > stale[-1]  # HOLD only once the tracker is back (and the health OK 30 s)
    # SAFE flies the rate damping of the gyro alone: each sample's command is the MRP feedback law with
    # no attitude gain on the gyro's rate (the estimate's rate plus its bias: the gyro's measurement,
    # to one rounding of each component), whatever the estimate's attitude
    safe_rows = np.flatnonzero(mode == SAFE)
    e = run.record.estimate[0]
    for k in safe_rows[:: max(1, safe_rows.size // 50)]:
        gyro = e[k, R_OMEGA:R_OMEGA + 3] + e[k, R_B:R_B + 3]
        unit = np.array([0.0, 0.0, 0.0, 1.0])
        out = np.zeros((1, N_OUT, 4))
        controller_step_one(KIND_MRP_FEEDBACK, run.t[k], dt, unit, gyro, unit, np.zeros(3), np.zeros(3), inp.modes.safe_prm[:1],
                            inp.controller.coef[:1], new_state(1), np.zeros((N_WORK, 4)), out, np.zeros((1, 3), bool))
        # the loop commands the law's torque after its actuator model (saturation, minimum output):
        # one rounding of the gyro's reconstruction, times the rate gain P = 40, is far below both
        np.testing.assert_allclose(run.out[0, k, O_CMD, :3], out[0, O_TORQUE_ROW, :3], rtol=0.0, atol=1e-12)
    result = simulate(sc, history="none")
    assert failed_requirements(result.metrics, sc.metrics.requirements, result.controller_summary,
                               settle_threshold=sc.metrics.settle_threshold) == []
    assert result.metrics["mode_sequence"] == ["DETUMBLE", "HOLD", "TRACK", "SAFE", "HOLD", "TRACK"]

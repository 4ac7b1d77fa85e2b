"""The offline loop in SIMD lanes (sappc.offline.lanes): what it covers, its parity with the
per-run loop, and the runs it hands back (docs/parity.md, "Campaign runs in SIMD lanes")."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import yaml

from conftest import SCENARIOS
from gnc_common import libm
from sappc.offline import compiled_loop
from sappc.offline.lanes import LANES, lanes_refusal
from sappc.scenario import load_scenario, scenario_from_mapping
from sappc_msgs_py.contract import ANSWER_NAMES
from spacecraft_sim.core.wheels import MAX_LANE_WHEELS, PRESETS

#: Runs of the batches below: a full group and a padded one.
N_RUNS = LANES + 3


def _scenario(duration_s: float = 5.0):  # type: ignore[no-untyped-def]
    raw = yaml.safe_load((SCENARIOS / "paper_montecarlo.yaml").read_text())
    raw["duration_s"] = duration_s
    raw["metrics"]["steady_from_s"] = duration_s / 2
    raw["metrics"]["t2_s"] = duration_s / 2
    return scenario_from_mapping(copy.deepcopy(raw))


def _attitudes(n: int, seed: int = 3) -> np.ndarray:
    """``n`` initial attitudes within 60 deg of the reference (the paper's campaign's range)."""
    rng = np.random.default_rng(seed)
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1)[:, None]
    angle = rng.uniform(0.05, np.radians(60.0), n)
    return np.column_stack((axis * np.sin(angle / 2)[:, None], np.cos(angle / 2)))


def _run(scenario, q, lanes: bool, omega=None, block_samples=None):  # type: ignore[no-untyped-def]
    inp = compiled_loop.prepare(scenario, on_infeasible="clamp", q_BN0=q, omega_BN_B0=omega, lanes=lanes)
    if block_samples is None:
        return compiled_loop.run_batch(inp, 1).record
    blocks = [[a.copy() for a in b.record] for b in compiled_loop.run_blocks(inp, 1, block_samples)]
    return [np.concatenate([b[i] for b in blocks], axis=1) if blocks[0][i].ndim >= 2 and name not in compiled_loop._PER_RUN else blocks[-1][i]
            for i, name in enumerate(compiled_loop.LoopRecord._fields)]


def test_the_lanes_cover_the_paper_campaign_and_say_why_not_the_others() -> None:
    paper = compiled_loop.prepare(load_scenario(SCENARIOS / "paper_montecarlo.yaml"), on_infeasible="clamp", lanes=True)
    assert lanes_refusal(paper) is None
    flight = compiled_loop.prepare(load_scenario(SCENARIOS / "paper_tracking_flight.yaml"), lanes=True)
    assert lanes_refusal(flight) is None  # the flight stack: sensors, the estimator, the wheels, the torque filter
    orbit = compiled_loop.prepare(load_scenario(SCENARIOS / "paper_tracking_orbit.yaml"), lanes=True)
    assert lanes_refusal(orbit) == "an orbit"
    faults = compiled_loop.prepare(load_scenario(SCENARIOS / "flight_tracker_outliers.yaml"), lanes=True)
    assert lanes_refusal(faults) == "faults"
    trappc = compiled_loop.prepare(load_scenario(SCENARIOS / "paper_comparison.yaml"), "trappc", lanes=True)
    assert lanes_refusal(trappc) == "the controller is not SAPPC"


def _flight_with_wheels(n_wheels: int, *, lanes: bool = True) -> compiled_loop.CompiledInputs:
    """The flight scenario over 0.2 s, two runs, with ``n_wheels`` wheels: the pyramid's four axes,
    then the body axes, then two diagonals (every wheel the scenario's HR16)."""
    raw = yaml.safe_load((SCENARIOS / "paper_tracking_flight.yaml").read_text())
    raw["duration_s"] = 0.2
    raw["metrics"].update(steady_from_s=0.1, t2_s=0.1, requirements={})
    axes = [list(a) for a in PRESETS["pyramid"]] + [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 1.0, 1.0], [1.0, -1.0, 0.0]]
    raw["actuator"]["wheels"]["spin_axes_B"] = axes[:n_wheels]
    return compiled_loop.prepare(scenario_from_mapping(raw), on_infeasible="clamp", q_BN0=_attitudes(2), lanes=lanes)


def test_the_lanes_refuse_more_wheels_than_their_rows_hold_and_the_loop_runs_them(monkeypatch: pytest.MonkeyPatch) -> None:
    """The lanes' wheel rows hold MAX_LANE_WHEELS (8) wheels (wheels.propagate_wheels_lanes):
    a batch of 9 is refused with the reason naming the count, 8 and the flight scenario's 4 are
    taken.  The refused batch, asked for lanes, runs in the per-run loop (the lanes' entry is
    never called) with all nine wheels: its record is the one of the same batch not asked for
    lanes, bit for bit."""
    assert MAX_LANE_WHEELS == 8
    flight = compiled_loop.prepare(load_scenario(SCENARIOS / "paper_tracking_flight.yaml"), lanes=True)
    assert flight.n_wheels == 4 and lanes_refusal(flight) is None
    eight, nine = _flight_with_wheels(8), _flight_with_wheels(9)
    assert eight.n_wheels == 8 and lanes_refusal(eight) is None
    assert nine.n_wheels == 9 and lanes_refusal(nine) == "more than 8 reaction wheels"
    assert compiled_loop.lanes_refusal(nine) == "more than 8 reaction wheels"  # (what the loop asks before it takes the lanes)
    monkeypatch.setattr(compiled_loop, "_loop_lanes", lambda *a, **k: pytest.fail("the lanes took a batch they refuse"))
    a, b = _records(_flight_with_wheels(9, lanes=False)), _records(nine)
    assert b["x_final"].shape == (2, 7 + 9) and np.all(b["x_final"][:, 7:] != 0.0)  # every wheel driven
    for name in compiled_loop.LoopRecord._fields:
        assert np.array_equal(a[name], b[name], equal_nan=True), name


def test_a_run_in_lanes_is_the_same_run_alone_bit_for_bit() -> None:
    """Parity (a): a lane's result does not depend on the other lanes of its group, so run K of a
    campaign, re-run alone (a group of one, ``sappc simulate --from-campaign``), is itself."""
    sc = _scenario()
    q = _attitudes(N_RUNS)
    together = _run(sc, q, lanes=True)
    for k in (0, LANES - 1, LANES, N_RUNS - 1):
        alone = _run(sc, q[k:k + 1], lanes=True)
        for name, a, b in zip(compiled_loop.LoopRecord._fields, together, alone):
            assert np.array_equal(a[k:k + 1], b, equal_nan=True), (k, name)


def test_the_lanes_equal_the_per_run_loop_within_libmvec_bound() -> None:
    """Parity with ``sappc simulate``'s loop: the same operations in the same order, except the
    libm calls of the loops LLVM vectorised, which are libmvec's (within 3 ulps of the scalar
    function's).  Bound on the state (unit quaternion and rates below 1 rad/s, ulp <= 2.2e-16):
    even if every sample added a 2-ulp difference and the closed loop contracted none of it, the
    difference after T samples stays below T * 2 * eps; with no variant declared, equality."""
    sc = _scenario()
    q = _attitudes(N_RUNS)
    per_run, lanes = _run(sc, q, lanes=False), _run(sc, q, lanes=True)
    fields = dict(zip(compiled_loop.LoopRecord._fields, zip(per_run, lanes)))
    for name in ("status", "rejected", "start", "d"):
        assert np.array_equal(*fields[name]), name
    assert np.all(fields["status"][1] == 0)  # every sample commanded: nothing handed back
    T = fields["x"][0].shape[1]
    bound = T * 2 * np.finfo(np.float64).eps
    dx = np.abs(fields["x"][0] - fields["x"][1]).max()
    assert dx <= bound, (dx, bound)
    if not libm.installed_variants():
        assert np.array_equal(*fields["x"]) and np.array_equal(*fields["out"], equal_nan=True)


def test_a_run_the_lanes_hand_back_is_the_per_run_loop_bit_for_bit() -> None:
    """A lane that meets what only the per-run loop answers (here: an implausible body rate, which
    the controller's check rejects at every sample, so the run never starts and the watchdog
    answers) is computed by the per-run loop; the other lanes of its group are unaffected."""
    sc = _scenario(2.0)
    q = _attitudes(N_RUNS)
    omega = np.zeros((N_RUNS, 3))
    omega[3] = (50.0, 0.0, 0.0)  # rad/s: above every plausible rate bound
    per_run, lanes = _run(sc, q, lanes=False, omega=omega), _run(sc, q, lanes=True, omega=omega)
    for name, a, b in zip(compiled_loop.LoopRecord._fields, per_run, lanes):
        assert np.array_equal(a[3], b[3], equal_nan=True), name
    assert np.all(lanes[compiled_loop.LoopRecord._fields.index("status")][3] != 0)
    assert lanes[compiled_loop.LoopRecord._fields.index("rejected")][3].sum() > 0
    others = [k for k in range(N_RUNS) if k != 3]
    alone = _run(sc, q[others], lanes=True, omega=omega[others])
    for name, a, b in zip(compiled_loop.LoopRecord._fields, lanes, alone):
        assert np.array_equal(a[others], b, equal_nan=True), name


@pytest.mark.parametrize("block_samples", [97, 250])
def test_the_lanes_in_blocks_are_the_lanes_in_one_block(block_samples: int) -> None:
    """The lanes carry each run's state from block to block in the per-run loop's LoopState: a
    campaign's blocks give the whole run's bits."""
    sc = _scenario()
    q = _attitudes(N_RUNS)
    whole = _run(sc, q, lanes=True)
    blocks = _run(sc, q, lanes=True, block_samples=block_samples)
    for name, a, b in zip(compiled_loop.LoopRecord._fields, whole, blocks):
        assert np.array_equal(a, b, equal_nan=True), name


#: The columns of a campaign's table from the runs' histories: each a max, a time mean or a
#: difference with the same rho of |q_ev| (Lipschitz constant 1 in the state), or a torque.
_QEV_COLUMNS = ("rpf_error_at_t2_per_axis", "steady_mean_abs_qev_per_axis", "steady_max_abs_qev")
#: Columns counted or timed from thresholds (exact while no sample lies within the bound of one).
_EXACT_COLUMNS = ("torque_sign_changes_per_s", "torque_reversals_per_s", "settling_time_s", "control_lost_at_s", "finite",
                  *(f"answers_{name}" for name in ANSWER_NAMES), "rpf_clamped", "rpf_flat")


def test_the_3000_run_table_in_lanes_is_the_per_run_table_within_the_bound(monkeypatch: pytest.MonkeyPatch) -> None:
    """Parity (c), docs/parity.md "Campaign runs in SIMD lanes": every metric of the paper's
    3000-run campaign table (``sappc montecarlo paper_montecarlo --runs 3000``, seed 0) in lanes
    against the same table from the per-run loop (``sappc simulate``'s).  Bounds, with no credit
    for the loop's contraction: the state T * 2 eps (above), which the |q_ev| metrics inherit
    (Lipschitz 1); the torque 3 libm terms per axis, each within 3 ulps of the largest torque
    (0.5 N m), in each of the T samples: 9 * 2^-53 * 0.5 N m * T."""
    from sappc.montecarlo import campaign

    raw = yaml.safe_load((SCENARIOS / "paper_montecarlo.yaml").read_text())
    runs = list(range(3000))
    in_lanes, _, _ = campaign.simulate_runs(raw, 0, runs, 0)
    real = campaign.run_scenario
    monkeypatch.setattr(campaign, "run_scenario", lambda *a, **k: real(*a, **{**k, "lanes": False}))
    per_run, _, _ = campaign.simulate_runs(raw, 0, runs, 0)
    T = round(raw["duration_s"] / raw["control_period_s"]) + 1
    eps = np.finfo(np.float64).eps
    for name in _QEV_COLUMNS:
        assert np.abs(in_lanes[name] - per_run[name]).max() <= T * 2 * eps, name
    assert np.abs(in_lanes["max_abs_torque_Nm"] - per_run["max_abs_torque_Nm"]).max() <= 9 * 2.0**-53 * 0.5 * T
    for name in _EXACT_COLUMNS:
        assert np.array_equal(in_lanes[name], per_run[name], equal_nan=True), name


def test_a_campaign_run_alone_is_its_row_when_each_run_has_its_own_disturbance() -> None:
    """The tuning scenario disperses the disturbance's scale and phase: a batch's disturbance
    differs by run, one run's is a table.  Both go in lanes (what the lanes cover depends on the
    scenario, not on the batch), so a run re-run alone is its row of the campaign, bit for bit."""
    from sappc.montecarlo.campaign import simulate_runs

    raw = yaml.safe_load((SCENARIOS / "paper_tracking_tune.yaml").read_text())
    raw["duration_s"] = 6.0
    raw["metrics"].update(steady_from_s=4.0, t2_s=5.0)
    together, _, _ = simulate_runs(raw, 0, [0, 1, 2], 0)
    for k in (0, 2):
        alone, _, _ = simulate_runs(raw, 0, [k], 0)
        for name in ("rpf_error_at_t2_per_axis", "steady_mean_abs_qev_per_axis", "steady_max_abs_qev", "max_abs_torque_Nm"):
            assert np.array_equal(np.asarray(together[name])[k], np.asarray(alone[name])[0]), (k, name)


def _watch_online_blocks(monkeypatch: pytest.MonkeyPatch, block_run_samples: int | None) -> list[list[int]]:
    """The runs of each block whose metrics the lanes handed to their record
    (``MetricsAccumulator.add_online_block``'s ``recorded``), block by block, as they come; with
    ``block_run_samples``, the blocks of the lanes that record only their answers that size too."""
    from sappc.evaluation.metrics import MetricsAccumulator

    if block_run_samples is not None:
        monkeypatch.setattr(compiled_loop, "BLOCK_RUN_SAMPLES", block_run_samples)
        monkeypatch.setattr(compiled_loop, "ONLINE_BLOCK_RUN_SAMPLES", block_run_samples)
    online_blocks: list[list[int]] = []
    real = MetricsAccumulator.add_online_block

    def spy(self, h, recorded, **kw):  # type: ignore[no-untyped-def]
        online_blocks.append(list(recorded))
        real(self, h, recorded, **kw)

    monkeypatch.setattr(MetricsAccumulator, "add_online_block", spy)
    return online_blocks


@pytest.mark.parametrize("block_run_samples", [None, N_RUNS * 97])
def test_the_lanes_online_metrics_are_their_records_metrics_bit_for_bit(monkeypatch: pytest.MonkeyPatch, block_run_samples: int | None) -> None:
    """A campaign's runs in lanes compute their metrics online, sample by sample, and record only
    their answers, and the trajectories' samples too where they are kept (sappc.offline.simulate.run_scenario);
    every sample's contribution is metric_sample_of's, which the record's metrics call too.  So
    every per-run metric state equals the one computed from the same lanes' record (run_blocks
    without an accumulator), bit for bit, and the trajectories are the record's: with a run the
    lanes hand back (its metrics taken from its record), in one block and over blocks that split
    the steady window."""
    from sappc.evaluation.metrics import MetricArrays
    from sappc.offline.simulate import run_scenario

    online_blocks = _watch_online_blocks(monkeypatch, block_run_samples)
    sc = _scenario()
    q = _attitudes(N_RUNS)
    omega = np.zeros((N_RUNS, 3))
    omega[3] = (50.0, 0.0, 0.0)  # rad/s: rejected at every sample, handed back
    kw = dict(on_infeasible="clamp", q_BN0=q, omega_BN_B0_rad_s=omega, lanes=True)
    online, run_online = run_scenario(sc, **kw)
    with_traj, run_with_traj = run_scenario(sc, **kw, trajectory=(N_RUNS, 3))
    blocks = len(online_blocks)
    assert blocks >= (2 if block_run_samples is None else 10) and all(r == [3] for r in online_blocks)
    real_blocks = compiled_loop.run_blocks
    monkeypatch.setattr(compiled_loop, "run_blocks", lambda inp, stride=1, block_samples=None, **_: real_blocks(inp, stride, block_samples))
    recorded, run_recorded = run_scenario(sc, **kw, trajectory=(N_RUNS, 3))
    assert len(online_blocks) == blocks  # the last went by its record
    assert online.samples == with_traj.samples == recorded.samples == round(sc.duration_s / sc.control_period_s) + 1
    for acc in (online, with_traj):
        for name in (*MetricArrays._fields, "origin_k", "k_t2_run"):
            a, b = getattr(acc, name), getattr(recorded, name)
            assert a.dtype == b.dtype and a.tobytes() == b.tobytes(), name
    for run in (run_online, run_with_traj):
        for name, counts in run.status.items():
            assert np.array_equal(counts, run_recorded.status[name]), name
        assert np.array_equal(run.x_final, run_recorded.x_final)
    assert run_with_traj.trajectory is not None and run_recorded.trajectory is not None
    for a, b in zip(run_with_traj.trajectory, run_recorded.trajectory):
        assert np.array_equal(a, b, equal_nan=True)


# ---- the flight stack in lanes: sensors, the estimator, the wheels, the torque filter ----------


def _flight_inputs(duration_s: float, *, estimator: bool = True, lanes: bool = True) -> compiled_loop.CompiledInputs:
    """The flight scenario (a star tracker, a gyro, the MEKF, four wheels, the torque filter) over
    ``duration_s``, :data:`N_RUNS` runs from dispersed attitudes; ``estimator`` false: the
    measurements feed the controller."""
    raw = yaml.safe_load((SCENARIOS / "paper_tracking_flight.yaml").read_text())
    raw["duration_s"] = duration_s
    raw["metrics"].update(steady_from_s=duration_s / 2, t2_s=duration_s / 2, requirements={})
    # an inertia with products (the scenario's J = 4 I makes the law's omega x J omega exactly zero,
    # whatever rate it is given: a test of which rate the law reads needs one that is not)
    raw["plant"]["inertia_kg_m2"] = [[4.0, 0.2, -0.1], [0.2, 5.0, 0.3], [-0.1, 0.3, 3.0]]
    if not estimator:
        del raw["estimator"]
    return compiled_loop.prepare(scenario_from_mapping(raw), on_infeasible="clamp", q_BN0=_attitudes(N_RUNS), lanes=lanes)


def _records(inp: compiled_loop.CompiledInputs) -> dict[str, np.ndarray]:
    return dict(zip(compiled_loop.LoopRecord._fields, compiled_loop.run_batch(inp, 1).record))


def _glitch(inp: compiled_loop.CompiledInputs, run: int, samples: slice, value: float) -> None:
    """The gyro's noise draws of ``run`` over ``samples`` set to ``value`` (NaN: the gyro sends no
    rate there, a measurement the filter does not take; huge: an implausible rate)."""
    inp.sensors.draws[run, samples, 3:6] = value


def test_the_flight_stack_in_lanes_is_the_per_run_loop_within_the_bound() -> None:
    """The lanes step the sensors, the filter, the wheels and the plant run by run with the per-run
    loop's pieces (sappc.offline.compiled_loop.measure_sample, estimate_sample, plant_step and the
    records'), the law in vector lanes with its torque filter: the same bits but the libm calls
    LLVM vectorised (libmvec's), so the true state within the bound above, T * 2 eps, and every
    answer, disturbance and start the same; with no variant declared, every field equal.  Runs 3
    and 9 lose their gyro for 3 and 40 samples (the estimate then has no measurement: the controller
    holds its last answer, then the watchdog answers zero), which the lanes answer as the loop does."""
    per_run, in_lanes = _flight_inputs(4.0, lanes=False), _flight_inputs(4.0)
    assert lanes_refusal(in_lanes) is None
    for inp in (per_run, in_lanes):
        _glitch(inp, 3, slice(150, 153), np.nan)
        _glitch(inp, 9, slice(200, 240), np.nan)
    a, b = _records(per_run), _records(in_lanes)
    for name in ("status", "rejected", "start", "d"):
        assert np.array_equal(a[name], b[name]), name
    answers = {name: int(np.count_nonzero(b["status"] == code)) for code, name in enumerate(ANSWER_NAMES)}
    assert answers["held"] > 0 and answers["watchdog_zero"] > 0 and answers["refused"] == 0, answers
    assert np.all(b["status"][[0, 1, 2, 4, 5, 6, 7, 8, 10]] == 0)  # the runs without a glitch: every sample commanded
    T = a["x"].shape[1]
    bound = T * 2 * np.finfo(np.float64).eps
    assert np.abs(a["x"] - b["x"]).max() <= bound
    assert np.abs(a["x_final"][:, :7] - b["x_final"][:, :7]).max() <= bound
    if not libm.installed_variants():
        for name in compiled_loop.LoopRecord._fields:
            assert np.array_equal(a[name], b[name], equal_nan=True), name


def test_a_flight_run_the_lanes_hand_back_starts_its_block_again_from_its_state() -> None:
    """Without the estimator the gyro's rate reaches the controller's input check: run 3's rate
    implausible at sample 120, a rejected input, which only the per-run loop answers.  The lanes
    step a flight run's own rows of the loop's state, so a run handed back starts its block again
    from the state kept before the block (sappc.offline.compiled_loop._loop_lanes).  In one block
    its record is the per-run loop's, bit for bit.  In blocks of 77 samples its first block goes
    in lanes and the next starts again from where that block ended: the answers and rejections
    the per-run loop's, the true state within the lanes' bound (without the state kept, that block
    would start 77 samples on).  The other runs are the lanes' in one block, and what they are
    without run 3's glitch."""
    runs = {}
    for lanes in (False, True):
        inp = _flight_inputs(2.0, estimator=False, lanes=lanes)
        _glitch(inp, 3, slice(120, 121), 1.0e6)
        runs[lanes] = _records(inp)
        if lanes:
            blocks = [[x.copy() for x in blk.record] for blk in compiled_loop.run_blocks(inp, 1, 77)]
            by_block = {name: (np.concatenate([blk[i] for blk in blocks], axis=1) if blocks[0][i].ndim >= 2 and name not in compiled_loop._PER_RUN
                               else blocks[-1][i]) for i, name in enumerate(compiled_loop.LoopRecord._fields)}
    a, b = runs[False], runs[True]
    assert a["rejected"][3].sum() > 0 and np.any(a["status"][3] != 0)
    others = [k for k in range(N_RUNS) if k != 3]
    for name in compiled_loop.LoopRecord._fields:
        assert np.array_equal(a[name][3], b[name][3], equal_nan=True), name
        assert np.array_equal(b[name][others], by_block[name][others], equal_nan=True), name
    for name in ("status", "rejected"):
        assert np.array_equal(a[name][3], by_block[name][3]), name
    assert np.abs(a["x"][3] - by_block["x"][3]).max() <= a["x"].shape[1] * 2 * np.finfo(np.float64).eps
    c = _records(_flight_inputs(2.0, estimator=False))  # (no glitch)
    for name in ("status", "d", "x", "out"):
        assert np.array_equal(b[name][others], c[name][others], equal_nan=True), name


class _Rows:
    """A stream of given rows in place of a generator's normals (``standard_normal(out=...)``)."""

    def __init__(self, rows: np.ndarray) -> None:
        self.rows, self.next = rows, 0

    def standard_normal(self, out: np.ndarray) -> None:
        out[...] = self.rows[self.next:self.next + out.shape[0]]
        self.next += out.shape[0]


#: The accumulator's arrays of the flight stack's metrics (besides the law's MetricArrays).
_FLIGHT_METRICS = ("wheel_speed_max", "wheel_torque_max", "wheel_energy", "est_att_max", "est_att_sq", "est_att_n", "est_bias_last", "est_nees_sum",
                   "est_nees_n", "est_status_counts", "est_mon_error", "est_mon_n", "est_withheld", "est_recoveries", "nees_sum_t", "nees_runs_t")


@pytest.mark.parametrize("block_run_samples", [None, N_RUNS * 97])
def test_the_flight_stacks_online_metrics_are_their_records_metrics_bit_for_bit(monkeypatch: pytest.MonkeyPatch, block_run_samples: int | None) -> None:
    """The lanes take the flight stack's metrics online too: the wheels' (wheel_metric_sample, the
    same bits as update_wheels) and the estimator's (estimate_metric_sample, the per-sample piece of
    the record's kernel; the NEES of each sample summed over the runs once the block is done), and
    record only the answers.  Every metric array equals the one from the same lanes' record, bit
    for bit, in one block and over blocks: with run 9's gyro silent for 40 samples (held and zero
    answers, no estimate) and run 3's gyro reading about 4 rad/s for 3 samples, which the filter
    takes and the controller's input check (its bound lowered to 1 rad/s) rejects, so that the
    lanes hand run 3 back and its metrics come from its record."""
    from sappc.evaluation.metrics import MetricArrays
    from sappc.offline.simulate import run_scenario

    online_blocks = _watch_online_blocks(monkeypatch, block_run_samples)
    raw = yaml.safe_load((SCENARIOS / "paper_tracking_flight.yaml").read_text())
    raw["duration_s"] = 6.0  # (the NEES is counted from 5 s)
    raw["metrics"].update(steady_from_s=3.0, t2_s=3.0, requirements={})
    raw["plant"]["inertia_kg_m2"] = [[4.0, 0.2, -0.1], [0.2, 5.0, 0.3], [-0.1, 0.3, 3.0]]
    raw["controller_node"] = {"max_body_rate_rad_s": 1.0}
    sc = scenario_from_mapping(raw)
    T = round(sc.duration_s / sc.control_period_s) + 1
    draws = np.array(np.broadcast_to(sc.sensors.draws(T), (N_RUNS,) + sc.sensors.draws(T).shape))
    draws[9, 400:440, 3:6] = np.nan
    draws[3, 120:123, 3] = 3.0e5  # x sigma_g = 1.45e-5 rad/s: 4.4 rad/s
    # each run's draws as a campaign's (compiled_loop.NoiseStreams: drawn block by block), from the table above
    streams = compiled_loop.NoiseStreams([lambda run=run: _Rows(draws[run]) for run in range(N_RUNS)], draws.shape[2])  # type: ignore[misc]
    sensors = (sc.sensors.params(sc.control_period_s), streams.runs, None)
    kw = dict(on_infeasible="clamp", q_BN0=_attitudes(N_RUNS), sensors=sensors, lanes=True)
    online, run_online = run_scenario(sc, **kw)
    blocks = len(online_blocks)
    assert blocks >= (1 if block_run_samples is None else 6) and [3] in online_blocks and all(r in ([], [3]) for r in online_blocks)
    real_blocks = compiled_loop.run_blocks
    monkeypatch.setattr(compiled_loop, "run_blocks", lambda inp, stride=1, block_samples=None, **_: real_blocks(inp, stride, block_samples))
    recorded, run_recorded = run_scenario(sc, **kw)
    assert len(online_blocks) == blocks  # the second run went by its record
    assert run_recorded.rejected["implausible"][3] > 0 and run_recorded.status["held"][9] > 0 and run_recorded.status["watchdog_zero"][9] > 0
    assert online.samples == recorded.samples == T
    assert recorded.est_nees_n is not None and recorded.est_nees_n.min() > 0 and recorded.wheel_energy is not None
    for name in (*MetricArrays._fields, *_FLIGHT_METRICS, "origin_k", "k_t2_run"):
        a, b = getattr(online, name), getattr(recorded, name)
        assert a.dtype == b.dtype and a.tobytes() == b.tobytes(), name
    for name, counts in run_online.status.items():
        assert np.array_equal(counts, run_recorded.status[name]), name
    assert np.array_equal(run_online.x_final, run_recorded.x_final)

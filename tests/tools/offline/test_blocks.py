"""The offline loop in blocks of samples (issue 47, docs/design/streaming.md): a run stepped block
after block (:func:`sappc.offline.compiled_loop.run_blocks`, its inputs made per block) is the run
in one call (:func:`~sappc.offline.compiled_loop.run_batch`), bit for bit, for every block size.

The equality is exact, not within a tolerance: the same compiled code does the same float64
operations in the same order on the same values; only where the loop's carried values live
(:class:`~sappc.offline.compiled_loop.LoopState`) and where its inputs are made changes.  A
value forgotten in the state, a reference integration restarted, a noise stream restarted or
misaligned changes the trajectory after the first block boundary, which these comparisons see.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from sappc.files import scenario_path
from sappc.montecarlo.draws import sensor_noise_draws, sensor_noise_streams
from sappc.offline import compiled_loop
from sappc.offline.compiled_loop import NoiseStreams, prepare, run_batch, run_blocks
from sappc.scenario import read_scenario_mapping, scenario_from_mapping
from spacecraft_sim.core.reference import sample_times

#: Block sizes [samples]: one sample (every boundary), a prime (boundaries at every phase of the
#: star tracker's and the magnetometer's strides), a power of two, and more than the run (one block).
BLOCKS = (1, 7, 4096, 10**9)
#: Per-run fields of the record: the run's so far, not per sample (the last block's are the run's).
PER_RUN = ("rejected", "x_final", "start")


def _with(name: str, duration_s: float, **changes: Any) -> Any:
    raw = read_scenario_mapping(scenario_path(name))
    raw.update(changes, duration_s=duration_s)
    (raw.get("metrics") or {}).pop("requirements", None)
    return scenario_from_mapping(raw)


def _blocked(inp: compiled_loop.CompiledInputs, block: int) -> dict[str, np.ndarray]:
    """The record of ``inp`` run in blocks of ``block`` samples, joined along the samples."""
    parts = [{f: np.array(getattr(run.record, f)) for f in run.record._fields} for run in run_blocks(inp, 1, block)]
    return {f: parts[-1][f] if f in PER_RUN else np.concatenate([p[f] for p in parts], axis=1) for f in parts[0]}


def _assert_same(whole: compiled_loop.CompiledRun, blocked: dict[str, np.ndarray], block: int) -> None:
    for f in whole.record._fields:
        a, b = getattr(whole.record, f), blocked[f]
        assert a.shape == b.shape and a.dtype == b.dtype, (f, block)
        assert np.array_equal(a.view(np.uint8), b.view(np.uint8)), (f, block)  # the bytes: NaN where NaN, -0.0 where -0.0


SCENARIOS = {
    # faults of every path (a delay, a freeze, dropouts, a stuck actuator, a noise fault) and a random disturbance
    "faults_random": lambda: _with("paper_fault", 3.0,
                                   disturbances=[{"kind": "paper_periodic", "omega_p_rad_s": 0.01},
                                                 {"kind": "random", "sigma_Nm": [1e-3, 1e-3, 1e-3], "hold_s": 0.03, "seed": 1}],
                                   faults=[{"kind": "sensor_noise", "start_s": 0.5, "end_s": 1.5, "attitude_std_rad": 1e-4,
                                            "rate_std_rad_s": 1e-5, "seed": 3},
                                           {"kind": "delay", "path": "sensor", "samples": 3, "start_s": 1.0, "end_s": 1.8},
                                           {"kind": "sensor_dropout", "start_s": 2.0, "end_s": 2.2},
                                           {"kind": "sensor_freeze", "start_s": 2.25, "end_s": 2.4},
                                           {"kind": "reference_dropout", "start_s": 2.45, "end_s": 2.5},
                                           {"kind": "actuator_stuck", "start_s": 2.6, "end_s": 2.7}]),
    # wheels, sensors, the estimator, a tracker outage, a delay and a dropout
    "flight_outage": lambda: _with("flight_tracker_outage", 4.0,
                                   sensors={**read_scenario_mapping(scenario_path("flight_tracker_outage"))["sensors"],
                                            "star_tracker": {**read_scenario_mapping(scenario_path("flight_tracker_outage"))["sensors"]["star_tracker"],
                                                             "outages_s": [[1.0, 2.5]]}},
                                   # a delay delivers tracker samples older than the last one delivered
                                   faults=[{"kind": "delay", "path": "sensor", "samples": 13, "start_s": 0.5, "end_s": 0.9},
                                           {"kind": "sensor_dropout", "start_s": 3.0, "end_s": 3.3}]),
    # the orbit: field, magnetometer, rods, gravity gradient, the predictive momentum law
    "orbit": lambda: _with("paper_tracking_orbit", 3.0),
}


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_a_run_in_blocks_is_the_run_in_one_call(name: str) -> None:
    scenario = SCENARIOS[name]()
    whole = run_batch(prepare(scenario), 1)
    blocked_inputs = prepare(scenario, whole=False)
    assert blocked_inputs.grid.t.size == 0  # nothing per sample held before the blocks
    for block in BLOCKS:
        _assert_same(whole, _blocked(blocked_inputs, block), block)
        _assert_same(whole, _blocked(prepare(scenario), block), block)  # slices of the whole run's inputs: the same


def test_a_campaign_sub_batch_in_blocks_is_the_sub_batch_in_one_call() -> None:
    """Dispersed starts, per-run noise streams (a campaign's), a sub-batch of runs 1..3 of 5."""
    scenario = _with("paper_tracking_flight", 3.0)
    rng = np.random.default_rng(3)
    q = rng.normal(size=(5, 4)) * 0.05 + np.asarray(scenario.q_BN0)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    params = scenario.sensors.params(scenario.control_period_s)
    T = sample_times(scenario.duration_s, scenario.control_period_s).size
    whole = run_batch(prepare(scenario, q_BN0=q, sensor_params=params).subset(1, 4, sensor_noise_draws(11, range(1, 4), T, 9)), 1)
    blocked = prepare(scenario, q_BN0=q, sensor_params=params, whole=False).subset(1, 4, sensor_noise_streams(11, range(1, 4), 9))
    for block in (7, 4096):
        _assert_same(whole, _blocked(blocked, block), block)


def test_an_orbit_sub_batch_in_blocks_is_the_sub_batch_in_one_call() -> None:
    """Each run's magnetometer stream keyed as a campaign keys it, runs 1..3 of 5 (their streams
    sliced from the batch's), blocks that start between the magnetometer's updates."""
    scenario = _with("paper_tracking_orbit", 2.0)
    q = np.tile(np.asarray(scenario.q_BN0), (5, 1))
    keys = [(k, 42) for k in range(5)]
    whole = run_batch(prepare(scenario, q_BN0=q, run_keys=keys).subset(1, 4), 1)
    blocked = prepare(scenario, q_BN0=q, run_keys=keys, whole=False).subset(1, 4)
    assert whole.record.env.shape[2] > 0 and scenario.environment.magnetometer is not None
    for block in (1, 7, 33):
        _assert_same(whole, _blocked(blocked, block), block)


@pytest.mark.parametrize("sizes", [(1, 7, 256, 300, 436), (256, 256, 488), (1000,)])
def test_noise_streams_in_blocks_are_the_whole_draws(sizes: tuple[int, ...]) -> None:
    """A Generator's standard normals drawn in blocks are the rows of one draw (what makes the
    sensors' draws per block the run's), for a campaign's streams and a scenario's shared one."""
    rows = sum(sizes)
    streams = sensor_noise_streams(5, [0, 4, 9], 9).open()
    got = np.concatenate([streams.take(s) for s in sizes], axis=1)
    assert np.array_equal(got, sensor_noise_draws(5, [0, 4, 9], rows, 9))
    shared = NoiseStreams([lambda: np.random.default_rng(7)], 9).open()
    assert np.array_equal(np.concatenate([shared.take(s) for s in sizes], axis=1)[0], np.random.default_rng(7).standard_normal((rows, 9)))


def test_a_block_must_start_at_a_recorded_sample() -> None:
    inp = prepare(_with("paper_tracking", 0.1))
    block = next(iter(inp.blocks(3, 1)))
    rec = compiled_loop._record(inp, 2, 1, 3)
    with pytest.raises(ValueError, match="multiple of the stride"):
        compiled_loop._loop(False, 2, compiled_loop.dataclasses.replace(block, k_lo=3), rec, compiled_loop._state(inp, 1))


@pytest.mark.parametrize("name", ["faults_random", "flight_outage", "orbit"])
def test_simulate_in_blocks_gives_the_metrics_of_the_whole_record(name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """``simulate(history="none")`` and ``"envelope"`` (``sappc simulate`` without and with
    ``--out``) step the run in blocks (of 7 samples here) and give every metric, the per-orbit table
    and the controller's summary of ``history="full"`` (the whole record), the same bits; the
    envelope of a run this short is its whole history."""
    from sappc.offline.simulate import simulate

    scenario = SCENARIOS[name]()
    full = simulate(scenario, history="full")
    monkeypatch.setattr(compiled_loop, "BLOCK_RUN_SAMPLES", 7)
    for kind in ("none", "envelope"):
        got = simulate(scenario, history=kind)
        for key in full.metrics.keys() - {"wall_time_s"}:
            assert repr(got.metrics[key]) == repr(full.metrics[key]), (kind, key)
        assert got.per_orbit == full.per_orbit and got.controller_summary == full.controller_summary, kind
    assert got.history is not None and full.history is not None
    assert np.array_equal(got.history.q_BR, full.history.q_BR) and np.array_equal(got.history.t, full.history.t)


def _traced_peak_of_first_blocks(duration_s: float) -> tuple[int, int]:
    """(the traced peak [bytes], the samples) of preparing the orbit scenario for ``duration_s``, its
    metrics' accumulator and its first two blocks through the metrics (``tracemalloc``: numpy's
    arrays included)."""
    import tracemalloc

    from sappc.offline.simulate import metrics_accumulator

    scenario = _with("paper_tracking_orbit", duration_s)
    tracemalloc.start()
    try:
        inp = prepare(scenario, whole=False)
        acc = metrics_accumulator(scenario, inp.n_samples, scenario.control_period_s, 1)
        for _, run in zip(range(2), run_blocks(inp, 1)):
            acc.add_history(run.history())
        return tracemalloc.get_traced_memory()[1], inp.n_samples
    finally:
        tracemalloc.stop()


def test_a_weeks_run_holds_nothing_of_its_length() -> None:
    """A week of the orbit scenario (60,480,001 samples) allocates, to start, what a day does
    (8,640,001) but for the one array that grows: the campaign's per-sample NEES, at most 2**22
    entries of 16 bytes (64 MiB; a day keeps 2,880,001: the week's adds 18 MiB).  The bound is one
    byte for each of the week's 51.8 million more samples (52 MB): any array over the run's
    samples, even the sample times alone (8 bytes a sample), breaks it."""
    day, day_samples = _traced_peak_of_first_blocks(86400.0)
    week, week_samples = _traced_peak_of_first_blocks(604800.0)
    assert week_samples == 60_480_001 and day_samples == 8_640_001
    assert week - day < 1.0 * (week_samples - day_samples), f"{(week - day) / 2**20:.0f} MiB more for a week"


def test_a_campaigns_sub_batches_share_the_blocks_made_once(monkeypatch: pytest.MonkeyPatch) -> None:
    """The grid, the reference and the disturbance of each block are the same for every
    sub-batch of a campaign (functions of the sample only): the inputs' SampleMaker makes each
    block once and hands the next sub-batch the same arrays, with the reference's carry where the
    block leaves it; the values are those made afresh.  Beyond MADE_BLOCKS_MAX_BYTES nothing more
    is kept (a long run's blocks, a disturbance drawn per run)."""
    sc = _with("paper_montecarlo", 2.0)
    q = np.broadcast_to(sc.q_BN0, (3, 4)).copy()
    inp = prepare(sc, on_infeasible="clamp", q_BN0=q, whole=False)
    first = [(b.grid, b.disturbance) for b in inp.subset(0, 1).blocks(64, 1)]
    again = [(b.grid, b.disturbance) for b in inp.subset(1, 3).blocks(64, 1)]
    assert len(first) == len(again) == 4  # 201 samples in blocks of 64
    for (g1, d1), (g2, d2) in zip(first, again):
        assert g1 is g2 and d1.table is d2.table
    monkeypatch.setattr(compiled_loop, "MADE_BLOCKS_MAX_BYTES", 0)
    fresh = prepare(sc, on_infeasible="clamp", q_BN0=q, whole=False)
    made = [(b.grid, b.disturbance) for b in fresh.blocks(64, 1)]
    assert fresh.maker is not None and not fresh.maker.made
    for (g1, d1), (g2, d2) in zip(first, made):
        assert g1 is not g2
        for a, b in zip((*g1, d1.table, d1.windows), (*g2, d2.table, d2.windows)):
            assert np.array_equal(a, b), "a block kept differs from the block made afresh"


def test_the_work_done_before_forking_campaign_workers_keeps_them_forked() -> None:
    """``sappc montecarlo`` loads numba's CPU target and the start's kernels once, before forking
    its workers (compiled_loop.load_before_fork), so that they share them.  It must not start
    numba's thread pool (loading a parallel kernel does): the workers would then come from a fork
    server, with nothing loaded.  In a fresh interpreter: after the load, numba's array functions
    (the target's first use) are loaded and the campaign still forks."""
    import subprocess
    import sys

    code = ("import sys\n"
            "from sappc.files import scenario_path\n"
            "from sappc.scenario import load_scenario\n"
            "from sappc.offline import compiled_loop\n"
            "from sappc.montecarlo.campaign import _start_method\n"
            "assert 'numba.np.arraymath' not in sys.modules\n"
            "compiled_loop.load_before_fork(load_scenario(scenario_path('paper_montecarlo')))\n"
            "print('numba.np.arraymath' in sys.modules, _start_method())\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["True", "fork"]

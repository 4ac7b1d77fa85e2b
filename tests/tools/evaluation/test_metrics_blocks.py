"""A long record fed to the metrics a block at a time (issue 47): the same bits as the whole record.

:meth:`MetricsAccumulator.add_history` takes every metric block by block, as views of the record
(``block_samples``) or as separate calls, each with its block's own times (a run longer than memory,
on a :class:`SampleGrid`); every metric, the per-orbit table (its orbits cut by the blocks) and the
campaign's per-sample NEES must then be the bits of one pass over the whole record, for any block
size, and the per-orbit table the bits of its definitions over each whole orbit as the record-wide
pass computed them.  On a grid the accumulator's memory does not grow with the run's samples.  The
offline path (:func:`sappc.offline.simulate.run_scenario`) is checked the same way on the flight
scenario (wheels, sensors, the MEKF) and on an orbit with rods: its report is the same bits whatever
:data:`~sappc.offline.simulate.METRICS_BLOCK` is."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from conftest import cut_short, random_unit_quaternions
from sappc.evaluation import metrics as metrics_module
from sappc.evaluation.estimation import EstimateHistory
from sappc.evaluation.history import History
from sappc.evaluation.metrics import MetricsAccumulator, SampleGrid

#: Samples and runs of the synthetic record (two orbits and a half of a 2 s period at 100 Hz).
T, N = 501, 3
ORBIT_PERIOD_S = 2.0
#: Its sample period [s].
DT_S = 0.01
#: The block sizes a run is cut into: a sample at a time, a size prime to the orbits' (cutting
#: inside them at every phase), the driver's order of size, and the whole run (one block).
BLOCKS = (1, 7, 4096, None)


def _record(samples: int = T) -> tuple[History, Any]:
    """A record of ``samples`` with every part the metrics read (errors, torques, bands, wheels, the
    estimator's record with its monitor, the rods' dipoles), random but with a run that goes
    non-finite and samples without an estimate, and its orbit bins."""
    from sappc.scenario import OrbitBins

    T = samples
    rng = np.random.default_rng(47)
    t = np.arange(T) * DT_S
    q_BN = random_unit_quaternions(rng, T * N).reshape(T, N, 4)
    q_ev = 0.01 * np.exp(-t)[:, None, None] * rng.standard_normal((T, N, 3))
    q_BR = np.concatenate((q_ev, np.sqrt(1.0 - np.sum(q_ev**2, axis=2, keepdims=True))), axis=2)
    band = 0.004 + 0.01 * np.exp(-t)[:, None, None] * np.ones((T, N, 3))
    torque = 0.05 * rng.standard_normal((T, N, 3))
    torque[np.abs(torque) < 0.02] = 0.0
    h = History(t=t, q_BN=q_BN, omega_BN_B=1e-3 * rng.standard_normal((T, N, 3)), q_BR=q_BR, torque_B=torque,
                torque_cmd_B=torque.copy(), saturated=rng.random((T, N, 3)) < 0.1, disturbance_B=np.zeros((T, N, 3)),
                rho=0.01 * rng.standard_normal((T, N, 3)), band_lower=-band, band_upper=band, eps=np.zeros((T, N, 3)),
                z=np.zeros((T, N, 3)), V=np.zeros((T, N, 3)))
    h.omega_BN_B[T - 30, 2, 0] = np.nan  # run 2 fails 30 samples before the end
    W, M = 4, 3
    G = rng.normal(size=(3, W))
    h.wheel_speed_rad_s = 50.0 * rng.standard_normal((T, N, W))
    h.wheel_torque_Nm = 0.1 * rng.standard_normal((T, N, W))
    h.orbit = np.concatenate((np.zeros((T, N, 9)), rng.uniform(-40.0, 40.0, (T, N, M))), axis=2)
    q_est = q_BN + 1e-6 * rng.standard_normal((T, N, 4))
    q_est /= np.linalg.norm(q_est, axis=-1, keepdims=True)
    A = rng.standard_normal((T, N, 6, 6))
    P = 1e-12 * (A @ np.swapaxes(A, -1, -2) + np.eye(6))
    b = 1e-6 * rng.standard_normal((T, N, 3))
    level = rng.integers(0, 3, (T, N)).astype(np.float64)
    q_est[:40, 1] = np.nan  # run 1 has no estimate at first
    level[:40, 1] = np.nan
    h.estimate = EstimateHistory(q_BN=q_est, omega_BN_B=np.zeros((T, N, 3)), gyro_bias=b, covariance=P, nis=rng.random((T, N)),
                                 status=rng.integers(0, 4, (T, N)).astype(np.int8), gyro_bias_true=b + 1e-7 * rng.standard_normal((T, N, 3)),
                                 monitor_level=level, monitor_nis_sum=np.zeros((T, N)), usable=(rng.random((T, N)) < 0.9).astype(np.float64),
                                 recoveries=np.cumsum(rng.random((T, N)) < 0.01, axis=0).astype(np.float64))
    return h, OrbitBins(ORBIT_PERIOD_S, np.array([0.1, 0.2, 0.3, 0.4]), G, np.array([10.0, 20.0, 40.0]))


def _accumulator(t: np.ndarray | SampleGrid, bins: Any, *, t2_s: float = 1.0) -> MetricsAccumulator:
    return MetricsAccumulator(t, N, steady_from_s=0.5, settle_threshold=1e-3, t2_s=t2_s, fault_windows=[(2.0, 2.5)],
                              orbit_bins=bins)


def _fed_in_calls(acc: MetricsAccumulator, h: History, block: int | None) -> MetricsAccumulator:
    """``h`` fed to ``acc`` as separate histories of ``block`` samples each (``None``: one), each with
    its block's own times, as a run longer than memory is."""
    step = h.t.size if block is None else block
    for lo in range(0, h.t.size, step):
        acc.add_history(h.samples(lo, lo + step))
    return acc


def _orbit_tables_as_the_whole_record(h: History, bins: Any, steady_from_s: float) -> list[list[dict[str, Any]]]:
    """Each run's per-orbit table as the record-wide pass computed it, each orbit's samples at once
    (the expressions of ``_update_orbits`` before the pass went online): the steady ``|q_ev|``'s
    maximum and ``0 + sum(axis=0)`` over the orbit's (S, N, 3), the wheels' ``|h_B|`` and speeds,
    the rods' ``np.nansum(|m| / m_max, axis=(0, 2))`` over the orbit's (S, N, M)."""
    def value(x: Any) -> float | None:
        return float(x) if np.isfinite(x) else None

    orbit = (h.t // bins.period_s).astype(np.int64)
    m = bins.rod_max_dipole_Am2.size
    tables: list[list[dict[str, Any]]] = [[] for _ in range(h.q_BR.shape[1])]
    for j in np.unique(orbit):
        lo, hi = np.flatnonzero(orbit == j)[[0, -1]] + (0, 1)
        steady = h.t[lo:hi] >= steady_from_s
        q = np.abs(h.q_BR[lo:hi, ..., :3])[steady]
        q_max, q_sum = np.max(q, axis=(0, 2)) if steady.any() else None, 0.0 + q.sum(axis=0)
        w = h.wheel_speed_rad_s[lo:hi]
        hB = np.linalg.norm((w * bins.wheel_spin_inertia_kg_m2) @ np.asarray(bins.wheel_axes_B).T, axis=2)
        duty = np.nansum(np.abs(h.orbit[lo:hi, :, 9:9 + m]) / bins.rod_max_dipole_Am2, axis=(0, 2))
        for n, table in enumerate(tables):
            table.append({"orbit": int(j), "from_s": float(j * bins.period_s),
                          "steady_max_abs_qev": value(q_max[n]) if q_max is not None else None,
                          "steady_mean_abs_qev": value((q_sum[n] / int(steady.sum())).max()) if steady.any() else None,
                          "max_wheel_momentum_B_Nms": value(hB.max(axis=0)[n]), "end_wheel_momentum_B_Nms": value(hB[-1, n]),
                          "max_abs_wheel_speed_rad_s": value(np.abs(w).max(axis=(0, 2))[n]),
                          "rods_mean_dipole_fraction": value(duty[n] / ((hi - lo) * m))})
    return tables


def _everything(acc: MetricsAccumulator) -> dict[str, Any]:
    """What the commands read: every run's metrics and per-orbit table, the campaign's arrays and
    its per-sample NEES."""
    mean, runs = acc.mean_nees_over_runs()
    return {"runs": [acc.run_metrics(n) for n in range(N)], "orbits": [acc.orbit_metrics(n) for n in range(N)],
            "criteria": {k: v.tobytes() for k, v in acc.criteria_arrays().items()}, "nees": (mean.tobytes(), runs.tobytes())}


@pytest.mark.parametrize("block", [1, 7, 128, T - 1, T, 10 * T])
def test_a_record_fed_in_blocks_gives_the_bits_of_the_whole_record(block: int) -> None:
    h, bins = _record()
    whole = _accumulator(h.t, bins)
    whole.add_history(h)
    blocks = _accumulator(h.t, bins)
    blocks.add_history(h, block_samples=block)
    got, want = _everything(blocks), _everything(whole)
    assert got == want
    assert want["runs"][2]["finite"] is False and want["runs"][0]["mean_nees"] is not None and len(want["orbits"][0]) == 3


def test_a_block_is_a_view_of_the_record() -> None:
    h, _ = _record()
    b = h.samples(100, 164)
    assert b.t.size == 64 and b.estimate is not None and h.estimate is not None
    for part, whole in ((b.q_BR, h.q_BR), (b.estimate.covariance, h.estimate.covariance), (b.orbit, h.orbit), (b.wheel_speed_rad_s, h.wheel_speed_rad_s)):
        assert part is not None and whole is not None
        assert np.shares_memory(part, whole) and np.array_equal(part, whole[100:164])
    assert b.samples(0, 0).t.size == 0


def test_a_second_history_continues_the_samples_seen() -> None:
    """Two halves of a record fed one after the other: the per-sample metrics (settling, the sample
    nearest t2, the loss of control, the constraint's last exit) count from the first sample of
    the run, as when fed whole (the per-orbit sums, split inside an orbit, add in another order)."""
    h, _ = _record()
    whole = _accumulator(h.t, None)
    whole.add_history(h)
    halves = _accumulator(h.t, None)
    halves.add_history(h.samples(0, 250), block_samples=64)
    halves.add_history(h.samples(250, T), block_samples=64)
    assert [halves.run_metrics(n) for n in range(N)] == [whole.run_metrics(n) for n in range(N)]


@pytest.mark.parametrize("name, duration_s", [("paper_tracking_flight", None), ("paper_tracking_orbit", 120.0)])
def test_the_offline_report_is_the_same_bits_for_any_metrics_block(name: str, duration_s: float | None,
                                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    """``sappc simulate``'s metrics, per-orbit table and controller summary with the record fed in
    blocks of 1000 samples and whole: the same bits (the estimator's, the wheels' and the orbit's
    metrics included)."""
    from sappc.files import scenario_path
    from sappc.offline import simulate as sim
    from sappc.scenario import read_scenario_mapping, scenario_from_mapping

    raw = read_scenario_mapping(scenario_path(name))
    if duration_s is not None:
        raw["duration_s"] = duration_s
    scenario = scenario_from_mapping(raw)
    reports = []
    for block in (1 << 62, 1000):
        monkeypatch.setattr(sim, "METRICS_BLOCK", block)
        r = sim.simulate(scenario)
        r.metrics.pop("wall_time_s")
        reports.append((r.metrics, r.per_orbit, r.controller_summary))
    assert reports[0] == reports[1]
    assert reports[0][0]["finite"] and ("mean_nees" in reports[0][0]) and (duration_s is None or len(reports[0][1]) == 1)


def _with_gaps(h: History) -> History:
    """``h`` with non-finite samples inside orbits (an error of run 1 in orbit 1's steady samples, a
    wheel speed of run 0 in orbit 2, a dipole of run 2 in orbit 0): a NaN wins an orbit's maximum
    and its mean whichever block it falls in, and is left out of the rods' duty."""
    assert h.wheel_speed_rad_s is not None and h.orbit is not None
    h.q_BR[260, 1, 0] = np.nan
    h.wheel_speed_rad_s[430, 0, 2] = np.nan
    h.orbit[50, 2, 10] = np.nan
    return h


@pytest.mark.parametrize("gaps", [False, True], ids=["finite", "gaps"])
@pytest.mark.parametrize("block", BLOCKS, ids=lambda b: "whole" if b is None else f"B{b}")
def test_the_per_orbit_table_fed_in_blocks_cut_inside_orbits_is_the_whole_records(block: int | None, gaps: bool) -> None:
    """The record fed as separate histories of ``block`` samples (each with its own times) into an
    accumulator on the grid: every run's per-orbit table is the bits of each orbit's definitions over
    the whole orbit, and every metric the bits of the whole record fed at once on its times."""
    h, bins = _record()
    if gaps:
        h = _with_gaps(h)
    whole = _accumulator(h.t, bins)
    whole.add_history(h)
    fed = _fed_in_calls(_accumulator(SampleGrid(T, DT_S), bins), h, block)
    assert repr(_everything(fed)) == repr(_everything(whole))  # repr: float's shortest round trip, a NaN equal to a NaN
    tables = _orbit_tables_as_the_whole_record(h, bins, 0.5)
    assert [fed.orbit_metrics(n) for n in range(N)] == tables
    assert len(tables[0]) == 3 and all(e["rods_mean_dipole_fraction"] is not None for e in tables[2])
    if gaps:
        assert tables[1][1]["steady_max_abs_qev"] is None and tables[0][2]["max_abs_wheel_speed_rad_s"] is None


@pytest.fixture(scope="module")
def orbit_run() -> tuple[History, Any, dict[str, Any]]:
    """``paper_tracking_orbit`` cut to 60 s (wheels, the MEKF, the magnetometer, the rods commanded
    by the management node), its record, its orbit bins with a 13.7 s period (four orbits and a
    part, two of them cut by 4096-sample blocks) and its metric settings."""
    import dataclasses

    from sappc.files import scenario_path
    from sappc.offline.simulate import run_scenario
    from sappc.scenario import read_scenario_mapping, scenario_from_mapping

    scenario = scenario_from_mapping(cut_short(read_scenario_mapping(scenario_path("paper_tracking_orbit")), 60.0))
    _, run = run_scenario(scenario, keep_history=True)
    assert run.history is not None and scenario.orbit_bins() is not None
    ms = scenario.metrics
    settings = {"steady_from_s": ms.steady_from_s, "settle_threshold": ms.settle_threshold, "t2_s": ms.t2_s,
                "fault_windows": scenario.event_windows()}
    return run.history, dataclasses.replace(scenario.orbit_bins(), period_s=13.7), settings


@pytest.mark.parametrize("block", BLOCKS, ids=lambda b: "whole" if b is None else f"B{b}")
def test_an_orbit_run_fed_in_blocks_is_the_whole_records(block: int | None,
                                                          orbit_run: tuple[History, Any, dict[str, Any]]) -> None:
    """A closed-loop run in orbit with rods, fed in blocks on its grid: its metrics, NEES and per-orbit
    table (orbits cut inside by the blocks) are the bits of the whole record on its times, and the
    table the bits of each orbit's definitions as the record-wide pass computed them."""
    h, bins, settings = orbit_run
    whole = MetricsAccumulator(h.t, 1, orbit_bins=bins, **settings)
    whole.add_history(h)
    fed = _fed_in_calls(MetricsAccumulator(SampleGrid.of_run(60.0, float(h.t[1])), 1, orbit_bins=bins, **settings), h, block)
    got, want = (fed.run_metrics(0), fed.orbit_metrics(0), fed.mean_nees_over_runs()[0].tobytes()), \
        (whole.run_metrics(0), whole.orbit_metrics(0), whole.mean_nees_over_runs()[0].tobytes())
    assert got == want
    assert want[1] == _orbit_tables_as_the_whole_record(h, bins, settings["steady_from_s"])[0]
    assert len(want[1]) == 5 and all(e["rods_mean_dipole_fraction"] for e in want[1]) and want[0]["mean_nees"] is not None


def test_the_grid_gives_the_bits_of_its_times() -> None:
    """An accumulator on a :class:`SampleGrid` and one on the same times as an array: the same bits
    for every metric (the sample nearest ``t2``: on a sample, halfway between two, before the first,
    past the last by less and by more than half a step, not finite); the grid of a run is
    :func:`~spacecraft_sim.core.reference.sample_times`' to the bit."""
    from spacecraft_sim.core.reference import sample_times

    h, bins = _record()
    for t2_s in (1.0, 1.005, 0.0, -0.3, 4.999, (T - 1) * DT_S + 0.004, (T - 1) * DT_S + 0.006, 100.0, np.nan, np.inf):
        on_times, on_grid = _accumulator(h.t, bins, t2_s=t2_s), _accumulator(SampleGrid(T, DT_S), bins, t2_s=t2_s)
        assert on_grid.k_t2 == on_times.k_t2, t2_s
        on_times.add_history(h, block_samples=64)
        on_grid.add_history(h, block_samples=64)
        assert _everything(on_grid) == _everything(on_times), t2_s
    assert _accumulator(h.t, bins, t2_s=1.005).k_t2 == 100  # a tie: the first of the two, as argmin
    for n in (0, 1, 2):
        t = np.arange(n) * DT_S
        a, b = _accumulator(t, None, t2_s=0.0), _accumulator(SampleGrid(n, DT_S), None, t2_s=0.0)
        assert (a.k_t2, a.dt, a.n_grid) == (b.k_t2, b.dt, b.n_grid)
    for duration_s, dt_s in ((60.0, 0.01), (21600.0, 0.01), (75.0, 0.01), (1.0, 0.05), (7 * 86400.0, 0.1), (0.004, 0.01)):
        grid = SampleGrid.of_run(duration_s, dt_s)
        assert np.array_equal(grid.times_s(np.arange(grid.n_samples)), sample_times(duration_s, dt_s))
        assert grid.times_s(grid.n_samples - 1) == sample_times(duration_s, dt_s)[-1]


def _array_bytes(value: Any) -> int:
    """The bytes of the arrays ``value`` holds (an array, a list or tuple of them, a dataclass)."""
    import dataclasses

    if isinstance(value, np.ndarray):
        return value.nbytes
    if isinstance(value, (list, tuple)):
        return sum(_array_bytes(v) for v in value)
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return sum(_array_bytes(getattr(value, f.name)) for f in dataclasses.fields(value))
    return 0


def test_the_accumulators_memory_does_not_grow_with_the_run(monkeypatch: pytest.MonkeyPatch) -> None:
    """On a grid, fed 512 samples at a time, an accumulator of a run of 2000 samples and one of 20000
    (every part: wheels, the estimator, an orbit of 100 samples with rods) hold the same bytes of
    arrays, but for the per-orbit table, a row per orbit; with the per-sample NEES kept at 1000
    samples at most (:data:`~sappc.evaluation.metrics.NEES_EXACT_MAX_SAMPLES` lowered), every 2nd
    and every 20th sample."""
    monkeypatch.setattr(metrics_module, "NEES_EXACT_MAX_SAMPLES", 1000)
    sizes = {}
    for samples in (2000, 20000):
        h, bins = _record(samples)
        bins = type(bins)(1.0, bins.wheel_spin_inertia_kg_m2, bins.wheel_axes_B, bins.rod_max_dipole_Am2)
        acc = _fed_in_calls(_accumulator(SampleGrid(samples, DT_S), bins), h, 512)
        orbits = {k: _array_bytes(v) for k, v in vars(acc).items() if k.startswith("orb_")}
        rest = {k: _array_bytes(v) for k, v in vars(acc).items() if not k.startswith("orb_")}
        n_orbits = samples // 100
        # per run and orbit: 8 float64 (the maxima, the end, the 3 sums, the duty) and the steady
        # samples' count (each run's window is its own: issue 49's modes); per orbit the samples' count
        assert sum(orbits.values()) == n_orbits * (N * 8 * 8 + N * 8 + 8)
        assert acc.nees_sum_t is not None and acc.nees_sum_t.size == 1000 and acc.nees_stride == samples // 1000
        assert acc.t is None and acc.hold_s is None and len(acc.orbit_metrics(0)) == n_orbits
        sizes[samples] = rest
    assert sizes[2000] == sizes[20000]
    assert sum(sizes[20000].values()) < 64 * 1024  # the rods' buffer (an orbit), the NEES (1000 samples), per-run state


@pytest.mark.parametrize("block", [1, 7, None], ids=lambda b: "whole" if b is None else f"B{b}")
def test_a_long_runs_nees_is_kept_at_every_strideth_sample(block: int | None, monkeypatch: pytest.MonkeyPatch) -> None:
    """Past :data:`~sappc.evaluation.metrics.NEES_EXACT_MAX_SAMPLES` (lowered to 100 here: 1001
    samples keep every 11th), the campaign's per-sample NEES is the bits of the full one at the
    samples kept, whatever the blocks; its times are theirs, and the campaign's consistency test
    (:func:`sappc.montecarlo.results.nees_consistency`) takes those samples."""
    import types

    from sappc.montecarlo.results import nees_consistency

    samples, stride = 1001, 11  # 10 s: the NEES counts from 5 s
    h, bins = _record(samples)
    full = _accumulator(h.t, bins)
    full.add_history(h)
    monkeypatch.setattr(metrics_module, "NEES_EXACT_MAX_SAMPLES", 100)
    kept = _fed_in_calls(_accumulator(SampleGrid(samples, DT_S), bins), h, block)
    assert kept.nees_stride == stride
    (mean, runs), (full_mean, full_runs) = kept.mean_nees_over_runs(), full.mean_nees_over_runs()
    assert mean.tobytes() == full_mean[::stride].tobytes() and runs.tobytes() == full_runs[::stride].tobytes()
    assert kept.nees_times_s().tobytes() == h.t[::stride].tobytes() and runs.max() == N
    assert repr([kept.run_metrics(n) for n in range(N)]) == repr([full.run_metrics(n) for n in range(N)])
    scenario = types.SimpleNamespace(duration_s=(samples - 1) * DT_S, control_period_s=DT_S)
    table = {"tsum_nees": kept.nees_sum_t, "tsum_nees_runs": kept.nees_runs_t}
    test = nees_consistency(table, scenario)  # type: ignore[arg-type]
    assert test["t_s"].tobytes() == h.t[::stride].tobytes() and test["mean"].tobytes() == mean.tobytes() and test["runs"] == N


def test_accumulators_joined_inside_an_orbit_keep_each_parts_rods_duty() -> None:
    """One-run accumulators fed half the record (cut inside orbit 1), joined, then fed the rest: each
    run's per-orbit table is that of its run's accumulator fed whole (the rods' open orbit stays
    summed per part), but for the wheels' momentum, a matrix product whose last bits depend on the
    batch's runs (three there, one alone), as they did before the pass went online."""
    h, bins = _record()
    settings: dict[str, Any] = {"steady_from_s": 0.5, "settle_threshold": 1e-3, "t2_s": 1.0, "fault_windows": [],
                                "orbit_bins": bins}
    alone, parts = [], []
    for n in range(N):
        one = History(**{f: h.t if f == "t" else None if getattr(h, f) is None or f == "estimate" else getattr(h, f)[:, n:n + 1]
                         for f in History.__dataclass_fields__})
        acc = MetricsAccumulator(h.t, 1, **settings)
        acc.add_history(one)
        alone.append(acc.orbit_metrics(0))
        part = MetricsAccumulator(SampleGrid(T, DT_S), 1, **settings)
        part.add_history(one.samples(0, 250))
        parts.append(part)
    joined = MetricsAccumulator.concatenate(parts)
    rest = h.samples(250, T)
    rest.estimate = None
    joined.add_history(rest, block_samples=7)
    momentum = ("max_wheel_momentum_B_Nms", "end_wheel_momentum_B_Nms")
    def split(table: list[dict[str, Any]]) -> tuple[list[dict[str, Any]], np.ndarray]:
        others = [{k: v for k, v in e.items() if k not in momentum} for e in table]
        return others, np.array([[e[k] for k in momentum] for e in table])

    for n in range(N):
        (got, got_momentum), (want, want_momentum) = split(joined.orbit_metrics(n)), split(alone[n])
        assert got == want and got_momentum == pytest.approx(want_momentum, rel=1e-15)

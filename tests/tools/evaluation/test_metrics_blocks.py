"""A long record fed to the metrics a block at a time (issue 47): the same bits as the whole record.

:meth:`MetricsAccumulator.add_history` with ``block_samples`` takes the per-sample metrics (the
compiled pass, the wheels', the estimator's) block by block as views of the record, and each orbit's
samples at once; every metric, the per-orbit table and the campaign's per-sample NEES must then be
the bits of one pass over the whole record, for any block size.  The offline path
(:func:`sappc.offline.simulate.run_scenario`) is checked the same way on the flight scenario (wheels,
sensors, the MEKF) and on an orbit with rods: its report is the same bits whatever
:data:`~sappc.offline.simulate.METRICS_BLOCK` is."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from conftest import random_unit_quaternions
from sappc.evaluation.estimation import EstimateHistory
from sappc.evaluation.history import History
from sappc.evaluation.metrics import MetricsAccumulator

#: Samples and runs of the synthetic record (two orbits and a half of a 2 s period at 100 Hz).
T, N = 501, 3
ORBIT_PERIOD_S = 2.0


def _record() -> tuple[History, Any]:
    """A record with every part the metrics read (errors, torques, bands, wheels, the estimator's
    record with its monitor, the rods' dipoles), random but with a run that goes non-finite and
    samples without an estimate, and its orbit bins."""
    from sappc.scenario import OrbitBins

    rng = np.random.default_rng(47)
    t = np.arange(T) * 0.01
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


def _accumulator(t: np.ndarray, bins: Any) -> MetricsAccumulator:
    return MetricsAccumulator(t, N, steady_from_s=0.5, settle_threshold=1e-3, t2_s=1.0, fault_windows=[(2.0, 2.5)], orbit_bins=bins)


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

"""Disturbance models: the paper's formula, fault windows on a sampling grid, seeded randomness, blocks."""

from __future__ import annotations

import numpy as np
import pytest

from sappc.offline.closed_loop import step_times
from spacecraft_sim.core.disturbance import ConstantTorque, DisturbanceSum, PaperPeriodic, PulseTorque, RandomTorque, StepTorque
from gnc_common.validation import ConfigError


def test_paper_periodic_matches_the_printed_formula() -> None:
    w = 0.01
    for t in (0.0, 17.3, 123.0):
        expected = 1e-3 * np.array([
            4 * np.sin(3 * w * t) + 3 * np.cos(10 * w * t) - 20,
            -1.5 * np.sin(2 * w * t) + 3 * np.cos(5 * w * t) + 20,
            3 * np.sin(10 * w * t) - 8 * np.cos(4 * w * t) + 20,
        ])
        np.testing.assert_allclose(PaperPeriodic().torque_B(np.array([t]), 1)[0, 0], expected, rtol=1e-15, atol=1e-18)


def test_paper_periodic_per_run_scale_and_phase() -> None:
    d = PaperPeriodic(scale=(1.0, 2.0), phase_rad=(0.0, 0.3)).torque_B(np.array([5.0]), 2)
    np.testing.assert_allclose(d[0, 1], 2.0 * PaperPeriodic().torque_B(np.array([5.0 + 0.3 / 0.01]), 1)[0, 0], rtol=1e-13)


def test_sudden_fault_covers_exactly_fifty_samples_at_100_hz() -> None:
    t = step_times(80.0, 0.01)
    d = PulseTorque(start_s=50.0, duration_s=0.5, torque_Nm=(1.0, 1.0, 1.0)).torque_B(t, 1)[:, 0]
    on = np.flatnonzero(d[:, 0] > 0)
    assert on.size == 50 and t[on[0]] == pytest.approx(50.0) and t[on[-1]] == pytest.approx(50.49)
    np.testing.assert_array_equal(d[on], np.ones((50, 3)))


def test_step_and_constant() -> None:
    t = np.array([0.0, 0.99, 1.0, 2.0])
    np.testing.assert_array_equal(StepTorque(1.0, (0.1, 0.0, 0.0)).torque_B(t, 3)[:, 0, 0], [0.0, 0.0, 0.1, 0.1])
    assert ConstantTorque((1.0, 2.0, 3.0)).torque_B(t, 5).shape == (4, 1, 3)


def test_random_torque_is_a_pure_function_of_seed_and_window() -> None:
    m = RandomTorque(sigma_Nm=(0.01, 0.02, 0.03), hold_s=0.1, seed=7)
    t = np.arange(0.0, 2.0, 0.01)
    whole = m.torque_B(t, 2)
    pieces = np.concatenate([m.torque_B(t[i : i + 37], 2) for i in range(0, t.size, 37)])
    np.testing.assert_array_equal(whole, pieces)  # any block split gives the same sequence
    np.testing.assert_array_equal(whole[:10], np.repeat(whole[:1], 10, axis=0))  # held over 0.1 s
    assert not np.array_equal(whole[:, 0], whole[:, 1])  # independent streams per run
    alone = RandomTorque(sigma_Nm=(0.01, 0.02, 0.03), hold_s=0.1, seed=8).torque_B(t, 1)
    np.testing.assert_array_equal(alone[:, 0], whole[:, 1])  # run k of a batch = seed + k alone
    sample = RandomTorque(sigma_Nm=(1.0, 1.0, 1.0), hold_s=1.0, seed=1).torque_B(np.arange(20000.0), 1)[:, 0]
    assert abs(sample.mean()) < 0.03 and abs(sample.std() - 1.0) < 0.02  # 4 sigma for n = 60000


def test_sum_and_events() -> None:
    s = DisturbanceSum((PaperPeriodic(), PulseTorque(50.0, 0.5, (1.0, 1.0, 1.0)), StepTorque(70.0, (0.0, 0.1, 0.0))))
    assert s.events() == [(50.0, 50.5), (70.0, float("inf"))]
    d = s.torque_B(np.array([50.0]), 4)
    np.testing.assert_allclose(d[0, 0], PaperPeriodic().torque_B(np.array([50.0]), 1)[0, 0] + 1.0)


@pytest.mark.parametrize(
    "build, fragment",
    [
        (lambda: PulseTorque(50.0, 0.0, (1, 1, 1)), "duration_s"),
        (lambda: PulseTorque(50.0, 0.5, (1, 1)), "torque_Nm must have trailing shape"),
        (lambda: RandomTorque((0.1, -0.1, 0.1), 0.1), "sigma_Nm must be >= 0"),
        (lambda: RandomTorque((0.1, 0.1, 0.1), 0.1, seed=-1), "seed"),
        (lambda: PaperPeriodic(omega_p_rad_s=float("nan")), "omega_p_rad_s"),
    ],
)
def test_bad_models_are_rejected_by_name(build, fragment) -> None:
    with pytest.raises((ConfigError, ValueError), match=fragment):
        build()

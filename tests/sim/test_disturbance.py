"""Disturbance models (the compiled kernels behind ``torque_B``): the paper's formula, fault windows
on a sampling grid, seeded randomness, blocks, every kind against the numpy oracle
(``tests/sim/oracle.py``)."""

from __future__ import annotations

import numpy as np
import pytest

from sim import oracle
from spacecraft_sim.core.disturbance import (
    ConstantTorque,
    DisturbanceSum,
    PaperPeriodic,
    PulseTorque,
    RandomTorque,
    StepTorque,
    disturbances_from_list,
    encode_disturbance,
    random_draws,
)
from spacecraft_sim.core.reference import sample_times
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
    t = sample_times(80.0, 0.01)
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


def test_every_kind_and_the_sum_equal_the_numpy_oracle() -> None:
    entries = [
        {"kind": "paper_periodic", "omega_p_rad_s": 0.01, "scale": [0.9, 1.1, 1.0], "phase_rad": [0.0, 1.3, -0.4]},
        {"kind": "constant", "torque_Nm": [1e-3, -2e-3, 3e-3]},
        {"kind": "step", "start_s": 0.5, "torque_Nm": [0.1, 0.2, -0.3]},
        {"kind": "pulse", "start_s": 1.0, "duration_s": 0.5, "torque_Nm": [1.0, 1.0, 1.0]},
        {"kind": "random", "sigma_Nm": [1e-3, 2e-3, 3e-3], "hold_s": 0.03, "seed": 11},
        {"kind": "random", "sigma_Nm": [4e-3, 0.0, 1e-3], "hold_s": 0.01, "seeds": [5, 9, 2]},
    ]
    t = sample_times(3.0, 0.01)
    model = disturbances_from_list(entries)
    expected = [
        oracle.paper_periodic(t, 0.01, np.array([0.9, 1.1, 1.0]), np.array([0.0, 1.3, -0.4])),
        oracle.window(t, 0.0, np.inf, (1e-3, -2e-3, 3e-3)),
        oracle.window(t, 0.5, np.inf, (0.1, 0.2, -0.3)),
        oracle.window(t, 1.0, 1.5, (1.0, 1.0, 1.0)),
        oracle.random_torque(t, (1e-3, 2e-3, 3e-3), 0.03, [11, 12, 13]),
        oracle.random_torque(t, (4e-3, 0.0, 1e-3), 0.01, [5, 9, 2]),
    ]
    for m, ref in zip(model.models, expected):
        d = m.torque_B(t, 3)
        assert d.shape == (t.size, ref.shape[1], 3), type(m).__name__
        if isinstance(m, PaperPeriodic):  # sin, cos: libm against numpy's, a few ulps of 0.02 N m
            np.testing.assert_allclose(d, ref, rtol=0.0, atol=2e-17)
        else:  # no arithmetic but a product: bit for bit (windows switch on the same samples)
            np.testing.assert_array_equal(d, ref)
    total = model.torque_B(t, 3)
    np.testing.assert_allclose(total, sum(expected[1:], expected[0]), rtol=0.0, atol=1e-16)
    # a block of samples and the samples one by one (the injector node's calls) agree bit for bit
    np.testing.assert_array_equal(np.concatenate([model.torque_B(t[k : k + 1], 3) for k in range(0, t.size, 7)]), total[::7])


def test_shared_models_give_one_column_and_per_run_models_n() -> None:
    t = np.array([0.0, 1.0])
    assert DisturbanceSum((PaperPeriodic(), StepTorque(0.5, (0.1, 0.0, 0.0)))).torque_B(t, 4).shape == (2, 1, 3)
    assert DisturbanceSum((PaperPeriodic(), RandomTorque((0.1, 0.1, 0.1), 1.0))).torque_B(t, 4).shape == (2, 4, 3)
    assert DisturbanceSum().torque_B(t, 2).shape == (2, 1, 3)
    m = RandomTorque((0.1, 0.1, 0.1), 1.0, seed=3)
    np.testing.assert_array_equal(m.torque_B(t, 1)[:, 0], m.torque_B(t, 3)[:, 0])  # encodings per batch size, cached
    with pytest.raises(ConfigError, match="seeds lists 2 runs, the batch has 3"):
        RandomTorque((0.1, 0.1, 0.1), 1.0, seeds=(1, 2)).torque_B(t, 3)


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


def test_random_draws_default_to_one_run_of_the_models_seed() -> None:
    """The compiled random disturbance's draw tables (``random_draws``): one run by default,
    run n drawing with ``seed + n``, one draw per hold window of the grid."""
    from spacecraft_sim.core import kernels as PK

    model = DisturbanceSum((RandomTorque((1e-3, 2e-3, 3e-3), 0.5, seed=4),))
    t = np.arange(5) * 0.25  # windows 0, 0, 1, 1, 2
    draws, win = random_draws(model, t)
    assert draws.shape == (1, 1, 3, 3) and win.tolist() == [[0, 0, 1, 1, 2]]
    np.testing.assert_array_equal(draws[0, 0, 2], np.random.default_rng([4, 2]).standard_normal(3))
    kinds, dparams, dscale, dphase = encode_disturbance(model)  # its encoding: one run by default too
    assert kinds.tolist() == [PK.D_RANDOM] and dscale.shape == dphase.shape == (1, 1) and dparams[0, :3].tolist() == [1e-3, 2e-3, 3e-3]
    two, _ = random_draws(model, t, 2)
    np.testing.assert_array_equal(two[0, 0], draws[0, 0])
    np.testing.assert_array_equal(two[0, 1, 1], np.random.default_rng([5, 1]).standard_normal(3))


def test_models_add_per_axis_in_list_order_and_a_step_allows_the_grid_rounding() -> None:
    """The sum adds each model's own components (a constant before the paper model keeps its
    per-axis values); a step is on from ``start_s`` less the 1e-9 s allowed for ``k * dt``
    rounding: on at a sample 1e-9 s before its start, off 2e-9 s before."""
    t = np.array([0.0, 7.0, 250.0])
    const = ConstantTorque((1e-3, -2e-3, 3e-3))
    total = DisturbanceSum((const, PaperPeriodic())).torque_B(t, 1)
    np.testing.assert_array_equal(total, const.torque_B(t, 1) + PaperPeriodic().torque_B(t, 1))
    start = 0.3 + 1e-9  # (0.3 + 1e-9) - 1e-9 == 0.3 exactly in float64
    assert start - 1e-9 == 0.3
    on = StepTorque(start, (1.0, 2.0, 3.0)).torque_B(np.array([0.3, 0.3 - 1e-9]), 1)
    assert on[:, 0].tolist() == [[1.0, 2.0, 3.0], [0.0, 0.0, 0.0]]
    # a pulse: on during [start_s, start_s + duration_s), both ends less the same 1e-9 s
    assert start + 0.25 - 1e-9 == 0.55
    pulse = PulseTorque(start, 0.25, (1.0, 2.0, 3.0)).torque_B(np.array([0.3 - 1e-9, 0.3, 0.55 - 1e-9, 0.55]), 1)
    assert pulse[:, 0, 0].tolist() == [0.0, 1.0, 1.0, 0.0]

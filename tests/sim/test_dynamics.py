"""Rigid-body plant (the compiled kernels behind :class:`RigidBody`): conservation laws, integrator
order, closed forms, the numpy oracle (``tests/sim/oracle.py``), batch equivalence, shapes, input checks."""

from __future__ import annotations

import numpy as np
import pytest

from conftest import random_unit_quaternions
from gnc_common.attitude import quat_to_dcm_BN
from sim import oracle
from spacecraft_sim.core.dynamics import RigidBody, initial_state, kinetic_energy_J
from gnc_common.validation import ConfigError, InputError

# A general (non-diagonal) SPD inertia: principal moments 3, 5, 7 kg m^2 in a rotated frame (a rigid
# body: I1 + I2 >= I3, gnc_common.validation.check_spd_inertia).
_R = np.linalg.qr(np.array([[1.0, 2.0, 0.5], [0.3, -1.0, 2.0], [2.0, 0.1, 1.0]]))[0]
J_GENERAL = _R @ np.diag([3.0, 5.0, 7.0]) @ _R.T


def _momentum_N(J: np.ndarray, x: np.ndarray) -> np.ndarray:
    C_BN = quat_to_dcm_BN(x[:, :4])
    return np.einsum("nji,nj->ni", C_BN, x[:, 4:] @ J.T)  # H_N = C_BN^T J omega


def _torque_free(J: np.ndarray, dt: float, T: float) -> tuple[np.ndarray, np.ndarray]:
    body = RigidBody(J)
    x0 = initial_state([0.2, -0.1, 0.4, 0.88], [0.4, -0.7, 0.3])
    x0[:, :4] /= np.linalg.norm(x0[:, :4])
    x = x0.copy()
    zero = np.zeros((1, 3))
    for _ in range(int(round(T / dt))):
        x = body.rk4_step(x, zero, dt)
    return x0, x


def test_torque_free_motion_conserves_momentum_and_energy_to_fourth_order() -> None:
    # Tumbling at ~0.8 rad/s for 30 s about a non-principal axis.
    errs = {}
    for dt in (0.04, 0.02):
        x0, x = _torque_free(J_GENERAL, dt, 30.0)
        dH = np.linalg.norm(_momentum_N(J_GENERAL, x) - _momentum_N(J_GENERAL, x0))
        dE = abs(kinetic_energy_J(J_GENERAL, x[:, 4:]) - kinetic_energy_J(J_GENERAL, x0[:, 4:]))[0]
        errs[dt] = (dH, dE)
    # RK4's global error is O(dt^4): halving dt divides the momentum drift by 2^4 = 16
    # (measured 15.9 with the compiled kernel; accepted 2^3.6 .. 2^4.3).  The energy drift falls at
    # least as fast (measured 29: RK4 is superconvergent in energy here), so only a lower bound is
    # asserted.
    # Step sizes are large enough that round-off (1e-13 over the run) does not blur the ratios.
    ratio_H = errs[0.04][0] / errs[0.02][0]
    ratio_E = errs[0.04][1] / errs[0.02][1]
    assert 2**3.6 < ratio_H < 2**4.3, errs
    assert ratio_E > 2**3.6, errs
    assert errs[0.02][0] < 2e-8 and errs[0.02][1] < 1e-10, errs


def test_spin_about_principal_axis_is_steady_and_matches_closed_form() -> None:
    body = RigidBody(np.diag([3.0, 5.0, 7.0]))
    w = 0.5
    x = initial_state([0.0, 0.0, 0.0, 1.0], [0.0, 0.0, w])
    for _ in range(1000):
        x = body.rk4_step(x, np.zeros((1, 3)), 0.01)
    t = 10.0
    np.testing.assert_allclose(x[0, 4:], [0.0, 0.0, w], atol=1e-15)
    np.testing.assert_allclose(x[0, :4], [0.0, 0.0, np.sin(w * t / 2), np.cos(w * t / 2)], atol=1e-12)


def test_constant_torque_about_principal_axis_spins_up_linearly() -> None:
    body = RigidBody(np.diag([4.0, 4.0, 4.0]))
    x = initial_state([0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 0.0])
    torque = np.array([[0.5, 0.0, 0.0]])
    x = body.propagate(x, torque, 2.0, substeps=200)
    alpha = 0.5 / 4.0
    np.testing.assert_allclose(x[0, 4:], [alpha * 2.0, 0.0, 0.0], atol=1e-14)
    angle = 0.5 * alpha * 2.0**2  # theta = alpha t^2 / 2 (quadratic: RK4 is exact)
    np.testing.assert_allclose(x[0, :4], [np.sin(angle / 2), 0.0, 0.0, np.cos(angle / 2)], atol=1e-12)


def test_batch_equals_single_runs(rng) -> None:
    body = RigidBody(J_GENERAL)
    q = random_unit_quaternions(rng, 5)
    x = initial_state(q, rng.standard_normal((5, 3)))
    u = rng.standard_normal((5, 3))
    batch = body.propagate(x, u, 0.1, substeps=3)
    for k in range(5):
        single = body.propagate(x[k : k + 1], u[k : k + 1], 0.1, substeps=3)
        np.testing.assert_array_equal(single[0], batch[k])


def test_per_run_inertia_batch_matches_shared_inertia(rng) -> None:
    x = initial_state(random_unit_quaternions(rng, 4), rng.standard_normal((4, 3)))
    u = rng.standard_normal((4, 3))
    shared = RigidBody(J_GENERAL).propagate(x, u, 0.05)
    per_run = RigidBody(np.broadcast_to(J_GENERAL, (4, 3, 3))).propagate(x, u, 0.05)
    np.testing.assert_allclose(per_run, shared, atol=1e-15)


@pytest.mark.parametrize("per_run", [False, True])
def test_compiled_plant_equals_the_numpy_oracle(rng, per_run: bool) -> None:
    n = 16
    J = J_GENERAL
    if per_run:  # dispersed inertias, one per run
        S = np.sqrt(1.0 + rng.uniform(-0.2, 0.2, (n, 3)))
        J = S[:, :, None] * J_GENERAL[None] * S[:, None, :]
    body = RigidBody(J)
    x = initial_state(random_unit_quaternions(rng, n), 0.5 * rng.standard_normal((n, 3)))
    u = 0.3 * rng.standard_normal((n, 3))
    np.testing.assert_allclose(body.derivative(x, u), oracle.derivative(x, u, J), rtol=0.0, atol=2e-15)
    np.testing.assert_allclose(body.propagate(x, u, 0.1, substeps=3), oracle.propagate(x, u, J, 0.1, 3), rtol=0.0, atol=2e-15)
    y, y_oracle = x, x
    for _ in range(200):  # 20 s: the two stay together over a run, not only on one step
        y, y_oracle = body.propagate(y, u, 0.1), oracle.propagate(y_oracle, u, J, 0.1, 1)
    np.testing.assert_allclose(y, y_oracle, rtol=0.0, atol=1e-12)


def test_one_run_shapes_layout_and_sharing(rng) -> None:
    body = RigidBody(J_GENERAL)
    x = initial_state(random_unit_quaternions(rng, 3), rng.standard_normal((3, 3)))  # Fortran order
    u = rng.standard_normal((3, 3))
    x_before = x.copy()
    batch = body.propagate(x, u, 0.05, 2)
    np.testing.assert_array_equal(x, x_before)  # a new array; the input is not changed
    assert batch.shape == (3, 7) and batch.flags.f_contiguous  # a Fortran batch stays Fortran
    one = body.propagate(np.ascontiguousarray(x[1]), u[1], 0.05, 2)
    assert one.shape == (7,)
    np.testing.assert_array_equal(one, batch[1])  # one run (7,) = its row of the batch, bit for bit
    shared = body.propagate(x[:1], u, 0.05, 2)  # one state, three torques
    for k in range(3):
        np.testing.assert_array_equal(shared[k], body.propagate(x[0], u[k], 0.05, 2))
    with pytest.raises(InputError, match="batch sizes"):
        body.propagate(x, u[:2], 0.05)
    with pytest.raises(InputError, match="expected states"):
        body.propagate(x[:, :6], u, 0.05)
    with pytest.raises(InputError, match="batch sizes"):
        RigidBody(np.broadcast_to(J_GENERAL, (2, 3, 3))).propagate(x, u, 0.05)


@pytest.mark.parametrize(
    "J, fragment",
    [
        (np.diag([1.0, -1.0, 1.0]), "positive definite"),
        (np.array([[1.0, 0.5, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]), "symmetric"),
        (np.diag([1.0, np.nan, 1.0]), "non-finite"),
        (np.eye(2), "3x3"),
    ],
)
def test_bad_inertia_is_rejected_with_its_value(J, fragment) -> None:
    with pytest.raises(ConfigError, match=fragment):
        RigidBody(J)


@pytest.mark.parametrize("dt", [0.0, -0.01, np.nan, np.inf])
def test_bad_step_is_rejected(dt) -> None:
    body = RigidBody(np.eye(3))
    with pytest.raises(InputError, match="dt"):
        body.propagate(initial_state([0, 0, 0, 1.0], [0, 0, 0]), np.zeros((1, 3)), dt)


@pytest.mark.parametrize("substeps", [0, -1, 1.5])
def test_bad_substeps_are_rejected(substeps) -> None:
    with pytest.raises(InputError, match="substeps"):
        RigidBody(np.eye(3)).propagate(initial_state([0, 0, 0, 1.0], [0, 0, 0]), np.zeros((1, 3)), 0.01, substeps)


def test_derivative_shares_a_batch_of_one_as_propagate_does(rng) -> None:  # type: ignore[no-untyped-def]
    """``derivative`` of N runs with one torque, one state or one inertia shared by them (a batch
    of one is shared, as in ``propagate``) equals each run's derivative alone, bit for bit."""
    x = initial_state(random_unit_quaternions(rng, 3), rng.standard_normal((3, 3)))
    u = rng.standard_normal((3, 3))
    Js = np.stack([J_GENERAL, np.diag([2.0, 3.0, 4.0]), np.diag([4.0, 4.0, 5.0])])
    body, per_run = RigidBody(J_GENERAL), RigidBody(Js)
    alone = [body.derivative(np.ascontiguousarray(x[k]), u[k]) for k in range(3)]
    np.testing.assert_array_equal(body.derivative(x, u[:1]), [body.derivative(np.ascontiguousarray(x[k]), u[0]) for k in range(3)])
    np.testing.assert_array_equal(body.derivative(x[:1], u), [body.derivative(np.ascontiguousarray(x[0]), u[k]) for k in range(3)])
    np.testing.assert_array_equal(body.derivative(x, u), alone)
    np.testing.assert_array_equal(per_run.derivative(x, u), [RigidBody(Js[k]).derivative(np.ascontiguousarray(x[k]), u[k]) for k in range(3)])
    np.testing.assert_array_equal(body.derivative(x[:2], u[:2]), alone[:2])  # two runs, two torques
    np.testing.assert_array_equal(RigidBody(Js[:2]).derivative(x[:2], u[:2]),  # two runs, two inertias
                                  [RigidBody(Js[k]).derivative(np.ascontiguousarray(x[k]), u[k]) for k in range(2)])
    shared_torque = body.propagate(x, u[:1], 0.05, 2)  # propagate too: one torque for three states
    for k in range(3):
        np.testing.assert_array_equal(shared_torque[k], body.propagate(np.ascontiguousarray(x[k]), u[0], 0.05, 2))
    two = body.propagate(x[:2], u[:2], 0.05, 2)  # two runs, two torques
    two_J = RigidBody(Js[:2]).propagate(x[:2], u[:2], 0.05, 2)  # two runs, two inertias
    for k in range(2):
        np.testing.assert_array_equal(two[k], body.propagate(np.ascontiguousarray(x[k]), u[k], 0.05, 2))
        np.testing.assert_array_equal(two_J[k], RigidBody(Js[k]).propagate(np.ascontiguousarray(x[k]), u[k], 0.05, 2))


def test_propagate_into_is_propagate_bit_for_bit(rng) -> None:  # type: ignore[no-untyped-def]
    """``propagate_into`` (the plant node's step into its own buffers) gives ``propagate``'s state,
    bit for bit, step after step, for one run and for a batch; ``x`` is left as it was."""
    body = RigidBody(J_GENERAL)
    for n in (1, 4):
        x = np.ascontiguousarray(initial_state(random_unit_quaternions(rng, n), 0.1 * rng.standard_normal((n, 3))))
        expected, buf = x.copy(), np.empty_like(x)
        for _ in range(50):
            u = rng.standard_normal((n, 3))
            before = x.copy()
            expected = body.propagate(expected, u, 0.01, 2)
            body.propagate_into(x, u, 0.01, 2, buf)
            np.testing.assert_array_equal(x, before)
            x, buf = buf, x
            np.testing.assert_array_equal(x, expected)

"""Reaction wheels (spacecraft_sim.core.wheels): the compiled dynamics against an independent
oracle in another formulation (wheel speeds instead of momenta, integrated by scipy to 1e-12),
total angular momentum conserved without external torque whatever the motors and friction do,
the torque path (minimum-norm allocation, motor limit, speed limit), presets and validation."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from gnc_common.attitude import quat_to_dcm_BN
from gnc_common.validation import ConfigError
from spacecraft_sim.core.wheels import PRESETS, PYRAMID_CANT_DEG, ReactionWheels, allocation_matrix, angular_momentum_B, propagate_wheels
from spacecraft_sim.core.wheels import wheel_speeds, wheel_torques

J = np.array([[4.0, 0.1, -0.05], [0.1, 3.5, 0.02], [-0.05, 0.02, 4.5]])
WHEELS = ReactionWheels(spin_axes_B="pyramid", spin_inertia_kg_m2=[0.02, 0.025, 0.02, 0.03], max_torque_Nm=0.2, max_speed_rad_s=600.0,
                        coulomb_friction_Nm=[1e-3, 2e-3, 1e-3, 1.5e-3], viscous_friction_Nm_s=2e-5, initial_speed_rad_s=[50.0, -30.0, 0.05, 10.0])


def _x0(wheels: ReactionWheels = WHEELS) -> np.ndarray:
    q = np.array([0.1, -0.2, 0.3, 0.9])
    w = np.array([0.02, -0.01, 0.015])
    return np.concatenate((q / np.linalg.norm(q), w, wheels.initial_momentum(w)))


def _oracle_rhs(t: float, y: np.ndarray, u: np.ndarray, L: np.ndarray, wheels: ReactionWheels) -> np.ndarray:
    """The same physics written in wheel speeds: y = (q, omega, Omega)."""
    q, w, Om = y[:4], y[4:7], y[7:]
    G, Js = wheels.G, wheels.per_wheel("spin_inertia_kg_m2")
    c, b, wc = wheels.per_wheel("coulomb_friction_Nm"), wheels.per_wheel("viscous_friction_Nm_s"), wheels.coulomb_speed_rad_s
    f = c * np.clip(Om / wc, -1.0, 1.0) + b * Om
    H = J @ w + G @ (Js * (G.T @ w + Om))
    wdot = np.linalg.solve(J, L - G @ (u - f) - np.cross(w, H))
    Omdot = (u - f) / Js - G.T @ wdot
    qv, qs = q[:3], q[3]
    qdot = 0.5 * np.concatenate((qs * w + np.cross(qv, w), [-qv @ w]))
    return np.concatenate((qdot, wdot, Omdot))


SMOOTH = ReactionWheels(spin_axes_B="pyramid", spin_inertia_kg_m2=[0.02, 0.025, 0.02, 0.03], max_torque_Nm=0.2, max_speed_rad_s=600.0,
                        viscous_friction_Nm_s=2e-5, initial_speed_rad_s=[0.5, -0.3, 0.05, 0.1])  # no Coulomb kink; speeds cross zero
FAST = ReactionWheels(spin_axes_B="pyramid", spin_inertia_kg_m2=[0.02, 0.025, 0.02, 0.03], max_torque_Nm=0.2, max_speed_rad_s=600.0,
                      coulomb_friction_Nm=[1e-3, 2e-3, 1e-3, 1.5e-3], viscous_friction_Nm_s=2e-5,
                      initial_speed_rad_s=[300.0, -250.0, 200.0, -300.0])  # Coulomb, never near zero speed


@pytest.mark.parametrize(("wheels", "torque_Nm", "substeps"), [(SMOOTH, 0.05, 10), (FAST, 0.002, 40)],
                         ids=["torques-crossing-zero-speed", "coulomb-at-speed"])
def test_the_dynamics_match_an_independent_oracle_in_wheel_speeds(wheels: ReactionWheels, torque_Nm: float, substeps: int) -> None:
    """60 s of 0.1 s periods, each with its own held motor and external torques (RK4) against
    DOP853 at rtol 1e-12 on the speed formulation: body state within 1e-11, wheel speeds within
    1e-11 relative.  RK4's global error goes as (lambda h)^4; wheels at 300 rad/s make the body's
    gyroscopic rate lambda ~ |G h| / J ~ 1.5 rad/s, so they get h = 2.5 ms (measured 1e-10 at
    h = 10 ms; the slow wheels 3.4e-13 at 10 ms).  The right-hand side must be smooth for that:
    where a wheel's speed crosses the Coulomb friction's kink (+-coulomb_speed_rad_s) a fixed-step
    RK4 loses its order (measured 2.6e-7 on the body state over the same 60 s), so Coulomb
    friction is checked on wheels that stay at speed."""
    rng = np.random.default_rng(4)
    x = _x0(wheels)
    y = np.concatenate((x[:7], wheel_speeds(wheels, x)))
    J_inv = np.linalg.inv(J)
    prm, G = wheels.params(), np.ascontiguousarray(wheels.G)
    crossings = 0  # wheel speeds changing sign from one period to the next
    for _ in range(600):
        u = rng.uniform(-torque_Nm, torque_Nm, 4)
        L = rng.uniform(-0.01, 0.01, 3)
        propagate_wheels(x, u, L, 0.1, substeps, J, J_inv, G, prm)
        before = y[7:].copy()
        y = solve_ivp(_oracle_rhs, (0.0, 0.1), y, method="DOP853", rtol=1e-12, atol=1e-14, args=(u, L, wheels)).y[:, -1]
        y[:4] /= np.linalg.norm(y[:4])
        crossings += int(np.count_nonzero(np.sign(y[7:]) != np.sign(before)))
    assert np.max(np.abs(x[:7] - y[:7])) < 1e-11
    assert np.max(np.abs(wheel_speeds(wheels, x) - y[7:])) < 1e-11 * max(1.0, np.max(np.abs(y[7:])))
    assert (crossings > 10) if wheels is SMOOTH else (crossings == 0)  # through zero speed (where a kink would be); never


def test_total_angular_momentum_is_conserved_in_the_inertial_frame_without_external_torque() -> None:
    rng = np.random.default_rng(5)
    x = _x0()
    J_inv = np.linalg.inv(J)
    prm, G = WHEELS.params(), np.ascontiguousarray(WHEELS.G)

    def H_N(x: np.ndarray) -> np.ndarray:
        return quat_to_dcm_BN(x[:4]).T @ angular_momentum_B(J, WHEELS, x)  # C_BN^T: B -> N

    H0 = H_N(x)
    for _ in range(2000):  # 20 s, motors changing every 10 ms, friction acting
        propagate_wheels(x, rng.uniform(-0.2, 0.2, 4), np.zeros(3), 0.01, 1, J, J_inv, G, prm)
    assert np.linalg.norm(H_N(x) - H0) < 1e-10 * np.linalg.norm(H0) + 1e-13
    assert np.max(np.abs(wheel_speeds(WHEELS, x) - wheel_speeds(WHEELS, _x0()))) > 1.0  # the wheels did move


def test_the_torque_path_allocates_minimum_norm_then_clips_and_stops_at_the_speed_limit() -> None:
    G, G_pinv, prm = np.ascontiguousarray(WHEELS.G), allocation_matrix(WHEELS.G), WHEELS.params()
    x = _x0()
    u = np.empty(4)
    tau = np.array([0.05, -0.03, 0.04])
    wheel_torques(tau, G_pinv, G, prm, x, u)
    assert np.allclose(-G @ u, tau, rtol=0, atol=1e-15)  # the body receives the command
    assert np.allclose(u, -np.linalg.pinv(G) @ tau, rtol=0, atol=1e-15)  # the minimum-norm solution
    wheel_torques(tau * 100.0, G_pinv, G, prm, x, u)  # beyond the motors: each clipped to 0.2 N m
    assert np.allclose(u, np.clip(-np.linalg.pinv(G) @ (tau * 100.0), -0.2, 0.2), rtol=0, atol=1e-15) and np.abs(u).max() == 0.2
    at_limit = ReactionWheels(spin_axes_B="pyramid", spin_inertia_kg_m2=0.02, max_torque_Nm=0.2, max_speed_rad_s=100.0)
    w = _x0()[4:7]  # wheels 0 and 1 just past +-100 rad/s (a limit reached during a sample)
    x = np.concatenate((_x0()[:7], 0.02 * (at_limit.G.T @ w + np.array([100.0 + 1e-9, -100.0 - 1e-9, 0.0, 0.0]))))
    cut = 0
    for sign in (1.0, -1.0):
        wheel_torques(sign * tau, allocation_matrix(at_limit.G), np.ascontiguousarray(at_limit.G), at_limit.params(), x, u)
        free = -np.linalg.pinv(at_limit.G) @ (sign * tau)
        expected = free.copy()
        expected[0] = 0.0 if free[0] > 0 else free[0]  # wheel 0 at +100 rad/s: no further speed-up
        expected[1] = 0.0 if free[1] < 0 else free[1]  # wheel 1 at -100 rad/s
        assert np.allclose(u, expected, rtol=0, atol=1e-15), sign
        cut += int(np.count_nonzero(expected != free))
    assert cut == 2  # each of the two wheels at its limit had its speed-up cut in one of the two cases


def test_presets_and_the_pyramid_envelope() -> None:
    G = ReactionWheels(spin_axes_B="pyramid", spin_inertia_kg_m2=0.02, max_torque_Nm=0.2, max_speed_rad_s=600.0).G
    assert np.allclose(np.linalg.norm(G, axis=0), 1.0) and np.allclose(np.degrees(np.arccos(G[2])), PYRAMID_CANT_DEG)
    envelope = np.abs(G).sum(axis=1) * 0.2  # the largest torque about x, y, z with every motor at its limit
    assert np.allclose(envelope, envelope[0])
    assert np.array_equal(ReactionWheels(spin_axes_B="orthogonal", spin_inertia_kg_m2=0.02, max_torque_Nm=0.2, max_speed_rad_s=600.0).G, np.eye(3))
    assert set(PRESETS) == {"orthogonal", "pyramid"}


@pytest.mark.parametrize(("change", "match"), [
    ({"spin_axes_B": "tetrahedron"}, "spin_axes_B must be one of"),
    ({"spin_axes_B": [[1, 0, 0], [0, 1, 0], [1, 1, 0]]}, "span three dimensions"),
    ({"spin_axes_B": [[1, 0, 0], [0, 0, 0], [0, 0, 1]]}, "zero axis"),
    ({"spin_inertia_kg_m2": [0.02, 0.02]}, "spin_inertia_kg_m2 must be one finite number or 4"),
    ({"max_torque_Nm": 0.0}, "max_torque_Nm must be > 0"),
    ({"coulomb_friction_Nm": -1e-3}, "coulomb_friction_Nm must be >= 0"),
    ({"initial_speed_rad_s": 700.0}, "within max_speed_rad_s"),
    ({"coulomb_speed_rad_s": 0.0}, "coulomb_speed_rad_s must be > 0"),
])
def test_a_bad_wheel_set_is_refused_naming_the_value(change: dict[str, object], match: str) -> None:
    base = {"spin_axes_B": "pyramid", "spin_inertia_kg_m2": 0.02, "max_torque_Nm": 0.2, "max_speed_rad_s": 600.0}
    with pytest.raises(ConfigError, match=match):
        ReactionWheels(**{**base, **change})  # type: ignore[arg-type]

"""Reaction wheels (spacecraft_sim.core.wheels): the compiled dynamics against an independent
oracle in another formulation (wheel speeds instead of momenta, integrated by scipy to 1e-12),
total angular momentum conserved without external torque whatever the motors and friction do,
the torque path (minimum-norm allocation, motor limit, speed limit), presets and validation, and
the SIMD lanes' RK4 (propagate_wheels_lanes) bit for bit the per-run one's."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from gnc_common.attitude import quat_to_dcm_BN
from gnc_common.validation import ConfigError
from spacecraft_sim.core.wheels import PRESETS, PYRAMID_CANT_DEG, ReactionWheels, allocation_matrix, angular_momentum_B, propagate_wheels
from gnc_common.compiled import jit
from spacecraft_sim.core.wheels import LANE_L, LANE_U, LANE_X, MAX_LANE_WHEELS, N_WHEEL_LANE_ROWS, propagate_wheels_into, propagate_wheels_lanes
from spacecraft_sim.core.wheels import wheel_lane_params, wheel_speeds, wheel_torques

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


# ---- the wheels' RK4 in SIMD lanes (propagate_wheels_lanes) ------------------------------------


@jit(cache=False)  # type: ignore[no-untyped-call]  # the project's options (error_model="numpy", no fastmath); not cached
def _lane_constants(F, J, J_inv, G, prm):  # type: ignore[no-untyped-def]
    """Each lane ``w``'s constants (``J[w]``, ``J_inv[w]``, ``G[w]``, ``prm[w]``) into its column of ``F``
    (wheel_lane_params is inline="always": it is called from compiled code)."""
    for w in range(F.shape[1]):
        wheel_lane_params(J[w], J_inv[w], G[w], prm[w], F, w)


@jit(cache=False)  # type: ignore[no-untyped-call]
def _lanes_step(F, n, dt, substeps, nl):  # type: ignore[no-untyped-def]
    """propagate_wheels_lanes (inline="always") of lanes ``0 .. nl - 1``."""
    propagate_wheels_lanes(F, n, dt, substeps, nl)


def _spd_inertia(rng: np.random.Generator) -> np.ndarray:
    """A full symmetric positive definite inertia: distinct principal moments 3 to 6 kg m^2 in a random frame."""
    Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    J = Q @ np.diag(rng.uniform(3.0, 6.0, 3)) @ Q.T
    sym: np.ndarray = (J + J.T) / 2
    return sym


def _lane_wheels(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """``n`` random unit spin axes ``G`` (3, n) and per-wheel parameters (n, 6), each wheel its own
    ``Js``, Coulomb friction, Coulomb speed and viscous friction (the limits are the torque path's)."""
    a = rng.normal(size=(3, n))
    G = np.ascontiguousarray(a / np.linalg.norm(a, axis=0))
    assert np.linalg.matrix_rank(G) == 3
    prm = np.column_stack((rng.uniform(0.015, 0.04, n), np.full(n, 0.2), np.full(n, 600.0), rng.uniform(5e-4, 3e-3, n),
                           rng.uniform(1e-5, 5e-5, n), rng.uniform(0.05, 0.2, n)))
    return G, np.ascontiguousarray(prm)


def _lane_speeds(x: np.ndarray, G: np.ndarray, prm: np.ndarray) -> np.ndarray:
    """``Omega = h / Js - G^T omega`` (n,) of one state."""
    Om: np.ndarray = x[7:] / prm[:, 0] - G.T @ x[4:7]
    return Om


@pytest.mark.parametrize("nl", [8, 5], ids=["all-lanes", "5-of-8-lanes"])
@pytest.mark.parametrize("substeps", [1, 3])
@pytest.mark.parametrize("n", [3, 4, 6])
def test_the_wheels_rk4_in_lanes_is_the_per_run_rk4_bit_for_bit(n: int, substeps: int, nl: int) -> None:
    """propagate_wheels_lanes over W = 8 lanes, each lane its own wheel set (random unit axes, its
    own Js, Coulomb friction, Coulomb speed and viscous friction per wheel), its own full inertia
    with products (J^-1 its inverse) and its own state (unit quaternion, rates ~0.05 rad/s, wheel
    speeds within +-0.3 rad/s of zero), 20 consecutive 0.1 s periods, each with its own motor and
    external torques: every lane's state equals propagate_wheels_into's on the same inputs bit for
    bit after every period (its docstring's claim: the same operations in the same order, no libm).
    The speeds start in both the Coulomb friction's linear region (|Omega| < Omega_c) and its
    saturated one, and some cross zero during the periods (asserted), so both branches of the
    friction's clip are compared.  With nl = 5 the lanes 5 .. 7 are not touched: their whole
    column of the array, state, inputs, constants and scratch, keeps its bytes.  The rows the
    lanes must not read (scratch in the first period, the torques and constants of wheels n .. 7)
    are NaN, which such a read would carry into the state.  (A reordered sum moves the state by a
    fraction of an ulp per step, which rounding often absorbs: hence 20 periods and the 12 cases;
    each of four one-operation changes of the lanes' arithmetic failed at least 8 of them.)"""
    rng = np.random.default_rng(100 + 10 * n + substeps)
    W, dt = 8, 0.1
    assert n <= MAX_LANE_WHEELS
    J = np.array([_spd_inertia(rng) for _ in range(W)])
    J_inv = np.array([np.linalg.inv(Jw) for Jw in J])
    wheels = [_lane_wheels(rng, n) for _ in range(W)]
    G = np.array([g for g, _ in wheels])
    prm = np.array([p for _, p in wheels])
    x = np.empty((W, 7 + n))
    for w in range(W):
        q = rng.normal(size=4)
        omega = rng.normal(0.0, 0.05, 3)
        Om = rng.uniform(-0.3, 0.3, n)  # around the Coulomb speeds 0.05 .. 0.2: both regions
        x[w] = np.concatenate((q / np.linalg.norm(q), omega, prm[w, :, 0] * (G[w].T @ omega + Om)))
    F = np.full((N_WHEEL_LANE_ROWS, W), np.nan)
    _lane_constants(F, J, J_inv, G, prm)
    F[LANE_X:LANE_X + 7 + n] = x.T
    linear = saturated = crossings = 0
    for _ in range(20):
        u = rng.uniform(-0.05, 0.05, (W, n))  # up to 3 rad/s^2 on a wheel: 0.3 rad/s in a period
        L = rng.uniform(-0.01, 0.01, (W, 3))
        F[LANE_U:LANE_U + n] = u.T
        F[LANE_L:LANE_L + 3] = L.T
        before = F.copy()
        _lanes_step(F, n, dt, substeps, nl)
        for w in range(W):
            if w >= nl:
                assert F[:, w].tobytes() == before[:, w].tobytes(), w  # not a lane of this call
                continue
            Om0 = _lane_speeds(x[w], G[w], prm[w])
            linear += int(np.count_nonzero(np.abs(Om0) < prm[w, :, 5]))
            saturated += int(np.count_nonzero(np.abs(Om0) > prm[w, :, 5]))
            propagate_wheels_into(x[w], u[w], L[w], dt, substeps, J[w], J_inv[w], G[w], prm[w], np.empty((5, 7 + n)), np.empty((3, 3)))
            crossings += int(np.count_nonzero(np.sign(_lane_speeds(x[w], G[w], prm[w])) != np.sign(Om0)))
            lane = np.ascontiguousarray(F[LANE_X:LANE_X + 7 + n, w])
            assert lane.tobytes() == x[w].tobytes(), (w, np.max(np.abs(lane - x[w])))
    assert linear > 0 and saturated > 0 and crossings > 0, (linear, saturated, crossings)

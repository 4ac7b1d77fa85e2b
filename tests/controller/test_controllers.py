"""Controller cores: the law against an independent implementation, batch == single run (bitwise),
eq. (dEpsilon) against finite differences, regularisations, guards and input errors."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from conftest import SCENARIOS, random_unit_quaternions
from sappc.evaluation.history import HistoryRecorder
from sappc.offline.closed_loop import run_closed_loop, step_times
from sappc.scenario import load_scenario
from sappc_controller.core.common import Actuator, ActuatorConfig, DynamicSurfaceFilter, predefined_time_gain
from sappc_controller.core.sappc import SappcTransformation
from gnc_common.attitude import euler_to_quaternion
from spacecraft_sim.core.dynamics import RigidBody, initial_state
from gnc_common.validation import ConfigError, InputError

SCENARIO = load_scenario(SCENARIOS / "paper_tracking.yaml")
REF = SCENARIO.reference
W_D = REF.omega_RN_R(0.0)
WDOT_D = REF.omegadot_RN_R(0.0)
Q_D = np.array([0.0, 0.0, 0.0, 1.0])


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def _hamilton(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    # scalar-last Hamilton product written out independently of the core
    px, py, pz, pw = p
    qx, qy, qz, qw = q
    return np.array([
        pw * qx + px * qw + py * qz - pz * qy,
        pw * qy - px * qz + py * qw + pz * qx,
        pw * qz + px * qy - py * qx + pz * qw,
        pw * qw - px * qx - py * qy - pz * qz,
    ])


def _reference_sappc_torques(cfg, dt, states) -> list[np.ndarray]:  # type: ignore[no-untyped-def]
    """Eqs. (virtualcontrol), (U), (dSd) with explicit matrices, for a sequence of (t, q_BN, w_B) samples."""
    g = cfg.gains
    J = np.asarray(cfg.inertia_kg_m2)
    k = np.tan(np.radians(cfg.theta_deg))
    tr = SappcTransformation(cfg.rpf, cfg.B0, np.radians(cfg.theta_deg))
    out = []
    S_d = None
    for t, q, w in states:
        q_e = _hamilton(np.array([-Q_D[0], -Q_D[1], -Q_D[2], Q_D[3]]), q)
        q_e = -q_e if q_e[3] < 0 else q_e
        qv, q0 = q_e[:3], q_e[3]
        C_e = (q0**2 - qv @ qv) * np.eye(3) + 2 * np.outer(qv, qv) - 2 * q0 * _skew(qv)
        w_e = w - C_e @ W_D
        if S_d is None:
            tr.start(qv[None])
        rho, rho_dot = tr.rpf.evaluate(t)
        rho, rho_dot = rho[0], rho_dot[0]
        delta = cfg.B0 / np.abs(rho)
        z = qv / rho
        # solve eq. (solve) by bisection, independent of the core's Newton solver
        eps = np.empty(3)
        for i in range(3):
            lo, hi = 1 - delta[i], 1 + delta[i]
            for _ in range(200):
                mid = 0.5 * (lo + hi)
                if mid + k * np.tan(np.pi * (mid - 1) / (2 * delta[i])) > z[i]:
                    hi = mid
                else:
                    lo = mid
            eps[i] = np.tan(np.pi * (0.5 * (lo + hi) - 1) / (2 * delta[i]))
        P_s = np.pi * (eps**2 + 1) / (np.pi * (eps**2 + 1) * k + 2 * delta)  # eq. (PS)
        psi = np.diag(P_s / rho)
        eta = np.diag(-rho_dot / rho)
        V1 = 0.5 * eps @ eps
        M_q = np.exp(V1**g.p) * V1 ** (-g.p) / (2 * g.p * g.T1_s)
        Gamma = 0.5 * (q0 * np.eye(3) + _skew(qv))
        alpha = np.linalg.inv(Gamma) @ (-np.linalg.inv(psi) @ (M_q * g.K_q * eps) - eta @ qv)
        if S_d is None:
            S_d = alpha.copy()
        H_d = S_d - alpha
        V3 = 0.5 * H_d @ H_d
        M3 = np.exp(max(V3, g.V_floor) ** g.p) * max(V3, g.V_floor) ** (-g.p) / (2 * g.p * g.T3_s)
        S_d_dot = -(1 - np.exp(-M3 * dt)) / dt * H_d
        z2 = w_e - S_d
        V2 = 0.5 * z2 @ J @ z2
        M_w = np.exp(V2**g.p) * V2 ** (-g.p) / (2 * g.p * g.T2_s)
        W0 = J @ _skew(w_e) @ C_e @ W_D - J @ C_e @ WDOT_D - _skew(w) @ J @ w
        u = -W0 + J @ S_d_dot - g.D_m_Nm * np.tanh(z2 / g.mu_rad_s) - M_w * g.K_omega * J @ z2
        out.append(u)
        S_d = S_d + dt * S_d_dot
    return out


def test_sappc_law_matches_an_independent_implementation_of_the_paper_equations() -> None:
    cfg = dataclasses.replace(SCENARIO.controller_config("sappc"), inertia_kg_m2=((4.0, 0.1, 0.0), (0.1, 5.0, -0.2), (0.0, -0.2, 3.0)))
    ctrl = SCENARIO.build_controller("sappc")
    ctrl = type(ctrl)(cfg)
    q = np.array([0.3254, 0.4068, -0.3254, 0.7891])
    q = q / np.linalg.norm(q)
    dt = 0.01
    states = [(0.0, q, np.array([0.01, -0.02, 0.03])), (dt, q + np.array([1e-3, -2e-3, 1e-3, 0]), np.array([0.02, -0.01, 0.04]))]
    states = [(t, qq / np.linalg.norm(qq), w) for t, qq, w in states]
    expected = _reference_sappc_torques(cfg, dt, states)
    for (t, qq, w), u_ref in zip(states, expected, strict=True):
        out = ctrl.step(t, dt, qq, w, Q_D, W_D, WDOT_D)
        # the bisection reference is exact to ~1e-15 in z0; through tan near the band edge that is ~1e-10 relative in u
        np.testing.assert_allclose(out.torque_cmd_B, u_ref, rtol=1e-8, atol=1e-12)


def _batch_histories(kind: str, q0s: np.ndarray, duration_s: float = 3.0):  # type: ignore[no-untyped-def]
    t = step_times(duration_s, SCENARIO.control_period_s)
    ref = REF.sample(t)
    rec = HistoryRecorder(t, q0s.shape[0])
    run_closed_loop(RigidBody(SCENARIO.inertia_kg_m2), SCENARIO.build_controller(kind), ref, SCENARIO.disturbance,
                    initial_state(q0s, np.zeros(3)), SCENARIO.control_period_s, observer=rec)
    return rec.history()


@pytest.mark.parametrize("kind", ["sappc", "trappc", "blfppc"])
def test_one_run_alone_equals_the_same_run_inside_a_batch_bit_for_bit(kind) -> None:
    angles = np.radians([[20, -15, 30], [-40, 10, 5], [5, 5, -25], [30, 20, 10]])
    q0s = euler_to_quaternion(angles, "ZYX")
    batch = _batch_histories(kind, q0s)
    for k in (0, 2):
        alone = _batch_histories(kind, q0s[k : k + 1])
        for name, value in vars(alone).items():
            if name != "t":
                np.testing.assert_array_equal(value[:, 0], getattr(batch, name)[:, k], err_msg=name)


def test_eps_dot_identity_of_eq_dEpsilon_along_a_smooth_trajectory() -> None:
    cfg = SCENARIO.controller_config("sappc")
    tr = SappcTransformation(cfg.rpf, cfg.B0, np.radians(cfg.theta_deg))
    tr.start(np.array([[0.3, 0.4, -0.3]]))

    def q_ev(t: float) -> np.ndarray:  # a smooth error trajectory crossing in and out of the band
        return np.array([[0.3 * np.exp(-0.3 * t) + 0.01 * np.sin(t), 0.4 * np.exp(-0.5 * t), -0.3 * np.exp(-0.4 * t) + 0.02 * np.cos(2 * t)]])

    h = 1e-6
    for t in (0.5, 3.0, 12.0, 18.5, 19.9):
        e = q_ev(t)
        e_dot = (q_ev(t + h) - q_ev(t - h)) / (2 * h)
        tr_now = tr.transform(e, t)
        eps_fd = (tr.transform(q_ev(t + h), t + h).eps - tr.transform(q_ev(t - h), t - h).eps) / (2 * h)
        predicted = tr_now.psi * (e_dot + tr_now.eta * e) + tr_now.xi
        np.testing.assert_allclose(predicted, eps_fd, rtol=1e-6, atol=1e-6 * np.abs(tr_now.eps).max())


def test_predefined_time_gain_is_finite_at_zero_and_exact_above_the_floor() -> None:
    V = np.array([0.0, 1e-300, 1e-12, 1e-6, 0.5, 1.0, 30.0])
    M = predefined_time_gain(V, 0.1, 3.0, 1e-12)
    assert np.all(np.isfinite(M))
    exact = np.exp(V[2:] ** 0.1) * V[2:] ** -0.1 / 0.6
    np.testing.assert_allclose(M[2:], exact, rtol=1e-14)
    assert M[0] == M[1] == M[2]  # capped at M(V_floor)
    assert np.all(np.diff(M[2:6]) < 0) and M[6] > M[5]  # decreasing below V = 1, increasing above


def test_dynamic_surface_filter_is_stable_for_any_gain() -> None:
    f = DynamicSurfaceFilter(p=0.1, T3=2.0, V_floor=1e-300)  # floor so low that M3 reaches ~1e29
    alpha = np.array([[1.0, -2.0, 0.5]])
    f.update(alpha, 0.01)
    H = [np.abs(f.S_d - 0).max()]
    for _ in range(200):
        S_d, S_d_dot, _ = f.update(np.zeros((1, 3)), 0.01)
        assert np.all(np.isfinite(S_d_dot)) and np.abs(S_d_dot).max() <= np.abs(S_d).max() / 0.01 * (1 + 1e-15)
        H.append(np.abs(f.S_d).max())
    assert all(b <= a for a, b in zip(H, H[1:], strict=False))  # a contraction, never an overshoot
    assert H[-1] < 1e-12


def test_filter_derivative_tends_to_eq_dSd_for_small_steps() -> None:
    f = DynamicSurfaceFilter(p=0.1, T3=2.0, V_floor=1e-12)
    f.S_d = np.array([[0.01, 0.0, -0.02]])
    _, S_d_dot, V3 = f.update(np.zeros((1, 3)), 1e-7)
    M3 = np.exp(V3**0.1) * V3**-0.1 / (2 * 0.1 * 2.0)
    np.testing.assert_allclose(S_d_dot, -M3[:, None] * np.array([[0.01, 0.0, -0.02]]), rtol=1e-5)


def test_actuator_saturates_per_axis_and_drops_commands_below_the_minimum() -> None:
    act = Actuator(ActuatorConfig(max_torque_Nm=0.5, min_torque_Nm=0.005))
    u, sat = act.apply(np.array([[0.7, -0.004, 0.004999], [-3.0, 0.005, 0.2]]))
    np.testing.assert_array_equal(u, [[0.5, 0.0, 0.0], [-0.5, 0.005, 0.2]])
    np.testing.assert_array_equal(sat, [[True, False, False], [True, False, False]])
    with pytest.raises(ConfigError, match="min_torque_Nm"):
        ActuatorConfig(max_torque_Nm=0.5, min_torque_Nm=0.6)


@pytest.mark.parametrize(
    "field, value, fragment",
    [
        ("q_BN", [0.0, 0.0, 0.0, 0.0], "q_BN must be a unit quaternion"),
        ("q_BN", [0.1, 0.2, 0.3, 0.5], "norm"),
        ("q_BN", [np.nan, 0.0, 0.0, 1.0], "q_BN contains a non-finite value nan"),
        ("omega_BN_B", [0.0, np.inf, 0.0], "omega_BN_B contains a non-finite value inf"),
        ("q_RN", [0.0, 0.0, 0.0, 2.0], "q_RN"),
        ("omega_RN_R", [0.0, 0.0], "omega_RN_R must have trailing shape"),
        ("omegadot_RN_R", [np.nan, 0.0, 0.0], "omegadot_RN_R"),
        ("dt", 0.0, "dt must be > 0"),
        ("dt", np.nan, "dt contains a non-finite"),
        ("t", np.inf, "t contains a non-finite"),
    ],
)
@pytest.mark.parametrize("kind", ["sappc", "trappc", "blfppc"])
def test_bad_input_raises_naming_the_value_and_never_returns_nan(kind, field, value, fragment) -> None:
    args = dict(t=0.0, dt=0.01, q_BN=[0.1, 0.2, -0.1, np.sqrt(0.94)], omega_BN_B=[0.0, 0.0, 0.0], q_RN=Q_D, omega_RN_R=W_D, omegadot_RN_R=WDOT_D)
    args[field] = value
    with pytest.raises(InputError, match=fragment.replace("(", r"\(").replace("[", r"\[")):
        SCENARIO.build_controller(kind).step(**args)


def test_start_at_the_180_degree_singularity_is_rejected() -> None:
    with pytest.raises(InputError, match="q_e0 = 0 .*180 deg"):
        SCENARIO.build_controller("sappc").step(0.0, 0.01, [1.0, 0.0, 0.0, 0.0], [0, 0, 0], Q_D, W_D, WDOT_D)


def test_batch_size_change_is_rejected() -> None:
    c = SCENARIO.build_controller("sappc")
    q = np.array([[0.1, 0.2, -0.1, np.sqrt(0.94)]] * 2)
    c.step(0.0, 0.01, q, np.zeros((2, 3)), Q_D, W_D, WDOT_D)
    with pytest.raises(InputError, match="reset"):
        c.step(0.01, 0.01, q[:1], np.zeros((1, 3)), Q_D, W_D, WDOT_D)


@pytest.mark.parametrize("kind", ["sappc", "trappc", "blfppc"])
def test_passing_through_180_degrees_mid_run_gives_bounded_torque(kind) -> None:
    c = SCENARIO.build_controller(kind)
    c.step(0.0, 0.01, [0.1, 0.2, -0.1, np.sqrt(0.94)], [0, 0, 0], Q_D, W_D, WDOT_D)
    for q0 in (1e-3, 1e-9, 0.0):
        qv = np.array([0.6, 0.0, 0.8]) * np.sqrt(1 - q0**2)
        out = c.step(0.01, 0.01, np.append(qv, q0), [0.5, -0.5, 0.5], Q_D, W_D, WDOT_D)
        assert np.all(np.isfinite(out.torque_cmd_B)) and np.all(np.abs(out.torque_B) <= 0.5)


def test_benchmarks_outside_their_funnels_give_finite_saturated_torque() -> None:
    for kind in ("trappc", "blfppc"):
        c = SCENARIO.build_controller(kind)
        c.step(0.0, 0.01, [0.1, 0.2, -0.1, np.sqrt(0.94)], [0, 0, 0], Q_D, W_D, WDOT_D)
        for qv in ([-0.3, 0.2, -0.1], [0.1, -0.2, 0.1], [0.25, 0.0, 0.0]):  # wrong side, and exactly on a wall
            q = np.append(qv, np.sqrt(1 - np.dot(qv, qv)))
            out = c.step(30.0, 0.01, q, [0, 0, 0], Q_D, W_D, WDOT_D)
            assert np.all(np.isfinite(out.torque_cmd_B)) and np.all(np.abs(out.torque_B) <= 0.5)


def test_benchmarks_must_start_inside_their_funnel() -> None:
    with pytest.raises(ConfigError, match="rho_0 = 0.5 must exceed"):
        SCENARIO.build_controller("trappc").step(0.0, 0.01, [0.6, 0.0, 0.0, 0.8], [0, 0, 0], Q_D, W_D, WDOT_D)
    with pytest.raises(ConfigError, match="rho_initial = 0.5 must exceed"):
        SCENARIO.build_controller("blfppc").step(0.0, 0.01, [0.6, 0.0, 0.0, 0.8], [0, 0, 0], Q_D, W_D, WDOT_D)


def test_gains_are_validated_with_their_names() -> None:
    cfg = SCENARIO.controller_config("sappc")
    with pytest.raises(ConfigError, match="gains.K_q"):
        dataclasses.replace(cfg, gains=dataclasses.replace(cfg.gains, K_q=-1.0))
    with pytest.raises(ConfigError, match=r"p \* gains.T3_s must be < 1"):
        dataclasses.replace(cfg, gains=dataclasses.replace(cfg.gains, T3_s=20.0))
    with pytest.raises(ConfigError, match="theta_deg"):
        dataclasses.replace(cfg, theta_deg=90.0)
    with pytest.raises(ConfigError, match="inertia_kg_m2 must be positive definite"):
        dataclasses.replace(cfg, inertia_kg_m2=((1.0, 0, 0), (0, -1.0, 0), (0, 0, 1.0)))


def test_single_run_output_has_no_batch_axis() -> None:
    out = SCENARIO.build_controller("sappc").step(0.0, 0.01, [0.1, 0.2, -0.1, np.sqrt(0.94)], [0, 0, 0], Q_D, W_D, WDOT_D)
    assert out.torque_B.shape == (3,) and out.V.shape == (3,) and out.q_BR.shape == (4,)
    rng = np.random.default_rng(0)
    q = random_unit_quaternions(rng, 5)
    q = np.where(q[:, 3:] < 0, -q, q)
    out = SCENARIO.build_controller("sappc").step(0.0, 0.01, q, np.zeros((5, 3)), Q_D, W_D, WDOT_D)
    assert out.torque_B.shape == (5, 3)


def test_per_run_gains_in_a_batch_equal_the_same_gains_alone() -> None:
    base = SCENARIO.controller_config("sappc")
    K_q = np.array([0.25, 0.3, 0.35])
    mu = np.array([6e-5, 7e-5, 8e-5])
    batch_cfg = dataclasses.replace(base, gains=dataclasses.replace(base.gains, K_q=K_q, mu_rad_s=mu))
    q = euler_to_quaternion(np.radians([[20, -15, 30], [-40, 10, 5], [5, 5, -25]]), "ZYX")
    batch = type(SCENARIO.build_controller("sappc"))(batch_cfg)
    outs = [batch.step(0.01 * k, 0.01, q, np.full((3, 3), 0.01), Q_D, W_D, WDOT_D) for k in range(3)]
    for i in range(3):
        alone_cfg = dataclasses.replace(base, gains=dataclasses.replace(base.gains, K_q=float(K_q[i]), mu_rad_s=float(mu[i])))
        alone = type(SCENARIO.build_controller("sappc"))(alone_cfg)
        for k in range(3):
            out = alone.step(0.01 * k, 0.01, q[i], np.full(3, 0.01), Q_D, W_D, WDOT_D)
            np.testing.assert_array_equal(out.torque_cmd_B, outs[k].torque_cmd_B[i])
    with pytest.raises(ConfigError, match="gains.K_q must be finite and > 0"):
        dataclasses.replace(base.gains, K_q=np.array([0.3, -0.1]))

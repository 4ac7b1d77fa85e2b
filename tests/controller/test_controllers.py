"""The compiled controller law (``sappc_controller.core.kernels``, through ``AttitudeController.step``
and its pieces): against an independent implementation of the paper's equations, batch == single
run (bitwise), eq. (dEpsilon) against finite differences, regularisations, guards, input errors,
runtime gain changes."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from conftest import SCENARIOS, random_unit_quaternions
from controller.oracle import constraint_bound, rpf_evaluate
from sappc.scenario import load_scenario
from sappc_controller.core import kernels as K
from sappc_controller.core import packing as KP
from sappc_controller.core.common import ActuatorConfig
from sappc_controller.core.rpf import ReferencePerformanceFunction
from gnc_common.attitude import euler_to_quaternion, quat_multiply
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
    rpf = None
    out = []
    S_d = None
    for t, q, w in states:
        q_e = _hamilton(np.array([-Q_D[0], -Q_D[1], -Q_D[2], Q_D[3]]), q)
        q_e = -q_e if q_e[3] < 0 else q_e
        qv, q0 = q_e[:3], q_e[3]
        C_e = (q0**2 - qv @ qv) * np.eye(3) + 2 * np.outer(qv, qv) - 2 * q0 * _skew(qv)
        w_e = w - C_e @ W_D
        if rpf is None:
            rpf = ReferencePerformanceFunction(cfg.rpf, qv[None])  # the run's set-up (Lambert W)
        rho, rho_dot = rpf_evaluate(rpf, t)  # the oracle's eq. (RPF)
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


def _open_loop_outputs(kind: str, q0s: np.ndarray, runs: np.ndarray, batch: bool, n_steps: int = 60) -> list[dict[str, np.ndarray]]:
    """Outputs (copied) of one controller stepping runs ``runs`` (rows of ``q0s``) along smooth
    state sequences (each run's own), as a batch or, for one run, with (4,)/(3,) inputs."""
    ctrl = SCENARIO.build_controller(kind)
    t = np.arange(n_steps) * SCENARIO.control_period_s
    ref = REF.sample(t)
    w_d, wd_d = REF.omega_RN_R(t), REF.omegadot_RN_R(t)
    q0s, k_run = q0s[runs], runs[:, None]
    outs = []
    for k in range(n_steps):
        rot = euler_to_quaternion(np.radians(0.05 * k * np.hstack((k_run + 1, -k_run, 0.5 + k_run))), "ZYX")
        q = quat_multiply(q0s, rot)
        w = 0.01 * np.sin(0.1 * k + np.hstack((k_run, 2 * k_run, 3 * k_run)))
        args = (q, w) if batch else (q[0], w[0])
        out = ctrl.step(float(t[k]), SCENARIO.control_period_s, *args, ref.q_RN[k], w_d[k], wd_d[k])
        outs.append({f.name: np.array(getattr(out, f.name)).reshape(q.shape[0], -1) for f in dataclasses.fields(out)})
    return outs


@pytest.mark.parametrize("kind", ["sappc", "trappc", "blfppc"])
def test_one_run_alone_equals_the_same_run_inside_a_batch_bit_for_bit(kind) -> None:
    angles = np.radians([[20, -15, 30], [-40, 10, 5], [5, 5, -25], [30, 20, 10]])
    q0s = euler_to_quaternion(angles, "ZYX")
    batch = _open_loop_outputs(kind, q0s, np.arange(4), batch=True)
    for k in (0, 2):
        alone = _open_loop_outputs(kind, q0s, np.array([k]), batch=False)
        for step_b, step_a in zip(batch, alone, strict=True):
            for name, value in step_a.items():
                np.testing.assert_array_equal(value[0], step_b[name][k], err_msg=name)


def _sappc_transform(cfg, rpf: ReferencePerformanceFunction):  # type: ignore[no-untyped-def]
    """The compiled SMETF transformation (``kernels.sappc_transform``) of one run, cold (no warm
    start): ``(q_ev, tau) -> (eps, psi, eta, d eps / d delta)``."""
    prm, coef = KP.pack_params(cfg)[0], KP.rpf_coef(rpf)[0]
    work, out = np.zeros((K.N_WORK, 4)), np.zeros((K.N_OUT, 4))

    def transform(q_ev: np.ndarray, tau: float) -> tuple[np.ndarray, ...]:
        state = K.new_state(1)[0]
        work[K.W_QBR, :3] = q_ev
        K.sappc_transform(prm, coef, state, tau, work, out)
        return work[K.W_EPS, :3].copy(), work[K.W_PSI, :3].copy(), work[K.W_ETA, :3].copy(), state[K.S_PREV + 9 : K.S_PREV + 12].copy()

    return transform


def test_eps_dot_identity_of_eq_dEpsilon_along_a_smooth_trajectory() -> None:
    """The compiled transformation's psi, eta and d eps / d delta satisfy eq. (dEpsilon),
    ``eps_dot = psi (q_ev_dot + eta q_ev) + xi`` with ``xi = (d eps / d delta) delta_dot``
    (``delta_dot`` of eq. delta_i in closed form), against central differences of its eps."""
    cfg = SCENARIO.controller_config("sappc")
    rpf = ReferencePerformanceFunction(cfg.rpf, np.array([[0.3, 0.4, -0.3]]))
    transform = _sappc_transform(cfg, rpf)

    def q_ev(t: float) -> np.ndarray:  # a smooth error trajectory crossing in and out of the band
        return np.array([0.3 * np.exp(-0.3 * t) + 0.01 * np.sin(t), 0.4 * np.exp(-0.5 * t), -0.3 * np.exp(-0.4 * t) + 0.02 * np.cos(2 * t)])

    h = 1e-6
    for t in (0.5, 3.0, 12.0, 18.5, 19.9):
        e = q_ev(t)
        e_dot = (q_ev(t + h) - q_ev(t - h)) / (2 * h)
        eps, psi, eta, d_eps_d_delta = transform(e, t)
        _, delta_dot = constraint_bound(cfg.B0, *rpf_evaluate(rpf, t))
        eps_fd = (transform(q_ev(t + h), t + h)[0] - transform(q_ev(t - h), t - h)[0]) / (2 * h)
        predicted = psi * (e_dot + eta * e) + d_eps_d_delta * delta_dot[0]
        np.testing.assert_allclose(predicted, eps_fd, rtol=1e-6, atol=1e-6 * np.abs(eps).max())


def test_predefined_time_gain_is_finite_at_zero_and_exact_above_the_floor() -> None:
    V = np.array([0.0, 1e-300, 1e-12, 1e-6, 0.5, 1.0, 30.0])
    M = np.array([K.predefined_time_gain(v, 0.1, 3.0, 1e-12) for v in V])
    assert np.all(np.isfinite(M))
    exact = np.exp(V[2:] ** 0.1) * V[2:] ** -0.1 / 0.6
    np.testing.assert_allclose(M[2:], exact, rtol=1e-14)
    assert M[0] == M[1] == M[2]  # capped at M(V_floor)
    assert np.all(np.diff(M[2:6]) < 0) and M[6] > M[5]  # decreasing below V = 1, increasing above


def _filter(V_floor: float):  # type: ignore[no-untyped-def]
    """The compiled dynamic-surface filter (``kernels.filter_update``), p = 0.1, T3 = 2 s:
    ``(alpha, dt) -> (S_d, S_d_dot, V3)``, and its state."""
    prm, state = np.zeros(K.N_PARAMS), K.new_state(1)[0]
    prm[K.P_P], prm[K.P_T3], prm[K.P_VFLOOR] = 0.1, 2.0, V_floor

    def update(alpha: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray, float]:
        a = np.asarray(alpha, dtype=float)
        V3, S_d, S_d_dot = K.filter_update(prm, state, dt, a[0], a[1], a[2])
        return np.array(S_d), np.array(S_d_dot), V3

    return update, state


def test_dynamic_surface_filter_is_stable_for_any_gain() -> None:
    update, state = _filter(1e-300)  # floor so low that M3 reaches ~1e29
    update(np.array([1.0, -2.0, 0.5]), 0.01)
    H = [np.abs(state[K.S_SD : K.S_SD + 3]).max()]
    for _ in range(200):
        S_d, S_d_dot, _ = update(np.zeros(3), 0.01)
        assert np.all(np.isfinite(S_d_dot)) and np.abs(S_d_dot).max() <= np.abs(S_d).max() / 0.01 * (1 + 1e-15)
        H.append(np.abs(state[K.S_SD : K.S_SD + 3]).max())
    assert all(b <= a for a, b in zip(H, H[1:], strict=False))  # a contraction, never an overshoot
    assert H[-1] < 1e-12


def test_filter_derivative_tends_to_eq_dSd_for_small_steps() -> None:
    update, state = _filter(1e-12)
    state[K.S_SD : K.S_SD + 3] = [0.01, 0.0, -0.02]
    state[K.S_FILTER_ON] = 1.0
    _, S_d_dot, V3 = update(np.zeros(3), 1e-7)
    M3 = np.exp(V3**0.1) * V3**-0.1 / (2 * 0.1 * 2.0)
    np.testing.assert_allclose(S_d_dot, -M3 * np.array([0.01, 0.0, -0.02]), rtol=1e-5)


def test_actuator_saturates_per_axis_and_drops_commands_below_the_minimum() -> None:
    prm, out = np.zeros(K.N_PARAMS), np.zeros((K.N_OUT, 4))
    prm[K.P_UMAX], prm[K.P_UMIN] = 0.5, 0.005  # ActuatorConfig(max_torque_Nm=0.5, min_torque_Nm=0.005)
    for u_cmd, u_ref, sat_ref in (([0.7, -0.004, 0.004999], [0.5, 0.0, 0.0], [1.0, 0.0, 0.0]),
                                   ([-3.0, 0.005, 0.2], [-0.5, 0.005, 0.2], [1.0, 0.0, 0.0])):
        out[K.O_CMD, :3] = u_cmd
        K.actuator(prm, np.zeros(K.N_STATE), 0.01, out)  # the torque filter off (prm[P_TORQUE_WC] = 0)
        np.testing.assert_array_equal(out[K.O_TORQUE, :3], u_ref)
        np.testing.assert_array_equal(out[K.O_SAT, :3], sat_ref)
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
    outs = [batch.step(0.01 * k, 0.01, q, np.full((3, 3), 0.01), Q_D, W_D, WDOT_D).copy() for k in range(3)]
    for i in range(3):
        alone_cfg = dataclasses.replace(base, gains=dataclasses.replace(base.gains, K_q=float(K_q[i]), mu_rad_s=float(mu[i])))
        alone = type(SCENARIO.build_controller("sappc"))(alone_cfg)
        for k in range(3):
            out = alone.step(0.01 * k, 0.01, q[i], np.full(3, 0.01), Q_D, W_D, WDOT_D)
            np.testing.assert_array_equal(out.torque_cmd_B, outs[k].torque_cmd_B[i])
    with pytest.raises(ConfigError, match="gains.K_q must be finite and > 0"):
        dataclasses.replace(base.gains, K_q=np.array([0.3, -0.1]))


def test_reconfigure_changes_the_packed_gains_from_the_next_step() -> None:
    """A runtime gain change (the node's parameters) reaches the compiled law: after it, the run
    continues as a run that had the new gains from the start would at that sample (same state)."""
    base = SCENARIO.controller_config("sappc")
    new = dataclasses.replace(base, gains=dataclasses.replace(base.gains, K_q=0.2, D_m_Nm=0.002),
                              actuator=ActuatorConfig(max_torque_Nm=0.4, min_torque_Nm=0.001))
    q = np.array([0.1, 0.2, -0.1, np.sqrt(0.94)])
    changed, fresh = SCENARIO.build_controller("sappc"), type(SCENARIO.build_controller("sappc"))(new)
    a = changed.step(0.0, 0.01, q, [0.01, 0, 0], Q_D, W_D, WDOT_D).copy()
    b = fresh.step(0.0, 0.01, q, [0.01, 0, 0], Q_D, W_D, WDOT_D).copy()
    assert not np.array_equal(a.torque_cmd_B, b.torque_cmd_B)
    changed.reconfigure(new)
    np.testing.assert_array_equal(changed._prm, KP.pack_params(new))
    changed._state[...] = fresh._state  # same filter and warm start: only the gains can differ
    a = changed.step(0.01, 0.01, q, [0.02, 0, 0], Q_D, W_D, WDOT_D).copy()
    b = fresh.step(0.01, 0.01, q, [0.02, 0, 0], Q_D, W_D, WDOT_D).copy()
    np.testing.assert_array_equal(a.torque_cmd_B, b.torque_cmd_B)
    np.testing.assert_array_equal(a.torque_B, b.torque_B)
    with pytest.raises(ConfigError, match="gains.T3_s cannot change"):
        changed.reconfigure(dataclasses.replace(new, gains=dataclasses.replace(new.gains, T3_s=1.0)))
    np.testing.assert_array_equal(changed._prm, KP.pack_params(new))  # all or nothing


def test_outputs_are_views_valid_until_the_next_step_and_copy_keeps_them() -> None:
    c = SCENARIO.build_controller("sappc")
    first = c.step(0.0, 0.01, [0.1, 0.2, -0.1, np.sqrt(0.94)], [0, 0, 0], Q_D, W_D, WDOT_D)
    kept = first.copy()
    second = c.step(0.01, 0.01, [0.1, 0.2, -0.1, np.sqrt(0.94)], [0.1, 0, 0], Q_D, W_D, WDOT_D)
    assert not np.array_equal(kept.torque_cmd_B, second.torque_cmd_B)
    np.testing.assert_array_equal(first.torque_cmd_B, second.torque_cmd_B)  # the first output now shows the second step
    q = np.array([0.1, 0.2, -0.1, np.sqrt(0.94)])
    assert c.step(0.02, 0.01, q, np.zeros(3), Q_D, W_D, WDOT_D) is c.step(0.03, 0.01, q, np.zeros(3), Q_D, W_D, WDOT_D)

"""A plain numpy reference of the three control laws: a test oracle, not a product path.

The product's one implementation is compiled (``sappc_controller.core.kernels``); this module is
the numpy core it replaced, condensed, kept to check it against.  Runs are batched along a leading
axis N (vectors (N, 3), quaternions (N, 4)); the RPF's coefficients come from the product's set-up
(:class:`sappc_controller.core.rpf.ReferencePerformanceFunction`, Lambert W), everything evaluated
per sample is written here again.  Equation numbers are the paper's.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from gnc_common.attitude import cross, dot, error_quaternion, matvec
from sappc_controller.core.blfppc import BARRIER_MARGIN, BlfppcConfig
from sappc_controller.core.rpf import ReferencePerformanceFunction
from sappc_controller.core.sappc import SappcConfig
from sappc_controller.core.trappc import DOMAIN_MARGIN, TrappcConfig

Array = np.ndarray
_TWO_OVER_PI = 2.0 / np.pi


def dcm_BR_times(q_BR: Array, v_R: Array) -> Array:
    """``C_e v``, ``C_e = (q0^2 - q_v·q_v) I + 2 q_v q_v^T - 2 q0 q_v^x`` (eq. errorsystem), (N, 3)."""
    qv, q0 = q_BR[..., :3], q_BR[..., 3:]
    return (q0 * q0 - dot(qv, qv)[..., None]) * v_R + 2.0 * dot(qv, v_R)[..., None] * qv - 2.0 * q0 * cross(qv, v_R)


def gamma_inverse_times(q_BR: Array, x: Array, q0_floor: float) -> Array:
    """``Gamma(q_e)^-1 x = 2 (q0 x - q_v × x + q_v (q_v·x) / q0)`` with ``q0`` floored (docs/paper_notes.md, error 5)."""
    qv = q_BR[..., :3]
    q0 = np.maximum(q_BR[..., 3:], q0_floor)
    return 2.0 * (q0 * x - cross(qv, x) + (dot(qv, x)[..., None] / q0) * qv)


def rpf_evaluate(r: ReferencePerformanceFunction, t: float) -> tuple[Array, Array]:
    """RPF value and slope (N, 3) at ``t`` (eq. RPF): exponential, parabola, ``g_inf``; times the sign."""
    p = r.params
    t = max(float(t), 0.0)
    if t >= p.t2_s:
        return r.sign * p.g_inf, np.zeros_like(r.sign)
    expo = r.A * np.exp(-r.l * t)
    dt2 = t - p.t2_s
    in_exp = t < r.t1
    rho = np.where(in_exp, expo + p.rho_einf, r.a1 * dt2 * dt2 + p.g_inf)
    rho_dot = np.where(in_exp, -r.l * expo, 2.0 * r.a1 * dt2)
    return r.sign * rho, r.sign * rho_dot


def constraint_bound(B0: float, rho: Array, rho_dot: Array) -> tuple[Array, Array]:
    """``delta = B0 / |rho|`` (eq. delta_i) and ``delta_dot = -B0 sign(rho) rho_dot / rho^2``."""
    abs_rho = np.abs(rho)
    delta = B0 / abs_rho
    return delta, -delta * np.sign(rho) * rho_dot / abs_rho


def smetf(z_s: Array, delta: Array, k: float) -> tuple[Array, Array]:
    """``eps`` and ``z0 - 1`` solving eq. (solve) ``(2 delta/pi) arctan(eps) + k eps = z_s - 1``
    (monotone Newton from the lower bound, cold)."""
    a = _TWO_OVER_PI * delta
    w = z_s - 1.0
    abs_w = np.abs(w)
    lower = np.maximum(abs_w / (a + k), (abs_w - a * (np.pi / 2.0)) / k)
    eps = lower
    for _ in range(60):
        a_atan = a * np.arctan(eps)
        resid = a_atan + k * eps - abs_w
        active = np.abs(resid) > 4.0 * np.finfo(float).eps * (a_atan + k * eps + abs_w)
        if not active.any():
            break
        eps = np.maximum(eps - np.where(active, resid / (a / (1.0 + eps * eps) + k), 0.0), lower)
    return np.copysign(eps, w), np.copysign(a_atan, w)


def smetf_derivatives(eps: Array, z0_offset: Array, delta: Array, k: float) -> tuple[Array, Array]:
    """``P_s`` (eq. PS) and ``d eps / d delta = -((z0 - 1)/delta) P_s`` (docs/paper_notes.md, error 3)."""
    P_s = 1.0 / (k + (_TWO_OVER_PI * delta) / (1.0 + eps * eps))
    return P_s, -(z0_offset / delta) * P_s


def predefined_time_gain(V: Array, p: float, T: float, V_floor: float) -> Array:
    """``M = exp(V^p) V^-p / (2 p T)`` at ``max(V, V_floor)`` (docs/paper_notes.md, error 4)."""
    Vp = np.maximum(V, V_floor) ** p
    return np.exp(Vp) / (Vp * (2.0 * p * T))


class Filter:
    """Dynamic-surface filter (eq. dSd), exact exponential update with ``M3`` frozen over a step."""

    def __init__(self, p: float, T3: float, V_floor: float) -> None:
        self.p, self.T3, self.V_floor = p, T3, V_floor
        self.S_d: Array | None = None

    def update(self, alpha: Array, dt: float) -> tuple[Array, Array, Array]:
        if self.S_d is None:
            self.S_d = alpha.copy()
        S_d = self.S_d
        H_d = S_d - alpha
        V3 = 0.5 * dot(H_d, H_d)
        rate = -np.expm1(-predefined_time_gain(V3, self.p, self.T3, self.V_floor) * dt) / dt
        S_d_dot = -rate[:, None] * H_d
        self.S_d = S_d + dt * S_d_dot
        return S_d, S_d_dot, V3


def actuator(u: Array, max_torque: float, min_torque: float) -> tuple[Array, Array]:
    """Per-axis saturation and minimum-output deadband: produced torque, saturation flags."""
    torque = np.clip(u, -max_torque, max_torque)
    return np.where(np.abs(u) < min_torque, 0.0, torque), np.abs(u) > max_torque


def ftppf(cfg: BlfppcConfig, t: float) -> tuple[float, float]:
    """BLFPPC's finite-time PF ``rho_0 (1 - t/T_f)^(1/m) + rho_Tf`` and its slope (Appendix C)."""
    pf = cfg.ftppf
    if t >= pf.T_f_s:
        return pf.rho_Tf, 0.0
    inv_m, rho_0, frac = pf.m_even / pf.m_odd, pf.rho_initial - pf.rho_Tf, 1.0 - max(t, 0.0) / pf.T_f_s
    return rho_0 * frac**inv_m + pf.rho_Tf, -rho_0 * inv_m * frac ** (inv_m - 1.0) / pf.T_f_s


class OracleController:
    """One law (by the config's type) for a batch, ``step(tau, dt, ...)`` with ``tau`` the time
    since the run's start; returns a dict of the :class:`~sappc_controller.core.base.ControlOutput` fields."""

    def __init__(self, config: Any, q_BR0: Array, on_infeasible: str = "raise") -> None:
        self.cfg = config
        self.J = np.asarray(config.inertia_kg_m2, dtype=float)
        q_ev0 = np.atleast_2d(q_BR0)[:, :3]
        self.sign = np.where(q_ev0 >= 0.0, 1.0, -1.0)
        g = config.gains
        self.filter = Filter(g.p, g.T3_s, g.V_floor)
        if isinstance(config, SappcConfig):
            self.rpf = ReferencePerformanceFunction(config.rpf, q_ev0, on_infeasible=on_infeasible)

    def _transform(self, q_ev: Array, tau: float) -> tuple[Array, ...]:
        """eps, psi, eta, xi, rho, z, band lower, band upper (eq. dEpsilon: eps_dot = psi (e_dot + eta e) + xi)."""
        cfg = self.cfg
        if isinstance(cfg, SappcConfig):
            k = float(np.tan(np.radians(cfg.theta_deg)))
            rho, rho_dot = rpf_evaluate(self.rpf, tau)  # eq. RPF
            delta, delta_dot = constraint_bound(cfg.B0, rho, rho_dot)  # eq. delta_i
            z = q_ev / rho
            eps, offset = smetf(z, delta, k)  # eqs. Rs, solve
            P_s, d_eps_d_delta = smetf_derivatives(eps, offset, delta, k)  # eq. PS, paper_notes error 3
            return eps, P_s / rho, -rho_dot / rho, d_eps_d_delta * delta_dot, rho, z, rho - cfg.B0, rho + cfg.B0
        assert isinstance(cfg, TrappcConfig)
        pf, K, s = cfg.pf, cfg.K, self.sign
        decay = (pf.rho_0 - pf.rho_inf) * np.exp(-pf.l * tau)
        rho, rho_dot = decay + pf.rho_inf, -pf.l * decay
        z = q_ev / rho
        x = np.clip(s * z, -K + DOMAIN_MARGIN, 1.0 - DOMAIN_MARGIN)
        eps = s * np.log((K + x) / (K * (1.0 - x)))  # homeomorphic transformation (Appendix B)
        rho_b = np.full_like(z, rho)
        return (eps, (1.0 / (K + x) + 1.0 / (1.0 - x)) / rho, np.full_like(z, -rho_dot / rho), np.zeros_like(z), s * rho_b, z,
                np.where(s > 0, -K * rho_b, -rho_b), np.where(s > 0, rho_b, K * rho_b))

    def step(self, tau: float, dt: float, q_BN: Array, w: Array, q_RN: Array, w_d: Array, wdot_d: Array) -> dict[str, Array]:
        cfg, g, J = self.cfg, self.cfg.gains, self.J
        q_BR = error_quaternion(np.atleast_2d(q_RN), np.atleast_2d(q_BN))  # eq. errorsystem
        w = np.atleast_2d(w)
        Cw, Cwd = dcm_BR_times(q_BR, np.atleast_2d(w_d)), dcm_BR_times(q_BR, np.atleast_2d(wdot_d))
        w_e = w - Cw  # omega_e = omega_s - C_e omega_d
        q_ev = q_BR[:, :3]
        W0 = matvec(J, cross(w_e, Cw) - Cwd) - cross(w, matvec(J, w))  # after eq. U
        if isinstance(cfg, BlfppcConfig):
            f, f_dot = ftppf(cfg, tau)
            up = self.sign > 0
            rho_u, rho_l = np.where(up, f, 0.0), np.where(up, 0.0, -f)
            rho_u_dot, rho_l_dot = np.where(up, f_dot, 0.0), np.where(up, 0.0, -f_dot)
            width, P_lu = rho_u - rho_l, rho_l + rho_u
            eps = (2.0 * q_ev - P_lu) / width
            S_v = ((rho_u_dot - rho_l_dot) * q_ev + (rho_l_dot * rho_u - rho_u_dot * rho_l)) / width
            alpha = gamma_inverse_times(q_BR, -g.K1 * q_ev + 0.5 * g.K1 * P_lu + S_v, g.q0_floor)
            S_d, S_d_dot, V3 = self.filter.update(alpha, dt)
            z2 = w_e - S_d
            barrier = 1.0 - eps * eps
            barrier = np.where(np.abs(barrier) < BARRIER_MARGIN, np.copysign(BARRIER_MARGIN, barrier), barrier)
            Jz2 = matvec(J, z2)
            u = (-g.K2 * Jz2 - 2.0 * g.K3 * gamma_inverse_times(q_BR, eps / (barrier * width), g.q0_floor) - W0 + matvec(J, S_d_dot)
                 - g.D_m_Nm * np.tanh(z2 / g.mu_rad_s))
            V = np.stack((0.5 * dot(eps, eps), 0.5 * dot(z2, Jz2), V3), axis=1)
            diag = {"rho": np.where(up, rho_u, rho_l), "band_lower": rho_l, "band_upper": rho_u, "eps": eps, "z": q_ev}
        else:
            eps, psi, eta, _, rho, z, lo, hi = self._transform(q_ev, tau)
            V1 = 0.5 * dot(eps, eps)
            M_q = predefined_time_gain(V1, g.p, g.T1_s, g.V_floor)
            alpha = gamma_inverse_times(q_BR, -(g.K_q * M_q)[:, None] * eps / psi - eta * q_ev, g.q0_floor)  # eq. virtualcontrol
            S_d, S_d_dot, V3 = self.filter.update(alpha, dt)  # eq. dSd
            z2 = w_e - S_d
            Jz2 = matvec(J, z2)
            V2 = 0.5 * dot(z2, Jz2)
            M_w = predefined_time_gain(V2, g.p, g.T2_s, g.V_floor)
            u = -W0 + matvec(J, S_d_dot) - g.D_m_Nm * np.tanh(z2 / g.mu_rad_s) - (g.K_omega * M_w)[:, None] * Jz2  # eq. U
            V = np.stack((V1, V2, V3), axis=1)
            diag = {"rho": rho, "band_lower": lo, "band_upper": hi, "eps": eps, "z": z}
        torque, sat = actuator(u, cfg.actuator.max_torque_Nm, cfg.actuator.min_torque_Nm)
        return {"torque_B": torque, "torque_cmd_B": u, "saturated": sat, "q_BR": q_BR, "V": V, **diag}

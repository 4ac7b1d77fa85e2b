"""The controller laws' run arrays from their validated configs: the Python side of the compiled
laws (:mod:`.kernels`, which imports no config class).

:func:`kind_of` picks a law's kernel, :func:`pack_params` lays a config out as the kernels'
``prm`` rows, :func:`start_coef` makes the start checks and the per-run constants ``coef`` of a
run's first sample (the RPF's coefficients by Lambert W, which needs scipy: set-up work, never
per step).  The controller object (:mod:`.base`), the offline loop and campaigns all call these.
"""

from __future__ import annotations

import numpy as np

from gnc_common.validation import ConfigError
from sappc_controller.core.base import check_start
from sappc_controller.core.blfppc import BlfppcConfig
from sappc_controller.core.kernels import (
    ControllerArrays,
    C_A,
    C_A1,
    C_L,
    C_SIGN,
    C_T1,
    KIND_BLFPPC,
    KIND_MRP_FEEDBACK,
    KIND_SAPPC,
    KIND_TRAPPC,
    N_COEF,
    N_PARAMS,
    P_B0,
    P_DM,
    P_FT_INVM,
    P_FT_RHO0,
    P_FT_RHOTF,
    P_FT_TF,
    P_GINF,
    P_J,
    P_K1,
    P_K2,
    P_K3,
    P_KFUN,
    P_KQ,
    P_KW,
    P_MRP_INT_LIMIT,
    P_MRP_K,
    P_MRP_KI,
    P_MRP_P,
    P_MU,
    P_P,
    P_PF_L,
    P_PF_RHO0,
    P_PF_RHOINF,
    P_Q0FLOOR,
    P_RATE_WC,
    P_RHO_EINF,
    P_RPF_T2,
    P_T1,
    P_T2,
    P_T3,
    P_TANTH,
    P_TORQUE_WC,
    P_UMAX,
    P_UMIN,
    P_VFLOOR,
)
from sappc_controller.core.mrp_feedback import MrpFeedbackConfig
from sappc_controller.core.rpf import ReferencePerformanceFunction
from sappc_controller.core.sappc import SappcConfig
from sappc_controller.core.trappc import TrappcConfig

__all__ = ["kind_of", "pack_controller", "pack_params", "rpf_coef", "start_coef"]


def kind_of(config: object) -> int:
    """The kernel kind of a controller config."""
    if isinstance(config, SappcConfig):
        return KIND_SAPPC
    if isinstance(config, TrappcConfig):
        return KIND_TRAPPC
    if isinstance(config, BlfppcConfig):
        return KIND_BLFPPC
    if isinstance(config, MrpFeedbackConfig):
        return KIND_MRP_FEEDBACK
    raise ConfigError(f"no compiled kernel for {type(config).__name__}")


def pack_params(config: object, n_runs: int = 1, gains: dict[str, np.ndarray] | None = None) -> np.ndarray:
    """``prm`` rows for ``n_runs`` runs, shape (n_runs, N_PARAMS), from a validated config.

    ``gains`` optionally gives per-run values (N,) of ``K_q``, ``K_omega``, ``D_m_Nm``, ``mu_rad_s``
    (Monte Carlo gain dispersions, SAPPC and TraPPC; the config's gains may also hold such arrays).
    """
    prm = np.zeros((n_runs, N_PARAMS))
    g = config.gains  # type: ignore[attr-defined]
    J = np.asarray(config.inertia_kg_m2, dtype=np.float64)  # type: ignore[attr-defined]
    prm[:, P_UMAX] = config.actuator.max_torque_Nm  # type: ignore[attr-defined]
    prm[:, P_UMIN] = config.actuator.min_torque_Nm  # type: ignore[attr-defined]
    prm[:, P_J : P_J + 9] = J.reshape(-1)
    nf = config.noise_filter  # type: ignore[attr-defined]
    prm[:, P_RATE_WC] = 2.0 * np.pi * nf.rate_cutoff_hz  # cut-off as an angular frequency [rad/s]; 0: off
    prm[:, P_TORQUE_WC] = 2.0 * np.pi * nf.torque_cutoff_hz
    if isinstance(config, MrpFeedbackConfig):
        if gains:
            raise ConfigError(f"per-run gains {sorted(gains)} are for SAPPC and TraPPC, not the MRP feedback controller")
        prm[:, P_MRP_K], prm[:, P_MRP_P], prm[:, P_MRP_KI], prm[:, P_MRP_INT_LIMIT] = g.K_Nm, g.P_Nms, g.Ki_per_kg_m2, g.integralLimit_Nms
        return prm
    prm[:, P_P], prm[:, P_T3], prm[:, P_VFLOOR], prm[:, P_Q0FLOOR] = g.p, g.T3_s, g.V_floor, g.q0_floor
    prm[:, P_DM], prm[:, P_MU] = g.D_m_Nm, g.mu_rad_s
    if isinstance(config, BlfppcConfig):
        prm[:, P_K1], prm[:, P_K2], prm[:, P_K3] = g.K1, g.K2, g.K3
        pf = config.ftppf
        prm[:, P_FT_RHO0], prm[:, P_FT_RHOTF], prm[:, P_FT_TF] = pf.rho_initial, pf.rho_Tf, pf.T_f_s
        prm[:, P_FT_INVM] = pf.m_even / pf.m_odd
    else:
        prm[:, P_T1], prm[:, P_T2], prm[:, P_KQ], prm[:, P_KW] = g.T1_s, g.T2_s, g.K_q, g.K_omega
        if isinstance(config, SappcConfig):
            prm[:, P_B0] = config.B0
            prm[:, P_TANTH] = float(np.tan(np.radians(config.theta_deg)))
            prm[:, P_RHO_EINF], prm[:, P_GINF], prm[:, P_RPF_T2] = config.rpf.rho_einf, config.rpf.g_inf, config.rpf.t2_s
        elif isinstance(config, TrappcConfig):
            prm[:, P_KFUN] = config.K
            prm[:, P_PF_RHO0], prm[:, P_PF_RHOINF], prm[:, P_PF_L] = config.pf.rho_0, config.pf.rho_inf, config.pf.l
        else:
            raise ConfigError(f"no compiled kernel for {type(config).__name__}")
    for name, col in (("K_q", P_KQ), ("K_omega", P_KW), ("D_m_Nm", P_DM), ("mu_rad_s", P_MU)):
        if gains and name in gains:
            prm[:, col] = np.asarray(gains[name], dtype=np.float64)
    return prm


def rpf_coef(rpf: ReferencePerformanceFunction) -> np.ndarray:
    """``coef`` rows (N, N_COEF, 3) of an RPF set up for N runs: sign, ``t1``, ``a1``, ``l``, ``A``."""
    coef = np.zeros((rpf.sign.shape[0], N_COEF, 3))
    coef[:, C_SIGN], coef[:, C_T1], coef[:, C_A1], coef[:, C_L], coef[:, C_A] = rpf.sign, rpf.t1, rpf.a1, rpf.l, rpf.A
    return coef


def start_coef(config: object, q_BR0: np.ndarray, *, on_infeasible: str = "raise") -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Run constants ``coef`` (N, N_COEF, 3) from the first error quaternions ``q_BR0`` (N, 4), after
    the start checks: the 180 deg singularity (:func:`.base.check_start`, raising
    :class:`.base.SingularStartError`; every law, MRP feedback included, so that every law refuses the
    same starts), the funnel containing the initial error (TraPPC, BLFPPC: ``ConfigError``), the
    RPF feasibility (SAPPC; ``on_infeasible`` as in
    :class:`.rpf.ReferencePerformanceFunction`).  Also returns the RPF's ``flat`` and ``clamped`` flags.
    """
    q_BR0 = np.atleast_2d(np.asarray(q_BR0, dtype=np.float64))
    check_start(q_BR0)
    q_ev0 = q_BR0[:, :3]
    n = q_ev0.shape[0]
    flags = {"flat": np.zeros((n, 3), bool), "clamped": np.zeros((n, 3), bool)}
    if isinstance(config, SappcConfig):
        rpf = ReferencePerformanceFunction(config.rpf, q_ev0, on_infeasible=on_infeasible)
        return rpf_coef(rpf), {"flat": rpf.flat, "clamped": rpf.clamped}
    if isinstance(config, MrpFeedbackConfig):  # no performance function: no run constants
        return np.zeros((n, N_COEF, 3)), flags
    if isinstance(config, TrappcConfig):
        rho0, name, who = config.pf.rho_0, "pf.rho_0", "TraPPC"
    elif isinstance(config, BlfppcConfig):
        rho0, name, who = config.ftppf.rho_initial, "ftppf.rho_initial", "BLFPPC"
    else:
        raise ConfigError(f"no compiled kernel for {type(config).__name__}")
    worst = float(np.max(np.abs(q_ev0)))
    if worst >= rho0:
        raise ConfigError(f"{name} = {rho0!r} must exceed the largest initial error |q_ev,i(0)| = {worst:.6g}: {who} must start inside its funnel")
    coef = np.zeros((n, N_COEF, 3))
    coef[:, C_SIGN] = np.where(q_ev0 >= 0.0, 1.0, -1.0)  # sign of e(0); BLFPPC: the side of its funnel
    return coef, flags


def pack_controller(config: object, n_runs: int, *, stale_timeout_ns: int, input_bounds: np.ndarray,
                    gains: dict[str, np.ndarray] | None = None) -> ControllerArrays:
    """A batch's controller for the whole-run loop: the law's kind and ``prm`` rows
    (:func:`pack_params`, ``gains`` per run), the start constants to be set at each run's first
    valid sample (zeros), the watchdog's timeout [ns] and the input check's packed bounds."""
    return ControllerArrays(kind_of(config), np.ascontiguousarray(pack_params(config, n_runs, gains), dtype=np.float64),
                            np.zeros((n_runs, N_COEF, 3)), int(stale_timeout_ns), np.ascontiguousarray(input_bounds, dtype=np.float64))

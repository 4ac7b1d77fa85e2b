"""SAPPC: the backstepping controller of Sec. IV.F with the SMETF, RPF and time-varying constraint.

The law (eqs. virtualcontrol, U, dSd), with the SMETF ``eps`` (eqs. Rs, solve, PS), the RPF ``rho``
(eq. RPF) and ``psi = P_s / rho``, ``eta = -rho_dot / rho`` (eq. dEpsilon):

    alpha = Gamma^-1 [ -psi^-1 M_q K_q eps - eta q_ev ]                     (virtualcontrol)
    z2    = omega_e - S_d,   H_d = S_d - alpha                               (Step 2, 3)
    u     = -W0 + J dS_d/dt - D_m tanh(z2 / mu) - M_omega K_omega J z2       (U)
    dS_d/dt = -1/(2 p T3) exp(V3^p) V3^-p H_d                               (dSd)

is implemented once, compiled, in :mod:`.kernels` (``sappc_transform`` and ``backstepping_law``;
TraPPC, Appendix B, uses the same law with another error transformation).  This module holds the
validated configuration and the controller class.

docs/paper_notes.md, observation 7: with ``omega_e = z2 + H_d + alpha``, ``dV1/dt``
contains ``eps^T psi Gamma (z2 + H_d)``, which the paper's analysis drops and
the published law does not cancel.  The published law is implemented.
"""

from __future__ import annotations

from dataclasses import dataclass

from gnc_common.validation import ConfigError, check_positive, check_spd_inertia

from sappc_controller.core.base import AttitudeController
from sappc_controller.core.common import ActuatorConfig, NoiseFilterConfig
from sappc_controller.core.rpf import InfeasiblePolicy, RPFParameters

__all__ = ["BacksteppingGains", "SappcConfig", "SappcController"]


@dataclass(frozen=True)
class BacksteppingGains:
    """Gains of the backstepping law shared by SAPPC and TraPPC (Sec. IV.F).

    Attributes
    ----------
    K_q : float
        First-layer gain (``K_q``, eq. virtualcontrol).
    K_omega : float
        Second-layer gain (``K_omega``, eq. U).

    ``K_q``, ``K_omega``, ``D_m_Nm`` and ``mu_rad_s`` may also hold an (N,) array of per-run
    values for a batch (Monte Carlo gain dispersions); the other fields are scalars.
    p : float
        Predefined-time exponent ``p1 = p2 = p3 = p`` in (0, 1); the paper uses 0.1.
    T1_s, T2_s, T3_s : float
        Predefined-time parameters [s]; the paper uses 3, 3, 2.
    D_m_Nm : float
        Known bound of the disturbance norm (Assumption 2) [N m].
    mu_rad_s : float
        Smoothing width of ``tanh(z2 / mu)`` [rad/s] (Lemma 1; same for all axes).
    V_floor : float
        Floor of ``V`` in the predefined-time gains (docs/paper_notes.md, error 4), in (0, 1].
    q0_floor : float
        Floor of ``q_e0`` in ``Gamma^-1`` (docs/paper_notes.md, error 5), in (0, 1).
    """

    K_q: float
    K_omega: float
    D_m_Nm: float
    mu_rad_s: float
    p: float = 0.1
    T1_s: float = 3.0
    T2_s: float = 3.0
    T3_s: float = 2.0
    V_floor: float = 1e-12
    q0_floor: float = 1e-3

    def __post_init__(self) -> None:
        for name in ("K_q", "K_omega", "mu_rad_s", "T1_s", "T2_s", "T3_s", "V_floor", "q0_floor"):
            check_positive(f"gains.{name}", getattr(self, name))
        check_positive("gains.D_m_Nm", self.D_m_Nm, allow_zero=True)
        if not 0.0 < self.p < 1.0:
            raise ConfigError(f"gains.p must be in (0, 1), got {self.p!r}")
        if self.V_floor > 1.0:
            raise ConfigError(f"gains.V_floor must be in (0, 1] (the gain is decreasing only below V = 1), got {self.V_floor!r}")
        if self.q0_floor >= 1.0:
            raise ConfigError(f"gains.q0_floor must be in (0, 1), got {self.q0_floor!r}")
        if self.p * self.T3_s >= 1.0:
            raise ConfigError(
                f"gains.p * gains.T3_s must be < 1 (remark after M_a: M_a > 0 needs 1/(p T3) - 1 > 0), "
                f"got p = {self.p!r}, T3_s = {self.T3_s!r}"
            )


@dataclass(frozen=True)
class SappcConfig:
    """Validated configuration of the SAPPC controller.

    Attributes
    ----------
    inertia_kg_m2 : tuple of tuples
        Known inertia ``J`` (3x3, symmetric positive definite) [kg m^2].
    rpf : RPFParameters
        RPF design (Table 1).
    B0 : float
        Constraint constant of eq. (delta_i); the band is ``|q_ev,i - rho_i| < B0``.
    theta_deg : float
        Shear angle [deg] in (0, 90); the paper uses 10.
    gains : BacksteppingGains
    actuator : ActuatorConfig
    noise_filter : NoiseFilterConfig
        The filters of measurement noise in the control path (all off by default; docs/design/noise.md).
    """

    inertia_kg_m2: tuple[tuple[float, float, float], ...]
    rpf: RPFParameters
    B0: float
    gains: BacksteppingGains
    actuator: ActuatorConfig = ActuatorConfig()
    theta_deg: float = 10.0
    noise_filter: NoiseFilterConfig = NoiseFilterConfig()

    def __post_init__(self) -> None:
        check_spd_inertia("inertia_kg_m2", self.inertia_kg_m2)
        check_positive("B0", self.B0)
        if not 0.0 < self.theta_deg < 90.0:
            raise ConfigError(f"theta_deg must be in (0, 90), got {self.theta_deg!r}")


class SappcController(AttitudeController):
    """The SAPPC controller (Sec. IV) built from a :class:`SappcConfig`.

    Parameters
    ----------
    config : SappcConfig
    on_infeasible : InfeasiblePolicy or {"raise", "clamp"}
        RPF policy for infeasible components (see :mod:`.rpf`); ``"raise"``
        unless a Monte Carlo campaign asks otherwise.
    """

    config: SappcConfig

    def __init__(self, config: SappcConfig, *, on_infeasible: InfeasiblePolicy | str = InfeasiblePolicy.RAISE) -> None:
        super().__init__(config, on_infeasible=on_infeasible)

"""SAPPC: the backstepping controller of Sec. IV.F with the SMETF, RPF and time-varying constraint.

The law (eqs. virtualcontrol, U, dSd):

    alpha = Gamma^-1 [ -psi^-1 M_q K_q eps - eta q_ev ]                     (virtualcontrol)
    z2    = omega_e - S_d,   H_d = S_d - alpha                               (Step 2, 3)
    u     = -W0 + J dS_d/dt - D_m tanh(z2 / mu) - M_omega K_omega J z2       (U)
    dS_d/dt = -1/(2 p T3) exp(V3^p) V3^-p H_d                               (dSd)

``TraPPC`` (Appendix B) uses this same law with another error transformation,
so the law lives in :class:`BacksteppingPPC`, parameterised by an
:class:`ErrorTransformation`.

docs/paper_notes.md, observation 7: with ``omega_e = z2 + H_d + alpha``, ``dV1/dt``
contains ``eps^T psi Gamma (z2 + H_d)``, which the paper's analysis drops and
the published law does not cancel.  This module implements the published law.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gnc_common.attitude import dot, gamma_inverse_times
from gnc_common.validation import ConfigError, check_positive, check_spd_inertia

from sappc_controller.core.base import AttitudeController
from sappc_controller.core.common import ActuatorConfig, DynamicSurfaceFilter, ErrorState, predefined_time_gain, robust_term, w0_dynamics
from sappc_controller.core.rpf import InfeasiblePolicy, ReferencePerformanceFunction, RPFParameters, constraint_bound
from sappc_controller.core.smetf import smetf, smetf_derivatives

__all__ = [
    "BacksteppingGains",
    "BacksteppingPPC",
    "ErrorTransformation",
    "SappcConfig",
    "SappcController",
    "SappcTransformation",
    "Transformed",
]

Array = NDArray[np.float64]


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


class Transformed(NamedTuple):
    """Output of an error transformation for a batch, each (N, 3).

    ``eps_dot = psi (q_ev_dot + eta q_ev) + xi`` (eq. dEpsilon).
    """

    eps: Array
    psi: Array
    eta: Array
    xi: Array
    rho: Array
    z: Array
    band_lower: Array
    band_upper: Array


class ErrorTransformation(Protocol):
    """A performance function plus an error transformation (SAPPC's or TraPPC's)."""

    def start(self, q_ev0: Array) -> None:
        """Set the run up from the initial error vector part, (N, 3)."""

    def reset(self) -> None:
        """Forget the run."""

    def transform(self, q_ev: Array, tau: float) -> Transformed:
        """Transform ``q_ev`` at ``tau`` seconds into the run."""


class SappcTransformation:
    """RPF (eq. RPF) + time-varying constraint (eq. delta_i) + SMETF (eqs. Rs, solve, PS).

    Parameters
    ----------
    rpf : RPFParameters
    B0 : float
        Constraint constant: the band is ``|q_ev,i - rho_i| < B0``.
    theta_rad : float
        Shear angle in (0, pi/2).
    on_infeasible : InfeasiblePolicy or {"raise", "clamp"}
        Passed to :class:`ReferencePerformanceFunction`.
    """

    def __init__(self, rpf: RPFParameters, B0: float, theta_rad: float, *, on_infeasible: InfeasiblePolicy | str = InfeasiblePolicy.RAISE) -> None:
        self.rpf_params = rpf
        self.B0 = B0
        self.tan_theta = float(np.tan(theta_rad))
        self.on_infeasible = on_infeasible
        self.rpf: ReferencePerformanceFunction | None = None
        # (eps, P_s, z, d eps/d delta, delta) of the previous sample: warm start of the SMETF solver
        self._prev: tuple[Array, Array, Array, Array, Array] | None = None

    def start(self, q_ev0: Array) -> None:
        self.rpf = ReferencePerformanceFunction(self.rpf_params, q_ev0, on_infeasible=self.on_infeasible)
        self._prev = None

    def reset(self) -> None:
        self.rpf = None
        self._prev = None

    def transform(self, q_ev: Array, tau: float) -> Transformed:
        assert self.rpf is not None, "start() first"
        rho, rho_dot = self.rpf.evaluate(tau)  # eq. RPF
        delta, delta_dot = constraint_bound(self.B0, rho, rho_dot)  # eq. delta_i
        z = q_ev / rho  # z_qi = q_evi / rho_i
        # Warm start: first-order prediction from the previous sample (any guess is safe, see smetf).
        prev = self._prev
        guess = None if prev is None else prev[0] + prev[1] * (z - prev[2]) + prev[3] * (delta - prev[4])
        eps, z0_offset = smetf(z, delta, self.tan_theta, guess)  # eqs. Rs, solve, chosenfunction
        P_s, d_eps_d_delta = smetf_derivatives(eps, z0_offset, delta, self.tan_theta)  # eq. PS, docs/paper_notes.md, error 3
        self._prev = (eps, P_s, z, d_eps_d_delta, delta)
        return Transformed(
            eps=eps,
            psi=P_s / rho,  # psi_si = P_si / rho_i (eq. dEpsilon)
            eta=-rho_dot / rho,  # eta_si = -rho_dot_i / rho_i
            xi=d_eps_d_delta * delta_dot,  # xi_si = (d eps / d delta) delta_dot
            rho=rho,
            z=z,
            band_lower=rho - self.B0,
            band_upper=rho + self.B0,
        )


class BacksteppingPPC(AttitudeController):
    """The predefined-time backstepping law with dynamic-surface filter (Sec. IV.F).

    Parameters
    ----------
    inertia_kg_m2 : array_like
        Known inertia ``J``.
    transformation : ErrorTransformation
        Performance function and error transformation.
    gains : BacksteppingGains
    actuator : ActuatorConfig
    """

    def __init__(
        self,
        inertia_kg_m2: ArrayLike,
        transformation: ErrorTransformation,
        gains: BacksteppingGains,
        actuator: ActuatorConfig,
    ) -> None:
        super().__init__(inertia_kg_m2, actuator)
        self.transformation = transformation
        self.gains = gains
        self.filter = DynamicSurfaceFilter(p=gains.p, T3=gains.T3_s, V_floor=gains.V_floor)

    def _set_gains(self, gains: Any) -> None:
        self.gains = gains

    def _reset_law(self) -> None:
        self.transformation.reset()
        self.filter.reset()

    def _start(self, err: ErrorState) -> None:
        self.transformation.start(err.q_BR[:, :3])

    def _law(self, tau: float, dt: float, err: ErrorState) -> tuple[Array, dict[str, Array]]:
        g = self.gains
        q_ev = err.q_BR[:, :3]
        tr = self.transformation.transform(q_ev, tau)
        eps = tr.eps
        V1 = 0.5 * dot(eps, eps)  # V1 = z1^T z1 / 2, z1 = eps_q
        M_q = predefined_time_gain(V1, g.p, g.T1_s, g.V_floor)
        # eq. (virtualcontrol): alpha = Gamma^-1 [-psi^-1 M_q K_q eps - eta q_ev]
        alpha = gamma_inverse_times(err.q_BR, -(g.K_q * M_q)[:, None] * eps / tr.psi - tr.eta * q_ev, g.q0_floor)
        S_d, S_d_dot, V3 = self.filter.update(alpha, dt)  # eq. (dSd), exact exponential update
        z2 = err.omega_BR_B - S_d  # z2 = omega_e - S_d
        Jz2 = self.J_times(z2)
        V2 = 0.5 * dot(z2, Jz2)  # V2 = z2^T J z2 / 2
        M_w = predefined_time_gain(V2, g.p, g.T2_s, g.V_floor)
        # eq. (U): u = -W0 + J dS_d/dt - D_m tanh(z2/mu) - M_omega K_omega J z2
        u = -w0_dynamics(self.J_times, err) + self.J_times(S_d_dot) - robust_term(g.D_m_Nm, z2, g.mu_rad_s) - (g.K_omega * M_w)[:, None] * Jz2
        diag = {
            "rho": tr.rho,
            "band_lower": tr.band_lower,
            "band_upper": tr.band_upper,
            "eps": eps,
            "z": tr.z,
            "V": np.stack((V1, V2, V3), axis=1),
        }
        return u, diag


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
    """

    inertia_kg_m2: tuple[tuple[float, float, float], ...]
    rpf: RPFParameters
    B0: float
    gains: BacksteppingGains
    actuator: ActuatorConfig = ActuatorConfig()
    theta_deg: float = 10.0

    def __post_init__(self) -> None:
        check_spd_inertia("inertia_kg_m2", self.inertia_kg_m2)
        check_positive("B0", self.B0)
        if not 0.0 < self.theta_deg < 90.0:
            raise ConfigError(f"theta_deg must be in (0, 90), got {self.theta_deg!r}")


class SappcController(BacksteppingPPC):
    """The SAPPC controller (Sec. IV) built from a :class:`SappcConfig`.

    Parameters
    ----------
    config : SappcConfig
    on_infeasible : InfeasiblePolicy or {"raise", "clamp"}
        RPF policy for infeasible components (see :mod:`.rpf`); ``"raise"``
        unless a Monte Carlo campaign asks otherwise.
    """

    def __init__(self, config: SappcConfig, *, on_infeasible: InfeasiblePolicy | str = InfeasiblePolicy.RAISE) -> None:
        self.config = config
        super().__init__(
            config.inertia_kg_m2,
            SappcTransformation(config.rpf, config.B0, np.radians(config.theta_deg), on_infeasible=on_infeasible),
            config.gains,
            config.actuator,
        )

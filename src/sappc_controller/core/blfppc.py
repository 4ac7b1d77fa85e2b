"""BLFPPC benchmark (Appendix C): barrier-Lyapunov-function PPC with a finite-time performance function.

Finite-time performance function (FTPPF), with ``rho_0 = rho(0) - rho_Tf`` and
``m lambda = rho_0^m / T_f``:

    rho(t) = (rho_0^m - m lambda t)^(1/m) + rho_Tf = rho_0 (1 - t/T_f)^(1/m) + rho_Tf,   t < T_f
    rho(t) = rho_Tf,                                                                    t >= T_f

with ``m = a1/a2 in (0, 1)``, ``a1`` odd and ``a2`` even.  The paper sets the
FTPPF as the upper bound and ``rho_l = 0`` "to avoid overshooting"; for a
component whose initial error is negative the mirror image is used
(``rho_u = 0``, ``rho_l = -FTPPF``).

Law (Appendix C):

    eps   = (2 q_ev - (rho_u + rho_l)) / (rho_u - rho_l)                      (BLF-type transformation)
    alpha = Gamma^-1 [ -K1 q_ev + 1/2 K1 P_lu + S_v ]
    u     = -K2 J z2 - 2 K3 Gamma^-1 D_rho eps - W0 + J dS_d/dt - D_m tanh(z2 / mu)
    P_lu  = rho_l + rho_u,   S_b = rho_l' rho_u - rho_u' rho_l
    S_v   = diag(1 / (rho_u - rho_l)) [ diag(rho_u' - rho_l') q_ev + S_b ]
    D_rho = diag(1 / ((1 - eps_i^2)(rho_u - rho_l)))

``eps = 0`` at the middle of the funnel: the error is steered to
``(rho_u + rho_l) / 2``.  ``S_d`` comes from the same dynamic-surface filter as
SAPPC.  Implemented, compiled, in :mod:`.kernels` (``blfppc_law``); this module holds the
configuration and the controller class.

docs/paper_notes.md, observation 6: the term ``-2 K3 Gamma^-1 D_rho eps`` is meant to
cancel the cross term between the two backstepping layers; differentiating the
log-barrier gives ``Gamma^T`` there, not ``Gamma^-1``.  This module implements
the benchmark as the appendix writes it (``Gamma^-1``), because it is the
paper's benchmark.

Barrier guard: ``D_rho`` is infinite on the funnel boundary (``|eps| = 1``)
and changes sign outside it, the "wrong direction repulsive force" the paper
describes after the sudden fault.  The software must not emit NaN, so
``1 - eps^2`` is kept at least ``BARRIER_MARGIN`` away from zero, with its sign.
"""

from __future__ import annotations

from dataclasses import dataclass

from gnc_common.validation import ConfigError, check_positive, check_spd_inertia

from sappc_controller.core.base import AttitudeController
from sappc_controller.core.common import ActuatorConfig, NoiseFilterConfig
from sappc_controller.core.kernels import BARRIER_MARGIN

__all__ = ["BARRIER_MARGIN", "BlfppcConfig", "BlfppcController", "BlfppcGains", "FiniteTimePF"]



@dataclass(frozen=True)
class FiniteTimePF:
    """The FTPPF of Appendix C.

    Attributes
    ----------
    rho_initial : float
        ``rho(0)``; must exceed every ``|q_ev,i(0)|``.
    rho_Tf : float
        Terminal value, ``0 < rho_Tf < rho_initial``.
    T_f_s : float
        Settling time of the performance function [s].
    m_odd, m_even : int
        ``m = m_odd / m_even`` with ``m_odd`` a positive odd and ``m_even`` a positive even integer, ``m < 1``.
    """

    rho_initial: float
    rho_Tf: float
    T_f_s: float
    m_odd: int = 1
    m_even: int = 2

    def __post_init__(self) -> None:
        check_positive("ftppf.rho_initial", self.rho_initial)
        check_positive("ftppf.rho_Tf", self.rho_Tf)
        check_positive("ftppf.T_f_s", self.T_f_s)
        if not self.rho_Tf < self.rho_initial:
            raise ConfigError(f"ftppf.rho_Tf ({self.rho_Tf!r}) must be less than ftppf.rho_initial ({self.rho_initial!r})")
        if not (isinstance(self.m_odd, int) and self.m_odd > 0 and self.m_odd % 2 == 1):
            raise ConfigError(f"ftppf.m_odd must be a positive odd integer, got {self.m_odd!r}")
        if not (isinstance(self.m_even, int) and self.m_even > 0 and self.m_even % 2 == 0):
            raise ConfigError(f"ftppf.m_even must be a positive even integer, got {self.m_even!r}")
        if not self.m_odd < self.m_even:
            raise ConfigError(f"m = ftppf.m_odd / ftppf.m_even must be < 1, got {self.m_odd}/{self.m_even}")


@dataclass(frozen=True)
class BlfppcGains:
    """Gains of the BLFPPC law (Appendix C) and of its dynamic-surface filter.

    Attributes
    ----------
    K1, K2, K3 : float
        Diagonal gains ``K_1``, ``K_2``, ``K_3`` (equal on the three axes).
    D_m_Nm : float
        Disturbance bound [N m].
    mu_rad_s : float
        ``tanh`` width [rad/s].
    p, T3_s, V_floor : float
        Filter parameters, as in :class:`~.sappc.BacksteppingGains`.
    q0_floor : float
        Floor of ``q_e0`` in ``Gamma^-1``.
    """

    K1: float
    K2: float
    K3: float
    D_m_Nm: float
    mu_rad_s: float
    p: float = 0.1
    T3_s: float = 2.0
    V_floor: float = 1e-12
    q0_floor: float = 1e-3

    def __post_init__(self) -> None:
        for name in ("K1", "K2", "mu_rad_s", "T3_s", "V_floor", "q0_floor"):
            check_positive(f"gains.{name}", getattr(self, name))
        check_positive("gains.K3", self.K3, allow_zero=True)
        check_positive("gains.D_m_Nm", self.D_m_Nm, allow_zero=True)
        if not 0.0 < self.p < 1.0:
            raise ConfigError(f"gains.p must be in (0, 1), got {self.p!r}")
        if self.V_floor > 1.0 or self.q0_floor >= 1.0:
            raise ConfigError(f"gains.V_floor must be in (0, 1] and gains.q0_floor in (0, 1), got {self.V_floor!r}, {self.q0_floor!r}")


@dataclass(frozen=True)
class BlfppcConfig:
    """Validated configuration of the BLFPPC benchmark.

    Attributes
    ----------
    inertia_kg_m2 : 3x3 known inertia ``J`` [kg m^2].
    ftppf : FiniteTimePF
    gains : BlfppcGains
    actuator : ActuatorConfig
    noise_filter : NoiseFilterConfig
        The filters of measurement noise in the control path (all off by default; docs/design/noise.md).
    """

    inertia_kg_m2: tuple[tuple[float, float, float], ...]
    ftppf: FiniteTimePF
    gains: BlfppcGains
    actuator: ActuatorConfig = ActuatorConfig()
    noise_filter: NoiseFilterConfig = NoiseFilterConfig()

    def __post_init__(self) -> None:
        check_spd_inertia("inertia_kg_m2", self.inertia_kg_m2)


class BlfppcController(AttitudeController):
    """The BLFPPC benchmark controller of Appendix C."""

    config: BlfppcConfig

    def __init__(self, config: BlfppcConfig) -> None:
        super().__init__(config)

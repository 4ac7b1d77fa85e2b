"""TraPPC benchmark (Appendix B): traditional homeomorphic PPC with the SAPPC backstepping law.

Performance function: the usual exponential ``rho(t) = (rho_0 - rho_inf) exp(-l t) + rho_inf > 0``.
Error transformation (Table "Characteristic of Traditional PPC Error
Transformation", homeomorphic type, ``K = 0.3`` in the paper):

* initial error ``e(0) >= 0``: ``eps = ln((K + z) / (K (1 - z)))``, constraint ``-K rho < e < rho``;
* initial error ``e(0) < 0``:  ``eps = ln(K (1 + z) / (K - z))``,   constraint ``-rho < e < K rho``;

with ``z = e / rho``.  The second row is the first mirrored,
``eps_2(z) = -eps_1(-z)``, so with ``s = sign(e(0))``: ``eps = s f(s z)``,
``f(x) = ln((K + x) / (K (1 - x)))``, ``d eps / d z = f'(s z) = 1/(K + s z) + 1/(1 - s z)``.
``eps = 0`` at ``e = 0``: TraPPC drives the error to zero inside the funnel.
Appendix B: the virtual control, actual control and filter are those of SAPPC,
so ``psi = f'/rho``, ``eta = -rho_dot/rho`` and ``xi = 0`` feed the same backstepping law.
Implemented, compiled, in :mod:`.kernels` (``trappc_transform``, ``backstepping_law``); this
module holds the configuration and the controller class.

Singularity guard: the transformation is undefined once ``s z`` leaves
``(-K, 1)`` (the traditional PPC's singularity, Sec. IV.E).  The software must
not emit NaN, so ``s z`` is clipped to ``[-K + m, 1 - m]`` with
``m = DOMAIN_MARGIN``: outside the funnel the law acts as if the error sat just
inside the violated boundary (a large, finite, saturating command).
"""

from __future__ import annotations

from dataclasses import dataclass

from gnc_common.validation import ConfigError, check_positive, check_spd_inertia

from sappc_controller.core.base import AttitudeController
from sappc_controller.core.common import ActuatorConfig, NoiseFilterConfig
from sappc_controller.core.kernels import DOMAIN_MARGIN
from sappc_controller.core.sappc import BacksteppingGains

__all__ = ["DOMAIN_MARGIN", "ExponentialPF", "TrappcConfig", "TrappcController"]



@dataclass(frozen=True)
class ExponentialPF:
    """``rho(t) = (rho_0 - rho_inf) exp(-l t) + rho_inf``.

    Attributes
    ----------
    rho_0 : float
        Initial value; must exceed every ``|q_ev,i(0)|`` so the run starts inside the funnel.
    rho_inf : float
        Terminal value, ``0 < rho_inf < rho_0``.
    l : float
        Decay rate [1/s].
    """

    rho_0: float
    rho_inf: float
    l: float

    def __post_init__(self) -> None:
        check_positive("pf.rho_0", self.rho_0)
        check_positive("pf.rho_inf", self.rho_inf)
        check_positive("pf.l", self.l)
        if not self.rho_inf < self.rho_0:
            raise ConfigError(f"pf.rho_inf ({self.rho_inf!r}) must be less than pf.rho_0 ({self.rho_0!r})")


@dataclass(frozen=True)
class TrappcConfig:
    """Validated configuration of the TraPPC benchmark.

    Attributes
    ----------
    inertia_kg_m2 : 3x3 known inertia [kg m^2].
    pf : ExponentialPF
    K : float
        Asymmetry of the funnel, in (0, 1); the paper uses 0.3.
    gains : BacksteppingGains
        Same law as SAPPC (Appendix B).
    actuator : ActuatorConfig
    noise_filter : NoiseFilterConfig
        The filters of measurement noise in the control path (all off by default; docs/design/noise.md).
    """

    inertia_kg_m2: tuple[tuple[float, float, float], ...]
    pf: ExponentialPF
    gains: BacksteppingGains
    actuator: ActuatorConfig = ActuatorConfig()
    K: float = 0.3
    noise_filter: NoiseFilterConfig = NoiseFilterConfig()

    def __post_init__(self) -> None:
        check_spd_inertia("inertia_kg_m2", self.inertia_kg_m2)
        if not 0.0 < self.K < 1.0:
            raise ConfigError(f"K must be in (0, 1), got {self.K!r}")


class TrappcController(AttitudeController):
    """The TraPPC benchmark controller built from a :class:`TrappcConfig`."""

    config: TrappcConfig

    def __init__(self, config: TrappcConfig) -> None:
        super().__init__(config)

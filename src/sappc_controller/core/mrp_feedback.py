"""MRP feedback: the law of Basilisk's ``mrpFeedback`` flight module, as a fourth controller.

Schaub & Junkins, *Analytical Mechanics of Space Systems*, Example 8.14 (nonlinear MRP tracking
feedback with an integral measure of the attitude error), as Basilisk's
``src/fswAlgorithms/attControl/mrpFeedback/mrpFeedback.c`` implements it.  With
``omega = omega_BN_B``, ``dw = omega_BR_B``, ``omega_r = omega_RN_B`` and ``domega_r = domega_RN_B``
(body components), the torque to apply is ``u = -L_r`` with

    L_r = K sigma_BR + P dw + P Ki z - (omega_r + Ki z) x (J omega) + J (omega x omega_r - domega_r)

and the integral measure ``z = K int(sigma_BR) dt + J dw`` while ``Ki > 0`` (``z = 0`` otherwise).
``int(sigma_BR) dt`` is accumulated once per call as ``int_sigma += K h sigma_BR``, ``h`` the time
since the previous call (``h = 0`` at a run's first call, as ``mrpFeedback`` does with its prior
call time); here ``h`` is the step's ``dt``, the control period the node, the offline loop and
campaigns all pass.  Each component of ``int_sigma`` is scaled back to ``integralLimit`` when it
exceeds it, its sign kept.  Basilisk's output message ``cmdTorqueOutMsg.torqueRequestBody`` is
``-L_r``, the torque to apply: it is this controller's commanded torque, before the actuator model
(:class:`.common.ActuatorConfig`) as for the other laws.  Implemented, compiled, in
:mod:`.kernels` (``mrp_feedback_law``); this module holds the configuration and the controller class.

The reference, from the quaternions every law takes: ``q_BR = q_RN^* ⊗ q_BN`` with ``q_BR0 >= 0``
(the project's error quaternion), then ``sigma_BR = q_BR,v / (1 + q_BR0)``.  With ``q_BR0 >= 0``
``|sigma_BR| <= 1``: this is the short-rotation set that Basilisk's guidance (``attTrackingError``,
whose ``subMRP`` switches to the shadow set when ``|sigma| > 1``) feeds ``mrpFeedback``, so no
switch is needed after the conversion (the two sets meet at 180 deg, ``|sigma_BR| = 1``).
``omega_BR_B = omega_BN_B - C_BR omega_RN_R``, ``omega_RN_B = C_BR omega_RN_R`` and
``domega_RN_B = C_BR omegadot_RN_R`` (``omega_RN`` has the same derivative seen from R and from N).

What this project leaves out of ``mrpFeedback``, and why:

* the reaction-wheel terms (``rwParamsInMsg``, ``rwSpeedsInMsg``: the wheels' momentum ``G_s h_s``
  in the gyroscopic term): the controllers of this project receive no wheel speeds (the contract's
  inputs are the attitude, the body rate and the reference), so the gyroscopic term uses
  ``J omega`` alone, as ``mrpFeedback`` does when no wheel message is connected;
* ``knownTorquePntB_B``: no known external torque is modelled (Basilisk's default, zero);
* ``controlLawType = 1`` (``omega_BN_B`` in place of ``omega_r + Ki z`` in the gyroscopic term):
  only Basilisk's default law, ``controlLawType = 0``, is provided.

``Ki``: ``mrpFeedback`` turns the integral on for ``Ki > 0`` and off otherwise (its default is
-1).  Parameters here are non-negative (:mod:`sappc_controller.params`), so ``Ki = 0`` turns it
off; the compiled law keeps Basilisk's test ``Ki > 0``.

Units (dimensional analysis of the law; Basilisk's header comments give other units):
``K`` multiplies the dimensionless MRP, so N m; ``P`` a rate, N m s; ``z`` is a momentum, N m s
(kg m^2 rad/s), and ``Ki z`` is added to a rate, so ``Ki`` is in 1/(kg m^2); ``integralLimit``
bounds ``K int(sigma) dt``, N m s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from gnc_common.validation import ConfigError, check_positive, check_spd_inertia

from sappc_controller.core.base import AttitudeController
from sappc_controller.core.common import ActuatorConfig, NoiseFilterConfig

__all__ = ["MrpFeedbackConfig", "MrpFeedbackController", "MrpFeedbackGains"]


@dataclass(frozen=True)
class MrpFeedbackGains:
    """Gains of the MRP feedback law (Basilisk's ``mrpFeedback`` names, units in the names).

    Attributes
    ----------
    K_Nm : float
        Proportional gain on the MRP error ``sigma_BR``, ``mrpFeedback.K`` (> 0) [N m].
    P_Nms : float
        Rate-error gain on ``omega_BR_B``, ``mrpFeedback.P`` (> 0) [N m s].
    integralLimit_Nms : float
        Per-component bound of ``K int(sigma_BR) dt``, ``mrpFeedback.integralLimit`` (> 0); used
        only while ``Ki > 0``.  Required: its scale is the disturbance's (``P Ki int_sigma`` balances
        it at rest), which no default knows [N m s].
    Ki_per_kg_m2 : float
        Integral feedback gain, ``mrpFeedback.Ki``; 0, the default, turns the integral term off
        (Basilisk: any ``Ki <= 0``, its default -1) [1/(kg m^2)].
    """

    K_Nm: float
    P_Nms: float
    integralLimit_Nms: float
    Ki_per_kg_m2: float = 0.0

    def __post_init__(self) -> None:
        check_positive("gains.K_Nm", self.K_Nm)
        check_positive("gains.P_Nms", self.P_Nms)
        try:
            check_positive("gains.Ki_per_kg_m2", self.Ki_per_kg_m2, allow_zero=True)
        except ConfigError as exc:
            raise ConfigError(f"{exc} (0 turns the integral term off, as Basilisk's Ki <= 0 does)") from None
        check_positive("gains.integralLimit_Nms", self.integralLimit_Nms)


@dataclass(frozen=True)
class MrpFeedbackConfig:
    """Validated configuration of the MRP feedback controller.

    Attributes
    ----------
    inertia_kg_m2 : 3x3 known inertia ``J`` (Basilisk's ``VehicleConfigMsg.ISCPntB_B``) [kg m^2].
    gains : MrpFeedbackGains
    actuator : ActuatorConfig
    noise_filter : NoiseFilterConfig
        The filters of measurement noise in the control path (all off by default; docs/design/noise.md).
    """

    inertia_kg_m2: tuple[tuple[float, float, float], ...]
    gains: MrpFeedbackGains
    actuator: ActuatorConfig = ActuatorConfig()
    noise_filter: NoiseFilterConfig = NoiseFilterConfig()

    def __post_init__(self) -> None:
        check_spd_inertia("inertia_kg_m2", self.inertia_kg_m2)


class MrpFeedbackController(AttitudeController):
    """The MRP feedback controller built from a :class:`MrpFeedbackConfig`."""

    config: MrpFeedbackConfig

    def __init__(self, config: MrpFeedbackConfig) -> None:
        super().__init__(config)


def hold_and_safe_params(inertia_kg_m2: ArrayLike, gains: MrpFeedbackGains, actuator: ActuatorConfig) -> tuple[np.ndarray, np.ndarray]:
    """The parameter rows of the flight modes' HOLD and SAFE laws (docs/design/modes.md): this law
    with ``gains``, the spacecraft's inertia [kg m^2] and actuator; SAFE the same with no attitude
    gain (``K = 0``: the attitude is not trusted, the rate alone is damped).  The offline loop's
    (:class:`~sappc_modes.core.packing.ModeArrays`) and the controller node's
    (:class:`sappc_controller.modes.ModeLaws`) one packing."""
    from sappc_controller.core.kernels import P_MRP_K
    from sappc_controller.core.packing import pack_params

    J = tuple(map(tuple, np.asarray(inertia_kg_m2, dtype=np.float64).tolist()))
    hold = pack_params(MrpFeedbackConfig(J, gains, actuator), 1)[0]
    safe = hold.copy()
    safe[P_MRP_K] = 0.0
    return hold, safe


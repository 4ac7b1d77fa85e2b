"""Configuration shared by the three controllers: the actuator model's limits.

The actuator model itself (per-axis saturation, minimum-output deadband) is part of the compiled
law, :func:`.kernels.actuator`.
"""

from __future__ import annotations

from dataclasses import dataclass

from gnc_common.validation import ConfigError, check_positive

__all__ = ["ActuatorConfig"]


@dataclass(frozen=True)
class ActuatorConfig:
    """Per-axis actuator limits (paper Sec. V: 0.5 N m maximum, 0.005 N m minimum).

    Attributes
    ----------
    max_torque_Nm : float
        Per-axis saturation: commands are clipped to ``[-max, max]``.
    min_torque_Nm : float
        Smallest producible magnitude: commands with ``|u_i| < min`` give 0
        (docs/paper_notes.md reading of "minimum output"); 0 disables it.
    """

    max_torque_Nm: float = 0.5
    min_torque_Nm: float = 0.005

    def __post_init__(self) -> None:
        check_positive("actuator.max_torque_Nm", self.max_torque_Nm)
        check_positive("actuator.min_torque_Nm", self.min_torque_Nm, allow_zero=True)
        if self.min_torque_Nm >= self.max_torque_Nm:
            raise ConfigError(
                f"actuator.min_torque_Nm ({self.min_torque_Nm!r}) must be less than "
                f"actuator.max_torque_Nm ({self.max_torque_Nm!r})"
            )

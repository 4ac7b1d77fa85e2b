"""Configuration shared by the four controllers: the actuator model's limits and the treatment of
measurement noise in the control path.

The actuator model itself (per-axis saturation, minimum-output deadband) and the noise filters
are part of the compiled law, :func:`.kernels.actuator` and :func:`.kernels.controller_step`.
"""

from __future__ import annotations

from dataclasses import dataclass

from gnc_common.validation import ConfigError, check_positive

__all__ = ["ActuatorConfig", "NoiseFilterConfig"]


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


@dataclass(frozen=True)
class NoiseFilterConfig:
    """First-order low-pass filters in the control path (issue 34; docs/design/noise.md).

    Each is ``y[k] = y[k-1] + (1 - exp(-2 pi f_c dt)) (x[k] - y[k-1])``, the continuous filter
    ``dy/dt = 2 pi f_c (x - y)`` sampled exactly (matched pole), started at its first input; ``dt``
    is each step's own period.  0, the default, turns a filter off: the law then runs exactly as
    without it, bit for bit (the paper's scenarios).

    Attributes
    ----------
    rate_cutoff_hz : float
        Cut-off of the filter on the measured (or estimated) body rate ``omega_BN_B`` before the
        law uses it; 0 turns it off [Hz].
    torque_cutoff_hz : float
        Cut-off of the filter on the law's commanded torque, clipped to ``actuator.max_torque_Nm``
        before it is filtered (the filter never winds up beyond what the actuator delivers), ahead
        of the minimum-output deadband; the commanded torque the controller publishes stays the
        law's, the produced torque is the filtered one; 0 turns it off [Hz].
    """

    rate_cutoff_hz: float = 0.0
    torque_cutoff_hz: float = 0.0

    def __post_init__(self) -> None:
        for name in ("rate_cutoff_hz", "torque_cutoff_hz"):
            try:
                check_positive(f"noise_filter.{name}", getattr(self, name), allow_zero=True)
            except ConfigError as exc:
                raise ConfigError(f"{exc} (0 turns the filter off)") from None

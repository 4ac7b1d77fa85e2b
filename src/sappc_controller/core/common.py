"""Pieces shared by the three controllers: predefined-time gains, the dynamic-surface
filter, the dynamical terms ``W0``, the actuator model and the step inputs.

All arrays carry a leading batch axis of N runs: vectors are (N, 3), quaternions (N, 4).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from gnc_common.attitude import Linear3, cross, dcm_BR_times, dot, error_quaternion
from gnc_common.validation import ConfigError, check_positive

__all__ = [
    "ActuatorConfig",
    "DynamicSurfaceFilter",
    "ErrorState",
    "Actuator",
    "error_state",
    "predefined_time_gain",
    "robust_term",
    "w0_dynamics",
]

Array = NDArray[np.float64]


def predefined_time_gain(V: Array, p: float, T: float, V_floor: float) -> Array:
    """``M = exp(V^p) V^(-p) / (2 p T)`` (eqs. for M_q, M_omega and eq. dSd).

    ``M`` grows without bound as ``V -> 0`` and is undefined at ``V = 0``
    (docs/paper_notes.md, error 4).  A sampled controller evaluates it at
    ``max(V, V_floor)``: ``M`` is decreasing on ``(0, 1)`` (its derivative is
    ``p exp(V^p) V^(-p-1) (V^p - 1)``), so this caps the gain at
    ``M(V_floor)`` and leaves it unchanged for ``V >= V_floor``.

    Parameters
    ----------
    V : ndarray, shape (N,)
        Lyapunov value(s), ``>= 0``.
    p : float
        Exponent in (0, 1).
    T : float
        Predefined-time parameter [s].
    V_floor : float
        Regularisation floor, ``0 < V_floor <= 1``.
    """
    Vp = np.maximum(V, V_floor) ** p
    return np.exp(Vp) / (Vp * (2.0 * p * T))


@dataclass
class DynamicSurfaceFilter:
    """Dynamic-surface filter of the virtual control (eq. dSd), stable for any gain.

    Eq. (dSd) is ``dS_d/dt = -M3 H_d`` with ``H_d = S_d - alpha`` and
    ``M3 = exp(V3^p) V3^(-p) / (2 p T3)``, ``V3 = |H_d|^2 / 2``.  Forward Euler
    is unstable once ``M3 dt > 2``, which happens as ``H_d -> 0`` (docs/paper_notes.md
    error 4).  The update here freezes ``M3`` and ``alpha`` over one step and
    integrates exactly:

        S_d[k+1] = alpha[k] + exp(-M3 dt) (S_d[k] - alpha[k]),

    a contraction for every ``M3 >= 0`` and ``dt > 0``.  The derivative fed to the
    control law is the secant of that update,
    ``dS_d/dt = -(1 - exp(-M3 dt)) / dt * H_d``, whose gain is bounded by
    ``1 / dt`` and tends to eq. (dSd) as ``dt -> 0``.  The filter starts at the
    first virtual control (``H_d(0) = 0``).
    """

    p: float
    T3: float
    V_floor: float
    S_d: Array | None = field(default=None)

    def reset(self) -> None:
        self.S_d = None

    def update(self, alpha: Array, dt: float) -> tuple[Array, Array, Array]:
        """Advance one sampling period.

        Returns
        -------
        S_d : ndarray, shape (N, 3)
            Filter output for this step (before the update).
        S_d_dot : ndarray, shape (N, 3)
            Its derivative used by the control law.
        V3 : ndarray, shape (N,)
            ``|H_d|^2 / 2``.
        """
        if self.S_d is None:
            self.S_d = alpha.copy()
        S_d = self.S_d
        H_d = S_d - alpha
        V3 = 0.5 * dot(H_d, H_d)
        M3 = predefined_time_gain(V3, self.p, self.T3, self.V_floor)
        rate = -np.expm1(-M3 * dt) / dt
        S_d_dot = -rate[:, None] * H_d
        self.S_d = S_d + dt * S_d_dot
        return S_d, S_d_dot, V3



@dataclass(frozen=True)
class ErrorState:
    """Tracking error quantities of eq. (errorsystem) for a batch.

    Attributes
    ----------
    q_BR : (N, 4) error quaternion, scalar last, ``q0 >= 0``.
    omega_BR_B : (N, 3) error rate ``omega_e = omega_s - C_e omega_d`` [rad/s].
    omega_BN_B : (N, 3) body rate ``omega_s`` [rad/s].
    C_omega_d : (N, 3) ``C_e omega_d`` [rad/s].
    C_omegadot_d : (N, 3) ``C_e d(omega_d)/dt`` [rad/s^2].
    """

    q_BR: Array
    omega_BR_B: Array
    omega_BN_B: Array
    C_omega_d: Array
    C_omegadot_d: Array


def error_state(q_BN: Array, omega_BN_B: Array, q_RN: Array, omega_RN_R: Array, omegadot_RN_R: Array) -> ErrorState:
    """Build the error state of eq. (errorsystem) from measured and desired attitude and rate."""
    q_BR = error_quaternion(q_RN, q_BN)
    # C_e applied to omega_d and omegadot_d in one broadcast call: (N, 1, 4) x (N or 1, 2, 3)
    C_both = dcm_BR_times(q_BR[:, None, :], np.stack((omega_RN_R, omegadot_RN_R), axis=-2))
    C_omega_d = C_both[:, 0]
    return ErrorState(
        q_BR=q_BR,
        omega_BR_B=omega_BN_B - C_omega_d,
        omega_BN_B=omega_BN_B,
        C_omega_d=C_omega_d,
        C_omegadot_d=C_both[:, 1],
    )


def w0_dynamics(J_times: Linear3, err: ErrorState) -> Array:
    """``W0 = J omega_e^x C_e omega_d - J C_e omegadot_d - omega_s^x J omega_s`` (after eq. U).

    ``J_times`` applies the known inertia ``J`` (shared or per run).
    """
    return J_times(cross(err.omega_BR_B, err.C_omega_d) - err.C_omegadot_d) - cross(err.omega_BN_B, J_times(err.omega_BN_B))


def per_run(value: float | Array) -> float | Array:
    """A gain as a scalar, or its (N,) per-run values as an (N, 1) column for (N, 3) arrays."""
    return np.reshape(value, (-1, 1)) if np.ndim(value) else value


def robust_term(D_m: float | Array, z2: Array, mu: float | Array) -> Array:
    """``D_m vec(tanh(z2_i / mu_i))`` (eq. U, Lemma 1); ``D_m`` and ``mu`` scalar or per run."""
    return per_run(D_m) * np.tanh(z2 / per_run(mu))


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


class Actuator:
    """Applies :class:`ActuatorConfig` to commanded torques."""

    def __init__(self, config: ActuatorConfig) -> None:
        self.config = config

    def apply(self, torque_cmd_B: Array) -> tuple[Array, NDArray[np.bool_]]:
        """Return the produced torque and a per-axis saturation flag, both (N, 3)."""
        c = self.config
        magnitude = np.abs(torque_cmd_B)
        torque = np.minimum(np.maximum(torque_cmd_B, -c.max_torque_Nm), c.max_torque_Nm)
        return np.where(magnitude < c.min_torque_Nm, 0.0, torque), magnitude > c.max_torque_Nm

"""The controller interface shared by SAPPC, TraPPC and BLFPPC.

A controller never reads a clock: time ``t`` [s] and the sampling period
``dt`` [s] are arguments of :meth:`AttitudeController.step`.  Inputs are
checked there, once; the laws behind it work on clean (N, ...) arrays.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gnc_common.attitude import Linear3, dot
from gnc_common.validation import QUATERNION_NORM_TOL, ConfigError, InputError, as_finite_array, check_unit_quaternion

from sappc_controller.core.common import Actuator, ActuatorConfig, ErrorState, error_state

__all__ = ["AttitudeController", "ControlOutput", "SINGULAR_Q0_AT_START", "SingularStartError", "check_start"]

Array = NDArray[np.float64]

#: A run may not *start* with an error scalar part below this: the paper's
#: Jacobian is singular at q_e0 = 0 (180 deg error, SPEC_NOTES error 5) and the
#: RPF sign and the virtual control are undefined there.  1e-6 is 179.9998 deg.
SINGULAR_Q0_AT_START = 1e-6


def _valid_inputs(t: float, dt: float, *arrays: ArrayLike) -> tuple[float, float, Array, Array, Array, Array, Array] | None:
    """All step inputs as float64 arrays if every check passes, else ``None``.

    A fast path over all inputs at once (one finiteness test, one norm test per
    quaternion); on ``None`` the caller runs the per-input checks, which raise
    an :class:`InputError` naming the offending value.  ``t`` and ``dt`` are typed as
    :meth:`AttitudeController.step` declares them; anything else that arrives is caught here.
    """
    try:
        t_f, dt_f = float(t), float(dt)
        q, w, q_d, w_d, wdot_d = (np.asarray(a, dtype=np.float64) for a in arrays)
    except (TypeError, ValueError):
        return None
    if q.shape[-1:] != (4,) or q_d.shape[-1:] != (4,) or w.shape[-1:] != (3,) or w_d.shape[-1:] != (3,) or wdot_d.shape[-1:] != (3,):
        return None
    values = np.concatenate((q.ravel(), w.ravel(), q_d.ravel(), w_d.ravel(), wdot_d.ravel(), (t_f, dt_f)))
    if not (np.isfinite(values).all() and dt_f > 0.0):
        return None
    for quat in (q, q_d):
        if (np.abs(np.sqrt(dot(quat, quat)) - 1.0) > QUATERNION_NORM_TOL).any():
            return None
    return t_f, dt_f, q, w, q_d, w_d, wdot_d


@dataclass(frozen=True)
class ControlOutput:
    """One control step's result for a batch (leading axis N), or one run (no batch axis).

    Attributes
    ----------
    torque_B : torque produced by the actuator model [N m], body frame.
    torque_cmd_B : torque commanded by the law before the actuator model [N m].
    saturated : per-axis flag, ``|torque_cmd_B| > max_torque_Nm``.
    q_BR : error quaternion used (scalar last, ``q0 >= 0``).
    rho : performance / reference function value per component.
    band_lower, band_upper : constraint band on ``q_ev`` per component.
    eps : transformed error per component.
    z : ``q_ev / rho`` per component (BLFPPC: ``q_ev``).
    V : (…, 3) Lyapunov values ``V1, V2, V3`` of the backstepping layers.
    """

    torque_B: Array
    torque_cmd_B: Array
    saturated: NDArray[np.bool_]
    q_BR: Array
    rho: Array
    band_lower: Array
    band_upper: Array
    eps: Array
    z: Array
    V: Array

    def first(self) -> ControlOutput:
        """The same output with the batch axis removed (run 0)."""
        return ControlOutput(**{f.name: getattr(self, f.name)[0] for f in fields(self)})


class SingularStartError(InputError):
    """A run starts at the 180 deg singularity: ``q_e0 < SINGULAR_Q0_AT_START``.

    Attributes
    ----------
    q_e0 : float
        The run's initial error scalar part.
    run : int
        The run's index (along the batch axis, or a campaign's run number once the campaign names it).
    """

    def __init__(self, q_e0: float, run: int) -> None:
        self.q_e0, self.run = q_e0, run
        super().__init__(
            f"initial error quaternion scalar part q_e0 = {q_e0:.3g} (run {run}) is at the 180 deg singularity "
            f"of Gamma(q_e) (needs q_e0 >= {SINGULAR_Q0_AT_START}): the RPF sign and the virtual control are undefined"
        )

    def __reduce__(self) -> tuple[type[SingularStartError], tuple[float, int]]:  # crosses process boundaries (campaign workers)
        return SingularStartError, (self.q_e0, self.run)


def check_start(err: ErrorState) -> None:
    """Refuse a run that starts at the 180 deg singularity (``q_e0 < SINGULAR_Q0_AT_START``).

    Raises
    ------
    SingularStartError
        Naming the first such run of the batch (its index along the batch axis) and its ``q_e0``.
    """
    q0 = err.q_BR[:, 3]
    bad = q0 < SINGULAR_Q0_AT_START
    if np.any(bad):
        k = int(np.argmax(bad))
        raise SingularStartError(float(q0[k]), k)


class AttitudeController(ABC):
    """Base class: input checking, batching, actuator; subclasses implement the law.

    Parameters
    ----------
    inertia_kg_m2 : array_like, shape (3, 3) or (N, 3, 3)
        The known inertia ``J`` (Assumption 1), already checked SPD by the config.
    actuator : ActuatorConfig
        Actuator limits applied to the commanded torque.
    """

    def __init__(self, inertia_kg_m2: ArrayLike, actuator: ActuatorConfig) -> None:
        self.J: Array = np.asarray(inertia_kg_m2, dtype=np.float64)
        self.J_times = Linear3(self.J)  # v -> J v
        self.actuator = Actuator(actuator)
        self.t0: float | None = None
        self.n_runs: int | None = None

    #: The validated config of the controller's kind (a dataclass with ``gains`` and
    #: ``actuator``), set by each subclass's ``__init__``.
    config: Any

    #: Gain fields :meth:`reconfigure` may change during a run (the filter's p, T3_s and
    #: V_floor are part of its state; the performance functions fix the run's envelope).
    RUNTIME_GAINS = ("K_q", "K_omega", "K1", "K2", "K3", "D_m_Nm", "mu_rad_s", "q0_floor")

    def reconfigure(self, config: Any) -> None:
        """Take new gains and actuator limits during a run, all or nothing.

        ``config`` is a validated config of this controller's kind; it may differ from the
        current one only in ``gains`` fields listed in :data:`RUNTIME_GAINS` and in ``actuator``.

        Raises
        ------
        ConfigError
            Naming the first field that may not change during a run.
        """
        current = self.config
        if type(config) is not type(current):
            raise ConfigError(f"reconfigure needs a {type(current).__name__}, got {type(config).__name__}")
        for f in fields(current):
            if f.name in ("gains", "actuator"):
                continue
            if getattr(config, f.name) != getattr(current, f.name):
                raise ConfigError(f"{f.name} cannot change during a run (it defines the performance envelope); restart the controller")
        for f in fields(current.gains):
            if f.name not in self.RUNTIME_GAINS and getattr(config.gains, f.name) != getattr(current.gains, f.name):
                raise ConfigError(f"gains.{f.name} cannot change during a run (it is part of the filter's state); restart the controller")
        self.config = config
        self.actuator = Actuator(config.actuator)
        self._set_gains(config.gains)

    def _set_gains(self, gains: Any) -> None:
        """Use ``gains`` from the next step on (laws that read ``self.config.gains`` need nothing)."""

    def reset(self) -> None:
        """Forget the run: the next step starts a new one (RPF, filter, time origin)."""
        self.t0 = None
        self.n_runs = None
        self._reset_law()

    def step(
        self,
        t: float,
        dt: float,
        q_BN: ArrayLike,
        omega_BN_B: ArrayLike,
        q_RN: ArrayLike,
        omega_RN_R: ArrayLike,
        omegadot_RN_R: ArrayLike,
    ) -> ControlOutput:
        """Compute the torque for one sampling instant.

        Parameters
        ----------
        t : float
            Time [s]; the first call fixes the run's time origin.
        dt : float
            Sampling period [s] (> 0), used by the dynamic-surface filter.
        q_BN : array_like, (4,) or (N, 4)
            Measured attitude, unit quaternion, scalar last.
        omega_BN_B : array_like, (3,) or (N, 3)
            Measured body rate [rad/s].
        q_RN, omega_RN_R, omegadot_RN_R : array_like
            Desired attitude, rate [rad/s] and acceleration [rad/s^2] in the
            desired frame; shapes (4,)/(3,) are shared by the whole batch.

        Returns
        -------
        ControlOutput
            Without a batch axis when ``q_BN`` was a single quaternion.

        Raises
        ------
        InputError
            Naming the offending input (non-finite values, non-unit or zero
            quaternions, ``dt <= 0``, a batch size that changed, or a run that
            starts at the 180 deg singularity).
        """
        inputs = _valid_inputs(t, dt, q_BN, omega_BN_B, q_RN, omega_RN_R, omegadot_RN_R)
        if inputs is None:  # something is wrong: the detailed checks name it
            t_f = float(as_finite_array("t", t))
            dt_f = float(as_finite_array("dt", dt))
            if dt_f <= 0.0:
                raise InputError(f"dt must be > 0, got {dt!r}")
            inputs = (
                t_f,
                dt_f,
                check_unit_quaternion("q_BN", q_BN),
                as_finite_array("omega_BN_B", omega_BN_B, shape_tail=(3,)),
                check_unit_quaternion("q_RN", q_RN),
                as_finite_array("omega_RN_R", omega_RN_R, shape_tail=(3,)),
                as_finite_array("omegadot_RN_R", omegadot_RN_R, shape_tail=(3,)),
            )
        t_f, dt_f, q, w, q_d, w_d, wdot_d = inputs
        single = q.ndim == 1
        q2 = np.atleast_2d(q)
        err = error_state(q2, np.atleast_2d(w), np.atleast_2d(q_d), np.atleast_2d(w_d), np.atleast_2d(wdot_d))
        if self.n_runs is not None and q2.shape[0] != self.n_runs:
            raise InputError(f"q_BN has {q2.shape[0]} runs but this run started with {self.n_runs}; call reset() first")
        out = self.step_unchecked(t_f, dt_f, err)  # the start check is there, on every path
        if not (np.all(np.isfinite(out.torque_B)) and np.all(np.isfinite(out.torque_cmd_B))):
            raise FloatingPointError("controller produced a non-finite torque; refusing to output it")
        return out.first() if single else out

    def step_unchecked(self, t: float, dt: float, err: ErrorState) -> ControlOutput:
        """:meth:`step` for inputs already checked (the offline runner's hot path).

        The start of a run is checked here, not in :meth:`step`, so that every caller (the
        node, the offline runner, Monte Carlo, rerun) refuses the same starts with the same error.

        Raises
        ------
        InputError
            At the first step of a run, if a run starts at the 180 deg singularity (see
            :func:`check_start`); the controller then stays unstarted.
        """
        if self.t0 is None:
            check_start(err)
            self.t0 = t
            self.n_runs = err.q_BR.shape[0]
            self._start(err)
        torque_cmd, diag = self._law(t - self.t0, dt, err)
        torque, saturated = self.actuator.apply(torque_cmd)
        return ControlOutput(torque_B=torque, torque_cmd_B=torque_cmd, saturated=saturated, q_BR=err.q_BR, **diag)

    @staticmethod
    def error_state(q_BN: Array, omega_BN_B: Array, q_RN: Array, omega_RN_R: Array, omegadot_RN_R: Array) -> ErrorState:
        """The error state of eq. (errorsystem), for callers of :meth:`step_unchecked`."""
        return error_state(q_BN, omega_BN_B, q_RN, omega_RN_R, omegadot_RN_R)

    @abstractmethod
    def _reset_law(self) -> None:
        """Clear the law's internal state (filter, performance functions)."""

    @abstractmethod
    def _start(self, err: ErrorState) -> None:
        """Initialise the run from the first error state (RPF sign, magnitudes)."""

    @abstractmethod
    def _law(self, tau: float, dt: float, err: ErrorState) -> tuple[Array, dict[str, Array]]:
        """Commanded torque (N, 3) and diagnostics at ``tau`` seconds into the run."""

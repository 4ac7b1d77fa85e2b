"""The flight modes' laws of HOLD and SAFE for the controller node (issue 49): its torque outside TRACK.

The offline loop calls the same kernel on the same arrays
(:func:`sappc.offline.compiled_loop._run_one`, "Flight modes"); this class holds them for a node,
one sample at a time, so that a lockstep run's torque equals the offline run's, bit for bit:

- HOLD: Basilisk's MRP feedback (:func:`~sappc_controller.core.kernels.mrp_feedback_step`, the
  controller's step of ``KIND_MRP_FEEDBACK``, with the rows of :func:`~sappc_controller.core.mrp_feedback.hold_and_safe_params`)
  on the controller's input (the estimate) of a valid sample, towards the scenario's reference
  with its rates (``hold_on_reference``: an acquisition) or the attitude of HOLD's first valid
  sample at rest (an inertial hold);
- SAFE: the same law with no attitude gain on the gyro's rate alone (the attitude is not used);
- each entry into HOLD or SAFE restarts the law's state (and HOLD's attitude).

A sample without what its law needs (HOLD: no valid sample; SAFE: no gyro rate), or whose torque
is not finite, commands zero.  Pure: no ROS, no clock.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from sappc_controller.core.kernels import N_COEF, N_OUT, N_STATE, N_WORK, O_TORQUE, mrp_feedback_step
from sappc_controller.core.common import ActuatorConfig
from sappc_controller.core.mrp_feedback import MrpFeedbackGains, hold_and_safe_params
from sappc_modes.core.modes import HOLD, SAFE

__all__ = ["ModeLaws"]

Array = NDArray[np.float64]


class ModeLaws:
    """HOLD's and SAFE's MRP feedback for one spacecraft (module docstring).

    Parameters
    ----------
    inertia_kg_m2 : (3, 3) array
        The spacecraft's inertia (the controller's own).
    gains : MrpFeedbackGains
        HOLD's gains (``modes.hold_gains``); SAFE's are the same with ``K = 0``.
    actuator : ActuatorConfig
        The controller's actuator limits.
    hold_on_reference : bool
        HOLD points at the reference (``modes.hold_attitude: reference``), else holds its entry attitude.
    """

    def __init__(self, inertia_kg_m2: ArrayLike, gains: MrpFeedbackGains, actuator: ActuatorConfig, hold_on_reference: bool) -> None:
        self.hold_prm, self.safe_prm = hold_and_safe_params(np.asarray(inertia_kg_m2, dtype=np.float64), gains, actuator)
        self.hold_on_reference = bool(hold_on_reference)
        self._state = np.zeros(N_STATE)
        self._work = np.zeros((N_WORK, 4))
        self._out = np.zeros((N_OUT, 4))
        self._coef = np.zeros((N_COEF, 3))  # the MRP feedback law reads none
        self._q_hold = np.full(4, np.nan)
        self._q_unit = np.array([0.0, 0.0, 0.0, 1.0])
        self._zero3 = np.zeros(3)
        # the compiled step loaded now, not at the first sample of HOLD or SAFE: a direct call of the kernel is a
        # dispatch of its own (measured: the first HOLD sample of a separation through the graph took the plant's
        # 2 s lockstep timeout to answer), then the law afresh
        at_rest = (self._q_unit, self._zero3, self._q_unit, self._zero3, self._zero3)
        self.torque(HOLD, 0.0, 0.01, at_rest, None)
        self.torque(SAFE, 0.0, 0.01, None, self._zero3)
        self._out[:] = 0.0
        self._work[:] = 0.0
        self.enter()

    def enter(self) -> None:
        """An entry into HOLD or SAFE: the law's state afresh, HOLD's attitude taken at its next valid sample."""
        self._state[:] = 0.0
        self._q_hold[:] = np.nan

    def torque(self, mode: int, t_s: float, dt_s: float, inputs: tuple[Array, Array, Array, Array, Array] | None,
               gyro_rad_s: Array | None) -> list[float]:
        """The torque [N m] of sample ``t_s`` in ``mode`` (HOLD or SAFE; any other: zero):
        ``inputs`` the controller's five values of a valid sample (``q_BN, omega_BN_B, q_RN,
        omega_RN_R, omegadot_RN_R``; ``None``: not valid), ``gyro_rad_s`` the gyro's rate
        (``None``: none delivered)."""
        law = False
        if mode == HOLD and inputs is not None:
            q, w, q_r, w_r, wd_r = inputs
            if self.hold_on_reference:
                mrp_feedback_step(t_s, dt_s, q, w, q_r, w_r, wd_r, self.hold_prm, self._coef, self._state, self._work, self._out)
            else:
                if math.isnan(self._q_hold[0]):
                    self._q_hold[:] = q
                mrp_feedback_step(t_s, dt_s, q, w, self._q_hold, self._zero3, self._zero3, self.hold_prm, self._coef,
                                self._state, self._work, self._out)
            law = True
        elif mode == SAFE and gyro_rad_s is not None:
            mrp_feedback_step(t_s, dt_s, self._q_unit, gyro_rad_s, self._q_unit, self._zero3, self._zero3, self.safe_prm,
                            self._coef, self._state, self._work, self._out)
            law = True
        torque = self._out[O_TORQUE, :3].tolist()
        return torque if law and all(map(math.isfinite, torque)) else [0.0, 0.0, 0.0]

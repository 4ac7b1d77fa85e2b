"""The controller's input pairing: which inputs, of which stamps, make one control step.

Used by the controller node (:mod:`sappc_controller.node`) and by ``sappc rerun``
(:mod:`sappc.analysis.rerun`), so that a re-run pairs the recorded inputs exactly as the node
paired them when they arrived.  The pairing itself is the contract's
(:mod:`sappc_msgs_py.inputs`, shared with the estimator node); this module fixes the controller's
inputs and makes the one call of the core per sample.  Pure: no ROS, no clock; values are numpy
arrays already decoded and checked by the caller, stamps are integer nanoseconds.

The five inputs are :data:`~sappc_msgs_py.contract.CONTROLLER_INPUTS`, in the order of
``AttitudeController.step(t, dt, q, w, q_d, w_d, wdot_d)``.

``lockstep`` (:class:`LockstepPairing`)
    A sample is complete when the five inputs of one stamp have arrived; the step runs at that
    stamp.  An input that arrived but is invalid (a sensor's "no data": non-finite values, as
    REP 117 has for invalid ranges; a wrong frame or a non-unit quaternion) still counts as
    arrived (:meth:`LockstepPairing.add_invalid`): the sample completes without a step
    (``valid`` false), so the controller answers it at once instead of waiting for a timeout.
    At most :data:`MAX_PENDING` incomplete stamps wait for their other inputs; beyond that the
    oldest is dropped.
``realtime`` (:class:`RealtimePairing`)
    A sample is complete when the attitude and the rate of a new stamp (a frame of
    :mod:`sappc_msgs_py.timeline`) and the reference of the same stamp have arrived; the
    reference is held (the newest earlier one) when the one of that stamp arrived invalid, or
    had not arrived by the middle of the state's frame.  The step's time is counted from the
    first step's stamp (``origin_ns`` of :func:`step_sample`): a float of epoch seconds would lose
    0.2 us, and counted so, a real-time step on the inputs of a lockstep step computes the same
    torque, bit for bit.
"""

from __future__ import annotations

from gnc_common.validation import ConfigError, InputError
from sappc_msgs_py.contract import CONTROLLER_INPUTS, Topic
from sappc_msgs_py.inputs import MAX_PENDING, NS_PER_S, ControlSample, LockstepPairing, RealtimePairing

from sappc_controller.core.base import AttitudeController, ControlOutput

__all__ = [
    "INPUT_TOPICS",
    "MAX_PENDING",
    "NS_PER_S",
    "STEP_ERRORS",
    "ControlSample",
    "LockstepPairing",
    "RealtimePairing",
    "step_sample",
]

#: The five inputs of one control step, by topic, in the order of ``AttitudeController.step``.
INPUT_TOPICS: tuple[Topic, ...] = CONTROLLER_INPUTS
#: The errors with which the core refuses a step; the node then commands zero torque.
STEP_ERRORS = (InputError, FloatingPointError, ConfigError)


def step_sample(controller: AttitudeController, dt_s: float, sample: ControlSample, origin_ns: int = 0) -> ControlOutput:
    """One control step on ``sample``: ``controller.step((t_ns - origin_ns) / 1e9, dt_s, q, w, q_d, w_d, wdot_d)``.

    Parameters
    ----------
    controller : AttitudeController
        The controller core.
    dt_s : float
        Control period [s].
    sample : ControlSample
        The step's time and inputs.
    origin_ns : int
        The run's time origin [ns]: 0 in lockstep (the stamps are the run's time), the first
        step's stamp in real time (the stamps are epoch times).

    Raises
    ------
    InputError, FloatingPointError, ConfigError
        (:data:`STEP_ERRORS`) when the core refuses the step; the node then commands zero torque.
    """
    return controller.step((sample.t_ns - origin_ns) / NS_PER_S, dt_s, *sample.values)

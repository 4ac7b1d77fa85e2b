"""The controller's input pairing: which inputs, of which stamps, make one control step.

The one owner of this rule, used by the controller node (:mod:`sappc_controller.node`) and by
``sappc rerun`` (:mod:`sappc.analysis.rerun`), so that a re-run pairs the recorded inputs exactly
as the node paired them when they arrived.  Pure: no ROS, no clock; values are numpy arrays
already decoded and checked by the caller, stamps are integer nanoseconds.

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
    :mod:`sappc_msgs_py.timeline`) have arrived; the step runs at that stamp with the reference of
    the same stamp, else the newest earlier one.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from gnc_common.validation import ConfigError, InputError
from sappc_msgs_py.contract import CONTROLLER_INPUTS, Topic
from sappc_msgs_py.timeline import StampedWindow

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

Array = NDArray[np.float64]

#: Nanoseconds per second: stamps are integer nanoseconds, the core's time is float seconds.
NS_PER_S = 1_000_000_000
#: The five inputs of one control step, by topic, in the order of ``AttitudeController.step``.
INPUT_TOPICS: tuple[Topic, ...] = CONTROLLER_INPUTS
#: Largest number of stamps waiting for their other inputs (lockstep); older ones are dropped.
MAX_PENDING = 64
#: The errors with which the core refuses a step; the node then commands zero torque.
STEP_ERRORS = (InputError, FloatingPointError, ConfigError)


@dataclass(frozen=True)
class ControlSample:
    """One complete set of the controller's inputs and the time of the step they feed.

    Attributes
    ----------
    t_ns : int
        Controller time of the step [ns]: the state's stamp (lockstep: every input's).
    input_ns : tuple of int
        Header stamps of the inputs used [ns], in :data:`INPUT_TOPICS` order.
    values : tuple of ndarray
        The inputs in :data:`INPUT_TOPICS` order: ``q_BN`` (x, y, z, w), ``omega_BN_B``
        [rad/s], ``q_RN`` (x, y, z, w), ``omega_RN_R`` [rad/s], ``omegadot_RN_R`` [rad/s^2].
        Empty when the sample is not ``valid``.
    valid : bool
        Every input arrived valid (lockstep: ``False`` when one arrived invalid).
    """

    t_ns: int
    input_ns: tuple[int, ...]
    values: tuple[Array, ...]
    valid: bool = True

    @property
    def oldest_ns(self) -> int:
        """Stamp [ns] of the oldest input used."""
        return min(self.input_ns)

    @property
    def t_s(self) -> float:
        """Controller time of the step [s], as the core receives it (``t_ns / 1e9``)."""
        return self.t_ns / NS_PER_S


class LockstepPairing:
    """Lockstep pairing: the inputs of one stamp, gathered until all have arrived.

    Parameters
    ----------
    topics : sequence of Topic
        The inputs of a step, in step order (default :data:`INPUT_TOPICS`).
    max_pending : int
        Largest number of incomplete stamps kept (default :data:`MAX_PENDING`).
    """

    def __init__(self, topics: Sequence[Topic] = INPUT_TOPICS, max_pending: int = MAX_PENDING) -> None:
        self.topics = tuple(topics)
        self.max_pending = max_pending
        self._pending: dict[int, dict[str, Array | None]] = {}  # stamp [ns] -> topic name -> value (None: invalid)

    @property
    def pending(self) -> int:
        """Number of stamps waiting for their other inputs."""
        return len(self._pending)

    def add(self, topic_name: str, stamp_ns: int, value: Array | None) -> ControlSample | None:
        """Take one (checked) input, ``None`` when it arrived invalid; return the sample it completes, if any.

        Parameters
        ----------
        topic_name : str
            The input's topic (a name of :attr:`topics`).
        stamp_ns : int
            Its header stamp [ns].
        value : ndarray
            Its decoded value.

        Returns
        -------
        ControlSample or None
            The five inputs of ``stamp_ns``, stepped at ``stamp_ns``, when this input was the last
            one missing; else ``None`` (and the oldest incomplete stamp is dropped when more than
            :attr:`max_pending` wait).
        """
        entry = self._pending.setdefault(stamp_ns, {})
        entry[topic_name] = value
        if len(entry) == len(self.topics):
            del self._pending[stamp_ns]
            values = [entry[t.name] for t in self.topics]
            valid = [v for v in values if v is not None]
            if len(valid) < len(values):
                return ControlSample(stamp_ns, (stamp_ns,) * len(self.topics), (), valid=False)
            return ControlSample(stamp_ns, (stamp_ns,) * len(self.topics), tuple(valid))
        if len(self._pending) > self.max_pending:
            del self._pending[min(self._pending)]
        return None

    def add_invalid(self, topic_name: str, stamp_ns: int) -> ControlSample | None:
        """Take an input that arrived invalid; return the sample it completes (``valid`` false), if
        any (see :meth:`add`)."""
        return self.add(topic_name, stamp_ns, None)


class RealtimePairing:
    """Real-time pairing: a step on each fresh state, with the reference of the state's stamp.

    The state of frame ``f`` (attitude and rate stamped ``f dt``, :mod:`sappc_msgs_py.timeline`)
    makes a sample as soon as both have arrived, if it is newer than the last sample; each
    reference input is the one of the same stamp (published ahead, it is normally there), else
    the newest one stamped before it (held).  There is no sample until every reference topic has
    delivered one stamped at or before the state.  Whether the inputs are too old is the caller's
    decision (:attr:`ControlSample.oldest_ns`).

    Parameters
    ----------
    topics : sequence of Topic
        The inputs of a step, in step order (default :data:`INPUT_TOPICS`): the two state topics,
        then the reference topics.
    window : int
        Messages kept per topic (default :data:`MAX_PENDING`): the references published ahead, and
        state parts waiting for their other half.
    """

    #: The state topics come first in :data:`INPUT_TOPICS` (attitude, rate).
    N_STATE = 2

    def __init__(self, topics: Sequence[Topic] = INPUT_TOPICS, window: int = MAX_PENDING) -> None:
        self.topics = tuple(topics)
        self._state = LockstepPairing(self.topics[: self.N_STATE], window)
        self._windows: dict[str, StampedWindow[Array]] = {t.name: StampedWindow(window) for t in self.topics[self.N_STATE :]}
        self._last: dict[str, int] = {}  # topic name -> stamp [ns] of its latest message
        self.last_sample_ns: int | None = None  # stamp of the last sample made

    def last_ns(self, topic_name: str) -> int | None:
        """Stamp [ns] of the topic's latest input, ``None`` before the first."""
        return self._last.get(topic_name)

    def add(self, topic_name: str, stamp_ns: int, value: Array) -> ControlSample | None:
        """Take one (checked) input; return the sample it completes (a fresh state with a
        reference at or before its stamp), if any."""
        self._last[topic_name] = stamp_ns
        window = self._windows.get(topic_name)
        if window is not None:
            window.add(stamp_ns, value)
            return None
        state = self._state.add(topic_name, stamp_ns, value)
        if state is None or (self.last_sample_ns is not None and stamp_ns <= self.last_sample_ns):
            return None
        refs = [self._windows[t.name].at_or_before(stamp_ns) for t in self.topics[self.N_STATE :]]
        if any(r is None for r in refs):
            return None  # not started: no reference yet for this state
        self.last_sample_ns = stamp_ns
        held = [r for r in refs if r is not None]
        return ControlSample(stamp_ns, (*state.input_ns, *(r[0] for r in held)), (*state.values, *(r[1] for r in held)))


def step_sample(controller: AttitudeController, dt_s: float, sample: ControlSample) -> ControlOutput:
    """One control step on ``sample``: ``controller.step(t_ns / 1e9, dt_s, q, w, q_d, w_d, wdot_d)``.

    Parameters
    ----------
    controller : AttitudeController
        The controller core.
    dt_s : float
        Control period [s].
    sample : ControlSample
        The step's time and inputs.

    Raises
    ------
    InputError, FloatingPointError, ConfigError
        (:data:`STEP_ERRORS`) when the core refuses the step; the node then commands zero torque.
    """
    return controller.step(sample.t_s, dt_s, *sample.values)

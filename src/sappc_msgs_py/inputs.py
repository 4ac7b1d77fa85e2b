"""How a node that consumes the contract's stamped samples checks its inputs and pairs them.

One rule for every consumer of the loop's samples: the controller (:mod:`sappc_controller.node`,
five inputs: the state and the reference) and the estimator (:mod:`sappc_estimator.node`, two:
the measured state), and ``sappc rerun``, which re-pairs recorded inputs exactly as the node
paired them when they arrived.  Pure: no ROS, no clock (the callers pass stamps and times as
integer nanoseconds; values are numpy arrays already decoded).

Input checks (:func:`screen_input`: :func:`stamp_rejection`, then the node's decode, e.g.
:func:`decode_input`): a message with a wrong frame id, a
non-finite value or a zero or non-unit quaternion is ``"invalid"``; a stamp not after the last one
the node accepted (lockstep: the last sample it answered or computed; real time: the topic's
previous message) is ``"stamp_in_past"``; a stamp more than ``max_stamp_ahead_s`` ahead of the
node's time (lockstep: the latest ``/clock``; real time: the node's clock) is
``"stamp_too_far_ahead"`` (:data:`REJECT_REASONS`).  The contract's "no data" sample (NaN in
every value, :func:`~sappc_msgs_py.convert.no_data_msg`: a relay's dropped measurement, an
estimator's sample without an estimate) is no error: it arrived, without a value, and is counted
apart (:data:`NO_DATA`), never among the rejected messages.

``lockstep`` (:class:`LockstepPairing`)
    A sample is complete when every input of one stamp has arrived; the step runs at that
    stamp.  An input that arrived but is invalid (a sensor's "no data": non-finite values, as
    REP 117 has for invalid ranges; a wrong frame or a non-unit quaternion) still counts as
    arrived (:meth:`LockstepPairing.add_invalid`): the sample completes without a step
    (``valid`` false), so the node answers it at once instead of waiting for a timeout.
    At most :data:`MAX_PENDING` incomplete stamps wait for their other inputs; beyond that the
    oldest is dropped.
``realtime`` (:class:`RealtimePairing`)
    A sample is complete when the attitude and the rate of a new stamp (a frame of
    :mod:`sappc_msgs_py.timeline`) have arrived and each further input (the controller's
    reference) of the same stamp; a further input of that stamp that arrived invalid, or has not
    arrived by the caller's deadline, is replaced by the newest earlier one (held).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from gnc_common.validation import ConfigError, InputError, check_positive, check_unit_quaternion
from sappc_msgs_py.contract import CONTROLLER_INPUTS, Topic
from sappc_msgs_py.convert import cdr_stamp_ns, is_no_data_msg, quaternion_from_msg, vector3_from_msg
from sappc_msgs_py.timeline import StampedWindow
from sappc_msgs_py.wire import deserialize, take

__all__ = [
    "DEFAULT_MAX_STAMP_AHEAD_S",
    "MAX_PENDING",
    "NO_DATA",
    "NS_PER_S",
    "REJECT_REASONS",
    "WATCHDOG_RANGE_S",
    "ControlSample",
    "LockstepPairing",
    "RealtimePairing",
    "check_watchdog_seconds",
    "decode_input",
    "stamp_rejection",
]

Array = NDArray[np.float64]

#: Nanoseconds per second: stamps are integer nanoseconds, the cores' time is float seconds.
NS_PER_S = 1_000_000_000
#: Largest number of stamps waiting for their other inputs (lockstep); older ones are dropped.
MAX_PENDING = 64
#: Why an input is rejected (``rejected_by_reason`` keys of the nodes): a wrong frame id, a
#: non-finite value or a zero or non-unit quaternion; a stamp not after the last accepted one; a
#: stamp more than ``max_stamp_ahead_s`` ahead of the node's time.
REJECT_REASONS = ("invalid", "stamp_in_past", "stamp_too_far_ahead")
#: What :func:`screen_input` reports for the contract's "no data" sample (its ``no_data`` callback):
#: not a reason for rejection (not in :data:`REJECT_REASONS`), an input that says it has no value.
NO_DATA = "no_data"
#: Default ``max_stamp_ahead_s`` [s]: inputs stamped further ahead of the node's time are
#: rejected (a clock jump or a wrong stamp, not a late sample).
DEFAULT_MAX_STAMP_AHEAD_S = 1.0
#: Range of the nodes' watchdog times [s]: from one microsecond (below it the nanosecond stamps
#: cannot resolve the timeout) to an hour (an input older than an hour is never "fresh").
WATCHDOG_RANGE_S = (1e-6, 3600.0)


def check_watchdog_seconds(name: str, value: Any) -> float:
    """A watchdog time [s] checked: finite, within :data:`WATCHDOG_RANGE_S` (error names ``name``)."""
    seconds = float(check_positive(name, value))
    lo, hi = WATCHDOG_RANGE_S
    if not lo <= seconds <= hi:
        raise ConfigError(f"{name} must be within [{lo:g}, {hi:g}] s, got {value!r}")
    return seconds


def stamp_rejection(topic_name: str, stamp_ns: int, last_ns: int | None, now_ns: int | None, max_ahead_ns: int,
                    last_what: str) -> tuple[str, str] | None:
    """Why an input stamped ``stamp_ns`` is rejected, or ``None`` when its stamp is acceptable.

    Parameters
    ----------
    topic_name : str
        The input's topic (for the message).
    stamp_ns : int
        Its header stamp [ns].
    last_ns : int or None
        The stamp it must be after [ns] (``None``: none yet).
    now_ns : int or None
        The node's time [ns] (``None``: unknown yet, no "far ahead" check).
    max_ahead_ns : int
        Largest accepted ``stamp_ns - now_ns`` [ns].
    last_what : str
        What ``last_ns`` is, in words ("the last computed sample").

    Returns
    -------
    tuple of str or None
        ``(reason, message)``: ``reason`` one of :data:`REJECT_REASONS`.
    """
    if last_ns is not None and stamp_ns <= last_ns:
        return "stamp_in_past", (f"{topic_name}: stamp {stamp_ns / NS_PER_S:.9f} s is in the past (not after {last_what}, "
                                 f"{last_ns / NS_PER_S:.9f} s)")
    if now_ns is not None and stamp_ns > now_ns + max_ahead_ns:
        return "stamp_too_far_ahead", (f"{topic_name}: stamp {stamp_ns / NS_PER_S:.9f} s is more than {max_ahead_ns / NS_PER_S} s "
                                       f"ahead of the node's time {now_ns / NS_PER_S:.9f} s")
    return None


def screen_input(msg: bytes, topic: Topic, last_ns: int | None, now_ns: int | None, max_ahead_ns: int, last_what: str,
                 decode: Callable[[bytes, Topic], Array], reject: Callable[[str, str], None],
                 no_data: Callable[[str], None] | None = None) -> tuple[int, Array | None] | None:
    """The checks every consumer makes of one input message, received as CDR bytes (a
    subscription's ``raw=True``: :mod:`sappc_msgs_py.wire`), in this order: its stamp
    (:func:`stamp_rejection`; a rejected stamp drops the message: ``None``), then its value
    (``decode(msg, topic)``, e.g. :func:`decode_input`; an :class:`~gnc_common.validation.InputError`
    is rejected under its ``reason`` and the value is ``None``: in lockstep the input arrived,
    invalid).  ``reject(message, reason)`` is called for each rejection.  The contract's "no data"
    sample (:func:`~sappc_msgs_py.convert.is_no_data_msg`) is not rejected: ``no_data(message)`` is
    called instead (the caller counts it apart) and the value is ``None``, as for an invalid one
    (without ``no_data`` it is rejected as ``invalid``).

    Returns
    -------
    tuple or None
        ``(stamp_ns, value or None)``, or ``None`` for a dropped message.
    """
    stamp_ns = cdr_stamp_ns(topic.type_name, msg)
    if not ((last_ns is None or stamp_ns > last_ns) and (now_ns is None or stamp_ns <= now_ns + max_ahead_ns)):  # stamp_rejection's test
        rejection = stamp_rejection(topic.name, stamp_ns, last_ns, now_ns, max_ahead_ns, last_what)
        if rejection is not None:
            reject(rejection[1], rejection[0])
            return None
    try:
        return stamp_ns, decode(msg, topic)
    except InputError as exc:
        if no_data is not None and is_no_data_msg(deserialize(msg, topic), topic):
            no_data(f"{topic.name}: no data at {stamp_ns // NS_PER_S}.{stamp_ns % NS_PER_S:09d} s")
        else:
            reject(str(exc), exc.reason)
        return stamp_ns, None


def decode_input(msg: bytes, topic: Topic) -> Array:
    """The value of an input message of ``topic`` (CDR bytes, :func:`sappc_msgs_py.wire.take`): a
    ``QuaternionStamped``'s unit quaternion ``(x, y, z, w)``, a ``Vector3Stamped``'s vector.

    Raises
    ------
    InputError
        For a wrong frame id, a non-finite value, a zero or non-unit quaternion ("invalid").
    """
    if topic.type_name.endswith("QuaternionStamped"):
        return check_unit_quaternion(f"{topic.name} quaternion", np.asarray(take(msg, topic, lambda m: quaternion_from_msg(m, topic))))
    return np.asarray(take(msg, topic, lambda m: vector3_from_msg(m, topic)))


class ControlSample(NamedTuple):
    """One complete set of a node's inputs and the time of the step they feed (a sample of the
    control loop); immutable (a named tuple: one is made per sample, at a third of a frozen
    dataclass's cost).

    Attributes
    ----------
    t_ns : int
        Time of the step [ns]: the state's stamp (lockstep: every input's).
    input_ns : tuple of int
        Header stamps of the inputs used [ns], in the pairing's topic order.
    values : tuple of ndarray
        The inputs in the pairing's topic order (the controller's:
        :data:`~sappc_msgs_py.contract.CONTROLLER_INPUTS`, ``q_BN`` (x, y, z, w), ``omega_BN_B``
        [rad/s], ``q_RN``, ``omega_RN_R`` [rad/s], ``omegadot_RN_R`` [rad/s^2]).  Empty when the
        sample is not ``valid``.
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
        """Time of the step [s], as the cores receive it (``t_ns / 1e9``)."""
        return self.t_ns / NS_PER_S


class LockstepPairing:
    """Lockstep pairing: the inputs of one stamp, gathered until all have arrived.

    Parameters
    ----------
    topics : sequence of Topic
        The inputs of a step, in step order (default the controller's,
        :data:`~sappc_msgs_py.contract.CONTROLLER_INPUTS`).
    max_pending : int
        Largest number of incomplete stamps kept (default :data:`MAX_PENDING`).
    """

    def __init__(self, topics: Sequence[Topic] = CONTROLLER_INPUTS, max_pending: int = MAX_PENDING) -> None:
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
            Every input of ``stamp_ns``, stepped at ``stamp_ns``, when this input was the last one
            missing; else ``None`` (and the oldest incomplete stamp is dropped when more than
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
    """Real-time pairing: a step on each fresh state, with the further inputs of the state's own stamp.

    The state of frame ``f`` (attitude and rate stamped ``f dt``, :mod:`sappc_msgs_py.timeline`)
    is fresh once both have arrived, if it is newer than the last sample.  It makes a sample as
    soon as each further input (the controller's reference, published ahead, normally there
    already) has delivered the message of the same stamp, as in lockstep.  A further input whose
    message of that stamp arrived invalid (a dropped reference's "no data") is answered at once
    with the newest valid earlier one, held; one that has not arrived by the caller's deadline is
    held likewise (:meth:`take_held`: the controller calls it in the middle of the state's frame,
    so its torque still reaches the plant's next tick).  A newer fresh state replaces one still
    waiting.  There is no sample until every further topic has delivered one stamped at or before
    the state.  Whether the inputs are too old is the caller's decision
    (:attr:`ControlSample.oldest_ns`); which inputs were held, the sample's ``input_ns`` says.

    Parameters
    ----------
    topics : sequence of Topic
        The inputs of a step, in step order (default the controller's,
        :data:`~sappc_msgs_py.contract.CONTROLLER_INPUTS`): the two state topics first, then any
        further ones (none for the estimator).
    window : int
        Messages kept per topic (default :data:`MAX_PENDING`): the references published ahead, and
        state parts waiting for their other half.
    """

    #: The state topics come first in ``topics`` (attitude, rate).
    N_STATE = 2

    def __init__(self, topics: Sequence[Topic] = CONTROLLER_INPUTS, window: int = MAX_PENDING) -> None:
        self.topics = tuple(topics)
        self._state = LockstepPairing(self.topics[: self.N_STATE], window)
        self._windows: dict[str, StampedWindow[Array]] = {t.name: StampedWindow(window) for t in self.topics[self.N_STATE :]}
        self._invalid: dict[str, int] = {}  # further topic name -> stamp [ns] of its latest message that arrived invalid
        self._last: dict[str, int] = {}  # topic name -> stamp [ns] of its latest message
        self._waiting: ControlSample | None = None  # the fresh state waiting for a further input of its stamp
        self.last_sample_ns: int | None = None  # stamp of the last sample made

    def last_ns(self, topic_name: str) -> int | None:
        """Stamp [ns] of the topic's latest input, ``None`` before the first."""
        return self._last.get(topic_name)

    @property
    def waiting_ns(self) -> int | None:
        """Stamp [ns] of the fresh state waiting for a further input of its stamp, ``None`` when none waits."""
        return None if self._waiting is None else self._waiting.t_ns

    def add(self, topic_name: str, stamp_ns: int, value: Array | None) -> ControlSample | None:
        """Take one checked input (``value`` ``None``: it arrived invalid); return the sample it
        completes, if any (see the class docstring)."""
        self._last[topic_name] = stamp_ns
        window = self._windows.get(topic_name)
        if window is not None:
            if value is None:
                self._invalid[topic_name] = stamp_ns
            else:
                window.add(stamp_ns, value)
            return self._complete(hold=False)
        if value is None:
            return None  # a state part that arrived invalid makes no sample (the caller's watchdog covers its frame)
        state = self._state.add(topic_name, stamp_ns, value)
        if state is None or (self.last_sample_ns is not None and stamp_ns <= self.last_sample_ns):
            return None
        self._waiting = state
        return self._complete(hold=False)

    def take_held(self) -> ControlSample | None:
        """The waiting state's sample, each further input missing its stamp held (the newest one
        before it); ``None`` when no state waits, or a further topic has delivered nothing at or
        before its stamp yet (it keeps waiting)."""
        return self._complete(hold=True)

    def _complete(self, hold: bool) -> ControlSample | None:
        state = self._waiting
        if state is None:
            return None
        further: list[tuple[int, Array]] = []
        for t in self.topics[self.N_STATE :]:
            found = self._windows[t.name].at_or_before(state.t_ns)
            if found is None:
                return None  # not started: no further input at or before this state yet
            if found[0] != state.t_ns and not hold and self._invalid.get(t.name) != state.t_ns:
                return None  # its own stamp may still come
            further.append(found)
        self._waiting = None
        self.last_sample_ns = state.t_ns
        return ControlSample(state.t_ns, (*state.input_ns, *(f[0] for f in further)), (*state.values, *(f[1] for f in further)))

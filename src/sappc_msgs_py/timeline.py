"""The real-time frame grid: one time base shared by every node without talking to each other.

Flight software runs its control loop in fixed frames on one clock: the sensors are sampled at a
frame's start, the controller computes on them within the frame, the actuators apply its command
over the next frame.  In ``realtime`` mode the project's nodes do the same on the system clock
(the ROS clock without ``use_sim_time``), which every process of a host shares (hosts share it
through PTP or chrony):

- frame ``f`` starts at ``f * dt`` nanoseconds since the epoch (``dt`` in integer nanoseconds:
  :func:`period_ns`), so every node knows the grid without a handshake;
- each node's timer is phased to the grid (:meth:`~sappc_msgs_py.runtime.ProjectNode.create_frame_timer`):
  the plant at the frame's start (:data:`PLANT_PHASE`), the reference, the injector and the
  controller's watchdog in the middle of the frame (:data:`MID_FRAME_PHASE`), so a tick is
  never ambiguous about its frame (:func:`frame_index` takes the nearest, within half a frame);
- the plant stamps the state of frame ``f`` with the frame's start, not with the instant its
  timer happened to run; the reference and the disturbance are known in advance and published
  :data:`AHEAD_FRAMES` frames ahead, stamped with their frames; the controller computes as soon
  as a fresh state arrives, with the reference of the state's own stamp
  (:class:`StampedWindow`), and stamps the torque with it, as in lockstep; the plant applies it
  over the next frame and counts a frame whose torque is not the answer to the previous frame's
  state (a step that used a stale state).

Pure: no ROS, no clock (the callers pass the time).
"""

from __future__ import annotations

from collections import OrderedDict
from typing import Generic, TypeVar

from gnc_common.validation import ConfigError

__all__ = ["AHEAD_FRAMES", "MID_FRAME_PHASE", "PLANT_PHASE", "START_LEAD_FRAMES", "StampedWindow", "frame_index", "period_ns"]

T = TypeVar("T")

#: Phase of the plant's timer in its frame, as a fraction of the period: at the frame's start (the
#: timer runs a few tens of microseconds after it, the callback's dispatch).
PLANT_PHASE = 0.0
#: Phase of the timers of the nodes that publish ahead (reference, injector) and of the
#: controller's watchdog: half a frame from the plant's ticks, the farthest from them.
MID_FRAME_PHASE = 0.5
#: Frames the reference and the disturbance are published ahead of the current frame: the
#: sample of frame ``f`` is out ``AHEAD_FRAMES - 1/2`` frames before the plant's state of ``f``,
#: and the controller waits for the reference of a state's own stamp until the middle of the
#: state's frame, so a reference publisher's timer may stall for ``AHEAD_FRAMES`` frames (100 ms at
#: the paper's 100 Hz: the controller's stale-input timeout; Python timers on a loaded 2-vCPU VM
#: wake up to 20 ms late, docs/performance.md) before a step holds an older reference.  The
#: windows that keep them (the controller's, :data:`~sappc_msgs_py.inputs.MAX_PENDING` = 64, and
#: the plant's) hold more.
AHEAD_FRAMES = 10
#: Frames before its own frame ``f0`` that the plant publishes sample 0 (the initial state, which
#: holds until ``f0``): the reference and the injector learn ``f0`` from it and publish its inputs
#: ahead, and the controller answers it, all before the plant's first integration at ``f0 + 1``.
#: Without it the first frame's torque had one frame for three processes to wake in turn
#: (plant, reference, controller) and came late on a loaded machine.  The same margin as
#: :data:`AHEAD_FRAMES`.
START_LEAD_FRAMES = AHEAD_FRAMES


def period_ns(dt_s: float) -> int:
    """The frame period [ns] of ``dt_s`` seconds, rounded to the nanosecond (the grid ``f * dt``
    of integer nanoseconds does not drift; the plant integrates ``dt_s`` a frame, within 0.5 ns).

    Raises
    ------
    ConfigError
        When ``dt_s`` is not a finite period of at least 1 us.
    """
    if not (isinstance(dt_s, (int, float)) and dt_s >= 1e-6 and dt_s < float("inf")):
        raise ConfigError(f"control_period_s must be a finite period of at least 1 us, got {dt_s!r}")
    return int(round(dt_s * 1e9))


def frame_index(now_ns: int, dt_ns: int, phase: float) -> int:
    """The frame of a tick at ``now_ns`` of a timer phased at ``phase`` (a fraction of the frame):
    the frame whose tick instant ``f dt + phase dt`` is nearest (a tick late or early by less
    than half a frame keeps its frame)."""
    return (now_ns - round(phase * dt_ns) + dt_ns // 2) // dt_ns


class StampedWindow(Generic[T]):
    """The last ``size`` values of a topic by stamp, and the one that holds at a given stamp.

    Values published ahead of their time (the reference, the disturbance) wait here until the
    frame they belong to; :meth:`at_or_before` gives the value of a stamp, or, when its message
    has not arrived, the latest earlier one (the last value held).
    """

    def __init__(self, size: int) -> None:
        if size < 1:
            raise ValueError(f"size must be >= 1, got {size}")
        self.size = size
        self._values: OrderedDict[int, T] = OrderedDict()  # stamp [ns] -> value, in increasing stamp order

    def __len__(self) -> int:
        return len(self._values)

    def add(self, stamp_ns: int, value: T) -> None:
        """Keep ``value`` of ``stamp_ns`` (a stamp not after the newest replaces nothing and is dropped:
        the callers reject stamps in the past first); the oldest is forgotten beyond ``size``."""
        if self._values and stamp_ns <= next(reversed(self._values)):
            return
        self._values[stamp_ns] = value
        if len(self._values) > self.size:
            self._values.popitem(last=False)

    @property
    def newest_ns(self) -> int | None:
        """Stamp [ns] of the newest value, ``None`` when empty."""
        return next(reversed(self._values)) if self._values else None

    def at_or_before(self, stamp_ns: int) -> tuple[int, T] | None:
        """``(stamp, value)`` of the newest value stamped at or before ``stamp_ns``; ``None`` when none is."""
        for s in reversed(self._values):
            if s <= stamp_ns:
                return s, self._values[s]
        return None

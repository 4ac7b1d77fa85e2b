"""The disturbance and fault injector (``python -m spacecraft_sim.disturbance``).

Scheduled from a YAML file (parameter ``schedule_file``; a scenario file works: only its
``disturbances:`` and ``faults:`` lists are read, see :mod:`spacecraft_sim.core.disturbance` and
:mod:`spacecraft_sim.core.faults`):

- external torques: publishes ``disturbance/torque`` for every sample, the sum of the
  scheduled models at the sample time (``lockstep``: samples 0 and 1 as soon as its subscribers
  are matched, then on each ``/clock`` tick ``t_k`` sample ``k + 1``, one ahead so that it is
  never on the loop's critical path, and any earlier one a missed tick left out:
  :class:`~sappc_msgs_py.runtime.GridCursor`;
  ``realtime``: in the frames of :mod:`sappc_msgs_py.timeline`, sample ``k`` at ``t = k dt``
  stamped with frame ``f0 + k``, ``f0`` the frame of the plant's first ``state/attitude``
  (:class:`~sappc_msgs_py.runtime.FramesAhead`: published on that state up to
  :data:`~sappc_msgs_py.timeline.AHEAD_FRAMES` frames ahead, then by a timer in the middle of
  each frame); the plant applies each over its own frame; the fault windows are in the time
  since ``f0``).  The plant adds it to the control torque (``use_disturbance_topic``).
- faults, by relaying the contract's relayed topics
  (:data:`~sappc_msgs_py.contract.RELAYED_SENSOR_TOPICS`,
  :data:`~sappc_msgs_py.contract.RELAYED_REFERENCE_TOPICS`,
  :data:`~sappc_msgs_py.contract.RELAYED_ACTUATOR_TOPICS`) through
  :class:`~spacecraft_sim.core.faults.FaultSchedule`: with sensor faults it subscribes to
  ``state/attitude`` and ``state/rate``, pairs them by stamp and republishes the faulty
  measurement on ``fault/state/*`` (the controller is remapped to those; with an estimator, which
  reads the sensors' own topics, parameter ``relay_attitude_epoch``: ``sensors/gyro`` and
  ``state/attitude_epoch`` paired by stamp, with the quaternion of the ``sensors/star_tracker``
  sample the epoch names, relayed on ``fault/sensors/gyro`` and ``fault/state/attitude_epoch``, and
  the tracker's sample on ``fault/sensors/star_tracker``, stamped with its own epoch, when the
  relayed epoch is a new one: a frozen or delayed tracker sample is not sent again); with reference faults
  it does the same with the three reference topics (``fault/reference/*``); with actuator faults
  it relays ``control/torque`` to ``fault/control/torque`` (the plant is remapped to it).  A
  dropped measurement or reference is relayed as "no data" (non-finite values, its stamp), which
  the controller takes no value from (counting it apart from the messages it rejects) but answers at once; a dropped command is answered with the last
  delivered torque, with the dropped command's stamp (the actuator holds it; the plant does not
  wait for a command that will never come).

Parameters: :data:`PARAMETERS` (``python -m spacecraft_sim.disturbance --help``), and those of
:class:`~sappc_msgs_py.runtime.ProjectNode`.
"""

from __future__ import annotations

import sys
from collections import deque
from functools import partial
from typing import Any

import numpy as np

from sappc_msgs_py.contract import (
    CLOCK,
    DISTURBANCE_TORQUE,
    RELAYED_ACTUATOR_TOPICS,
    RELAYED_PATHS,
    RELAYED_SENSOR_TOPICS,
    RELAYED_SENSOR_TOPICS_FOR_ESTIMATOR,
    SENSOR_GYRO,
    SENSOR_STAR_TRACKER,
    Topic,
    faulty,
    qos_profile,
)
from sappc_msgs_py import wire
from sappc_msgs_py.convert import (
    cdr_stamp_ns,
    epoch_from_msg,
    epoch_msg,
    gyro_from_msg,
    gyro_msg,
    no_data_msg,
    ns_to_stamp,
    quaternion_from_msg,
    quaternion_msg,
    stamp_to_ns,
    star_tracker_from_msg,
    star_tracker_msg,
    time_to_ns,
    torque_from_msg,
    torque_msg,
    vector3_from_msg,
    vector3_msg,
)
from sappc_msgs_py.parameters import Param
from sappc_msgs_py.runtime import LOCKSTEP, MODE, FramesAhead, GridCursor, ProjectNode, StartGate, run_node, unmatched

from spacecraft_sim.core.disturbance import DisturbanceSum, disturbances_from_list
from spacecraft_sim.core.faults import FaultSchedule, faults_from_list
from gnc_common.validation import ConfigError, InputError, check_positive, read_yaml_file

__all__ = ["InjectorNode", "PARAMETERS", "load_schedule", "main"]

#: Samples of disturbance computed at once [samples]: one compiled call per block, not one per
#: sample (10 us each); the torque of each sample is the same bits either way (the kernel computes
#: every sample on its own, at its own ``k dt``).
DISTURBANCE_BLOCK = 1024

#: The injector's parameters (``--help``), in the order the node declares them.
PARAMETERS = (
    Param("schedule_file", "", "YAML file with 'disturbances:' and/or 'faults:' lists (a scenario file works); '' for none: zero "
          "disturbance, no fault"),
    MODE,
    Param("control_period_s", 0.01, "sample period dt of the plant's grid k dt", "s", check="> 0"),
    Param("duration_s", 0.0, "end of the grid: no disturbance sample after duration_s (0: no end)", "s", check=">= 0"),
    Param("relay_attitude_epoch", False, "relay the sensors' own topics (sensors/gyro, state/attitude_epoch, sensors/star_tracker) "
          "instead of state/*: an estimator reads them (a frozen or delayed tracker sample keeps its own epoch; the plant must "
          "publish them, i.e. have sensor models)"),
)
_P = {p.name: p for p in PARAMETERS}


def _relayed_msg(topic: Topic, value: Any, stamp: Any) -> Any:
    """The relay's message for ``topic`` (its :func:`faulty` twin) carrying ``value``, or "no data"
    when ``value`` is ``None``: a dropped measurement or reference is relayed as the contract's "no
    data" sample (:func:`~sappc_msgs_py.convert.no_data_msg`: a message of its stamp whose values
    are all NaN, the convention of REP 117 for invalid ranges).  The controller takes no value
    from it (it counts it as an input without data, not as a rejected message) but knows the sample is complete, so it answers at once (held torque, or zero once
    stale) rather than after a timeout, and lockstep stays deterministic."""
    out = faulty(topic)
    if value is None:
        return no_data_msg(out, stamp)
    if topic.type_name.endswith("TimeReference"):
        return epoch_msg(int(value), stamp, out)
    if topic.type_name.endswith("Imu"):  # value: (the measurement, the original's covariance diagonal)
        encode = star_tracker_msg if topic is SENSOR_STAR_TRACKER else gyro_msg
        return encode(value[0], value[1], stamp, out)
    return quaternion_msg(value, stamp, out) if _is_quaternion(topic) else vector3_msg(value, stamp, out)


def _is_quaternion(topic: Topic) -> bool:
    return topic.type_name.endswith("QuaternionStamped")


def load_schedule(path: str) -> tuple[DisturbanceSum, FaultSchedule]:
    """The disturbances and faults of a schedule (or scenario) file."""
    if not path:
        return DisturbanceSum(()), FaultSchedule(())
    try:
        data = read_yaml_file(path, "schedule")
    except ConfigError as exc:  # it cannot be read, or is not YAML: the message names the file
        raise ConfigError(f"schedule_file: {exc}") from None
    if not isinstance(data, dict):
        raise ConfigError(f"schedule_file {path!r} must hold a mapping with 'disturbances' and/or 'faults'")
    return disturbances_from_list(data.get("disturbances")), FaultSchedule(faults_from_list(data.get("faults")))


class InjectorNode(ProjectNode):
    """See the module docstring."""

    PARAMETERS = PARAMETERS
    COMMAND = "python -m spacecraft_sim.disturbance"

    def __init__(self, node_name: str = "injector", **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.disturbance, self.faults = load_schedule(str(self.param(_P["schedule_file"])))
        self.disturbance.torque_B(np.array([0.0]), 1)  # load the compiled models now, not at the first sample
        self.faults.warm_up()  # (the plant waits lockstep_timeout_s for the first torque, a compile is longer)
        self.mode = self.mode_param()
        self.dt = check_positive("control_period_s", self.param(_P["control_period_s"]))
        duration = check_positive("duration_s", self.param(_P["duration_s"]), allow_zero=True)
        self.last_k = int(round(duration / self.dt)) if duration > 0 else None  # the grid's last sample
        self.rejected = 0
        qos = qos_profile()
        self.pub_d = self.counting_publisher(DISTURBANCE_TORQUE, 1)
        self._wire_d = wire.codec(DISTURBANCE_TORQUE)  # published as CDR bytes (sappc_msgs_py.wire)
        self._table: tuple[int, list[int], list[bytes]] = (0, [], [])  # samples lo, lo + 1, ... (a block): stamps, messages
        self.frames: FramesAhead | None = None
        if self.mode == LOCKSTEP:
            self._cursor = GridCursor(self.last_k)
            self.create_subscription(CLOCK.msg_class, CLOCK.name, self._on_clock, qos, raw=True)
            self.start_when(lambda: unmatched([self.pub_d]), lambda: self._publish_through(1))
        else:  # sample k on the plant's frame f0 + k, f0 its first state's (FramesAhead)
            gate = StartGate(self, lambda: unmatched([self.pub_d]))  # no publish may block a callback
            self.frames = FramesAhead(self, self.dt, self.last_k, gate.open,
                                      lambda k, ns: self._publish_disturbance(k, ns))
        # the paired paths: the measurements (q_BN, omega_BN_B) and the reference, each paired by stamp
        self._paired: dict[tuple[Topic, ...], dict[int, dict[str, Any]]] = {}  # path -> stamp [ns] -> topic name -> value
        self.pub_relay: dict[str, Any] = {}
        # the measurements, with the tracker's epoch when an estimator reads them
        self._sensor_path = RELAYED_SENSOR_TOPICS_FOR_ESTIMATOR if bool(self.param(_P["relay_attitude_epoch"])) else RELAYED_SENSOR_TOPICS
        self._epoch_origin_ns: int | None = None  # epochs go through the fault kernels relative to the first one (exact in a float)
        # the estimator's path: the plant's tracker samples by stamp (q_BN, covariance diagonal), the
        # latest epoch relayed, and the samples waiting, in order, for the tracker sample their epoch names
        self._tracker: dict[int, tuple[Any, Any]] = {}
        self._relayed_epoch_ns: int | None = None
        self._waiting: deque[tuple[Any, int, Any]] = deque()
        for path, topics in RELAYED_PATHS.items():
            if not self.faults.acts_on(path):
                continue
            if topics is RELAYED_SENSOR_TOPICS:
                topics = self._sensor_path
            for t in topics:
                self.pub_relay[t.name] = self.counting_publisher(faulty(t), 1)
                handler = (self._on_command if topics is RELAYED_ACTUATOR_TOPICS else self._on_tracker if t is SENSOR_STAR_TRACKER
                           else partial(self._on_paired, path=topics[:2] if topics is RELAYED_SENSOR_TOPICS_FOR_ESTIMATOR else topics))
                self.create_subscription(t.msg_class, t.name, partial(handler, topic=t), qos)
            if topics is RELAYED_SENSOR_TOPICS_FOR_ESTIMATOR:
                self._paired[topics[:2]] = {}
            elif topics is not RELAYED_ACTUATOR_TOPICS:
                self._paired[topics] = {}

    def _publish_disturbance(self, k: int, stamp_ns: int) -> None:
        """Publish sample ``k``'s disturbance (at ``t = k dt``), stamped ``stamp_ns``."""
        lo, stamps, messages = self._table
        i = k - lo
        if not (0 <= i < len(stamps) and stamps[i] == stamp_ns):  # the next block of samples, at once
            self._table = lo, stamps, messages = self._encode_block(k, stamp_ns)
            i = 0
        self.pub_d.publish(messages[i])

    def _encode_block(self, k: int, stamp_ns: int) -> tuple[int, list[int], list[bytes]]:
        """Samples ``k ..`` (:data:`DISTURBANCE_BLOCK`, to the grid's end) computed (one compiled call,
        not one a sample) and encoded (:meth:`~sappc_msgs_py.wire.Codec.encode_block`), sample ``k``
        stamped ``stamp_ns``, the others as the node will ask for them: on the plant's grid in
        lockstep (``k dt``, as ``sample_times``), the frames after ``k``'s in real time.  A sample
        asked for with another stamp starts a new block (``_publish_disturbance`` checks)."""
        n = DISTURBANCE_BLOCK if self.last_k is None else max(1, min(DISTURBANCE_BLOCK, self.last_k + 1 - k))
        torque = self.disturbance.torque_B(np.arange(k, k + n) * self.dt, 1)[:, 0]
        if self.frames is None:
            stamps = [time_to_ns(j * self.dt) for j in range(k, k + n)]
        else:
            stamps = [stamp_ns + (j - k) * self.frames.dt_ns for j in range(k, k + n)]
        stamps[0] = stamp_ns
        return k, stamps, self._wire_d.encode_block(stamps, torque)

    def _on_clock(self, raw: bytes) -> None:
        self._publish_through(round(cdr_stamp_ns(CLOCK.type_name, raw) / 1e9 / self.dt) + 1)  # one sample ahead

    def _publish_through(self, k: int) -> None:
        for j in self._cursor.through(k):
            self._publish_disturbance(j, time_to_ns(j * self.dt))  # on the plant's grid (k dt, as sample_times)

    def _run_time_s(self, stamp_ns: int) -> float:
        """The run's time [s] of a stamp, which the fault windows are in: the stamp itself in
        lockstep (the plant's clock starts at 0), the time since sample 0's frame in real time.
        Every relayed stream starts at the plant's first frame (the plant waits for this node's
        subscriptions), so the first relayed message the node sees also starts the run, should
        it come before the plant's first state reaches :attr:`frames`."""
        if self.frames is None:
            return stamp_ns / 1e9
        self.frames.start_at(stamp_ns)
        t = self.frames.run_time_s(stamp_ns)
        assert t is not None  # started above
        return t

    def _reject(self, exc: Exception) -> None:
        self.rejected += 1
        self.get_logger().warning(f"rejected a message ({self.rejected} so far): {exc}")

    def _on_paired(self, msg: Any, topic: Topic, path: tuple[Topic, ...]) -> None:
        """A measurement or reference message: relayed (faulty) once its path's sample is complete."""
        try:
            if topic.type_name.endswith("TimeReference"):
                value: Any = epoch_from_msg(msg, topic)
            elif topic is SENSOR_GYRO:
                value = (gyro_from_msg(msg, topic), np.diag(np.reshape(msg.angular_velocity_covariance, (3, 3))))
            else:
                value = quaternion_from_msg(msg, topic) if _is_quaternion(topic) else vector3_from_msg(msg, topic)
        except InputError as exc:
            self._reject(exc)
            return
        ns = stamp_to_ns(msg.header.stamp)
        pending = self._paired[path]
        entry = pending.setdefault(ns, {})
        entry[topic.name] = value
        if len(entry) < len(path):
            return
        del pending[ns]
        for old in [k for k in pending if k < ns]:  # an unpaired older sample will never pair
            del pending[old]
        arrived: tuple[Any, ...] = tuple(entry[t.name] for t in path)
        values: tuple[Any, ...] | None = arrived
        if path[0] is SENSOR_GYRO:
            self._waiting.append((msg.header.stamp, ns, arrived))
            self._relay_sensors()
            return
        if path is self._sensor_path:
            faulted = self.faults.sensor(self._run_time_s(ns), ns, arrived[0], arrived[1])
            values = None if faulted is None else faulted[:2]
        elif not self.faults.reference(self._run_time_s(ns)):
            values = None
        for t, value in zip(path, values or [None] * len(path)):
            self.pub_relay[t.name].publish(_relayed_msg(t, value, msg.header.stamp))

    def _on_tracker(self, msg: Any, topic: Topic) -> None:
        """A tracker sample of the plant (stamped when measured): kept until the samples whose epoch
        names it have been relayed."""
        try:
            q = star_tracker_from_msg(msg, topic)
        except InputError as exc:
            self._reject(exc)
            return
        self._tracker[stamp_to_ns(msg.header.stamp)] = (q, np.diag(np.reshape(msg.orientation_covariance, (3, 3))))
        self._relay_sensors()

    def _relay_sensors(self) -> None:
        """The waiting samples of the estimator's path (gyro and epoch of one stamp), in order, each
        once the tracker sample its epoch names has arrived: through the faults with that sample's
        quaternion (the plant's held measurement), then relayed; the tracker sample relayed too when
        the relayed epoch is a new one, stamped with that epoch (a frozen or delayed sample is not
        sent again)."""
        while self._waiting and int(self._waiting[0][2][1]) in self._tracker:  # else on its way (no order among topics)
            self._relay_sample(*self._waiting.popleft())

    def _relay_sample(self, stamp: Any, ns: int, arrived: tuple[Any, ...]) -> None:
        (w, w_variance), epoch = arrived
        epoch_ns = int(epoch)
        for old in [k for k in self._tracker if k < epoch_ns]:  # the plant's epochs only increase
            del self._tracker[old]
        q, q_variance = self._tracker[epoch_ns]
        if self._epoch_origin_ns is None:
            self._epoch_origin_ns = epoch_ns
        faulted = self.faults.sensor(self._run_time_s(ns), ns, q, w, float(epoch_ns - self._epoch_origin_ns))
        gyro, epoch = faulty(SENSOR_GYRO), faulty(RELAYED_SENSOR_TOPICS_FOR_ESTIMATOR[1])
        if faulted is None:
            self.pub_relay[SENSOR_GYRO.name].publish(no_data_msg(gyro, stamp))
            self.pub_relay[RELAYED_SENSOR_TOPICS_FOR_ESTIMATOR[1].name].publish(no_data_msg(epoch, stamp))
            return
        relayed_ns = self._epoch_origin_ns + int(faulted[2])
        if self._relayed_epoch_ns is None or relayed_ns > self._relayed_epoch_ns:
            self._relayed_epoch_ns = relayed_ns
            self.pub_relay[SENSOR_STAR_TRACKER.name].publish(_relayed_msg(SENSOR_STAR_TRACKER, (faulted[0], q_variance), ns_to_stamp(relayed_ns)))
        self.pub_relay[SENSOR_GYRO.name].publish(_relayed_msg(SENSOR_GYRO, (faulted[1], w_variance), stamp))
        self.pub_relay[RELAYED_SENSOR_TOPICS_FOR_ESTIMATOR[1].name].publish(_relayed_msg(RELAYED_SENSOR_TOPICS_FOR_ESTIMATOR[1], relayed_ns, stamp))

    def _on_command(self, msg: Any, topic: Topic) -> None:
        try:
            torque = torque_from_msg(msg, topic)
        except InputError as exc:
            self._reject(exc)
            return
        t = self._run_time_s(stamp_to_ns(msg.header.stamp))
        self.pub_relay[topic.name].publish(torque_msg(self.faults.actuator(t, torque), msg.header.stamp, faulty(topic)))


def main(argv: list[str] | None = None) -> int:
    """Run the injector until stopped."""
    return run_node(lambda args: InjectorNode(), argv, InjectorNode)


if __name__ == "__main__":
    sys.exit(main())

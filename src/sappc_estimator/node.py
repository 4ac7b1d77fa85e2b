"""The estimator node (``python -m sappc_estimator``): the multiplicative EKF between the sensors and the controller.

Subscribes to the sensors on their own topics (``sensors/gyro``: the gyro's ``omega_BN_B`` each
sample; ``sensors/star_tracker``: the tracker's ``q_BN`` each time it makes a sample, stamped when
it was measured; both ``sensor_msgs/Imu``) and to the tracker's epoch of each sample
(``state/attitude_epoch``: which tracker sample is the latest at that sample; the estimator knows a
new tracker sample by its stamp, never by comparing values), and publishes, per sample and with
the sample's stamp, the estimate on
``estimate/attitude`` and ``estimate/rate`` (the types and frames of ``state/*``, so the
controller takes it by a remap: ``python -m sappc_controller --ros-args -r
state/attitude:=estimate/attitude -r state/rate:=estimate/rate``), and beside it, in standard
messages that Foxglove and PlotJuggler plot, ``estimator/gyro_bias``, ``estimator/attitude_sigma``,
``estimator/bias_sigma``, ``estimator/covariance`` and ``estimator/diagnostics``
(:mod:`sappc_msgs_py.contract`).  The filter is :mod:`sappc_estimator.core.mekf` (``docs/estimator.md``),
one compiled kernel for the node and the offline loop; its settings are the parameters of
:data:`~sappc_estimator.params.FILTER_PARAMETERS` (a ROS YAML file: ``--ros-args --params-file
config/estimator_mekf.yaml``), validated at start-up by the config's own checks: a missing,
unknown or invalid parameter stops the node with one line naming it (exit status 2; a managed
node's configure transition fails instead: "Managed" below).  Every parameter is read once, at
start-up.

Modes (parameter ``mode``):

``lockstep`` (default)
    One filter step per sample, when the gyro and the tracker's epoch of one stamp have arrived,
    and the tracker sample that epoch names if it is a new one (a later epoch than every earlier
    sample named: the topics are not ordered among themselves, so the epoch says what to wait
    for), at the stamp's time (``t = stamp`` in seconds), the outputs stamped with it.  A sample whose input
    arrived invalid (non-finite, e.g. the fault injector's "no data" for a dropped measurement; a
    zero or non-unit quaternion; a wrong frame id) is not stepped (the filter skips it: the next
    valid sample propagates over the whole elapsed time) and is answered at once with the "no
    data" estimate (NaN, :func:`~sappc_msgs_py.convert.no_data_msg`), so the controller counts its
    sample as arrived and answers it as it answers its own dropped input (held torque, or zero
    once stale).  So is a step before the filter has an estimate (before its first tracker sample).
``realtime``
    One filter step per fresh sample (gyro and epoch of one new stamp: a frame of
    :mod:`sappc_msgs_py.timeline`), as soon as both have arrived and the tracker sample the epoch
    names, when it is a new one, has too (as in lockstep: the topics are not ordered among
    themselves), published with the sample's stamp; its latency (publication minus the state's
    stamp) is measured, and a step later than ``control_period_s`` is counted (``late_steps`` in
    ``timing_file``).  A tracker sample that has not arrived by the middle of its sample's frame
    (a timer of the frame grid), or by the time the next sample is complete, is *late*: the sample
    is stepped without it (propagated on the gyro) and the tracker sample is refused, never applied
    at a later step (counted: ``late_tracker_samples``, logged at most once a second).  An invalid
    input is rejected and makes no sample (the controller's own watchdog covers the frame); the
    filter's time is counted from the first sample's stamp (a float of epoch seconds would lose
    0.2 us).

Time (docs/how-to/realtime.md, "Time"): stamps and epochs are integer nanoseconds; the filter gets
float seconds since an integer origin (0 in lockstep, the first sample's stamp in real time), never
a float of absolute time.  A tracker sample is applied at the step of the sample whose epoch first
names it, which the plant does at the tracker sample's own stamp.  An epoch *later* than the
sample that names it (a tracker sample "from the future", which the filter cannot take: once the
plant's float of absolute nanoseconds, issue 46) is a contract error: counted
(``future_tracker_epochs``), logged at most once a second, and that tracker sample is refused (it
is never applied, neither at this step nor at a later one); the sample itself is stepped on the
gyro and gets its estimate (not "no data").  An epoch first named by a later sample than its own
(its own sample was dropped, or a fault relay delays the tracker) is applied at that step, as the
offline loop does: the filter does not model a measurement's delay.

Input checks (:mod:`sappc_msgs_py.inputs`, the controller's): a message with a wrong frame id, a
non-finite value, a zero or non-unit quaternion, a sensor message that marks its measurement
absent ("invalid"), a stamp in the past (lockstep: not after the last answered sample; real time,
and the tracker's samples, which are stamped when measured: not after the topic's previous
message) or more than
``max_stamp_ahead_s`` ahead of the node's time (lockstep: the latest ``/clock``; real time: the
node's clock) is rejected, logged and counted, in total (``estimator/diagnostics``
``rejected_messages``) and by reason (:data:`~sappc_msgs_py.inputs.REJECT_REASONS`).  A finite
but implausible measurement (a rate beyond ``max_body_rate_rad_s``) is no measurement for the
filter (docs/estimator.md, step 0): the filter is unchanged and the sample is "no data", as the
offline loop answers it.

The contract's "no data" inputs (the fault injector's dropped gyro sample: NaN in every value;
:func:`~sappc_msgs_py.convert.is_no_data_msg`) are no error: the sample is answered as for an
invalid input, and they are counted apart (``no_data_inputs``), not among the rejected messages.

The closing line and ``timing_file`` count the samples answered, the filter steps, its updates,
gate rejections and re-initialisations, the "no data" samples, the rejected messages, the inputs
without data, the future tracker epochs and (real time) the late tracker samples.

Managed (``managed:=true``; default false: the plain node above): a ROS 2 managed (lifecycle) node,
as :class:`~sappc_msgs_py.runtime.ManagedNode` says for every node; for this one:

- configure: everything the plain node does at start-up: the parameters declared and validated
  into the filter's config, the compiled kernel loaded (a step on throwaway arrays), the inputs
  subscribed, the outputs offered.  A bad parameter (missing, unknown, invalid) fails the
  transition and is logged naming it; the node stays ``unconfigured`` (the process lives on).  The
  node is then ``inactive``.
- inactive (after configure, or deactivate): the filter is not stepped, but every sample the node
  would answer is still answered, when it would be (in lockstep once its inputs, and the new
  tracker sample its epoch names, have arrived), so a plant in lockstep never waits: with the
  sample's stamp, the contract's "no data" (NaN) on ``estimate/attitude``, ``estimate/rate``,
  ``estimator/gyro_bias``, ``estimator/attitude_sigma``, ``estimator/bias_sigma`` and
  ``estimator/covariance`` (as for a sample whose inputs arrived invalid: the controller behind it
  answers as to its own dropped input), and on ``estimator/diagnostics`` the status
  :data:`~sappc_msgs_py.contract.ESTIMATOR_INACTIVE` (``inactive``, 7) whatever the sample's inputs
  (``no_input`` would say they arrived invalid), the sample counted in ``no_data_samples`` (not
  in ``withheld_samples``: no estimate was made), the filter's own figures (``nis``, its totals,
  the monitor's level and NIS sum) as its last step left them.  ``diagnostics`` says so at level
  WARN (message ``inactive: ...``, key ``estimate`` ``withheld``), at once when the node answers
  its first sample inactive and then once a second of the samples' time.  Inputs are still checked
  and counted (rejected messages, inputs without data, future tracker epochs, late tracker
  samples), and the tracker's samples are still taken as the samples name them, so none is applied
  after activation that belongs to a sample answered inactive.
- activate: the filter steps again from the next sample.  One that has not stepped since it was
  built starts as a configured filter does (at its first tracker sample, or from its prior); one
  deactivated after it had stepped is replaced by a fresh filter from the same config, as a fresh
  configure would build (not propagated over the gap: its estimate, covariance, bias and monitor
  afresh, from the next valid sample: the tracker's latest sample, provisional until a new one
  comes, or the prior), whose totals (updates, gate rejections, re-initialisations, recoveries,
  drift alarms) go on from the earlier filter's, so the diagnostics' counts stay totals
  (:meth:`~sappc_estimator.core.estimator.Mekf.restarted`).  The node's own counts go on too.
- cleanup: the subscriptions, timers and publishers destroyed; ``unconfigured``.  A new configure
  builds a new filter (and new counts) from the same parameters.
- shutdown: as cleanup, then ``finalized``; the process ends on SIGINT or SIGTERM, as always.

Design: the lifecycle is :class:`~sappc_msgs_py.runtime.ManagedNode`, as the controller's.
Start-up is :meth:`EstimatorNode.configure_node`, which the base runs while building a plain node
and at the configure transition of a managed one: one code path for both, so a plain node is
exactly what it was.  Every sample is answered by one method, which steps no filter and answers
``inactive`` whenever the node is not active.  rclpy's ``LifecyclePublisher`` is not used: it
would drop an inactive estimator's messages, and the controller (and the plant behind it) would
then wait.
"""

from __future__ import annotations

import sys
from functools import partial
from typing import Any

import numpy as np
from numpy.typing import NDArray

from gnc_common.timing import LatencyStatistics
from gnc_common.validation import check_positive, check_unit_quaternion
from sappc_msgs_py.contract import (
    CLOCK,
    ESTIMATE_ATTITUDE,
    ESTIMATE_RATE,
    ESTIMATOR_ATTITUDE_SIGMA,
    ESTIMATOR_BIAS_SIGMA,
    ESTIMATOR_COVARIANCE,
    ESTIMATOR_DIAGNOSTICS,
    ESTIMATOR_DIAGNOSTICS_LAYOUT,
    ESTIMATOR_GYRO_BIAS,
    ESTIMATOR_HEALTH,
    ESTIMATOR_INACTIVE,
    ESTIMATOR_INPUTS,
    ESTIMATOR_NO_INPUT,
    SENSOR_STAR_TRACKER,
    ESTIMATOR_TOPICS,
    Topic,
    qos_profile,
)
from sappc_msgs_py.convert import (
    covariance_values,
    epoch_from_msg,
    gyro_from_msg,
    health_msg,
    ns_to_stamp,
    cdr_stamp_ns,
    star_tracker_from_msg,
)
from sappc_msgs_py.inputs import (
    DEFAULT_MAX_STAMP_AHEAD_S,
    NS_PER_S,
    REJECT_REASONS,
    WATCHDOG_RANGE_S,
    ControlSample,
    LockstepPairing,
    RealtimePairing,
    check_watchdog_seconds,
    screen_input,
)
from sappc_msgs_py.parameters import Param
from sappc_msgs_py.runtime import COMMON_PARAMETERS, LOCKSTEP, MANAGED, MODE, REALTIME, ManagedNode, StartGate, run_node, unmatched
from sappc_msgs_py.runtime import write_json_whole
from sappc_msgs_py.timeline import MID_FRAME_PHASE, period_ns
from sappc_msgs_py import wire

from sappc_estimator.core import mekf
from sappc_estimator.core.config import chi2_band
from sappc_estimator.core.estimator import Mekf
from sappc_estimator.params import DEFAULT_CONTROL_PERIOD_S, FILTER_PARAMETERS, config_from_parameters

__all__ = ["EstimatorNode", "PARAMETERS", "main"]

#: The node's own parameters (``--help``; the filter's, :data:`~sappc_estimator.params.FILTER_PARAMETERS`,
#: follow), in the order the node declares them.
PARAMETERS = (
    MODE,
    MANAGED,
    Param("max_stamp_ahead_s", DEFAULT_MAX_STAMP_AHEAD_S, "inputs stamped further ahead of the node's time (lockstep: the latest "
          "/clock; real time: its clock) are rejected", "s", range=WATCHDOG_RANGE_S),
    Param("control_period_s", DEFAULT_CONTROL_PERIOD_S, "real time: a step published later than this after its state's stamp is "
          "counted late (the control period: the controller needs the estimate within its frame)", "s", check="> 0"),
    Param("timing_file", "", "where to write the node's statistics when it finishes (JSON: samples, filter steps, updates, gate "
          "rejections, re-initialisations, no-data samples, rejected messages by reason; real time: the steps' latency "
          "and late steps); '' for none"),
)
_P = {p.name: p for p in PARAMETERS}

#: The estimate the controller takes: each publisher waits for one subscriber (the controller)
#: before its first message; the other topics wait for none unless ``expected_subscribers`` says so.
_LOOP_OUTPUTS = (ESTIMATE_ATTITUDE, ESTIMATE_RATE)
#: The longest time [s of the samples' stamps] between two health reports while the monitor's
#: level does not change: 1 s, the period of ROS's diagnostic_updater (a change is reported at once).
HEALTH_PERIOD_S = 1.0
#: The health's message for each monitor level (``mekf.MON_*``).
_HEALTH_MESSAGES = ("consistent: the innovations' window inside its band",
                    "warning: the innovations' window outside its warning band, or recovering",
                    "inconsistent: the innovations' window outside its error band, or their drift test past its threshold",
                    "stale: no tracker sample for longer than tracker_stale_s")
#: The health's message while the node is inactive (level WARN; module docstring, "Managed").
_INACTIVE_MESSAGE = "inactive: the estimator is not active (a managed node configured and not activated, or deactivated); no estimate"
#: The health's remembered level for a report while inactive: a key of its own, so the first
#: inactive sample is reported at once whatever the monitor's level was (and so is the first after).
_INACTIVE_KEY = -1


def _seconds(ns: int) -> str:
    """A stamp [ns] in seconds, exactly (``sec.nanosec``): a float of a real-time stamp would round it."""
    return f"{ns // NS_PER_S}.{ns % NS_PER_S:09d}"


def _named_epoch(sample: ControlSample) -> int:
    """The tracker epoch [ns] a valid sample names (its ``state/attitude_epoch``); 0 for an invalid one."""
    return int(sample.values[1][0]) if sample.valid else 0


def decode_estimator_input(raw: bytes, topic: Topic) -> Any:
    """The value of an estimator input received as CDR bytes (:func:`sappc_msgs_py.wire.take`):
    the gyro's angular velocity [rad/s], the tracker's unit quaternion ``q_BN`` (x, y, z, w), the
    epoch [ns] (an int64 array of one, exact) for ``state/attitude_epoch``; raises
    :class:`~gnc_common.validation.InputError` as the decoders do."""
    if topic.type_name.endswith("TimeReference"):  # the layout fixes the source: the sensor's epoch
        return np.array([wire.take(raw, topic, lambda m: epoch_from_msg(m, topic), pick=lambda v: v[0])], dtype=np.int64)
    if topic.name.endswith(SENSOR_STAR_TRACKER.name):
        q = wire.take(raw, topic, lambda m: star_tracker_from_msg(m, topic), pick=wire.PICK_ORIENTATION)
        return check_unit_quaternion(f"{topic.name} orientation", q)
    return wire.take(raw, topic, lambda m: gyro_from_msg(m, topic), pick=wire.PICK_GYRO)


class TrackerSamples:
    """The tracker's samples by stamp, and the one a sample of the loop uses.

    A loop sample names, by its epoch, the latest tracker sample at its time.  The quaternion it
    uses is that of the latest valid epoch any sample has named so far (:meth:`use`): a held or
    delayed epoch (a fault) names an older sample, whose quaternion the filter does not use (not
    new: only its validity is checked), so the filter takes what the offline loop gives it
    (``sappc.offline.compiled_loop``: the quaternion of the latest new epoch delivered) bit for bit.
    A tracker sample that arrived invalid is no measurement: the samples that name it propagate."""

    #: Tracker samples kept that no loop sample has named yet: a tracker at 1 Hz beside a 1 kHz
    #: loop names each within a thousand samples; more are dropped, oldest first.
    MAX_KEPT = 1000

    def __init__(self) -> None:
        self._by_ns: dict[int, NDArray[np.float64] | None] = {}  # stamp -> q_BN (None: arrived invalid)
        self.latest_ns: int | None = None  # the latest epoch a loop sample named
        self.q: NDArray[np.float64] = np.full(4, np.nan)  # the quaternion of the latest valid one (NaN before one)
        self.q_ns: int | None = None  # and its epoch
        self.last_arrived_ns: int | None = None  # the latest stamp that arrived (stamps only increase)

    def add(self, stamp_ns: int, q: NDArray[np.float64] | None) -> None:
        """Keep a tracker sample that arrived (``None``: arrived invalid)."""
        self.last_arrived_ns = stamp_ns
        if self.latest_ns is not None and stamp_ns <= self.latest_ns:
            return  # older than a sample named already: never used
        self._by_ns[stamp_ns] = q
        if len(self._by_ns) > self.MAX_KEPT:
            del self._by_ns[min(self._by_ns)]

    def ready(self, epoch_ns: int) -> bool:
        """Whether a loop sample naming ``epoch_ns`` can be stepped: the epoch is not a new one, or
        its tracker sample has arrived."""
        return (self.latest_ns is not None and epoch_ns <= self.latest_ns) or epoch_ns in self._by_ns

    def refuse(self, epoch_ns: int) -> None:
        """Never use the tracker sample of ``epoch_ns`` (nor an older one), arrived or not: it is
        taken as named (a later sample naming it finds it not new) without its quaternion, as one
        that arrived invalid; when it arrives later it is not kept."""
        if self.latest_ns is None or epoch_ns > self.latest_ns:
            self.latest_ns = epoch_ns
            for ns in [ns for ns in self._by_ns if ns <= epoch_ns]:
                del self._by_ns[ns]

    def use(self, epoch_ns: int) -> int:
        """The epoch [ns] a loop sample naming ``epoch_ns`` gives the filter, its quaternion in
        :attr:`q`: ``epoch_ns`` itself, but the latest valid one's (not new to the filter) when
        the sample it names arrived invalid or (real time) has not arrived yet."""
        if epoch_ns in self._by_ns and (self.latest_ns is None or epoch_ns > self.latest_ns):
            q = self._by_ns[epoch_ns]
            self.latest_ns = epoch_ns
            for ns in [ns for ns in self._by_ns if ns <= epoch_ns]:
                del self._by_ns[ns]
            if q is not None:
                self.q, self.q_ns = q, epoch_ns
        if self.q_ns is not None and epoch_ns > self.q_ns and epoch_ns not in self._by_ns:
            return self.q_ns  # invalid, or not here yet: no new measurement
        return epoch_ns  # (before any valid sample q is NaN: no measurement)


class EstimatorNode(ManagedNode):
    """See the module docstring (its section "Managed" for the lifecycle)."""

    PARAMETERS = PARAMETERS
    COMMAND = "python -m sappc_estimator"

    @classmethod
    def parameter_sections(cls) -> list[tuple[str, tuple[Param, ...]]]:
        return [("parameters", cls.PARAMETERS),
                ("parameters of the filter (docs/estimator.md; per-axis values are [x, y, z], one number for all three)", FILTER_PARAMETERS),
                ("parameters of every node", COMMON_PARAMETERS)]

    def __init__(self, node_name: str = "estimator", **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)  # not managed: configured (configure_node) and active; managed: unconfigured

    def configure_node(self) -> None:
        """The parameters declared and validated into the filter's config, the compiled kernel
        loaded, the inputs subscribed and the outputs offered
        (:class:`~sappc_msgs_py.runtime.ManagedNode`: while the node is built, or at a managed
        node's configure transition).  Raises ``ConfigError`` naming a bad parameter."""
        self.mode = self.mode_param()
        self.max_ahead_ns = round(check_watchdog_seconds("max_stamp_ahead_s", self.param(_P["max_stamp_ahead_s"])) * NS_PER_S)
        self.dt = check_positive("control_period_s", self.param(_P["control_period_s"]))
        self.timing_file = str(self.param(_P["timing_file"]))
        self.config = config_from_parameters({p.name: self.param(p) for p in FILTER_PARAMETERS})
        self.check_unknown_overrides()  # after every declaration
        self.filter = Mekf(self.config)
        self.filter.warm_up()  # the compiled kernel loaded now (cache load ~1 s), not at the first sample
        self._steps_at_filter = 0  # self.steps when this filter was built (a later activation builds a fresh one)

        self.pub = {t.name: self.counting_publisher(t, 1 if t in _LOOP_OUTPUTS else 0) for t in ESTIMATOR_TOPICS}
        self._wire = {t.name: wire.codec(t) for t in ESTIMATOR_TOPICS if t is not ESTIMATOR_HEALTH}
        qos = qos_profile()
        for topic in ESTIMATOR_INPUTS:
            self.create_subscription(topic.msg_class, topic.name, partial(self._on_input, topic=topic), qos, raw=True)
        self.create_subscription(SENSOR_STAR_TRACKER.msg_class, SENSOR_STAR_TRACKER.name, self._on_tracker, qos, raw=True)
        self.tracker = TrackerSamples()
        self._waiting: ControlSample | None = None  # lockstep: a sample whose new tracker sample has not arrived
        self.samples = 0  # samples answered (an estimate or "no data")
        self.steps = 0  # filter steps (valid samples)
        self.no_data = 0  # samples answered with "no data"
        self.rejected = 0
        self.rejected_by_reason: dict[str, int] = {}
        self.no_data_inputs = 0  # the contract's "no data" inputs (not rejections)
        self.future_tracker_epochs = 0  # samples naming a tracker epoch later than their own stamp (a contract error)
        self.late_tracker_samples = 0  # real time: tracker samples not there when their sample's step was due (refused)
        self._answered_ns: int | None = None  # lockstep: the latest stamp answered
        self._clock_ns: int | None = None  # lockstep: the latest /clock
        self._origin_ns: int | None = 0 if self.mode == LOCKSTEP else None  # real time: the first sample's stamp
        self._pending = LockstepPairing(ESTIMATOR_INPUTS)  # lockstep: the inputs of each stamp until complete
        self._rt = RealtimePairing(ESTIMATOR_INPUTS)  # real time: a sample per fresh state
        self.latency = LatencyStatistics(self.dt)  # real time: the steps' latency, in bounded memory
        self._diag = np.zeros(len(ESTIMATOR_DIAGNOSTICS_LAYOUT))
        self.withheld = 0  # samples whose estimate was withheld (initialising, unconfirmed)
        self._health_level: int | None = None  # the level last reported on diagnostics (_INACTIVE_KEY: inactive)
        self._health_t_s = -np.inf  # when [s since the time origin]
        dof = 3 * self.config.monitor_window_samples
        self._band = chi2_band(dof, self.config.monitor_error_probability)
        if self.mode == LOCKSTEP:
            self.create_subscription(CLOCK.msg_class, CLOCK.name, self._on_clock, qos, raw=True)
        else:  # no publish may block a callback: samples before the controller is matched are skipped
            self._gate = StartGate(self, lambda: unmatched(list(self.pub.values())))
            self.dt_ns = period_ns(self.dt)
            self.create_frame_timer(self.dt, MID_FRAME_PHASE, self._on_timer)  # the deadline of a sample waiting for its tracker sample
        self.get_logger().info(f"MEKF estimator ready ({self.mode}; gate at NIS {self.config.gate_chi2:.4g}, "
                               f"{'prior attitude' if self.config.initial_q_BN is not None else 'starts at the first tracker sample'})")

    # ---- inputs ---------------------------------------------------------------------------
    def _reject(self, reason: str, kind: str) -> None:
        """Count (in total and by ``kind``: one of :data:`~sappc_msgs_py.inputs.REJECT_REASONS`) and log a rejected input."""
        self.rejected += 1
        self.rejected_by_reason[kind] = self.rejected_by_reason.get(kind, 0) + 1
        self.get_logger().warning(f"rejected a message ({self.rejected} so far): {reason}", throttle_duration_sec=1.0)

    def _no_data(self, what: str) -> None:
        """Count (apart from the rejected messages) and log, at most once a second, an input that is
        the contract's "no data" sample."""
        self.no_data_inputs += 1
        self.get_logger().info(f"an input without data ({self.no_data_inputs} so far): {what}", throttle_duration_sec=1.0)

    def _on_clock(self, raw: bytes) -> None:
        self._clock_ns = cdr_stamp_ns(CLOCK.type_name, raw)

    def _now_ns(self) -> int | None:
        """The node's time: the latest /clock in lockstep, the node clock in real time."""
        return self._clock_ns if self.mode == LOCKSTEP else self.get_clock().now().nanoseconds

    def _on_input(self, msg: bytes, topic: Topic) -> None:
        last = self._answered_ns if self.mode == LOCKSTEP else self._rt.last_ns(topic.name)
        what = "the last answered sample" if self.mode == LOCKSTEP else f"the last {topic.name} message"
        screened = screen_input(msg, topic, last, self._now_ns(), self.max_ahead_ns, what, decode_estimator_input, self._reject, self._no_data)
        if screened is None:
            return
        ns, value = screened  # value None: arrived without a valid value (module docstring)
        if self.mode == REALTIME:
            fresh = None if value is None else self._rt.add(topic.name, ns, value)
            if fresh is not None and self._gate.open():
                if self._waiting is not None:  # a newer sample is complete: the older one's tracker sample is late
                    self._answer_without_tracker()
                self._take(fresh)
            return
        sample = self._pending.add(topic.name, ns, value)
        if sample is not None:
            self._take(sample)

    def _take(self, sample: ControlSample) -> None:
        """A complete sample: answered now, or (valid, its epoch names a new tracker sample of its
        time or before that has not arrived) kept until that tracker sample comes (lockstep: one
        sample at a time; real time: until the deadline, :meth:`_on_timer`)."""
        named = _named_epoch(sample)
        if sample.valid and named <= sample.t_ns and not self.tracker.ready(named):
            self._waiting = sample  # its tracker sample is on its way
        else:
            self._step(sample)

    def _step(self, sample: ControlSample) -> None:
        """Answer ``sample``; in real time its latency measured."""
        self._answer(sample)
        if self.mode == REALTIME:
            self.latency.add(self.get_clock().now().nanoseconds - sample.t_ns)

    def _answer_without_tracker(self) -> None:
        """Real time: the waiting sample's tracker sample is late: refused (never applied at a later
        step), counted and logged; the sample is stepped on the gyro."""
        waiting = self._waiting
        assert waiting is not None
        self._waiting = None
        named = _named_epoch(waiting)
        self.late_tracker_samples += 1
        self.get_logger().warning(f"the tracker sample of {_seconds(named)} s had not arrived when the sample of {_seconds(waiting.t_ns)} s "
                                  f"that names it was due: refused, the sample propagates on the gyro ({self.late_tracker_samples} so far)",
                                  throttle_duration_sec=1.0)
        self.tracker.refuse(named)
        self._step(waiting)

    def _on_timer(self) -> None:
        """Real time, in the middle of each frame: a sample still waiting for its tracker sample
        once the middle of its own frame has passed is stepped without it."""
        waiting = self._waiting
        if waiting is not None and self.get_clock().now().nanoseconds >= waiting.t_ns + self.dt_ns // 2:
            self._answer_without_tracker()

    def _on_tracker(self, msg: bytes) -> None:
        """A tracker sample (stamped when measured): kept by its stamp until a loop sample names it."""
        topic = SENSOR_STAR_TRACKER
        screened = screen_input(msg, topic, self.tracker.last_arrived_ns, self._now_ns(), self.max_ahead_ns,
                                f"the last {topic.name} message", decode_estimator_input, self._reject, self._no_data)
        if screened is None:
            return
        self.tracker.add(*screened)
        waiting = self._waiting
        if waiting is not None and self.tracker.ready(_named_epoch(waiting)):
            self._waiting = None
            self._step(waiting)

    # ---- samples --------------------------------------------------------------------------
    def _answer(self, sample: ControlSample) -> None:
        """One sample: a filter step on valid inputs, then its estimate (or "no data") published."""
        t_ns = sample.t_ns
        self._answered_ns = t_ns
        self.samples += 1
        if not sample.valid:
            self._publish(t_ns, ESTIMATOR_NO_INPUT if self.active else ESTIMATOR_INACTIVE, figures=False)
            return
        if self._origin_ns is None:
            self._origin_ns = t_ns
        omega_meas, epoch = sample.values
        named = int(epoch[0])
        if named > t_ns:  # a tracker sample from the future: a contract error (module docstring), refused
            self.future_tracker_epochs += 1
            self.get_logger().warning(f"contract error: the sample of {_seconds(t_ns)} s names the tracker epoch {_seconds(named)} s, "
                                      f"{named - t_ns} ns after it; that tracker sample is refused, the sample propagates on the gyro "
                                      f"({self.future_tracker_epochs} so far)", throttle_duration_sec=1.0)
            self.tracker.refuse(named)
        epoch_ns = self.tracker.use(named)
        if not self.active:  # managed, inactive: the tracker's sample taken as named, no filter step ("Managed")
            self._publish(t_ns, ESTIMATOR_INACTIVE, figures=False)
            return
        status = self.filter.step((t_ns - self._origin_ns) / NS_PER_S, self.tracker.q, omega_meas, (epoch_ns - self._origin_ns) / NS_PER_S)
        self.steps += 1
        # an implausible measurement (a rate beyond max_body_rate_rad_s ...) is no measurement: the
        # filter is unchanged and the sample is "no data", as the offline loop answers it
        figures = status != mekf.STATUS_NONE and self.filter.initialised
        self._publish(t_ns, status, figures=figures, estimate=figures and self.filter.usable)

    def _publish(self, t_ns: int, status: int, *, figures: bool, estimate: bool = False) -> None:
        """The sample's outputs, stamped ``t_ns``: the filter's estimate, or "no data" (NaN) in the
        estimate topics (the controller's inputs) when it has none or withholds it (not confirmed:
        :attr:`Mekf.usable`); its figures (bias, sigmas, covariance) when it has them, else "no data";
        the diagnostics in every case, the health when due (``status`` inactive: the health says so)."""
        p = self.pub
        w = self._wire  # every output but the health as CDR bytes (sappc_msgs_py.wire)
        f = self.filter
        if estimate:
            p[ESTIMATE_ATTITUDE.name].publish(w[ESTIMATE_ATTITUDE.name].encode(t_ns, f.q_BN))
            p[ESTIMATE_RATE.name].publish(w[ESTIMATE_RATE.name].encode(t_ns, f.omega_BN_B))
        else:
            self.no_data += 1
            self.withheld += figures
            for topic in (ESTIMATE_ATTITUDE, ESTIMATE_RATE):
                p[topic.name].publish(w[topic.name].no_data(t_ns))
        for topic, value in ((ESTIMATOR_GYRO_BIAS, f.gyro_bias_rad_s), (ESTIMATOR_ATTITUDE_SIGMA, f.attitude_sigma_rad),
                             (ESTIMATOR_BIAS_SIGMA, f.bias_sigma_rad_s)):
            p[topic.name].publish(w[topic.name].encode(t_ns, value) if figures else w[topic.name].no_data(t_ns))
        t_s = t_ns / NS_PER_S  # the arrays' time label (the contract's data[0], seconds): never computed with
        p[ESTIMATOR_COVARIANCE.name].publish(w[ESTIMATOR_COVARIANCE.name].encode(None, covariance_values(t_s, f.P if figures else None)))
        d = self._diag
        d[:] = (t_s, f.nis, status, f.updates, f.rejections, f.reinitialisations, self.no_data, self.rejected,
                f.monitor_level, f.monitor_nis_sum, f.recoveries, self.withheld)
        p[ESTIMATOR_DIAGNOSTICS.name].publish(w[ESTIMATOR_DIAGNOSTICS.name].encode(None, d))
        self._report_health(ns_to_stamp(t_ns), t_ns, figures, estimate, status == ESTIMATOR_INACTIVE)

    def _report_health(self, stamp: Any, t_ns: int, figures: bool, estimate: bool, inactive: bool = False) -> None:
        """``diagnostics`` (ROS's health convention): the monitor's level and figures, when the level
        changes (or the node becomes inactive, or active again) and at least every
        :data:`HEALTH_PERIOD_S` of the samples' time; inactive: a warning that says so."""
        f = self.filter
        level = f.monitor_level if figures else mekf.MON_WARN  # no estimate yet (or no input, or inactive): a warning
        if not estimate and figures:
            level = max(level, mekf.MON_WARN)  # withheld: the controller is not fed
        t_s = (t_ns - (self._origin_ns or 0)) / NS_PER_S  # since the integer origin (0 in lockstep): never absolute time in a float
        key = _INACTIVE_KEY if inactive else level
        if key == self._health_level and t_s - self._health_t_s < HEALTH_PERIOD_S:
            return
        self._health_level, self._health_t_s = key, t_s
        message = _HEALTH_MESSAGES[level] if figures else _INACTIVE_MESSAGE if inactive else "no estimate: initialising or no valid input"
        if figures and np.isnan(f.monitor_nis_sum):
            message = "no verdict yet: the innovations' window is filling"
        if figures and not estimate:
            message += "; the estimate is withheld (a prior, or re-initialised, not yet confirmed by a tracker sample)"
        c = self.config
        values = {"time_s": _seconds(t_ns), "window_samples": str(c.monitor_window_samples), "nis_sum_dof": str(3 * c.monitor_window_samples),
                  "nis_sum": f"{f.monitor_nis_sum:.6g}", "nis_sum_band": f"[{self._band[0]:.6g}, {self._band[1]:.6g}]",
                  "band_probability": f"{c.monitor_error_probability:.6g}", "mean_statistic": f"{f.monitor_mean_statistic:.6g}",
                  "outside_in_a_row": str(f.monitor_outside), "persistence": str(c.monitor_persistence),
                  "estimate": "used" if estimate else "withheld", "recoveries": str(f.recoveries),
                  "reinitialisations": str(f.reinitialisations), "withheld_samples": str(self.withheld),
                  "drift_statistic": f"{f.monitor_drift_statistic:.6g}", "drift_threshold": f"{f.monitor_drift_threshold:.6g}",
                  "drift_alarms": str(f.drift_alarms)}
        p = self.pub[ESTIMATOR_HEALTH.name]
        p.publish(health_msg(stamp, level, message, values, out=p.msg))

    # ---- lifecycle --------------------------------------------------------------------------
    def on_activate(self, state: Any) -> Any:
        """A later activation (the filter had stepped): a fresh filter from the same config, its
        totals carried on (module docstring, "Managed"); then active, from the next sample."""
        if self.steps > self._steps_at_filter:
            self.filter = self.filter.restarted()
            self._steps_at_filter = self.steps
            self.get_logger().info("a fresh filter from the same config: it starts again at the next valid sample")
        return super().on_activate(state)

    # ---- the end --------------------------------------------------------------------------
    def statistics(self) -> dict[str, Any]:
        """What the node did: the counts of the closing line, the rejected messages by reason and
        (real time) the steps' latency (:class:`~gnc_common.timing.LatencyStatistics`)."""
        return {"samples": self.samples, "steps": self.steps, "updates": self.filter.updates, "gate_rejections": self.filter.rejections,
                "reinitialisations": self.filter.reinitialisations, "recoveries": self.filter.recoveries,
                "withheld_samples": self.withheld, "no_data_samples": self.no_data,
                "rejected": self.rejected, "rejected_by_reason": {r: self.rejected_by_reason.get(r, 0) for r in REJECT_REASONS},
                "no_data_inputs": self.no_data_inputs, "future_tracker_epochs": self.future_tracker_epochs,
                **({"late_tracker_samples": self.late_tracker_samples} if self.mode == REALTIME else {}),
                **({"latency": dict(self.latency.summary())} if self.mode == REALTIME else {})}

    def finish(self) -> None:
        if self.finished_unconfigured():
            return
        s = self.statistics()
        self.get_logger().info(f"finished: {s['samples']} samples, {s['steps']} filter steps ({s['updates']} updates, {s['gate_rejections']} "
                               f"gate rejections, {s['reinitialisations']} re-initialisations, {s['recoveries']} recoveries), "
                               f"{s['no_data_samples']} no-data samples ({s['withheld_samples']} withheld), "
                               f"{s['rejected']} rejected messages {self.rejected_by_reason or ''}"
                               + (f"; {s['no_data_inputs']} inputs without data" if s["no_data_inputs"] else "")
                               + (f"; {s['future_tracker_epochs']} future tracker epochs (contract errors, refused)" if s["future_tracker_epochs"] else "")
                               + (f"; {s['late_tracker_samples']} late tracker samples (refused)" if s.get("late_tracker_samples") else ""))
        super().finish()
        if self.timing_file:
            write_json_whole(self.timing_file, s)  # whole or not at all (sappc run reads it)


def main(argv: list[str] | None = None) -> int:
    """Run the estimator node until stopped."""
    return run_node(lambda args: EstimatorNode(), argv, EstimatorNode)


if __name__ == "__main__":
    sys.exit(main())

"""The controller node (``python -m sappc_controller``): SAPPC, TraPPC, BLFPPC or MRP feedback on the graph.

Subscribes to the state (``state/attitude``, ``state/rate``) and the reference
(``reference/attitude``, ``reference/rate``, ``reference/acceleration``), publishes
``control/torque`` and ``controller/diagnostics`` (see :mod:`sappc_msgs_py.contract`).

Parameters come from a ROS YAML file (``--ros-args --params-file config/controller_sappc.yaml``,
names in :mod:`sappc_controller.params`) and are turned into the core's validated config at
start-up: a missing, unknown, invalid or infeasible parameter stops the node with one line
naming it (exit status 2; a managed node's configure transition fails instead: "Managed" below).  At run time the gains listed in
:data:`~sappc_controller.core.base.AttitudeController.RUNTIME_GAINS`, the actuator limits and the
noise filters' cut-offs (:func:`~sappc_controller.params.runtime_parameter_names`) may be changed (``ros2 param set`` or any parameter client); a change is validated as a whole and
applied at the next step, or rejected with the reason, never half-applied.  Everything else is
read-only during a run.

Start: ``control/torque`` and ``controller/diagnostics`` are offered (their publishers created)
once each of the five inputs has a publisher.  A plant waits for a publisher of
``control/torque`` before its first sample (docs/tutorials/your-plant.md), so the loop starts
only when the controller can compute its first sample, whatever order the plant, the reference
and the controller were started in: no sample is answered without the law for want of a partner
that had not started yet.  The closing log line counts the samples answered in each way
(:data:`~sappc_msgs_py.contract.ANSWER_NAMES`: commanded, held, watchdog zero, refused), as
``sappc run`` does from the bag.

Modes (parameter ``mode``):

``lockstep`` (default)
    The controller computes once per sample, when the two state messages and the three
    reference messages of the same stamp have arrived, and stamps the torque with it.
``realtime``
    In the frames of :mod:`sappc_msgs_py.timeline`: the controller computes as soon as the state
    of a new frame (attitude and rate of one stamp) and the reference of the same stamp have
    arrived (the reference node publishes it ahead, so it is normally there first), and stamps
    the torque with the state's stamp, so the plant applies it over the next frame, as in
    lockstep.  A reference of that stamp that arrived invalid, or has not arrived by the middle of
    the state's frame, is replaced by the newest earlier one (held; counted:
    ``held_reference_steps`` in ``timing_file``).  The law's time is counted from the first step's
    stamp, so a step on the same inputs as a lockstep step gives the same torque, bit for bit.
    Its latency (the torque's publication minus the state's stamp) is measured, and a
    step later than ``control_period_s`` (it missed the plant's next frame) is counted
    (``late_steps`` in ``timing_file``).  A state that is complete more than a frame after its
    stamp is not stepped (``late_states``): its torque could no longer reach the plant's tick (a
    plant that missed ticks publishes their states late, in a burst, and the newest is the one to
    answer).  A timer in the middle of each frame is the watchdog.
    With ``duration_s`` (``sappc run`` sets the scenario's), the state of the frame
    ``duration_s`` after the first is the last one answered: the watchdog then stops (the plant
    has finished), so no torque is published past the run's end.

Input checks: a message with a wrong frame id, a non-finite value, a zero or non-unit
quaternion ("invalid"), a body rate, reference rate or reference acceleration beyond its
plausibility bound (``max_body_rate_rad_s``, ...: "implausible"; the check is
:mod:`gnc_common.input_check`, the offline loop's too), a stamp in the past (lockstep: not after the last computed sample; real
time: not after the topic's previous message) or more than ``max_stamp_ahead_s`` ahead of the
controller's time ("far future") is rejected, logged and counted, in total (diagnostics
``status[0]``) and by reason (:data:`REJECT_REASONS`); it never reaches the law.  The contract's
"no data" sample (NaN in every value: the fault injector's dropped measurement or reference, the
estimator's sample without an estimate, :func:`~sappc_msgs_py.convert.no_data_msg`) is not an
error: it reaches no law either and its sample is answered as a dropped input, but it is counted
apart (``no_data_inputs`` in ``timing_file`` and the closing line, logged at most once a second
at info level), never among the rejected messages.  In real time the inputs that arrive after
the run's last frame is answered are not looked at (nor counted): they belong to no sample of the
run, and the diagnostics' count (which ``sappc run`` reads from the bag) could not include them.

Answers (diagnostics ``status[2]``, :data:`~sappc_msgs_py.contract.ANSWER_NAMES`): a sample
whose inputs are complete and valid is computed.  Without one at a control instant, the
controller commands zero torque when no valid state is newer than ``stale_timeout_s`` (the
watchdog; ``status[1] = 1``; in real time also when an input of the sample is older than that),
before its first valid sample included (there is no answer to hold), else it holds its last
answer (a short outage is ridden through; in real time the plant holds it); it computes again as
soon as valid inputs return.

Flight modes (parameter ``flight_modes``, default false; lockstep only; docs/design/modes.md, "The
modes on the graph"): the node also takes, for each sample, the mode node's ``mode/status`` (paired
by its time) and the gyro's ``sensors/gyro``, and answers the sample once all seven have arrived.
In TRACK it answers as without modes, its law restarted at each later entry into TRACK (afresh at
its first valid sample there, up to :data:`~sappc_modes.core.packing.MAX_RESTARTS` times, as the
offline loop); outside TRACK it answers ``inactive`` with the mode's own law
(:class:`sappc_controller.modes.ModeLaws`: HOLD's MRP feedback of the ``hold_*`` gains on a valid
sample, towards the reference with ``hold_attitude: reference`` or HOLD's entry attitude; SAFE's on
the gyro's rate alone; zero in DETUMBLE, and when the law has no input), as its torque and command,
saturation zero.  An infeasible RPF start is clamped (counted), as the offline loop's flights.

Managed (``managed:=true``; default false: the plain node above): a ROS 2 managed (lifecycle) node,
as :class:`~sappc_msgs_py.runtime.ManagedNode` says for every node; for this one:

- configure: everything the plain node does at start-up: the parameters declared and validated
  into the law's config, the compiled step loaded (a step at rest), the inputs subscribed, the
  outputs offered once every input has a publisher.  A bad parameter (missing, unknown, invalid,
  infeasible) fails the transition and is logged naming it; the node stays ``unconfigured`` (the
  process lives on).  The node is then ``inactive``.
- inactive (after configure, or deactivate): the controller steps no law, but it keeps answering
  the plant in lockstep (and each fresh state and the watchdog in real time), so the loop never
  waits for it: every sample answered gets, on ``control/torque``, the torque (0, 0, 0) stamped
  with the sample's stamp, and on ``controller/diagnostics``: ``torque_cmd_Nm`` and
  ``saturated`` zero, ``status = [rejected so far, 1, 4]`` (the answer
  :data:`~sappc_msgs_py.contract.ANSWER_INACTIVE`, "inactive"), input stamps zero, and the rho,
  band, eps, z and V rows of the last computed sample (NaN before the first), as the offline loop
  records a sample the controller does not command.  Inputs are still checked and counted.
- activate: the law answers again, from the next sample: a controller that has not started yet
  starts at its first valid sample while active (its time origin and funnel); one that was
  deactivated after it had started starts again there, afresh (its state, time origin and funnel
  from that sample: as the offline loop restarts it at each later entry into TRACK), and a
  sample without valid inputs is answered as above (held: the last answer, zero after an
  inactive one; or watchdog zero).
- cleanup: the subscriptions, timers and publishers destroyed and the parameter callback removed;
  ``unconfigured``.  A new configure builds a new law (a fresh start) from the same parameters.
- shutdown: as cleanup, then ``finalized``; the process ends on SIGINT or SIGTERM, as always.

Design: the lifecycle is :class:`~sappc_msgs_py.runtime.ManagedNode`, the project's base node
with rclpy's :class:`~rclpy.lifecycle.LifecycleNodeMixin` mixed in (the mixin is initialised,
and its services created, only when ``managed`` is true).  Start-up moved whole into
:meth:`ControllerNode.configure_node`, which the base runs while building a plain node and at the
configure transition of a managed one: one code path for both, so a plain node is exactly what it
was.  Lockstep answering needs no change: every answer goes through one publishing method, which
commands zero torque and the answer ``inactive`` whenever the node is not active (and the law is
not stepped).  rclpy's ``LifecyclePublisher`` is not used: it would drop an inactive
controller's messages, and the plant would then wait for its torque.

The run starts at the first valid sample (:class:`~sappc_controller.core.base.AttitudeController`'s
first step): its time is the performance function's time origin and its error gives the
performance function's start (sign, and ``rpf.rho_e0`` when that is left to the initial error).
Until then the diagnostics' rho, band, eps, z and V rows are NaN: there is no performance
function yet (the offline loop records the same).

In lockstep the control instant of sample t_k is decided by the inputs themselves, whatever
the order in which ``/clock`` and the inputs arrive: when the five inputs of t_k have arrived,
valid or not (an invalid input, e.g. the fault injector's non-finite "no data" for a dropped
measurement, counts as arrived), the sample is answered at once.  Only when an input of the
latest ``/clock`` tick never arrives (a message lost on the network) does the tick wait
``lockstep_grace_s`` of wall time before the same rule answers it, so a lost message costs that
wait, not the plant's longer ``lockstep_timeout_s``.  A zero or held answer never moves the
"last computed sample", so no valid input after an outage is refused as "in the past".  The
published torque is always finite and within the actuator limits (the core refuses a
non-finite torque; the node then publishes zero, counts the refused step and says so).
"""

from __future__ import annotations

import math
import sys
import time
from functools import partial
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from rcl_interfaces.msg import SetParametersResult

from sappc_msgs_py.contract import (
    MODE_STATUS,
    SENSOR_GYRO,
    ANSWER_COMMANDED,
    ANSWER_HELD,
    ANSWER_INACTIVE,
    ANSWER_NAMES,
    ANSWER_REFUSED,
    ANSWER_WATCHDOG_ZERO,
    CLOCK,
    CONTROL_TORQUE,
    CONTROLLER_DIAGNOSTICS,
    Topic,
    qos_profile,
)
from sappc_msgs_py import wire
from sappc_msgs_py.convert import (
    time_to_ns,
    cdr_stamp_ns,
    diagnostics_values,
    quaternion_from_msg,
    vector3_from_msg,
)
from sappc_msgs_py.inputs import screen_input
from sappc_msgs_py.parameters import Param
from sappc_msgs_py.runtime import LOCKSTEP, MANAGED, MODE, NEVER_CONFIGURED, REALTIME, CountingPublisher, ManagedNode, StartGate, run_node, unmatched
from sappc_msgs_py.runtime import write_json_whole
from gnc_common.timing import LatencyStatistics
from gnc_common.validation import ConfigError, InputError, check_positive

from sappc_controller.core.base import AttitudeController
from sappc_controller.core.mrp_feedback import MrpFeedbackGains
from sappc_controller.modes import ModeLaws
from sappc_modes.core.modes import HOLD, R_NONE, SAFE, TRACK
from sappc_modes.core.packing import MAX_RESTARTS
from gnc_common.input_check import REJECT_REASONS as INPUT_REJECT_REASONS
from gnc_common.input_check import INPUT_OK, InputBounds, check_input, input_verdict
from sappc_msgs_py.timeline import MID_FRAME_PHASE, period_ns
from sappc_controller.inputs import INPUT_TOPICS, NS_PER_S, STEP_ERRORS, ControlSample, LockstepPairing, RealtimePairing, step_sample
from sappc_controller.params import (
    CONTROLLER_CLASSES,
    DEFAULT_CONTROL_PERIOD_S,
    DEFAULT_LOCKSTEP_GRACE_S,
    DEFAULT_MAX_STAMP_AHEAD_S,
    DEFAULT_STALE_TIMEOUT_S,
    WATCHDOG_RANGE_S,
    check_watchdog_seconds,
    config_from_parameters,
    config_parameters,
    runtime_parameter_names,
)

__all__ = ["ControllerNode", "PARAMETERS", "main"]

#: The five inputs of one control step, by topic (paired by :mod:`sappc_controller.inputs`).
_INPUTS = INPUT_TOPICS
#: Each input topic's slot in the input check (:mod:`gnc_common.input_check`: the step's order).
_SLOTS = {topic.name: slot for slot, topic in enumerate(_INPUTS)}
#: How the input check names each input's value.
_WHAT = {t.name: f"{t.name} quaternion" if t.type_name.endswith("QuaternionStamped") else t.name for t in _INPUTS}
_NS = NS_PER_S


#: Why an input is rejected (``rejected_by_reason`` keys): :data:`gnc_common.input_check.REJECT_REASONS`
#: (the offline loop counts the same).
REJECT_REASONS = INPUT_REJECT_REASONS

#: The plausibility bounds on the inputs (:class:`~gnc_common.input_check.InputBounds`), read at start-up.
_BOUND_PARAMS = ("max_attitude_norm_error", "max_body_rate_rad_s", "max_reference_rate_rad_s", "max_reference_acceleration_rad_s2")
#: Watchdog parameters: changeable at run time, applied at once, each within WATCHDOG_RANGE_S.
_WATCHDOG_PARAMS = ("stale_timeout_s", "max_stamp_ahead_s", "lockstep_grace_s")
#: Period of the lockstep grace check [s]: the grace is honoured to within this.
_GRACE_CHECK_S = 0.05


#: The controller node's own parameters (``--help``; those of the law, :func:`~sappc_controller.params.config_parameters`,
#: follow ``controller``), in the order the node declares them.
PARAMETERS = (
    Param("controller", "sappc", "the law: SAPPC, one of the paper's benchmarks (trappc, blfppc), or Basilisk's MRP feedback", choices=tuple(CONTROLLER_CLASSES)),
    Param("control_period_s", DEFAULT_CONTROL_PERIOD_S, "control period dt: the law's step (and the real-time frame and deadline)", "s",
          check="> 0"),
    MODE,
    MANAGED,
    Param("stale_timeout_s", DEFAULT_STALE_TIMEOUT_S, "zero torque when no valid state is newer than this at a control instant", "s",
          range=WATCHDOG_RANGE_S, read_only=False),
    Param("max_stamp_ahead_s", DEFAULT_MAX_STAMP_AHEAD_S, "inputs stamped further ahead of the controller's time are rejected", "s",
          range=WATCHDOG_RANGE_S, read_only=False),
    Param("lockstep_grace_s", DEFAULT_LOCKSTEP_GRACE_S, "lockstep: wall time a /clock tick waits for an input that never arrives "
          "before it is answered", "s", range=WATCHDOG_RANGE_S, read_only=False),
    Param("max_attitude_norm_error", InputBounds.max_attitude_norm_error, "attitudes (measured, reference) whose norm differs from 1 by "
          "more than this are rejected as invalid (at most the law's own 1e-6)", check="in (0, 1e-6]"),
    Param("max_body_rate_rad_s", InputBounds.max_body_rate_rad_s, "a measured body rate of larger magnitude is rejected as implausible "
          "(beyond any spacecraft gyro's range)", "rad/s", check="> 0"),
    Param("max_reference_rate_rad_s", InputBounds.max_reference_rate_rad_s, "a reference rate of larger magnitude is rejected as "
          "implausible", "rad/s", check="> 0"),
    Param("max_reference_acceleration_rad_s2", InputBounds.max_reference_acceleration_rad_s2, "a reference acceleration of larger "
          "magnitude is rejected as implausible (ten times the most agile spacecraft's)", "rad/s^2", check="> 0"),
    Param("timing_file", "", "where to write the node's statistics when it finishes (JSON: steps, refused, rejected by reason, inputs "
          "without data; real time: the steps' latency and late steps); '' for none"),
    Param("duration_s", 0.0, "real time: the run's length from the first state; after answering the state of its last frame the "
          "controller answers nothing more (its watchdog stops: the plant has finished); 0: no end", "s", check=">= 0"),
    Param("flight_modes", False, "lockstep: take each sample's mode (mode/status) and gyro (sensors/gyro); outside TRACK answer "
          "'inactive' with the mode's law (HOLD, SAFE), restart the law at each later entry into TRACK, clamp an infeasible RPF start "
          "(docs/design/modes.md)"),
    Param("hold_K_Nm", 0.0, "flight modes: HOLD's MRP feedback attitude gain K (SAFE's is 0)", "N m", check="> 0 with flight_modes"),
    Param("hold_P_Nms", 0.0, "flight modes: HOLD's and SAFE's rate gain P", "N m s", check="> 0 with flight_modes"),
    Param("hold_integralLimit_Nms", 0.0, "flight modes: HOLD's and SAFE's integral limit", "N m s", check=">= 0"),
    Param("hold_Ki_per_kg_m2", 0.0, "flight modes: HOLD's and SAFE's integral gain (0: none)", "1/(kg m^2)", check=">= 0"),
    Param("hold_attitude", "entry", "flight modes: HOLD holds the attitude of its entry, or points at the reference (an acquisition)",
          choices=("entry", "reference")),
)
_P = {p.name: p for p in PARAMETERS}
#: The flight modes' HOLD and SAFE law's parameters (``flight_modes``).
_HOLD_PARAMS = ("hold_K_Nm", "hold_P_Nms", "hold_integralLimit_Nms", "hold_Ki_per_kg_m2", "hold_attitude")


def _seconds_to_ns(name: str, value: Any) -> int:
    """A watchdog parameter [s] checked (finite, within :data:`~sappc_controller.params.WATCHDOG_RANGE_S`) -> [ns]."""
    return int(round(check_watchdog_seconds(name, value) * _NS))


#: Where the gyro's angular velocity sits in a ``sensor_msgs/Imu``'s 37 doubles (:func:`sappc_msgs_py.wire.gyro_values`).
_IMU_OMEGA = 13


class _FlightModes:
    """What the node keeps with flight modes (parameter ``flight_modes``): the laws of HOLD and
    SAFE, the samples waiting for their mode and gyro (by stamp), and the law's starts."""

    def __init__(self, laws: ModeLaws) -> None:
        self.laws = laws
        self.samples: dict[int, ControlSample] = {}
        self.modes: dict[int, tuple[int, int]] = {}
        self.gyro: dict[int, np.ndarray | None] = {}
        self.started = False  # the law has started since the last entry into TRACK
        self.starts = 0  # the law's starts so far (the first, then one per later entry into TRACK)


#: Inputs of the warm-up step (identity attitude and reference, at rest).
_AT_REST_Q = np.array([0.0, 0.0, 0.0, 1.0])
_ZERO3 = np.zeros(3)

class ControllerNode(ManagedNode):
    """See the module docstring (its section "Managed" for the lifecycle)."""

    PARAMETERS = PARAMETERS
    COMMAND = "python -m sappc_controller"

    @classmethod
    def parameter_sections(cls) -> list[tuple[str, tuple[Param, ...]]]:
        laws = [(f"parameters of the {kind} law (controller: {kind}; runtime-changeable gains and limits are applied at the next step)",
                 config_parameters(kind)) for kind in CONTROLLER_CLASSES]
        return [("parameters", cls.PARAMETERS), *laws, *super().parameter_sections()[1:]]

    def __init__(self, node_name: str = "controller", **kwargs: Any) -> None:
        self._parameter_callback = False  # whether _on_set_parameters is added (configure_node; a cleanup removes it)
        super().__init__(node_name, **kwargs)  # not managed: configured (configure_node) and active; managed: unconfigured

    def configure_node(self) -> None:
        """The parameters declared and validated into the law's config, the compiled step loaded,
        the inputs subscribed; the outputs offered once every input has a publisher
        (:class:`~sappc_msgs_py.runtime.ManagedNode`: while the node is built, or at a managed
        node's configure transition).  Raises ``ConfigError`` naming a bad parameter."""
        self.kind = str(self.param(_P["controller"]))
        declared = config_parameters(self.kind)
        self._config_names = [p.name for p in declared]
        for p in declared:
            self.param(p)
        config = config_from_parameters(self.kind, self._config_values())
        self.flight_modes = bool(self.param(_P["flight_modes"]))
        # with flight modes the law starts at each entry into TRACK from whatever error the acquisition left: an infeasible RPF
        # start is clamped (counted), as offline (sappc.offline.compiled_loop.prepare)
        self.controller: AttitudeController = (CONTROLLER_CLASSES[self.kind](config, on_infeasible="clamp")
                                               if self.flight_modes and self.kind == "sappc" else CONTROLLER_CLASSES[self.kind](config))
        hold = {name: self.param(_P[name]) for name in _HOLD_PARAMS}  # declared whether or not the run flies modes (--help lists them)
        self._modes = self._flight_modes(config, hold) if self.flight_modes else None
        self.dt = check_positive("control_period_s", self.param(_P["control_period_s"]))
        self.mode = self.mode_param()
        self.stale_timeout_ns = _seconds_to_ns("stale_timeout_s", self.param(_P["stale_timeout_s"]))
        self.max_ahead_ns = _seconds_to_ns("max_stamp_ahead_s", self.param(_P["max_stamp_ahead_s"]))
        self.grace_ns = _seconds_to_ns("lockstep_grace_s", self.param(_P["lockstep_grace_s"]))
        self.input_bounds = InputBounds(**{name: self.param(_P[name]) for name in _BOUND_PARAMS})
        self._bounds = self.input_bounds.packed()
        self._bounds_list = self._bounds.tolist()  # the per-message check's (floats, not array items)

        # load the compiled step now (cache load ~1 s), not at the first sample, which the plant
        # waits for at most lockstep_timeout_s: a step at rest, then forget it
        self.controller.step(0.0, self.dt, _AT_REST_Q, _ZERO3, _AT_REST_Q, _ZERO3, _ZERO3)
        self.controller.reset()
        # the outputs are offered once every input has a publisher (_offer_outputs): a plant waits
        # for a publisher of control/torque, so it cannot start before the reference is there
        self.pub_torque: CountingPublisher | None = None
        self.pub_diag: CountingPublisher | None = None
        qos = qos_profile()
        # every topic as CDR bytes (sappc_msgs_py.wire): taken raw, published as bytes
        self._wire = {t.name: wire.codec(t) for t in (*_INPUTS, CONTROL_TORQUE, CONTROLLER_DIAGNOSTICS)}
        self._wire_modes = {t.name: wire.codec(t) for t in (MODE_STATUS, SENSOR_GYRO)}
        self._decoders = {t.name: partial(quaternion_from_msg if t.type_name.endswith("QuaternionStamped") else vector3_from_msg, topic=t)
                          for t in _INPUTS}  # what a message the codec does not take goes through (wire.take)
        self._input_subs = [self.create_subscription(topic.msg_class, topic.name, partial(self._on_input, topic=topic), qos, raw=True)
                            for topic in _INPUTS]
        self.rejected = 0
        self.answers = dict.fromkeys(ANSWER_NAMES, 0)  # samples answered, by answer (diagnostics status[2])
        self.rejected_by_reason: dict[str, int] = {}
        self.no_data_inputs = 0  # the contract's "no data" samples received (not rejections: module docstring)
        self.refused = 0  # control steps whose torque the core refused (non-finite)
        self.stale = False
        self.steps = 0
        self._last_ns: int | None = None  # stamp of the last computed sample (lockstep: every input of it carries it)
        self._answered_ns: int | None = None  # lockstep: the latest stamp a torque was published for
        self._clock_ns: int | None = None  # lockstep: the latest /clock
        self._clock_wall_ns = 0  # lockstep: wall time [ns] the latest /clock arrived
        self._pending = LockstepPairing(_INPUTS)  # lockstep: the inputs of each stamp until complete
        self._rt = RealtimePairing(_INPUTS)  # real time: a sample per fresh state
        self.latency = LatencyStatistics(self.dt)  # real time: the steps' latency, in bounded memory
        self.held_reference_steps = 0  # real time: steps on a reference not of the state's own stamp (held)
        # real time: the first sample answered unlike the lockstep run (a held reference; a state too
        # late to step; a state replaced by a newer one before any reference came: never stepped),
        # counted from the first state's (sample 0)
        self.first_deviating_sample: int | None = None
        self._first_state_ns: int | None = None  # real time: the run's first state's stamp (sample 0)
        self.late_states = 0  # real time: states more than a frame old when complete, not stepped
        self._origin_ns: int | None = 0 if self.mode == LOCKSTEP else None  # the run's time origin: real time, the first step's stamp
        self._end_ns: int | None = None  # real time: the stamp of the run's last frame (duration_s after the first state)
        self._ended = False  # real time: the last frame is answered
        # before the first computed sample the controller has no performance function: NaN rows (as the offline loop records)
        self._diag_rows: dict[str, list[float]] = {k: [math.nan] * 3 for k in ("rho", "band_lower", "band_upper", "eps", "z", "lyapunov_V")}
        self._held: tuple[list[float], list[float], list[float]] = ([0.0] * 3, [0.0] * 3, [0.0] * 3)  # last torque, command, saturation
        self.start_when(self._inputs_missing, self._offer_outputs)
        if self._modes is not None:
            if self.mode != LOCKSTEP:
                raise ConfigError("flight_modes: lockstep only (real time: not yet)")
            self._input_subs += [self.create_subscription(t.msg_class, t.name, partial(self._on_mode_input, topic=t), qos, raw=True)
                                 for t in (MODE_STATUS, SENSOR_GYRO)]
        if self.mode == LOCKSTEP:
            self.create_subscription(CLOCK.msg_class, CLOCK.name, self._on_clock, qos, raw=True)
            self.create_timer(_GRACE_CHECK_S, self._check_grace)
        else:
            self.dt_ns = period_ns(self.dt)
            self._gate = StartGate(self, self._outputs_unmatched)  # no publish may block a callback
            self.create_frame_timer(self.dt, MID_FRAME_PHASE, self._on_timer)
        self.timing_file = str(self.param(_P["timing_file"]))
        duration = check_positive("duration_s", self.param(_P["duration_s"]), allow_zero=True)
        self._n_frames = int(round(duration / self.dt))  # frames after the first (0: no end)
        self._check_unknown_overrides()  # after every declaration
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._parameter_callback = True
        self.get_logger().info(f"{self.kind} controller ready ({self.mode}, dt = {self.dt} s)")

    def _flight_modes(self, config: Any, hold: dict[str, Any]) -> _FlightModes:
        """The flight modes' laws and bookkeeping (parameter ``flight_modes``) from the ``hold_*``
        parameters' values; raises ``ConfigError`` naming a bad gain."""
        try:
            gains = MrpFeedbackGains(K_Nm=float(hold["hold_K_Nm"]), P_Nms=float(hold["hold_P_Nms"]),
                                     integralLimit_Nms=float(hold["hold_integralLimit_Nms"]), Ki_per_kg_m2=float(hold["hold_Ki_per_kg_m2"]))
        except (ConfigError, ValueError) as exc:
            raise ConfigError(f"flight_modes: HOLD's gains (hold_K_Nm, hold_P_Nms, hold_integralLimit_Nms, hold_Ki_per_kg_m2): {exc}") from None
        laws = ModeLaws(np.asarray(config.inertia_kg_m2, dtype=np.float64), gains, config.actuator, str(hold["hold_attitude"]) == "reference")
        return _FlightModes(laws)

    def release_node(self) -> None:
        """A managed controller's cleanup: its parameter callback removed (its subscriptions,
        timers and publishers are destroyed by :class:`~sappc_msgs_py.runtime.ManagedNode`); the
        parameters stay declared, and the next configure builds a new law from them."""
        if self._parameter_callback:
            self.remove_on_set_parameters_callback(self._on_set_parameters)
            self._parameter_callback = False

    # ---- start ----------------------------------------------------------------------------
    def _inputs_missing(self) -> list[str]:
        """The inputs without a publisher yet, in words (empty: the controller can compute)."""
        return [f"a publisher of {sub.topic_name}" for sub in self._input_subs if sub.get_publisher_count() < 1]

    def _offer_outputs(self) -> None:
        """Create ``control/torque`` and ``controller/diagnostics`` (once).

        Called when every input has a publisher, or at the first complete sample if that comes
        first (a plant that did not wait).  A plant waits for a publisher of ``control/torque``
        before its first sample, so the loop starts only once the controller can answer it with
        the law: whatever order the plant, the reference and the controller start in, the first
        sample is computed and no tick is answered by ``lockstep_grace_s`` (issue 25, defect 6).
        """
        if self.pub_torque is None:
            self.pub_torque = self.counting_publisher(CONTROL_TORQUE, 1)
            self.pub_diag = self.counting_publisher(CONTROLLER_DIAGNOSTICS)
            self.get_logger().info("every input has a publisher: control/torque is offered")

    def _outputs_unmatched(self) -> list[str]:
        """Real time: what the first step still waits for (the outputs offered and matched)."""
        if self.pub_torque is None or self.pub_diag is None:
            return ["control/torque to be offered (every input with a publisher)"]
        return unmatched([self.pub_torque, self.pub_diag])

    # ---- parameters -----------------------------------------------------------------------
    def _config_values(self, changes: dict[str, Any] | None = None) -> dict[str, Any]:
        values = {name: self.get_parameter(name).value for name in self._config_names}
        values.update(changes or {})
        return values

    def _check_unknown_overrides(self) -> None:
        """Reject overrides this node does not know (a typo would otherwise be ignored); the other
        laws' parameters may be given (one parameters file for every kind)."""
        self.check_unknown_overrides(tuple(f"{k}." for k in CONTROLLER_CLASSES if k != self.kind))

    def _on_set_parameters(self, params: list[Any]) -> SetParametersResult:
        changes = {p.name: p.value for p in params}
        watchdog = {n: v for n, v in changes.items() if n in _WATCHDOG_PARAMS}
        try:  # checked whole before anything is applied
            watchdog_ns = {n: _seconds_to_ns(n, v) for n, v in watchdog.items()}
        except (ConfigError, InputError, TypeError) as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        runtime = runtime_parameter_names(self.kind)
        fixed = sorted(n for n in changes if n in self._config_names and n not in runtime)
        if fixed:
            return SetParametersResult(successful=False, reason=f"{fixed[0]} cannot change during a run; restart the controller")
        if not any(n in self._config_names for n in changes):
            self._apply_watchdog(watchdog_ns)
            if watchdog:
                self.get_logger().info(f"parameters changed: {watchdog}")
            return SetParametersResult(successful=True)
        try:
            config = config_from_parameters(self.kind, self._config_values(changes))
            self.controller.reconfigure(config)
        except (ConfigError, ValueError, TypeError) as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        self._apply_watchdog(watchdog_ns)
        self.get_logger().info(f"parameters changed: {changes}")
        return SetParametersResult(successful=True)

    def _apply_watchdog(self, watchdog_ns: dict[str, int]) -> None:
        self.stale_timeout_ns = watchdog_ns.get("stale_timeout_s", self.stale_timeout_ns)
        self.max_ahead_ns = watchdog_ns.get("max_stamp_ahead_s", self.max_ahead_ns)
        self.grace_ns = watchdog_ns.get("lockstep_grace_s", self.grace_ns)

    # ---- inputs ---------------------------------------------------------------------------
    def _reject(self, reason: str, kind: str) -> None:
        """Count (in total and by ``kind``: one of :data:`REJECT_REASONS`) and log a rejected input."""
        self.rejected += 1
        self.rejected_by_reason[kind] = self.rejected_by_reason.get(kind, 0) + 1
        self.get_logger().warning(f"rejected a message ({self.rejected} so far): {reason}", throttle_duration_sec=1.0)

    def _no_data(self, what: str) -> None:
        """Count (apart from the rejected messages) and log, at most once a second, an input that is
        the contract's "no data" sample (module docstring)."""
        self.no_data_inputs += 1
        self.get_logger().info(f"an input without data ({self.no_data_inputs} so far): {what}; its sample is answered as a dropped input",
                               throttle_duration_sec=1.0)

    def _now_ns(self) -> int | None:
        """The controller's time: the latest /clock in lockstep, the node clock in real time."""
        return self._clock_ns if self.mode == LOCKSTEP else self.get_clock().now().nanoseconds

    def _decode(self, raw: bytes, topic: Topic) -> np.ndarray:
        """The message's value (:func:`sappc_msgs_py.wire.take`), checked by
        :func:`~gnc_common.input_check.check_input` (the offline loop's check): raises
        ``InputError`` (invalid) or ``ImplausibleInputError``."""
        slot = _SLOTS[topic.name]
        values = self._wire[topic.name].values(raw)  # a message of the layout: its values, checked as they are
        if values is not None and input_verdict(slot, values, self._bounds_list) == INPUT_OK:  # accepted: finite too
            return np.array(values)
        # anything else (another layout, a rejected value): the decoder and the check that name what is wrong
        value: np.ndarray = wire.take(raw, topic, self._decoders[topic.name], self._wire[topic.name])
        check_input(slot, _WHAT[topic.name], value, self.input_bounds, self._bounds)
        return value

    def _on_input(self, msg: bytes, topic: Topic) -> None:
        if self._ended:
            return  # real time: the run's last frame is answered; nothing after it is the run's (not even counted)
        last = self._last_ns if self.mode == LOCKSTEP else self._rt.last_ns(topic.name)
        what = "the last computed sample" if self.mode == LOCKSTEP else f"the last {topic.name} message"
        screened = screen_input(msg, topic, last, self._now_ns(), self.max_ahead_ns, what, self._decode, self._reject, self._no_data)
        if screened is None:
            return
        ns, value = screened  # value None: arrived without a valid value: invalid, or "no data" (module docstring)
        if self.mode == REALTIME:
            waited = self._rt.waiting_ns
            fresh = self._rt.add(topic.name, ns, value)
            start = fresh.t_ns if fresh is not None else self._rt.waiting_ns
            if self._first_state_ns is None and start is not None:
                self._first_state_ns = start
            if self._end_ns is None and self._n_frames and start is not None:  # the first state: the run's last frame follows
                self._end_ns = start + self._n_frames * self.dt_ns
            if waited is not None and self._rt.waiting_ns != waited and (fresh is None or fresh.t_ns != waited):
                self._deviates_at(waited)  # a state replaced by a newer one before any reference came: never stepped, unlike lockstep
            if fresh is not None:
                self._on_fresh_state(fresh)
            return
        sample = self._pending.add(topic.name, ns, value)
        if sample is None:
            return
        if self._modes is not None:  # the sample waits for its mode and gyro (_answer_in_mode)
            self._modes.samples[sample.t_ns] = sample
            self._try_mode_sample(sample.t_ns)
            return
        if sample.valid:
            self._compute(sample)
        else:
            self._answer_without_inputs(sample.t_ns)

    # ---- flight modes (lockstep) -----------------------------------------------------------
    def _on_mode_input(self, raw: bytes, topic: Topic) -> None:
        """``mode/status`` or ``sensors/gyro`` of a sample (parameter ``flight_modes``)."""
        fm = self._modes
        assert fm is not None
        values = self._wire_modes[topic.name].values(raw)
        if values is None:  # not the contract's layout: rejected (the sample then waits for the grace)
            self._reject(f"{topic.name}: not the contract's layout", "invalid")
            return
        if topic is MODE_STATUS:
            ns = time_to_ns(values[0])
            fm.modes[ns] = (int(values[1]), int(values[2]))
        else:
            ns = cdr_stamp_ns(topic.type_name, raw)
            omega = np.array(values[_IMU_OMEGA:_IMU_OMEGA + 3])
            fm.gyro[ns] = omega if np.all(np.isfinite(omega)) else None
        self._try_mode_sample(ns)

    def _try_mode_sample(self, t_ns: int) -> None:
        """Answer sample ``t_ns`` once its five inputs, its mode and its gyro have arrived."""
        fm = self._modes
        assert fm is not None
        if t_ns not in fm.samples or t_ns not in fm.modes or t_ns not in fm.gyro:
            return
        sample, (mode, reason), gyro = fm.samples.pop(t_ns), fm.modes.pop(t_ns), fm.gyro.pop(t_ns)
        for table in (fm.samples, fm.modes, fm.gyro):  # an earlier sample that never completed
            for old in [k for k in table if k < t_ns]:
                del table[old]
        self._answer_in_mode(sample, mode, reason, gyro)

    def _answer_in_mode(self, sample: ControlSample, mode: int, reason: int, gyro: np.ndarray | None) -> None:
        """A sample of a flight (the offline loop's rules, docs/design/modes.md): at an entry into
        TRACK the law restarts (when it had started, up to ``MAX_RESTARTS`` times), at one into HOLD
        or SAFE their law's state; in TRACK the law answers as without modes, elsewhere the mode's law,
        answered ``inactive``."""
        fm = self._modes
        assert fm is not None
        if reason != R_NONE:
            if mode == TRACK:
                if fm.started and fm.starts <= MAX_RESTARTS:
                    self.controller.reset()  # a later entry: the law starts afresh at its first valid sample
                    fm.started = False
            elif mode in (HOLD, SAFE):
                fm.laws.enter()
        t_ns = sample.t_ns
        if mode == TRACK:
            if sample.valid:
                if not fm.started:
                    fm.started = True
                    fm.starts += 1
                self._compute(sample)
            else:
                self._answer_without_inputs(t_ns)
            return
        if self._answered(t_ns):
            return
        if not self.active:
            self._answer_inactive(t_ns)
            return
        inputs = tuple(np.asarray(v) for v in sample.values) if sample.valid else None
        torque = fm.laws.torque(mode, t_ns / _NS, self.dt, inputs, gyro)  # type: ignore[arg-type]
        self._publish(t_ns, torque, torque, [0.0] * 3, [0] * len(_INPUTS), ANSWER_INACTIVE)

    # ---- control instants -----------------------------------------------------------------
    def _outage_at(self, t_ns: int) -> bool:
        """Lockstep: whether no valid sample (its state included) has been computed yet, or the last one is more than
        ``stale_timeout_s`` before ``t_ns``: then there is no answer to hold."""
        return self._last_ns is None or t_ns - self._last_ns > self.stale_timeout_ns

    def _answered(self, t_ns: int) -> bool:
        return self._answered_ns is not None and t_ns <= self._answered_ns

    def _answer_without_inputs(self, t_ns: int) -> None:
        """Lockstep: sample ``t_ns`` has no valid inputs: zero torque when stale, else the last answer held
        (inactive: zero torque, answered ``inactive``)."""
        if self._answered(t_ns):
            return
        if not self.active:
            self._answer_inactive(t_ns)
        elif self._outage_at(t_ns):
            self._publish_zero(t_ns, "no valid state", ANSWER_WATCHDOG_ZERO)
        else:
            torque, torque_cmd, saturated = self._held
            self._publish(t_ns, torque, torque_cmd, saturated, [0] * len(_INPUTS), ANSWER_HELD)

    def _on_clock(self, raw: bytes) -> None:
        self._clock_ns = cdr_stamp_ns(CLOCK.type_name, raw)
        self._clock_wall_ns = time.monotonic_ns()

    def _check_grace(self) -> None:
        """Lockstep: answer the latest tick when an input of it has not arrived within ``lockstep_grace_s``."""
        t_ns = self._clock_ns
        if t_ns is None or self._answered(t_ns) or time.monotonic_ns() - self._clock_wall_ns < self.grace_ns:
            return
        self.get_logger().warning(f"t = {t_ns / _NS:.3f} s: an input did not arrive within {self.grace_ns / _NS} s", throttle_duration_sec=1.0)
        self._answer_without_inputs(t_ns)

    def _deviates_at(self, t_ns: int) -> None:
        """Real time: note sample ``t_ns`` as answered unlike the lockstep run (the first one is
        :attr:`first_deviating_sample`)."""
        if self.first_deviating_sample is None and self._first_state_ns is not None:
            self.first_deviating_sample = round((t_ns - self._first_state_ns) / self.dt_ns)

    def _on_fresh_state(self, sample: ControlSample) -> None:
        """Real time: a step on the state of a new frame, at once; its latency measured.  A state
        more than a frame old is not stepped (counted: ``late_states``): its frame is over, so its
        torque could not reach the plant's tick, and the states the plant published late after a
        missed tick come in a burst whose newest is the one to answer (stepping each would cost a
        step per missed frame just when the process is behind)."""
        if not self._gate.open() or self._answered(sample.t_ns):
            return  # the plant or the recorder not matched yet; or the watchdog answered its frame
        if self.get_clock().now().nanoseconds - sample.t_ns > self.dt_ns:
            self.late_states += 1
            self._deviates_at(sample.t_ns)  # no torque of its own (the last frame's: the plant does not wait for it)
            return
        if self.get_clock().now().nanoseconds - sample.oldest_ns > self.stale_timeout_ns:
            self._publish_zero(sample.t_ns, f"inputs older than {self.stale_timeout_ns / _NS} s", ANSWER_WATCHDOG_ZERO)
            return
        self._compute(sample)
        self.latency.add(self.get_clock().now().nanoseconds - sample.t_ns)

    def _on_timer(self) -> None:
        """Real time, in the middle of each frame: a state still waiting for its reference since
        its frame's middle is stepped with the reference held (:meth:`RealtimePairing.take_held`,
        counted), then the watchdog (zero torque, stamped with the current frame, when no fresh
        state came for ``stale_timeout_s``)."""
        if self._ended:
            return
        now = self.get_clock().now().nanoseconds
        waiting = self._rt.waiting_ns
        if waiting is not None and now >= waiting + round(MID_FRAME_PHASE * self.dt_ns):
            held = self._rt.take_held()
            if held is not None:
                self._on_fresh_state(held)
        if self._ended or not self._gate.open() or self._rt.last_sample_ns is None:
            return  # the last frame answered; not started
        frame_ns = now // self.dt_ns * self.dt_ns
        if self._end_ns is not None and frame_ns > self._end_ns:  # past the run's last frame, even one not answered (late)
            self._ended = True
            return
        if now - self._rt.last_sample_ns > self.stale_timeout_ns and not self._answered(frame_ns):
            self._publish_zero(frame_ns, f"no state newer than {self.stale_timeout_ns / _NS} s", ANSWER_WATCHDOG_ZERO)

    def _compute(self, sample: ControlSample) -> None:
        """One control step on a complete sample (the inputs paired by :mod:`sappc_controller.inputs`);
        inactive: no step, the sample answered with zero torque (``inactive``)."""
        t_ns, input_ns = sample.t_ns, list(sample.input_ns)
        late = self.mode == LOCKSTEP and self._answered(t_ns)  # its tick already answered (after the grace)
        if not self.active:
            if not late:
                self._answer_inactive(t_ns)
            return
        if self._origin_ns is None:  # real time: the first step's stamp is the run's time 0
            self._origin_ns = t_ns
        if self.mode == REALTIME and any(ns != t_ns for ns in input_ns[2:]):
            self.held_reference_steps += 1
            self._deviates_at(t_ns)  # its torque is not lockstep's
        try:
            out = step_sample(self.controller, self.dt, sample, self._origin_ns)
        except STEP_ERRORS as exc:
            self.get_logger().error(f"control step at {t_ns / _NS:.9f} s failed: {exc}; commanding zero torque")
            self.refused += 1
            self._publish_zero(t_ns, "control step failed", ANSWER_REFUSED)
            return
        self._last_ns = t_ns
        self.steps += 1
        if late:  # computed (the law steps), but the tick was answered without it
            self.get_logger().warning(f"the inputs of {t_ns / _NS:.3f} s arrived after their tick was answered")
            return
        if self.stale:
            self.get_logger().info("valid inputs again: control resumed")
        self.stale = False
        # out's arrays are the core's buffer, overwritten by the next step: kept as lists (republished with zero torque)
        self._diag_rows = {"rho": out.rho.tolist(), "band_lower": out.band_lower.tolist(), "band_upper": out.band_upper.tolist(), "eps": out.eps.tolist(),
                           "z": out.z.tolist(), "lyapunov_V": out.V.tolist()}
        self._publish(t_ns, out.torque_B.tolist(), out.torque_cmd_B.tolist(), out.saturated.tolist(), input_ns, ANSWER_COMMANDED)

    def on_activate(self, state: Any) -> Any:
        """A later activation (the law had started): the law starts again, afresh, at its first valid
        sample while active (module docstring), as the offline loop's later entries into TRACK."""
        if self.steps > 0:
            self.controller.reset()
        return super().on_activate(state)

    def _answer_inactive(self, t_ns: int) -> None:
        """Sample ``t_ns`` answered by an inactive (deactivated, or configured and not yet activated)
        controller: zero torque, no control step (module docstring, "Managed")."""
        zero = [0.0] * 3
        self._publish(t_ns, zero, zero, zero, [0] * len(_INPUTS), ANSWER_INACTIVE)

    def _publish_zero(self, t_ns: int, why: str, answer: int) -> None:
        if not self.active:
            self._answer_inactive(t_ns)
            return
        if not self.stale:
            self.get_logger().warning(f"{why}: commanding zero torque until valid inputs return")
        self.stale = True
        zero = [0.0] * 3
        self._publish(t_ns, zero, zero, zero, [0] * len(_INPUTS), answer)

    def _publish(self, t_ns: int, torque: list[float], torque_cmd: list[float], saturated: list[float], input_ns: list[int], answer: int) -> None:
        """Publish sample ``t_ns``'s torque and diagnostics (the values as lists of floats: the torque
        produced and commanded [N m], the saturation flags)."""
        self._offer_outputs()  # a sample completed before the offer (its inputs' publishers not yet seen)
        assert self.pub_torque is not None and self.pub_diag is not None
        if not self.active:  # whatever path led here, an inactive controller commands zero torque
            torque = torque_cmd = saturated = [0.0] * 3
            answer = ANSWER_INACTIVE
        self._answered_ns = t_ns if self._answered_ns is None else max(self._answered_ns, t_ns)
        self._ended = self._end_ns is not None and t_ns >= self._end_ns  # real time: nothing is answered past the last frame
        self.answers[ANSWER_NAMES[answer]] += 1
        self._held = (torque, torque_cmd, saturated)
        self.pub_torque.publish(self._wire[CONTROL_TORQUE.name].encode(t_ns, torque))
        rows: dict[str, ArrayLike] = {**self._diag_rows, "torque_cmd_Nm": torque_cmd, "saturated": saturated,
                                      "status": [float(self.rejected), float(answer != ANSWER_COMMANDED), float(answer)],
                                      "input_stamps_state_s": [input_ns[0] / _NS, input_ns[1] / _NS, 0.0],
                                      "input_stamps_reference_s": [n / _NS for n in input_ns[2:]]}
        self.pub_diag.publish(self._wire[CONTROLLER_DIAGNOSTICS.name].encode(None, diagnostics_values(t_ns / _NS, rows)))

    def latency_statistics(self) -> dict[str, Any]:
        """Real time: the steps' latency (torque out minus the state's stamp: p50, p99, max) and
        the steps later than ``control_period_s``, from :class:`~gnc_common.timing.LatencyStatistics`."""
        return dict(self.latency.summary())

    def closing_line(self) -> str:
        """What the node did, for its last log line: the samples answered, by answer (what it did
        not compute included, as ``sappc run`` reports it from the bag), and the inputs rejected."""
        if not self.configurations:
            return NEVER_CONFIGURED
        a = self.answers
        reasons = f" {self.rejected_by_reason}" if self.rejected_by_reason else ""
        no_data = f"; {self.no_data_inputs} inputs without data (the contract's no data, not rejected)" if self.no_data_inputs else ""
        inactive = f", {a['inactive']} inactive" if a["inactive"] else ""
        return (f"finished: answered {sum(a.values())} samples: {a['commanded']} commanded, {a['held']} held, {a['watchdog_zero']} watchdog zero, "
                f"{a['refused']} refused{inactive} ({self.steps} control steps computed); {self.rejected} input messages rejected{reasons}{no_data}")

    def finish(self) -> None:
        self.get_logger().info(self.closing_line())
        super().finish()
        if self.configurations and self.timing_file:
            stats = {"steps": self.steps, "refused_steps": self.refused, "answers": dict(self.answers), "rejected": self.rejected,
                     "rejected_inputs": self.rejected,  # the key of sappc run's controller summary
                     "rejected_by_reason": {r: self.rejected_by_reason.get(r, 0) for r in REJECT_REASONS},
                     "no_data_inputs": self.no_data_inputs,
                     **({"latency": self.latency_statistics(), "held_reference_steps": self.held_reference_steps,
                         "first_deviating_sample": self.first_deviating_sample,
                         "late_states": self.late_states} if self.mode == REALTIME else {})}
            write_json_whole(self.timing_file, stats)  # whole or not at all (sappc run reads it)


def main(argv: list[str] | None = None) -> int:
    """Run the controller node until stopped."""
    return run_node(lambda args: ControllerNode(), argv, ControllerNode)


if __name__ == "__main__":
    sys.exit(main())

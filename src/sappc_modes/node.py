"""The mode node (``python -m sappc_modes``): the flight-mode manager on the graph (issue 49),
flight software beside the estimator and momentum management.

For each sample it takes, all of one stamp (lockstep: the plant owns time; a real-time mode is
not built yet and the node refuses it):

- the gyro's sample, ``sensors/gyro`` (``sensor_msgs/Imu``; a fault relay's output with sensor faults);
- the estimator's estimate, ``estimate/attitude`` and ``estimate/rate`` ("no data" when it has
  none or withholds it), its covariance ``estimator/covariance`` and its ``estimator/diagnostics``
  (the health monitor's level);
- the reference, ``reference/attitude``, ``reference/rate``, ``reference/acceleration`` (a fault
  relay's output with reference faults);
- the wheels' tachometers, ``state/wheel_speed``;

and publishes the sample's mode on ``mode/status`` (:data:`~sappc_msgs_py.contract.MODE_STATUS_LAYOUT`:
the time [s], the mode, the reason of the transition taken at the sample), which the controller
and the momentum node take as one more input of the sample, and the mode in words on ROS's
``diagnostics`` (``sappc_msgs_py.contract.MODE_HEALTH_NAME``: at each transition and at least once a
second of the samples' time; ERROR in SAFE, else OK).  The transition kernel is
:func:`sappc_modes.core.modes.mode_step`, fed exactly as the offline loop feeds it
(:func:`sappc.offline.compiled_loop._run_one`'s docstring, "Flight modes"): the gyro's rate
magnitude (NaN when its sample is "no data" or not finite), the monitor's level and the largest
attitude 1-sigma of the covariance when the estimator has figures (NaN otherwise), the largest
wheel speed as a fraction of its limit (``wheel_max_speed_rad_s``), the ground's requests, and
the attitude error of the estimate against the reference when the controller would find the
sample valid (the controller's own input check,
:func:`~gnc_common.input_check.sample_verdicts`, with the same bounds): so a lockstep
run's modes equal the offline run's, sample for sample.

Ground commands (standard ROS 2 parameters, ``ros2 param set /modes request_mode SAFE``):
``request_mode`` (a mode's name: requested at the next sample, once; the parameter then reads
''), ``inhibit`` (names of automatic transitions to stop: ``detumbled``, ``acquired``, ``safe``,
``recovered``; a request still goes through).  The scenario's own requests
(``requests_at_s``, ``requests_mode``) are requested at the first sample at or after their time,
as offline.  The external loss-of-control flag (``IN_LOST``) is not fed (0, as offline): the
online loss of control is the kernel's own guard on the estimate's error (``lost_error_rad`` of
``transitions``).

Managed (``managed:=true``; default false: the plain node above): a ROS 2 managed (lifecycle) node,
as :class:`~sappc_msgs_py.runtime.ManagedNode` says for every node; for this one:

- configure (:meth:`ModeNode.configure_node`, the plain node's start-up): the parameters declared
  and validated (the guards, the first mode, the scheduled requests, the input bounds, the ground
  commands), the compiled kernels loaded, the ground commands' parameter callback added, the
  inputs subscribed, ``mode/status`` and ``diagnostics`` offered; then ``inactive``, in the first
  mode (``initial_mode``).
- inactive (after configure, or deactivate): the kernel is not stepped, but every sample is still
  answered on ``mode/status``, when it is complete, so a plant in lockstep never waits (the
  controller and the momentum node wait for it): the mode held, reason none (0), as if every
  automatic transition were inhibited and no request came.  No request is taken: a ground request
  (``request_mode``) stays pending, read back as the mode's name, and is taken at the first sample
  answered active; a scheduled request (``requests_at_s``) whose sample is answered inactive is not
  taken (its sample has passed).  ``diagnostics`` says so, at level WARN (ERROR still in SAFE), its
  message starting ``inactive: ...`` and naming the mode held, at once at the first sample answered
  inactive and then at least once a second of the samples' time.  Inputs are still checked and
  counted; the samples answered inactive are counted apart (``inactive_samples`` in the closing
  line and ``timing_file``).
- activate: the flight goes on from the mode held, every guard's count restarted (each condition
  counts its persistence again from the first sample answered active, as after a transition);
  ``diagnostics`` reports at once that the node is active.
- cleanup: the parameter callback removed too.  A new configure starts a new flight (the first
  mode, new counts) from the same parameters.
"""

from __future__ import annotations

import json
import math
import sys
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
from rcl_interfaces.msg import SetParametersResult

from gnc_common.validation import ConfigError, as_finite_array, from_mapping
from gnc_common.input_check import InputBounds, sample_verdicts
from sappc_modes.core.modes import (
    HEALTH_ERROR, HEALTH_OK, HEALTH_WARN, HOLD, IN_ERROR, IN_HEALTH, IN_INHIBIT, IN_LOST, IN_RATE, IN_REQUEST, IN_SIGMA, IN_WHEEL, INHIBIT_ACQUIRED, INHIBIT_DETUMBLED,
    INHIBIT_RECOVERED, INHIBIT_SAFE, MODE_NAMES, N_INPUTS, REASON_NAMES, R_NONE, S_MODE, S_REASON, SAFE, ModeConfig, attitude_error_angle, mode_step, restart_counts,
    new_mode_state, sigma_of_covariance, wheel_speed_fraction,
)
from sappc_msgs_py import wire
from sappc_msgs_py.contract import (ESTIMATE_ATTITUDE, ESTIMATE_RATE, ESTIMATOR_COVARIANCE, ESTIMATOR_DIAGNOSTICS, ESTIMATOR_DIAGNOSTICS_LAYOUT,
                                    ESTIMATOR_HEALTH, MODE_HEALTH_NAME, MODE_STATUS, REFERENCE_ACCELERATION, REFERENCE_ATTITUDE, REFERENCE_RATE, SENSOR_GYRO, STATE_WHEEL_SPEED,
                                    Topic, qos_profile)
from sappc_msgs_py.convert import cdr_stamp_ns, health_msg, ns_to_stamp, time_to_ns
from sappc_msgs_py.inputs import NS_PER_S
from sappc_msgs_py.parameters import Param
from sappc_msgs_py.runtime import LOCKSTEP, MANAGED, MODE, ManagedNode, run_node

__all__ = ["INACTIVE_MESSAGE", "INHIBITS", "INPUTS", "ModeNode", "PARAMETERS", "main"]

#: The node's inputs of one sample (module docstring).
INPUTS = (SENSOR_GYRO, ESTIMATE_ATTITUDE, ESTIMATE_RATE, ESTIMATOR_COVARIANCE, ESTIMATOR_DIAGNOSTICS, REFERENCE_ATTITUDE, REFERENCE_RATE,
          REFERENCE_ACCELERATION, STATE_WHEEL_SPEED)
#: ``inhibit``'s names: the automatic transitions the ground may stop (``sappc_modes.core.modes.INHIBIT_*``).
INHIBITS = {"detumbled": INHIBIT_DETUMBLED, "acquired": INHIBIT_ACQUIRED, "safe": INHIBIT_SAFE, "recovered": INHIBIT_RECOVERED}
#: Where the gyro's angular velocity sits in a ``sensor_msgs/Imu``'s 37 doubles (after the
#: orientation and its covariance: :func:`sappc_msgs_py.wire.gyro_values`).
_IMU_OMEGA = 13
_MONITOR_LEVEL = ESTIMATOR_DIAGNOSTICS_LAYOUT.index("monitor_level")
#: The longest time [s of the samples' stamps] between two reports on ``diagnostics`` while the mode
#: does not change: 1 s, ROS's diagnostic_updater's period (the estimator's too); a transition is reported at once.
HEALTH_PERIOD_S = 1.0
#: How ``diagnostics``' message starts while the node is inactive (level WARN; module docstring, "Managed").
INACTIVE_MESSAGE = "inactive: the mode manager is not active (a managed node configured and not activated, or deactivated); the mode held"

PARAMETERS = (
    MODE,
    MANAGED,
    Param("control_period_s", 0.01, "the loop's sample period (the persistences in samples, the requests' sample)", "s", check="> 0"),
    Param("initial_mode", "DETUMBLE", "the mode of the first sample (after separation: DETUMBLE)", choices=MODE_NAMES),
    Param("transitions", "", "the guards' thresholds and persistences as a JSON mapping of sappc_modes.core.modes.ModeConfig's fields "
          "(the scenario's modes.transitions); '' for the defaults"),
    Param("wheel_max_speed_rad_s", [], "each wheel's speed limit, in the order of state/wheel_speed (the wheel guard); [] without wheels",
          "rad/s", check="W values > 0", type="double[]"),
    Param("requests_at_s", [], "the scenario's ground requests: their times", "s", check="finite, >= 0", type="double[]"),
    Param("requests_mode", [], "... and the modes requested (names, one per time)", type="string[]"),
    Param("max_attitude_norm_error", InputBounds.max_attitude_norm_error, "the controller's input check (the attitude error guard "
          "reads the estimate only when the controller would find the sample valid): its bound on a quaternion's norm"),
    Param("max_body_rate_rad_s", InputBounds.max_body_rate_rad_s, "the controller's input check: its body-rate bound", "rad/s"),
    Param("max_reference_rate_rad_s", InputBounds.max_reference_rate_rad_s, "the controller's input check: its reference-rate bound", "rad/s"),
    Param("max_reference_acceleration_rad_s2", InputBounds.max_reference_acceleration_rad_s2,
          "the controller's input check: its reference-acceleration bound", "rad/s^2"),
    Param("request_mode", "", "ground: request this mode at the next sample (a name of MODE_NAMES; read back '' once taken)",
          read_only=False),
    Param("inhibit", [""], "ground: the automatic transitions stopped (detumbled, acquired, safe, recovered); [''] for none",
          type="string[]", read_only=False),
    Param("timing_file", "", "where to write the node's counts at the end (JSON: samples, transitions, rejected messages); '' for none"),
)
_P = {p.name: p for p in PARAMETERS}
_BOUNDS = ("max_attitude_norm_error", "max_body_rate_rad_s", "max_reference_rate_rad_s", "max_reference_acceleration_rad_s2")


def _inhibit_flags(names: list[str]) -> int:
    """``inhibit``'s names as ``IN_INHIBIT`` flags; raises ``ConfigError`` naming an unknown one."""
    flags = 0
    for name in names:
        if name == "":
            continue
        if name not in INHIBITS:
            raise ConfigError(f"inhibit: {name!r} is not an automatic transition (one of {', '.join(INHIBITS)})")
        flags |= INHIBITS[name]
    return flags


class ModeNode(ManagedNode):
    """See the module docstring (its section "Managed" for the lifecycle)."""

    PARAMETERS = PARAMETERS
    COMMAND = "python -m sappc_modes"

    def __init__(self, node_name: str = "modes", **kwargs: Any) -> None:
        self._parameter_callback = False  # whether _on_set_parameters is added (configure_node; a cleanup removes it)
        super().__init__(node_name, **kwargs)  # not managed: configured (configure_node) and active; managed: unconfigured

    def configure_node(self) -> None:
        """The parameters declared and validated (the guards, the first mode, the requests, the
        input bounds), the compiled kernels loaded, the inputs subscribed and the outputs offered
        (:class:`~sappc_msgs_py.runtime.ManagedNode`: while the node is built, or at a managed
        node's configure transition).  Raises ``ConfigError`` naming a bad parameter."""
        self.mode = self.mode_param()
        if self.mode != LOCKSTEP:
            raise ConfigError(f"mode: the mode node runs in lockstep only (real time: not yet), got {self.mode!r}")
        self.dt = float(self.param(_P["control_period_s"]))
        if not (math.isfinite(self.dt) and self.dt > 0.0):
            raise ConfigError(f"control_period_s must be > 0, got {self.dt!r}")
        self.dt_ns = time_to_ns(self.dt)
        text = str(self.param(_P["transitions"]))
        try:
            mapping = json.loads(text) if text else {}
        except json.JSONDecodeError as exc:
            raise ConfigError(f"transitions must be a JSON mapping of the guards' settings, got {text!r} ({exc.msg})") from None
        config: ModeConfig = from_mapping(ModeConfig, mapping, "transitions")
        self._prm = config.packed(self.dt)
        self._state = new_mode_state(MODE_NAMES.index(str(self.param(_P["initial_mode"]))))
        self._in = np.full(N_INPUTS, np.nan)
        self._q_err = np.zeros(4)
        self._rejected_inputs = np.zeros(2, dtype=np.int64)  # sample_verdicts' count (the controller counts its own)
        max_speed = as_finite_array("wheel_max_speed_rad_s", self.param(_P["wheel_max_speed_rad_s"]))
        if max_speed.ndim != 1 or not np.all(max_speed > 0):
            raise ConfigError(f"wheel_max_speed_rad_s must be one value > 0 per wheel, got {max_speed.tolist()!r}")
        self._max_speed = np.ascontiguousarray(max_speed, dtype=np.float64)
        at = as_finite_array("requests_at_s", self.param(_P["requests_at_s"]))
        names = list(self.param(_P["requests_mode"]))
        if at.ndim != 1 or len(names) != at.size or np.any(at < 0.0):
            raise ConfigError(f"requests_at_s (times >= 0 [s]) and requests_mode (mode names) must be lists of one length, got "
                              f"{at.tolist()!r} and {names!r}")
        for name in names:
            if name not in MODE_NAMES:
                raise ConfigError(f"requests_mode: {name!r} is not a mode (one of {', '.join(MODE_NAMES)})")
        self._requests = [(float(a), float(MODE_NAMES.index(m))) for a, m in zip(at.tolist(), names)]
        self._bounds = InputBounds(**{name: float(self.param(_P[name])) for name in _BOUNDS}).packed()
        self._ground_request: int | None = None
        self._inhibit = 0
        self._apply_ground(str(self.param(_P["request_mode"])), list(self.param(_P["inhibit"])))
        self.timing_file = str(self.param(_P["timing_file"]))
        self.check_unknown_overrides()
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._parameter_callback = True
        # load the compiled kernels now, not at the first sample (which the plant waits for)
        mode_step(new_mode_state(HOLD), self._in, self._prm)
        attitude_error_angle(np.array([0.0, 0.0, 0.0, 1.0]), np.array([0.0, 0.0, 0.0, 1.0]), self._q_err)
        sigma_of_covariance(np.eye(6))
        wheel_speed_fraction(np.zeros(1), np.ones(1))
        sample_verdicts(False, False, self._q_err, self._q_err[:3], self._q_err, self._q_err[:3], self._q_err[:3], self._bounds,
                        self._rejected_inputs)
        self._codecs = {t.name: wire.codec(t) for t in INPUTS if t is not STATE_WHEEL_SPEED}
        n_wheels = self._max_speed.size
        self._codecs[STATE_WHEEL_SPEED.name] = wire.Codec(wire.joint_state(STATE_WHEEL_SPEED, n_wheels, "speed", None), STATE_WHEEL_SPEED.name)
        self._pending: dict[int, dict[str, tuple[float, ...]]] = {}
        self.samples = 0
        self.inactive_samples = 0  # samples answered inactive (managed: module docstring, "Managed")
        self.transitions = 0
        self.rejected = 0
        self.pub_status = self.counting_publisher(MODE_STATUS, 1)
        self.pub_health = self.counting_publisher(ESTIMATOR_HEALTH, 1)  # ROS's diagnostics topic (the estimator's too)
        self._health_msg: Any = None  # the DiagnosticArray, reused
        self._health_t_s = -math.inf  # the samples' time of the last report [s]
        self._health_inactive = False  # whether the last report said inactive (a change is reported at once)
        self._since_s = 0.0  # the current mode's entry [s]
        self._wire_status = wire.codec(MODE_STATUS)
        qos = qos_profile()
        for topic in INPUTS:
            self.create_subscription(topic.msg_class, topic.name, partial(self._on_input, topic=topic), qos, raw=True)
        self.get_logger().info(f"mode manager ready (lockstep; first mode {MODE_NAMES[int(self._state[S_MODE])]}, "
                               f"{len(self._requests)} scheduled requests)")

    def release_node(self) -> None:
        """A managed node's cleanup: its parameter callback removed (its subscriptions and
        publishers are destroyed by :class:`~sappc_msgs_py.runtime.ManagedNode`); the parameters
        stay declared, and the next configure reads them again."""
        if self._parameter_callback:
            self.remove_on_set_parameters_callback(self._on_set_parameters)
            self._parameter_callback = False

    # ---- ground commands ---------------------------------------------------------------------
    def _apply_ground(self, request: str, inhibit: list[str]) -> None:
        """A ground request (a mode's name, '' none) and the inhibits, checked; raises ``ConfigError`` naming a bad one."""
        if request and request not in MODE_NAMES:
            raise ConfigError(f"request_mode: {request!r} is not a mode (one of {', '.join(MODE_NAMES)})")
        self._inhibit = _inhibit_flags(inhibit)
        if request:
            self._ground_request = MODE_NAMES.index(request)

    def _on_set_parameters(self, params: list[Any]) -> SetParametersResult:
        values = {p.name: p.value for p in params}
        if not {"request_mode", "inhibit"} & values.keys():
            return SetParametersResult(successful=True)
        request = str(values.get("request_mode", ""))
        inhibit = list(values["inhibit"]) if "inhibit" in values else [n for n, f in INHIBITS.items() if self._inhibit & f]
        try:
            self._apply_ground(request, inhibit)
        except ConfigError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        if request:
            self.get_logger().info(f"ground: {request} requested (taken at the next sample{'' if self.active else ' answered active'})")
        return SetParametersResult(successful=True)

    # ---- samples -----------------------------------------------------------------------------
    def _stamp_ns(self, raw: bytes, topic: Topic, values: tuple[float, ...]) -> int:
        if topic.frame_id is None:  # a float array of the contract: its time [s] in data[0] (exact in lockstep)
            return time_to_ns(values[0])
        return cdr_stamp_ns(topic.type_name, raw)

    def _on_input(self, raw: bytes, topic: Topic) -> None:
        values = self._codecs[topic.name].values(raw)
        if values is None:  # not the contract's layout (a wrong frame, a wrong size): rejected, the sample waits
            self.rejected += 1
            self.get_logger().warning(f"rejected a {topic.name} message of another layout ({self.rejected} so far)", throttle_duration_sec=1.0)
            return
        ns = self._stamp_ns(raw, topic, values)
        sample = self._pending.setdefault(ns, {})
        sample[topic.name] = values
        if len(sample) < len(INPUTS):
            return
        del self._pending[ns]
        for old in [k for k in self._pending if k < ns]:  # an earlier sample that never completed
            del self._pending[old]
        self._step(ns, sample)

    def _step(self, t_ns: int, sample: dict[str, tuple[float, ...]]) -> None:
        """One sample (module docstring): the kernel's inputs as the offline loop makes them, its step,
        ``mode/status``; inactive, the mode held (:meth:`_answer_inactive`)."""
        if not self.active:
            self._answer_inactive(t_ns)
            return
        mode_in = self._in
        gyro = sample[SENSOR_GYRO.name][_IMU_OMEGA:_IMU_OMEGA + 3]
        gyro_in = all(map(math.isfinite, gyro))
        mode_in[IN_RATE] = math.sqrt((gyro[0] * gyro[0] + gyro[1] * gyro[1]) + gyro[2] * gyro[2]) if gyro_in else math.nan
        P = np.array(sample[ESTIMATOR_COVARIANCE.name][1:37]).reshape(6, 6)
        has_estimate = math.isfinite(P[0, 0])  # the estimator's figures ("no data": NaN)
        mode_in[IN_HEALTH] = sample[ESTIMATOR_DIAGNOSTICS.name][_MONITOR_LEVEL] if has_estimate else math.nan
        mode_in[IN_SIGMA] = sigma_of_covariance(P) if has_estimate else math.nan
        mode_in[IN_LOST] = 0.0
        mode_in[IN_WHEEL] = wheel_speed_fraction(np.array(sample[STATE_WHEEL_SPEED.name]), self._max_speed) if self._max_speed.size else math.nan
        k = t_ns // self.dt_ns
        t = float(k) * self.dt  # the offline grid's time of the sample (sappc.evaluation.metrics.SampleGrid)
        mode_in[IN_REQUEST] = -1.0
        for at_s, requested in self._requests:  # the first sample at or after the request's time
            if t >= at_s and t - self.dt < at_s:
                mode_in[IN_REQUEST] = requested
        if self._ground_request is not None:
            mode_in[IN_REQUEST] = float(self._ground_request)
            self._ground_request = None
            self.set_parameters([_parameter("request_mode", "")])
        mode_in[IN_INHIBIT] = float(self._inhibit)
        q = np.array(sample[ESTIMATE_ATTITUDE.name])
        w = np.array(sample[ESTIMATE_RATE.name])
        q_r, w_r, wd_r = (np.array(sample[t_.name]) for t_ in (REFERENCE_ATTITUDE, REFERENCE_RATE, REFERENCE_ACCELERATION))
        state_in = bool(np.all(np.isfinite(q)) and np.all(np.isfinite(w)))  # the estimator's "no data": NaN
        reference_in = bool(np.all(np.isfinite(q_r)) and np.all(np.isfinite(w_r)) and np.all(np.isfinite(wd_r)))
        valid = sample_verdicts(state_in, reference_in, q, w, q_r, w_r, wd_r, self._bounds, self._rejected_inputs)
        mode_in[IN_ERROR] = attitude_error_angle(q_r, q, self._q_err) if valid else math.nan
        reason = int(mode_step(self._state, mode_in, self._prm))
        mode = int(self._state[S_MODE])
        t_s = t_ns / NS_PER_S
        if reason != R_NONE:
            self.transitions += 1
            self._since_s = t_s
            self.get_logger().info(f"t = {t_s:.2f} s: {MODE_NAMES[mode]} ({REASON_NAMES[reason]})")
        self.pub_status.publish(self._wire_status.encode(None, [t_s, float(mode), float(reason)]))
        if reason != R_NONE or self.samples == 0 or self._health_inactive or t_s - self._health_t_s >= HEALTH_PERIOD_S:
            self._report(t_ns, mode)
        self.samples += 1

    def _answer_inactive(self, t_ns: int) -> None:
        """Sample ``t_ns`` answered by an inactive node (module docstring, "Managed"): the mode held,
        reason none, no kernel step, no request taken; ``diagnostics`` says so at once and then at
        least every :data:`HEALTH_PERIOD_S`."""
        mode = int(self._state[S_MODE])
        t_s = t_ns / NS_PER_S
        self.pub_status.publish(self._wire_status.encode(None, [t_s, float(mode), float(R_NONE)]))
        if not self._health_inactive or t_s - self._health_t_s >= HEALTH_PERIOD_S:
            self._report(t_ns, mode, inactive=True)
        self.samples += 1
        self.inactive_samples += 1

    def _report(self, t_ns: int, mode: int, inactive: bool = False) -> None:
        """``diagnostics`` (ROS's health convention): the mode in words, at each transition and at
        least every :data:`HEALTH_PERIOD_S` of the samples' time; ERROR in SAFE, else OK; inactive
        (managed), a warning that says so (ERROR still in SAFE)."""
        t_s = t_ns / NS_PER_S
        self._health_t_s = t_s
        self._health_inactive = inactive
        entry = REASON_NAMES[int(self._state[S_REASON])] if self.transitions else "initial"
        values = {"time_s": f"{t_s:.9f}", "mode": MODE_NAMES[mode], "since_s": f"{self._since_s:.9f}", "reason": entry,
                  "transitions": str(self.transitions), "inhibit": ",".join(n for n, f in INHIBITS.items() if self._inhibit & f)}
        level = HEALTH_ERROR if mode == SAFE else HEALTH_WARN if inactive else HEALTH_OK
        message = f"{MODE_NAMES[mode]} since {self._since_s:.2f} s ({entry})" + (": the mission is interrupted" if mode == SAFE else "")
        if inactive:
            message = f"{INACTIVE_MESSAGE}; {message}"
        self._health_msg = health_msg(ns_to_stamp(t_ns), level, message, values, out=self._health_msg, name=MODE_HEALTH_NAME,
                                      hardware_id="sappc_modes")
        self.pub_health.publish(self._health_msg)

    # ---- lifecycle --------------------------------------------------------------------------
    def on_activate(self, state: Any) -> Any:
        """An activation: the flight goes on from the mode held, every guard's count restarted (as
        at a transition: each condition counts again from here); then active, from the next sample."""
        restart_counts(self._state)
        return super().on_activate(state)

    # ---- the end --------------------------------------------------------------------------
    def finish(self) -> None:
        if self.finished_unconfigured():
            return
        inactive = f" ({self.inactive_samples} inactive)" if self.managed else ""
        self.get_logger().info(f"finished: {self.samples} samples{inactive}, {self.transitions} transitions, last mode "
                               f"{MODE_NAMES[int(self._state[S_MODE])]}, {self.rejected} rejected messages")
        super().finish()
        if self.timing_file:
            counts = {"samples": self.samples, "transitions": self.transitions, "rejected": self.rejected,
                      **({"inactive_samples": self.inactive_samples} if self.managed else {})}
            Path(self.timing_file).write_text(json.dumps(counts))


def _parameter(name: str, value: Any) -> Any:
    """rclpy's ``Parameter`` ``name`` = ``value``."""
    from rclpy.parameter import Parameter

    return Parameter(name, value=value)


def main(argv: list[str] | None = None) -> int:
    """Run the mode node until stopped."""
    return run_node(lambda args: ModeNode(), argv, ModeNode)


if __name__ == "__main__":
    sys.exit(main())

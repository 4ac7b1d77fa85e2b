"""The plant node (``python -m spacecraft_sim``): a rigid body on the ROS 2 graph.

It publishes the measured attitude and body rate (``state/attitude``, ``state/rate``, see
:mod:`sappc_msgs_py.contract`) and the body frame in the inertial frame (``state/tf``: a
``TransformStamped`` with the same stamp and quaternion, for tf-style viewers), applies the torque received on ``control/torque`` plus, when
``use_disturbance_topic`` is true, the torque received on ``disturbance/torque``, and integrates
with the plant core (:class:`~spacecraft_sim.core.dynamics.RigidBody`, RK4, zero-order hold).

Modes (parameter ``mode``):

``lockstep`` (default)
    The plant owns time.  It publishes nothing before its partners are there: a publisher of the
    torque (the controller) and of the disturbance when it uses one, its expected subscribers,
    and every ``/clock`` subscriber on the graph matched, so a plant and a controller started
    in any order by hand lose no sample to discovery.  For sample ``k`` it publishes ``/clock`` = ``t_k = k dt``, then the
    state stamped ``t_k``; it waits for the torque (and disturbance) stamped ``t_k`` (inputs that
    arrive ahead of their sample are kept until it comes), then
    integrates over ``[t_k, t_k+1]``.  This is the offline runner's timing
    (:mod:`sappc.offline.compiled_loop`), so the results are the same.  When an input stamped ``t_k`` does
    not arrive within ``lockstep_timeout_s`` of wall time, the last received value is held (as
    an actuator holds its last command), the miss is counted and logged, and the run goes on.
    After sample ``n = duration_s / dt`` (and its torque) the node finishes.
``realtime``
    The plant runs in the frames of :mod:`sappc_msgs_py.timeline` (frame ``f`` starts at
    ``f dt`` on the system clock; its timer is phased to the frames' starts).  At the tick of
    frame ``f`` it integrates every frame since the previous tick, each with the torque held
    (zero-order hold: the latest received, as an actuator holds its last command) and the
    disturbance of that frame (the injector publishes it ahead), then publishes the state stamped
    ``f dt``.  Sample 0, the initial state, is published
    :data:`~sappc_msgs_py.timeline.START_LEAD_FRAMES` frames before its frame ``f0`` (the state
    holds until then), so that its reference, disturbance and torque are there before the first
    integration.  The world does not wait: a late tick integrates the frames it missed, and
    publishes their states too, late (the sensors skip no sample; each frame is measured with its
    own draws, as offline), which are counted (``missed_frames``), and so is every frame whose
    torque is not the controller's answer
    to that frame's state (``stale_torque_frames``: the controller missed its deadline, or had
    no state), and every frame integrated without the disturbance of its own stamp
    (``stale_disturbance_frames``).  No ``/clock``.  Sample ``k`` is frame ``f0 + k``, ``f0`` the
    frame ``START_LEAD_FRAMES`` after the first tick once the partners are matched (the reference and the injector take
    ``f0`` from that first state: :class:`~sappc_msgs_py.runtime.FramesAhead`, so the plant also
    waits for their ``state/attitude`` subscriptions).  After the state of the last frame
    (``n = duration_s / dt``; a late tick that skipped it still publishes it) the node finishes
    at the next tick: the controller has that frame to answer the last state, whose torque is
    received and recorded, not applied, as in lockstep; nothing is published past the last
    frame.

Every parameter is checked at start-up by the same functions the scenario loader uses
(:mod:`gnc_common.validation`); a missing or invalid one stops the node with one line naming it
(exit status 2).

Control torques are clipped to ``max_torque_Nm`` per axis (the actuator cannot do more whatever it is
commanded); a torque message that is non-finite or in the wrong frame is rejected, counted and
logged, and the previous value is held.

Backends (parameter ``backend``; ``python -m spacecraft_sim --backend basilisk`` sets it): ``native``,
the project's compiled plant, or ``basilisk``, Basilisk's spacecraft hub and reaction-wheel
effector (:mod:`spacecraft_sim.basilisk_plant`, the ``[basilisk]`` extra) stepped one period at a
time on the same inputs: the same topics either way.

Sensor models (parameter ``sensors``, the scenario's ``sensors`` mapping as JSON): ``state/*``
carry the star tracker's and the gyro's measurement of each sample
(:func:`spacecraft_sim.core.sensors.measure`, sample ``k`` drawing the ``k``-th row of the seed's
stream, as the offline loop does) and ``truth/attitude``, ``truth/rate`` the true state; in real
time the state of a frame whose tick was missed is measured and published late, at the next tick.
The tracker's epoch (``sensors/star_tracker``'s stamp, ``state/attitude_epoch``'s ``time_ref``) is
integer nanoseconds; the sensor kernel holds it as a float offset from sample 0's stamp
(:func:`tracker_epoch_offset`), never as a float of absolute nanoseconds (docs/how-to/realtime.md,
"Time").

Reaction wheels (parameter ``wheels``, the scenario's ``actuator.wheels`` mapping as JSON): the
held body-torque command goes through the wheels (:mod:`spacecraft_sim.core.wheels`: allocation,
motor and speed limits, their momentum in the dynamics) instead of the per-axis clip, and each
sample's wheel speeds and motor torques are published on ``joint_states``
(``sensor_msgs/JointState``, stamped with the sample), before the plant integrates over it: the
offline loop's order and kernels, so a lockstep bag equals the offline run.

An orbit (parameters ``orbit``, ``magnetorquers``, ``magnetometer``: the scenario's sections as
JSON; lockstep and the native backend only): each sample the plant computes its position, the
Earth's field and the magnetometer's reading with the offline loop's kernels
(:mod:`spacecraft_sim.core.environment`), publishes the reading on ``state/magnetic_field`` (and
the true field on ``truth/magnetic_field`` with a magnetometer), and, with
``publish_wheel_speed``, the wheels' tachometers on ``state/wheel_speed``; with
``use_dipole_topic`` it waits for the rods' commands of the sample on ``control/dipole`` (the
momentum-management node's) as for the torque; the gravity gradient and the rods' ``m x B`` are
then held over the period beside the disturbance, as offline, so a lockstep bag equals the
offline run.

Parameters: :data:`PARAMETERS` (``python -m spacecraft_sim --help``), and those of
:class:`~sappc_msgs_py.runtime.ProjectNode`.
"""

from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from sappc_msgs_py.contract import (CLOCK, CONTROL_DIPOLE, CONTROL_TORQUE, STATE_MAGNETIC_FIELD, STATE_WHEEL_SPEED, TRUTH_MAGNETIC_FIELD, DISTURBANCE_TORQUE,
                                   SENSOR_GYRO, SENSOR_STAR_TRACKER, STATE_ATTITUDE, STATE_ATTITUDE_EPOCH, STATE_RATE, STATE_TF, TRUTH_ATTITUDE,
                                   TRUTH_GYRO_BIAS, TRUTH_RATE,
                                   WHEEL_STATES, qos_profile)
from sappc_msgs_py import wire
from sappc_msgs_py.convert import (
    cdr_stamp_ns,
    dipole_from_msg,
    ns_to_stamp,
    time_to_ns,
    torque_from_msg,
)
from sappc_msgs_py.parameters import Param
from sappc_msgs_py.runtime import LOCKSTEP, MATCH_TIMEOUT_S, MODE, REALTIME, ProjectNode, StartGate, run_node, unmatched
from sappc_msgs_py.timeline import AHEAD_FRAMES, PLANT_PHASE, START_LEAD_FRAMES, StampedWindow, frame_index, period_ns
from gnc_common.timing import LatencyStatistics, PeriodStatistics

from spacecraft_sim.basilisk_plant import BasiliskPlant
from spacecraft_sim.core.dynamics import RigidBody, initial_state
from spacecraft_sim.core.environment import (Environment, environment_field, environment_from_mapping, environment_measure_field, environment_torque_B,
                                             locked_inertia, pack_environment)
from spacecraft_sim.core.faults import FaultSchedule, faults_from_list
from spacecraft_sim.core.sensors import G_SIGMA, N_SENSOR_DRAWS, S_BIAS0, ST_SIGMA, Sensors, measure, sensors_from_mapping
from spacecraft_sim.core.wheels import ReactionWheels, allocation_matrix, propagate_wheels_into, wheel_speeds_into, wheel_torques, wheels_from_mapping
from gnc_common.validation import ConfigError, InputError, as_finite_array, check_initial_quaternion, check_positive, check_positive_int, inertia_from_row_major

__all__ = ["BACKENDS", "PARAMETERS", "PlantNode", "main", "tracker_epoch_ns", "tracker_epoch_offset"]

#: The plant's dynamics (parameter ``backend``).
BACKENDS = ("native", "basilisk")

#: The plant node's parameters (``--help``), in the order the node declares them.
PARAMETERS = (
    Param("inertia_kg_m2", [4.0, 0.0, 0.0, 0.0, 4.0, 0.0, 0.0, 0.0, 4.0], "the body's inertia J about its centre of mass, in B, row major",
          "kg m^2", check="9 values of a symmetric positive definite matrix"),
    Param("q_BN0", [0.0, 0.0, 0.0, 1.0], "initial attitude of the body frame B relative to the inertial frame N, quaternion (x, y, z, w)",
          check="a unit quaternion to rounding (it is normalised)"),
    Param("omega_BN_B0_rad_s", [0.0, 0.0, 0.0], "initial body rate of B relative to N, in B", "rad/s", check="3 finite values"),
    Param("control_period_s", 0.01, "sample period dt: a sample every dt, the torque held over it (zero-order hold)", "s", check="> 0"),
    Param("duration_s", 60.0, "the run's length: samples k = 0 .. duration_s / dt, then the node finishes (0: until stopped, real time only)",
          "s", check=">= 0"),
    Param("rk4_substeps", 1, "RK4 steps per sample period", check="a positive integer"),
    Param("max_torque_Nm", 0.5, "per-axis limit of the applied control torque (the paper's actuator); commands beyond it are clipped",
          "N m", check="> 0"),
    MODE,
    Param("lockstep_timeout_s", 2.0, "lockstep: wall time a sample waits for its torque (and disturbance) before the last value is held",
          "s", check="> 0"),
    Param("wheels", "", "reaction wheels: the scenario's actuator.wheels mapping as JSON (spin_axes_B, spin_inertia_kg_m2, "
          "max_torque_Nm, max_speed_rad_s, ...); '' for the ideal actuator", check="a JSON mapping of ReactionWheels, or ''"),
    Param("sensors", "", "sensor models: the scenario's sensors mapping as JSON (star_tracker, gyro, seed): state/* then carry "
          "the measurements and truth/* the true state; '' for exact measurements", check="a JSON mapping of Sensors, or ''"),
    Param("sensor_faults", "", "with sensor models: the scenario's faults list as JSON; the rate bias of each sensor_bias fault "
          "(which the injector adds to the measured rate) is added to the gyro's true bias published on truth/gyro_bias, the "
          "truth an estimator is judged against; the other faults change nothing here; '' for none",
          check="a JSON list of faults (the scenario's faults section), or ''"),
    Param("backend", "native", "the dynamics: 'native' (the project's compiled plant) or 'basilisk' (Basilisk's spacecraft hub and "
          "reaction-wheel effector, the [basilisk] extra)", check="'native' or 'basilisk'"),
    Param("orbit", "", "an orbit: the scenario's orbit mapping as JSON (altitude or a Keplerian orbit, magnetic_field, gravity_gradient); "
          "lockstep and the native backend only; '' for none (the paper's inertial setting)", check="a JSON mapping of the orbit section, or ''"),
    Param("magnetorquers", "", "torque rods: the scenario's magnetorquers mapping as JSON (axes_B, max_dipole_Am2); needs orbit; '' for none",
          check="a JSON mapping of Magnetorquers, or ''"),
    Param("magnetometer", "", "the magnetometer read on state/magnetic_field: the scenario's magnetometer mapping as JSON (noise_T, bias_T, "
          "rate_hz, seed); needs orbit; '' for the true field, exactly", check="a JSON mapping of Magnetometer, or ''"),
    Param("use_dipole_topic", False, "wait each sample for the rods' commands on control/dipole (a momentum-management node's) and apply "
          "them; false: the rods command nothing (needs magnetorquers)"),
    Param("publish_wheel_speed", False, "publish the wheels' tachometers on state/wheel_speed with each state, for a momentum-management "
          "node (needs wheels and orbit)"),
    Param("use_disturbance_topic", False, "add the torque received on disturbance/torque (the injector's) to the control torque"),
    Param("timing_file", "", "where to write the run's timing (JSON: wall time from the first sample to the last one answered, samples, misses; real time: the "
          "timer's period error, missed frames, frames with a stale torque); '' for none"),
)
_P = {p.name: p for p in PARAMETERS}



def _time_and_values(values: tuple[float, ...]) -> tuple[float, np.ndarray] | None:
    """:func:`~sappc_msgs_py.wire.take`'s pick of a ``control/dipole`` of the layout: ``(time_s,
    dipoles)`` when every value is finite (what :func:`~sappc_msgs_py.convert.dipole_from_msg` gives)."""
    return (values[0], np.array(values[1:])) if all(map(math.isfinite, values)) else None


class PlantNode(ProjectNode):
    """See the module docstring."""

    PARAMETERS = PARAMETERS
    COMMAND = "python -m spacecraft_sim"

    def __init__(self, node_name: str = "plant", **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        J = inertia_from_row_major("inertia_kg_m2", self.param(_P["inertia_kg_m2"]))
        self.body = RigidBody(J)  # checks J with check_spd_inertia, as the scenario loader does
        q0 = check_initial_quaternion("q_BN0", self.param(_P["q_BN0"]))  # normalised
        w0 = as_finite_array("omega_BN_B0_rad_s", self.param(_P["omega_BN_B0_rad_s"]), shape_tail=(3,))
        self.x = initial_state(np.atleast_2d(q0), np.atleast_2d(w0))
        self.dt = check_positive("control_period_s", self.param(_P["control_period_s"]))
        duration = check_positive("duration_s", self.param(_P["duration_s"]), allow_zero=True)
        self.substeps = check_positive_int("rk4_substeps", self.param(_P["rk4_substeps"]))
        self.max_torque = check_positive("max_torque_Nm", self.param(_P["max_torque_Nm"]))  # the paper's actuator
        self.mode = self.mode_param()
        if self.mode == LOCKSTEP and duration == 0.0:
            raise ConfigError("duration_s must be > 0 in lockstep mode")
        self.timeout_s = check_positive("lockstep_timeout_s", self.param(_P["lockstep_timeout_s"]))
        self.use_disturbance = bool(self.param(_P["use_disturbance_topic"]))
        self.timing_file = str(self.param(_P["timing_file"]))
        self._wall_first: float | None = None  # monotonic time of the first sample's state, and of the run's end (the last sample answered)
        self._wall_last: float | None = None
        self.n_steps = int(round(duration / self.dt))  # samples k = 0 .. n_steps, as sample_times()
        self.wheels = _wheels_param(str(self.param(_P["wheels"])))
        self.sensors = _sensors_param(str(self.param(_P["sensors"])), self.dt)
        self._bias_faults = FaultSchedule(_faults_param(str(self.param(_P["sensor_faults"]))))  # (read always: every parameter declared)
        if self.sensors is not None:  # the measurement's state, and sample k's draws from the seed's stream
            self._sensor_prm, self._outages = self.sensors.params(self.dt), self.sensors.outages()
            self._sensor_rng = np.random.default_rng(self.sensors.seed)
            # the tracker's held quaternion and its epoch: a float of nanoseconds since the epoch
            # origin (sample 0's stamp, _epoch_origin_ns), exact below 2^53 ns (104 days of run); never
            # absolute nanoseconds (a real-time stamp, ~1.8e18 ns, is 256 ns from its neighbours in a float)
            self._held_q, self._bias, self._y = np.zeros(5), self._sensor_prm[S_BIAS0:S_BIAS0 + 3].copy(), np.zeros(8)
            self._epoch_origin_ns: int | None = None  # sample 0's stamp: 0 in lockstep, frame f0's start in real time
            self.pub_truth_att = self.counting_publisher(TRUTH_ATTITUDE)
            self.pub_truth_rate = self.counting_publisher(TRUTH_RATE)
            self.pub_truth_bias = self.counting_publisher(TRUTH_GYRO_BIAS)
            self.pub_epoch = self.counting_publisher(STATE_ATTITUDE_EPOCH)
            # the sensors on their own topics: the gyro each sample, the tracker each sample it makes
            self.pub_gyro = self.counting_publisher(SENSOR_GYRO)
            self.pub_tracker = self.counting_publisher(SENSOR_STAR_TRACKER)
            self._gyro_variance = self._sensor_prm[G_SIGMA:G_SIGMA + 3] ** 2
            self._tracker_variance = self._sensor_prm[ST_SIGMA:ST_SIGMA + 3] ** 2
            self._tracker_epoch_ns: int | None = None  # the last tracker sample published
            self._bias_k = np.zeros(3)  # the bias in sample k's rate (measure walks _bias on to k + 1), faults included
            self._bias_faults.gyro_bias_fault(0.0)  # load the compiled kernel now
            measure(0, 0.0, 0.0, self.x[0, :4], self.x[0, 4:], np.zeros(N_SENSOR_DRAWS), self._sensor_prm, self._outages, np.zeros(5),
                    self._bias.copy(), np.zeros(8))  # load the compiled kernel now
        backend = str(self.param(_P["backend"]))
        if backend not in BACKENDS:
            raise ConfigError(f"backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
        self.bsk: BasiliskPlant | None = None
        if backend == "basilisk":  # the torque arrives clipped (ideal actuator) or goes through the wheels
            self.bsk = BasiliskPlant(self.body.J, q0, w0, self.dt, self.substeps, wheels=self.wheels)
        if self.wheels is not None:
            w = self.wheels
            self._u_wheels, self._speeds = np.zeros(w.n), np.zeros(w.n)  # what joint_states publishes
            self.pub_wheels = self.counting_publisher(WHEEL_STATES)
            self._wire_wheels = wire.Codec(wire.joint_state(WHEEL_STATES, w.n, "speed", "effort"), WHEEL_STATES.name)
            if self.bsk is None:  # the native wheels: state (q, omega, h), the allocation and scratch, once
                self.xw = np.concatenate((self.x[0], w.initial_momentum(self.x[0, 4:])))
                self._G, self._Gp, self._wprm = w.G, allocation_matrix(w.G), w.params()
                self._J, self._J_inv = np.ascontiguousarray(self.body.J), np.ascontiguousarray(self.body.J_inv)
                self._wwork, self._wtmp = np.zeros((5, 7 + w.n)), np.zeros((3, 3))
                self._step_wheels(np.zeros(3), np.zeros(3), None)  # load the compiled kernels now, not at the first sample (state kept)

        self.body.propagate(self.x, np.zeros((1, 3)), self.dt, self.substeps)  # load the compiled plant now, not at the first sample
        self.x = np.ascontiguousarray(self.x)  # the native plant's two state buffers (1, 7) and its torque (1, 3)
        self._x_next, self._u_B = np.empty_like(self.x), np.zeros((1, 3))
        qos = qos_profile()
        self.pub_att = self.counting_publisher(STATE_ATTITUDE, 1)
        self.pub_rate = self.counting_publisher(STATE_RATE, 1)
        self.pub_tf = self.counting_publisher(STATE_TF)  # nobody needs it to fly: waits only for expected_subscribers
        # the loop's topics as CDR bytes (sappc_msgs_py.wire): published and taken without message objects
        self._wire = {t: wire.codec(t) for t in (CLOCK, STATE_ATTITUDE, STATE_RATE, STATE_TF, CONTROL_TORQUE, DISTURBANCE_TORQUE, TRUTH_ATTITUDE,
                                                 TRUTH_RATE, TRUTH_GYRO_BIAS, SENSOR_GYRO, SENSOR_STAR_TRACKER, STATE_ATTITUDE_EPOCH)}
        self.pub_clock = self.counting_publisher(CLOCK) if self.mode == LOCKSTEP else None
        self._inputs = {"torque": self.create_subscription(CONTROL_TORQUE.msg_class, CONTROL_TORQUE.name, self._on_torque, qos, raw=True)}
        if self.use_disturbance:
            self._inputs["disturbance"] = self.create_subscription(DISTURBANCE_TORQUE.msg_class, DISTURBANCE_TORQUE.name, self._on_disturbance,
                                                                   qos, raw=True)

        self.torque = np.zeros((1, 3))
        self.disturbance = np.zeros((1, 3))
        self.rejected = 0
        self.missed = {"torque": 0, "disturbance": 0}
        self.k = 0
        # lockstep: the stamp (ns) the plant waits for, and which inputs arrived for it
        self._waiting_ns: int | None = None
        self._inbox: dict[str, dict[int, np.ndarray]] = {"torque": {}}  # stamp -> value, per input
        if self.use_disturbance:
            self._inbox["disturbance"] = {}
        self._setup_orbit(qos)  # issue 36: the orbit, the field, the rods (their own block, below)
        self._waiting_since = 0.0
        if self.mode == LOCKSTEP:
            self._watchdog = self.create_timer(min(0.05, self.timeout_s / 4), self._check_timeout)
            self._created = time.monotonic()
            self.start_when(self._not_ready, self._publish_sample)
        else:
            self.dt_ns = period_ns(self.dt)
            self._frame: int | None = None  # the frame of the last state published
            self._frame0 = 0  # the first frame (sample 0)
            self._torque_ns: int | None = None  # stamp of the torque held
            self._disturbances: StampedWindow[np.ndarray] = StampedWindow(4 * AHEAD_FRAMES)  # published ahead, by stamp
            self.missed_frames = 0  # frames without a tick of their own (integrated at the next tick)
            self.stale_torque_frames = 0  # frames integrated with a torque that does not answer their state
            self.stale_disturbance_frames = 0  # frames integrated without the disturbance of their own stamp (the one before held)
            self.first_deviating_sample: int | None = None  # the first sample that did not run as in lockstep (_note_deviation)
            self.tick_stats = PeriodStatistics(self.dt)  # the timer's period error, in bounded memory
            self.tick_delay = LatencyStatistics(self.dt)  # when the state was out, after its frame's start
            self._gate = StartGate(self, self._not_ready)  # no publish may block a tick
            self.create_frame_timer(self.dt, PLANT_PHASE, self._realtime_tick)

    # ---- inputs ---------------------------------------------------------------------------
    def _decode(self, raw: bytes, topic: Any) -> np.ndarray | None:
        """The torque of a message, (1, 3) [N m], clipped to the ideal actuator's limit; ``None``
        for a rejected message (counted and logged)."""
        values = self._wire[topic].values(raw)  # a message of the layout, finite (NaN and Inf propagate to the sum)
        if values is None or not math.isfinite(sum(values)):  # anything else: the decoder names what is wrong
            try:
                values = tuple(np.asarray(wire.take(raw, topic, lambda msg: torque_from_msg(msg, topic), self._wire[topic])).reshape(3).tolist())
            except InputError as exc:
                self.rejected += 1
                self.get_logger().warning(f"rejected a message ({self.rejected} so far): {exc}")
                return None
        if topic is CONTROL_TORQUE and self.wheels is None:  # the ideal actuator's limit (on finite floats, as numpy's clip); the wheels have their own
            m = self.max_torque
            return np.array(([min(max(v, -m), m) for v in values],))
        return np.array((values,))

    def _on_torque(self, raw: bytes) -> None:
        self._on_input(raw, CONTROL_TORQUE, "torque")

    def _on_disturbance(self, raw: bytes) -> None:
        self._on_input(raw, DISTURBANCE_TORQUE, "disturbance")

    def _on_input(self, raw: bytes, topic: Any, which: str) -> None:
        value = self._decode(raw, topic)
        if value is None:
            return
        ns = cdr_stamp_ns(topic.type_name, raw)
        if self.mode == REALTIME:
            if which == "torque":
                self.torque, self._torque_ns = value, ns
            else:
                self._disturbances.add(ns, value)
            return
        if self._waiting_ns is not None and ns < self._waiting_ns:
            return  # a late answer to a sample already integrated (after a timeout)
        self._inbox[which][ns] = value  # inputs may arrive ahead of their sample (the injector publishes one ahead)
        self._try_advance()

    def _try_advance(self) -> None:
        ns = self._waiting_ns
        if ns is None or not all(ns in box for box in self._inbox.values()):
            return
        for which, box in self._inbox.items():
            setattr(self, which, box.pop(ns))
        self._advance()

    # ---- lockstep -------------------------------------------------------------------------
    def _not_ready(self) -> list[str]:
        """What the first sample still waits for (empty: ready).

        A sample published before the controller is there is lost (the topics are volatile) and
        the loop stalls for ``lockstep_timeout_s``.  So the plant waits for a publisher of each of
        its inputs (the controller's torque, the injector's disturbance), its expected
        subscribers, and, for at most :data:`~sappc_msgs_py.runtime.MATCH_TIMEOUT_S`, for every
        ``/clock`` subscriber on the graph to be matched (a node that subscribes with an
        incompatible QoS is never matched: the plant then starts without it, and says so).
        """
        missing = [f"a publisher of {sub.topic_name}" for sub in self._inputs.values() if sub.get_publisher_count() < 1]
        missing += unmatched([p for p in (self.pub_att, self.pub_rate, self.pub_tf, self.pub_clock, *self._orbit_publishers) if p is not None])
        if self.pub_clock is None:  # real time: no /clock
            return missing
        on_graph, matched = self.count_subscribers(self.pub_clock.resolved_name), self.pub_clock.pub.get_subscription_count()
        if not missing and matched < on_graph:
            if time.monotonic() - self._created < MATCH_TIMEOUT_S:
                missing.append(f"{on_graph - matched} of the {on_graph} {self.pub_clock.resolved_name} subscribers on the graph to match")
            else:
                self.get_logger().warning(f"{on_graph - matched} {self.pub_clock.resolved_name} subscriber(s) on the graph never matched "
                                          f"(an incompatible QoS?); starting without them")
        return missing

    def _publish_sample(self) -> None:
        t = self.k * self.dt  # the grid of spacecraft_sim.core.reference.sample_times
        assert self.pub_clock is not None
        t_ns = time_to_ns(t)
        self.pub_clock.publish(self._wire[CLOCK].encode(t_ns))
        self._publish_state(t, t_ns)
        if self._env is not None:
            self._publish_orbit(t)
        self._waiting_ns = t_ns
        self._waiting_since = time.monotonic()
        self._try_advance()  # the disturbance may already be there

    def _advance(self) -> None:
        waiting = self._waiting_ns
        if waiting is not None:
            for box in self._inbox.values():  # drop what belongs to this sample or earlier
                for old in [k for k in box if k <= waiting]:
                    del box[old]
        self._waiting_ns = None
        if self.k >= self.n_steps:  # the last sample's torque is received (and recorded), not applied
            if self.wheels is not None:
                self._wheel_command(self.torque[0], self.k * self.dt)
            self._wall_last = time.monotonic()  # the run's last sample is answered: the loop is over
            self.finished = True
            return
        self._integrate(self.torque[0], self.disturbance[0], self.k * self.dt)
        self.k += 1
        self._publish_sample()

    def _check_timeout(self) -> None:
        if self._waiting_ns is None or time.monotonic() - self._waiting_since < self.timeout_s:
            return
        missing = [w for w, box in self._inbox.items() if self._waiting_ns not in box]
        for which in missing:
            self.missed[which] += 1
        for which, box in self._inbox.items():
            if self._waiting_ns in box:
                setattr(self, which, box.pop(self._waiting_ns))
        self.get_logger().warning(
            f"t = {self.k * self.dt:.3f} s: no {' and no '.join(missing)} within {self.timeout_s} s; holding the last value "
            f"(missed so far: {self.missed})"
        )
        self._advance()

    # ---- real time ------------------------------------------------------------------------
    def _realtime_tick(self) -> None:
        if not self._gate.open():
            return
        self.tick_stats.tick(time.monotonic_ns())
        now_ns = self.get_clock().now().nanoseconds
        f = frame_index(now_ns, self.dt_ns, PLANT_PHASE)
        if self._frame is None:  # sample 0, the initial state, published START_LEAD_FRAMES ahead of its frame
            f = self._frame0 = f + START_LEAD_FRAMES
        elif f <= self._frame:
            return  # a second tick in the frame (an on-time tick right after a late one): nothing to do
        elif self.n_steps and self._frame == self._frame0 + self.n_steps:
            self._end_realtime()  # the first tick after the last frame's state
            return
        else:
            if self.n_steps:  # never past the last frame: a late tick that skipped it publishes it, late
                f = min(f, self._frame0 + self.n_steps)
            self.missed_frames += f - self._frame - 1
            if f - self._frame > 1:
                self._note_deviation(self._frame + 1)
            for g in range(self._frame, f):  # each frame since the last tick, with the torque held
                stamp_ns = g * self.dt_ns
                self._count_stale_torque(stamp_ns)
                held = self._disturbances.at_or_before(stamp_ns)
                if self.use_disturbance and (held is None or held[0] != stamp_ns):
                    self.stale_disturbance_frames += 1
                    self._note_deviation(g)
                disturbance = held[1] if held is not None else self.disturbance
                self._integrate(self.torque[0], disturbance[0], ns_to_stamp(stamp_ns))
                if g + 1 < f:  # a frame whose tick was missed: its state is published too, late (the sensors skip no sample)
                    self.k = g + 1 - self._frame0
                    self._publish_state(ns_to_stamp((g + 1) * self.dt_ns))
        self._frame = f
        self.k = f - self._frame0
        self._publish_state(ns_to_stamp(f * self.dt_ns))
        if self.k == 0:
            assert self._wall_first is not None  # set by the publish
            self._wall_first += START_LEAD_FRAMES * self.dt  # the run starts at its first frame
        else:
            self.tick_delay.add(self.get_clock().now().nanoseconds - f * self.dt_ns)

    def _count_stale_torque(self, stamp_ns: int) -> None:
        """Count frame ``stamp_ns`` when the torque held over it does not answer its state."""
        if self._torque_ns is None or self._torque_ns < stamp_ns:
            self.stale_torque_frames += 1
            self._note_deviation(stamp_ns // self.dt_ns)

    def _note_deviation(self, frame: int) -> None:
        """Frame ``frame`` did not run as in lockstep (a missed tick, a stale torque or
        disturbance): the first such sample is in ``timing_file`` (``first_deviating_sample``);
        before it, the run is the lockstep run."""
        k = frame - self._frame0
        if self.first_deviating_sample is None or k < self.first_deviating_sample:
            self.first_deviating_sample = k

    def _end_realtime(self) -> None:
        """The run's end, at the tick after its last frame (``n = duration_s / dt``): the
        controller had that frame to answer the last state; its torque is received (and recorded),
        not applied, as in lockstep, and counted stale if it has not come.  No sample is published
        past the last frame, and the node's timers stop (in a composed run the executor spins on
        while the recorder drains)."""
        assert self._frame is not None  # a state was published: the tick that ends follows it
        stamp_ns = self._frame * self.dt_ns  # the last frame's (frame f0 + n)
        self._count_stale_torque(stamp_ns)
        if self.wheels is not None:  # the last sample's wheel command, as lockstep publishes it
            self._wheel_command(self.torque[0], ns_to_stamp(stamp_ns))
        self.end_run()
        self._wall_last = time.monotonic()
        self.finished = True

    # ---- the dynamics ----------------------------------------------------------------------
    def _integrate(self, torque_B: np.ndarray, disturbance_B: np.ndarray, t_s: Any) -> None:
        """One sample period from the sample stamped ``t_s``, the command and the disturbance held:
        the native rigid body, the native wheels (publishing ``joint_states``) or Basilisk; in orbit
        the environment's torque held beside the disturbance (:meth:`_orbit_torque`)."""
        if self._env is not None:
            disturbance_B = self._orbit_torque(disturbance_B)
        if self.bsk is not None:
            if self.wheels is not None:
                self._wheel_command(torque_B, t_s)
            self.bsk.step(torque_B, disturbance_B)
            self.x = self.bsk.state()[None, :7]
        elif self.wheels is not None:
            self._step_wheels(torque_B, disturbance_B, t_s)
        else:  # into the state's second buffer, then swapped (self.x is read at once by whoever reads it)
            np.add(torque_B, disturbance_B, out=self._u_B[0])
            self.body.propagate_into(self.x, self._u_B, self.dt, self.substeps, self._x_next)
            self.x, self._x_next = self._x_next, self.x

    # ---- reaction wheels -------------------------------------------------------------------
    def _wheel_command(self, torque_B: np.ndarray, t_s: Any) -> None:
        """The motor torques for the held command at the current state, published with the speeds
        on ``joint_states`` stamped ``t_s`` (``None``: not published)."""
        if self.bsk is not None:
            self._u_wheels[:] = self.bsk.motor_command(torque_B)
            self._speeds[:] = self.bsk.wheel_speeds_rad_s()
        else:
            wheel_torques(np.ascontiguousarray(torque_B, dtype=np.float64), self._Gp, self._G, self._wprm, self.xw, self._u_wheels)
            wheel_speeds_into(self.xw, self._G, self._wprm, self._speeds)
        if t_s is not None:
            self.pub_wheels.publish(self._wire_wheels.encode(time_to_ns(t_s), self._speeds, self._u_wheels))

    def _step_wheels(self, torque_B: np.ndarray, disturbance_B: np.ndarray, t_s: Any) -> None:
        """One sample period with the wheels: the command (published at ``t_s``), then the
        integration with the motor torques and the disturbance held (``t_s`` ``None``: warm-up, the
        state is left as it was)."""
        self._wheel_command(torque_B, t_s)
        x = self.xw if t_s is not None else self.xw.copy()
        propagate_wheels_into(x, self._u_wheels, np.ascontiguousarray(disturbance_B, dtype=np.float64), self.dt, self.substeps,
                              self._J, self._J_inv, self._G, self._wprm, self._wwork, self._wtmp)
        if t_s is not None:
            self.x = x[None, :7].copy()

    def _publish_state(self, t_s: Any, t_ns: int | None = None) -> None:
        """Publish the state of the sample stamped ``t_s`` (``t_ns``: its nanoseconds, when the caller has them)."""
        if self._wall_first is None:
            self._wall_first = time.monotonic()
        if t_ns is None:
            t_ns = time_to_ns(t_s)
        if self.sensors is None:
            q, w = self.x[0, :4], self.x[0, 4:]
            self.pub_att.publish(self._wire[STATE_ATTITUDE].encode(t_ns, q))
            self.pub_rate.publish(self._wire[STATE_RATE].encode(t_ns, w))
            self.pub_tf.publish(self._wire[STATE_TF].encode(t_ns, q))  # after the state: off the loop's critical path
            return
        # the sensors' measurement of sample k (the offline loop's kernel and draws), then the truth
        self._bias_k[:] = self._bias + self._bias_faults.gyro_bias_fault(self.k * self.dt)
        stamp_ns = t_ns
        if self._epoch_origin_ns is None:
            self._epoch_origin_ns = stamp_ns
        measure(self.k, self.k * self.dt, tracker_epoch_offset(stamp_ns, self._epoch_origin_ns), self.x[0, :4], self.x[0, 4:],
                self._sensor_rng.standard_normal(N_SENSOR_DRAWS), self._sensor_prm, self._outages, self._held_q, self._bias, self._y)
        wc = self._wire
        y = self._y
        self.pub_att.publish(wc[STATE_ATTITUDE].encode(stamp_ns, y[:4]))
        self.pub_rate.publish(wc[STATE_RATE].encode(stamp_ns, y[4:7]))
        epoch_ns = tracker_epoch_ns(y[7], self._epoch_origin_ns)
        if self._tracker_epoch_ns is None or epoch_ns > self._tracker_epoch_ns:  # a new tracker sample, stamped when measured
            self._tracker_epoch_ns = epoch_ns
            self.pub_tracker.publish(wc[SENSOR_STAR_TRACKER].encode(epoch_ns, wire.star_tracker_values(y[:4], self._tracker_variance)))
        self.pub_gyro.publish(wc[SENSOR_GYRO].encode(stamp_ns, wire.gyro_values(y[4:7], self._gyro_variance)))
        self.pub_epoch.publish(wc[STATE_ATTITUDE_EPOCH].encode(stamp_ns, epoch_ns))
        q_true = self.x[0, :4]
        self.pub_truth_att.publish(wc[TRUTH_ATTITUDE].encode(stamp_ns, q_true))
        self.pub_truth_rate.publish(wc[TRUTH_RATE].encode(stamp_ns, self.x[0, 4:]))
        self.pub_truth_bias.publish(wc[TRUTH_GYRO_BIAS].encode(stamp_ns, self._bias_k))
        self.pub_tf.publish(wc[STATE_TF].encode(stamp_ns, q_true))  # the body as it is

    # ---- the orbit (issue 36) -------------------------------------------------------------
    def _setup_orbit(self, qos: Any) -> None:
        """The orbit's parameters, arrays, publishers and the rods' input (none without an orbit)."""
        env = _environment_param(str(self.param(_P["orbit"])), str(self.param(_P["magnetorquers"])), str(self.param(_P["magnetometer"])), self.dt)
        self.use_dipole = bool(self.param(_P["use_dipole_topic"]))
        publish_speed = bool(self.param(_P["publish_wheel_speed"]))
        self._env: Any = None
        self._orbit_publishers: list[Any] = []
        if env is None:
            if self.use_dipole or publish_speed:
                raise ConfigError(f"use_dipole_topic and publish_wheel_speed need an orbit (parameter orbit), got use_dipole_topic={self.use_dipole}, "
                                  f"publish_wheel_speed={publish_speed} and orbit ''")
            return
        if self.mode != LOCKSTEP:
            raise ConfigError(f"orbit: the plant flies an orbit in lockstep mode only (real time: not yet), got mode {self.mode!r}")
        if self.bsk is not None:
            raise ConfigError("orbit: the basilisk backend has no orbit (its environment modules are not wired): use backend 'native'")
        if self.use_dipole and env.magnetorquers is None:
            raise ConfigError("use_dipole_topic needs magnetorquers (the rods the commands are for), got magnetorquers ''")
        if publish_speed and self.wheels is None:
            raise ConfigError("publish_wheel_speed needs wheels (their tachometers), got wheels ''")
        w = self.wheels
        locked = locked_inertia(self.body.J) if w is None else locked_inertia(self.body.J, w.per_wheel("spin_inertia_kg_m2"), w.G)
        # the offline loop's arrays for one run (run 0: the magnetometer's draws of sappc simulate)
        self._env = pack_environment(env, 1, locked, n_samples=self.n_steps + 1, control_period_s=self.dt)
        self._r_N, self._B_N, self._B_B, self._B_meas, self._L_env = (np.zeros(3) for _ in range(5))
        self._etmp = np.zeros((2, 3))
        self.dipole = np.zeros(self._env.m_max.shape[1])  # the rods' commands (zero: none)
        mag = env.magnetometer
        self._mag_variance = np.zeros(3) if mag is None else np.broadcast_to(np.asarray(mag.noise_T, dtype=np.float64), (3,)) ** 2
        self.pub_mag = self.counting_publisher(STATE_MAGNETIC_FIELD)
        self.pub_mag_truth = self.counting_publisher(TRUTH_MAGNETIC_FIELD) if mag is not None else None
        self.pub_speed = self.counting_publisher(STATE_WHEEL_SPEED) if publish_speed else None
        self._tach = np.zeros(0 if w is None else w.n)
        # as CDR bytes (sappc_msgs_py.wire): the field (the magnetometer's variance fixed), the truth, the tachometers, the rods' commands
        self._wire_mag = wire.Codec(wire.magnetic_field(STATE_MAGNETIC_FIELD, "field", self._mag_variance), STATE_MAGNETIC_FIELD.name)
        self._wire_mag_truth = wire.Codec(wire.magnetic_field(TRUTH_MAGNETIC_FIELD, "field", np.zeros(3)), TRUTH_MAGNETIC_FIELD.name)
        self._wire_speed = wire.Codec(wire.joint_state(STATE_WHEEL_SPEED, self._tach.size, "speed", None), STATE_WHEEL_SPEED.name)
        self._wire_dipole = wire.Codec(wire.dipole(self.dipole.size), CONTROL_DIPOLE.name)
        self._orbit_publishers = [p for p in (self.pub_mag, self.pub_speed) if p is not None]
        if self.use_dipole:
            self._inputs["dipole"] = self.create_subscription(CONTROL_DIPOLE.msg_class, CONTROL_DIPOLE.name, self._on_dipole, qos, raw=True)
            self._inbox["dipole"] = {}
            self.missed["dipole"] = 0
        x = self._full_state().copy()  # load the compiled kernels now, not at the first sample (state kept)
        environment_field(self._env, 0, 0.0, x[:4], self._r_N, self._B_N, self._B_B)
        environment_measure_field(self._env, 0, 0, self._B_B, self._B_meas.copy())
        environment_torque_B(self._env, 0, x[:4], self._r_N, self._B_B, self.dipole, self._etmp, self._L_env)

    def _full_state(self) -> np.ndarray:
        """The state the offline loop carries: ``(q, omega)`` with the wheels' momenta when there are wheels."""
        return self.xw if self.wheels is not None and self.bsk is None else self.x[0]

    def _on_dipole(self, raw: bytes) -> None:
        try:
            t_s, m = wire.take(raw, CONTROL_DIPOLE, lambda msg: dipole_from_msg(msg, self.dipole.shape[0]), self._wire_dipole,
                               pick=_time_and_values)
            ns = time_to_ns(t_s)  # data[0], float seconds: exact in lockstep (from 0), the only mode with an orbit
        except InputError as exc:
            self.rejected += 1
            self.get_logger().warning(f"rejected a message ({self.rejected} so far): {exc}")
            return
        if self._waiting_ns is not None and ns < self._waiting_ns:
            return  # a late answer to a sample already integrated (after a timeout)
        self._inbox["dipole"][ns] = m
        self._try_advance()

    def _publish_orbit(self, t: float) -> None:
        """Sample ``k``'s position and field (the offline loop's kernels, at ``t_k`` and the state of
        ``t_k``), the magnetometer's reading, the true field and the tachometers, published."""
        x = self._full_state()
        environment_field(self._env, 0, t, x[:4], self._r_N, self._B_N, self._B_B)
        environment_measure_field(self._env, 0, self.k, self._B_B, self._B_meas)
        t_ns = time_to_ns(t)
        self.pub_mag.publish(self._wire_mag.encode(t_ns, self._B_meas))
        if self.pub_mag_truth is not None:
            self.pub_mag_truth.publish(self._wire_mag_truth.encode(t_ns, self._B_B))
        if self.pub_speed is not None:
            wheel_speeds_into(self.xw, self._G, self._wprm, self._tach)
            self.pub_speed.publish(self._wire_speed.encode(t_ns, self._tach))

    def _orbit_torque(self, disturbance_B: np.ndarray) -> np.ndarray:
        """The disturbance plus the environment's torque (gravity gradient, the rods' ``m x B`` of the
        sample's commands in the true field), as the offline loop adds them (``d + L_env``)."""
        x = self._full_state()
        environment_torque_B(self._env, 0, x[:4], self._r_N, self._B_B, self.dipole, self._etmp, self._L_env)
        out: np.ndarray = disturbance_B + self._L_env
        return out

    def finish(self) -> None:
        # the loop: the first sample to the last one's answer (not what comes after it: a composed
        # run's recorder drain, the acknowledgements); an interrupted run's, to now
        run_s = 0.0 if self._wall_first is None else (time.monotonic() if self._wall_last is None else self._wall_last) - self._wall_first
        self.get_logger().info(f"finished at sample {self.k} after {run_s:.3f} s: {self.rejected} rejected messages, missed inputs {self.missed}")
        super().finish()
        if self.timing_file:
            timing = {"run_s": run_s, "samples": self.k + 1, "rejected": self.rejected, "missed": self.missed, "first_sample_monotonic_s": self._wall_first,
                      "nodes_up_monotonic_s": self.up_monotonic_s}
            if self.mode == REALTIME:
                timing.update(self.tick_stats.summary(), missed_frames=self.missed_frames, stale_torque_frames=self.stale_torque_frames,
                              stale_disturbance_frames=self.stale_disturbance_frames, first_deviating_sample=self.first_deviating_sample,
                              state_delay={k.replace("latency", "delay"): v for k, v in self.tick_delay.summary().items()})
            Path(self.timing_file).write_text(json.dumps(timing))


def tracker_epoch_offset(stamp_ns: int, origin_ns: int) -> float:
    """The tracker epoch the sensor kernel carries (:func:`~spacecraft_sim.core.sensors.measure`'s
    ``t_epoch``, held in a float array) for a sample stamped ``stamp_ns``: nanoseconds since the run's
    integer origin ``origin_ns`` (sample 0's stamp), as a float, exact below 2^53 ns (104 days).

    Never the absolute stamp: a real-time stamp (~1.8e18 ns since 1970) is 256 ns from its float
    neighbours, so frame ``f`` at ``f * 10 ms`` came back 128 ns late for ``f`` = 3 mod 4, a tracker
    sample dated after the gyro sample that names it (issue 46).  In lockstep the origin is 0 and the
    offset is the stamp itself, bit for bit as before."""
    return float(stamp_ns - origin_ns)


def tracker_epoch_ns(offset: float, origin_ns: int) -> int:
    """The stamp [ns, an integer] of a tracker epoch the sensor kernel held as ``offset`` (see
    :func:`tracker_epoch_offset`): exact, the origin added back as an integer."""
    return origin_ns + int(offset)


def _json_param(name: str, text: str, what: str) -> Any:
    """A JSON-mapping parameter (``wheels``, ``sensors``: the scenario's section as JSON), or
    ``None`` for ``''``; a malformed one stops with an error naming the parameter."""
    if not text.strip():
        return None
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise ConfigError(f"{name} must be a JSON mapping of {what} or '', got {text!r} ({exc.msg})") from None


def _environment_param(orbit: str, rods: str, magnetometer: str, dt: float) -> Environment | None:
    """The ``orbit``, ``magnetorquers`` and ``magnetometer`` parameters (``''``: absent), read as the
    scenario loader reads its sections; errors name the key."""
    return environment_from_mapping(_json_param("orbit", orbit, "the orbit section"), _json_param("magnetorquers", rods, "the rods"),
                                    _json_param("magnetometer", magnetometer, "the magnetometer"), dt)


def _sensors_param(text: str, dt: float) -> Sensors | None:
    """The ``sensors`` parameter (``''``: exact measurements); errors name ``sensors.<key>``."""
    data = _json_param("sensors", text, "the sensor models")
    return None if data is None else sensors_from_mapping(data, "sensors", dt)


def _faults_param(text: str) -> tuple[Any, ...]:
    """The ``sensor_faults`` parameter (``''``: none); errors name ``sensor_faults[i].<key>``."""
    if not text.strip():
        return ()
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ConfigError(f"sensor_faults must be a JSON list of faults, got {text[:80]!r} ({exc})") from None
    return faults_from_list(data, "sensor_faults")


def _wheels_param(text: str) -> ReactionWheels | None:
    """The ``wheels`` parameter (``''``: the ideal actuator); errors name ``wheels.<key>``."""
    data = _json_param("wheels", text, "the wheel set")
    return None if data is None else wheels_from_mapping(data, "wheels")


def main(argv: list[str] | None = None) -> int:
    """Run the plant node until its run ends or a signal arrives.  ``--backend NAME`` before any
    ``--ros-args`` sets the ``backend`` parameter (``-p backend:=NAME``)."""
    args = list(sys.argv if argv is None else argv)
    if "--backend" in args[: args.index("--ros-args") if "--ros-args" in args else len(args)]:
        i = args.index("--backend")
        if i + 1 >= len(args) or args[i + 1].startswith("-"):
            print("python -m spacecraft_sim: --backend needs a value: native or basilisk", file=sys.stderr)
            return 2
        backend = args[i + 1]
        del args[i : i + 2]
        args += (["-p"] if "--ros-args" in args else ["--ros-args", "-p"]) + [f"backend:={backend}"]
    return run_node(lambda a: PlantNode(), args, PlantNode)


if __name__ == "__main__":
    sys.exit(main())

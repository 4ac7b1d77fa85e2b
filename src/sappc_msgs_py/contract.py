"""The topic contract between a plant and the controller: names, message types, frames, QoS.

A plant, whatever it is, publishes the measured attitude and body rate with header stamps and
applies the torque command it receives; the controller knows nothing but these topics and its
parameters.  Topic names are relative, so a namespace (``--ros-args -r __ns:=/sc1``) moves a
whole spacecraft.

============================  ==============================  ==========  =========================================
topic                         type                            frame_id    content
============================  ==============================  ==========  =========================================
``state/attitude``            geometry_msgs/QuaternionStamped ``inertial`` measured ``q_BN`` (body relative to inertial)
``state/rate``                geometry_msgs/Vector3Stamped    ``body``     measured ``omega_BN_B`` [rad/s]
``state/attitude_epoch``      sensor_msgs/TimeReference       ``body``     ``time_ref``: when the star tracker measured ``state/attitude`` (a plant with sensor models only)
``sensors/gyro``              sensor_msgs/Imu                 ``body``     the gyro's sample: ``angular_velocity`` [rad/s], its covariance (idem)
``sensors/star_tracker``      sensor_msgs/Imu                 ``body``     the tracker's sample: ``orientation`` ``q_BN``, its covariance, stamped when measured (idem)
``reference/attitude``        geometry_msgs/QuaternionStamped ``inertial`` desired ``q_RN``
``reference/rate``            geometry_msgs/Vector3Stamped    ``reference`` desired ``omega_RN_R`` [rad/s]
``reference/acceleration``    geometry_msgs/Vector3Stamped    ``reference`` desired ``omegadot_RN_R`` [rad/s^2]
``control/torque``            geometry_msgs/WrenchStamped     ``body``     commanded torque [N m] (force zero)
``disturbance/torque``        geometry_msgs/WrenchStamped     ``body``     injected external torque [N m]
``controller/diagnostics``    std_msgs/Float64MultiArray      (none)      see :data:`DIAGNOSTICS_LAYOUT`
``/clock``                    rosgraph_msgs/Clock             (none)      simulation time (lockstep mode)
``state/tf``                  geometry_msgs/TransformStamped  ``inertial`` frame ``body`` in ``inertial``: rotation ``q_BN``
``reference/tf``              geometry_msgs/TransformStamped  ``inertial`` frame ``reference`` in ``inertial``: ``q_RN``
``joint_states``              sensor_msgs/JointState          ``body``     reaction wheels (a plant with wheels only)
``truth/attitude``            geometry_msgs/QuaternionStamped ``inertial`` true ``q_BN`` (a plant with sensor models only)
``truth/rate``                geometry_msgs/Vector3Stamped    ``body``     true ``omega_BN_B`` [rad/s] (idem)
``truth/gyro_bias``           geometry_msgs/Vector3Stamped    ``body``     the gyro's true bias in this sample's rate [rad/s] (idem)
``estimate/attitude``         geometry_msgs/QuaternionStamped ``inertial`` estimated ``q_BN`` (an estimator only)
``estimate/rate``             geometry_msgs/Vector3Stamped    ``body``     estimated ``omega_BN_B`` [rad/s] (idem)
``estimator/gyro_bias``       geometry_msgs/Vector3Stamped    ``body``     estimated gyro bias [rad/s] (idem)
``estimator/attitude_sigma``  geometry_msgs/Vector3Stamped    ``body``     1-sigma attitude error per body axis [rad]
``estimator/bias_sigma``      geometry_msgs/Vector3Stamped    ``body``     1-sigma gyro bias error per axis [rad/s]
``estimator/covariance``      std_msgs/Float64MultiArray      (none)      see :data:`COVARIANCE_DIMS`
``estimator/diagnostics``     std_msgs/Float64MultiArray      (none)      see :data:`ESTIMATOR_DIAGNOSTICS_LAYOUT`
``diagnostics``               diagnostic_msgs/DiagnosticArray (none)      the estimator's health (:data:`ESTIMATOR_HEALTH_KEYS`)
``state/magnetic_field``      sensor_msgs/MagneticField       ``body``     measured Earth's field ``B_B`` [T] (a plant in orbit only)
``truth/magnetic_field``      sensor_msgs/MagneticField       ``body``     true ``B_B`` [T] (a plant in orbit with a magnetometer only)
``state/wheel_speed``         sensor_msgs/JointState          ``body``     the wheels' tachometers at ``t_k`` (momentum management only)
``control/dipole``            std_msgs/Float64MultiArray      (none)      the rods' dipole commands [A m^2], see :data:`DIPOLE_LABEL_PREFIX`
``control/wheel_torque``      geometry_msgs/WrenchStamped     ``body``     the wheels' body torque [N m] (momentum management only)
``mode/status``               std_msgs/Float64MultiArray      (none)      the flight mode of each sample, see :data:`MODE_STATUS_LAYOUT` (flight modes only)
============================  ==============================  ==========  =========================================

A star tracker holds its last quaternion between its updates (10 Hz beside a 100 Hz loop), so
``state/attitude`` repeats a measurement; a plant with sensor models says when each was measured
on ``state/attitude_epoch`` (``sensor_msgs/TimeReference``: the header stamp is the sample's, as
``state/attitude``'s, ``time_ref`` the tracker's own time of the quaternion, ``source``
``star_tracker``).

**The sensors on their own topics** (a plant with sensor models; what an estimator reads): each
sensor publishes a sample when it makes one, stamped with the time it was measured, in
``sensor_msgs/Imu`` with the parts it does not measure marked absent (element 0 of their
covariance -1, as the message's documentation says): ``sensors/gyro`` each sample of the loop
(``angular_velocity`` and the white noise's variance per axis on its covariance's diagonal),
``sensors/star_tracker`` at the tracker's own rate (``orientation`` ``q_BN``, the body, the
header's frame, relative to inertial, and the variance of its small rotation error about each body
axis), once per tracker sample: a held value is not sent again.  ``state/attitude_epoch`` is
published with each gyro sample and names, by its ``time_ref``, the latest tracker sample at that
time: a consumer knows a new tracker sample by its stamp, never by comparing values, and a
lockstep consumer knows which tracker sample to wait for (DDS does not order one topic's messages
against another's).  A fault relay relays the three (a frozen or delayed tracker sample keeps its
epoch and is not sent again).  ``state/*`` stay as they are (the measurements at the loop's rate),
so a plant may speak either contract: ``state/*`` alone for the controller, or ``sensors/*`` with
``state/attitude_epoch`` for an estimator.

An attitude estimator (``python -m sappc_estimator``: a multiplicative EKF, ``docs/estimator.md``)
takes the sensors' ``sensors/gyro``, ``sensors/star_tracker`` and ``state/attitude_epoch`` and publishes its estimate on
``estimate/attitude`` and ``estimate/rate``, with the same types, frames and stamps as ``state/*``,
so that the controller takes it by a remap (``-r state/attitude:=estimate/attitude -r
state/rate:=estimate/rate``); ``estimator/*`` carry what plotting tools show beside it (bias,
1-sigma bounds, covariance, diagnostics), same stamps (:data:`ESTIMATOR_TOPICS`, all optional: only
a run with an estimator has them).  A sample without an estimate (its inputs arrived invalid, e.g.
the injector's "no data" for a dropped measurement; or the filter is not initialised yet) is
published as "no data" (:func:`~sappc_msgs_py.convert.no_data_msg`): NaN in every value of every
estimate topic, the sample's stamp, so that the controller counts the sample as arrived and
answers it as it answers its own dropped input; the diagnostics stay finite (but for ``nis``, NaN
until the first tracker sample was compared).  "No data" is a sample that says it has no value,
not a bad message: a consumer counts it apart from the messages it rejects
(:func:`~sappc_msgs_py.convert.is_no_data_msg`, :data:`~sappc_msgs_py.inputs.NO_DATA`).  A sample
for which the estimator has an estimate is never published as "no data": a tracker sample it
refuses (one dated after the sample that names it, a contract error) leaves the sample
propagated on the gyro, with its estimate.

Time: every stamp of the contract is integer nanoseconds (``sec``, ``nanosec``), and so is a
tracker epoch (``state/attitude_epoch``'s ``time_ref``, ``sensors/star_tracker``'s stamp).  A node
that needs a float time counts it from an integer origin (0 in lockstep, the run's first sample in
real time), never from 1970: a real-time stamp (~1.8e18 ns) is 256 ns from its neighbours in a
float64.  A sample's tracker epoch is never later than the sample's own stamp.  The float arrays'
``data[0]`` (below) is a time in seconds as a float: exact in lockstep (from 0), a label within
0.12 us in real time, read back within 1 us (``sappc.bag.read.STAMP_TOL_NS``); no node computes
with it in real time (the plant matches ``control/dipole``'s to its sample in lockstep only, the
one mode with an orbit).

Every ``std_msgs/Float64MultiArray`` of the contract carries the time it belongs to [s] in
``data[0]`` (:func:`float_array_carries_time`), so a recorder on simulated time can stamp it.

With sensor models (a star tracker, a gyro: :mod:`spacecraft_sim.core.sensors`) ``state/*`` carry
what the sensors measure, as the contract says, and the plant adds the true state on
``truth/attitude`` and ``truth/rate``, and the gyro's true bias in the sample's rate
(``truth/gyro_bias``: what an estimator's bias estimate is judged against), same stamps: for the
record and the metrics, never for the controller.  Without sensor models ``state/*`` are the truth and ``truth/*`` are not published.

``joint_states`` follows the ROS convention of one joint per wheel: ``name`` ``wheel_1`` ..
``wheel_N``, ``velocity`` each wheel's speed relative to the body [rad/s], ``effort`` its motor
torque [N m] (what the allocation and the motor and speed limits made of the commanded body
torque), ``position`` empty (wheel angles are not modelled).  Stamped with the sample's stamp
``t_k``: the speed at ``t_k`` and the torque applied over ``[t_k, t_k+1]`` (the offline loop
records the same).  The controller does not consume it.

Momentum management (issue 36; ``python -m sappc_momentum``, flight software like the estimator).
A plant in orbit publishes what the magnetometer reads on ``state/magnetic_field``
(``sensor_msgs/MagneticField``, the ROS type for a magnetometer: tesla, body frame, the
measurement's covariance ``diag(sigma^2)`` [T^2] row major; without a magnetometer model the true
field, covariance zero), one message per sample stamped ``t_k``, held between the magnetometer's
updates as ``state/attitude`` holds the tracker's; with a magnetometer the true field goes on
``truth/magnetic_field`` (covariance zero).  With a momentum-management node it also publishes the
wheels' tachometers on ``state/wheel_speed`` (``sensor_msgs/JointState``, ``velocity`` the speeds
relative to the body at ``t_k`` [rad/s], ``effort`` and ``position`` empty): the management law
needs the speeds at ``t_k`` before the wheels' command of ``t_k`` exists, whereas ``joint_states``
carries that command's motor torques and is published once it is applied.  The node reads
``state/wheel_speed``, ``state/magnetic_field``, the controller's rate input (``state/rate``, or
what the controller is remapped to) and the controller's ``control/torque``, all of one stamp, and
publishes, stamped alike, the rods' commands on ``control/dipole`` and the wheels' body torque
(the controller's, minus the rods' torque as the flight software computes it, plus the gyroscopic
feed-forward) on ``control/wheel_torque``, which the plant then takes as its torque command
(``-r control/torque:=control/wheel_torque``), so the bag keeps the controller's own torque on
``control/torque``.

``control/dipole`` is a ``std_msgs/Float64MultiArray``: ``data[0]`` the sample's time [s] (the
contract's convention for arrays, :func:`float_array_carries_time`), then one dipole per rod
[A m^2] (each within the rod's limit), ``layout.dim[0].label`` ``time_s,rod_1,...,rod_M``.  Why this
type: a magnetorquer set is commanded per rod, in any number and along any axes (Basilisk's
``MTBCmdMsg`` is an array of ``mtbDipoleCmds``), which no ``geometry_msgs`` vector carries for a
non-orthogonal or redundant set; ROS has no magnetorquer message, and ``Float64MultiArray`` is
what ROS 2's actuator command interfaces take for a set of actuators (``ros2_control``'s
``forward_command_controller`` commands, one value per joint in a stated order).

Flight modes (issue 49; ``python -m sappc_modes``, the mode manager, flight software;
docs/design/modes.md).  The mode node reads each sample's gyro, estimate, estimator figures,
reference and tachometers and publishes the sample's mode on ``mode/status`` (a
``std_msgs/Float64MultiArray`` of :data:`MODE_STATUS_LAYOUT`: ``data[0]`` the sample's time [s],
then the mode's number, ``sappc_modes.core.modes.MODE_NAMES``, and the reason of the transition
taken at that sample, ``REASON_NAMES``, 0 for none), one message per sample.  The controller and
the momentum node take it as one more input of the sample (lockstep: paired by its time): outside
TRACK the controller answers ``inactive`` with the mode's law (HOLD, SAFE: MRP feedback) and the
momentum node commands B-dot on the rods in DETUMBLE.  Why this type: a number per sample that a
lockstep consumer pairs with the sample, in the contract's convention for arrays, plotted by every
tool; ``diagnostics`` carries the mode in words for people (:data:`MODE_HEALTH_NAME`, at each
transition and at least once a second of the samples' time).

Frames (:class:`Frame`): ``inertial`` (N, the fixed parent), ``body`` (B) and ``reference`` (R, the
desired attitude).  The two transform topics make the attitude visible to tf-style tools (Foxglove's
3D panel builds its frame tree from every ``TransformStamped``): parent ``inertial`` (the header
frame), child :attr:`Topic.child_frame_id`, translation zero (attitude only), rotation the attitude
quaternion as it is, because a transform's rotation maps child-frame coordinates to parent-frame
coordinates, ``v_N = q_BN ⊗ v_B ⊗ q_BN*``, which is what ``q_BN`` does (``gnc_common.attitude``).
Each is published by the node that owns the frame, once per sample with that sample's stamp (the
plant: B with the state; the reference node: R with the reference), each on its own topic, so that
a lockstep bag's order never depends on which of two publishers of one topic was first.  They are
not ``/tf`` (``tf2_msgs/msg/TFMessage``): ``tf2_msgs`` is not published as a PyPI wheel for Jazzy
(docs/design/frames.md).

When the fault injector relays a path (``python -m spacecraft_sim.disturbance``), it republishes
the faulty samples under ``fault/`` (``fault/state/attitude``, ``fault/state/rate``,
``fault/reference/*``, ``fault/control/torque``, same types and frames) and the consumer is
remapped to them (``--ros-args -r state/attitude:=fault/state/attitude``); the originals stay the
truth.  This module is the one place that says which topics are relayed
(:data:`RELAYED_SENSOR_TOPICS`, :data:`RELAYED_REFERENCE_TOPICS`, :data:`RELAYED_ACTUATOR_TOPICS`,
:data:`RELAYED_TOPICS`, :data:`FAULT_TOPICS`), how a consumer
is remapped (:func:`relay_remaps`) and which names a consumer may have read
(:func:`consumed_names`).

Quaternions are ``geometry_msgs/Quaternion`` ``(x, y, z, w)``, the project's own scalar-last
order (``gnc_common.attitude``): no reordering happens anywhere.  The two state topics
of one sample carry the same stamp; the controller pairs them by stamp.

QoS: every topic RELIABLE, VOLATILE, KEEP_LAST with depth :data:`QOS_DEPTH` = 10,000 (depth 1
would do for the loop; a best-effort publisher and a reliable subscriber never match).
"""

from __future__ import annotations

import functools
from collections.abc import Iterable
from dataclasses import dataclass
from enum import Enum
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # rclpy is imported where a node needs it, not by every user of the contract
    from rclpy.qos import QoSProfile

__all__ = [
    "CLOCK",
    "CONTROL_DIPOLE",
    "CONTROL_TORQUE",
    "CONTROL_WHEEL_TORQUE",
    "CONTROLLER_INPUTS",
    "DIPOLE_LABEL_PREFIX",
    "MOMENTUM_TOPICS",
    "MODE_HEALTH_KEYS",
    "MODE_HEALTH_NAME",
    "MODE_STATUS",
    "MODE_STATUS_LAYOUT",
    "STATE_MAGNETIC_FIELD",
    "STATE_WHEEL_SPEED",
    "TRUTH_MAGNETIC_FIELD",
    "CONTROLLER_DIAGNOSTICS",
    "DIAGNOSTICS_LAYOUT",
    "DISTURBANCE_TORQUE",
    "FAULT_PREFIX",
    "FAULT_TOPICS",
    "Frame",
    "QOS_DEPTH",
    "REFERENCE_ACCELERATION",
    "REFERENCE_ATTITUDE",
    "REFERENCE_RATE",
    "RELAYED_ACTUATOR_TOPICS",
    "ANSWER_COMMANDED",
    "ANSWER_NAMES",
    "ANSWER_HELD",
    "ANSWER_INACTIVE",
    "ANSWER_REFUSED",
    "ANSWER_WATCHDOG_ZERO",
    "RELAYED_PATHS",
    "RELAYED_REFERENCE_TOPICS",
    "RELAYED_SENSOR_TOPICS",
    "RELAYED_TOPICS",
    "REFERENCE_TF",
    "STATE_ATTITUDE",
    "STATE_RATE",
    "STATE_TF",
    "TOPICS",
    "OPTIONAL_TOPICS",
    "TRANSFORM_TOPICS",
    "TRUTH_ATTITUDE",
    "TRUTH_GYRO_BIAS",
    "TRUTH_RATE",
    "Topic",
    "WHEEL_STATES",
    "consumed_names",
    "controller_state_sources",
    "COVARIANCE_DIMS",
    "ERROR_STATE",
    "ESTIMATE_ATTITUDE",
    "ESTIMATE_RATE",
    "ESTIMATOR_ATTITUDE_SIGMA",
    "ESTIMATOR_BIAS_SIGMA",
    "ESTIMATOR_COVARIANCE",
    "ESTIMATOR_DIAGNOSTICS",
    "ESTIMATOR_DIAGNOSTICS_LAYOUT",
    "ESTIMATOR_HEALTH",
    "ESTIMATOR_HEALTH_KEYS",
    "ESTIMATOR_HEALTH_NAME",
    "RELAYED_SENSOR_TOPICS_FOR_ESTIMATOR",
    "SENSOR_GYRO",
    "SENSOR_STAR_TRACKER",
    "ESTIMATOR_SUBSCRIPTIONS",
    "STATE_ATTITUDE_EPOCH",
    "ESTIMATOR_GYRO_BIAS",
    "ESTIMATOR_INACTIVE",
    "ESTIMATOR_INPUTS",
    "ESTIMATOR_NO_INPUT",
    "ESTIMATOR_STATUS_NAMES",
    "ESTIMATOR_TOPICS",
    "faulty",
    "float_array_carries_time",
    "qos_profile",
    "relay_remaps",
]

#: History depth of every topic.  A reliable writer can only repair what is still in its history,
#: so the depth is how far behind a subscriber may fall without losing anything.  What is left
#: for it to cover since issue 25: the recorder takes every message on the executor's thread and
#: writes on another (a slow write no longer leaves samples in the middleware's queues), and in
#: ``sappc run`` it subscribes to ``/clock``, which the plant's start waits for, only once it has
#: matched every publisher on its own side (a writer no longer relies on its history for the
#: recorder's late side of a match; only ``/clock``'s own match remains).  What remains is a
#: subscriber process that is not scheduled at all: 10,000 samples are 6.7 s at lockstep's
#: ~1500 samples/s here, ten times the 0.7 s stall that overflowed depth 1000 in CI on 2026-11-25
#: (fault-matrix runs, ~14 topics).  Costs ~1.5 MB per topic at most, only while a subscriber lags.
QOS_DEPTH = 10_000


class Frame(str, Enum):
    """Frame ids used in message headers."""

    INERTIAL = "inertial"
    BODY = "body"
    REFERENCE = "reference"


@dataclass(frozen=True)
class Topic:
    """One topic of the contract.

    Attributes
    ----------
    name : str
        Relative topic name (absolute for ``/clock``).
    type_name : str
        ROS 2 type, ``pkg/msg/Type``.
    frame_id : str | None
        Required header frame id (``None``: the type has no header); a transform's parent frame.
    child_frame_id : str | None
        A ``TransformStamped``'s child frame id (``None`` for every other type).
    """

    name: str
    type_name: str
    frame_id: str | None
    child_frame_id: str | None = None

    @property
    def msg_class(self) -> type:
        """The generated message class (imports the ROS 2 message package)."""
        return _msg_class(self.type_name)


@functools.cache
def _msg_class(type_name: str) -> type:
    import importlib

    pkg, _, cls = type_name.split("/")
    msg_class: type = getattr(importlib.import_module(f"{pkg}.msg"), cls)
    return msg_class


STATE_ATTITUDE = Topic("state/attitude", "geometry_msgs/msg/QuaternionStamped", Frame.INERTIAL.value)
STATE_RATE = Topic("state/rate", "geometry_msgs/msg/Vector3Stamped", Frame.BODY.value)
STATE_ATTITUDE_EPOCH = Topic("state/attitude_epoch", "sensor_msgs/msg/TimeReference", Frame.BODY.value)
#: The sensors on their own topics (a plant with sensor models): each sample when the sensor makes
#: it, stamped with the time it was measured, in ``sensor_msgs/Imu`` with the parts the sensor does
#: not measure marked absent (element 0 of their covariance -1, as the message's documentation says).
SENSOR_GYRO = Topic("sensors/gyro", "sensor_msgs/msg/Imu", Frame.BODY.value)
SENSOR_STAR_TRACKER = Topic("sensors/star_tracker", "sensor_msgs/msg/Imu", Frame.BODY.value)
REFERENCE_ATTITUDE = Topic("reference/attitude", "geometry_msgs/msg/QuaternionStamped", Frame.INERTIAL.value)
REFERENCE_RATE = Topic("reference/rate", "geometry_msgs/msg/Vector3Stamped", Frame.REFERENCE.value)
REFERENCE_ACCELERATION = Topic("reference/acceleration", "geometry_msgs/msg/Vector3Stamped", Frame.REFERENCE.value)
CONTROL_TORQUE = Topic("control/torque", "geometry_msgs/msg/WrenchStamped", Frame.BODY.value)
DISTURBANCE_TORQUE = Topic("disturbance/torque", "geometry_msgs/msg/WrenchStamped", Frame.BODY.value)
CONTROLLER_DIAGNOSTICS = Topic("controller/diagnostics", "std_msgs/msg/Float64MultiArray", None)
CLOCK = Topic("/clock", "rosgraph_msgs/msg/Clock", None)
STATE_TF = Topic("state/tf", "geometry_msgs/msg/TransformStamped", Frame.INERTIAL.value, Frame.BODY.value)
REFERENCE_TF = Topic("reference/tf", "geometry_msgs/msg/TransformStamped", Frame.INERTIAL.value, Frame.REFERENCE.value)
WHEEL_STATES = Topic("joint_states", "sensor_msgs/msg/JointState", Frame.BODY.value)
TRUTH_ATTITUDE = Topic("truth/attitude", "geometry_msgs/msg/QuaternionStamped", Frame.INERTIAL.value)
TRUTH_RATE = Topic("truth/rate", "geometry_msgs/msg/Vector3Stamped", Frame.BODY.value)
TRUTH_GYRO_BIAS = Topic("truth/gyro_bias", "geometry_msgs/msg/Vector3Stamped", Frame.BODY.value)
ESTIMATE_ATTITUDE = Topic("estimate/attitude", STATE_ATTITUDE.type_name, STATE_ATTITUDE.frame_id)
ESTIMATE_RATE = Topic("estimate/rate", STATE_RATE.type_name, STATE_RATE.frame_id)
ESTIMATOR_GYRO_BIAS = Topic("estimator/gyro_bias", "geometry_msgs/msg/Vector3Stamped", Frame.BODY.value)
ESTIMATOR_ATTITUDE_SIGMA = Topic("estimator/attitude_sigma", "geometry_msgs/msg/Vector3Stamped", Frame.BODY.value)
ESTIMATOR_BIAS_SIGMA = Topic("estimator/bias_sigma", "geometry_msgs/msg/Vector3Stamped", Frame.BODY.value)
ESTIMATOR_COVARIANCE = Topic("estimator/covariance", "std_msgs/msg/Float64MultiArray", None)
ESTIMATOR_DIAGNOSTICS = Topic("estimator/diagnostics", "std_msgs/msg/Float64MultiArray", None)
STATE_MAGNETIC_FIELD = Topic("state/magnetic_field", "sensor_msgs/msg/MagneticField", Frame.BODY.value)
TRUTH_MAGNETIC_FIELD = Topic("truth/magnetic_field", "sensor_msgs/msg/MagneticField", Frame.BODY.value)
STATE_WHEEL_SPEED = Topic("state/wheel_speed", "sensor_msgs/msg/JointState", Frame.BODY.value)
CONTROL_DIPOLE = Topic("control/dipole", "std_msgs/msg/Float64MultiArray", None)
CONTROL_WHEEL_TORQUE = Topic("control/wheel_torque", "geometry_msgs/msg/WrenchStamped", Frame.BODY.value)
#: The flight mode of each sample (the mode node's; docstring).
MODE_STATUS = Topic("mode/status", "std_msgs/msg/Float64MultiArray", None)
#: Layout of ``mode/status``: one value per label, ``layout.dim[0]`` the labels joined by commas:
#: the sample's time [s], the mode's number (``sappc_modes.core.modes.MODE_NAMES``), the reason of
#: the transition taken at the sample (``sappc_modes.core.modes.REASON_NAMES``; 0: none).
MODE_STATUS_LAYOUT = ("time_s", "mode", "reason")
#: The rods' labels on ``control/dipole`` (after ``time_s``): ``rod_1`` .. ``rod_M``.
DIPOLE_LABEL_PREFIX = "rod_"
#: What momentum management adds to a run: the plant's magnetometer (and its truth) and tachometers,
#: the management node's outputs.
MOMENTUM_TOPICS = (STATE_MAGNETIC_FIELD, TRUTH_MAGNETIC_FIELD, STATE_WHEEL_SPEED, CONTROL_DIPOLE, CONTROL_WHEEL_TORQUE)
#: ROS's health convention (REP 107's diagnostics): a ``diagnostic_msgs/DiagnosticArray`` on
#: ``diagnostics`` (relative: ``/diagnostics`` in the root namespace, where the aggregator, rqt's
#: robot monitor and Foxglove's diagnostics panels look), one status named
#: :data:`ESTIMATOR_HEALTH_NAME`, its figures as key/values (:data:`ESTIMATOR_HEALTH_KEYS`).
ESTIMATOR_HEALTH = Topic("diagnostics", "diagnostic_msgs/msg/DiagnosticArray", None)

#: Prefix of the topics a fault relay republishes.
FAULT_PREFIX = "fault/"


def faulty(topic: Topic) -> Topic:
    """The relay's output topic for ``topic`` (same type and frame, under :data:`FAULT_PREFIX`)."""
    return Topic(FAULT_PREFIX + topic.name, topic.type_name, topic.frame_id)


#: The measurements a sensor-fault relay republishes (the controller is remapped to their
#: :func:`faulty` twins), in the order of ``FaultSchedule.sensor(t, stamp, q_BN, omega_BN_B)``.
RELAYED_SENSOR_TOPICS = (STATE_ATTITUDE, STATE_RATE)
#: The sensors a sensor-fault relay republishes for an estimator: the gyro and the tracker's epoch of
#: each sample, paired by stamp, then the tracker's own samples (relayed when the relayed epoch is
#: a new one); the faults take ``FaultSchedule.sensor(t, stamp, q_BN, omega_BN_B, epoch)`` with the
#: quaternion of the tracker sample the epoch names.  The estimator's subscriptions.
RELAYED_SENSOR_TOPICS_FOR_ESTIMATOR = (SENSOR_GYRO, STATE_ATTITUDE_EPOCH, SENSOR_STAR_TRACKER)
#: The reference a reference-fault relay republishes, paired by stamp (the controller is remapped).
RELAYED_REFERENCE_TOPICS = (REFERENCE_ATTITUDE, REFERENCE_RATE, REFERENCE_ACCELERATION)
#: The command an actuator-fault relay republishes (the plant is remapped to its :func:`faulty` twin).
RELAYED_ACTUATOR_TOPICS = (CONTROL_TORQUE,)
#: The relayed paths by name (``FaultSchedule.acts_on(name)``): the injector relays a path's topics
#: when a fault acts on it, and its consumer (the controller; the plant for ``actuator``) is remapped.
RELAYED_PATHS = {"sensor": RELAYED_SENSOR_TOPICS, "reference": RELAYED_REFERENCE_TOPICS, "actuator": RELAYED_ACTUATOR_TOPICS}
#: Every topic a fault relay may republish (the originals).
RELAYED_TOPICS = RELAYED_SENSOR_TOPICS + RELAYED_SENSOR_TOPICS_FOR_ESTIMATOR + RELAYED_REFERENCE_TOPICS + RELAYED_ACTUATOR_TOPICS
#: The relays' outputs, :func:`faulty` of each of :data:`RELAYED_TOPICS`.
FAULT_TOPICS = tuple(faulty(t) for t in RELAYED_TOPICS)


def relay_remaps(topics: Iterable[Topic]) -> list[str]:
    """The ``--ros-args`` remap arguments that move a consumer of ``topics`` to the relay's outputs.

    Parameters
    ----------
    topics : iterable of Topic
        Relayed topics the consumer subscribes to (e.g. :data:`RELAYED_SENSOR_TOPICS` for the
        controller).

    Returns
    -------
    list of str
        ``["-r", "state/attitude:=fault/state/attitude", ...]``, one pair per topic.
    """
    return [arg for t in topics for arg in ("-r", f"{t.name}:={faulty(t).name}")]


def consumed_names(topic: Topic) -> tuple[str, ...]:
    """The names under which a consumer of ``topic`` may have received it, the one to prefer first:
    the relay's output, then the original, for a relayed topic; the original alone otherwise."""
    return (faulty(topic).name, topic.name) if topic in RELAYED_TOPICS else (topic.name,)


#: The controller's five inputs, in the order of ``AttitudeController.step(t, dt, q, w, q_d, w_d, wdot_d)``.
CONTROLLER_INPUTS = (STATE_ATTITUDE, STATE_RATE, REFERENCE_ATTITUDE, REFERENCE_RATE, REFERENCE_ACCELERATION)


def controller_state_sources(estimating: bool) -> tuple[Topic, Topic]:
    """Where a run's controller takes its attitude and rate (its ``state/attitude`` and
    ``state/rate`` inputs) from: the estimator's estimate when the run has one (``sappc run``
    remaps them to ``estimate/*``), else the plant's ``state/*``.  The one rule for the launcher's
    remaps and for ``sappc rerun``, which feeds the controller the same messages again."""
    return (ESTIMATE_ATTITUDE, ESTIMATE_RATE) if estimating else (STATE_ATTITUDE, STATE_RATE)

#: The estimator's inputs of each sample, paired by stamp: the gyro's sample and the tracker's epoch
#: (which names the tracker sample, :data:`SENSOR_STAR_TRACKER` of that stamp, that the sample uses).
ESTIMATOR_INPUTS = RELAYED_SENSOR_TOPICS_FOR_ESTIMATOR[:2]
#: Every topic the estimator subscribes to: its paired inputs, then the tracker's samples.
ESTIMATOR_SUBSCRIPTIONS = RELAYED_SENSOR_TOPICS_FOR_ESTIMATOR
#: What an estimator publishes per sample, in the order it publishes them: the estimate the
#: controller takes (remapped from ``state/*``) first.
ESTIMATOR_TOPICS = (ESTIMATE_ATTITUDE, ESTIMATE_RATE, ESTIMATOR_GYRO_BIAS, ESTIMATOR_ATTITUDE_SIGMA, ESTIMATOR_BIAS_SIGMA,
                    ESTIMATOR_COVARIANCE, ESTIMATOR_DIAGNOSTICS, ESTIMATOR_HEALTH)

#: Every topic of the contract.
TOPICS = (
    STATE_ATTITUDE,
    STATE_RATE,
    REFERENCE_ATTITUDE,
    REFERENCE_RATE,
    REFERENCE_ACCELERATION,
    CONTROL_TORQUE,
    DISTURBANCE_TORQUE,
    CONTROLLER_DIAGNOSTICS,
    CLOCK,
    STATE_TF,
    REFERENCE_TF,
    WHEEL_STATES,
    TRUTH_ATTITUDE,
    TRUTH_RATE,
    TRUTH_GYRO_BIAS,
    STATE_ATTITUDE_EPOCH,
    SENSOR_GYRO,
    SENSOR_STAR_TRACKER,
    *ESTIMATOR_TOPICS,
    *MOMENTUM_TOPICS,
    MODE_STATUS,
)

#: Topics only some runs have (a plant with reaction wheels or sensor models, an estimator):
#: absent from a bag of a run without them, which is no fault.
OPTIONAL_TOPICS = (WHEEL_STATES, TRUTH_ATTITUDE, TRUTH_RATE, TRUTH_GYRO_BIAS, STATE_ATTITUDE_EPOCH, SENSOR_GYRO, SENSOR_STAR_TRACKER,
                   *ESTIMATOR_TOPICS, *MOMENTUM_TOPICS, MODE_STATUS)

#: The attitude as frames (body and reference relative to inertial), for visualisation only: no
#: node consumes them, a fault relay never republishes them (they show the truth).
TRANSFORM_TOPICS = (STATE_TF, REFERENCE_TF)

#: Layout of ``controller/diagnostics`` (``std_msgs/Float64MultiArray``): labelled rows of 3
#: values each (per axis or per layer), in this order.  The message's ``layout.dim`` carries the
#: same labels, so a reader never has to guess.  The input stamps say exactly which messages a
#: step used (lockstep: all equal ``time_s``; real time: the latest of each topic), which makes
#: ``sappc rerun`` exact in both modes; as float seconds they identify a message to ~0.5 us.
DIAGNOSTICS_LAYOUT = (
    "time_s",  # controller time of the sample (3 copies)
    "rho",  # performance / reference function per axis
    "band_lower",  # constraint band on q_ev per axis
    "band_upper",
    "eps",  # transformed error per axis
    "z",  # q_ev / rho per axis (BLFPPC: q_ev)
    "lyapunov_V",  # V1, V2, V3
    "torque_cmd_Nm",  # commanded before the actuator model
    "saturated",  # 1.0 where the axis saturated
    "status",  # rejected messages, stale flag (1.0 = zero torque), the answer's ANSWER_* code
    "input_stamps_state_s",  # header stamps of the state/attitude and state/rate used, 0.0 (0 when no step)
    "input_stamps_reference_s",  # header stamps of the reference attitude, rate, acceleration used
)


#: Components of the estimator's error state, in the order of the rows and columns of its
#: covariance ``P``: the attitude error ``a`` (a rotation vector in the body frame, true =
#: estimate ⊗ dq(a)) [rad], then the gyro bias error ``b`` (true minus estimated) [rad/s].
ERROR_STATE = ("a_x", "a_y", "a_z", "b_x", "b_y", "b_z")
#: Layout of ``estimator/covariance`` (``std_msgs/Float64MultiArray``): ``data[0]`` is the time of
#: the sample [s] (``layout.data_offset`` = 1: the element before the array), then the 6 x 6
#: covariance ``P`` of :data:`ERROR_STATE` row major, ``P[i, j] = data[1 + 6 i + j]`` (units rad^2,
#: rad^2/s, (rad/s)^2 by block).  ``layout.dim`` carries these two labels (rows, then columns;
#: size 6, strides 36 and 6), so a reader never has to guess.
COVARIANCE_DIMS = ("row:" + ",".join(ERROR_STATE), "column:" + ",".join(ERROR_STATE))

#: Layout of ``estimator/diagnostics`` (``std_msgs/Float64MultiArray``): one value per label, in
#: this order; ``layout.dim[0]`` carries the labels joined by commas.  The counts are totals since
#: the node started.
ESTIMATOR_DIAGNOSTICS_LAYOUT = (
    "time_s",  # time of the sample (its stamp) [s]
    "nis",  # the last normalised innovation squared (chi-square, 3 dof; NaN until a tracker sample was compared)
    "status",  # what the sample did: an ESTIMATOR_STATUS_NAMES code
    "updates",  # tracker samples accepted by the filter
    "gate_rejections",  # tracker samples rejected by its innovation gate
    "reinitialisations",  # attitude re-initialisations after consecutive rejections
    "no_data_samples",  # samples published as "no data"
    "rejected_messages",  # input messages rejected by the node's checks (frame, non-finite, stamp)
    "monitor_level",  # the health monitor's level: 0 ok, 1 warn, 2 error (diagnostic_msgs/DiagnosticStatus's)
    "monitor_nis_sum",  # its window's NIS sum at its last verdict (NaN before the first)
    "recoveries",  # bias recoveries after a failed monitor
    "withheld_samples",  # samples whose estimate was withheld from the controller (published as "no data")
)
#: The name of the mode manager's status in ``diagnostics`` (:data:`ESTIMATOR_HEALTH`'s topic, ROS's
#: one health topic: the mode node publishes there too), level OK but in SAFE (ERROR: the mission
#: is interrupted), its key/values :data:`MODE_HEALTH_KEYS`.
MODE_HEALTH_NAME = "sappc_modes: flight mode"
#: The key/values of that status, in order: the sample's time [s], the mode, since when [s], the
#: reason of its entry, the transitions so far, the ground's inhibits (names, comma-separated).
MODE_HEALTH_KEYS = ("time_s", "mode", "since_s", "reason", "transitions", "inhibit")
#: The name of the estimator's status in ``diagnostics`` (:data:`ESTIMATOR_HEALTH`).
ESTIMATOR_HEALTH_NAME = "sappc_estimator: MEKF health"
#: The key/values of that status, in order: the sample's time [s], the monitor's window (compared
#: tracker samples) and its NIS sum's degrees of freedom, the window's NIS sum and its band at the
#: stated probability, the mean statistic, the estimate's use (``used`` or ``withheld``), the
#: totals of recoveries, re-initialisations and withheld samples, then the drift test's statistic
#: (the largest of its CUSUMs of the whitened innovations), its threshold and the failed monitors it
#: started (issue 46).
ESTIMATOR_HEALTH_KEYS = ("time_s", "window_samples", "nis_sum_dof", "nis_sum", "nis_sum_band", "band_probability", "mean_statistic",
                         "outside_in_a_row", "persistence", "estimate", "recoveries", "reinitialisations", "withheld_samples",
                         "drift_statistic", "drift_threshold", "drift_alarms")
#: What a sample did (``estimator/diagnostics`` ``status``), by code: the filter's step statuses
#: (``sappc_estimator.core.mekf.STATUS_NAMES``, codes 0 to 5: not initialised yet, initialised,
#: propagated only, updated, tracker sample rejected by the gate, attitude re-initialised), then
#: :data:`ESTIMATOR_NO_INPUT` and :data:`ESTIMATOR_INACTIVE`.
ESTIMATOR_STATUS_NAMES = ("none", "initialised", "propagated", "updated", "rejected", "reinitialised", "no_input", "inactive")
#: The status of a sample whose inputs arrived invalid: no filter step ("no data" published).
ESTIMATOR_NO_INPUT = 6
#: The status of a sample answered by an inactive estimator (a managed node configured and not
#: activated, or deactivated: ``sappc_estimator.node``, "Managed"): no filter step, whatever its
#: inputs ("no data" published, as for :data:`ESTIMATOR_NO_INPUT`).
ESTIMATOR_INACTIVE = 7


def float_array_carries_time(first_label: str) -> bool:
    """Whether a ``std_msgs/Float64MultiArray`` whose ``layout.dim[0].label`` is ``first_label`` is
    one of the contract's, which carry the time they belong to [s] in ``data[0]``: the controller's
    and the estimator's diagnostics (their first label is ``time_s``) and the covariance
    (:data:`COVARIANCE_DIMS`)."""
    return first_label.split(",", 1)[0] == "time_s" or first_label == COVARIANCE_DIMS[0]


#: How the controller answered a sample (``controller/diagnostics`` ``status[2]``; the offline loop
#: records the same codes): a computed torque; zero torque from the stale-input watchdog (the
#: sample's inputs are missing or invalid and no valid state is newer than ``stale_timeout_s``);
#: the last torque held (inputs missing or invalid, not yet stale: a short outage is ridden
#: through, as an actuator holds its last command); zero torque because the core refused the
#: step (a non-finite torque); the controller inactive (flight modes: outside TRACK, the mode
#: manager's law commands the torque, docs/design/modes.md).
ANSWER_COMMANDED, ANSWER_WATCHDOG_ZERO, ANSWER_HELD, ANSWER_REFUSED, ANSWER_INACTIVE = 0, 1, 2, 3, 4
#: Names of the answer codes, in code order (run summaries).
ANSWER_NAMES = ("commanded", "watchdog_zero", "held", "refused", "inactive")


def qos_profile() -> QoSProfile:
    """The QoS of every topic: RELIABLE, VOLATILE, KEEP_LAST ``QOS_DEPTH`` (imports rclpy)."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.VOLATILE,
        history=HistoryPolicy.KEEP_LAST,
        depth=QOS_DEPTH,
    )

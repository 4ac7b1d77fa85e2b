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
============================  ==============================  ==========  =========================================

With sensor models (a star tracker, a gyro: :mod:`spacecraft_sim.core.sensors`) ``state/*`` carry
what the sensors measure, as the contract says, and the plant adds the true state on
``truth/attitude`` and ``truth/rate``, same stamps: for the record and the metrics, never for
the controller.  Without sensor models ``state/*`` are the truth and ``truth/*`` are not published.

``joint_states`` follows the ROS convention of one joint per wheel: ``name`` ``wheel_1`` ..
``wheel_N``, ``velocity`` each wheel's speed relative to the body [rad/s], ``effort`` its motor
torque [N m] (what the allocation and the motor and speed limits made of the commanded body
torque), ``position`` empty (wheel angles are not modelled).  Stamped with the sample's stamp
``t_k``: the speed at ``t_k`` and the torque applied over ``[t_k, t_k+1]`` (the offline loop
records the same).  The controller does not consume it.

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
    "CONTROL_TORQUE",
    "CONTROLLER_INPUTS",
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
    "TRUTH_RATE",
    "Topic",
    "WHEEL_STATES",
    "consumed_names",
    "faulty",
    "qos_profile",
    "relay_remaps",
]

#: History depth of every topic.  A reliable writer can only repair what is still in its history:
#: a subscriber whose side of the match completes after the writer's (measured: a recorder
#: matched during a burst of 500 messages received only the last 10 with depth 10), or one that
#: falls behind, loses nothing as long as it is less than this many samples late.  10,000: more
#: than a whole 60 s run at 100 Hz.  (It was 1000 until lockstep ran at ~1500 samples/s: a
#: recorder that started spinning or was scheduled 0.7 s late then lost blocks of samples, seen
#: 2026-11-25 in CI's fault-matrix runs, which record ~14 topics.)  Costs ~1.5 MB per topic at
#: most, only while a subscriber lags.
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

#: Prefix of the topics a fault relay republishes.
FAULT_PREFIX = "fault/"


def faulty(topic: Topic) -> Topic:
    """The relay's output topic for ``topic`` (same type and frame, under :data:`FAULT_PREFIX`)."""
    return Topic(FAULT_PREFIX + topic.name, topic.type_name, topic.frame_id)


#: The measurements a sensor-fault relay republishes (the controller is remapped to their
#: :func:`faulty` twins), in the order of ``FaultSchedule.sensor(t, stamp, q_BN, omega_BN_B)``.
RELAYED_SENSOR_TOPICS = (STATE_ATTITUDE, STATE_RATE)
#: The reference a reference-fault relay republishes, paired by stamp (the controller is remapped).
RELAYED_REFERENCE_TOPICS = (REFERENCE_ATTITUDE, REFERENCE_RATE, REFERENCE_ACCELERATION)
#: The command an actuator-fault relay republishes (the plant is remapped to its :func:`faulty` twin).
RELAYED_ACTUATOR_TOPICS = (CONTROL_TORQUE,)
#: The relayed paths by name (``FaultSchedule.acts_on(name)``): the injector relays a path's topics
#: when a fault acts on it, and its consumer (the controller; the plant for ``actuator``) is remapped.
RELAYED_PATHS = {"sensor": RELAYED_SENSOR_TOPICS, "reference": RELAYED_REFERENCE_TOPICS, "actuator": RELAYED_ACTUATOR_TOPICS}
#: Every topic a fault relay may republish (the originals).
RELAYED_TOPICS = RELAYED_SENSOR_TOPICS + RELAYED_REFERENCE_TOPICS + RELAYED_ACTUATOR_TOPICS
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
)

#: Topics only some plants publish (reaction wheels, sensor models): absent from a bag of a plant
#: without them, which is no fault.
OPTIONAL_TOPICS = (WHEEL_STATES, TRUTH_ATTITUDE, TRUTH_RATE)

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


#: How the controller answered a sample (``controller/diagnostics`` ``status[2]``; the offline loop
#: records the same codes): a computed torque; zero torque from the stale-input watchdog (the
#: sample's inputs are missing or invalid and no valid state is newer than ``stale_timeout_s``);
#: the last torque held (inputs missing or invalid, not yet stale: a short outage is ridden
#: through, as an actuator holds its last command); zero torque because the core refused the
#: step (a non-finite torque).
ANSWER_COMMANDED, ANSWER_WATCHDOG_ZERO, ANSWER_HELD, ANSWER_REFUSED = 0, 1, 2, 3
#: Names of the answer codes, in code order (run summaries).
ANSWER_NAMES = ("commanded", "watchdog_zero", "held", "refused")


def qos_profile() -> QoSProfile:
    """The QoS of every topic: RELIABLE, VOLATILE, KEEP_LAST ``QOS_DEPTH`` (imports rclpy)."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.VOLATILE,
        history=HistoryPolicy.KEEP_LAST,
        depth=QOS_DEPTH,
    )

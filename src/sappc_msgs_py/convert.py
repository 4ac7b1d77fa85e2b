"""numpy <-> message conversions for the topics of :mod:`sappc_msgs_py.contract`.

Encoders take SI arrays and a time in seconds (or a stamp); decoders return float64 arrays and check what a
message can get wrong (frame id, non-finite values), raising :class:`InputError` naming the
topic and value.  Quaternions keep the ``(x, y, z, w)`` order on both sides.

Time: a stamp is ``sec`` + ``nanosec``; :func:`time_to_stamp` rounds to the nearest nanosecond,
so the 10 ms grid of the lockstep loop is represented exactly.

Cost: the encoders run for every message a node publishes (nine a sample in the lockstep loop).
Each takes ``out=``, a message of the topic's type to fill instead of building a new one (a
``WrenchStamped`` is six Python objects; rclpy serializes a message when it is published, so a
node may refill the same one for its next publish), and values that are already a float64 vector
or a list of floats are checked with :func:`math.isfinite`, not through numpy.
"""

from __future__ import annotations

import array
import functools
import math
import struct
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gnc_common.validation import InputError, as_finite_array

from sappc_msgs_py.contract import (
    CONTROL_DIPOLE,
    CONTROL_TORQUE,
    DIPOLE_LABEL_PREFIX,
    STATE_MAGNETIC_FIELD,
    STATE_WHEEL_SPEED,
    COVARIANCE_DIMS,
    DIAGNOSTICS_LAYOUT,
    ERROR_STATE,
    ESTIMATOR_DIAGNOSTICS_LAYOUT,
    WHEEL_STATES,
    Topic,
    float_array_carries_time,
)

__all__ = [
    "clock_msg",
    "covariance_from_msg",
    "covariance_msg",
    "covariance_values",
    "estimator_diagnostics_from_msg",
    "estimator_diagnostics_msg",
    "epoch_from_msg",
    "epoch_msg",
    "health_msg",
    "gyro_from_msg",
    "gyro_msg",
    "IMU_ABSENT",
    "seconds_to_ns",
    "seconds_to_ns_array",
    "star_tracker_from_msg",
    "star_tracker_msg",
    "EPOCH_SOURCE",
    "is_no_data_msg",
    "no_data_msg",
    "diagnostics_from_msg",
    "diagnostics_msg",
    "diagnostics_values",
    "joint_state_msg",
    "ns_to_stamp",
    "cdr_stamp_ns",
    "quaternion_from_msg",
    "quaternion_msg",
    "stamp_to_ns",
    "stamp_to_time",
    "time_to_ns",
    "time_to_stamp",
    "torque_from_msg",
    "torque_msg",
    "transform_from_attitude",
    "transform_msg",
    "vector3_from_msg",
    "vector3_msg",
    "wheel_names",
    "dipole_from_msg",
    "dipole_msg",
    "magnetic_field_from_msg",
    "magnetic_field_msg",
    "wheel_speed_from_msg",
    "wheel_speed_msg",
]

Array = NDArray[np.float64]
_NS_PER_S = 1_000_000_000


@functools.cache
def _time_class() -> Any:
    from builtin_interfaces.msg import Time

    return Time


def _finite(topic: Topic, what: str, values: list[float]) -> Array:
    """``values`` as an array, or :class:`InputError` naming the topic (fast for 3-4 values:
    this runs for every message a node receives)."""
    if all(map(math.isfinite, values)):
        return np.array(values)
    return as_finite_array(f"{topic.name} {what}", values)  # raises, naming the value


def _encode(name: str, values: Any, n: int) -> list[float]:
    """``n`` finite floats to encode, or :class:`InputError` naming ``name`` and the value."""
    out: list[float]
    if isinstance(values, np.ndarray) and values.shape == (n,) and values.dtype == np.float64:
        out = values.tolist()
    elif isinstance(values, (list, tuple)) and len(values) == n and all(isinstance(v, float) for v in values):
        out = list(values)
    else:
        checked = as_finite_array(name, values, shape_tail=(n,))  # raises, naming the value
        if checked.shape != (n,):  # e.g. a (1, n) row: not n values
            raise InputError(f"{name} must be {n} values, got an array of shape {checked.shape}")
        out = checked.tolist()
    if not all(map(math.isfinite, out)):
        as_finite_array(name, values)  # raises, naming the value
    return out


def time_to_stamp(t_s: Any, out: Any = None) -> Any:
    """``builtin_interfaces/Time`` for ``t_s`` seconds (>= 0), rounded to the nanosecond (into
    ``out``, a ``Time``, when given).

    ``t_s`` may also be a stamp (anything with ``sec`` and ``nanosec``, e.g. a received header's
    stamp or ``Clock.now().to_msg()``), copied exactly: wall-clock times (1.7e9 s) lose about
    0.2 us in a float of seconds, so relays and real-time nodes pass stamps, not floats.
    """
    stamp = _time_class()() if out is None else out
    stamp.sec, stamp.nanosec = divmod(time_to_ns(t_s), _NS_PER_S)
    return stamp


def time_to_ns(t_s: Any) -> int:
    """The integer nanoseconds of the stamp :func:`time_to_stamp` gives for ``t_s`` (seconds,
    >= 0, rounded to the nanosecond; or a stamp, exact), without building it.

    Raises
    ------
    InputError
        For a negative or non-finite time.
    """
    if hasattr(t_s, "sec") and hasattr(t_s, "nanosec"):
        return int(t_s.sec) * _NS_PER_S + int(t_s.nanosec)
    t = t_s if type(t_s) is float and math.isfinite(t_s) else float(as_finite_array("t_s", t_s))
    if t < 0.0:
        raise InputError(f"t_s must be >= 0 for a ROS stamp, got {t_s!r}")
    return seconds_to_ns(t)


def seconds_to_ns(t_s: float) -> int:
    """The integer nanoseconds a stamp of ``t_s`` seconds carries (rounded half to even): the
    plant's stamp of sample ``k`` is ``seconds_to_ns(k * dt)`` (offline runs use the same stamps)."""
    return round(t_s * _NS_PER_S)


def seconds_to_ns_array(t_s: NDArray[np.float64]) -> NDArray[np.int64]:
    """:func:`seconds_to_ns` of every time of ``t_s`` (finite, >= 0, below 2**63 ns) at once: the
    same integers (the same float64 product, rounded half to even by ``rint``; exact in int64, as
    every product below 2**53 is and every one above is already an integer)."""
    out: NDArray[np.int64] = np.rint(np.asarray(t_s, dtype=np.float64) * float(_NS_PER_S)).astype(np.int64)
    return out


#: Types whose CDR body starts with a ``builtin_interfaces/Time`` (a ``std_msgs/Header``'s stamp,
#: or ``rosgraph_msgs/Clock``'s clock): ``int32 sec, uint32 nanosec`` after the 4-byte
#: encapsulation header.
_STAMP_FIRST = frozenset({"geometry_msgs/msg/QuaternionStamped", "geometry_msgs/msg/Vector3Stamped",
                          "geometry_msgs/msg/WrenchStamped", "geometry_msgs/msg/TransformStamped", "rosgraph_msgs/msg/Clock",
                          "sensor_msgs/msg/JointState", "sensor_msgs/msg/MagneticField", "sensor_msgs/msg/TimeReference", "sensor_msgs/msg/Imu",
                          "diagnostic_msgs/msg/DiagnosticArray"})
_FLOAT_ARRAY_TYPE = "std_msgs/msg/Float64MultiArray"
_STAMP_LE, _STAMP_BE = struct.Struct("<iI"), struct.Struct(">iI")


def cdr_stamp_ns(type_name: str, cdr: bytes) -> int:
    """The time [ns] a serialized message of the contract belongs to, read without deserializing.

    A stamped type's header stamp, ``/clock``'s clock; a ``Float64MultiArray`` of the contract
    (the controller's and the estimator's diagnostics, the estimator's covariance:
    :func:`~sappc_msgs_py.contract.float_array_carries_time`) its ``data[0]``, the time in
    seconds.  Byte order from the encapsulation header (CDR_BE 0, CDR_LE 1); alignment counted
    from the end of that 4-byte header.

    Raises
    ------
    ValueError
        For a type outside the contract, or a float array that is not one of the contract's.
    """
    if type_name in _STAMP_FIRST:
        sec, nanosec = (_STAMP_LE if cdr[1] & 1 else _STAMP_BE).unpack_from(cdr, 4)
        return int(sec) * _NS_PER_S + int(nanosec)
    order = "<" if cdr[1] & 1 else ">"
    if type_name == _FLOAT_ARRAY_TYPE:
        first = _float_array_time(order, cdr)
        if first is None:
            raise ValueError(f"a {type_name} of {len(cdr)} bytes is not one of the contract's float arrays "
                             "(controller or estimator diagnostics, estimator covariance)")
        return seconds_to_ns(first)
    raise ValueError(f"no stamp known for type {type_name!r}")


def _float_array_time(order: str, cdr: bytes) -> float | None:
    """``data[0]`` of a serialized ``Float64MultiArray`` whose first dimension's label says it is
    one of the contract's (``None`` otherwise, or when the bytes do not fit the type): layout
    ``sequence<{string label, uint32 size, uint32 stride}> dim``, ``uint32 data_offset``,
    ``sequence<float64> data`` (the doubles aligned to 8)."""
    body = 4  # after the encapsulation header: the alignment origin
    try:
        (ndim,) = struct.unpack_from(order + "I", cdr, body)
        off, first = 4, ""
        for i in range(ndim):
            (n,) = struct.unpack_from(order + "I", cdr, body + off)
            if i == 0:
                first = bytes(cdr[body + off + 4 : body + off + 3 + n]).decode("utf-8", "replace") if n else ""
            off = (off + 4 + n + 3) // 4 * 4 + 8  # the label, its padding, size and stride
        (count,) = struct.unpack_from(order + "I", cdr, body + off + 4)  # after data_offset
        off = (off + 8 + 7) // 8 * 8
        if ndim == 0 or count == 0 or not float_array_carries_time(first):
            return None
        (t,) = struct.unpack_from(order + "d", cdr, body + off)
    except struct.error:
        return None
    return float(t)


def ns_to_stamp(ns: int) -> Any:
    """``builtin_interfaces/Time`` of integer nanoseconds (exact)."""
    return _time_class()(sec=ns // _NS_PER_S, nanosec=ns % _NS_PER_S)


def stamp_to_ns(stamp: Any) -> int:
    """Integer nanoseconds of a stamp."""
    return int(stamp.sec) * _NS_PER_S + int(stamp.nanosec)


def stamp_to_time(stamp: Any) -> float:
    """Seconds of a stamp."""
    return stamp_to_ns(stamp) / _NS_PER_S


def _header(msg: Any, t_s: float, frame_id: str | None) -> Any:
    time_to_stamp(t_s, msg.header.stamp)
    msg.header.frame_id = frame_id or ""
    return msg


def _check_frame(msg: Any, topic: Topic) -> None:
    if topic.frame_id is not None and msg.header.frame_id != topic.frame_id:
        raise InputError(f"{topic.name}: frame_id must be {topic.frame_id!r}, got {msg.header.frame_id!r}")


def quaternion_msg(q_xyzw: ArrayLike, t_s: float, topic: Topic, out: Any = None) -> Any:
    """A ``QuaternionStamped`` for ``topic`` (e.g. ``STATE_ATTITUDE``), or ``out`` filled."""
    q = _encode(f"{topic.name} quaternion", q_xyzw, 4)
    msg = _header(topic.msg_class() if out is None else out, t_s, topic.frame_id)
    msg.quaternion.x, msg.quaternion.y, msg.quaternion.z, msg.quaternion.w = q
    return msg


def quaternion_from_msg(msg: Any, topic: Topic) -> Array:
    """``(x, y, z, w)`` from a ``QuaternionStamped`` of ``topic``; checks frame and finiteness
    (the unit norm is the controller's check, which names the value)."""
    _check_frame(msg, topic)
    q = msg.quaternion
    return _finite(topic, "quaternion", [q.x, q.y, q.z, q.w])


def vector3_msg(v: ArrayLike, t_s: float, topic: Topic, out: Any = None) -> Any:
    """A ``Vector3Stamped`` for ``topic``, or ``out`` filled."""
    a = _encode(f"{topic.name} vector", v, 3)
    msg = _header(topic.msg_class() if out is None else out, t_s, topic.frame_id)
    msg.vector.x, msg.vector.y, msg.vector.z = a
    return msg


def vector3_from_msg(msg: Any, topic: Topic) -> Array:
    """The vector of a ``Vector3Stamped`` of ``topic``; checks frame and finiteness."""
    _check_frame(msg, topic)
    v = msg.vector
    return _finite(topic, "vector", [v.x, v.y, v.z])


#: ``sensor_msgs/Imu``'s mark of a part the sensor does not measure: element 0 of its covariance
#: (the message's documentation: "If you have no estimate for one of the data elements ... please
#: set element 0 of the associated covariance matrix to -1").
IMU_ABSENT = -1.0


def _diagonal(variance: ArrayLike) -> list[float]:
    v = np.broadcast_to(np.asarray(variance, dtype=np.float64), (3,))
    return [float(v[0]), 0.0, 0.0, 0.0, float(v[1]), 0.0, 0.0, 0.0, float(v[2])]


def _imu(topic: Topic, t_s: Any, out: Any) -> Any:
    return _header(topic.msg_class() if out is None else out, t_s, topic.frame_id)


def gyro_msg(omega_B: ArrayLike, variance: ArrayLike, t_s: Any, topic: Topic, out: Any = None) -> Any:
    """A gyro sample as ``sensor_msgs/Imu`` for ``topic`` (:data:`~sappc_msgs_py.contract.SENSOR_GYRO`):
    ``angular_velocity`` the measured ``omega_BN_B`` [rad/s], ``angular_velocity_covariance`` the
    white noise's per-axis ``variance`` [(rad/s)^2] on its diagonal (the bias is not in it: it is
    the estimator's to estimate), orientation and linear acceleration marked absent
    (:data:`IMU_ABSENT`); the header of the time it was measured ``t_s``.  Into ``out`` when given."""
    w = _encode(f"{topic.name} angular_velocity", omega_B, 3)
    msg = _imu(topic, t_s, out)
    msg.angular_velocity.x, msg.angular_velocity.y, msg.angular_velocity.z = w
    msg.angular_velocity_covariance = _diagonal(variance)
    msg.orientation.x = msg.orientation.y = msg.orientation.z = 0.0
    msg.orientation.w = 1.0
    msg.orientation_covariance[0] = msg.linear_acceleration_covariance[0] = IMU_ABSENT
    return msg


def star_tracker_msg(q_BN: ArrayLike, variance: ArrayLike, t_s: Any, topic: Topic, out: Any = None) -> Any:
    """A star-tracker sample as ``sensor_msgs/Imu`` for ``topic``
    (:data:`~sappc_msgs_py.contract.SENSOR_STAR_TRACKER`): ``orientation`` the measured ``q_BN``
    (x, y, z, w; the body, the header's frame, relative to inertial), ``orientation_covariance`` the
    per-axis ``variance`` [rad^2] of its small rotation error about the body axes on its diagonal,
    angular velocity and linear acceleration marked absent (:data:`IMU_ABSENT`); the header of the
    time it was measured ``t_s``.  Into ``out`` when given."""
    q = _encode(f"{topic.name} orientation", q_BN, 4)
    msg = _imu(topic, t_s, out)
    msg.orientation.x, msg.orientation.y, msg.orientation.z, msg.orientation.w = q
    msg.orientation_covariance = _diagonal(variance)
    msg.angular_velocity.x = msg.angular_velocity.y = msg.angular_velocity.z = 0.0
    msg.angular_velocity_covariance[0] = msg.linear_acceleration_covariance[0] = IMU_ABSENT
    return msg


def gyro_from_msg(msg: Any, topic: Topic) -> Array:
    """The angular velocity [rad/s] of a gyro ``sensor_msgs/Imu`` of ``topic``; checks the frame,
    that it measures one (its covariance not marked absent) and finiteness."""
    _check_frame(msg, topic)
    if msg.angular_velocity_covariance[0] == IMU_ABSENT:
        raise InputError(f"{topic.name}: no angular velocity (angular_velocity_covariance[0] is {IMU_ABSENT})")
    w = msg.angular_velocity
    return _finite(topic, "angular_velocity", [w.x, w.y, w.z])


def star_tracker_from_msg(msg: Any, topic: Topic) -> Array:
    """The orientation ``q_BN`` (x, y, z, w) of a star-tracker ``sensor_msgs/Imu`` of ``topic``;
    checks the frame, that it measures one (its covariance not marked absent) and finiteness (the
    unit norm is the consumer's check, which names the value)."""
    _check_frame(msg, topic)
    if msg.orientation_covariance[0] == IMU_ABSENT:
        raise InputError(f"{topic.name}: no orientation (orientation_covariance[0] is {IMU_ABSENT})")
    q = msg.orientation
    return _finite(topic, "orientation", [q.x, q.y, q.z, q.w])


#: The ``source`` of a tracker epoch (``sensor_msgs/TimeReference``): the sensor that measured it.
EPOCH_SOURCE = "star_tracker"


def epoch_msg(epoch_ns: int, t_s: Any, topic: Topic, out: Any = None) -> Any:
    """A ``sensor_msgs/TimeReference`` for ``topic``: the header of the sample ``t_s`` (seconds or
    a stamp) and ``time_ref`` the time [ns] the sensor measured the sample's value (a star tracker's
    quaternion, held between its updates, keeps its own time), ``source`` :data:`EPOCH_SOURCE`."""
    msg = _header(topic.msg_class() if out is None else out, t_s, topic.frame_id)
    msg.time_ref = ns_to_stamp(int(epoch_ns))
    msg.source = EPOCH_SOURCE
    return msg


def epoch_from_msg(msg: Any, topic: Topic) -> int:
    """The epoch [ns] of a ``TimeReference`` of ``topic``; checks the frame, and that it names its
    sensor (the "no data" sample names none: :func:`no_data_msg`).

    Raises
    ------
    InputError
        ``invalid``: a wrong frame id, or a "no data" sample.
    """
    _check_frame(msg, topic)
    if msg.source != EPOCH_SOURCE:
        raise InputError(f"{topic.name}: no epoch (source {msg.source!r}, not {EPOCH_SOURCE!r})")
    return stamp_to_ns(msg.time_ref)


def health_msg(t_s: Any, level: int, message: str, values: dict[str, str], out: Any = None, *, name: str | None = None,
               hardware_id: str = "sappc_estimator") -> Any:
    """A node's health as ROS reports health: a ``diagnostic_msgs/DiagnosticArray`` of one
    ``DiagnosticStatus`` (``name``, by default the estimator's
    :data:`~sappc_msgs_py.contract.ESTIMATOR_HEALTH_NAME`, and ``hardware_id``; ``level`` 0 OK, 1
    WARN, 2 ERROR, ``message``, ``values`` as key/values in their order), the header of the sample
    ``t_s`` (seconds or a stamp).  Into ``out`` (an array from this function) when given."""
    from diagnostic_msgs.msg import DiagnosticStatus, KeyValue

    from sappc_msgs_py.contract import ESTIMATOR_HEALTH, ESTIMATOR_HEALTH_NAME

    msg = ESTIMATOR_HEALTH.msg_class() if out is None else out
    time_to_stamp(t_s, out=msg.header.stamp)
    if not msg.status:
        msg.status = [DiagnosticStatus(name=ESTIMATOR_HEALTH_NAME if name is None else name, hardware_id=hardware_id)]
    status = msg.status[0]
    status.level = bytes([int(level)])
    status.message = message
    status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
    return msg


def torque_msg(torque_B: ArrayLike, t_s: float, topic: Topic = CONTROL_TORQUE, out: Any = None) -> Any:
    """A ``WrenchStamped`` carrying ``torque_B`` [N m] (body frame, zero force), or ``out`` filled
    (its force is left as it is: zero when it was built by this function)."""
    if topic.type_name != CONTROL_TORQUE.type_name:
        raise ValueError(f"{topic.name} does not carry a torque")
    a = _encode(f"{topic.name} torque", torque_B, 3)
    msg = _header(topic.msg_class() if out is None else out, t_s, topic.frame_id)
    msg.wrench.torque.x, msg.wrench.torque.y, msg.wrench.torque.z = a
    return msg


def torque_from_msg(msg: Any, topic: Topic = CONTROL_TORQUE) -> Array:
    """The torque [N m] of a ``WrenchStamped``; checks frame and finiteness."""
    _check_frame(msg, topic)
    tq = msg.wrench.torque
    return _finite(topic, "torque", [tq.x, tq.y, tq.z])


def wheel_names(n: int) -> list[str]:
    """The joint names of ``n`` wheels on ``joint_states``: ``wheel_1`` .. ``wheel_n``."""
    return [f"wheel_{i + 1}" for i in range(n)]


def joint_state_msg(speed_rad_s: ArrayLike, torque_Nm: ArrayLike, t_s: float, out: Any = None) -> Any:
    """A ``JointState`` of the wheels (``WHEEL_STATES``): ``velocity`` the speeds relative to the
    body [rad/s], ``effort`` the motor torques [N m], ``position`` empty; or ``out`` filled (its
    names are set once, when it is built here or has none)."""
    speed, torque = np.asarray(speed_rad_s, dtype=np.float64), np.asarray(torque_Nm, dtype=np.float64)
    n = speed.shape[0] if speed.ndim == 1 else -1
    v = _encode(f"{WHEEL_STATES.name} velocity", speed, n)
    e = _encode(f"{WHEEL_STATES.name} effort", torque, n)
    msg = _header(WHEEL_STATES.msg_class() if out is None else out, t_s, WHEEL_STATES.frame_id)
    if len(msg.name) != n:
        msg.name = wheel_names(n)
    msg.velocity, msg.effort = v, e
    return msg


def transform_msg(topic: Topic) -> Any:
    """A ``TransformStamped`` for a transform topic (``STATE_TF``, ``REFERENCE_TF``): parent frame
    ``topic.frame_id``, child frame ``topic.child_frame_id``, translation zero, identity rotation,
    stamp zero.  A publisher builds one at start-up and fills it per sample with
    :func:`transform_from_attitude` (two assignments: the per-sample cost stays small)."""
    if topic.child_frame_id is None:
        raise ValueError(f"{topic.name} does not carry a transform")
    msg = topic.msg_class()
    msg.header.frame_id = topic.frame_id or ""
    msg.child_frame_id = topic.child_frame_id
    msg.transform.rotation.w = 1.0
    return msg


def transform_from_attitude(msg: Any, attitude: Any) -> Any:
    """``msg`` (from :func:`transform_msg`) with the stamp and quaternion of ``attitude``, a
    ``QuaternionStamped`` already encoded (``state/attitude``: ``q_BN``; ``reference/attitude``:
    ``q_RN``); returns ``msg``.

    The quaternion goes in as it is: a transform's rotation maps child-frame coordinates to
    parent-frame coordinates, and ``q_BN`` maps body coordinates to inertial ones
    (``v_N = q_BN ⊗ v_B ⊗ q_BN*``, :mod:`gnc_common.attitude`), so the child ``body`` in the parent
    ``inertial`` is ``q_BN``, not its conjugate.  The message shares the attitude's stamp and
    quaternion objects (rclpy serialises at ``publish``, and the attitude is filled for the sample
    before the transform is published).
    """
    msg.header.stamp = attitude.header.stamp
    msg.transform.rotation = attitude.quaternion
    return msg


def diagnostics_msg(t_s: float, rows: dict[str, ArrayLike], out: Any = None) -> Any:
    """A ``Float64MultiArray`` with the rows of :data:`DIAGNOSTICS_LAYOUT` (3 values each), or
    ``out`` filled.

    ``rows`` maps every label except ``time_s`` to 3 values; the labels go into ``layout.dim``.
    """
    return _float_array(np.array(diagnostics_values(t_s, rows)), _diagnostics_layout(), out)


_DIAGNOSTICS_ROWS = frozenset(DIAGNOSTICS_LAYOUT[1:])


def diagnostics_values(t_s: float, rows: dict[str, ArrayLike]) -> list[float]:
    """The data of :func:`diagnostics_msg`, row major (``time_s`` three times, then each row of
    ``rows`` in the layout's order; the nodes publish it as bytes with
    :func:`sappc_msgs_py.wire.codec`).  A row is 3 values (a float64 vector, or anything
    ``numpy.asarray`` makes 3 float64 of)."""
    if rows.keys() != _DIAGNOSTICS_ROWS:
        missing = [k for k in DIAGNOSTICS_LAYOUT[1:] if k not in rows]
        raise ValueError(f"diagnostics need exactly {DIAGNOSTICS_LAYOUT[1:]}, missing {missing}, extra {sorted(set(rows) - set(DIAGNOSTICS_LAYOUT))}")
    t = float(t_s)
    data = [t, t, t]
    for label in DIAGNOSTICS_LAYOUT[1:]:
        row = rows[label]
        if isinstance(row, list) and len(row) == 3:
            data += row
        elif type(row) is np.ndarray and row.shape == (3,) and row.dtype == np.float64:
            data += row.tolist()
        else:
            data += np.asarray(row, dtype=np.float64).reshape(3).tolist()
    return data


@functools.cache
def _diagnostics_layout() -> Any:
    from std_msgs.msg import MultiArrayDimension, MultiArrayLayout

    n = len(DIAGNOSTICS_LAYOUT)
    return MultiArrayLayout(dim=[
        MultiArrayDimension(label=",".join(DIAGNOSTICS_LAYOUT), size=n, stride=3 * n),
        MultiArrayDimension(label="axis", size=3, stride=3),
    ])


def diagnostics_from_msg(msg: Any) -> dict[str, Array]:
    """The labelled rows of a diagnostics message (labels read from its layout)."""
    labels = msg.layout.dim[0].label.split(",")
    data = np.asarray(msg.data, dtype=np.float64).reshape(len(labels), 3)
    return {label: data[i] for i, label in enumerate(labels)}


#: A value of the "no data" sample (the convention of REP 117 for invalid ranges).
_NO_DATA = float("nan")


def no_data_msg(topic: Topic, t_s: Any, out: Any = None) -> Any:
    """The contract's "no data" sample of ``topic`` (a ``QuaternionStamped`` or ``Vector3Stamped``
    topic): the header of time ``t_s`` (seconds or a stamp, :func:`time_to_stamp`) and NaN in every
    value, what a relay sends for a dropped measurement and an estimator for a sample without an
    estimate; a consumer takes no value from it but knows its sample arrived, and counts it apart
    from the messages it rejects (:func:`is_no_data_msg`; :func:`sappc_msgs_py.inputs.screen_input`).
    Into ``out`` when given."""
    msg = _header(topic.msg_class() if out is None else out, t_s, topic.frame_id)
    if topic.type_name.endswith("QuaternionStamped"):
        msg.quaternion.x = msg.quaternion.y = msg.quaternion.z = msg.quaternion.w = _NO_DATA
    elif topic.type_name.endswith("Vector3Stamped"):
        msg.vector.x = msg.vector.y = msg.vector.z = _NO_DATA
    elif topic.type_name.endswith("Imu"):  # NaN in what the sensor measures (the other parts stay absent)
        msg.orientation.x = msg.orientation.y = msg.orientation.z = msg.orientation.w = _NO_DATA
        msg.angular_velocity.x = msg.angular_velocity.y = msg.angular_velocity.z = _NO_DATA
        msg.linear_acceleration_covariance[0] = IMU_ABSENT
    elif topic.type_name.endswith("TimeReference"):  # no time to hold NaN: the epoch names no sensor
        msg.time_ref = ns_to_stamp(0)
        msg.source = ""
    else:
        raise ValueError(f"{topic.name} has no 'no data' sample (a QuaternionStamped, Vector3Stamped, Imu or TimeReference topic has)")
    return msg


def is_no_data_msg(msg: Any, topic: Topic) -> bool:
    """Whether ``msg`` is the contract's "no data" sample of ``topic`` (what :func:`no_data_msg`
    builds): the topic's frame id and NaN in every value it carries (an ``Imu``: in every part not
    marked absent, at least one part; a ``TimeReference``: no ``source``).  A message that is only
    partly NaN, holds an Inf or has another frame id is not: that one is invalid."""
    if getattr(getattr(msg, "header", None), "frame_id", None) != topic.frame_id:
        return False
    name = topic.type_name
    if name.endswith("QuaternionStamped"):
        q = msg.quaternion
        values = [q.x, q.y, q.z, q.w]
    elif name.endswith("Vector3Stamped"):
        v = msg.vector
        values = [v.x, v.y, v.z]
    elif name.endswith("Imu"):
        values = []
        if msg.orientation_covariance[0] != IMU_ABSENT:
            o = msg.orientation
            values += [o.x, o.y, o.z, o.w]
        if msg.angular_velocity_covariance[0] != IMU_ABSENT:
            w = msg.angular_velocity
            values += [w.x, w.y, w.z]
    elif name.endswith("TimeReference"):
        return bool(msg.source == "")
    else:
        return False
    return bool(values) and all(math.isnan(v) for v in values)


def _float_array(values: NDArray[np.float64], layout: Any, out: Any) -> Any:
    from std_msgs.msg import Float64MultiArray

    msg = Float64MultiArray() if out is None else out
    msg.layout = layout
    data = array.array("d")
    data.frombytes(np.ascontiguousarray(values, dtype=np.float64).tobytes())  # taken as it is (a list is checked value by value)
    msg.data = data
    return msg


def covariance_msg(t_s: float, P: ArrayLike | None, out: Any = None) -> Any:
    """An ``estimator/covariance`` message: ``data[0] = t_s`` [s], then the 6 x 6 covariance ``P``
    of :data:`~sappc_msgs_py.contract.ERROR_STATE` row major (:data:`~sappc_msgs_py.contract.COVARIANCE_DIMS`);
    ``P`` ``None`` gives the "no data" sample (NaN covariance).  Into ``out`` when given.

    Raises
    ------
    InputError
        When ``P`` is not a finite (6, 6) array.
    """
    return _float_array(covariance_values(t_s, P), _covariance_layout(), out)


def covariance_values(t_s: float, P: ArrayLike | None) -> Array:
    """The data of :func:`covariance_msg` (the nodes publish it as bytes with
    :func:`sappc_msgs_py.wire.codec`).

    Raises
    ------
    InputError
        When ``P`` is not a finite (6, 6) array.
    """
    n = len(ERROR_STATE)
    data = np.empty(1 + n * n)
    data[0] = t_s
    data[1:] = _NO_DATA if P is None else as_finite_array("estimator/covariance P", P, shape_tail=(n, n)).reshape(n * n)
    return data


@functools.cache
def _covariance_layout() -> Any:
    from std_msgs.msg import MultiArrayDimension, MultiArrayLayout

    n = len(ERROR_STATE)
    return MultiArrayLayout(dim=[MultiArrayDimension(label=COVARIANCE_DIMS[0], size=n, stride=n * n),
                                 MultiArrayDimension(label=COVARIANCE_DIMS[1], size=n, stride=n)], data_offset=1)


def covariance_from_msg(msg: Any) -> tuple[float, Array]:
    """``(t_s, P)`` of an ``estimator/covariance`` message (:func:`covariance_msg`).

    Raises
    ------
    InputError
        When the message's layout is not :data:`~sappc_msgs_py.contract.COVARIANCE_DIMS`.
    """
    n = len(ERROR_STATE)
    labels = tuple(d.label for d in msg.layout.dim)
    if labels != COVARIANCE_DIMS or msg.layout.data_offset != 1 or len(msg.data) != 1 + n * n:
        raise InputError(f"not an estimator covariance message (dims {labels}, data_offset {msg.layout.data_offset}, {len(msg.data)} values)")
    data = np.asarray(msg.data, dtype=np.float64)
    return float(data[0]), data[1:].reshape(n, n)


def estimator_diagnostics_msg(values: ArrayLike, out: Any = None) -> Any:
    """An ``estimator/diagnostics`` message: ``values`` in the order of
    :data:`~sappc_msgs_py.contract.ESTIMATOR_DIAGNOSTICS_LAYOUT` (``time_s`` first), labelled.
    Into ``out`` when given."""
    data = np.asarray(values, dtype=np.float64)
    if data.shape != (len(ESTIMATOR_DIAGNOSTICS_LAYOUT),):
        raise ValueError(f"estimator diagnostics need {len(ESTIMATOR_DIAGNOSTICS_LAYOUT)} values {ESTIMATOR_DIAGNOSTICS_LAYOUT}, got shape {data.shape}")
    return _float_array(data, _estimator_diagnostics_layout(), out)


@functools.cache
def _estimator_diagnostics_layout() -> Any:
    from std_msgs.msg import MultiArrayDimension, MultiArrayLayout

    n = len(ESTIMATOR_DIAGNOSTICS_LAYOUT)
    return MultiArrayLayout(dim=[MultiArrayDimension(label=",".join(ESTIMATOR_DIAGNOSTICS_LAYOUT), size=n, stride=n)])


def estimator_diagnostics_from_msg(msg: Any) -> dict[str, float]:
    """The labelled values of an ``estimator/diagnostics`` message (labels read from its layout)."""
    labels = msg.layout.dim[0].label.split(",")
    return {label: float(v) for label, v in zip(labels, msg.data, strict=True)}


def clock_msg(t_s: float, out: Any = None) -> Any:
    """A ``rosgraph_msgs/Clock`` for simulation time ``t_s``, or ``out`` filled."""
    if out is None:
        from rosgraph_msgs.msg import Clock

        out = Clock()
    time_to_stamp(t_s, out.clock)
    return out


# ---- the orbit's topics (issue 36) --------------------------------------------------------------
def magnetic_field_msg(field_T: ArrayLike, t_s: Any, topic: Topic = STATE_MAGNETIC_FIELD, variance_T2: ArrayLike = (0.0, 0.0, 0.0),
                       out: Any = None) -> Any:
    """A ``sensor_msgs/MagneticField`` (``STATE_MAGNETIC_FIELD`` or ``TRUTH_MAGNETIC_FIELD``):
    ``magnetic_field`` the field in B [T], ``magnetic_field_covariance`` ``diag(variance_T2)``
    [T^2] row major (zero: known exactly); or ``out`` filled."""
    if topic.type_name != STATE_MAGNETIC_FIELD.type_name:
        raise ValueError(f"{topic.name} does not carry a magnetic field")
    b = _encode(f"{topic.name} magnetic_field", field_T, 3)
    var = _encode(f"{topic.name} variance", variance_T2, 3)
    msg = _header(topic.msg_class() if out is None else out, t_s, topic.frame_id)
    msg.magnetic_field.x, msg.magnetic_field.y, msg.magnetic_field.z = b
    cov = np.zeros(9)
    cov[[0, 4, 8]] = var
    msg.magnetic_field_covariance = cov
    return msg


def magnetic_field_from_msg(msg: Any, topic: Topic = STATE_MAGNETIC_FIELD) -> Array:
    """The field [T] of a ``MagneticField``; checks frame and finiteness."""
    _check_frame(msg, topic)
    f = msg.magnetic_field
    return _finite(topic, "magnetic_field", [f.x, f.y, f.z])


def wheel_speed_msg(speed_rad_s: ArrayLike, t_s: Any, out: Any = None) -> Any:
    """The tachometers' ``JointState`` (``STATE_WHEEL_SPEED``): ``velocity`` the wheels' speeds
    relative to the body [rad/s], ``position`` and ``effort`` empty; or ``out`` filled."""
    speed = np.asarray(speed_rad_s, dtype=np.float64)
    n = speed.shape[0] if speed.ndim == 1 else -1
    v = _encode(f"{STATE_WHEEL_SPEED.name} velocity", speed, n)
    msg = _header(STATE_WHEEL_SPEED.msg_class() if out is None else out, t_s, STATE_WHEEL_SPEED.frame_id)
    if len(msg.name) != n:
        msg.name = wheel_names(n)
    msg.velocity = v
    return msg


def wheel_speed_from_msg(msg: Any, n_wheels: int) -> Array:
    """The speeds [rad/s] of a ``state/wheel_speed`` message; checks frame, count and finiteness."""
    _check_frame(msg, STATE_WHEEL_SPEED)
    if len(msg.velocity) != n_wheels:
        raise InputError(f"{STATE_WHEEL_SPEED.name}: {len(msg.velocity)} speeds for {n_wheels} wheels")
    return _finite(STATE_WHEEL_SPEED, "velocity", list(msg.velocity))


@functools.cache
def _dipole_layout(n_rods: int) -> Any:
    from std_msgs.msg import MultiArrayDimension, MultiArrayLayout

    labels = ["time_s"] + [f"{DIPOLE_LABEL_PREFIX}{j + 1}" for j in range(n_rods)]
    return MultiArrayLayout(dim=[MultiArrayDimension(label=",".join(labels), size=n_rods + 1, stride=n_rods + 1)])


def dipole_msg(t_s: float, dipoles_Am2: ArrayLike, out: Any = None) -> Any:
    """A ``control/dipole`` message: ``data[0]`` the sample's time ``t_s`` [s], then each rod's
    dipole command [A m^2]; labelled (:data:`~sappc_msgs_py.contract.DIPOLE_LABEL_PREFIX`).  Into
    ``out`` when given."""
    m = np.asarray(dipoles_Am2, dtype=np.float64).reshape(-1)
    data = np.empty(m.size + 1)
    data[0] = t_s
    data[1:] = m
    return _float_array(data, _dipole_layout(int(m.size)), out)


def dipole_from_msg(msg: Any, n_rods: int) -> tuple[float, Array]:
    """``(time_s, dipoles)`` of a ``control/dipole`` message; checks the layout, count and finiteness."""
    labels = msg.layout.dim[0].label.split(",") if msg.layout.dim else []
    if not labels or labels[0] != "time_s" or len(labels) != len(msg.data) or len(msg.data) != n_rods + 1:
        raise InputError(f"{CONTROL_DIPOLE.name}: expected time_s and {n_rods} rods, got labels {labels} and {len(msg.data)} values")
    data = _finite(CONTROL_DIPOLE, "data", list(msg.data))
    return float(data[0]), data[1:]

"""The contract's messages as CDR bytes (:mod:`sappc_msgs_py.wire`, issue 48), checked against rclpy.

For every layout the nodes and the offline bag writer use: the bytes :class:`~sappc_msgs_py.wire.Codec`
encodes deserialize (rclpy) into the message :mod:`sappc_msgs_py.convert`'s object encoder builds for
the same values, equal rclpy's own serialization of it at every byte but the alignment padding, and
:meth:`~sappc_msgs_py.wire.Codec.values` reads rclpy's serialization back bit for bit.  Then the
fallback of :func:`~sappc_msgs_py.wire.take` (another frame, NaN, another byte order or size: the
object decoder decides, with the contract's error), the encoder's checks, and the stamps.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from fractions import Fraction
from typing import Any, Callable

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message

from gnc_common.validation import InputError
from sappc_msgs_py import contract as c
from sappc_msgs_py import wire
from sappc_msgs_py.convert import (
    cdr_stamp_ns,
    clock_msg,
    covariance_msg,
    diagnostics_msg,
    diagnostics_values,
    dipole_msg,
    estimator_diagnostics_msg,
    epoch_msg,
    gyro_from_msg,
    gyro_msg,
    is_no_data_msg,
    joint_state_msg,
    magnetic_field_msg,
    no_data_msg,
    ns_to_stamp,
    quaternion_from_msg,
    quaternion_msg,
    seconds_to_ns,
    seconds_to_ns_array,
    star_tracker_from_msg,
    star_tracker_msg,
    stamp_to_ns,
    time_to_ns,
    time_to_stamp,
    torque_from_msg,
    torque_msg,
    transform_from_attitude,
    transform_msg,
    vector3_from_msg,
    vector3_msg,
    wheel_speed_msg,
)

#: The stamp of every case: sec 1234, nanosec 567890123 (neither part zero, nanosec near its top).
STAMP_NS = 1234 * 10**9 + 567_890_123
#: Its time as a float, for the float arrays' ``data[0]``.
T_S = STAMP_NS / 1e9
#: Values that a float-by-float copy could get wrong: a negative zero, the smallest subnormal, the largest double.
SPECIALS = [-0.0, 5e-324, -1.7976931348623157e308]


@dataclass
class Case:
    """One layout: its codec, what it encodes, and the message convert.py builds for the same values."""

    layout: wire.Layout
    codec: wire.Codec
    stamp_ns: int | None
    groups: list[list[float]]
    msg: Any  # the object encoder's message
    type_name: str

    @property
    def values(self) -> list[float]:
        return [v for g in self.groups for v in g]


def _vals(rng: np.random.Generator, n: int, scale: float = 1.0) -> list[float]:
    """``n`` random finite doubles, with the specials mixed in when there is room."""
    out = (rng.standard_normal(n) * scale).tolist()
    for i, s in enumerate(SPECIALS[: max(0, n - 1)]):
        out[(i * 2 + 1) % n] = s
    return out


def _quat(rng: np.random.Generator) -> list[float]:
    q = rng.standard_normal(4)
    return (q / np.linalg.norm(q)).tolist()


def _topic_case(topic: c.Topic, layout: wire.Layout, rng: np.random.Generator) -> Case:
    """A case of a topic that :func:`wire.codec` serves (the loop's topics and the relays' twins)."""
    stamp = ns_to_stamp(STAMP_NS)
    kind = topic.type_name.rsplit("/", 1)[1]
    if kind == "QuaternionStamped":
        g = _quat(rng)
        msg = quaternion_msg(g, stamp, topic)
    elif kind == "Vector3Stamped":
        g = _vals(rng, 3)
        msg = vector3_msg(g, stamp, topic)
    elif kind == "WrenchStamped":
        g = _vals(rng, 3, 0.1)
        msg = torque_msg(g, stamp, topic)
    elif kind == "TransformStamped":
        g = _quat(rng)
        attitude_topic = c.REFERENCE_ATTITUDE if "reference" in topic.name else c.STATE_ATTITUDE
        msg = transform_from_attitude(transform_msg(topic), quaternion_msg(g, stamp, attitude_topic))
    elif kind == "Clock":
        return Case(layout, wire.codec(topic), STAMP_NS, [], clock_msg(stamp), topic.type_name)
    elif kind == "Float64MultiArray":  # controller/diagnostics
        rows = {label: _vals(rng, 3) for label in c.DIAGNOSTICS_LAYOUT[1:]}
        data = np.asarray(diagnostics_values(T_S, rows), dtype=np.float64).ravel().tolist()
        return Case(layout, wire.codec(topic), None, [data], diagnostics_msg(T_S, rows), topic.type_name)
    else:  # pragma: no cover
        raise AssertionError(kind)
    return Case(layout, wire.codec(topic), STAMP_NS, [g], msg, topic.type_name)


#: The loop's topics, each with the layout built by the module's builders as documented (the
#: codec :func:`wire.codec` serves must have the same template).
TOPIC_LAYOUTS: dict[str, tuple[c.Topic, Callable[[], wire.Layout]]] = {
    "state_attitude": (c.STATE_ATTITUDE, lambda: wire.stamped(c.STATE_ATTITUDE, "q_BN", 4)),
    "state_rate": (c.STATE_RATE, lambda: wire.stamped(c.STATE_RATE, "omega_BN_B", 3)),
    "state_tf": (c.STATE_TF, lambda: wire.transform(c.STATE_TF, "q_BN")),
    "reference_attitude": (c.REFERENCE_ATTITUDE, lambda: wire.stamped(c.REFERENCE_ATTITUDE, "q_RN", 4)),
    "reference_rate": (c.REFERENCE_RATE, lambda: wire.stamped(c.REFERENCE_RATE, "omega_RN_R", 3)),
    "reference_acceleration": (c.REFERENCE_ACCELERATION, lambda: wire.stamped(c.REFERENCE_ACCELERATION, "omegadot_RN_R", 3)),
    "reference_tf": (c.REFERENCE_TF, lambda: wire.transform(c.REFERENCE_TF, "q_RN")),
    "control_torque": (c.CONTROL_TORQUE, lambda: wire.stamped(c.CONTROL_TORQUE, "torque_B", 3, before=3)),
    "disturbance_torque": (c.DISTURBANCE_TORQUE, lambda: wire.stamped(c.DISTURBANCE_TORQUE, "disturbance_B", 3, before=3)),
    "clock": (c.CLOCK, wire.clock),
    "controller_diagnostics": (c.CONTROLLER_DIAGNOSTICS, wire.controller_diagnostics),
    # the fault relays' twins: the layout from the type and the frame
    "fault_state_attitude": (c.faulty(c.STATE_ATTITUDE), lambda: wire.stamped(c.faulty(c.STATE_ATTITUDE), "quaternion", 4)),
    "fault_state_rate": (c.faulty(c.STATE_RATE), lambda: wire.stamped(c.faulty(c.STATE_RATE), "vector", 3)),
    "fault_reference_attitude": (c.faulty(c.REFERENCE_ATTITUDE), lambda: wire.stamped(c.faulty(c.REFERENCE_ATTITUDE), "quaternion", 4)),
    "fault_control_torque": (c.faulty(c.CONTROL_TORQUE), lambda: wire.stamped(c.faulty(c.CONTROL_TORQUE), "torque", 3, before=3)),
}
MAGNETIC_VARIANCE_T2 = np.array([1.0e-14, 2.5e-14, 4.0e-14])
OTHER_CASES = ["magnetic_field", "joint_state_with_effort", "joint_state_without_effort", "covariance", "estimator_diagnostics",
               "dipole_3_rods"]


def _other_case(name: str, rng: np.random.Generator) -> Case:
    """The layouts the offline bag writer fills (not served by :func:`wire.codec`)."""
    stamp = ns_to_stamp(STAMP_NS)
    if name == "magnetic_field":
        layout = wire.magnetic_field(c.STATE_MAGNETIC_FIELD, "field", MAGNETIC_VARIANCE_T2)
        b = (rng.standard_normal(3) * 3e-5).tolist()
        msg = magnetic_field_msg(b, stamp, c.STATE_MAGNETIC_FIELD, MAGNETIC_VARIANCE_T2)
        return Case(layout, wire.Codec(layout, c.STATE_MAGNETIC_FIELD.name), STAMP_NS, [b], msg, c.STATE_MAGNETIC_FIELD.type_name)
    if name == "joint_state_with_effort":
        layout = wire.joint_state(c.WHEEL_STATES, 4, "speed", "effort")
        speed, effort = _vals(rng, 4, 100.0), _vals(rng, 4, 0.01)
        msg = joint_state_msg(speed, effort, stamp)
        return Case(layout, wire.Codec(layout, c.WHEEL_STATES.name), STAMP_NS, [speed, effort], msg, c.WHEEL_STATES.type_name)
    if name == "joint_state_without_effort":
        layout = wire.joint_state(c.STATE_WHEEL_SPEED, 4, "speed", None)
        speed = _vals(rng, 4, 100.0)
        msg = wheel_speed_msg(speed, stamp)
        return Case(layout, wire.Codec(layout, c.STATE_WHEEL_SPEED.name), STAMP_NS, [speed], msg, c.STATE_WHEEL_SPEED.type_name)
    if name == "covariance":
        layout = wire.covariance()
        P = rng.standard_normal((6, 6))
        P = P @ P.T
        msg = covariance_msg(T_S, P)
        return Case(layout, wire.Codec(layout, c.ESTIMATOR_COVARIANCE.name), None, [[T_S, *P.ravel().tolist()]], msg,
                    c.ESTIMATOR_COVARIANCE.type_name)
    if name == "estimator_diagnostics":
        layout = wire.estimator_diagnostics()
        values = [T_S, *_vals(rng, len(c.ESTIMATOR_DIAGNOSTICS_LAYOUT) - 1)]
        msg = estimator_diagnostics_msg(values)
        return Case(layout, wire.Codec(layout, c.ESTIMATOR_DIAGNOSTICS.name), None, [values], msg, c.ESTIMATOR_DIAGNOSTICS.type_name)
    if name == "dipole_3_rods":
        layout = wire.dipole(3)
        m = _vals(rng, 3, 10.0)
        msg = dipole_msg(T_S, m)
        return Case(layout, wire.Codec(layout, c.CONTROL_DIPOLE.name), None, [[T_S, *m]], msg, c.CONTROL_DIPOLE.type_name)
    raise AssertionError(name)  # pragma: no cover


ALL_CASES = [*TOPIC_LAYOUTS, *OTHER_CASES]


def _case(name: str, rng: np.random.Generator) -> Case:
    if name in TOPIC_LAYOUTS:
        topic, build = TOPIC_LAYOUTS[name]
        return _topic_case(topic, build(), rng)
    return _other_case(name, rng)


def _msg_class(type_name: str) -> type:
    return c.Topic("x", type_name, None).msg_class


def _bits(x: float) -> bytes:
    return struct.pack("<d", x)


def _flatten(msg: Any, path: str = "") -> list[tuple[str, Any]]:
    """Every leaf of a message object, by path; floats as their 8 bytes (bit for bit: -0.0, NaN)."""
    if hasattr(msg, "get_fields_and_field_types"):
        out: list[tuple[str, Any]] = []
        for name in msg.get_fields_and_field_types():
            out += _flatten(getattr(msg, name), f"{path}.{name}")
        return out
    if isinstance(msg, float):
        return [(path, _bits(msg))]
    if isinstance(msg, (list, tuple)) or hasattr(msg, "__len__") and not isinstance(msg, (str, bytes)):
        out = [(f"{path}.len", len(msg))]
        for i, v in enumerate(msg):
            out += _flatten(float(v) if isinstance(v, (float, np.floating)) else v, f"{path}[{i}]")
        return out
    return [(path, msg)]


def _covered(layout: wire.Layout) -> set[int]:
    """The byte positions the layout writes a value or a fixed part at (the rest is alignment padding
    and the encapsulation options, bytes 2-3)."""
    pos = {0, 1}
    for a, b in layout.fixed:
        pos.update(range(a, b))
    for f in layout.fields:
        pos.update(range(f.offset, f.offset + 8 * max(f.count, 1)))  # a stamp: int32 sec, uint32 nanosec
    return pos


#: The types whose ``rclpy.serialization.serialize_message`` (rclpy 7.1.6, rmw_fastrtps 8.4.3) is
#: longer than the CDR it holds: a ``JointState`` of 4 wheels comes with 8 (with efforts) or 12
#: (without) bytes of whatever memory held past its last value (rclpy deserializes it all the same;
#: what a publisher of the same object sends, and a raw subscriber receives, is the CDR alone).
RCLPY_TRAILING_BYTES = ("sensor_msgs/msg/JointState",)


def _rclpy_cdr(case: Case) -> bytes:
    """rclpy's serialization of the case's object message, cut to the CDR it holds (the layout's size)
    for a type of :data:`RCLPY_TRAILING_BYTES`; the cut bytes still deserialize into the same message."""
    ref = serialize_message(case.msg)
    if case.type_name not in RCLPY_TRAILING_BYTES:
        return ref
    assert len(ref) >= case.codec.size
    cut = ref[: case.codec.size]
    assert _flatten(deserialize_message(cut, _msg_class(case.type_name))) == _flatten(case.msg)
    return cut


# ---- every layout against rclpy ---------------------------------------------------------------
@pytest.mark.parametrize("name", ALL_CASES)
def test_the_encoded_bytes_deserialize_into_the_object_encoders_message(name: str, rng: np.random.Generator) -> None:
    """rclpy reads the codec's bytes as the message convert.py builds for the same values, field by field, bit for bit."""
    case = _case(name, rng)
    raw = case.codec.encode(case.stamp_ns, *case.groups)
    got = deserialize_message(raw, _msg_class(case.type_name))
    assert _flatten(got) == _flatten(case.msg)
    if case.stamp_ns is not None:
        stamp = got.clock if case.type_name.endswith("Clock") else got.header.stamp
        assert (stamp.sec, stamp.nanosec) == (1234, 567_890_123)


@pytest.mark.parametrize("name", ALL_CASES)
def test_the_encoded_bytes_equal_rclpys_serialization_but_for_the_padding(name: str, rng: np.random.Generator) -> None:
    """The codec writes what rclpy's serializer writes at every byte that is not alignment padding, and zero padding."""
    case = _case(name, rng)
    raw = case.codec.encode(case.stamp_ns, *case.groups)
    ref = _rclpy_cdr(case)
    assert len(raw) == len(ref) == case.codec.size == len(case.layout.buf)
    covered = _covered(case.layout)
    diff = [i for i in sorted(covered) if raw[i] != ref[i]]
    assert not diff, f"bytes differ at {diff}: ours {raw.hex()}, rclpy {ref.hex()}"
    # what is not covered is alignment padding only: each gap shorter than a double, ending aligned
    # (from the end of the encapsulation header), and written zero
    gaps: list[tuple[int, int]] = []
    for i in range(4, len(raw)):
        if i not in covered:
            if gaps and gaps[-1][1] == i:
                gaps[-1] = (gaps[-1][0], i + 1)
            else:
                gaps.append((i, i + 1))
    for a, b in gaps:
        assert b - a < 8 and (b - 4) % 4 == 0, f"{name}: bytes {a}..{b} are neither a value, a fixed part nor padding"
        assert raw[a:b] == bytes(b - a)
    assert raw[:4] == wire.CDR_LE
    assert len(raw) - 1 in covered, f"{name}: padding after the last value (CDR ends with its last value)"


@pytest.mark.parametrize("name", ALL_CASES)
def test_values_reads_rclpys_serialization_bit_for_bit(name: str, rng: np.random.Generator) -> None:
    """Codec.values of rclpy's serialization of the object message returns the encoded values, bit for bit."""
    case = _case(name, rng)
    ref = _rclpy_cdr(case)
    got = case.codec.values(ref)
    assert got is not None, f"{name}: rclpy's bytes not taken by the fast path"
    assert [_bits(v) for v in got] == [_bits(v) for v in case.values]
    assert case.codec.count == len(case.values)


@pytest.mark.parametrize("name", list(TOPIC_LAYOUTS))
def test_codec_of_a_topic_is_the_builders_layout(name: str) -> None:
    """wire.codec(topic) serves the template the documented builder makes for the topic (and caches it)."""
    topic, build = TOPIC_LAYOUTS[name]
    assert wire.codec(topic).template == bytes(build().buf)
    assert wire.codec(topic) is wire.codec(topic)
    assert wire.codec(topic).finite is (topic is not c.CONTROLLER_DIAGNOSTICS)


def test_codec_refuses_a_type_without_a_fixed_layout() -> None:
    """wire.codec raises ValueError naming the topic for a type it has no layout for."""
    for topic in (c.WHEEL_STATES, c.STATE_MAGNETIC_FIELD, c.ESTIMATOR_HEALTH):
        with pytest.raises(ValueError, match=topic.name):
            wire.codec(topic)


def test_the_builders_write_the_labels_counts_and_fixed_values_the_object_encoders_write() -> None:
    """A layout's fixed parts: frame ids, joint names, labels, sizes and the magnetometer's covariance, as rclpy reads them."""
    mf = deserialize_message(bytes(wire.magnetic_field(c.STATE_MAGNETIC_FIELD, "f", MAGNETIC_VARIANCE_T2).buf), _msg_class(
        c.STATE_MAGNETIC_FIELD.type_name))
    assert mf.header.frame_id == "body"
    assert mf.magnetic_field_covariance.tolist() == [1.0e-14, 0, 0, 0, 2.5e-14, 0, 0, 0, 4.0e-14]
    js = deserialize_message(bytes(wire.joint_state(c.WHEEL_STATES, 4, "s", "e").buf), _msg_class(c.WHEEL_STATES.type_name))
    assert js.name == ["wheel_1", "wheel_2", "wheel_3", "wheel_4"] and len(js.position) == 0 and len(js.velocity) == len(js.effort) == 4
    dp = deserialize_message(bytes(wire.dipole(3).buf), _msg_class(c.CONTROL_DIPOLE.type_name))
    assert dp.layout.dim[0].label == "time_s,rod_1,rod_2,rod_3" and dp.layout.dim[0].size == 4 and len(dp.data) == 4
    tf = deserialize_message(bytes(wire.transform(c.REFERENCE_TF, "q").buf), _msg_class(c.REFERENCE_TF.type_name))
    assert (tf.header.frame_id, tf.child_frame_id) == ("inertial", "reference")


# ---- take: the fast path decides nothing -----------------------------------------------------
DECODERS: dict[str, tuple[c.Topic, Callable[[Any], Any]]] = {
    "attitude": (c.STATE_ATTITUDE, lambda m: quaternion_from_msg(m, c.STATE_ATTITUDE)),
    "rate": (c.STATE_RATE, lambda m: vector3_from_msg(m, c.STATE_RATE)),
    "reference_acceleration": (c.REFERENCE_ACCELERATION, lambda m: vector3_from_msg(m, c.REFERENCE_ACCELERATION)),
    "torque": (c.CONTROL_TORQUE, lambda m: torque_from_msg(m, c.CONTROL_TORQUE)),
}


def _sample(topic: c.Topic, values: list[float]) -> Any:
    stamp = ns_to_stamp(STAMP_NS)
    if topic.type_name.endswith("QuaternionStamped"):
        return quaternion_msg(values, stamp, topic)
    if topic.type_name.endswith("Vector3Stamped"):
        return vector3_msg(values, stamp, topic)
    return torque_msg(values, stamp, topic)


def _not_called(_msg: Any) -> Any:
    raise AssertionError("the object decoder was called for a message of the layout")


@pytest.mark.parametrize("which", list(DECODERS))
def test_take_reads_a_message_of_the_layout_without_the_object_decoder(which: str, rng: np.random.Generator) -> None:
    """A message of the layout with finite values is taken by the fast path: the values, bit for bit."""
    topic, _ = DECODERS[which]
    values = _quat(rng) if "attitude" in which else _vals(rng, 3)
    for raw in (serialize_message(_sample(topic, values)), wire.codec(topic).encode(STAMP_NS, values)):
        got = wire.take(raw, topic, _not_called)
        assert isinstance(got, np.ndarray) and got.dtype == np.float64
        assert [_bits(v) for v in got.tolist()] == [_bits(v) for v in values]


@pytest.mark.parametrize("frame", ["body", "inertiaX", "", "a_much_longer_frame_id"])
@pytest.mark.parametrize("which", list(DECODERS))
def test_take_of_another_frame_raises_the_object_decoders_error(which: str, frame: str, rng: np.random.Generator) -> None:
    """A message with a frame id not the contract's (same length or not) raises the object decoder's InputError, word for word."""
    topic, decoder = DECODERS[which]
    if frame == topic.frame_id:
        frame = "inertial"
    msg = _sample(topic, _quat(rng) if "attitude" in which else _vals(rng, 3))
    msg.header.frame_id = frame
    raw = serialize_message(msg)
    assert wire.codec(topic).values(raw) is None
    with pytest.raises(InputError) as expected:
        decoder(msg)
    with pytest.raises(InputError) as got:
        wire.take(raw, topic, decoder)
    assert str(got.value) == str(expected.value) and topic.name in str(got.value) and repr(frame) in str(got.value)


@pytest.mark.parametrize("which", list(DECODERS))
@pytest.mark.parametrize("bad", ["no_data", "inf"])
def test_take_of_a_non_finite_value_raises_via_the_object_decoder(which: str, bad: str, rng: np.random.Generator) -> None:
    """The contract's "no data" sample (NaN) and an Inf go to the object decoder, whose InputError take raises word for word."""
    topic, decoder = DECODERS[which]
    calls: list[Any] = []

    def spy(msg: Any) -> Any:
        calls.append(msg)
        return decoder(msg)

    if bad == "no_data" and not topic.type_name.endswith("WrenchStamped"):
        msg = no_data_msg(topic, ns_to_stamp(STAMP_NS))
    else:
        values = _quat(rng) if "attitude" in which else _vals(rng, 3)
        msg = _sample(topic, values)
        if topic.type_name.endswith("QuaternionStamped"):
            msg.quaternion.y = math.inf if bad == "inf" else math.nan
        elif topic.type_name.endswith("Vector3Stamped"):
            msg.vector.z = -math.inf if bad == "inf" else math.nan
        else:
            msg.wrench.torque.y = math.inf if bad == "inf" else math.nan
    raw = serialize_message(msg)
    assert wire.codec(topic).values(raw) is not None  # the layout is there: the value decides
    with pytest.raises(InputError) as expected:
        decoder(msg)
    with pytest.raises(InputError) as got:
        wire.take(raw, topic, spy)
    assert str(got.value) == str(expected.value) and topic.name in str(got.value)
    assert len(calls) == 1


def _big_endian_quaternion_stamped(stamp_ns: int, frame: str, q: list[float]) -> bytes:
    """A ``QuaternionStamped`` as CDR big endian (encapsulation 0x0000), written by hand."""
    sec, nanosec = divmod(stamp_ns, 10**9)
    body = struct.pack(">iI", sec, nanosec)
    text = frame.encode() + b"\0"
    body += struct.pack(">I", len(text)) + text
    body += bytes(-len(body) % 8)
    body += struct.pack(">4d", *q)
    return b"\x00\x00\x00\x00" + body


def test_a_big_endian_message_is_not_taken_by_the_fast_path_but_is_read_right(rng: np.random.Generator) -> None:
    """A big-endian message of the same size has no layout for the fast path (values None); take reads it through rclpy."""
    q = _quat(rng)
    raw = _big_endian_quaternion_stamped(STAMP_NS, "inertial", q)
    codec = wire.codec(c.STATE_ATTITUDE)
    assert len(raw) == codec.size  # same size, other byte order
    assert codec.values(raw) is None
    got = wire.take(raw, c.STATE_ATTITUDE, lambda m: quaternion_from_msg(m, c.STATE_ATTITUDE))
    assert [_bits(v) for v in got.tolist()] == [_bits(v) for v in q]
    assert cdr_stamp_ns(c.STATE_ATTITUDE.type_name, raw) == STAMP_NS
    with pytest.raises(InputError, match="frame_id"):  # and checked as any other message
        wire.take(_big_endian_quaternion_stamped(STAMP_NS, "body", q), c.STATE_ATTITUDE, lambda m: quaternion_from_msg(m, c.STATE_ATTITUDE))


@pytest.mark.parametrize("name", ALL_CASES)
def test_values_refuses_another_size_or_byte_order(name: str, rng: np.random.Generator) -> None:
    """Codec.values returns None for a message one byte or one double longer or shorter, or marked big endian."""
    case = _case(name, rng)
    raw = case.codec.encode(case.stamp_ns, *case.groups)
    assert case.codec.values(raw) is not None
    for other in (raw + bytes(8), raw + b"\0", raw[:-8], raw[:-1], raw[:1] + b"\x00" + raw[2:], b""):
        assert case.codec.values(other) is None


def test_values_refuses_a_changed_fixed_byte(rng: np.random.Generator) -> None:
    """Every fixed byte of a layout is compared: one flipped anywhere in them and the fast path does not take the message."""
    for name in ALL_CASES:
        case = _case(name, rng)
        raw = case.codec.encode(case.stamp_ns, *case.groups)
        for a, b in case.layout.fixed:
            for i in range(a, b):
                flipped = bytearray(raw)
                flipped[i] ^= 0x40
                assert case.codec.values(bytes(flipped)) is None, (name, i)


# ---- the encoder's checks --------------------------------------------------------------------
ENCODED_TOPICS = [c.STATE_ATTITUDE, c.STATE_RATE, c.STATE_TF, c.REFERENCE_ATTITUDE, c.REFERENCE_RATE, c.REFERENCE_ACCELERATION,
                  c.REFERENCE_TF, c.CONTROL_TORQUE, c.DISTURBANCE_TORQUE]


@pytest.mark.parametrize("topic", ENCODED_TOPICS, ids=lambda t: t.name)
def test_encode_refuses_a_non_finite_value_or_a_wrong_length_naming_the_topic(topic: c.Topic) -> None:
    """A node never publishes NaN or Inf, nor a value of another length: InputError naming the topic."""
    codec = wire.codec(topic)
    n = codec.count
    good = [0.0] * (n - 1) + [1.0]
    assert codec.encode(STAMP_NS, good)
    for bad in (math.nan, math.inf, -math.inf):
        for v in ([bad] + good[1:], np.array([bad] + good[1:]), tuple([bad] + good[1:])):
            with pytest.raises(InputError, match=topic.name):
                codec.encode(STAMP_NS, v)
    for v in (good[:-1], good + [0.0], np.zeros(n + 1), np.zeros(n - 1), [], (1.0,) * (n + 1)):
        with pytest.raises(InputError, match=topic.name):
            codec.encode(STAMP_NS, v)
    with pytest.raises(ValueError, match=topic.name):  # another number of value groups
        codec.encode(STAMP_NS, good, good)


def test_encode_refuses_a_value_of_another_shape_naming_the_topic() -> None:
    """A (1, n) array (the plant keeps its torque so) is not a field's n values: InputError naming the topic."""
    codec = wire.codec(c.CONTROL_TORQUE)
    with pytest.raises(InputError, match=c.CONTROL_TORQUE.name):
        codec.encode(STAMP_NS, np.zeros((1, 3)))


def test_encode_checks_each_field_of_a_two_field_layout() -> None:
    """The wheels' JointState: a NaN or a wrong length in either the speeds or the efforts raises, naming the topic."""
    codec = wire.Codec(wire.joint_state(c.WHEEL_STATES, 4, "speed", "effort"), c.WHEEL_STATES.name)
    ok = [1.0, 2.0, 3.0, 4.0]
    assert codec.values(codec.encode(STAMP_NS, ok, ok[::-1])) == (*ok, *ok[::-1])
    for speed, effort in ((ok, [1.0, math.nan, 0.0, 0.0]), ([math.inf, 0.0, 0.0, 0.0], ok), (ok, ok[:3]), (ok + [5.0], ok)):
        with pytest.raises(InputError, match=c.WHEEL_STATES.name):
            codec.encode(STAMP_NS, speed, effort)


def test_the_controller_diagnostics_codec_takes_nan_rows(rng: np.random.Generator) -> None:
    """controller/diagnostics may hold NaN (before the first step): encoded as they are, and rclpy reads them there."""
    codec = wire.codec(c.CONTROLLER_DIAGNOSTICS)
    rows = {label: _vals(rng, 3) for label in c.DIAGNOSTICS_LAYOUT[1:]}
    rows["rho"] = [math.nan] * 3
    rows["eps"] = [math.inf, -math.inf, math.nan]
    data = np.asarray(diagnostics_values(T_S, rows), dtype=np.float64).reshape(len(c.DIAGNOSTICS_LAYOUT), 3)
    raw = codec.encode(None, data.ravel())
    msg = deserialize_message(raw, c.CONTROLLER_DIAGNOSTICS.msg_class)
    got = np.asarray(msg.data).reshape(data.shape)
    np.testing.assert_array_equal(got, data)  # NaN where NaN
    assert msg.layout.dim[0].label == ",".join(c.DIAGNOSTICS_LAYOUT)
    assert cdr_stamp_ns(c.CONTROLLER_DIAGNOSTICS.type_name, raw) == seconds_to_ns(T_S)
    # not taken as finite values by take: the object decoder decides
    calls: list[Any] = []
    wire.take(raw, c.CONTROLLER_DIAGNOSTICS, lambda m: calls.append(m))
    assert len(calls) == 1


def test_the_controller_diagnostics_codec_refuses_a_wrong_length_naming_the_topic() -> None:
    """A wrong number of diagnostics values raises InputError naming the topic, as the encoder's docstring promises."""
    codec = wire.codec(c.CONTROLLER_DIAGNOSTICS)
    with pytest.raises(InputError, match=c.CONTROLLER_DIAGNOSTICS.name):
        codec.encode(None, np.zeros(codec.count - 1))


# ---- stamps ----------------------------------------------------------------------------------
STAMPS_NS = [0, 1, 999_999_999, 10**9, STAMP_NS, 60 * 10**9, 1_800_000_000 * 10**9 + 123_456_789, (2**31 - 1) * 10**9 + 999_999_999]


@pytest.mark.parametrize("name", ALL_CASES)
def test_cdr_stamp_ns_reads_the_encoded_stamp(name: str, rng: np.random.Generator) -> None:
    """cdr_stamp_ns of the codec's bytes is the stamp encoded (a float array's: its data[0], the time)."""
    case = _case(name, rng)
    if case.stamp_ns is None:  # a float array: the time in data[0]
        for t in (0.0, 0.01, 59.99, T_S, 1e6 - 0.01):
            groups = [[t, *case.groups[0][1:]]]
            if name == "controller_diagnostics":
                groups = [[t] * 3 + case.groups[0][3:]]
            assert cdr_stamp_ns(case.type_name, case.codec.encode(None, *groups)) == seconds_to_ns(t)
        return
    for ns in STAMPS_NS:
        raw = case.codec.encode(ns, *case.groups)
        assert cdr_stamp_ns(case.type_name, raw) == ns
        msg = deserialize_message(raw, _msg_class(case.type_name))
        assert stamp_to_ns(msg.clock if case.type_name.endswith("Clock") else msg.header.stamp) == ns


def test_a_blocks_stamps_at_once_are_each_samples_stamp(rng: np.random.Generator) -> None:
    """seconds_to_ns_array (the offline loop's and the bag writer's block of stamps) gives the integers
    seconds_to_ns gives one time at a time: a 6 h grid of 10 ms, random times to 1e6 s, and times
    whose nanoseconds end in exactly one half (rounded half to even by both)."""
    t = np.concatenate([np.arange(0, 2_160_001) * 0.01, rng.uniform(0.0, 1e6, 20_000), (np.arange(0, 2000) + 0.5) * 1e-9, [0.0]])
    got = seconds_to_ns_array(t)
    assert got.dtype == np.int64 and got.tolist() == [seconds_to_ns(float(x)) for x in t]


def test_time_to_ns_is_the_stamp_time_to_stamp_gives(rng: np.random.Generator) -> None:
    """time_to_ns(t) equals stamp_to_ns(time_to_stamp(t)), is within half a nanosecond of t, and is exact on the 10 ms grid up to 1e6 s."""
    ks = np.concatenate([np.arange(0, 20_000), rng.integers(0, 10**8 + 1, 20_000), [10**8, 10**8 - 1, 2**26, 99_999_999]])
    for k in ks.tolist():
        t = k * 0.01  # as the plant computes a sample's time
        ns = time_to_ns(t)
        assert ns == k * 10_000_000, (k, t, ns)
        assert ns == stamp_to_ns(time_to_stamp(t)) == seconds_to_ns(t)
    for t in np.concatenate([rng.uniform(0.0, 1e6, 20_000), rng.uniform(0.0, 1.0, 5_000), 10.0 ** rng.uniform(-9, 6, 5_000)]).tolist():
        ns = time_to_ns(t)
        assert ns == stamp_to_ns(time_to_stamp(t))
        assert abs(ns - Fraction(t) * 10**9) <= Fraction(6, 10), t  # rounded to the nanosecond (t * 1e9 in a double: ~0.06 ns off at 1e6 s)
    for t in (np.float64(12.34), 5, np.int64(7)):  # other numeric types: the same stamp
        assert time_to_ns(t) == stamp_to_ns(time_to_stamp(t)) == seconds_to_ns(float(t))
    stamp = ns_to_stamp(1_800_000_000 * 10**9 + 123_456_789)  # a stamp is copied exactly (a float of it would not be)
    assert time_to_ns(stamp) == 1_800_000_000 * 10**9 + 123_456_789
    for bad in (-0.01, math.nan, math.inf):
        with pytest.raises(InputError):
            time_to_ns(bad)


def test_deserialize_gives_the_topics_message_class(rng: np.random.Generator) -> None:
    """wire.deserialize reads bytes as the topic's message type."""
    q = _quat(rng)
    msg = wire.deserialize(wire.codec(c.STATE_ATTITUDE).encode(STAMP_NS, q), c.STATE_ATTITUDE)
    assert isinstance(msg, c.STATE_ATTITUDE.msg_class)
    assert [msg.quaternion.x, msg.quaternion.y, msg.quaternion.z, msg.quaternion.w] == q


# ---- the flight's sensors and the estimator's outputs -------------------------------------------
def test_the_sensors_imu_and_epoch_bytes_are_the_object_encoders_messages() -> None:
    """sensors/gyro, sensors/star_tracker (sensor_msgs/Imu) and state/attitude_epoch (TimeReference)
    as the plant publishes them: rclpy reads back the message convert.py builds for the same values."""
    variance = [1e-8, 2e-8, 3e-8]
    w, q = [0.1, -0.2, 0.3], [0.1, 0.2, 0.3, math.sqrt(1 - 0.14)]
    cases = [(c.SENSOR_GYRO, wire.gyro_values(w, variance), gyro_msg(w, variance, STAMP_NS / 1e9, c.SENSOR_GYRO)),
             (c.SENSOR_STAR_TRACKER, wire.star_tracker_values(q, variance), star_tracker_msg(q, variance, STAMP_NS / 1e9, c.SENSOR_STAR_TRACKER)),
             (c.STATE_ATTITUDE_EPOCH, 987_654_321, epoch_msg(987_654_321, STAMP_NS / 1e9, c.STATE_ATTITUDE_EPOCH))]
    for topic, values, expected in cases:
        raw = wire.codec(topic).encode(STAMP_NS, values)
        assert serialize_message(deserialize_message(raw, topic.msg_class)) == serialize_message(expected), topic.name
        assert wire.codec(topic).values(serialize_message(expected)) is not None, topic.name  # rclpy's bytes have the layout


def test_the_pickers_take_what_the_imu_decoders_take_and_leave_the_rest_to_them() -> None:
    """take with PICK_GYRO / PICK_ORIENTATION gives gyro_from_msg's / star_tracker_from_msg's value;
    a part marked absent or non-finite goes to the object decoder, which names the error."""
    variance = [1e-8] * 3
    gyro = wire.codec(c.SENSOR_GYRO).encode(STAMP_NS, wire.gyro_values([0.1, 0.2, 0.3], variance))
    np.testing.assert_array_equal(wire.take(gyro, c.SENSOR_GYRO, lambda m: gyro_from_msg(m, c.SENSOR_GYRO), pick=wire.PICK_GYRO), [0.1, 0.2, 0.3])
    tracker = wire.codec(c.SENSOR_STAR_TRACKER).encode(STAMP_NS, wire.star_tracker_values([0.0, 0.0, 0.0, 1.0], variance))
    with pytest.raises(InputError, match="no angular velocity"):  # a tracker's message on the gyro's topic: the decoder's words
        wire.take(tracker, c.SENSOR_GYRO, lambda m: gyro_from_msg(m, c.SENSOR_GYRO), pick=wire.PICK_GYRO)
    with pytest.raises(InputError, match="no orientation"):
        wire.take(gyro, c.SENSOR_STAR_TRACKER, lambda m: star_tracker_from_msg(m, c.SENSOR_STAR_TRACKER), pick=wire.PICK_ORIENTATION)
    nan_gyro = serialize_message(no_data_msg(c.SENSOR_GYRO, 1.0))
    with pytest.raises(InputError, match="non-finite"):
        wire.take(nan_gyro, c.SENSOR_GYRO, lambda m: gyro_from_msg(m, c.SENSOR_GYRO), pick=wire.PICK_GYRO)


@pytest.mark.parametrize("topic", [c.ESTIMATE_ATTITUDE, c.ESTIMATE_RATE, c.ESTIMATOR_GYRO_BIAS, c.STATE_ATTITUDE, c.REFERENCE_RATE])
def test_the_no_data_bytes_are_the_contracts_no_data_sample(topic: c.Topic) -> None:
    """Codec.no_data is no_data_msg's message (NaN in every value), recognised as "no data"."""
    raw = wire.codec(topic).no_data(STAMP_NS)
    expected = no_data_msg(topic, STAMP_NS / 1e9)
    assert serialize_message(deserialize_message(raw, topic.msg_class)) == serialize_message(expected)
    assert is_no_data_msg(deserialize_message(raw, topic.msg_class), topic)


@pytest.mark.parametrize("name", ALL_CASES)
def test_the_one_pack_encoder_writes_the_general_paths_bytes(name: str, rng: np.random.Generator) -> None:
    """Codec.encode's fast path (one struct over the message, for a float64 vector or a list) gives
    the bytes of its general path (a tuple of floats: the template copied, each field packed)."""
    case = _case(name, rng)
    fast = case.codec.encode(case.stamp_ns, *[np.asarray(g, dtype=np.float64) if not isinstance(g, int) else g for g in case.groups])
    general = case.codec.encode(case.stamp_ns, *[tuple(float(x) for x in g) if not isinstance(g, int) else g for g in case.groups])
    assert fast == general
    if case.codec.finite and len(case.groups) == 1 and not isinstance(case.groups[0], int):
        bad = np.asarray(case.groups[0], dtype=np.float64).copy()
        bad[-1] = math.nan
        with pytest.raises(InputError, match=case.codec.name):  # the fast path's check hands a NaN to the general path's
            case.codec.encode(case.stamp_ns, bad)


@pytest.mark.parametrize("topic", [*ENCODED_TOPICS, c.CONTROLLER_DIAGNOSTICS], ids=lambda t: t.name)
def test_encode_block_writes_encodes_bytes_message_by_message(topic: c.Topic, rng: np.random.Generator) -> None:
    """Codec.encode_block (the reference's and the injector's blocks) gives, message by message, the
    bytes Codec.encode gives for the same stamp and values: stamps over whole seconds, at zero and
    near int32 seconds' end included (its stamp is its own numpy arithmetic, not encode's divmod)."""
    codec = wire.codec(topic)
    stamps = [0, 1, 999_999_999, 1_000_000_000, 10_000_000, 59_990_000_000, STAMP_NS, (2**31 - 1) * 1_000_000_000 + 999_999_999]
    values = rng.normal(size=(len(stamps), codec.count))
    block = codec.encode_block(stamps, values)
    assert block == [codec.encode(None if topic is c.CONTROLLER_DIAGNOSTICS else s, v) for s, v in zip(stamps, values)]
    assert codec.encode_block([], np.zeros((0, codec.count))) == []


@pytest.mark.parametrize("topic", ENCODED_TOPICS, ids=lambda t: t.name)
def test_encode_block_refuses_what_encode_refuses_in_encodes_words(topic: c.Topic) -> None:
    """A block with a non-finite value or a stamp beyond int32 seconds is encode's, message by
    message: its error names the topic; values of another shape are refused naming it too."""
    codec = wire.codec(topic)
    good = np.zeros((3, codec.count))
    bad = good.copy()
    bad[1, -1] = math.nan
    with pytest.raises(InputError, match=topic.name):
        codec.encode_block([0, 1, 2], bad)
    with pytest.raises(struct.error):  # int32 seconds: what encode's pack raises
        codec.encode_block([0, 1, 2**31 * 1_000_000_000], good)
    with pytest.raises(ValueError, match=topic.name):
        codec.encode_block([0, 1], good)
    with pytest.raises(ValueError, match="one run of doubles"):
        wire.Codec(wire.joint_state(c.WHEEL_STATES, 3, "speed", "effort"), c.WHEEL_STATES.name).encode_block([0], np.zeros((1, 6)))

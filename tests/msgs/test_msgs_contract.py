"""The topic contract (sappc_msgs_py): conversions round-trip, quaternion order, exact stamps,
input checks, and schema texts / type hashes verified by two independent decoders (mcap_ros2,
rosbags) against bytes serialised by rclpy."""

from __future__ import annotations

import numpy as np
import pytest
from mcap_ros2._dynamic import generate_dynamic
from rclpy.serialization import serialize_message
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from sappc_msgs_py import contract as c
from sappc_msgs_py.convert import (
    dipole_from_msg,
    dipole_msg,
    magnetic_field_from_msg,
    magnetic_field_msg,
    wheel_speed_from_msg,
    wheel_speed_msg,
    cdr_stamp_ns,
    clock_msg,
    covariance_from_msg,
    covariance_msg,
    epoch_from_msg,
    epoch_msg,
    gyro_msg,
    star_tracker_msg,
    estimator_diagnostics_from_msg,
    estimator_diagnostics_msg,
    no_data_msg,
    diagnostics_from_msg,
    diagnostics_msg,
    health_msg,
    joint_state_msg,
    quaternion_from_msg,
    quaternion_msg,
    stamp_to_ns,
    stamp_to_time,
    time_to_stamp,
    torque_from_msg,
    torque_msg,
    transform_from_attitude,
    transform_msg,
    vector3_from_msg,
    vector3_msg,
)
from sappc_msgs_py.schemas import dependencies, schema_text, type_hash
from gnc_common.validation import InputError


def test_quaternion_keeps_the_scalar_last_order() -> None:
    q = np.array([0.3254, 0.4068, -0.3254, 0.7891])
    msg = quaternion_msg(q, 1.5, c.STATE_ATTITUDE)
    assert (msg.quaternion.x, msg.quaternion.y, msg.quaternion.z, msg.quaternion.w) == tuple(q)
    assert msg.header.frame_id == "inertial"
    np.testing.assert_array_equal(quaternion_from_msg(msg, c.STATE_ATTITUDE), q)


def test_vectors_and_torques_round_trip_with_their_frames() -> None:
    w = np.array([0.01, -0.02, 0.03])
    for topic in (c.STATE_RATE, c.REFERENCE_RATE, c.REFERENCE_ACCELERATION):
        msg = vector3_msg(w, 2.0, topic)
        assert msg.header.frame_id == topic.frame_id
        np.testing.assert_array_equal(vector3_from_msg(msg, topic), w)
    for topic in (c.CONTROL_TORQUE, c.DISTURBANCE_TORQUE):
        msg = torque_msg([0.5, -0.25, 0.005], 2.0, topic)
        assert msg.header.frame_id == "body" and (msg.wrench.force.x, msg.wrench.force.y, msg.wrench.force.z) == (0.0, 0.0, 0.0)
        np.testing.assert_array_equal(torque_from_msg(msg, topic), [0.5, -0.25, 0.005])


def test_stamps_are_exact_on_the_control_grid() -> None:
    for k in (0, 1, 7, 4999, 6000, 10**6 + 3):
        stamp = time_to_stamp(k * 0.01)
        assert stamp_to_ns(stamp) == k * 10_000_000
        assert abs(stamp_to_time(stamp) - k * 0.01) <= 1e-9
    assert stamp_to_ns(clock_msg(50.5).clock) == 50_500_000_000
    with pytest.raises(InputError, match="t_s must be >= 0"):
        time_to_stamp(-0.01)


def test_bad_messages_are_rejected_naming_the_topic() -> None:
    msg = vector3_msg([0.0, 0.0, 0.0], 0.0, c.STATE_RATE)
    msg.header.frame_id = "imu_link"
    with pytest.raises(InputError, match="state/rate: frame_id must be 'body', got 'imu_link'"):
        vector3_from_msg(msg, c.STATE_RATE)
    msg = quaternion_msg([0.0, 0.0, 0.0, 1.0], 0.0, c.STATE_ATTITUDE)
    msg.quaternion.w = float("nan")
    with pytest.raises(InputError, match="state/attitude quaternion contains a non-finite value nan"):
        quaternion_from_msg(msg, c.STATE_ATTITUDE)
    with pytest.raises(InputError, match="control/torque torque contains a non-finite value inf"):
        torque_msg([0.0, float("inf"), 0.0], 0.0)


def test_diagnostics_are_labelled() -> None:
    rows = {label: np.arange(3.0) + i for i, label in enumerate(c.DIAGNOSTICS_LAYOUT[1:])}
    back = diagnostics_from_msg(diagnostics_msg(12.5, rows))
    assert list(back) == list(c.DIAGNOSTICS_LAYOUT)
    np.testing.assert_array_equal(back["time_s"], [12.5] * 3)
    for label, values in rows.items():
        np.testing.assert_array_equal(back[label], values)
    with pytest.raises(ValueError, match="missing"):
        diagnostics_msg(0.0, {"rho": [0, 0, 0]})


def _sample(topic: c.Topic):  # type: ignore[no-untyped-def]
    if topic is c.ESTIMATOR_COVARIANCE:
        return covariance_msg(12.34, np.arange(36.0).reshape(6, 6) * 1e-9)
    if topic is c.ESTIMATOR_DIAGNOSTICS:
        return estimator_diagnostics_msg([12.34, 2.5, 3.0, 120.0, 1.0, 0.0, 0.0, 2.0, 1.0, 75.5, 1.0, 3.0])
    if topic is c.ESTIMATOR_HEALTH:
        return health_msg(12.34, 1, "warning", {key: str(i) for i, key in enumerate(c.ESTIMATOR_HEALTH_KEYS)})
    if topic is c.STATE_ATTITUDE_EPOCH:
        return epoch_msg(12_300_000_000, 12.34, topic)
    if topic is c.SENSOR_GYRO:
        return gyro_msg([1e-3, -2e-3, 3e-3], [1e-8, 2e-8, 3e-8], 12.34, topic)
    if topic is c.SENSOR_STAR_TRACKER:
        return star_tracker_msg([0.1, -0.2, 0.3, np.sqrt(0.86)], [4e-10, 4e-10, 9e-9], 12.3, topic)
    if topic in (c.STATE_MAGNETIC_FIELD, c.TRUTH_MAGNETIC_FIELD):
        return magnetic_field_msg([2.1e-5, -3.4e-6, 4.0e-5], 12.34, topic, [2.5e-15, 2.5e-15, 2.5e-15])
    if topic is c.CONTROL_DIPOLE:
        return dipole_msg(12.34, [100.0, -2500.0, 0.5])
    if topic.type_name.endswith("QuaternionStamped"):
        return quaternion_msg([0.1, -0.2, 0.3, np.sqrt(0.86)], 12.34, topic)
    if topic.type_name.endswith("Vector3Stamped"):
        return vector3_msg([1e-3, -2e-3, 3e-3], 12.34, topic)
    if topic.type_name.endswith("WrenchStamped"):
        return torque_msg([0.1, -0.2, 0.3], 12.34, topic)
    if topic.type_name.endswith("Clock"):
        return clock_msg(12.34)
    if topic.type_name.endswith("TransformStamped"):
        return transform_from_attitude(transform_msg(topic), quaternion_msg([0.1, -0.2, 0.3, np.sqrt(0.86)], 12.34, c.STATE_ATTITUDE))
    if topic.type_name.endswith("JointState"):  # joint_states, and state/wheel_speed's type (its velocity-only
        # message: the same decoders, tests/tools/graph/test_orbit_graph.py reads it from a recorded bag)
        # three wheels: rclpy's serialize_message leaves 8 bytes after a four-wheel message (which
        # rosbags rejects) where DDS sends the exact 156 bytes; the four-wheel pyramid recorded
        # through the graph decodes with rosbags (tests/tools/graph/test_wheels_graph.py)
        return joint_state_msg([100.0, -50.5, 3.25], [0.1, -0.2, 0.05], 12.34)
    return diagnostics_msg(12.34, {label: [1.0, 2.0, 3.0] for label in c.DIAGNOSTICS_LAYOUT[1:]})


@pytest.mark.parametrize("topic", c.TOPICS, ids=lambda t: t.name)
def test_schema_text_decodes_rclpy_bytes_with_two_independent_decoders(topic) -> None:
    msg = _sample(topic)
    raw = serialize_message(msg)
    pkg, _, name = topic.type_name.split("/")
    text = schema_text(topic.type_name)
    # mcap_ros2 (what an MCAP viewer uses) from the schema text alone
    decoded = generate_dynamic(f"{pkg}/{name}", text)[f"{pkg}/{name}"](raw)
    # rosbags' own CDR implementation from the same text
    store = get_typestore(Stores.EMPTY)
    store.register(get_types_from_msg(text, f"{pkg}/msg/{name}"))
    other = store.deserialize_cdr(raw, f"{pkg}/msg/{name}")
    if hasattr(msg, "header"):
        assert decoded.header.frame_id == other.header.frame_id == msg.header.frame_id
        assert decoded.header.stamp.nanosec == other.header.stamp.nanosec == msg.header.stamp.nanosec
    if hasattr(msg, "quaternion"):
        assert (decoded.quaternion.w, other.quaternion.w) == (msg.quaternion.w, msg.quaternion.w)
    if hasattr(msg, "vector"):
        assert decoded.vector.z == other.vector.z == msg.vector.z
    if hasattr(msg, "magnetic_field"):
        assert decoded.magnetic_field.y == other.magnetic_field.y == msg.magnetic_field.y == -3.4e-6
        assert list(decoded.magnetic_field_covariance) == list(other.magnetic_field_covariance) == list(msg.magnetic_field_covariance)
    if hasattr(msg, "wrench"):
        assert decoded.wrench.torque.y == other.wrench.torque.y == msg.wrench.torque.y
    if hasattr(msg, "velocity"):
        assert list(decoded.name) == list(other.name) == ["wheel_1", "wheel_2", "wheel_3"]
        assert list(decoded.velocity) == list(other.velocity) == [100.0, -50.5, 3.25]
        assert list(decoded.effort) == list(other.effort) == [0.1, -0.2, 0.05] and len(other.position) == 0
    if hasattr(msg, "transform"):
        assert decoded.child_frame_id == other.child_frame_id == msg.child_frame_id == topic.child_frame_id
        assert decoded.transform.rotation.z == other.transform.rotation.z == msg.transform.rotation.z == 0.3
        assert other.transform.translation.x == other.transform.translation.y == other.transform.translation.z == 0.0
    if hasattr(msg, "data"):
        assert list(decoded.data) == list(other.data) == list(msg.data)
    if hasattr(msg, "time_ref"):
        assert decoded.time_ref.sec == other.time_ref.sec == 12 and decoded.source == other.source == "star_tracker"
    if hasattr(msg, "status"):
        assert decoded.status[0].name == other.status[0].name == c.ESTIMATOR_HEALTH_NAME
        assert [kv.key for kv in decoded.status[0].values] == [kv.key for kv in other.status[0].values] == list(c.ESTIMATOR_HEALTH_KEYS)
    # and the hash of the type as rosbags computes it from the definition equals the installed one
    assert store.hash_rihs01(f"{pkg}/msg/{name}") == type_hash(topic.type_name)


def test_schema_dependencies_are_sorted_and_recursive() -> None:
    assert dependencies("geometry_msgs/msg/WrenchStamped") == [
        "builtin_interfaces/Time", "geometry_msgs/Vector3", "geometry_msgs/Wrench", "std_msgs/Header"]
    text = schema_text("geometry_msgs/msg/WrenchStamped")
    assert text.count("=" * 80 + "\nMSG: ") == 4
    assert type_hash("geometry_msgs/msg/WrenchStamped").startswith("RIHS01_") and len(type_hash("geometry_msgs/msg/WrenchStamped")) == 71
    with pytest.raises(FileNotFoundError, match="nav_msgs"):
        schema_text("nav_msgs/msg/Odometry")


def test_every_topic_has_a_message_class_and_the_shared_qos() -> None:
    from rclpy.qos import DurabilityPolicy, ReliabilityPolicy

    for topic in c.TOPICS:
        assert topic.msg_class.__name__ == topic.type_name.split("/")[-1]
    qos = c.qos_profile()
    assert qos.reliability == ReliabilityPolicy.RELIABLE and qos.durability == DurabilityPolicy.VOLATILE and qos.depth == c.QOS_DEPTH == 10_000


def test_fault_relay_topics_keep_type_and_frame_and_stamps_copy_exactly() -> None:
    relay = c.faulty(c.STATE_ATTITUDE)
    assert relay.name == "fault/state/attitude" and relay.type_name == c.STATE_ATTITUDE.type_name and relay.frame_id == "inertial"
    wall = time_to_stamp(1_795_350_022.171357654)  # a float of seconds loses ~0.2 us at this size...
    exact = time_to_stamp(type("S", (), {"sec": 1_795_350_022, "nanosec": 171_357_654})())  # ...a stamp does not
    assert (exact.sec, exact.nanosec) == (1_795_350_022, 171_357_654)
    assert abs(stamp_to_ns(wall) - stamp_to_ns(exact)) < 1_000
    msg = torque_msg([0.1, 0.2, 0.3], exact, c.faulty(c.CONTROL_TORQUE))
    assert stamp_to_ns(msg.header.stamp) == 1_795_350_022_171_357_654 and msg.header.frame_id == "body"


@pytest.mark.parametrize("t_s", [0.0, 0.01, 12.34, 59.99, 2.0**31 - 1.5])
def test_cdr_stamp_ns_reads_the_stamp_of_every_recorded_type_without_deserializing(t_s: float) -> None:
    """What the lockstep recorder logs a message at: the header stamp of the stamped types (the
    transforms included),
    /clock's clock, the diagnostics' time_s, equal to what the deserialized message says;
    little- and big-endian CDR (the encapsulation header says which)."""
    from rclpy.serialization import deserialize_message

    ns = stamp_to_ns(time_to_stamp(t_s))
    rows = {label: [0.5, -1.0, 2.0] for label in c.DIAGNOSTICS_LAYOUT[1:]}
    messages = {
        c.STATE_ATTITUDE: quaternion_msg([0.0, 0.0, 0.0, 1.0], t_s, c.STATE_ATTITUDE),
        c.STATE_RATE: vector3_msg([1.0, 2.0, 3.0], t_s, c.STATE_RATE),
        c.CONTROL_TORQUE: torque_msg([0.1, 0.2, 0.3], t_s, c.CONTROL_TORQUE),
        c.CLOCK: clock_msg(t_s),
        c.CONTROLLER_DIAGNOSTICS: diagnostics_msg(ns / 1e9, rows),
        c.ESTIMATOR_DIAGNOSTICS: estimator_diagnostics_msg([ns / 1e9, np.nan, 3.0, 7.0, 1.0, 0.0, 2.0, 4.0, 0.0, np.nan, 0.0, 0.0]),
        c.ESTIMATOR_HEALTH: health_msg(t_s, 0, "ok", {"time_s": "0"}),
        c.STATE_ATTITUDE_EPOCH: epoch_msg(0, t_s, c.STATE_ATTITUDE_EPOCH),
        c.SENSOR_GYRO: gyro_msg([1.0, 2.0, 3.0], [1e-8, 1e-8, 1e-8], t_s, c.SENSOR_GYRO),
        c.SENSOR_STAR_TRACKER: star_tracker_msg([0.0, 0.0, 0.0, 1.0], [1e-9, 1e-9, 1e-8], t_s, c.SENSOR_STAR_TRACKER),
        c.ESTIMATOR_COVARIANCE: covariance_msg(ns / 1e9, np.diag(np.arange(1.0, 7.0))),
        c.ESTIMATE_ATTITUDE: no_data_msg(c.ESTIMATE_ATTITUDE, t_s),
        c.STATE_MAGNETIC_FIELD: magnetic_field_msg([2e-5, 0.0, -3e-5], t_s),
        c.CONTROL_DIPOLE: dipole_msg(ns / 1e9, [1.0, 2.0, 3.0]),
        c.STATE_TF: transform_from_attitude(transform_msg(c.STATE_TF), quaternion_msg([0.0, 0.0, 0.0, 1.0], t_s, c.STATE_ATTITUDE)),
        c.REFERENCE_TF: transform_from_attitude(transform_msg(c.REFERENCE_TF), quaternion_msg([0.0, 0.0, 0.0, 1.0], t_s, c.REFERENCE_ATTITUDE)),
    }
    store = get_typestore(Stores.ROS2_JAZZY)
    for topic, msg in messages.items():
        cdr = serialize_message(msg)
        assert cdr[:2] == b"\x00\x01"  # rclpy writes little-endian CDR
        assert cdr_stamp_ns(topic.type_name, cdr) == ns, topic.name
        back = deserialize_message(cdr, topic.msg_class)
        if topic is c.CONTROLLER_DIAGNOSTICS:
            assert stamp_to_ns(time_to_stamp(float(diagnostics_from_msg(back)["time_s"][0]))) == ns
        elif topic.msg_class.__name__ == "Float64MultiArray":  # the estimator's: time_s in data[0]
            assert stamp_to_ns(time_to_stamp(float(back.data[0]))) == ns
        else:
            assert stamp_to_ns(back.clock if topic is c.CLOCK else back.header.stamp) == ns
        big = store.serialize_cdr(store.deserialize_cdr(cdr, topic.type_name), topic.type_name, little_endian=False)
        assert big[:2] == b"\x00\x00" and cdr_stamp_ns(topic.type_name, big) == ns, topic.name


def test_cdr_stamp_ns_refuses_a_type_it_cannot_time_and_a_foreign_float_array() -> None:
    from std_msgs.msg import Float64MultiArray, MultiArrayDimension

    with pytest.raises(ValueError, match="no stamp known for type 'std_msgs/msg/String'"):
        cdr_stamp_ns("std_msgs/msg/String", b"\x00\x01\x00\x00abcd")
    with pytest.raises(ValueError, match="not one of the contract's float arrays"):
        cdr_stamp_ns("std_msgs/msg/Float64MultiArray", serialize_message(Float64MultiArray(data=[1.0, 2.0])))
    labelled = Float64MultiArray(data=[1.0, 2.0])
    labelled.layout.dim = [MultiArrayDimension(label="speed,torque", size=2, stride=2)]  # labelled, but not time first
    with pytest.raises(ValueError, match="not one of the contract's float arrays"):
        cdr_stamp_ns("std_msgs/msg/Float64MultiArray", serialize_message(labelled))
    with pytest.raises(ValueError, match="not one of the contract's float arrays"):  # cut short
        cdr_stamp_ns("std_msgs/msg/Float64MultiArray", serialize_message(covariance_msg(1.0, np.eye(6)))[:40])


def test_transform_topics_name_the_contract_frames_and_carry_the_attitude_as_it_is() -> None:
    """``state/tf`` is frame ``body`` in ``inertial``, ``reference/tf`` frame ``reference`` in
    ``inertial``; translation zero; stamp and quaternion those of the attitude message."""
    assert c.TRANSFORM_TOPICS == (c.STATE_TF, c.REFERENCE_TF) and all(t in c.TOPICS for t in c.TRANSFORM_TOPICS)
    assert (c.STATE_TF.frame_id, c.STATE_TF.child_frame_id) == ("inertial", "body")
    assert (c.REFERENCE_TF.frame_id, c.REFERENCE_TF.child_frame_id) == ("inertial", "reference")
    assert c.STATE_TF.frame_id == c.STATE_ATTITUDE.frame_id and c.REFERENCE_TF.frame_id == c.REFERENCE_ATTITUDE.frame_id
    assert c.STATE_TF.child_frame_id == c.STATE_RATE.frame_id and c.REFERENCE_TF.child_frame_id == c.REFERENCE_RATE.frame_id
    assert {c.Frame(t.child_frame_id) for t in c.TRANSFORM_TOPICS} == {c.Frame.BODY, c.Frame.REFERENCE}
    q = np.array([0.3254, 0.4068, -0.3254, 0.7891]) / np.linalg.norm([0.3254, 0.4068, -0.3254, 0.7891])
    tf = transform_msg(c.STATE_TF)
    for k, t_s in enumerate((0.0, 0.01, 59.99)):  # one message, re-stamped sample after sample
        att = quaternion_msg(q * (-1) ** k, t_s, c.STATE_ATTITUDE)
        out = transform_from_attitude(tf, att)
        assert out is tf and stamp_to_ns(out.header.stamp) == stamp_to_ns(att.header.stamp)
        assert out.header.frame_id == "inertial" and out.child_frame_id == "body"
        r, p = out.transform.rotation, out.transform.translation
        assert (r.x, r.y, r.z, r.w) == tuple(q * (-1) ** k) and (p.x, p.y, p.z) == (0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="state/attitude does not carry a transform"):
        transform_msg(c.STATE_ATTITUDE)


def test_the_body_transform_maps_body_axes_to_inertial_axes() -> None:
    """The direction of the rotation, on a concrete vector.  A body turned +90 deg about the
    inertial z axis has its x axis along inertial +y.  ``state/tf``'s rotation, applied as tf
    applies a transform's rotation (child coordinates to parent coordinates; scipy's ``apply`` is
    the same active rotation ``q v q*``), must take the body x axis (1, 0, 0)_B to (0, 1, 0)_N;
    the conjugate would give (0, -1, 0)_N.  Checked against the project's own direction cosine
    matrix too (``C_BN`` maps inertial components to body ones, so ``C_BN^T`` body to inertial)."""
    from scipy.spatial.transform import Rotation

    from gnc_common.attitude import quat_to_dcm_BN

    half = np.pi / 4
    q_BN = np.array([0.0, 0.0, np.sin(half), np.cos(half)])  # +90 deg about z, scalar last
    tf = transform_from_attitude(transform_msg(c.STATE_TF), quaternion_msg(q_BN, 1.0, c.STATE_ATTITUDE))
    r = tf.transform.rotation
    rotation = Rotation.from_quat([r.x, r.y, r.z, r.w])  # scipy: scalar last, like geometry_msgs
    np.testing.assert_allclose(rotation.apply([1.0, 0.0, 0.0]), [0.0, 1.0, 0.0], atol=1e-15)  # body x -> inertial +y
    np.testing.assert_allclose(rotation.apply([0.0, 1.0, 0.0]), [-1.0, 0.0, 0.0], atol=1e-15)  # body y -> inertial -x
    np.testing.assert_allclose(rotation.apply([0.0, 0.0, 1.0]), [0.0, 0.0, 1.0], atol=1e-15)
    np.testing.assert_allclose(quat_to_dcm_BN(q_BN[None])[0].T @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-15)
    # a general attitude: the transform rotates body vectors into inertial ones as C_BN^T does
    q = np.array([0.3254, 0.4068, -0.3254, 0.7891]) / np.linalg.norm([0.3254, 0.4068, -0.3254, 0.7891])
    tf = transform_from_attitude(transform_msg(c.STATE_TF), quaternion_msg(q, 1.0, c.STATE_ATTITUDE))
    r = tf.transform.rotation
    v_B = np.array([0.2, -0.7, 0.4])
    np.testing.assert_allclose(Rotation.from_quat([r.x, r.y, r.z, r.w]).apply(v_B), quat_to_dcm_BN(q[None])[0].T @ v_B, atol=1e-15)


# ---- the estimator's topics (issue 26) -----------------------------------------------------------


def test_the_estimate_has_the_types_and_frames_of_the_state_it_replaces() -> None:
    """``estimate/*`` are what the controller takes by a remap of ``state/*``: same types, same
    frames; the estimator's other topics are body-frame vectors and labelled float arrays; all
    are optional contract topics (recorded by default, absent from a run without an estimator)."""
    assert (c.ESTIMATE_ATTITUDE.type_name, c.ESTIMATE_ATTITUDE.frame_id) == (c.STATE_ATTITUDE.type_name, "inertial")
    assert (c.ESTIMATE_RATE.type_name, c.ESTIMATE_RATE.frame_id) == (c.STATE_RATE.type_name, "body")
    for topic in (c.ESTIMATOR_GYRO_BIAS, c.ESTIMATOR_ATTITUDE_SIGMA, c.ESTIMATOR_BIAS_SIGMA):
        assert topic.type_name == "geometry_msgs/msg/Vector3Stamped" and topic.frame_id == "body"
    # the sensors on their own topics, each sample stamped when measured; the epoch names the tracker's
    assert c.ESTIMATOR_INPUTS == (c.SENSOR_GYRO, c.STATE_ATTITUDE_EPOCH)
    assert c.ESTIMATOR_SUBSCRIPTIONS == (c.SENSOR_GYRO, c.STATE_ATTITUDE_EPOCH, c.SENSOR_STAR_TRACKER)
    assert all(t.type_name == "sensor_msgs/msg/Imu" and t.frame_id == "body" for t in (c.SENSOR_GYRO, c.SENSOR_STAR_TRACKER))
    assert all(t in c.TOPICS and t in c.OPTIONAL_TOPICS and t in c.RELAYED_TOPICS for t in c.ESTIMATOR_SUBSCRIPTIONS)
    assert all(t in c.TOPICS and t in c.OPTIONAL_TOPICS for t in c.ESTIMATOR_TOPICS) and len(c.ESTIMATOR_TOPICS) == 8
    assert len({t.name for t in c.TOPICS}) == len(c.TOPICS)
    for topic in c.ESTIMATOR_TOPICS:
        assert f"``{topic.name}``" in (c.__doc__ or ""), topic.name  # in the contract's table


def test_the_estimator_status_codes_are_the_kernels_then_no_input_then_inactive() -> None:
    from sappc_estimator.core import mekf

    assert c.ESTIMATOR_STATUS_NAMES[: len(mekf.STATUS_NAMES)] == mekf.STATUS_NAMES
    assert c.ESTIMATOR_NO_INPUT == len(mekf.STATUS_NAMES) and c.ESTIMATOR_STATUS_NAMES[c.ESTIMATOR_NO_INPUT] == "no_input"
    assert c.ESTIMATOR_INACTIVE == c.ESTIMATOR_NO_INPUT + 1 and c.ESTIMATOR_STATUS_NAMES[c.ESTIMATOR_INACTIVE] == "inactive"
    assert len(c.ESTIMATOR_STATUS_NAMES) == c.ESTIMATOR_INACTIVE + 1


def test_the_covariance_round_trips_row_major_with_labelled_dimensions() -> None:
    rng = np.random.default_rng(5)
    A = rng.standard_normal((6, 6))
    P = A @ A.T * 1e-8
    msg = covariance_msg(12.5, P)
    assert [d.label for d in msg.layout.dim] == ["row:a_x,a_y,a_z,b_x,b_y,b_z", "column:a_x,a_y,a_z,b_x,b_y,b_z"]
    assert [(d.size, d.stride) for d in msg.layout.dim] == [(6, 36), (6, 6)] and msg.layout.data_offset == 1
    assert msg.data[0] == 12.5 and msg.data[1 + 6 * 2 + 4] == P[2, 4]  # P[i, j] = data[1 + 6 i + j]
    t, back = covariance_from_msg(msg)
    assert t == 12.5 and np.array_equal(back, P)
    t, none = covariance_from_msg(covariance_msg(3.0, None))  # "no data"
    assert t == 3.0 and none.shape == (6, 6) and np.all(np.isnan(none))
    with pytest.raises(InputError, match="estimator/covariance P contains a non-finite value"):
        covariance_msg(1.0, np.full((6, 6), np.nan))
    with pytest.raises(InputError, match="trailing shape"):
        covariance_msg(1.0, np.eye(3))
    with pytest.raises(InputError, match="not an estimator covariance message"):
        covariance_from_msg(diagnostics_msg(0.0, {label: [0.0] * 3 for label in c.DIAGNOSTICS_LAYOUT[1:]}))


def test_the_estimator_diagnostics_round_trip_labelled() -> None:
    values = [4.25, 1.5, float(c.ESTIMATOR_NO_INPUT), 40.0, 2.0, 1.0, 3.0, 5.0, 2.0, 130.5, 1.0, 12.0]
    back = estimator_diagnostics_from_msg(estimator_diagnostics_msg(values))
    assert list(back) == list(c.ESTIMATOR_DIAGNOSTICS_LAYOUT) and list(back.values()) == values
    with pytest.raises(ValueError, match="estimator diagnostics need 12 values"):
        estimator_diagnostics_msg(values[:-1])


def test_the_epoch_round_trips_exactly_and_its_no_data_sample_is_refused() -> None:
    """``state/attitude_epoch``: the tracker's own time of a sample as integer nanoseconds (an epoch
    stamp of 2026 too: no float in between); the "no data" sample names no sensor and is refused as
    invalid, as a NaN quaternion is."""
    epoch = 1_795_000_000_123_456_789
    msg = epoch_msg(epoch, 2.5, c.STATE_ATTITUDE_EPOCH)
    assert epoch_from_msg(msg, c.STATE_ATTITUDE_EPOCH) == epoch and stamp_to_ns(msg.header.stamp) == 2_500_000_000
    with pytest.raises(InputError, match="no epoch"):
        epoch_from_msg(no_data_msg(c.STATE_ATTITUDE_EPOCH, 2.5), c.STATE_ATTITUDE_EPOCH)


@pytest.mark.parametrize("topic", [c.ESTIMATE_ATTITUDE, c.ESTIMATE_RATE, c.ESTIMATOR_GYRO_BIAS, c.faulty(c.STATE_ATTITUDE)], ids=lambda t: t.name)
def test_the_no_data_sample_is_nan_in_every_value_with_its_stamp_and_frame(topic) -> None:  # type: ignore[no-untyped-def]
    msg = no_data_msg(topic, 2.5)
    assert stamp_to_ns(msg.header.stamp) == 2_500_000_000 and msg.header.frame_id == topic.frame_id
    values = [msg.quaternion.x, msg.quaternion.y, msg.quaternion.z, msg.quaternion.w] if hasattr(msg, "quaternion") else [msg.vector.x, msg.vector.y, msg.vector.z]
    assert all(np.isnan(values))
    with pytest.raises(InputError, match="non-finite"):  # what a consumer makes of it: invalid, counted as arrived
        (quaternion_from_msg if hasattr(msg, "quaternion") else vector3_from_msg)(msg, topic)
    again = no_data_msg(topic, 3.0, out=msg)
    assert again is msg and stamp_to_ns(msg.header.stamp) == 3_000_000_000
    with pytest.raises(ValueError, match="control/torque has no 'no data' sample"):
        no_data_msg(c.CONTROL_TORQUE, 0.0)


def test_no_data_is_told_from_an_invalid_message_and_screened_apart_from_the_rejections() -> None:
    """The contract's "no data" sample of every kind (:func:`no_data_msg`: NaN in every value, a
    TimeReference naming no sensor) is recognised; a message only partly NaN, with an Inf, or in
    another frame is not (it is invalid).  ``screen_input`` hands "no data" to its ``no_data``
    callback, not to ``reject``, with the value ``None`` (arrived, no value), and rejects it as
    invalid when the caller gives no such callback."""
    from sappc_msgs_py.convert import is_no_data_msg
    from sappc_msgs_py.inputs import decode_input, screen_input

    for topic in (c.ESTIMATE_ATTITUDE, c.ESTIMATE_RATE, c.SENSOR_GYRO, c.SENSOR_STAR_TRACKER, c.STATE_ATTITUDE_EPOCH, c.faulty(c.STATE_RATE)):
        assert is_no_data_msg(no_data_msg(topic, 2.5), topic), topic.name
    partly = no_data_msg(c.STATE_ATTITUDE, 1.0)
    partly.quaternion.w = 1.0
    inf = vector3_msg([0.0, 0.0, 0.0], 1.0, c.STATE_RATE)
    inf.vector.x = inf.vector.y = inf.vector.z = float("inf")
    wrong_frame = no_data_msg(c.Topic("x", c.STATE_RATE.type_name, "inertial"), 1.0)
    gyro = gyro_msg([0.0, 0.0, 0.0], 1e-8, 1.0, c.SENSOR_GYRO)
    gyro.angular_velocity.x = gyro.angular_velocity.y = gyro.angular_velocity.z = float("nan")  # the gyro's part only: no data
    assert is_no_data_msg(gyro, c.SENSOR_GYRO)
    for msg, topic in ((partly, c.STATE_ATTITUDE), (inf, c.STATE_RATE), (wrong_frame, c.STATE_RATE),
                       (epoch_msg(5, 1.0, c.STATE_ATTITUDE_EPOCH), c.STATE_ATTITUDE_EPOCH), (quaternion_msg([0, 0, 0, 1], 1.0, c.STATE_ATTITUDE), c.STATE_ATTITUDE)):
        assert not is_no_data_msg(msg, topic)
    from rclpy.serialization import serialize_message

    rejected: list[tuple[str, str]] = []
    no_data: list[str] = []
    reject = lambda m, r: rejected.append((m, r))  # noqa: E731
    raw_no_data = serialize_message(no_data_msg(c.STATE_RATE, 1.0))  # screen_input takes what a raw subscription gives
    assert screen_input(raw_no_data, c.STATE_RATE, None, None, 10**9, "", decode_input, reject, no_data.append) == (10**9, None)
    assert rejected == [] and no_data == ["state/rate: no data at 1.000000000 s"]
    assert screen_input(serialize_message(inf), c.STATE_RATE, None, None, 10**9, "", decode_input, reject, no_data.append) == (10**9, None)
    assert [r for _, r in rejected] == ["invalid"] and len(no_data) == 1
    assert screen_input(raw_no_data, c.STATE_RATE, None, None, 10**9, "", decode_input, reject) == (10**9, None)
    assert [r for _, r in rejected] == ["invalid", "invalid"]  # without the callback: rejected, as before


def test_the_sensors_imu_messages_mark_what_they_do_not_measure_and_their_decoders_check_it() -> None:
    """``sensors/*`` are ``sensor_msgs/Imu``: the gyro's angular velocity with its white noise's
    variance on the covariance's diagonal, the tracker's orientation with its own; the part a
    sensor does not measure has element 0 of its covariance at -1 (the message's documented mark),
    and a decoder refuses a message that marks its own measurement absent, a wrong frame, and NaN
    (the relay's "no data")."""
    from sappc_msgs_py.convert import IMU_ABSENT, gyro_from_msg, star_tracker_from_msg

    g = gyro_msg([1e-3, -2e-3, 3e-3], [1e-8, 2e-8, 3e-8], 1.5, c.SENSOR_GYRO)
    assert g.header.frame_id == "body" and stamp_to_ns(g.header.stamp) == 1_500_000_000
    np.testing.assert_array_equal(gyro_from_msg(g, c.SENSOR_GYRO), [1e-3, -2e-3, 3e-3])
    np.testing.assert_array_equal(np.reshape(g.angular_velocity_covariance, (3, 3)), np.diag([1e-8, 2e-8, 3e-8]))
    assert g.orientation_covariance[0] == IMU_ABSENT == g.linear_acceleration_covariance[0] == -1.0
    q = [0.1, -0.2, 0.3, np.sqrt(0.86)]
    st = star_tracker_msg(q, [4e-10, 4e-10, 9e-9], 1.2, c.SENSOR_STAR_TRACKER)
    np.testing.assert_array_equal(star_tracker_from_msg(st, c.SENSOR_STAR_TRACKER), q)
    np.testing.assert_array_equal(np.reshape(st.orientation_covariance, (3, 3)), np.diag([4e-10, 4e-10, 9e-9]))
    assert st.angular_velocity_covariance[0] == IMU_ABSENT == st.linear_acceleration_covariance[0]
    with pytest.raises(InputError, match="sensors/gyro: no angular velocity"):
        gyro_from_msg(st, c.SENSOR_GYRO)
    with pytest.raises(InputError, match="sensors/star_tracker: no orientation"):
        star_tracker_from_msg(g, c.SENSOR_STAR_TRACKER)
    with pytest.raises(InputError, match="frame_id must be 'body'"):
        gyro_from_msg(gyro_msg([0.0, 0.0, 0.0], 1e-8, 1.0, c.Topic("x", c.SENSOR_GYRO.type_name, "inertial")), c.SENSOR_GYRO)
    with pytest.raises(InputError, match="angular_velocity"):
        gyro_from_msg(no_data_msg(c.SENSOR_GYRO, 1.0), c.SENSOR_GYRO)


def test_the_orbits_topics_round_trip_and_bad_ones_are_refused_naming_what_is_wrong() -> None:
    """The magnetometer (tesla, body frame, covariance diag(sigma^2) row major), the tachometers
    (velocity only) and the rods' commands (time_s, then one per rod) round trip exactly (issue 36)."""
    from rclpy.serialization import deserialize_message

    B = np.array([2.1e-5, -3.4e-6, 4.0e-5])
    msg = deserialize_message(serialize_message(magnetic_field_msg(B, 12.34, c.STATE_MAGNETIC_FIELD, [1e-15, 4e-15, 9e-15])),
                              c.STATE_MAGNETIC_FIELD.msg_class)
    assert np.array_equal(magnetic_field_from_msg(msg), B) and msg.header.frame_id == "body"
    assert np.array_equal(np.asarray(msg.magnetic_field_covariance).reshape(3, 3), np.diag([1e-15, 4e-15, 9e-15]))
    msg.header.frame_id = "inertial"
    with pytest.raises(InputError, match="state/magnetic_field: frame_id must be 'body'"):
        magnetic_field_from_msg(msg)
    speeds = np.array([100.0, -50.5, 3.25, 0.0])
    js = deserialize_message(serialize_message(wheel_speed_msg(speeds, 1.0)), c.STATE_WHEEL_SPEED.msg_class)
    assert np.array_equal(wheel_speed_from_msg(js, 4), speeds) and list(js.effort) == [] and list(js.name) == ["wheel_1", "wheel_2", "wheel_3", "wheel_4"]
    with pytest.raises(InputError, match="3 speeds for 4 wheels|4 speeds for 3 wheels"):
        wheel_speed_from_msg(js, 3)
    m = np.array([100.0, -2500.0, 0.5])
    back = deserialize_message(serialize_message(dipole_msg(12.34, m)), c.CONTROL_DIPOLE.msg_class)
    t, got = dipole_from_msg(back, 3)
    assert t == 12.34 and np.array_equal(got, m) and back.layout.dim[0].label == "time_s,rod_1,rod_2,rod_3"
    with pytest.raises(InputError, match="expected time_s and 4 rods"):
        dipole_from_msg(back, 4)
    with pytest.raises(InputError, match="control/dipole data"):
        dipole_from_msg(dipole_msg(1.0, [np.nan, 0.0, 0.0]), 3)


def test_the_bag_decoder_reads_the_magnetic_field_as_rclpy_deserialises_it() -> None:
    """``sensor_msgs/MagneticField`` decoded straight from CDR (the field, not the covariance),
    equal to rclpy's deserialisation, stamps included."""
    from rclpy.serialization import deserialize_message

    from sappc.bag import cdr

    rng = np.random.default_rng(36)
    payloads = [serialize_message(magnetic_field_msg(4e-5 * rng.standard_normal(3), 0.01 * k, c.STATE_MAGNETIC_FIELD, [2.5e-15] * 3))
                for k in range(20)]
    start = np.cumsum([0] + [len(p) for p in payloads[:-1]])
    d = cdr.decode(c.STATE_MAGNETIC_FIELD.type_name, b"".join(payloads), start, np.array([len(p) for p in payloads]))
    assert d is not None and d.undecodable == 0 and d.frame_ids == ("body",)
    truth = [deserialize_message(p, c.STATE_MAGNETIC_FIELD.msg_class) for p in payloads]
    assert np.array_equal(d.values, np.array([[m.magnetic_field.x, m.magnetic_field.y, m.magnetic_field.z] for m in truth]))
    assert np.array_equal(d.stamps_ns, np.array([m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in truth]))


def test_the_bag_decoder_reads_the_tachometers_velocity_only_joint_states() -> None:
    """``state/wheel_speed`` (a ``JointState`` with velocities and no efforts) decodes to the
    speeds alone, as rclpy deserialises them (``joint_states``' decoding is unchanged: its test in
    tests/tools/graph/test_wheels_graph.py)."""
    from rclpy.serialization import deserialize_message

    from sappc.bag import cdr

    rng = np.random.default_rng(4)
    # the exact bytes DDS sends (rosbags' serializer): rclpy's serialize_message leaves 12 bytes of
    # padding after this message, more than a recorded one ever has
    store = get_typestore(Stores.ROS2_JAZZY)
    JointState, Header, Time = store.types["sensor_msgs/msg/JointState"], store.types["std_msgs/msg/Header"], store.types["builtin_interfaces/msg/Time"]
    payloads = [bytes(store.serialize_cdr(JointState(header=Header(stamp=Time(sec=0, nanosec=10_000_000 * k), frame_id="body"),
                                                     name=[f"wheel_{i + 1}" for i in range(4)], position=np.zeros(0),
                                                     velocity=100.0 * rng.standard_normal(4), effort=np.zeros(0)), "sensor_msgs/msg/JointState"))
                for k in range(10)]
    assert deserialize_message(serialize_message(wheel_speed_msg([1.0, 2.0, 3.0, 4.0], 0.0)), c.STATE_WHEEL_SPEED.msg_class).velocity.tolist() == [1, 2, 3, 4]
    start = np.cumsum([0] + [len(p) for p in payloads[:-1]])
    d = cdr.decode(c.STATE_WHEEL_SPEED.type_name, b"".join(payloads), start, np.array([len(p) for p in payloads]))
    assert d is not None and d.undecodable == 0 and d.values.shape == (10, 4)
    truth = [deserialize_message(p, c.STATE_WHEEL_SPEED.msg_class) for p in payloads]
    assert np.array_equal(d.values, np.array([list(m.velocity) for m in truth]))
    assert d.labels == ("wheel_1", "wheel_2", "wheel_3", "wheel_4")

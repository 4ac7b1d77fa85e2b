"""The contract's messages as CDR bytes: what the nodes publish and take (issue 48).

rclpy builds a Python object for every message a subscription takes (a ``WrenchStamped`` is six
of them, with a ``Header`` and a ``Time``) and walks one to serialize it on ``publish``; for the
lockstep loop's eleven messages a sample that is most of the graph's cost.  The contract's types
have a fixed layout once their frame ids, names and labels are known, so a node publishes the
bytes (``Publisher.publish`` takes serialized messages) and subscribes ``raw=True``:

:class:`Layout`
    One topic's message as CDR bytes with every varying value zero (the fixed parts, the frame
    ids, names, labels and counts, written once, as rclpy's serializer writes them: XCDR1 little
    endian, alignment from the end of the 4-byte encapsulation header, padding zero), and where
    its values go (:class:`Field`).  The layouts of every topic are built here (:func:`stamped`,
    :func:`transform`, :func:`clock`, :func:`magnetic_field`, :func:`joint_state`, the float
    arrays); the nodes' codecs and the offline bag writer (:mod:`sappc.bag.write_offline`, which
    fills a whole block of them at once) share them.
:class:`Codec`
    A layout's per-message encoder and decoder, precompiled ``struct`` formats: :meth:`~Codec.encode`
    copies the template and packs the stamp and the values (each checked finite, an
    :class:`~gnc_common.validation.InputError` naming the topic otherwise: a node never publishes
    NaN); :meth:`~Codec.values` reads the values of a message that has the layout byte for byte in
    its fixed parts (``None`` for any other: a frame id not the contract's, another length, a big
    endian message).
:func:`take`
    What a node does with the bytes it receives: the layout's values when the message has the
    layout and every value is finite; any other message (another layout, a non-finite value, the
    contract's "no data" sample) is deserialized by rclpy and goes through the object decoder of
    :mod:`sappc_msgs_py.convert`, whose checks and error messages are the contract's.  So the fast
    path decides nothing: a message it does not take is judged exactly as before.

Stamps are integer nanoseconds (``sec, nanosec = divmod(ns, 10**9)``, what
:func:`~sappc_msgs_py.convert.time_to_stamp` gives for the same time);
:func:`~sappc_msgs_py.convert.cdr_stamp_ns` reads them back.  The bytes equal rclpy's
serialization of the same message but for the padding, which rclpy leaves as it finds it and
this module writes zero (tests/msgs/test_wire.py checks both against rclpy's serializer and
deserializer for every layout).
"""

from __future__ import annotations

import functools
import math
import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np
from numpy.typing import NDArray

from sappc_msgs_py.contract import (
    CLOCK,
    CONTROL_TORQUE,
    CONTROLLER_DIAGNOSTICS,
    COVARIANCE_DIMS,
    DIAGNOSTICS_LAYOUT,
    DIPOLE_LABEL_PREFIX,
    DISTURBANCE_TORQUE,
    ERROR_STATE,
    ESTIMATOR_COVARIANCE,
    ESTIMATOR_DIAGNOSTICS,
    ESTIMATOR_DIAGNOSTICS_LAYOUT,
    MODE_STATUS,
    MODE_STATUS_LAYOUT,
    REFERENCE_ACCELERATION,
    REFERENCE_ATTITUDE,
    REFERENCE_RATE,
    REFERENCE_TF,
    STATE_ATTITUDE,
    STATE_RATE,
    STATE_TF,
    Topic,
)
from gnc_common.validation import InputError
from sappc_msgs_py.convert import EPOCH_SOURCE, IMU_ABSENT
from sappc_msgs_py.convert import _encode as checked_floats

__all__ = [
    "BLOCK_SAMPLES",
    "CDR_LE",
    "Codec",
    "Field",
    "Layout",
    "clock",
    "codec",
    "controller_diagnostics",
    "covariance",
    "dipole",
    "epoch",
    "estimator_diagnostics",
    "gyro_values",
    "imu",
    "joint_state",
    "star_tracker_values",
    "magnetic_field",
    "stamped",
    "take",
    "PICK_ALL",
    "PICK_GYRO",
    "PICK_ORIENTATION",
    "transform",
]

#: A CDR payload's encapsulation header (little-endian plain CDR, options zero): the alignment
#: origin is after it.
CDR_LE = b"\x00\x01\x00\x00"
_NS_PER_S = 1_000_000_000
_STAMP = struct.Struct("<iI")  # builtin_interfaces/Time: int32 sec, uint32 nanosec
#: The range of a stamp's int32 seconds (builtin_interfaces/Time).
_INT32_MIN, _INT32_MAX = -(2**31), 2**31 - 1
#: Samples a node that knows its messages ahead (the reference, the injector) encodes at once
#: (:meth:`Codec.encode_block`): a publish is then a list lookup.  1024 messages of ~80 bytes a
#: topic are small beside a run, and the block's numpy pass costs a sixth of encoding them one by
#: one (0.12 against 0.75 us a message, measured); a larger block saves nothing more.
BLOCK_SAMPLES = 1024

T = TypeVar("T")


#: :attr:`Field.count` of a time (``int32 sec, uint32 nanosec``, given as integer nanoseconds).
TIME_FIELD = -1


@dataclass(frozen=True)
class Field:
    """A value of a payload filled per message: ``key`` (a name the filler knows), at ``offset``
    in the payload, ``count`` float64 (``key == "stamp"``: the header's ``int32 sec, uint32
    nanosec``; ``count`` :data:`TIME_FIELD`: another time, given as integer nanoseconds)."""

    key: str
    offset: int
    count: int


class Layout:
    """A message's CDR bytes with every value zero, where its values go (:attr:`fields`), and
    which of its bytes are fixed (:attr:`fixed`: everything written but the stamp, the fields
    and the alignment padding)."""

    def __init__(self) -> None:
        self.buf = bytearray(CDR_LE)
        self.fields: list[Field] = []
        self.fixed: list[tuple[int, int]] = []  # [start, end) byte ranges a decoder compares

    def _put(self, raw: bytes, fixed: bool = True) -> None:
        if fixed and raw:
            start = len(self.buf)
            if self.fixed and self.fixed[-1][1] == start:  # adjacent: one range
                self.fixed[-1] = (self.fixed[-1][0], start + len(raw))
            else:
                self.fixed.append((start, start + len(raw)))
        self.buf += raw

    def align(self, n: int) -> None:
        self.buf += bytes(-(len(self.buf) - len(CDR_LE)) % n)

    def u32(self, value: int) -> None:
        self.align(4)
        self._put(struct.pack("<I", value))

    def string(self, text: str) -> None:
        raw = text.encode("utf-8") + b"\0"
        self.u32(len(raw))
        self._put(raw)

    def stamp(self) -> None:
        self.align(4)
        self.fields.append(Field("stamp", len(self.buf), 0))
        self.buf += bytes(8)

    def time(self, key: str) -> None:
        """A ``builtin_interfaces/Time`` filled from ``key`` (integer nanoseconds; ``count`` -1)."""
        self.align(4)
        self.fields.append(Field(key, len(self.buf), TIME_FIELD))
        self.buf += bytes(8)

    def header(self, frame_id: str | None) -> None:
        self.stamp()
        self.string(frame_id or "")

    def doubles(self, key: str | None, count: int, constant: Sequence[float] | None = None) -> None:
        """``count`` float64 (aligned to 8 when there is one), filled from ``key`` (``None``: the
        fixed ``constant``, zero when not given)."""
        if count == 0:
            return
        self.align(8)
        if key is not None:
            self.fields.append(Field(key, len(self.buf), count))
            self.buf += bytes(8 * count)
            return
        self._put(struct.pack(f"<{count}d", *(constant if constant is not None else [0.0] * count)))

    def sequence(self, key: str | None, count: int) -> None:
        """A ``sequence<float64>`` of ``count`` values (its length, then the values)."""
        self.u32(count)
        self.doubles(key, count)

    def multiarray(self, dims: list[tuple[str, int, int]], data_offset: int, key: str, count: int) -> None:
        """A ``std_msgs/Float64MultiArray``: its layout's dimensions (label, size, stride) and
        ``data_offset``, then ``count`` values."""
        self.u32(len(dims))
        for label, size, stride in dims:
            self.string(label)
            self.u32(size)
            self.u32(stride)
        self.u32(data_offset)
        self.sequence(key, count)


# ---- the layouts of the contract's topics ----------------------------------------------------
def stamped(topic: Topic, key: str, count: int, before: int = 0) -> Layout:
    """A header then ``count`` doubles of ``key`` (after ``before`` zero doubles: a wrench's force)."""
    p = Layout()
    p.header(topic.frame_id)
    p.doubles(None, before)
    p.doubles(key, count)
    return p


def transform(topic: Topic, key: str) -> Layout:
    """A ``TransformStamped``: the header, the child frame, zero translation, the rotation (x, y, z, w) of ``key``."""
    p = Layout()
    p.header(topic.frame_id)
    p.string(topic.child_frame_id or "")
    p.doubles(None, 3)  # the translation: zero
    p.doubles(key, 4)  # the rotation x y z w (the contract's transforms: the attitude)
    return p


def clock() -> Layout:
    """A ``rosgraph_msgs/Clock``: its stamp alone."""
    p = Layout()
    p.stamp()
    return p


def magnetic_field(topic: Topic, key: str, variance_T2: NDArray[np.float64]) -> Layout:
    """A ``sensor_msgs/MagneticField``: the header, the field of ``key``, the covariance
    ``diag(variance_T2)`` row major (fixed), as :func:`~sappc_msgs_py.convert.magnetic_field_msg` writes it."""
    p = stamped(topic, key, 3)
    cov = np.zeros(9)
    cov[[0, 4, 8]] = variance_T2
    p.doubles(None, 9, cov.tolist())
    return p


def joint_state(topic: Topic, n: int, speed: str, effort: str | None) -> Layout:
    """A ``sensor_msgs/JointState`` of ``n`` wheels (:func:`~sappc_msgs_py.convert.wheel_names`):
    no positions, the velocities of ``speed``, the efforts of ``effort`` (``None``: none)."""
    p = Layout()
    p.header(topic.frame_id)
    p.u32(n)
    for i in range(n):  # wheel_names(n)
        p.string(f"wheel_{i + 1}")
    p.sequence(None, 0)  # position: empty
    p.sequence(speed, n)
    p.sequence(effort, n if effort is not None else 0)
    return p


#: ``sensor_msgs/Imu``'s doubles after its header, in order: orientation (4), its covariance (9),
#: angular velocity (3), its covariance (9), linear acceleration (3), its covariance (9); every
#: array of fixed size, so one field of 37 (:func:`imu`).  Where each part starts:
IMU_ORIENTATION, IMU_ORIENTATION_COV, IMU_ANGULAR_VELOCITY, IMU_ANGULAR_VELOCITY_COV, IMU_LINEAR_ACCELERATION_COV = 0, 4, 13, 16, 28
IMU_DOUBLES = 37


def imu(topic: Topic) -> Layout:
    """A ``sensor_msgs/Imu`` of ``topic``: the header, then its 37 doubles as one field ``imu``
    (:data:`IMU_DOUBLES`; :func:`gyro_values`, :func:`star_tracker_values`)."""
    p = Layout()
    p.header(topic.frame_id)
    p.doubles("imu", IMU_DOUBLES)
    return p


def _diagonal9(variance: Any) -> list[float]:
    v = np.broadcast_to(np.asarray(variance, dtype=np.float64), (3,)).tolist()
    return [v[0], 0.0, 0.0, 0.0, v[1], 0.0, 0.0, 0.0, v[2]]


def gyro_values(omega_B: Any, variance: Any) -> list[float]:
    """The 37 doubles of a gyro sample (:func:`~sappc_msgs_py.convert.gyro_msg`'s message): no
    orientation (its covariance marked absent, :data:`~sappc_msgs_py.convert.IMU_ABSENT`), the
    angular velocity [rad/s] with ``diag(variance)``, no linear acceleration (marked absent)."""
    absent = [-1.0] + [0.0] * 8
    return [0.0, 0.0, 0.0, 1.0, *absent, *np.asarray(omega_B, dtype=np.float64).reshape(3).tolist(), *_diagonal9(variance),
            0.0, 0.0, 0.0, *absent]


def star_tracker_values(q_BN: Any, variance: Any) -> list[float]:
    """The 37 doubles of a star-tracker sample (:func:`~sappc_msgs_py.convert.star_tracker_msg`'s
    message): the orientation (x, y, z, w) with ``diag(variance)``, no angular velocity nor linear
    acceleration (their covariances marked absent)."""
    absent = [-1.0] + [0.0] * 8
    return [*np.asarray(q_BN, dtype=np.float64).reshape(4).tolist(), *_diagonal9(variance), 0.0, 0.0, 0.0, *absent, 0.0, 0.0, 0.0, *absent]


def epoch(topic: Topic, source: str) -> Layout:
    """A ``sensor_msgs/TimeReference`` of ``topic``: the header, ``time_ref`` (field ``time_ref``,
    integer nanoseconds), ``source`` (fixed)."""
    p = Layout()
    p.header(topic.frame_id)
    p.time("time_ref")
    p.string(source)
    return p


def controller_diagnostics() -> Layout:
    """``controller/diagnostics``: the rows of :data:`~sappc_msgs_py.contract.DIAGNOSTICS_LAYOUT`, 3 values each."""
    n = len(DIAGNOSTICS_LAYOUT)  # as convert.diagnostics_msg lays it out
    p = Layout()
    p.multiarray([(",".join(DIAGNOSTICS_LAYOUT), n, 3 * n), ("axis", 3, 3)], 0, "diagnostics", 3 * n)
    return p


def covariance() -> Layout:
    """``estimator/covariance``: the time, then the error state's covariance row major."""
    n = len(ERROR_STATE)  # as convert.covariance_msg lays it out
    p = Layout()
    p.multiarray([(COVARIANCE_DIMS[0], n, n * n), (COVARIANCE_DIMS[1], n, n)], 1, "covariance", 1 + n * n)
    return p


def estimator_diagnostics() -> Layout:
    """``estimator/diagnostics``: the values of :data:`~sappc_msgs_py.contract.ESTIMATOR_DIAGNOSTICS_LAYOUT`."""
    n = len(ESTIMATOR_DIAGNOSTICS_LAYOUT)  # as convert.estimator_diagnostics_msg lays it out
    p = Layout()
    p.multiarray([(",".join(ESTIMATOR_DIAGNOSTICS_LAYOUT), n, n)], 0, "estimator_diagnostics", n)
    return p


def mode_status() -> Layout:
    """``mode/status``: the values of :data:`~sappc_msgs_py.contract.MODE_STATUS_LAYOUT`."""
    n = len(MODE_STATUS_LAYOUT)
    p = Layout()
    p.multiarray([(",".join(MODE_STATUS_LAYOUT), n, n)], 0, "mode_status", n)
    return p


def dipole(n_rods: int) -> Layout:
    """``control/dipole``: the time, then each rod's dipole."""
    labels = ["time_s"] + [f"{DIPOLE_LABEL_PREFIX}{j + 1}" for j in range(n_rods)]  # as convert.dipole_msg lays it out
    p = Layout()
    p.multiarray([(",".join(labels), n_rods + 1, n_rods + 1)], 0, "dipole", n_rods + 1)
    return p


# ---- per message ------------------------------------------------------------------------------
class Codec:
    """One layout's messages, one at a time (module docstring).  ``name``: what an error names
    (the topic); ``finite``: whether every value published must be finite (a float array's rows
    may hold NaN: the controller's diagnostics before its first step, "no data" figures)."""

    def __init__(self, layout: Layout, name: str, finite: bool = True) -> None:
        self.name = name
        self.finite = finite
        self.template = bytes(layout.buf)
        self.size = len(self.template)
        stamps = [f.offset for f in layout.fields if f.key == "stamp"]
        self._stamp_at = stamps[0] if stamps else None
        self._fields = [(f.key, f.offset, f.count, _STAMP if f.count == TIME_FIELD else struct.Struct(f"<{f.count}d"))
                        for f in layout.fields if f.key != "stamp"]
        self.count = sum(f[2] for f in self._fields if f[2] != TIME_FIELD)
        self._fixed = [(a, b, self.template[a:b]) for a, b in layout.fixed]
        # one struct over every value when the fields are one run of doubles (every layout but JointState's)
        one = len(self._fields) == 1 and self._fields[0][2] != TIME_FIELD
        self._read = self._fields[0][3] if one else None
        self._read_at = self._fields[0][1] if one else 0
        # the fast encoder of a layout of one run of doubles (after the stamp, when there is one):
        # one struct over the whole message, its fixed bytes as strings (what encode writes, in one pack)
        self._whole: struct.Struct | None = None
        self._pieces: tuple[bytes, ...] = ()
        if one:
            _key, at, count, _fmt = self._fields[0]
            stamp = self._stamp_at
            if stamp is None:
                self._pieces = (self.template[:at], self.template[at + 8 * count:])
                self._whole = struct.Struct(f"<{at}s{count}d{self.size - at - 8 * count}s")
            elif stamp + 8 <= at:
                self._pieces = (self.template[:stamp], self.template[stamp + 8:at], self.template[at + 8 * count:])
                self._whole = struct.Struct(f"<{stamp}siI{at - stamp - 8}s{count}d{self.size - at - 8 * count}s")
            self._count = count

    def encode(self, stamp_ns: int | None, *values: Any) -> bytes:
        """The message stamped ``stamp_ns`` with each field's values, in the layout's field order
        (each a float64 vector, a list or tuple of floats).

        Raises
        ------
        InputError
            For a value that is not finite or a field of another length, naming the topic.
        """
        whole = self._whole
        if whole is not None and len(values) == 1:  # one pack (a third of the general path's time), the same bytes
            v = values[0]
            vals = v.tolist() if type(v) is np.ndarray and v.shape == (self._count,) and v.dtype == np.float64 else (
                v if type(v) is list and len(v) == self._count else None)
            try:
                if vals is not None and (not self.finite or math.isfinite(sum(vals))):  # NaN and Inf propagate to the sum
                    if self._stamp_at is None:
                        return whole.pack(self._pieces[0], *vals, self._pieces[1])
                    assert stamp_ns is not None, f"{self.name}: a stamped message needs its stamp"
                    return whole.pack(self._pieces[0], *divmod(stamp_ns, _NS_PER_S), self._pieces[1], *vals, self._pieces[2])
            except (TypeError, struct.error):
                pass  # not numbers: the general path says what is wrong
        buf = bytearray(self.template)
        if self._stamp_at is not None:
            assert stamp_ns is not None, f"{self.name}: a stamped message needs its stamp"
            _STAMP.pack_into(buf, self._stamp_at, *divmod(stamp_ns, _NS_PER_S))
        if len(values) != len(self._fields):
            raise ValueError(f"{self.name}: {len(values)} value groups for the layout's {len(self._fields)}")
        for (key, offset, count, fmt), v in zip(self._fields, values):
            if count == TIME_FIELD:
                fmt.pack_into(buf, offset, *divmod(int(v), _NS_PER_S))
            elif self.finite:
                fmt.pack_into(buf, offset, *checked_floats(f"{self.name} {key}", v, count))
            elif type(v) is list and len(v) == count:  # any floats (NaN included)
                fmt.pack_into(buf, offset, *v)
            else:  # any float64
                a = np.asarray(v, dtype=np.float64)
                if a.size != count:
                    raise InputError(f"{self.name} {key} must be {count} values, got {a.size}")
                fmt.pack_into(buf, offset, *a.reshape(count).tolist())
        return bytes(buf)

    def encode_block(self, stamps_ns: Sequence[int], values: Any) -> list[bytes]:
        """``[encode(stamps_ns[i], values[i]) for i ...]``, the same bytes, built in one numpy pass
        (a node that knows its samples ahead, the reference and the injector, encodes a block of
        them at once: a publish is then a list lookup).  For a layout of one run of doubles (after
        its stamp, if it has one); ``values`` (n, count).  A block that :meth:`encode` would refuse
        (a non-finite value, a stamp beyond int32 seconds) is encoded message by message, so the
        error is :meth:`encode`'s, naming the value.

        Raises
        ------
        ValueError
            For a layout of several fields, or ``values`` of another shape.
        """
        if self._whole is None:
            raise ValueError(f"{self.name}: encode_block takes a layout of one run of doubles")
        v = np.asarray(values, dtype=np.float64)
        n = len(stamps_ns)
        if v.shape != (n, self._count):
            raise ValueError(f"{self.name}: encode_block needs values of shape {(n, self._count)}, got {v.shape}")
        ns = np.asarray(stamps_ns, dtype=np.int64).reshape(n)
        sec, nsec = np.divmod(ns, _NS_PER_S)  # floor division: what encode's divmod gives
        if (self.finite and not np.isfinite(v).all()) or (n and (sec.min() < _INT32_MIN or sec.max() > _INT32_MAX)):
            return [self.encode(int(s), row) for s, row in zip(ns.tolist(), v)]
        rows = np.empty((n, self.size), np.uint8)
        rows[:] = np.frombuffer(self.template, np.uint8)
        if self._stamp_at is not None:
            at = self._stamp_at
            rows[:, at:at + 4] = sec.astype("<i4").view(np.uint8).reshape(n, 4)
            rows[:, at + 4:at + 8] = nsec.astype("<u4").view(np.uint8).reshape(n, 4)
        rows[:, self._read_at:self._read_at + 8 * self._count] = np.ascontiguousarray(v, dtype="<f8").view(np.uint8).reshape(n, 8 * self._count)
        flat, w = rows.tobytes(), self.size
        return [flat[i * w:(i + 1) * w] for i in range(n)]

    def values(self, raw: bytes) -> tuple[float, ...] | None:
        """Every field's values of ``raw`` in the layout's order, when ``raw`` has the layout
        (length, little endian, every fixed byte); ``None`` otherwise (not checked for finiteness)."""
        if len(raw) != self.size or raw[1] != 1:
            return None
        for a, b, expected in self._fixed:
            if raw[a:b] != expected:
                return None
        if self._read is not None:
            return self._read.unpack_from(raw, self._read_at)
        out: tuple[float, ...] = ()
        for _key, offset, count, fmt in self._fields:
            if count == TIME_FIELD:
                sec, nanosec = fmt.unpack_from(raw, offset)
                out += (sec * _NS_PER_S + nanosec,)
            else:
                out += fmt.unpack_from(raw, offset)
        return out

    def no_data(self, stamp_ns: int) -> bytes:
        """The contract's "no data" sample (:func:`~sappc_msgs_py.convert.no_data_msg`) of a layout
        whose values are all its fields' doubles (a ``QuaternionStamped`` or ``Vector3Stamped``):
        NaN in every value, stamped ``stamp_ns``."""
        buf = bytearray(self.template)
        if self._stamp_at is not None:
            _STAMP.pack_into(buf, self._stamp_at, *divmod(stamp_ns, _NS_PER_S))
        for _key, offset, count, fmt in self._fields:
            fmt.pack_into(buf, offset, *([math.nan] * count))
        return bytes(buf)


#: The layouts of the loop's fixed topics (those whose layout the topic alone decides).
_LAYOUTS: dict[Topic, Callable[[], Layout]] = {
    CLOCK: clock,
    STATE_ATTITUDE: lambda: stamped(STATE_ATTITUDE, "q_BN", 4),
    STATE_RATE: lambda: stamped(STATE_RATE, "omega_BN_B", 3),
    STATE_TF: lambda: transform(STATE_TF, "q_BN"),
    REFERENCE_ATTITUDE: lambda: stamped(REFERENCE_ATTITUDE, "q_RN", 4),
    REFERENCE_RATE: lambda: stamped(REFERENCE_RATE, "omega_RN_R", 3),
    REFERENCE_ACCELERATION: lambda: stamped(REFERENCE_ACCELERATION, "omegadot_RN_R", 3),
    REFERENCE_TF: lambda: transform(REFERENCE_TF, "q_RN"),
    CONTROL_TORQUE: lambda: stamped(CONTROL_TORQUE, "torque_B", 3, before=3),
    DISTURBANCE_TORQUE: lambda: stamped(DISTURBANCE_TORQUE, "disturbance_B", 3, before=3),
    CONTROLLER_DIAGNOSTICS: controller_diagnostics,
    ESTIMATOR_COVARIANCE: covariance,
    ESTIMATOR_DIAGNOSTICS: estimator_diagnostics,
    MODE_STATUS: mode_status,
}
#: Topics whose values may be NaN (float arrays of figures: no figure yet, "no data").
_MAY_BE_NAN = frozenset({CONTROLLER_DIAGNOSTICS, ESTIMATOR_COVARIANCE, ESTIMATOR_DIAGNOSTICS})

#: The value a topic's type carries, by type, for the topics not listed in :data:`_LAYOUTS`
#: (a relay's ``fault/...`` topics, a remapped name): the layout from the type and the frame.
_BY_TYPE: dict[str, Callable[[Topic], Layout]] = {
    "geometry_msgs/msg/QuaternionStamped": lambda t: stamped(t, "quaternion", 4),
    "geometry_msgs/msg/Vector3Stamped": lambda t: stamped(t, "vector", 3),
    "geometry_msgs/msg/WrenchStamped": lambda t: stamped(t, "torque", 3, before=3),
    "geometry_msgs/msg/TransformStamped": lambda t: transform(t, "rotation"),
    "rosgraph_msgs/msg/Clock": lambda t: clock(),
    "sensor_msgs/msg/Imu": imu,
    "sensor_msgs/msg/TimeReference": lambda t: epoch(t, EPOCH_SOURCE),
}


@functools.cache
def codec(topic: Topic) -> Codec:
    """The codec of ``topic``, a topic of the contract whose layout its type and frame ids decide
    (the stamped vectors and quaternions, torques, transforms, ``/clock``, the controller's
    diagnostics); a topic of another type raises ``ValueError``."""
    make = _LAYOUTS.get(topic)
    if make is not None:
        return Codec(make(), topic.name, finite=topic not in _MAY_BE_NAN)
    by_type = _BY_TYPE.get(topic.type_name)
    if by_type is None:
        raise ValueError(f"{topic.name}: no fixed CDR layout for {topic.type_name}")
    return Codec(by_type(topic), topic.name)


def _all_finite(values: tuple[float, ...]) -> NDArray[np.float64] | None:
    return np.array(values) if all(map(math.isfinite, values)) else None


def _gyro(values: tuple[float, ...]) -> NDArray[np.float64] | None:
    """A gyro ``Imu``'s angular velocity, when it measures one (its covariance not marked absent) and it is finite."""
    w = values[IMU_ANGULAR_VELOCITY:IMU_ANGULAR_VELOCITY + 3]
    return np.array(w) if values[IMU_ANGULAR_VELOCITY_COV] != IMU_ABSENT and all(map(math.isfinite, w)) else None


def _orientation(values: tuple[float, ...]) -> NDArray[np.float64] | None:
    """A star tracker ``Imu``'s orientation, when it measures one (its covariance not marked absent) and it is finite."""
    q = values[IMU_ORIENTATION:IMU_ORIENTATION + 4]
    return np.array(q) if values[IMU_ORIENTATION_COV] != IMU_ABSENT and all(map(math.isfinite, q)) else None


#: What :func:`take` picks from a message's values (``None``: the object decoder decides): every
#: value, finite (the default); a gyro's angular velocity; a star tracker's orientation.
PICK_ALL: Callable[[tuple[float, ...]], NDArray[np.float64] | None] = _all_finite
PICK_GYRO: Callable[[tuple[float, ...]], NDArray[np.float64] | None] = _gyro
PICK_ORIENTATION: Callable[[tuple[float, ...]], NDArray[np.float64] | None] = _orientation


def take(raw: bytes, topic: Topic, decoder: Callable[[Any], T], fast: Codec | None = None,
         pick: Callable[[tuple[float, ...]], Any] = _all_finite) -> Any:
    """The value of a message of ``topic`` received as bytes.

    ``fast`` (default :func:`codec` of ``topic``): when ``raw`` has its layout, ``pick(values)``
    (default :data:`PICK_ALL`: every value, all finite, as a float64 array), unless it is ``None``.
    Otherwise ``raw`` is deserialized (rclpy) and ``decoder(msg)`` (the topic's object decoder of
    :mod:`sappc_msgs_py.convert`) decides: its value, or its
    :class:`~gnc_common.validation.InputError` naming what is wrong.  A ``pick`` accepts exactly
    what the decoder accepts of a message of the layout, and gives the decoder's value.
    """
    c = fast if fast is not None else codec(topic)
    values = c.values(raw)
    if values is not None:
        value = pick(values)
        if value is not None:
            return value
    return decoder(deserialize(raw, topic))


def deserialize(raw: bytes, topic: Topic) -> Any:
    """``raw`` as a message object of ``topic``'s type (rclpy's deserializer)."""
    from rclpy.serialization import deserialize_message

    return deserialize_message(raw, topic.msg_class)

"""Vectorised CDR decoding of the topic contract's message types, straight from a byte buffer.

The contract's types have a fixed layout once the header's ``frame_id`` string is known, and the
messages of one topic almost always share one length.  So the messages of a topic are gathered,
one group per payload length, into a ``(messages, bytes)`` matrix and every field is read as a
column view: no per-message Python.  Layout (ROS 2 CDR, XCDR1 little endian, alignment counted
from the end of the 4-byte encapsulation header):

``*Stamped`` (QuaternionStamped, Vector3Stamped, WrenchStamped), ``sensor_msgs/MagneticField`` and ``sensor_msgs/Imu``
    header: ``int32 sec`` @0, ``uint32 nanosec`` @4, ``string frame_id`` (``uint32`` length with
    the NUL, then the characters) @8; then the doubles (4, 3 or 6; MagneticField: the field's 3 and
    the covariance's fixed 9, of which the field is kept; Imu: its 37, every array of fixed size,
    all kept) at the next multiple of 8.
``geometry_msgs/TransformStamped`` (the frames ``state/tf``, ``reference/tf``)
    the header as above, then ``string child_frame_id`` at the next multiple of 4, then 7 doubles
    (translation x y z, rotation x y z w) at the next multiple of 8; the rotation is kept (the
    contract's transforms have zero translation), the header frame ids are reported.
``rosgraph_msgs/Clock``
    ``int32 sec`` @0, ``uint32 nanosec`` @4.
``sensor_msgs/TimeReference`` (``state/attitude_epoch``)
    the header, ``time_ref`` (``int32 sec``, ``uint32 nanosec``) at the next multiple of 4, then
    ``string source``; kept: ``time_ref``'s two fields and whether ``source`` names a sensor.
``sensor_msgs/JointState`` (``joint_states``: the wheels; ``state/wheel_speed``: their tachometers, no efforts)
    the header, ``sequence<string> name`` (at the next multiple of 4), then ``sequence<float64>``
    position (empty in the contract), velocity and effort (empty on ``state/wheel_speed``) (each count at a multiple of 4, its
    doubles at the next multiple of 8).  Parsed in Python for the first message of a group, the
    others checked to carry the same frame id, names and counts (as for the multiarray below).
``std_msgs/Float64MultiArray``
    ``sequence<MultiArrayDimension{string label, uint32 size, uint32 stride}> dim``,
    ``uint32 data_offset``, ``sequence<float64> data`` (the doubles aligned to 8).  Parsed in
    Python for the first message of a group; the others must carry the same bytes up to the
    data (the same layout), which is checked, or they are parsed one by one (the slow path,
    counted in :attr:`Decoded.slow_path`).  Only the bytes the parse reads are compared: the
    encapsulation options and the alignment padding (after each label, before the doubles) are
    left uninitialised by the serializer and may differ between messages of one layout.

A message that does not fit its type's layout (wrong length, big-endian encapsulation, an
inconsistent string length) is not decoded and is counted.  The decoders are tested against
``rclpy.serialization.deserialize_message`` on every message of a recorded bag.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sappc_msgs_py.contract import float_array_carries_time

__all__ = ["DECODERS", "Decoded", "decode"]

#: Encapsulation header of little-endian plain CDR, the only one ROS 2 writes on this platform.
_CDR_LE = (0x00, 0x01)
#: Payload offset of the CDR body (after the encapsulation header) [bytes].
_BODY = 4
_NS = 1_000_000_000

#: Doubles after the header of each stamped type, and which of them are the values kept.
_STAMPED = {
    "geometry_msgs/msg/QuaternionStamped": (4, slice(0, 4)),  # x, y, z, w
    "geometry_msgs/msg/Vector3Stamped": (3, slice(0, 3)),
    "geometry_msgs/msg/WrenchStamped": (6, slice(3, 6)),  # force x y z, torque x y z: keep the torque
    # (the sensors) orientation x y z w, its covariance (9), angular velocity x y z, its covariance (9),
    # linear acceleration x y z, its covariance (9): every array of fixed size, so the layout of a
    # stamped type; all kept (columns 0:4 the orientation, 13:16 the angular velocity)
    "sensor_msgs/msg/Imu": (37, slice(0, 37)),
    "sensor_msgs/msg/MagneticField": (12, slice(0, 3)),  # the field x y z, then float64[9] covariance: keep the field
}


@dataclass
class Decoded:
    """The decoded messages of one topic (rows in file order, undecodable ones left out)."""

    index: NDArray[np.int64]  # (n,) position of each decoded message among the topic's messages
    stamps_ns: NDArray[np.int64]  # (n,) header stamp (Clock: the clock; diagnostics: time_s)
    values: NDArray[np.float64]  # (n, width)
    frame_ids: tuple[str, ...] = ()  # the distinct header frame ids seen
    labels: tuple[str, ...] = ()  # Float64MultiArray: the first dimension's label, split at commas
    undecodable: int = 0
    slow_path: int = 0  # messages parsed one by one (not in a group's vectorised layout)


def _groups(u8: NDArray[np.uint8], start: NDArray[np.int64], length: NDArray[np.int64]) -> Iterator[tuple[NDArray[np.int64], NDArray[np.uint8]]]:
    """Yield (positions, rows) per distinct payload length: rows is (g, L) uint8."""
    for L in np.unique(length):
        pos = np.flatnonzero(length == L)
        L = int(L)
        rows = u8[start[pos, None] + np.arange(L)] if L else np.empty((pos.size, 0), np.uint8)
        yield pos, rows


def _le(rows: NDArray[np.uint8]) -> NDArray[np.bool_]:
    le: NDArray[np.bool_] = (rows[:, 0] == _CDR_LE[0]) & (rows[:, 1] == _CDR_LE[1])  # numpy's stub: & of the comparisons is Any
    return le


def _col(rows: NDArray[np.uint8], begin: int, end: int, dtype: str) -> NDArray[Any]:
    return np.ascontiguousarray(rows[:, begin:end]).view(dtype)


def _stamp_ns(rows: NDArray[np.uint8]) -> NDArray[np.int64]:
    sec = _col(rows, _BODY, _BODY + 4, "<i4")[:, 0].astype(np.int64)
    nsec = _col(rows, _BODY + 4, _BODY + 8, "<u4")[:, 0].astype(np.int64)
    return sec * _NS + nsec


def _add_frame_ids(frames: set[str], rows: NDArray[np.uint8], slen: NDArray[np.int64]) -> None:
    """Add to ``frames`` the distinct header frame ids of ``rows`` (``slen``: each one's string
    length, its NUL included)."""
    for n in np.unique(slen):
        chars = rows[slen == n, _BODY + 12 : _BODY + 12 + int(n) - 1]
        if (chars == chars[0]).all():  # the usual case, one frame per topic: no sort of the rows (np.unique's)
            frames.add(bytes(chars[0]).decode("utf-8", "replace"))
        else:
            frames.update(bytes(c).decode("utf-8", "replace") for c in np.unique(chars, axis=0))


def _decode_stamped(u8: NDArray[np.uint8], start: NDArray[np.int64], length: NDArray[np.int64], n_doubles: int, keep: slice) -> Decoded:
    idx: list[NDArray[np.int64]] = []
    stamps: list[NDArray[np.int64]] = []
    vals: list[NDArray[np.float64]] = []
    frames: set[str] = set()
    width = keep.stop - keep.start
    for pos, rows in _groups(u8, start, length):
        L = rows.shape[1]
        data_at = L - 8 * n_doubles  # absolute offset of the doubles
        if data_at < _BODY + 13:  # header (12 bytes) and at least the NUL of frame_id
            continue
        slen = _col(rows, _BODY + 8, _BODY + 12, "<u4")[:, 0].astype(np.int64)
        ok = _le(rows) & (slen >= 1) & (_BODY + ((12 + slen + 7) // 8) * 8 == data_at)
        if not ok.any():
            continue
        rows, pos, slen = rows[ok], pos[ok], slen[ok]
        idx.append(pos)
        stamps.append(_stamp_ns(rows))
        vals.append(_col(rows, data_at, L, "<f8")[:, keep])
        _add_frame_ids(frames, rows, slen)
    return _assemble(idx, stamps, vals, width, length.size, frame_ids=tuple(sorted(frames)))


def _decode_transform(u8: NDArray[np.uint8], start: NDArray[np.int64], length: NDArray[np.int64]) -> Decoded:
    """``TransformStamped``: two strings of any lengths before the doubles, so each row's child
    string offset is computed from its own frame id length (still no per-message Python)."""
    idx: list[NDArray[np.int64]] = []
    stamps: list[NDArray[np.int64]] = []
    vals: list[NDArray[np.float64]] = []
    frames: set[str] = set()
    for pos, rows in _groups(u8, start, length):
        L = rows.shape[1]
        data_at = L - 8 * 7  # absolute offset of the doubles
        if data_at < _BODY + 20:  # header (12 bytes, the NUL of frame_id) and the child string's length and NUL
            continue
        slen = _col(rows, _BODY + 8, _BODY + 12, "<u4")[:, 0].astype(np.int64)
        child_at = _BODY + (12 + slen + 3) // 4 * 4  # absolute offset of the child string's length, per row
        inside = (slen >= 1) & (child_at + 4 <= data_at)
        clen = np.zeros(rows.shape[0], np.int64)
        r = np.flatnonzero(inside)
        clen[r] = np.ascontiguousarray(rows[r[:, None], child_at[r, None] + np.arange(4)]).view("<u4")[:, 0]
        ok = _le(rows) & inside & (clen >= 1) & (_BODY + (child_at - _BODY + 4 + clen + 7) // 8 * 8 == data_at)
        if not ok.any():
            continue
        rows, pos, slen = rows[ok], pos[ok], slen[ok]
        idx.append(pos)
        stamps.append(_stamp_ns(rows))
        vals.append(_col(rows, data_at, L, "<f8")[:, 3:7])  # the rotation, x y z w
        _add_frame_ids(frames, rows, slen)
    return _assemble(idx, stamps, vals, 4, length.size, frame_ids=tuple(sorted(frames)))


def _decode_time_reference(u8: NDArray[np.uint8], start: NDArray[np.int64], length: NDArray[np.int64]) -> Decoded:
    """``sensor_msgs/TimeReference`` (``state/attitude_epoch``): the header, ``time_ref`` (``int32
    sec``, ``uint32 nanosec``) at the next multiple of 4 after the frame id, then ``string source``.
    The values are ``time_ref``'s seconds and nanoseconds (as floats: exact, where one float of
    nanoseconds would not be for a wall-clock epoch) and whether ``source`` names a sensor (1.0; 0.0
    for the contract's "no data", which names none)."""
    idx: list[NDArray[np.int64]] = []
    stamps: list[NDArray[np.int64]] = []
    vals: list[NDArray[np.float64]] = []
    frames: set[str] = set()
    for pos, rows in _groups(u8, start, length):
        L = rows.shape[1]
        if L < _BODY + 25:  # header (12 bytes, the NUL of frame_id), time_ref (8), source's length and NUL
            continue
        slen = _col(rows, _BODY + 8, _BODY + 12, "<u4")[:, 0].astype(np.int64)
        time_at = _BODY + (12 + slen + 3) // 4 * 4  # absolute offset of time_ref, per row
        inside = (slen >= 1) & (time_at + 12 <= L)
        srclen = np.zeros(rows.shape[0], np.int64)
        r = np.flatnonzero(inside)
        srclen[r] = np.ascontiguousarray(rows[r[:, None], time_at[r, None] + 8 + np.arange(4)]).view("<u4")[:, 0]
        ok = _le(rows) & inside & (srclen >= 1) & (time_at + 12 + srclen == L)
        if not ok.any():
            continue
        rows, pos, slen, time_at, srclen = rows[ok], pos[ok], slen[ok], time_at[ok], srclen[ok]
        at = time_at[:, None] + np.arange(8)
        raw = np.ascontiguousarray(rows[np.arange(rows.shape[0])[:, None], at])
        sec, nanosec = raw[:, :4].copy().view("<i4")[:, 0], raw[:, 4:].copy().view("<u4")[:, 0]
        idx.append(pos)
        stamps.append(_stamp_ns(rows))
        vals.append(np.stack((sec.astype(np.float64), nanosec.astype(np.float64), (srclen > 1).astype(np.float64)), axis=1))
        _add_frame_ids(frames, rows, slen)
    return _assemble(idx, stamps, vals, 3, length.size, frame_ids=tuple(sorted(frames)))


def _decode_clock(u8: NDArray[np.uint8], start: NDArray[np.int64], length: NDArray[np.int64]) -> Decoded:
    idx, stamps, vals = [], [], []
    for pos, rows in _groups(u8, start, length):
        if rows.shape[1] != _BODY + 8:
            continue
        ok = _le(rows)
        ns = _stamp_ns(rows[ok])
        idx.append(pos[ok])
        stamps.append(ns)
        vals.append((ns / 1e9)[:, None])
    return _assemble(idx, stamps, vals, 1, length.size)


def _parse_multiarray(payload: bytes) -> tuple[list[str], int, int, NDArray[np.bool_]]:
    """(dimension labels, absolute offset of the data, number of doubles, meaningful bytes) of one message.

    The meaningful bytes (a mask over ``payload[:data offset]``) are those the parse reads: the
    encapsulation kind, the counts, lengths, characters (with the NUL), sizes, strides and
    ``data_offset``; not the encapsulation options nor the alignment padding.  A message of the
    same length whose meaningful bytes are equal parses to the same layout, whatever its padding.

    Raises ``ValueError`` (or ``struct.error``) when the payload does not fit the layout.
    """
    if tuple(payload[:2]) != _CDR_LE:
        raise ValueError("not little-endian CDR")
    body = memoryview(payload)[_BODY:]
    read = [(0, 2)]  # absolute [begin, end) ranges read; the encapsulation kind
    (ndim,) = struct.unpack_from("<I", body, 0)
    read.append((_BODY, _BODY + 4))
    off, labels = 4, []
    for _ in range(ndim):
        (n,) = struct.unpack_from("<I", body, off)
        labels.append(bytes(body[off + 4 : off + 4 + n - 1]).decode("utf-8") if n else "")
        read.append((_BODY + off, _BODY + off + 4 + n))  # length, characters, NUL
        off = (off + 4 + n + 3) // 4 * 4
        read.append((_BODY + off, _BODY + off + 8))  # size, stride
        off += 8
    read.append((_BODY + off, _BODY + off + 8))  # data_offset, count
    off += 4  # data_offset
    (count,) = struct.unpack_from("<I", body, off)
    off = (off + 4 + 7) // 8 * 8
    if off + 8 * count != len(body):
        raise ValueError(f"{count} doubles do not fill the message ({len(body) - off} bytes left)")
    meaningful = np.zeros(_BODY + off, dtype=bool)
    for begin, end in read:
        meaningful[begin:end] = True
    return labels, _BODY + off, count, meaningful


def _multiarray_stamps(values: NDArray[np.float64], labels: list[str]) -> NDArray[np.int64]:
    """The stamp of the contract's float arrays (diagnostics, the estimator's covariance): their
    ``data[0]`` (:func:`~sappc_msgs_py.contract.float_array_carries_time`), else zero."""
    if labels and float_array_carries_time(labels[0]) and values.shape[1]:
        return np.round(values[:, 0] * 1e9).astype(np.int64)
    return np.zeros(values.shape[0], np.int64)


def _decode_multiarray(u8: NDArray[np.uint8], start: NDArray[np.int64], length: NDArray[np.int64]) -> Decoded:
    # per layout: (positions, values, first dimension's labels)
    parts: list[tuple[NDArray[np.int64], NDArray[np.float64], list[str]]] = []
    slow = 0
    for pos, rows in _groups(u8, start, length):
        try:
            lab, data_at, _count, meaningful = _parse_multiarray(bytes(rows[0]))
        except (ValueError, struct.error):
            lab, data_at, meaningful = [], -1, np.zeros(0, bool)
        if data_at > 0:  # the same layout: equal meaningful bytes (padding is not compared)
            cols = np.flatnonzero(meaningful)
            same = (rows[:, cols] == rows[0, cols]).all(axis=1)
        else:
            same = np.zeros(rows.shape[0], bool)
        if same.any():
            parts.append((pos[same], _col(rows[same], data_at, rows.shape[1], "<f8"), lab))
        for r in np.flatnonzero(~same):  # another layout in a message of the same length
            try:
                lab_r, at, cnt, _ = _parse_multiarray(bytes(rows[r]))
            except (ValueError, struct.error):
                continue
            slow += 1
            parts.append((pos[r : r + 1], np.frombuffer(bytes(rows[r, at : at + 8 * cnt]), "<f8")[None, :], lab_r))
    width = max([v.shape[1] for _, v, _ in parts] + [1])
    out = _assemble(
        [p for p, _, _ in parts],
        [_multiarray_stamps(v, lab) for _, v, lab in parts],
        [np.pad(v, ((0, 0), (0, width - v.shape[1])), constant_values=np.nan) for _, v, _ in parts],
        width,
        length.size,
    )
    if parts:  # the topic's layout: that of most of its messages
        labels = max(parts, key=lambda part: part[0].size)[2]
        out.labels = tuple(labels[0].split(",")) if labels and labels[0] else ()
    out.slow_path = slow
    return out


#: Bytes allowed after a ``JointState``'s last double (see :func:`_parse_joint_state`).
_TRAILING = 8


def _parse_joint_state(payload: bytes) -> tuple[list[str], str, int, int, int, NDArray[np.bool_]]:
    """(joint names, frame id, absolute offsets of the velocities and of the efforts, number of
    joints, meaningful bytes) of one ``sensor_msgs/JointState`` with no positions and as many velocities and efforts
    as names (the contract's ``joint_states``), or as many velocities and no efforts (its
    ``state/wheel_speed``, the tachometers: the efforts' offset is then -1).  Up to :data:`_TRAILING` bytes after the last
    double are allowed (rclpy's serializer was seen to leave 8 there).  The meaningful bytes are those the parse reads
    except the stamp (which differs from message to message): the encapsulation kind, the frame
    id, the names and the counts.  Raises ``ValueError`` (or ``struct.error``) otherwise."""
    if tuple(payload[:2]) != _CDR_LE:
        raise ValueError("not little-endian CDR")
    body = memoryview(payload)[_BODY:]
    read = [(0, 2)]
    (flen,) = struct.unpack_from("<I", body, 8)
    frame = bytes(body[12 : 12 + flen - 1]).decode("utf-8") if flen else ""
    read.append((_BODY + 8, _BODY + 12 + flen))
    off = (12 + flen + 3) // 4 * 4
    (n,) = struct.unpack_from("<I", body, off)
    read.append((_BODY + off, _BODY + off + 4))
    off += 4
    names = []
    for _ in range(n):
        (m,) = struct.unpack_from("<I", body, off)
        names.append(bytes(body[off + 4 : off + 4 + m - 1]).decode("utf-8") if m else "")
        read.append((_BODY + off, _BODY + off + 4 + m))
        off = (off + 4 + m + 3) // 4 * 4
    (npos,) = struct.unpack_from("<I", body, off)
    read.append((_BODY + off, _BODY + off + 4))
    if npos != 0:
        raise ValueError("joint positions are not part of the contract's joint_states")
    off += 4
    (nvel,) = struct.unpack_from("<I", body, off)
    read.append((_BODY + off, _BODY + off + 4))
    vel_at = (off + 4 + 7) // 8 * 8 if nvel else off + 4
    off = vel_at + 8 * nvel
    (neff,) = struct.unpack_from("<I", body, off)
    read.append((_BODY + off, _BODY + off + 4))
    eff_at = (off + 4 + 7) // 8 * 8 if neff else off + 4
    if nvel != n or neff not in (n, 0) or not 0 <= len(body) - (eff_at + 8 * neff) <= _TRAILING:
        raise ValueError(f"{n} joints, {nvel} velocities, {neff} efforts do not fill the message")
    meaningful = np.zeros(_BODY + eff_at, dtype=bool)
    for begin, end in read:
        meaningful[begin:end] = True
    return names, frame, _BODY + vel_at, _BODY + eff_at if neff else -1, n, meaningful


def _decode_joint_state(u8: NDArray[np.uint8], start: NDArray[np.int64], length: NDArray[np.int64]) -> Decoded:
    """``sensor_msgs/JointState`` (the wheels): values (velocities, then efforts), labels the joint names."""
    parts: list[tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float64], list[str]]] = []
    frames: set[str] = set()
    slow = 0
    for pos, rows in _groups(u8, start, length):
        try:
            names, frame, vel_at, eff_at, n, meaningful = _parse_joint_state(bytes(rows[0]))
        except (ValueError, struct.error):
            names, frame, vel_at, eff_at, n, meaningful = [], "", -1, -1, 0, np.zeros(0, bool)
        same = np.zeros(rows.shape[0], bool)
        if vel_at > 0:
            cols = np.flatnonzero(meaningful)
            same = (rows[:, cols] == rows[0, cols]).all(axis=1)
        if same.any():
            r = rows[same]
            efforts = [_col(r, eff_at, eff_at + 8 * n, "<f8")] if eff_at > 0 else []  # none: the tachometers
            parts.append((pos[same], _stamp_ns(r), np.hstack((_col(r, vel_at, vel_at + 8 * n, "<f8"), *efforts)), names))
            frames.add(frame)
        for k in np.flatnonzero(~same):  # another layout in a message of the same length
            try:
                names_k, frame_k, at, eff, nk, _ = _parse_joint_state(bytes(rows[k]))
            except (ValueError, struct.error):
                continue
            slow += 1
            raw = bytes(rows[k])
            eff_vals = [np.frombuffer(raw[eff : eff + 8 * nk], "<f8")] if eff > 0 else []
            vals = np.concatenate((np.frombuffer(raw[at : at + 8 * nk], "<f8"), *eff_vals))[None, :]
            parts.append((pos[k : k + 1], _stamp_ns(rows[k : k + 1]), vals, names_k))
            frames.add(frame_k)
    width = max([v.shape[1] for _, _, v, _ in parts] + [0])
    out = _assemble([p for p, _, _, _ in parts], [s for _, s, _, _ in parts],
                    [np.pad(v, ((0, 0), (0, width - v.shape[1])), constant_values=np.nan) for _, _, v, _ in parts], width, length.size,
                    frame_ids=tuple(sorted(frames)))
    if parts:
        out.labels = tuple(max(parts, key=lambda part: part[0].size)[3])
    out.slow_path = slow
    return out


def _assemble(idx: list[NDArray[np.int64]], stamps: list[NDArray[np.int64]], vals: list[NDArray[np.float64]], width: int, total: int,
              frame_ids: tuple[str, ...] = ()) -> Decoded:
    if not idx:
        return Decoded(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, width)), frame_ids, undecodable=total)
    index = np.concatenate(idx)
    order = np.argsort(index, kind="stable")  # back to file order
    return Decoded(
        index=index[order],
        stamps_ns=np.concatenate(stamps)[order],
        values=np.concatenate(vals)[order],
        frame_ids=frame_ids,
        undecodable=total - index.size,
    )


_Decoder = Callable[[NDArray[np.uint8], NDArray[np.int64], NDArray[np.int64]], Decoded]


def _stamped_decoder(n_doubles: int, keep: slice) -> _Decoder:
    return lambda u8, s, n: _decode_stamped(u8, s, n, n_doubles, keep)


#: Decoder of each type name: ``f(u8, start, length) -> Decoded``.
DECODERS: dict[str, _Decoder] = {name: _stamped_decoder(d, k) for name, (d, k) in _STAMPED.items()}
DECODERS["geometry_msgs/msg/TransformStamped"] = _decode_transform
DECODERS["rosgraph_msgs/msg/Clock"] = _decode_clock
DECODERS["std_msgs/msg/Float64MultiArray"] = _decode_multiarray
DECODERS["sensor_msgs/msg/JointState"] = _decode_joint_state
DECODERS["sensor_msgs/msg/TimeReference"] = _decode_time_reference


def decode(type_name: str, buffer: bytes, start: NDArray[np.int64], length: NDArray[np.int64]) -> Decoded | None:
    """Decode the messages at ``buffer[start:start+length]`` as ``type_name`` (``None``: not a type
    of the contract)."""
    fn = DECODERS.get(type_name)
    if fn is None:
        return None
    return fn(np.frombuffer(buffer, np.uint8), np.asarray(start, np.int64), np.asarray(length, np.int64))

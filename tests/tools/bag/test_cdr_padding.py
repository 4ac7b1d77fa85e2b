"""The vectorised diagnostics decoder ignores CDR padding (issue 12, the slow decode path).

The serializer leaves the alignment padding of a ``Float64MultiArray`` (after each dimension
label, before the doubles) and the encapsulation options uninitialised, so messages of one
layout may differ there.  They must all take the vectorised path, and decode to exactly what
``rclpy``'s deserialiser gives.  A message whose *layout* differs (same length, another label)
must still be parsed on its own.
"""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
from mcap.writer import CompressionType, Writer
from rclpy.serialization import deserialize_message, serialize_message

from sappc.bag import cdr
from sappc.bag.read import read_bag
from sappc_msgs_py import contract as c
from sappc_msgs_py.convert import diagnostics_msg
from sappc_msgs_py.schemas import schema_text

TYPE = c.CONTROLLER_DIAGNOSTICS.type_name
N = 200


def _padding_offsets(labels: list[str], n_doubles: int, total: int) -> list[int]:
    """Offsets (from the start of the payload) of the bytes no field owns, by the XCDR1 rules,
    worked out here independently of the decoder: encapsulation options, alignment padding."""
    pads = [2, 3]  # encapsulation options
    off = 4  # body offset 0 = payload offset 4; alignment counts from the body
    off += 4  # dim sequence length
    for label in labels:
        off += 4 + len(label.encode()) + 1  # string length, characters, NUL
        aligned = (off - 4 + 3) // 4 * 4 + 4
        pads += range(off, aligned)
        off = aligned + 8  # size, stride
    off += 4 + 4  # data_offset, data sequence length
    aligned = (off - 4 + 7) // 8 * 8 + 4
    pads += range(off, aligned)
    assert aligned + 8 * n_doubles == total, "the test's layout arithmetic is wrong"
    return pads


def _scribbled(rng: np.random.Generator) -> tuple[list, list[bytes]]:
    """N diagnostics messages and their CDR payloads with random bytes in every padding byte."""
    msgs, payloads = [], []
    for k in range(N):
        rows = {label: rng.standard_normal(3) for label in c.DIAGNOSTICS_LAYOUT[1:]}
        msg = diagnostics_msg(0.01 * k, rows)
        raw = bytearray(serialize_message(msg))
        pads = _padding_offsets([d.label for d in msg.layout.dim], len(msg.data), len(raw))
        for p, v in zip(pads, rng.integers(1, 256, len(pads))):
            raw[p] = int(v)
        msgs.append(msg)
        payloads.append(bytes(raw))
    return msgs, payloads


def _decode_counting(payloads: list[bytes], monkeypatch: pytest.MonkeyPatch) -> tuple[cdr.Decoded, int]:
    """Decode ``payloads`` as one topic; also return how many times a message was parsed in
    Python (once per group of one length on the vectorised path, plus once per slow message)."""
    calls = []
    parse = cdr._parse_multiarray
    monkeypatch.setattr(cdr, "_parse_multiarray", lambda payload: calls.append(1) or parse(payload))
    length = np.array([len(p) for p in payloads], np.int64)
    start = np.concatenate(([0], np.cumsum(length)[:-1])).astype(np.int64)
    d = cdr.decode(TYPE, b"".join(payloads), start, length)
    assert d is not None
    return d, len(calls)


def test_padding_bytes_do_not_send_diagnostics_to_the_slow_path(rng, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    from std_msgs.msg import Float64MultiArray

    msgs, payloads = _scribbled(rng)
    assert len({len(p) for p in payloads}) == 1 and len(set(payloads)) == N  # one length, all different
    assert len({p[2:4] for p in payloads}) > 1  # the encapsulation options differ too
    # rclpy ignores the padding: the scribbled payloads are the same messages
    truth = [deserialize_message(p, Float64MultiArray) for p in payloads]
    assert all(list(t.data) == list(m.data) and t.layout == m.layout for t, m in zip(truth, msgs))

    d, parses = _decode_counting(payloads, monkeypatch)
    slow = parses - 1  # one parse for the group; every other parse is a message on the slow path
    assert slow == 0, f"{slow} of {N} messages took the slow per-message path"
    assert d.slow_path == 0 and d.undecodable == 0
    assert d.index.tolist() == list(range(N))
    assert d.labels == c.DIAGNOSTICS_LAYOUT
    expected = np.array([t.data.tolist() for t in truth])
    assert np.array_equal(d.values, expected)  # bit for bit
    assert d.stamps_ns.tolist() == [round(0.01 * k * 1e9) for k in range(N)]


def test_another_layout_of_the_same_length_is_still_parsed_on_its_own(rng, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """Masking the padding must not merge layouts: a label changed in one character (same
    length) is a different layout and takes the slow path, with its own values."""
    from std_msgs.msg import Float64MultiArray

    _, payloads = _scribbled(rng)
    msg = diagnostics_msg(5.0, {label: rng.standard_normal(3) for label in c.DIAGNOSTICS_LAYOUT[1:]})
    msg.layout = copy.deepcopy(msg.layout)  # the encoder shares one layout among its messages: changed here, every later one would carry it
    msg.layout.dim[1].label = "axiz"
    payloads.insert(7, serialize_message(msg))
    d, parses = _decode_counting(payloads, monkeypatch)
    assert parses - 1 == 1 and d.slow_path == 1 and d.undecodable == 0
    assert np.array_equal(d.values[7], np.asarray(msg.data))
    truth = np.array([deserialize_message(p, Float64MultiArray).data.tolist() for p in payloads])
    assert np.array_equal(d.values, truth)


def test_a_bag_of_scribbled_diagnostics_reads_as_rclpy_deserialises(tmp_path: Path, rng) -> None:  # type: ignore[no-untyped-def]
    from std_msgs.msg import Float64MultiArray

    _, payloads = _scribbled(rng)
    path = tmp_path / "d.mcap"
    with open(path, "wb") as f:
        w = Writer(f, chunk_size=4096, compression=CompressionType.ZSTD)
        w.start(profile="ros2", library="tests")
        ch = w.register_channel(c.CONTROLLER_DIAGNOSTICS.name, "cdr", w.register_schema(TYPE, "ros2msg", schema_text(TYPE).encode()))
        for k, p in enumerate(payloads):
            w.add_message(ch, log_time=k * 10_000_000, data=p, publish_time=k * 10_000_000)
        w.finish()
    bag = read_bag(path)
    assert bag.undecodable == {} and bag.diagnostics_labels == c.DIAGNOSTICS_LAYOUT
    s = bag.series[c.CONTROLLER_DIAGNOSTICS.name]
    assert np.array_equal(s.values, np.array([deserialize_message(p, Float64MultiArray).data.tolist() for p in payloads]))


def test_time_references_decode_their_epoch_exactly_and_say_which_name_no_sensor() -> None:
    """``state/attitude_epoch`` (``sensor_msgs/TimeReference``): the header stamp, ``time_ref`` as
    seconds and nanoseconds (a wall-clock epoch exactly), whether ``source`` names a sensor (the
    "no data" sample names none), the frame ids seen, rows of any frame-id length, as rclpy wrote them."""
    from rclpy.serialization import serialize_message

    from sappc.bag.cdr import decode
    from sappc_msgs_py import contract as c
    from sappc_msgs_py.convert import epoch_msg, no_data_msg, ns_to_stamp

    msgs = [epoch_msg(1_795_000_000_123_456_789 + k, ns_to_stamp(5_000_000_000 + k), c.STATE_ATTITUDE_EPOCH) for k in range(3)]
    msgs[1].header.frame_id = "body_2"  # another length: another group, another offset of time_ref
    msgs.append(no_data_msg(c.STATE_ATTITUDE_EPOCH, 7.0))
    data = [serialize_message(m) for m in msgs]
    start = np.cumsum([0] + [len(d) for d in data[:-1]])
    d = decode("sensor_msgs/msg/TimeReference", b"".join(data), start, np.array([len(b) for b in data]))
    assert d is not None and d.undecodable == 0 and d.index.tolist() == [0, 1, 2, 3]
    assert d.stamps_ns.tolist() == [5_000_000_000, 5_000_000_001, 5_000_000_002, 7_000_000_000]
    assert [int(s) * 1_000_000_000 + int(n) for s, n in d.values[:3, :2]] == [1_795_000_000_123_456_789 + k for k in range(3)]
    assert d.values[:, 2].tolist() == [1.0, 1.0, 1.0, 0.0] and d.frame_ids == ("body", "body_2")


def test_frame_ids_of_one_length_are_each_found_and_one_frame_is_found_once() -> None:
    """The frame ids of a stamped topic's rows of one frame-id length: every distinct one (the sort's
    path), or the one they all share (the path that skips the sort), the same set either way."""
    from geometry_msgs.msg import Vector3Stamped
    from rclpy.serialization import serialize_message

    from sappc.bag.cdr import decode

    def frames(ids: list[str]) -> tuple[str, ...]:
        msgs = []
        for k, frame in enumerate(ids):
            m = Vector3Stamped()
            m.header.frame_id = frame
            m.header.stamp.nanosec = k
            m.vector.x = float(k)
            msgs.append(m)
        data = [serialize_message(m) for m in msgs]
        start = np.cumsum([0] + [len(b) for b in data[:-1]])
        d = decode("geometry_msgs/msg/Vector3Stamped", b"".join(data), start, np.array([len(b) for b in data]))
        assert d is not None and d.undecodable == 0 and d.values[:, 0].tolist() == [float(k) for k in range(len(ids))]
        return d.frame_ids

    assert frames(["ab", "cd", "ab", "ef"]) == ("ab", "cd", "ef")
    assert frames(["body"] * 5) == ("body",)
    assert frames(["ab", "ab", "body", "cd"]) == ("ab", "body", "cd")

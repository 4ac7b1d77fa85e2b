"""The bag writer's rosbag2 layout, ``sappc repair`` and the lockstep recorder's closing sort
(:mod:`sappc.bag.rosbag2`), on bags written here as the recorder writes them (the ``mcap``
package's writer, chunks flushed as it goes; a killed recording is the file as it stood, cut
inside the chunk being written).

What a user relies on: a repaired bag is read whole by rosbags (through ``metadata.yaml``), by
mcap's indexed reader (summary and footer) and by the project's reader, with every message the
killed recorder had flushed, unchanged and in the order written, and counts, times and the
run's files in ``metadata.yaml``; a complete bag is left as it is; and a sorted bag is in
(stamp, topic, arrival on the topic) order whatever order its messages arrived in."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import pytest
import yaml
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer
from rclpy.qos import DurabilityPolicy, HistoryPolicy, LivelinessPolicy, ReliabilityPolicy
from rclpy.serialization import serialize_message

from sappc.bag.errors import BagError
from sappc.bag.read import read_bag
from sappc.bag.rosbag2 import BAG_METADATA, bag_metadata, offered_qos_v9, repair, sort_by_log_time, write_bag_metadata
from sappc_msgs_py import contract as c
from sappc_msgs_py.convert import quaternion_msg, torque_msg, vector3_msg
from sappc_msgs_py.schemas import schema_text, type_hash

NS = 1_000_000_000
#: The recorder's chunk size is 256 KiB; these bags are flushed by hand, so a chunk never fills.
CHUNK_BYTES = 1 << 20
#: The recorded topics, in the recorder's (channel) order: rate before attitude, so that the
#: channel order is not the topics' alphabetical order; the torque channel gets no message.
TOPICS = (c.STATE_RATE, c.STATE_ATTITUDE, c.CONTROL_TORQUE)
SCENARIO_TEXT = "duration_s: 2.0\n"


@dataclass(frozen=True)
class Sent:
    """A message as the recorder wrote it."""

    topic: str
    log_time: int
    sequence: int
    data: bytes


def _data(topic: c.Topic, stamp_ns: int) -> bytes:
    t = stamp_ns / NS
    if topic is c.STATE_ATTITUDE:
        return bytes(serialize_message(quaternion_msg([0.0, 0.0, 0.0, 1.0], t, topic)))
    if topic is c.CONTROL_TORQUE:
        return bytes(serialize_message(torque_msg([0.0, 0.0, 0.0], t)))
    return bytes(serialize_message(vector3_msg([stamp_ns / NS, 0.0, 0.0], t, topic)))


class Recording:
    """A bag directory written as the recorder writes it: ``metadata.yaml`` with the topics at the
    start, the run's scenario as a metadata record, the channels flushed at once, messages with
    their stamps as log and publish times and their arrival count on the topic as sequence, chunks
    flushed by :meth:`flush`."""

    def __init__(self, bag_dir: Path, compression: CompressionType = CompressionType.ZSTD) -> None:
        bag_dir.mkdir()
        self.dir = bag_dir
        self.path = bag_dir / f"{bag_dir.name}_0.mcap"
        self._file = self.path.open("wb")
        self.writer = Writer(self._file, chunk_size=CHUNK_BYTES, compression=compression)
        self.writer.start(profile="ros2", library="tests/test_rosbag2")
        self.channels: dict[str, int] = {}
        for topic in TOPICS:
            sid = self.writer.register_schema(topic.type_name, "ros2msg", schema_text(topic.type_name).encode())
            self.channels[f"/{topic.name}"] = self.writer.register_channel(
                f"/{topic.name}", "cdr", sid, {"offered_qos_profiles": yaml.safe_dump(offered_qos_v9(), sort_keys=False),
                                                "topic_type_hash": type_hash(topic.type_name)})
        self.writer.add_metadata("sappc/scenario.yaml", {"text": SCENARIO_TEXT})
        self.topics = [(f"/{t.name}", t.type_name) for t in TOPICS]
        write_bag_metadata(bag_dir, bag_metadata(self.path.name, self.topics, {n: 0 for n, _ in self.topics}, 0, 0,
                                                 {"sappc/scenario.yaml": "scenario.yaml"}))
        self.metadata_at_start = (bag_dir / BAG_METADATA).read_text()
        self.sent: list[Sent] = []
        self._arrivals: dict[str, int] = {}
        self.flush()  # as the recorder does once its channels are registered (mcap writes no chunk without a message)

    def add(self, topic: c.Topic, stamp_ns: int) -> Sent:
        name = f"/{topic.name}"
        self._arrivals[name] = self._arrivals.get(name, 0) + 1
        m = Sent(name, stamp_ns, self._arrivals[name], _data(topic, stamp_ns))
        self.writer.add_message(self.channels[name], log_time=stamp_ns, data=m.data, publish_time=stamp_ns, sequence=m.sequence)
        self.sent.append(m)
        return m

    def flush(self) -> None:
        self.writer.flush()
        self._file.flush()

    def killed(self, *, torn_tail: list[tuple[c.Topic, int]]) -> list[Sent]:
        """The recorder killed while writing ``torn_tail``: the file ends half-way through that
        chunk; the messages flushed before it are returned."""
        self.flush()
        kept = list(self.sent)
        size = self.path.stat().st_size
        for topic, stamp in torn_tail:
            self.add(topic, stamp)
        self.flush()
        self._file.close()
        os.truncate(self.path, size + (self.path.stat().st_size - size) // 2)
        return kept

    def finish(self) -> list[Sent]:
        """Closed as the recorder closes a bag (with its ``rosbag2`` metadata record)."""
        meta = bag_metadata(self.path.name, self.topics, self.counts(), min((m.log_time for m in self.sent), default=0),
                            max((m.log_time for m in self.sent), default=0), {"sappc/scenario.yaml": "scenario.yaml"})
        self.writer.add_metadata("rosbag2", {"serialized_metadata": yaml.safe_dump(meta["rosbag2_bagfile_information"], sort_keys=False)})
        self.writer.finish()
        self._file.close()
        write_bag_metadata(self.dir, meta)
        return list(self.sent)

    def counts(self) -> dict[str, int]:
        return {name: sum(m.topic == name for m in self.sent) for name, _ in self.topics}


def _in_file(path: Path) -> list[Sent]:
    """The messages of a complete MCAP file, in file order, through mcap's indexed reader (it
    needs the summary and the footer)."""
    with path.open("rb") as f:
        reader = make_reader(f)
        assert reader.get_summary() is not None
        out = []
        for _, channel, m in reader.iter_messages(log_time_order=False):
            assert m.publish_time == m.log_time
            out.append(Sent(channel.topic, m.log_time, m.sequence, m.data))
        return out


def _metadata_records(path: Path) -> list[tuple[str, dict[str, str]]]:
    with path.open("rb") as f:
        return [(m.name, dict(m.metadata)) for m in make_reader(f).iter_metadata()]


def _rosbags_counts(bag_dir: Path) -> dict[str, int]:
    """What rosbags reads, opening the bag through its ``metadata.yaml`` (every message decoded)."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    counts: dict[str, int] = {}
    with AnyReader([bag_dir], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        for conn, _, raw in reader.messages():
            reader.deserialize(raw, conn.msgtype)
            counts[conn.topic] = counts.get(conn.topic, 0) + 1
    return counts


def _info(bag_dir: Path) -> dict:  # type: ignore[type-arg]
    return yaml.safe_load((bag_dir / BAG_METADATA).read_text())["rosbag2_bagfile_information"]


def _two_flushed_chunks(rec: Recording) -> list[Sent]:
    """Two chunks flushed (stamps out of order: the first and last written are neither the
    earliest nor the latest), then killed inside a third."""
    for stamp in (20, 10, 30):
        rec.add(c.STATE_RATE, stamp * NS // 100)
    rec.add(c.STATE_ATTITUDE, 5 * NS // 100)
    rec.flush()
    rec.add(c.STATE_ATTITUDE, 40 * NS // 100)
    rec.add(c.STATE_RATE, 25 * NS // 100)
    return rec.killed(torn_tail=[(c.STATE_RATE, 50 * NS // 100), (c.STATE_ATTITUDE, 1 * NS // 100), (c.STATE_RATE, 60 * NS // 100)])


def test_repair_of_a_killed_recording_keeps_every_flushed_message_and_every_reader_reads_it(tmp_path: Path) -> None:
    rec = Recording(tmp_path / "bag")
    kept = _two_flushed_chunks(rec)
    assert read_bag(rec.dir).truncated is not None  # killed: no summary, no footer
    r = repair(rec.dir)
    assert (r.path, r.was_complete, r.messages) == (rec.path, False, 6) and r.stopped_at is not None
    assert r.counts == {"/state/rate": 4, "/state/attitude": 2, "/control/torque": 0}
    assert (r.first_ns, r.last_ns) == (5 * NS // 100, 40 * NS // 100)  # the earliest and latest stamps, not the first and last written
    assert _in_file(rec.path) == kept  # unchanged, in the order written
    assert _rosbags_counts(rec.dir) == {"/state/rate": 4, "/state/attitude": 2}
    assert read_bag(rec.dir).truncated is None
    info = _info(rec.dir)
    assert info["message_count"] == 6 and info["relative_file_paths"] == [rec.path.name] and info["version"] == 9
    assert info["starting_time"] == {"nanoseconds_since_epoch": 5 * NS // 100} and info["duration"] == {"nanoseconds": 35 * NS // 100}
    assert info["files"] == [{"path": rec.path.name, "starting_time": {"nanoseconds_since_epoch": 5 * NS // 100},
                              "duration": {"nanoseconds": 35 * NS // 100}, "message_count": 6}]
    assert [(t["topic_metadata"]["name"], t["topic_metadata"]["type"], t["message_count"]) for t in info["topics_with_message_count"]] == [
        ("/state/rate", c.STATE_RATE.type_name, 4), ("/state/attitude", c.STATE_ATTITUDE.type_name, 2),
        ("/control/torque", c.CONTROL_TORQUE.type_name, 0)]
    assert info["custom_data"] == {"sappc/scenario.yaml": "scenario.yaml"}  # the run's files, as the recorder lists them
    records = _metadata_records(rec.path)
    assert records[0] == ("sappc/scenario.yaml", {"text": SCENARIO_TEXT})
    assert [n for n, _ in records] == ["sappc/scenario.yaml", "rosbag2"]  # and the record the recorder writes when it closes a bag
    assert yaml.safe_load(records[1][1]["serialized_metadata"]) == info
    assert records[1][1]["serialized_metadata"] == yaml.safe_dump(info, sort_keys=False)  # one document: metadata.yaml's words and order


def test_a_recording_killed_after_its_last_flush_is_repaired_to_the_bag_its_close_writes(tmp_path: Path) -> None:
    """Killed once every message was flushed: the repaired file holds the messages and the metadata
    records of the same recording closed normally, the closing rosbag2 record's text byte for byte,
    and the same metadata.yaml."""
    bags = []
    for name in ("closed", "killed"):
        (tmp_path / name).mkdir()
        rec = Recording(tmp_path / name / "bag")
        for stamp in (3, 1, 2):
            rec.add(c.STATE_RATE, stamp * NS)
        rec.add(c.STATE_ATTITUDE, 2 * NS)
        bags.append(rec)
    closed, killed = bags
    closed.finish()
    killed.killed(torn_tail=[])
    r = repair(killed.dir)
    assert not r.was_complete and r.messages == 4
    assert _in_file(killed.path) == _in_file(closed.path)
    assert _metadata_records(killed.path) == _metadata_records(closed.path)
    assert (killed.dir / BAG_METADATA).read_text() == (closed.dir / BAG_METADATA).read_text()


def test_a_killed_recording_cut_anywhere_is_repaired_to_what_was_flushed_before_the_cut(tmp_path: Path) -> None:
    """Four chunks of three messages, the file cut at every 97th byte after the first chunk: each
    repair keeps the messages of every chunk whole before the cut, unchanged and in order, whatever
    record the cut falls in (a chunk, or the message indexes after it)."""
    rec = Recording(tmp_path / "bag")
    ends = []  # the file's size once each chunk is flushed
    for k in range(4):
        for i in range(3):
            rec.add(c.STATE_RATE, (3 * k + i) * NS // 100)
        rec.flush()
        ends.append(rec.path.stat().st_size)
    rec._file.close()
    data = rec.path.read_bytes()
    for cut in range(ends[0], len(data), 97):
        path = tmp_path / f"cut{cut}.mcap"
        path.write_bytes(data[:cut])
        r = repair(path)
        whole = sum(e <= cut for e in ends)  # chunks flushed with their indexes before the cut (a chunk may be whole, its index not)
        assert r.messages in (3 * whole, 3 * whole + 3) and _in_file(path) == rec.sent[: r.messages], cut


def test_repair_of_a_complete_bag_leaves_its_file_and_writes_its_metadata(tmp_path: Path) -> None:
    rec = Recording(tmp_path / "bag")
    rec.add(c.STATE_RATE, 2 * NS)
    rec.add(c.STATE_RATE, 1 * NS)
    sent = rec.finish()
    before = rec.path.read_bytes()
    (rec.dir / BAG_METADATA).unlink()
    r = repair(rec.dir)
    assert r.was_complete and r.stopped_at is None and r.messages == 2 and (r.first_ns, r.last_ns) == (1 * NS, 2 * NS)
    assert rec.path.read_bytes() == before
    assert _info(rec.dir)["message_count"] == 2 and _in_file(rec.path) == sent


@pytest.mark.parametrize("stamps", [[], [3 * NS, 1 * NS, 2 * NS]], ids=["nothing recorded", "three messages"])
def test_repair_of_a_complete_bag_writes_the_metadata_the_recorder_wrote(tmp_path: Path, stamps: list[int]) -> None:
    """Killed after the MCAP file was closed but before ``metadata.yaml`` was rewritten (it still
    holds the counts of the start): repair writes it as the recorder would have, also for a run
    that recorded nothing (the channels are in the summary)."""
    rec = Recording(tmp_path / "bag")
    for stamp in stamps:
        rec.add(c.STATE_RATE, stamp)
    rec.finish()
    written = (rec.dir / BAG_METADATA).read_text()
    (rec.dir / BAG_METADATA).write_text(rec.metadata_at_start)
    r = repair(rec.dir)
    assert r.was_complete and r.messages == len(stamps)
    assert (rec.dir / BAG_METADATA).read_text() == written


def test_repair_stops_at_a_chunk_whose_checksum_fails(tmp_path: Path) -> None:
    """A byte of the second chunk's data flipped (uncompressed chunks, where nothing but the
    checksum tells): the first chunk is kept, the corrupted one is not, and the sort refuses it."""
    rec = Recording(tmp_path / "bag", compression=CompressionType.NONE)
    first = rec.add(c.STATE_RATE, 1 * NS)
    rec.flush()
    second = rec.add(c.STATE_RATE, 2 * NS)
    kept = rec.killed(torn_tail=[])
    assert kept == [first, second]
    data = bytearray(rec.path.read_bytes())
    at = data.rindex(second.data)
    data[at + len(second.data) - 1] ^= 0xFF  # the message's last byte, inside the chunk
    rec.path.write_bytes(bytes(data))
    r = repair(rec.dir)
    assert r.messages == 1 and _in_file(rec.path) == [first] and "crc" in (r.stopped_at or "").lower()
    whole = Recording(tmp_path / "whole", compression=CompressionType.NONE)
    whole.add(c.STATE_RATE, 1 * NS)
    last = whole.add(c.STATE_RATE, 2 * NS)
    whole.finish()
    data = bytearray(whole.path.read_bytes())
    data[data.rindex(last.data) + len(last.data) - 1] ^= 0xFF
    whole.path.write_bytes(bytes(data))
    with pytest.raises(BagError, match="cannot sort an incomplete file"):
        sort_by_log_time(whole.path)
    assert whole.path.read_bytes() == data


def test_repair_keeps_a_channel_without_a_schema_without_one(tmp_path: Path) -> None:
    """MCAP allows a channel without a schema (schema id 0; not the recorder's, but a bag from
    elsewhere): repaired, it still has none, and the schema of the other channel stays its own."""
    path = tmp_path / "foreign.mcap"
    with path.open("wb") as f:
        w = Writer(f, chunk_size=CHUNK_BYTES)
        w.start(profile="", library="elsewhere")
        sid = w.register_schema(c.STATE_RATE.type_name, "ros2msg", schema_text(c.STATE_RATE.type_name).encode())
        typed = w.register_channel("/typed", "cdr", sid)
        raw = w.register_channel("/raw", "json", 0)
        w.add_message(typed, log_time=1, data=_data(c.STATE_RATE, 1), publish_time=1)
        w.add_message(raw, log_time=2, data=b"{}", publish_time=2)
        w.flush()
        f.flush()
    r = repair(path)
    assert r.messages == 2
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    by_topic = {ch.topic: ch.schema_id for ch in summary.channels.values()}
    assert by_topic["/raw"] == 0 and summary.schemas[by_topic["/typed"]].name == c.STATE_RATE.type_name


def test_repair_of_a_file_cut_after_its_rosbag2_record_keeps_one(tmp_path: Path) -> None:
    """Killed while writing the summary: the closing ``rosbag2`` record is in the file already."""
    rec = Recording(tmp_path / "bag")
    rec.add(c.STATE_RATE, 1 * NS)
    rec.finish()
    data = rec.path.read_bytes()
    rec.path.write_bytes(data[:-40])  # the footer and the closing magic lost
    r = repair(rec.dir)
    assert not r.was_complete and r.messages == 1
    assert [n for n, _ in _metadata_records(rec.path)] == ["sappc/scenario.yaml", "rosbag2"]


def test_repair_of_a_lone_mcap_file_writes_no_metadata_beside_it(tmp_path: Path) -> None:
    rec = Recording(tmp_path / "bag")
    kept = _two_flushed_chunks(rec)
    lone = tmp_path / "lone.mcap"
    rec.path.rename(lone)
    r = repair(lone)
    assert r.path == lone and r.messages == len(kept) and _in_file(lone) == kept
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag", "lone.mcap"]  # no metadata.yaml, no temporary file left


def test_a_recording_killed_before_its_first_chunk_is_refused_as_it_holds_nothing(tmp_path: Path) -> None:
    """The channels travel in the chunks (mcap's writer writes no chunk without a message): killed
    before the first flush, the file holds no channel, and repair says so and changes nothing."""
    rec = Recording(tmp_path / "bag")
    assert rec.killed(torn_tail=[(c.STATE_RATE, 1 * NS)]) == []
    data, meta = rec.path.read_bytes(), (rec.dir / BAG_METADATA).read_text()
    with pytest.raises(BagError, match="no channel could be read"):
        repair(rec.dir)
    assert rec.path.read_bytes() == data and (rec.dir / BAG_METADATA).read_text() == meta


@pytest.mark.parametrize("content", [b"", b"\x89MC", b"\x89MCAP0\r\n", b"not a bag at all, just some text" * 3])
def test_repair_refuses_what_is_not_an_mcap_file(tmp_path: Path, content: bytes) -> None:
    path = tmp_path / "x.mcap"
    path.write_bytes(content)
    with pytest.raises(BagError, match="no channel could be read"):
        repair(path)
    assert path.read_bytes() == content  # left as it was


def test_the_offered_qos_in_metadata_is_what_the_projects_publishers_offer() -> None:
    """``ros2 bag play`` publishes with the offered QoS it reads from ``metadata.yaml``: the
    project's publishers' own (:func:`sappc_msgs_py.contract.qos_profile`), in rosbag2's layout."""
    qos = c.qos_profile()
    (offered,) = offered_qos_v9()
    assert offered["history"] == {HistoryPolicy.KEEP_LAST: "keep_last"}[qos.history] and offered["depth"] == qos.depth
    assert offered["reliability"] == {ReliabilityPolicy.RELIABLE: "reliable"}[qos.reliability]
    assert offered["durability"] == {DurabilityPolicy.VOLATILE: "volatile"}[qos.durability]
    assert offered["liveliness"] == {LivelinessPolicy.AUTOMATIC: "automatic", LivelinessPolicy.SYSTEM_DEFAULT: "automatic"}[qos.liveliness]
    infinite = {"sec": 0, "nsec": 0}  # rosbag2 writes rclpy's default (infinite) durations as zero
    assert qos.deadline.nanoseconds == qos.lifespan.nanoseconds == qos.liveliness_lease_duration.nanoseconds == 0
    assert offered["deadline"] == offered["lifespan"] == offered["liveliness_lease_duration"] == infinite
    assert offered["avoid_ros_namespace_conventions"] is qos.avoid_ros_namespace_conventions is False


def test_metadata_without_the_runs_files_has_no_custom_data(tmp_path: Path) -> None:
    meta = bag_metadata("b_0.mcap", [("/state/rate", c.STATE_RATE.type_name)], {}, 7, 3, {})["rosbag2_bagfile_information"]
    assert meta["custom_data"] is None and meta["duration"] == {"nanoseconds": 0}  # an end before the start: no negative duration
    assert meta["topics_with_message_count"][0]["message_count"] == 0 and meta["message_count"] == 0
    write_bag_metadata(tmp_path, {"rosbag2_bagfile_information": meta})
    assert [p.name for p in tmp_path.iterdir()] == [BAG_METADATA]  # written whole, its temporary file renamed


# ----------------------------------------------------------------------------- the closing sort


def _arrived_out_of_order(path: Path) -> dict[str, Sent]:
    """A complete bag whose messages arrived out of stamp order on three topics (file order a..i):
    ties on the stamp across topics and, on the torque topic, messages with equal stamp and
    sequence (a foreign bag's sequence 0: file order is all that tells them apart)."""
    rec = Recording(path)
    rate, att, torque = c.STATE_RATE, c.STATE_ATTITUDE, c.CONTROL_TORQUE
    arrivals = [("a", rate, 30), ("b", att, 10), ("c", rate, 10), ("d", att, 30), ("e", rate, 20), ("f", rate, 10), ("g", att, 10)]
    tags = {tag: rec.add(topic, stamp * NS // 100) for tag, topic, stamp in arrivals}
    for tag, payload in (("h", 1.0), ("i", 2.0)):  # sequence 0, equal stamps: told apart by their data only
        data = bytes(serialize_message(torque_msg([payload, 0.0, 0.0], 0.2)))
        rec.writer.add_message(rec.channels["/control/torque"], log_time=20 * NS // 100, data=data, publish_time=20 * NS // 100, sequence=0)
        tags[tag] = Sent("/control/torque", 20 * NS // 100, 0, data)
        rec.sent.append(tags[tag])
    rec.finish()
    return tags


@pytest.mark.parametrize("memory_bytes", [1, 2_000, None], ids=["a run per message", "runs of a few messages", "one run"])
def test_the_sort_orders_by_stamp_then_topic_then_arrival_on_the_topic(tmp_path: Path, memory_bytes: int | None) -> None:
    """The recorder's closing sort: stamp first; at equal stamps the topics in the recorder's
    channel order (rate before attitude: not alphabetical); on one topic at one stamp, the order of
    arrival; equal in all three, the order in the file.  However many runs the bounded sort cuts
    the bag into, the same file."""
    tags = _arrived_out_of_order(tmp_path / "bag")
    path = tmp_path / "bag" / "bag_0.mcap"
    before = _metadata_records(path)
    kwargs = {} if memory_bytes is None else {"memory_bytes": memory_bytes}
    assert sort_by_log_time(path, chunk_size=CHUNK_BYTES, library="tests/test_rosbag2", **kwargs) == 9
    assert [next(t for t, m in tags.items() if m == s) for s in _in_file(path)] == list("cfbgehiad")
    assert _metadata_records(path) == before and _rosbags_counts(tmp_path / "bag") == {"/state/rate": 4, "/state/attitude": 3,
                                                                                         "/control/torque": 2}
    assert not [p for p in (tmp_path / "bag").iterdir() if p.name.startswith(".")]  # no run file left
    if memory_bytes is None:
        reference = path.read_bytes()
        (tmp_path / "again").mkdir()
        _arrived_out_of_order(tmp_path / "again" / "bag")
        again = tmp_path / "again" / "bag" / "bag_0.mcap"
        sort_by_log_time(again, chunk_size=CHUNK_BYTES, library="tests/test_rosbag2", memory_bytes=1)
        assert again.read_bytes() == reference  # one run or one per message: the same bytes
        with again.open("rb") as f:
            assert make_reader(f).get_header().library == "tests/test_rosbag2"


def test_the_default_sort_of_a_long_bag_stays_within_the_recorders_memory_budget(tmp_path: Path) -> None:
    """The closing sort's default budget (issue 25: the recorder within 200 MB): a bag of 6,000
    messages (a minute of one topic at 100 Hz) is sorted holding a small fraction of it, whatever
    its length would be; the sort cannot trade memory for temporary files without bound."""
    import tracemalloc

    rec = Recording(tmp_path / "bag")
    for k in range(6000):
        rec.add(c.STATE_RATE, (6000 - k) * NS // 100)  # arrived in reverse stamp order
    rec.finish()
    tracemalloc.start()
    try:
        assert sort_by_log_time(rec.path) == 6000
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 200 * 1024 * 1024 // 4, peak
    assert [m.log_time for m in _in_file(rec.path)] == [k * NS // 100 for k in range(1, 6001)]

"""The recorder node in-process (issue 25, defect 7): it takes messages on the executor's thread
and writes them on its own, so a write that stalls (a chunk being compressed, a slow disk) never
stops the executor; and it subscribes to ``/clock``, which the plant's start waits for, only once
it has matched the publishers it was told to expect, on its own side of the match."""

from __future__ import annotations

import math

import threading
import time

import pytest
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter

from gnc_common.validation import ConfigError
from sappc.bag.read import read_bag
from sappc_msgs_py import contract as c
from sappc_msgs_py.convert import vector3_msg

#: Longest wait for a condition [s] (discovery inside one process: milliseconds).
DEADLINE_S = 20.0
#: Timer ticks another node must get while the writer is stalled: the executor is not blocked.
TICKS_WHILE_STALLED = 20
#: Period of that timer [s].
TICK_PERIOD_S = 0.005


def _spin_until(executor: SingleThreadedExecutor, condition, what: str) -> None:  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + DEADLINE_S
    while not condition():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        executor.spin_once(timeout_sec=0.01)


def _stalled_recorder(ros_context, tmp_path):  # type: ignore[no-untyped-def]
    """A recorder whose writer thread stalls on its first message until ``release`` is set, beside a
    node publishing ``state/rate``, both on one executor: (recorder, stalled, release, other node,
    its publisher, executor)."""
    from sappc.graph.recorder import RecorderNode

    rec = RecorderNode(context=ros_context, parameter_overrides=[Parameter("output_dir", value=str(tmp_path / "bag"))])
    stalled, release = threading.Event(), threading.Event()
    add_messages = rec.writer.add_messages

    def stalling_add_messages(*args, **kwargs):  # type: ignore[no-untyped-def]
        stalled.set()
        assert release.wait(DEADLINE_S), "never released"
        return add_messages(*args, **kwargs)

    rec.writer.add_messages = stalling_add_messages  # type: ignore[method-assign]
    other = Node("other", context=ros_context)
    pub = other.create_publisher(c.STATE_RATE.msg_class, c.STATE_RATE.name, c.qos_profile())
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(rec)
    ex.add_node(other)
    return rec, stalled, release, other, pub, ex


def test_a_stalled_write_does_not_stop_the_executor(ros_context, tmp_path) -> None:  # type: ignore[no-untyped-def]
    rec, stalled, release, other, pub, ex = _stalled_recorder(ros_context, tmp_path)
    ticks: list[float] = []
    other.create_timer(TICK_PERIOD_S, lambda: ticks.append(time.monotonic()))
    try:
        _spin_until(ex, lambda: pub.get_subscription_count() >= 1, "the recorder's subscription")
        pub.publish(vector3_msg([0.0, 0.0, 0.0], 0.0, c.STATE_RATE))
        _spin_until(ex, stalled.is_set, "the first write")  # stalled with nothing behind it
        for k in (1, 2):
            pub.publish(vector3_msg([float(k), 0.0, 0.0], k * 0.01, c.STATE_RATE))
        n = len(ticks)
        # the writer is stalled in the middle of a message: the executor still runs every callback
        _spin_until(ex, lambda: len(ticks) >= n + TICKS_WHILE_STALLED and rec._handover.qsize() == 2, "timer ticks while the write stalls")
        assert stalled.is_set() and not release.is_set()
    finally:
        release.set()
    rec.drain(lambda timeout_s: ex.spin_once(timeout_sec=timeout_s))
    rec.finish()
    ex.shutdown()
    rec.destroy_node()
    other.destroy_node()
    bag = read_bag(tmp_path / "bag")
    # the writer took the second message with the third behind it: two messages taken and not yet written
    assert bag.series["/state/rate"].values[:, 0].tolist() == [0.0, 1.0, 2.0] and rec.max_backlog == 2


#: How long the writer stays stalled after the close has begun [s]: the close must wait this out.
STALL_AFTER_CLOSE_S = 0.5
#: Messages taken while the writer is stalled on the first: all behind it when the bag is closed.
BEHIND_AT_CLOSE = 50


def test_closing_while_the_writer_is_behind_waits_for_its_last_pass(ros_context, tmp_path) -> None:  # type: ignore[no-untyped-def]
    """The close hands the writer thread its end and waits for it: every message taken before the
    close is in the bag, even those the writer had not reached when the close began (a close that
    did not wait, ``join(timeout=0.0)``, lost the bag's tail)."""
    rec, stalled, release, other, pub, ex = _stalled_recorder(ros_context, tmp_path)
    timer = threading.Timer(STALL_AFTER_CLOSE_S, release.set)
    try:
        _spin_until(ex, lambda: pub.get_subscription_count() >= 1, "the recorder's subscription")
        pub.publish(vector3_msg([0.0, 0.0, 0.0], 0.0, c.STATE_RATE))
        _spin_until(ex, stalled.is_set, "the first write")
        for k in range(1, BEHIND_AT_CLOSE + 1):
            pub.publish(vector3_msg([float(k), 0.0, 0.0], k * 0.01, c.STATE_RATE))
        _spin_until(ex, lambda: rec._handover.qsize() == BEHIND_AT_CLOSE, "every message taken")
        assert not release.is_set()  # the writer is still on the first message, the others behind it
        timer.start()
        rec.finish()
        assert release.is_set(), "the close returned while its writer was still stalled"
    finally:
        release.set()
        timer.cancel()
        ex.shutdown()
        rec.destroy_node()
        other.destroy_node()
    assert read_bag(tmp_path / "bag").series["/state/rate"].values[:, 0].tolist() == [float(k) for k in range(BEHIND_AT_CLOSE + 1)]


def test_the_recorder_subscribes_to_clock_once_its_expected_publishers_are_matched(ros_context, tmp_path) -> None:  # type: ignore[no-untyped-def]
    from sappc.graph.recorder import RecorderNode

    rec = RecorderNode(context=ros_context, parameter_overrides=[Parameter("output_dir", value=str(tmp_path / "bag")),
                                                                  Parameter("expected_publishers", value=["state/rate=1"])])
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(rec)
    start = time.monotonic()
    while time.monotonic() - start < 0.3:  # 30 of the start check's periods: nothing to match yet
        ex.spin_once(timeout_sec=0.01)
    assert rec.count_subscribers(c.CLOCK.name) == 0 and rec.count_subscribers(c.STATE_RATE.name) == 1
    other = Node("plant_like", context=ros_context)
    other.create_publisher(c.STATE_RATE.msg_class, c.STATE_RATE.name, c.qos_profile())
    ex.add_node(other)
    _spin_until(ex, lambda: rec.count_subscribers(c.CLOCK.name) == 1, "the recorder's /clock subscription")
    assert rec._recorded_subs[c.STATE_RATE.name].get_publisher_count() == 1  # matched on the recorder's side first
    ex.shutdown()
    rec.finish()
    rec.destroy_node()
    other.destroy_node()
    assert "name: /clock" in (tmp_path / "bag" / "metadata.yaml").read_text()  # its channel registered at the start, as before


@pytest.mark.parametrize(("entry", "message"), [
    ("/clock=1", "expected_publishers: '/clock' must be a recorded topic other than /clock"),
    ("state/nothing=1", "expected_publishers: 'state/nothing' must be a recorded topic"),
    ("state/rate", "expected_publishers: entry 'state/rate' must be 'topic=count'"),
])
def test_a_bad_expected_publisher_is_refused_naming_it(ros_context, tmp_path, entry: str, message: str) -> None:  # type: ignore[no-untyped-def]
    from sappc.graph.recorder import RecorderNode

    with pytest.raises(ConfigError) as err:
        RecorderNode(context=ros_context, parameter_overrides=[Parameter("output_dir", value=str(tmp_path / "bag")),
                                                               Parameter("expected_publishers", value=[entry])])
    assert str(err.value).startswith(message)


# ----------------------------------------------------------------------------- what the recorder writes

NS = 1_000_000_000


def _stamped(topic, stamp_ns: int, x: float = 0.0):  # type: ignore[no-untyped-def]
    """A message of ``topic`` stamped ``stamp_ns`` to the nanosecond, carrying ``x``."""
    from rosgraph_msgs.msg import Clock

    from sappc_msgs_py.convert import quaternion_msg, torque_msg

    if topic is c.CLOCK:
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = divmod(stamp_ns, NS)
        return msg
    if topic is c.CONTROL_TORQUE:
        msg = torque_msg([x, 0.0, 0.0], 0.0)
    elif topic is c.STATE_ATTITUDE:
        msg = quaternion_msg([0.0, 0.0, 0.0, 1.0], 0.0, topic)
    else:
        msg = vector3_msg([x, 0.0, 0.0], 0.0, topic)
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, NS)
    return msg


class Driver:
    """A recorder in-process and a node publishing to it, on one executor (the test's thread)."""

    def __init__(self, ros_context, bag_dir, topics, **params) -> None:  # type: ignore[no-untyped-def]
        from sappc.graph.recorder import RecorderNode

        self.rec = RecorderNode(context=ros_context, parameter_overrides=[
            Parameter("output_dir", value=str(bag_dir)), Parameter("topics", value=[t.name for t in topics]),
            *(Parameter(k, value=v) for k, v in params.items())])
        self.node = Node("publisher", context=ros_context)
        self.pubs = {t.name: self.node.create_publisher(t.msg_class, t.name, c.qos_profile()) for t in topics}
        self.ex = SingleThreadedExecutor(context=ros_context)
        self.ex.add_node(self.rec)
        self.ex.add_node(self.node)
        for name, pub in self.pubs.items():
            _spin_until(self.ex, lambda pub=pub: pub.get_subscription_count() >= 1, f"the recorder's subscription to {name}")
        self.published = 0

    def publish(self, topic, stamp_ns: int, x: float = 0.0) -> None:  # type: ignore[no-untyped-def]
        self.pubs[topic.name].publish(_stamped(topic, stamp_ns, x))
        self.published += 1

    def written(self) -> None:
        """Spin until the writer thread has written everything published."""
        _spin_until(self.ex, lambda: sum(self.rec.counts.values()) >= self.published, "the recorder's writes")

    def close(self) -> None:
        self.written()
        self.rec.finish()
        self.ex.shutdown()
        self.rec.destroy_node()
        self.node.destroy_node()


def _messages(bag_dir) -> list[tuple[str, int, int, int]]:  # type: ignore[no-untyped-def]
    """(topic, log time, sequence, publish time) of every message, in file order (mcap's indexed reader)."""
    from mcap.reader import make_reader

    with next(bag_dir.glob("*.mcap")).open("rb") as f:
        reader = make_reader(f)
        return [(ch.topic, m.log_time, m.sequence, m.publish_time) for _, ch, m in reader.iter_messages(log_time_order=False)]


def _info(bag_dir):  # type: ignore[no-untyped-def]
    import yaml

    return yaml.safe_load((bag_dir / "metadata.yaml").read_text())["rosbag2_bagfile_information"]


def test_a_lockstep_bag_comes_out_sorted_by_stamp_then_topic_then_arrival(ros_context, tmp_path) -> None:  # type: ignore[no-untyped-def]
    """Issue 25, section 3: messages arriving out of stamp order come out ordered by their stamp,
    then by topic (the order of the recorder's ``topics``: rate before attitude, not the names'
    alphabetical order), then by arrival on the topic (the rate's two messages of 0.1 s: the one
    that arrived first, x = 1, first); a message's log and publish times are its stamp and its
    sequence its arrival count on its topic; ``/clock`` is recorded once per message."""
    bag = tmp_path / "bag"
    d = Driver(ros_context, bag, [c.STATE_RATE, c.STATE_ATTITUDE, c.CLOCK])
    start = time.monotonic()
    while time.monotonic() - start < 0.3:  # 30 start-check periods: no second /clock subscription comes
        d.ex.spin_once(timeout_sec=0.01)
    assert d.rec.count_subscribers(c.CLOCK.name) == 1
    for stamp_cs, x in ((30, 0.0), (10, 1.0), (20, 0.0), (10, 3.0)):
        d.publish(c.STATE_RATE, stamp_cs * NS // 100, x)
    for stamp_cs in (10, 30):
        d.publish(c.STATE_ATTITUDE, stamp_cs * NS // 100)
    for stamp_cs in (20, 10):
        d.publish(c.CLOCK, stamp_cs * NS // 100)
    d.close()
    cs = NS // 100
    rate, att, clock = "/state/rate", "/state/attitude", "/clock"
    assert _messages(bag) == [(t, s * cs, q, s * cs) for t, s, q in [
        (rate, 10, 2), (rate, 10, 4), (att, 10, 1), (clock, 10, 2), (rate, 20, 3), (clock, 20, 1), (rate, 30, 1), (att, 30, 2)]]
    values = read_bag(bag).series[rate].values[:, 0].tolist()
    assert values == [1.0, 3.0, 0.0, 0.0]  # the two of 0.1 s in their order of arrival
    info = _info(bag)
    assert info["starting_time"] == {"nanoseconds_since_epoch": 10 * cs} and info["duration"] == {"nanoseconds": 20 * cs}
    assert info["message_count"] == 8 and d.rec.counts == {rate: 4, att: 2, clock: 2}
    assert [(t["topic_metadata"]["name"], t["message_count"]) for t in info["topics_with_message_count"]] == [(rate, 4), (att, 2), (clock, 2)]
    from mcap.reader import make_reader
    import yaml

    with next(bag.glob("*.mcap")).open("rb") as f:
        closing = [m for m in make_reader(f).iter_metadata() if m.name == "rosbag2"]
    assert len(closing) == 1 and yaml.safe_load(closing[0].metadata["serialized_metadata"]) == info  # as rosbag2 closes a bag


def test_a_realtime_bag_is_on_wall_time_in_order_of_arrival(ros_context, tmp_path) -> None:  # type: ignore[no-untyped-def]
    """Real time: a message's log time is the wall time it was taken, the file is not sorted by
    stamp (the stamps 0.3, 0.1, 0.2 s stay in that order), and the bag starts at the first taken."""
    bag = tmp_path / "bag"
    before = time.time_ns()
    d = Driver(ros_context, bag, [c.STATE_RATE], mode="realtime")
    for stamp_cs in (30, 10, 20):
        d.publish(c.STATE_RATE, stamp_cs * NS // 100, float(stamp_cs))
    d.close()
    after = time.time_ns()
    got = _messages(bag)
    assert [q for _, _, q, _ in got] == [1, 2, 3] and read_bag(bag).series["/state/rate"].values[:, 0].tolist() == [30.0, 10.0, 20.0]
    log = [t for _, t, _, _ in got]
    assert before <= log[0] <= log[1] <= log[2] <= after and all(p == t for _, t, _, p in got)
    assert _info(bag)["starting_time"] == {"nanoseconds_since_epoch": log[0]}


@pytest.mark.parametrize("mode", ["lockstep", "realtime"])
def test_end_file_is_written_once_the_recorded_torques_span_end_after_s(ros_context, tmp_path, mode: str) -> None:  # type: ignore[no-untyped-def]
    """With an external plant (``end_after_s``): the end is the first torque stamped
    ``end_after_s`` after the first torque, within the 1 us rounding allowance of a grid time (in
    both modes by the torques' stamps, not by when they were recorded); other topics do not count;
    the file names that torque and stays as written; what follows is still recorded."""
    bag, end = tmp_path / "bag", tmp_path / "end"
    d = Driver(ros_context, bag, [c.CONTROL_TORQUE, c.STATE_RATE], mode=mode, end_after_s=1.0, end_file=str(end))
    first = 5 * NS
    d.publish(c.CONTROL_TORQUE, first)
    d.publish(c.STATE_RATE, 100 * NS)  # not a torque
    d.publish(c.CONTROL_TORQUE, first + NS - 1001)  # 1 us and 1 ns short
    d.publish(c.CONTROL_TORQUE, first + NS - 1000)  # within the allowance: the end
    _spin_until(d.ex, lambda: d.rec.end_reached, "the end")
    d.publish(c.CONTROL_TORQUE, first + 2 * NS)
    d.close()
    assert end.read_text() == f"{first + NS - 1000}\n" and d.rec.counts["/control/torque"] == 4


def test_without_end_after_s_the_recorder_never_ends_a_run(ros_context, tmp_path) -> None:  # type: ignore[no-untyped-def]
    """``end_after_s`` 0 (the default, the recorder of ``sappc run``'s own plant): torques over a
    minute mark no end."""
    d = Driver(ros_context, tmp_path / "bag", [c.CONTROL_TORQUE], end_file=str(tmp_path / "end"))
    for k in range(7):
        d.publish(c.CONTROL_TORQUE, k * 10 * NS)
    d.close()
    assert not d.rec.end_reached and not (tmp_path / "end").exists()


def test_end_after_s_without_an_end_file_only_marks_the_end(ros_context, tmp_path) -> None:  # type: ignore[no-untyped-def]
    d = Driver(ros_context, tmp_path / "bag", [c.CONTROL_TORQUE], end_after_s=0.5)
    d.publish(c.CONTROL_TORQUE, 1 * NS)
    d.publish(c.CONTROL_TORQUE, 1 * NS + NS // 2)
    d.close()
    assert d.rec.end_reached and sorted(p.name for p in tmp_path.iterdir()) == ["bag", "roslog"]


def test_the_runs_files_are_copied_into_the_bag_and_stored_in_it(ros_context, tmp_path) -> None:  # type: ignore[no-untyped-def]
    """``metadata_files`` ('' entries ignored): copied beside the MCAP file, stored as metadata
    records ``sappc/<name>`` and listed in ``metadata.yaml``'s ``custom_data``; the output
    directory may be nested; a bag that recorded nothing opens with no message and no duration."""
    from mcap.reader import make_reader

    from sappc.graph.recorder import RecorderNode

    scenario = tmp_path / "scenario.yaml"
    scenario.write_text("duration_s: 2.0\n")
    bag = tmp_path / "runs" / "one" / "bag"
    rec = RecorderNode(context=ros_context, parameter_overrides=[Parameter("output_dir", value=str(bag)),
                                                                  Parameter("metadata_files", value=[str(scenario), ""])])
    rec.finish()
    rec.destroy_node()
    assert (bag / "scenario.yaml").read_text() == "duration_s: 2.0\n"
    with next(bag.glob("*.mcap")).open("rb") as f:
        records = {m.name: dict(m.metadata) for m in make_reader(f).iter_metadata()}
    assert records["sappc/scenario.yaml"] == {"text": "duration_s: 2.0\n"}
    info = _info(bag)
    assert info["custom_data"] == {"sappc/scenario.yaml": "scenario.yaml"}
    assert info["message_count"] == 0 and info["duration"] == {"nanoseconds": 0} and info["starting_time"] == {"nanoseconds_since_epoch": 0}
    import yaml

    assert yaml.safe_load(records["rosbag2"]["serialized_metadata"]) == info  # the closing record says the same
    assert records["rosbag2"]["serialized_metadata"] == yaml.safe_dump(info, sort_keys=False)  # in metadata.yaml's words and order
    assert rec.max_backlog == 0  # no message ever waited


def test_topics_are_given_with_or_without_their_leading_slash(ros_context, tmp_path) -> None:  # type: ignore[no-untyped-def]
    from sappc.graph.recorder import RecorderNode

    rec = RecorderNode(context=ros_context, parameter_overrides=[Parameter("output_dir", value=str(tmp_path / "bag")),
                                                                  Parameter("topics", value=["/state/rate", "control/torque"])])
    assert rec.topics == [("/state/rate", c.STATE_RATE.type_name), ("/control/torque", c.CONTROL_TORQUE.type_name)]
    rec.finish()
    rec.destroy_node()


@pytest.mark.parametrize(("params", "message"), [
    ({}, "output_dir must be set"),
    ({"output_dir": "EXISTING"}, "already exists; a recorder never overwrites a bag"),
    ({"output_dir": "NEW", "topics": ["state/nothing"]}, "topics: 'state/nothing' is not a topic of the contract"),
    ({"output_dir": "NEW", "metadata_files": ["MISSING"]}, "metadata_files: MISSING is not a file"),
])
def test_a_recorder_that_cannot_record_as_asked_refuses_to_start(ros_context, tmp_path, params: dict, message: str) -> None:  # type: ignore[no-untyped-def,type-arg]
    from sappc.graph.recorder import RecorderNode

    (tmp_path / "EXISTING").mkdir()
    names = {"EXISTING": str(tmp_path / "EXISTING"), "NEW": str(tmp_path / "NEW"), "MISSING": str(tmp_path / "missing.yaml")}
    overrides = [Parameter(k, value=[names.get(x, x) for x in v] if isinstance(v, list) else names[v]) for k, v in params.items()]
    with pytest.raises(ConfigError) as err:
        RecorderNode(context=ros_context, parameter_overrides=overrides)
    assert message.replace("MISSING", names["MISSING"]) in str(err.value)
    assert not (tmp_path / "NEW").exists()  # nothing created


def test_the_drain_takes_every_acknowledged_message(ros_context, tmp_path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """On SIGINT the recorder drains its queues before closing the bag: 200 messages the
    middleware has acknowledged (in the recorder's queue, none taken yet) are all in the bag.

    The drain ends after ``DRAIN_QUIET_S`` of wall time without a message: 0.3 s, which a stall of
    this test's thread between two takes could exceed on a loaded machine; 3 s here (the rule
    itself: test_the_drain_ends_after_a_quiet_time_or_at_its_limit, on a fake clock)."""
    import sappc.graph.recorder as recorder

    monkeypatch.setattr(recorder, "DRAIN_QUIET_S", 3.0)
    d = Driver(ros_context, tmp_path / "bag", [c.STATE_RATE])
    for k in range(200):
        d.publish(c.STATE_RATE, k * NS // 100, float(k))
    assert d.pubs[c.STATE_RATE.name].wait_for_all_acked()
    d.rec.drain(lambda timeout_s: d.ex.spin_once(timeout_sec=timeout_s))
    d.rec.finish()  # what the drain took, and only that
    d.ex.shutdown()
    d.rec.destroy_node()
    d.node.destroy_node()
    assert read_bag(tmp_path / "bag").series["/state/rate"].values[:, 0].tolist() == [float(k) for k in range(200)]


def test_the_bag_is_compressed(ros_context, tmp_path) -> None:  # type: ignore[no-untyped-def]
    """The recorder compresses its chunks (zstd): 2,000 samples of a rate take less room on disk
    than their raw CDR data, the index of every message and the schemas included."""
    from rclpy.serialization import serialize_message

    d = Driver(ros_context, tmp_path / "bag", [c.STATE_RATE])
    for k in range(2000):
        d.publish(c.STATE_RATE, k * NS // 100, 1e-3 * k)
    d.close()
    raw = 2000 * len(serialize_message(_stamped(c.STATE_RATE, 0)))
    assert next((tmp_path / "bag").glob("*.mcap")).stat().st_size < raw


def test_a_failing_writer_fails_the_close_naming_the_bag(ros_context, tmp_path) -> None:  # type: ignore[no-untyped-def]
    d = Driver(ros_context, tmp_path / "bag", [c.STATE_RATE])

    def broken(*args, **kwargs):  # type: ignore[no-untyped-def]
        raise OSError("No space left on device")

    d.rec.writer.add_messages = broken  # type: ignore[method-assign]
    d.publish(c.STATE_RATE, NS)
    _spin_until(d.ex, lambda: d.rec._writer_error is not None, "the writer's failure")
    with pytest.raises(RuntimeError, match=f"{tmp_path / 'bag'}: the bag writer failed: No space left on device"):
        d.rec.finish()
    d.ex.shutdown()
    d.rec.destroy_node()
    d.node.destroy_node()


class _FakeClock:
    """``time`` for the writer thread's loop: a clock the test moves."""

    def __init__(self) -> None:
        self.now = 1000.0

    def monotonic(self) -> float:
        return self.now

    def time_ns(self) -> int:
        return int(self.now * 1e9)

    def sleep(self, seconds: float) -> None:
        self.now += seconds


class _Arrivals:
    """The hand-over queue on the fake clock: each item arrives at its time; ``get`` waits for the
    next one until its timeout, moving the clock."""

    def __init__(self, clock: _FakeClock, arrivals: list[tuple[float, object]]) -> None:
        self.clock, self.arrivals = clock, list(arrivals)

    def get(self, timeout: float) -> object:
        import queue

        t, item = self.arrivals[0]
        if t > self.clock.now + timeout:
            self.clock.now += timeout
            raise queue.Empty
        self.clock.now = max(self.clock.now, t)
        self.arrivals.pop(0)
        return item

    def get_nowait(self) -> object:
        import queue

        if not self.arrivals or self.arrivals[0][0] > self.clock.now:
            raise queue.Empty
        return self.arrivals.pop(0)[1]

    def qsize(self) -> int:
        return sum(t <= self.clock.now for t, _ in self.arrivals)


def test_every_message_is_flushed_to_the_file_within_a_second_of_being_written(ros_context, tmp_path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """What a SIGKILL can lose is bounded (README: the last second): the writer thread flushes
    the MCAP file at most a second after writing any message, during a burst, after the burst
    with nothing more arriving, and for a lone message long after.  Its loop runs on a clock the
    test moves (no timing luck)."""
    import sappc.graph.recorder as recorder

    rec = recorder.RecorderNode(context=ros_context, parameter_overrides=[Parameter("output_dir", value=str(tmp_path / "bag"))])
    rec._handover.put(None)  # stop the real writer thread; its loop runs below on the fake clock
    rec._writer_thread.join()
    clock = _FakeClock()
    burst = [(1000.0 + 0.01 * k, ("state/rate", b"", 0)) for k in range(300)]  # 3 s of messages, then quiet
    arrivals = [*burst, (1010.0, ("state/rate", b"", 0)), (1020.0, None)]
    writes: list[float] = []
    flushes: list[float] = []

    class Writer:
        def flush(self) -> None:
            flushes.append(clock.now)

    real_handover, real_writer = rec._handover, rec.writer
    monkeypatch.setattr(recorder, "time", clock)
    rec._handover, rec.writer = _Arrivals(clock, arrivals), Writer()  # type: ignore[assignment]
    rec._write_batch = lambda batch: writes.extend(clock.now for _ in batch)  # type: ignore[method-assign]
    rec._write_loop()
    monkeypatch.undo()
    assert rec._writer_error is None and len(writes) == 301
    # written in passes every WRITE_PASS_PERIOD_S: at most what arrives in one period (100 Hz) waits
    assert 1 <= rec.max_backlog <= 1 + math.ceil(recorder.WRITE_PASS_PERIOD_S / 0.01)
    assert all(any(w <= f <= w + 1.0 for f in flushes) for w in writes), (writes, flushes)
    rec._handover, rec.writer = real_handover, real_writer
    rec.finish()
    rec.destroy_node()


class _DrainClock:
    """``time`` for :meth:`RecorderNode.drain`: each pass of the executor takes its whole timeout,
    and a message arrives in it while ``publishing``."""

    def __init__(self) -> None:
        self.now, self.passes = 500.0, []  # type: ignore[var-annotated]

    def monotonic(self) -> float:
        return self.now


@pytest.mark.parametrize("publishing", [False, True], ids=["quiet", "a publisher that never stops"])
def test_the_drain_ends_after_a_quiet_time_or_at_its_limit(monkeypatch, publishing: bool) -> None:  # type: ignore[no-untyped-def]
    """The drain after a signal (module constants, on a clock the test moves): it takes the queues
    in passes of a third of the quiet time (0.1 s), and ends once 0.3 s pass without a message; a
    publisher that keeps publishing is cut off after 10 s."""
    import types

    import sappc.graph.recorder as recorder

    clock = _DrainClock()
    rec = types.SimpleNamespace()
    monkeypatch.setattr(recorder, "time", clock)

    def spin_once(timeout_s: float) -> None:
        clock.passes.append(timeout_s)
        clock.now += timeout_s
        if publishing:
            rec._last_message = clock.now

    recorder.RecorderNode.drain(rec, spin_once)  # type: ignore[arg-type]
    assert all(t == pytest.approx(0.1) for t in clock.passes)
    if publishing:
        assert 10.0 <= clock.now - 500.0 < 10.1 + 1e-9, clock.now
    else:
        assert len(clock.passes) == 3 and clock.now - 500.0 == pytest.approx(0.3)

"""The recorder node in-process (issue 25, defect 7): it takes messages on the executor's thread
and writes them on its own, so a write that stalls (a chunk being compressed, a slow disk) never
stops the executor; and it subscribes to ``/clock``, which the plant's start waits for, only once
it has matched the publishers it was told to expect, on its own side of the match."""

from __future__ import annotations

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


def test_a_stalled_write_does_not_stop_the_executor(ros_context, tmp_path) -> None:  # type: ignore[no-untyped-def]
    from sappc.graph.recorder import RecorderNode

    rec = RecorderNode(context=ros_context, parameter_overrides=[Parameter("output_dir", value=str(tmp_path / "bag"))])
    stalled, release = threading.Event(), threading.Event()
    add_message = rec.writer.add_message

    def stalling_add_message(*args, **kwargs):  # type: ignore[no-untyped-def]
        stalled.set()
        assert release.wait(DEADLINE_S), "never released"
        return add_message(*args, **kwargs)

    rec.writer.add_message = stalling_add_message  # type: ignore[method-assign]
    other = Node("other", context=ros_context)
    pub = other.create_publisher(c.STATE_RATE.msg_class, c.STATE_RATE.name, c.qos_profile())
    ticks: list[float] = []
    other.create_timer(TICK_PERIOD_S, lambda: ticks.append(time.monotonic()))
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(rec)
    ex.add_node(other)
    try:
        _spin_until(ex, lambda: pub.get_subscription_count() >= 1, "the recorder's subscription")
        for k in range(3):
            pub.publish(vector3_msg([float(k), 0.0, 0.0], k * 0.01, c.STATE_RATE))
        _spin_until(ex, stalled.is_set, "the first write")
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
    assert bag.series["/state/rate"].values[:, 0].tolist() == [0.0, 1.0, 2.0] and rec.max_backlog >= 2  # two waited behind the stall


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

"""The real-time frame grid (sappc_msgs_py.timeline) and the plant's frames: states stamped with
their frame's start, every elapsed frame integrated with the torque held and its own
disturbance, missed frames and frames with a stale torque counted.  The plant's timer is
cancelled and its tick called at the times of a clock the test sets (no timing luck)."""

from __future__ import annotations

import time

import numpy as np
import pytest
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter

from gnc_common.timing import LatencyStatistics
from gnc_common.validation import ConfigError
from sappc_msgs_py import contract as c
from sappc_msgs_py.convert import stamp_to_ns, torque_msg
from sappc_msgs_py.timeline import MID_FRAME_PHASE, PLANT_PHASE, StampedWindow, frame_index, period_ns
from fake_clock import FakeClock

NS = 1_000_000_000
DT_NS = 10_000_000
DEADLINE_S = 20.0


def test_frame_index_keeps_a_tick_in_its_frame_within_half_a_frame() -> None:
    f = 170_000_000_000  # frames of 10 ms since the epoch
    start = f * DT_NS
    assert frame_index(start, DT_NS, PLANT_PHASE) == f
    assert frame_index(start + DT_NS // 2 - 1, DT_NS, PLANT_PHASE) == f  # late by just under half a frame
    assert frame_index(start + DT_NS // 2, DT_NS, PLANT_PHASE) == f + 1
    assert frame_index(start - DT_NS // 2, DT_NS, PLANT_PHASE) == f  # early by half a frame
    mid = start + DT_NS // 2
    assert frame_index(mid, DT_NS, MID_FRAME_PHASE) == f
    assert frame_index(mid + DT_NS // 2 - 1, DT_NS, MID_FRAME_PHASE) == f
    assert frame_index(mid - DT_NS // 2, DT_NS, MID_FRAME_PHASE) == f


def test_period_ns_rounds_to_the_nanosecond_and_refuses_what_is_not_a_period() -> None:
    assert period_ns(0.01) == 10_000_000 and period_ns(1e-6) == 1_000 and period_ns(0.0123456789) == 12_345_679
    assert period_ns(2.5) == 2_500_000_000 and period_ns(60) == 60 * NS  # long periods to the nanosecond too
    for bad in (0.0, -0.01, 5e-7, float("inf"), float("nan")):
        with pytest.raises(ConfigError, match="control_period_s"):
            period_ns(bad)


def test_stamped_window_gives_the_value_of_a_stamp_or_the_newest_earlier_one() -> None:
    w: StampedWindow[str] = StampedWindow(3)
    assert w.at_or_before(10) is None and w.newest_ns is None
    for stamp in (10, 20, 30):
        w.add(stamp, f"v{stamp}")
    w.add(20, "again")  # not after the newest: dropped
    assert w.at_or_before(20) == (20, "v20") and w.at_or_before(29) == (20, "v20") and w.at_or_before(9) is None
    w.add(40, "v40")  # the oldest forgotten beyond 3
    assert len(w) == 3 and w.at_or_before(15) is None and w.at_or_before(45) == (40, "v40") and w.newest_ns == 40
    w.add(40, "again")  # the newest stamp again: the first value of a stamp is kept
    assert w.at_or_before(40) == (40, "v40") and len(w) == 3


def test_a_window_of_one_holds_the_newest_value_and_a_window_of_none_is_refused() -> None:
    one: StampedWindow[str] = StampedWindow(1)
    one.add(10, "a")
    one.add(20, "b")
    assert len(one) == 1 and one.at_or_before(25) == (20, "b") and one.at_or_before(15) is None
    with pytest.raises(ValueError, match="size must be >= 1, got 0"):
        StampedWindow(0)


def test_latency_statistics_count_steps_strictly_later_than_the_deadline() -> None:
    stats = LatencyStatistics(0.01)
    for ns in (700_000, 10_000_000, 10_000_001):
        stats.add(ns)
    s = stats.summary()
    assert s["steps"] == 3 and s["late_steps"] == 1 and s["latency_max_ms"] == 10.000001
    assert LatencyStatistics(0.01).summary() == {"steps": 0}



def test_the_plant_integrates_every_elapsed_frame_and_counts_missed_frames_and_stale_torques(ros_context, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    from spacecraft_sim.plant_node import PlantNode

    plant = PlantNode(context=ros_context, parameter_overrides=[
        Parameter("mode", value="realtime"), Parameter("duration_s", value=0.0), Parameter("use_disturbance_topic", value=True),
        Parameter("omega_BN_B0_rad_s", value=[0.01, -0.02, 0.03])])
    for timer in plant._frame_timers:
        timer.cancel()
    f0 = 170_000_000_000
    clock = FakeClock(f0 * DT_NS + 300_000)  # 0.3 ms into frame f0
    monkeypatch.setattr(plant, "get_clock", lambda: clock)
    probe = Node("probe", context=ros_context)
    qos = c.qos_profile()
    pub_torque = probe.create_publisher(c.CONTROL_TORQUE.msg_class, c.CONTROL_TORQUE.name, qos)
    pub_dist = probe.create_publisher(c.DISTURBANCE_TORQUE.msg_class, c.DISTURBANCE_TORQUE.name, qos)
    states: list[int] = []
    probe.create_subscription(c.STATE_ATTITUDE.msg_class, c.STATE_ATTITUDE.name, lambda m: states.append(stamp_to_ns(m.header.stamp)), qos)
    probe.create_subscription(c.STATE_RATE.msg_class, c.STATE_RATE.name, lambda m: None, qos)
    ex = SingleThreadedExecutor(context=ros_context)
    for n in (plant, probe):
        ex.add_node(n)

    def spin_until(condition, what: str) -> None:  # type: ignore[no-untyped-def]
        deadline = time.monotonic() + DEADLINE_S
        while not condition():
            assert time.monotonic() < deadline, f"timed out waiting for {what}"
            ex.spin_once(timeout_sec=0.02)

    try:
        spin_until(lambda: not plant._not_ready() and pub_dist.get_subscription_count() and pub_torque.get_subscription_count(), "matching")
        disturbance = {f0 + g: np.array([1e-3 * g, -2e-3, 5e-4 * g]) for g in range(8)}
        for frame, d in disturbance.items():  # published ahead, each stamped with its own frame
            m = torque_msg(d, 0.0, c.DISTURBANCE_TORQUE)
            m.header.stamp.sec, m.header.stamp.nanosec = divmod(frame * DT_NS, NS)
            pub_dist.publish(m)
        spin_until(lambda: plant._disturbances.newest_ns == (f0 + 7) * DT_NS, "the disturbances ahead")

        def torque(frame: int, value: list[float]) -> None:
            m = torque_msg(value, 0.0, c.CONTROL_TORQUE)
            m.header.stamp.sec, m.header.stamp.nanosec = divmod(frame * DT_NS, NS)
            pub_torque.publish(m)
            spin_until(lambda: plant._torque_ns == frame * DT_NS, f"the torque of frame {frame}")

        x = plant.x.copy()
        body, dt = plant.body, plant.dt
        plant._realtime_tick()  # frame f0: the first state, nothing integrated
        spin_until(lambda: len(states) == 1, "the state of f0")
        assert states == [f0 * DT_NS] and plant.stale_torque_frames == 0 and plant.missed_frames == 0
        torque(f0, [0.1, -0.2, 0.3])  # the answer to f0, in time
        clock.ns = (f0 + 1) * DT_NS + 200_000
        plant._realtime_tick()
        x = body.propagate(x, np.array([[0.1, -0.2, 0.3]]) + disturbance[f0], dt, 1)
        plant._realtime_tick()  # a second tick in the same frame: nothing
        clock.ns = (f0 + 2) * DT_NS + 4_900_000  # late, but within half a frame: frame f0 + 2, no answer to f0 + 1
        plant._realtime_tick()
        x = body.propagate(x, np.array([[0.1, -0.2, 0.3]]) + disturbance[f0 + 1], dt, 1)
        assert plant.stale_torque_frames == 1 and plant.missed_frames == 0
        torque(f0 + 2, [-0.05, 0.0, 0.05])
        clock.ns = (f0 + 5) * DT_NS + 100_000  # frames f0 + 3 and f0 + 4 had no tick
        plant._realtime_tick()
        for g in (2, 3, 4):  # each with the torque held and its own disturbance
            x = body.propagate(x, np.array([[-0.05, 0.0, 0.05]]) + disturbance[f0 + g], dt, 1)
        spin_until(lambda: len(states) == 4, "the states")
        assert states == [(f0 + g) * DT_NS for g in (0, 1, 2, 5)]
        assert plant.missed_frames == 2 and plant.stale_torque_frames == 3  # f0 + 1, f0 + 3, f0 + 4
        assert np.array_equal(plant.x, x) and plant.k == 5
    finally:
        ex.shutdown()
        probe.destroy_node()
        plant.destroy_node()


def test_the_injector_places_fault_windows_in_the_runs_time_in_both_modes(ros_context, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """Fault windows are in the run's time: in lockstep a stamp is that time; in real time the
    stamps are epoch times of frames, and the run's time is counted from the frame of the
    injector's sample 0 (the frame after its first tick), so a fault at 20 s starts 20 s into the
    run, not in 1970."""
    from spacecraft_sim.disturbance import InjectorNode

    rt = InjectorNode(context=ros_context, parameter_overrides=[Parameter("mode", value="realtime")])
    for timer in rt._frame_timers:
        timer.cancel()
    f = 170_000_000_000
    clock = FakeClock(f * DT_NS + DT_NS // 2)  # mid-frame f
    monkeypatch.setattr(rt, "get_clock", lambda: clock)
    stamp = (f + 1 + 2000) * DT_NS  # 2000 frames after sample 0's frame (f + 1)
    assert rt._run_time_s(stamp) == 20.0 and rt._frame0 == f + 1
    clock.ns += 50 * DT_NS  # later calls keep the origin
    assert rt._run_time_s(stamp) == 20.0
    lock = InjectorNode("injector2", context=ros_context)
    assert lock._run_time_s(20 * NS) == 20.0
    rt.destroy_node()
    lock.destroy_node()


def test_the_reference_publishes_each_frames_sample_a_frame_and_a_half_ahead(ros_context, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """The module's timing (sappc_msgs_py.timeline): a publisher ahead ticks mid-frame and sends the
    samples through two frames ahead, so the sample of frame g is out at the middle of frame g - 2,
    a frame and a half before the plant's state of g; each stamped with its own frame, none twice."""
    from spacecraft_sim.reference import ReferenceNode

    ref = ReferenceNode(context=ros_context, parameter_overrides=[Parameter("mode", value="realtime")])
    try:
        for timer in ref._frame_timers:
            timer.cancel()
        f = 170_000_000_000
        clock = FakeClock(f * DT_NS + DT_NS // 2)  # mid-frame f
        monkeypatch.setattr(ref, "get_clock", lambda: clock)
        monkeypatch.setattr(ref._gate, "open", lambda: True)  # matched: this test has no subscribers
        sent: list[tuple[int, int]] = []
        monkeypatch.setattr(ref, "_publish", lambda k, stamp: sent.append((k, stamp_to_ns(stamp))))
        ref._on_timer()  # sample 0 is frame f + 1's; through frame f + 2
        assert sent == [(0, (f + 1) * DT_NS), (1, (f + 2) * DT_NS)]
        clock.ns += DT_NS  # mid-frame f + 1: frame f + 3's sample only
        ref._on_timer()
        assert sent[2:] == [(2, (f + 3) * DT_NS)]
        clock.ns += 3 * DT_NS  # two ticks missed: made up, through frame f + 6
        ref._on_timer()
        assert sent[3:] == [(k, (f + 1 + k) * DT_NS) for k in (3, 4, 5)]
    finally:
        ref.destroy_node()

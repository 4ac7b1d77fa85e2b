"""The real-time frame grid (sappc_msgs_py.timeline) and the plant's frames: states stamped with
their frame's start, sample 0 published ahead of its frame, every elapsed frame integrated with
the torque held and its own disturbance (the states of missed ticks published late), missed
frames and frames with a stale torque or disturbance counted, the end at the tick after the
last frame with nothing published past it; the reference and the injector on the plant's frames.  The plant's timer is
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
from sappc_msgs_py.timeline import AHEAD_FRAMES, MID_FRAME_PHASE, PLANT_PHASE, START_LEAD_FRAMES, StampedWindow, frame_index, period_ns
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



def _realtime_plant(ros_context, monkeypatch, clock_ns: int, duration_s: float):  # type: ignore[no-untyped-def]
    """A real-time plant whose timer is cancelled and whose clock the test sets, with a probe that
    publishes its inputs and records the stamps of its states; returns (plant, probe, clock,
    states, spin_until, send(topic publisher, frame, value), executor)."""
    from spacecraft_sim.plant_node import PlantNode

    plant = PlantNode(context=ros_context, parameter_overrides=[
        Parameter("mode", value="realtime"), Parameter("duration_s", value=duration_s), Parameter("use_disturbance_topic", value=True),
        Parameter("omega_BN_B0_rad_s", value=[0.01, -0.02, 0.03])])
    for timer in plant._frame_timers:
        timer.cancel()
    clock = FakeClock(clock_ns)
    monkeypatch.setattr(plant, "get_clock", lambda: clock)
    probe = Node("probe", context=ros_context)
    qos = c.qos_profile()
    pubs = {"torque": probe.create_publisher(c.CONTROL_TORQUE.msg_class, c.CONTROL_TORQUE.name, qos),
            "disturbance": probe.create_publisher(c.DISTURBANCE_TORQUE.msg_class, c.DISTURBANCE_TORQUE.name, qos)}
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

    def send(which: str, frame: int, value) -> None:  # type: ignore[no-untyped-def]
        topic = c.CONTROL_TORQUE if which == "torque" else c.DISTURBANCE_TORQUE
        m = torque_msg(value, 0.0, topic)
        m.header.stamp.sec, m.header.stamp.nanosec = divmod(frame * DT_NS, NS)
        pubs[which].publish(m)
        if which == "torque":
            spin_until(lambda: plant._torque_ns == frame * DT_NS, f"the torque of frame {frame}")

    # the plant also waits for the probe's state subscriptions (its expected subscribers default to 1)
    spin_until(lambda: not plant._not_ready() and all(p.get_subscription_count() for p in pubs.values()), "matching")
    return plant, probe, clock, states, spin_until, send, ex


def test_the_plant_integrates_every_elapsed_frame_and_counts_missed_frames_and_stale_torques(ros_context, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    f0 = 170_000_000_000
    # the first tick, 0.3 ms into frame f0 - START_LEAD_FRAMES: sample 0, the initial state, is published for frame f0
    plant, probe, clock, states, spin_until, send, ex = _realtime_plant(ros_context, monkeypatch,
                                                                        (f0 - START_LEAD_FRAMES) * DT_NS + 300_000, 0.0)
    try:
        disturbance = {f0 + g: np.array([1e-3 * g, -2e-3, 5e-4 * g]) for g in range(8)}
        for frame, d in disturbance.items():  # published ahead, each stamped with its own frame
            send("disturbance", frame, d)
        spin_until(lambda: plant._disturbances.newest_ns == (f0 + 7) * DT_NS, "the disturbances ahead")
        x = plant.x.copy()
        body, dt = plant.body, plant.dt
        plant._realtime_tick()  # sample 0, ahead of its frame f0: nothing integrated
        spin_until(lambda: len(states) == 1, "the state of f0")
        assert states == [f0 * DT_NS] and plant.stale_torque_frames == 0 and plant.missed_frames == 0 and plant.k == 0
        clock.ns = f0 * DT_NS + 200_000
        plant._realtime_tick()  # frame f0's own tick: its state is out already
        assert len(states) == 1 and np.array_equal(plant.x, x)
        send("torque", f0, [0.1, -0.2, 0.3])  # the answer to f0, in time
        clock.ns = (f0 + 1) * DT_NS + 200_000
        plant._realtime_tick()
        x = body.propagate(x, np.array([[0.1, -0.2, 0.3]]) + disturbance[f0], dt, 1)
        plant._realtime_tick()  # a second tick in the same frame: nothing
        clock.ns = (f0 + 2) * DT_NS + 4_900_000  # late, but within half a frame: frame f0 + 2, no answer to f0 + 1
        plant._realtime_tick()
        x = body.propagate(x, np.array([[0.1, -0.2, 0.3]]) + disturbance[f0 + 1], dt, 1)
        assert plant.stale_torque_frames == 1 and plant.missed_frames == 0 and plant.first_deviating_sample == 1
        send("torque", f0 + 2, [-0.05, 0.0, 0.05])
        clock.ns = (f0 + 5) * DT_NS + 100_000  # frames f0 + 3 and f0 + 4 had no tick
        plant._realtime_tick()
        for g in (2, 3, 4):  # each with the torque held and its own disturbance
            x = body.propagate(x, np.array([[-0.05, 0.0, 0.05]]) + disturbance[f0 + g], dt, 1)
        spin_until(lambda: len(states) == 6, "the states")
        # the states of the frames without a tick are published too, late: the sensors skip no sample
        assert states == [(f0 + g) * DT_NS for g in range(6)]
        assert plant.missed_frames == 2 and plant.stale_torque_frames == 3  # f0 + 1, f0 + 3, f0 + 4
        assert np.array_equal(plant.x, x) and plant.k == 5 and plant.stale_disturbance_frames == 0
        clock.ns = (f0 + 9) * DT_NS  # frame f0 + 8 has no disturbance of its own: the one of f0 + 7 held, counted
        plant._realtime_tick()
        assert plant.stale_disturbance_frames == 1 and plant.first_deviating_sample == 1
    finally:
        ex.shutdown()
        probe.destroy_node()
        plant.destroy_node()


def test_a_realtime_plant_ends_at_the_tick_after_its_last_frame_without_publishing_past_it(ros_context, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """duration_s = 3 frames: the states of f0 .. f0 + 3, then at the next tick the node finishes,
    its timers stopped, with no state past the last frame; the torque of the last frame is
    received, not applied, and counted stale when it has not come (the controller's frame)."""
    f0 = 170_000_000_000
    plant, probe, clock, states, spin_until, send, ex = _realtime_plant(ros_context, monkeypatch,
                                                                        (f0 - START_LEAD_FRAMES) * DT_NS + 300_000, 3 * DT_NS / NS)
    try:
        for g in range(6):
            send("disturbance", f0 + g, [0.0, 0.0, 0.0])
        spin_until(lambda: plant._disturbances.newest_ns == (f0 + 5) * DT_NS, "the disturbances ahead")
        plant._realtime_tick()
        for g in range(3):
            send("torque", f0 + g, [0.01, 0.0, 0.0])
            clock.ns = (f0 + g + 1) * DT_NS + 100_000
            plant._realtime_tick()
        assert not plant.finished and plant.k == 3
        x = plant.x.copy()
        clock.ns = (f0 + 5) * DT_NS + 100_000  # the tick after the last frame (late: it skipped f0 + 4)
        plant._realtime_tick()
        spin_until(lambda: len(states) == 4, "the states")
        assert plant.finished and states == [(f0 + g) * DT_NS for g in range(4)]
        assert np.array_equal(plant.x, x)  # the last frame's torque is not applied
        assert plant.stale_torque_frames == 1 and plant.first_deviating_sample == 3  # no answer to the last state came
        assert not any(t.is_ready() or not t.is_canceled() for t in plant.timers)  # the node's timers stopped
        clock.ns += 10 * DT_NS
        plant._realtime_tick()  # a tick that ran anyway publishes nothing
        ex.spin_once(timeout_sec=0.2)
        assert len(states) == 4
    finally:
        ex.shutdown()
        probe.destroy_node()
        plant.destroy_node()


def test_the_injector_places_fault_windows_in_the_runs_time_in_both_modes(ros_context, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """Fault windows are in the run's time: in lockstep a stamp is that time; in real time the
    stamps are epoch times of frames, and the run's time is counted from the frame of the plant's
    first state (FramesAhead; the first relayed message starts it too, should it come first), so a
    fault at 20 s starts 20 s into the run, not in 1970."""
    from spacecraft_sim.disturbance import InjectorNode

    rt = InjectorNode(context=ros_context, parameter_overrides=[Parameter("mode", value="realtime")])
    for timer in rt._frame_timers:
        timer.cancel()
    f = 170_000_000_000
    clock = FakeClock((f - 5) * DT_NS)
    monkeypatch.setattr(rt, "get_clock", lambda: clock)
    assert rt.frames is not None and rt.frames.run_time_s(f * DT_NS) is None  # not started
    assert rt._run_time_s(f * DT_NS) == 0.0 and rt.frames.frame0 == f  # the first stamp seen starts the run
    stamp = (f + 2000) * DT_NS
    assert rt._run_time_s(stamp) == 20.0
    clock.ns += 50 * DT_NS
    rt.frames.start_at((f + 7) * DT_NS)  # later states keep the origin
    assert rt._run_time_s(stamp) == 20.0 and rt.frames.frame0 == f
    lock = InjectorNode("injector2", context=ros_context)
    assert lock._run_time_s(20 * NS) == 20.0
    rt.destroy_node()
    lock.destroy_node()


def test_the_reference_publishes_its_samples_on_the_plants_frames_ahead(ros_context, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """The module's timing (sappc_msgs_py.timeline, runtime.FramesAhead): nothing before the plant's
    first state; on it, samples 0 .. AHEAD_FRAMES stamped with the frames f0 .. f0 + AHEAD_FRAMES
    (f0 that state's frame); then a timer mid-frame g sends through frame g + AHEAD_FRAMES, a
    missed tick made up, none twice, none before the publishers are matched, none past the grid."""
    from spacecraft_sim.reference import ReferenceNode

    ref = ReferenceNode(context=ros_context, parameter_overrides=[Parameter("mode", value="realtime"),
                                                                    Parameter("duration_s", value=0.2)])  # samples 0 .. 20
    try:
        for timer in ref._frame_timers:
            timer.cancel()
        f0 = 170_000_000_000
        clock = FakeClock((f0 - START_LEAD_FRAMES) * DT_NS + DT_NS // 2)  # the plant publishes sample 0 START_LEAD_FRAMES ahead
        monkeypatch.setattr(ref, "get_clock", lambda: clock)
        matched = {"yes": False}
        monkeypatch.setattr(ref.frames, "_ready", lambda: matched["yes"])
        sent: list[tuple[int, int]] = []
        monkeypatch.setattr(ref, "_publish", lambda k, stamp_ns: sent.append((k, stamp_ns)))
        ref.frames._on_timer()
        assert sent == []  # no state yet: the run has not started
        ref.frames.start_at(f0 * DT_NS)
        assert sent == []  # not matched yet
        ref.frames._on_timer()
        matched["yes"] = True
        ref.frames._on_timer()  # the tick of frame f0 - START_LEAD_FRAMES: through f0 + AHEAD_FRAMES
        assert sent == [(k, (f0 + k) * DT_NS) for k in range(AHEAD_FRAMES + 1)]
        clock.ns = f0 * DT_NS + DT_NS // 2  # mid-frame f0: nothing new
        ref.frames._on_timer()
        assert len(sent) == AHEAD_FRAMES + 1
        clock.ns += DT_NS  # mid-frame f0 + 1: one more
        ref.frames._on_timer()
        assert sent[AHEAD_FRAMES + 1:] == [(AHEAD_FRAMES + 1, (f0 + AHEAD_FRAMES + 1) * DT_NS)]
        clock.ns += 4 * DT_NS  # three ticks missed: made up, through frame f0 + 5 + AHEAD_FRAMES
        ref.frames._on_timer()
        assert [k for k, _ in sent] == list(range(AHEAD_FRAMES + 6))
        clock.ns += 100 * DT_NS
        ref.frames._on_timer()  # never past the grid's last sample, 20
        assert [k for k, _ in sent] == list(range(21)) and sent[-1] == (20, (f0 + 20) * DT_NS)
    finally:
        ref.destroy_node()

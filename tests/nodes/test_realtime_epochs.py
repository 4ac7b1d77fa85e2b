"""Real-time-sized stamps (~1.8e18 ns since 1970) through the star tracker's path, plant to
estimator (issue 46, item 2): what lockstep tests cannot catch, since lockstep stamps count from 0.

A float64 near 1.8e18 is 256 ns from its neighbours, so the frame stamp ``f * 10 ms`` is exact
only for even ``f``; the plant once carried the tracker's epoch as a float of absolute
nanoseconds, which dated the tracker sample of a frame ``f = 3 mod 4`` 128 ns after the gyro
sample naming it, and the estimator answered it as "no data" (NaN), then applied it 10 ms late.
Here: the conversion itself (exact from any origin, the old path's error shown), the plant and the
estimator nodes in one process on frames whose first one is odd or even, ticked at the times of a
clock the test sets (no timing luck), with the fix and with the old float path put back (the
estimator then counts each future epoch as a contract error, refuses that tracker sample, never
publishes NaN for a sample it has an estimate of and never applies it late); and the estimator
alone fed a future epoch and a late tracker sample."""

from __future__ import annotations

import json
import math
import time
from typing import Any

import numpy as np
import pytest
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter

from sappc_estimator.core import mekf
from sappc_msgs_py import contract as c
from sappc_msgs_py.convert import epoch_from_msg, stamp_to_ns
from sappc_msgs_py.timeline import START_LEAD_FRAMES
from spacecraft_sim.core.sensors import S_BIAS0, measure
from spacecraft_sim.plant_node import tracker_epoch_ns, tracker_epoch_offset

from fake_clock import FakeClock
from test_estimator_node import DT_NS, EPOCHS, OMEGA_TRUE, SENSORS, Driver, Reference, measurements, overrides

DEADLINE_S = 20.0
#: First frames of 10 ms near 1.8e18 ns: odd, 3 mod 4 (its tracker frames f0 + 20 j came 128 ns late
#: through a float), odd, 1 mod 4 (f0 + 10 + 20 j did), and even.
F0 = {"odd, 3 mod 4": 179_999_999_999, "odd, 1 mod 4": 180_000_000_001, "even": 180_000_000_000}
#: The flight scenario's sensors as the plant's ``sensors`` parameter.
SENSORS_JSON = json.dumps({"star_tracker": {"noise_rad": [9.7e-6, 9.7e-6, 7.3e-5], "rate_hz": 10.0},
                           "gyro": {"angle_random_walk_rad_sqrt_s": 1.45e-6, "bias_random_walk_rad_s_sqrt_s": 8.1e-10,
                                    "initial_bias_rad_s": [2.4e-6, -1.5e-6, 1.0e-6]}, "seed": 7})


def _old_offset(stamp_ns: int, origin_ns: int) -> float:
    """The plant's conversion before the fix: a float of absolute nanoseconds."""
    return float(stamp_ns)


def _old_ns(offset: float, origin_ns: int) -> int:
    return int(offset)


# ---- the conversion -------------------------------------------------------------------------------


@pytest.mark.parametrize("case", list(F0))
def test_the_tracker_epoch_goes_through_the_sensor_kernel_exact_from_any_origin(case: str) -> None:
    """The sensor kernel (the plant's and the offline loop's ``measure``) holds the epoch in a float
    array: as an offset from sample 0's stamp it comes back as the exact stamp for every frame of a
    run (here 1000, a tracker sample every 10th), odd first frame or even; the old float of absolute
    nanoseconds comes back 128 ns late for every frame = 3 mod 4 (and early for 1 mod 4)."""
    f0 = F0[case]
    origin = f0 * DT_NS
    prm, draws = SENSORS.params(DT_NS / 1e9), SENSORS.draws(1000)
    held, bias, y = np.zeros(5), prm[S_BIAS0 : S_BIAS0 + 3].copy(), np.zeros(8)
    q = np.array([0.0, 0.0, 0.0, 1.0])
    for k in range(1000):
        stamp = (f0 + k) * DT_NS
        measure(k, k * DT_NS / 1e9, tracker_epoch_offset(stamp, origin), q, OMEGA_TRUE, draws[k], prm, SENSORS.outages(), held, bias, y)
        assert tracker_epoch_ns(y[7], origin) == (f0 + k // 10 * 10) * DT_NS  # the tracker's own frame, held in between
    errors = {f % 4: int(float(f * DT_NS)) - f * DT_NS for f in range(f0, f0 + 8)}  # the old path
    assert errors == {0: 0, 1: -128, 2: 0, 3: 128}
    assert tracker_epoch_offset(7 * DT_NS, 0) == 7.0 * DT_NS and tracker_epoch_ns(7.0 * DT_NS, 0) == 7 * DT_NS  # lockstep: the stamp itself


# ---- plant and estimator, frame by frame ----------------------------------------------------------


class _Graph:
    """A real-time plant with the flight sensors and a real-time estimator on its sensors' topics, in
    one process, both on the clock the test sets; a probe offers the plant's torque input and reads
    the state, the estimate and the tracker's epochs.  ``tick(f)`` runs the plant's tick of frame
    ``f`` and waits for the estimator's answer of every state published."""

    def __init__(self, ros_context: Any, monkeypatch: Any, f0: int) -> None:
        from sappc_estimator.node import EstimatorNode
        from spacecraft_sim.plant_node import PlantNode

        self.f0 = f0
        self.clock = FakeClock((f0 - START_LEAD_FRAMES) * DT_NS + 300_000)  # sample 0 is published START_LEAD_FRAMES ahead
        self.plant = PlantNode(context=ros_context, parameter_overrides=[
            Parameter("mode", value="realtime"), Parameter("duration_s", value=0.0), Parameter("sensors", value=SENSORS_JSON),
            Parameter("omega_BN_B0_rad_s", value=[1.0e-3, -2.0e-3, 0.5e-3])])
        for timer in self.plant._frame_timers:
            timer.cancel()
        self.est = EstimatorNode(context=ros_context, parameter_overrides=overrides(mode="realtime"))
        for node in (self.plant, self.est):
            monkeypatch.setattr(node, "get_clock", lambda: self.clock)
        self.probe = Node("probe", context=ros_context)
        qos = c.qos_profile()
        self.torque = self.probe.create_publisher(c.CONTROL_TORQUE.msg_class, c.CONTROL_TORQUE.name, qos)
        self.estimates: dict[int, np.ndarray] = {}
        self.epochs: dict[int, int] = {}  # gyro sample's stamp -> the tracker epoch it names
        self.tracker: list[int] = []  # the tracker samples' stamps
        self.probe.create_subscription(c.STATE_ATTITUDE.msg_class, c.STATE_ATTITUDE.name, lambda m: None, qos)
        self.probe.create_subscription(c.STATE_RATE.msg_class, c.STATE_RATE.name, lambda m: None, qos)
        self.probe.create_subscription(c.ESTIMATE_RATE.msg_class, c.ESTIMATE_RATE.name, lambda m: None, qos)
        self.probe.create_subscription(c.ESTIMATE_ATTITUDE.msg_class, c.ESTIMATE_ATTITUDE.name, lambda m: self.estimates.__setitem__(
            stamp_to_ns(m.header.stamp), np.array([m.quaternion.x, m.quaternion.y, m.quaternion.z, m.quaternion.w])), qos)
        self.probe.create_subscription(c.STATE_ATTITUDE_EPOCH.msg_class, c.STATE_ATTITUDE_EPOCH.name, lambda m: self.epochs.__setitem__(
            stamp_to_ns(m.header.stamp), epoch_from_msg(m, c.STATE_ATTITUDE_EPOCH)), qos)
        self.probe.create_subscription(c.SENSOR_STAR_TRACKER.msg_class, c.SENSOR_STAR_TRACKER.name,
                                       lambda m: self.tracker.append(stamp_to_ns(m.header.stamp)), qos)
        self.ex = SingleThreadedExecutor(context=ros_context)
        for node in (self.plant, self.est, self.probe):
            self.ex.add_node(node)
        p = self.plant
        self.spin_until(lambda: not p._not_ready() and self.est._gate.open()
                        and p.pub_gyro.pub.get_subscription_count() >= 1
                        and all(x.pub.get_subscription_count() >= 2 for x in (p.pub_epoch, p.pub_tracker)), "matching")

    def spin_until(self, condition: Any, what: str) -> None:
        deadline = time.monotonic() + DEADLINE_S
        while not condition():
            assert time.monotonic() < deadline, f"timed out waiting for {what}"
            self.ex.spin_once(timeout_sec=0.02)

    def run(self, frames: int) -> None:
        """Sample 0 ahead of its frame, then the tick of each frame 0.2 ms after its start (a
        sample a frame, each answered by the estimator before the next tick)."""
        self.plant._realtime_tick()
        self.spin_until(lambda: self.est.samples == 1 and len(self.estimates) == 1, "the estimate of sample 0")
        for g in range(1, frames):
            self.clock.ns = (self.f0 + g) * DT_NS + 200_000
            self.plant._realtime_tick()
            self.spin_until(lambda: self.est.samples == g + 1 and len(self.estimates) == g + 1, f"the estimate of frame {g}")

    def close(self) -> None:
        self.ex.shutdown()
        for node in (self.probe, self.est, self.plant):
            node.destroy_node()


FRAMES = 51  # five tracker samples after the first (10 Hz beside 100 Hz)


@pytest.mark.parametrize("case", list(F0))
def test_at_real_time_stamps_every_tracker_epoch_is_its_own_frame_and_every_sample_has_its_estimate(ros_context, monkeypatch, case) -> None:  # type: ignore[no-untyped-def]
    """With the fix, whatever the first frame's parity: every tracker sample is stamped with its own
    frame's start, every gyro sample names a tracker epoch at or before its own stamp (the latest
    tracker frame), the estimator initialises at sample 0 and updates at each of the next five
    tracker samples, with no gate rejection, no future epoch, no late tracker sample, and a finite
    estimate for every sample."""
    g = _Graph(ros_context, monkeypatch, F0[case])
    try:
        g.run(FRAMES)
        f0 = g.f0
        assert g.tracker == [(f0 + 10 * j) * DT_NS for j in range(6)]
        g.spin_until(lambda: len(g.epochs) == FRAMES, "every epoch")
        assert g.epochs == {(f0 + k) * DT_NS: (f0 + k // 10 * 10) * DT_NS for k in range(FRAMES)}
        s = g.est.statistics()
        assert (s["future_tracker_epochs"], s["late_tracker_samples"], s["no_data_samples"], s["gate_rejections"]) == (0, 0, 0, 0)
        assert (s["samples"], s["steps"], s["updates"], s["rejected"], s["no_data_inputs"]) == (FRAMES, FRAMES, 5, 0, 0)
        assert all(np.all(np.isfinite(q)) for q in g.estimates.values())
    finally:
        g.close()


def test_the_old_float_epochs_are_counted_refused_and_never_make_a_nan_estimate(ros_context, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """The old conversion put back (a float of absolute nanoseconds) on a first frame 3 mod 4: the
    tracker samples of f0, f0 + 20 and f0 + 40 are dated 128 ns after their frame.  The estimator
    counts each as a contract error (``future_tracker_epochs``: 3, in its statistics and its
    closing line), refuses that tracker sample (never applied, neither then nor at a later sample:
    no gate rejection), and steps its sample on the gyro: a finite estimate for every sample once
    the filter has one (f0 + 10; before it, "no data" is the truth: no estimate yet)."""
    import spacecraft_sim.plant_node as plant_node

    monkeypatch.setattr(plant_node, "tracker_epoch_offset", _old_offset)
    monkeypatch.setattr(plant_node, "tracker_epoch_ns", _old_ns)
    g = _Graph(ros_context, monkeypatch, F0["odd, 3 mod 4"])
    try:
        g.run(FRAMES)
        f0 = g.f0
        late = {(f0 + 10 * j) * DT_NS for j in (0, 2, 4)}
        assert {ns - f0 * DT_NS for ns in g.tracker} == {10 * j * DT_NS + (128 if (f0 + 10 * j) * DT_NS in late else -128) for j in range(6)}
        s = g.est.statistics()
        assert s["future_tracker_epochs"] == 3 and s["gate_rejections"] == 0 and s["late_tracker_samples"] == 0
        # f0 + 10's sample, dated 128 ns early (not of its step), initialises provisionally, f0 + 30's
        # replaces it (docs/estimator.md, step 2), f0 + 50's updates
        assert s["updates"] == 1 and s["reinitialisations"] == 0 and s["rejected"] == 0
        assert s["no_data_samples"] == 10  # f0 .. f0 + 9: the filter has no estimate yet (f0's sample refused)
        first = (f0 + 10) * DT_NS
        assert all(np.all(np.isfinite(q)) for ns, q in g.estimates.items() if ns >= first)
        assert all(np.all(np.isnan(q)) for ns, q in g.estimates.items() if ns < first)
    finally:
        g.close()


# ---- the estimator alone: a future epoch, a late tracker sample -----------------------------------


def _diagnostics(drv: Driver, ns: int) -> Any:
    """The estimator's diagnostics of the sample stamped ``ns``: the Driver keys them by ``data[0]``
    (float seconds, the contract's label), which at real-time stamps is within 128 ns of the stamp."""
    got = drv.got[c.ESTIMATOR_DIAGNOSTICS.name]
    near = [k for k in got if abs(k - ns) <= 1_000]
    return got[near[0]] if near else None


def _answered(drv: Driver, ns: int) -> bool:
    return ns in drv.got[c.ESTIMATE_ATTITUDE.name] and _diagnostics(drv, ns) is not None


@pytest.fixture
def realtime_estimator(ros_context, monkeypatch):  # type: ignore[no-untyped-def]
    from sappc_estimator.node import EstimatorNode

    node = EstimatorNode(context=ros_context, parameter_overrides=overrides(mode="realtime"))
    t0 = 180_000_000_001 * DT_NS  # an odd frame near 1.8e18 ns
    clock = FakeClock(t0 + 300_000)
    monkeypatch.setattr(node, "get_clock", lambda: clock)
    drv = Driver(ros_context, [node])
    drv.matched(node)
    yield node, drv, clock, t0
    drv.close()
    node.destroy_node()


def test_a_tracker_epoch_after_its_sample_is_a_counted_contract_error_not_no_data(realtime_estimator) -> None:  # type: ignore[no-untyped-def]
    """Sample 10 (a tracker frame) names its tracker sample 128 ns after its own stamp: counted
    (``future_tracker_epochs``), refused; the sample gets its estimate, propagated on the gyro
    (not "no data"); sample 11, naming the same epoch, propagates too (the refused sample is never
    applied late), and the next tracker sample (20) updates; as the kernel called with the last valid
    tracker sample's epoch."""
    node, drv, clock, t0 = realtime_estimator
    q, w = measurements(21)
    ref = Reference()
    for k in range(21):
        ns = t0 + k * DT_NS
        epoch = t0 + EPOCHS[k * DT_NS] + (128 if 10 <= k < 20 else 0)
        clock.ns = ns + 300_000
        drv.send(ns, q[k], w[k], epoch_ns=epoch)
        if k == 10:  # the tracker's sample, stamped (wrongly) with its epoch
            drv.send(epoch, q[k], w[k], topics=(c.SENSOR_STAR_TRACKER,), epoch_ns=epoch)
        drv.spin_until(lambda: _answered(drv, ns), f"the estimate of sample {k}")
        status = ref.step(k * DT_NS / 1e9, q[k], w[k], 0.0 if 10 <= k < 20 else None)
        assert _diagnostics(drv, ns)["status"] == status
        np.testing.assert_array_equal(drv.got[c.ESTIMATE_ATTITUDE.name][ns], ref.out[mekf.EO_Q : mekf.EO_Q + 4])
    statuses = [_diagnostics(drv, t0 + k * DT_NS)["status"] for k in range(21)]
    assert statuses[10] == statuses[11] == mekf.STATUS_PROPAGATED and statuses[20] == mekf.STATUS_UPDATED
    s = node.statistics()
    assert s["future_tracker_epochs"] == 1 and s["no_data_samples"] == 0 and s["updates"] == 1 and s["gate_rejections"] == 0
    assert s["rejected"] == 0 and s["late_tracker_samples"] == 0


def test_a_tracker_sample_waits_for_its_own_step_or_is_refused_never_applied_later(realtime_estimator) -> None:  # type: ignore[no-untyped-def]
    """Real time, as lockstep: a sample whose new tracker sample has not arrived waits for it and is
    updated at its own step when it comes (sample 10); one that has not come by the middle of its
    sample's frame (sample 20: the estimator's frame timer) is late: the sample is stepped on the
    gyro, the tracker sample counted (``late_tracker_samples``) and refused when it arrives, so
    the next sample (21) propagates instead of applying it 10 ms late."""
    node, drv, clock, t0 = realtime_estimator
    q, w = measurements(22)
    gyro_epoch = (c.SENSOR_GYRO, c.STATE_ATTITUDE_EPOCH)
    for k in range(22):
        ns = t0 + k * DT_NS
        clock.ns = ns + 300_000
        if k in (10, 20):
            drv.send(ns, q[k], w[k], topics=gyro_epoch, epoch_ns=ns)  # the tracker's sample not yet
            drv.spin_until(lambda: node._waiting is not None, f"sample {k} waiting")
            if k == 10:
                drv.send(ns, q[k], w[k], topics=(c.SENSOR_STAR_TRACKER,), epoch_ns=ns)
            else:
                clock.ns = ns + DT_NS // 2  # the middle of its frame: the timer answers it
        else:
            drv.send(ns, q[k], w[k], epoch_ns=t0 + k // 10 * 10 * DT_NS)
        drv.spin_until(lambda: _answered(drv, ns), f"the estimate of sample {k}")
        if k == 20:
            drv.send(ns, q[k], w[k], topics=(c.SENSOR_STAR_TRACKER,), epoch_ns=ns)  # it arrives: too late
    statuses = [_diagnostics(drv, t0 + k * DT_NS)["status"] for k in range(22)]
    assert statuses[10] == mekf.STATUS_UPDATED and statuses[20] == statuses[21] == mekf.STATUS_PROPAGATED
    s = node.statistics()
    assert s["late_tracker_samples"] == 1 and s["updates"] == 1 and s["no_data_samples"] == 0 and s["future_tracker_epochs"] == 0
    assert all(not math.isnan(v) for k in range(22) for v in drv.got[c.ESTIMATE_ATTITUDE.name][t0 + k * DT_NS])

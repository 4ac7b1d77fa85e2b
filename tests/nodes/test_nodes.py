"""Each node in-process with an executor, on an isolated domain: the controller's input checks,
stale-input handling, runtime parameter changes; the plant's lockstep protocol; the reference
publisher and the injector's relays.  Waits are on conditions (with a generous deadline), never
on fixed sleeps."""

from __future__ import annotations

import contextlib
import math
import os
import time

import numpy as np
import pytest
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter

from sappc.scenario import load_scenario
from sappc_controller.core.packing import pack_params
from sappc_controller.params import PARAMETER_MAX, parameters_from_config
from sappc_msgs_py import contract as c
from sappc_msgs_py.convert import (
    clock_msg,
    diagnostics_from_msg,
    quaternion_from_msg,
    quaternion_msg,
    stamp_to_ns,
    torque_from_msg,
    torque_msg,
    vector3_msg,
)

from conftest import ROOT, SCENARIOS
from fake_clock import FakeClock

#: The paper's initial attitude, normalised.
Q0 = tuple(np.array([0.3254, 0.4068, -0.3254, 0.7891]) / np.linalg.norm([0.3254, 0.4068, -0.3254, 0.7891]))
#: Longest wait for a condition [s]: discovery takes 0.2-0.55 s with the project's profile.
#: ``SAPPC_TEST_DEADLINE_S`` shortens it where a missing message is the expected failure
#: (benchmarks/bench_mutation.py: a mutant that never publishes fails in seconds, not 20 s).
DEADLINE_S = float(os.environ.get("SAPPC_TEST_DEADLINE_S", "20"))


class Driver:
    """A test node publishing the controller's inputs and collecting its outputs."""

    def __init__(self, context, nodes):  # type: ignore[no-untyped-def]
        self.node = Node("driver", context=context)
        qos = c.qos_profile()
        self.pub = {t.name: self.node.create_publisher(t.msg_class, t.name, qos) for t in (c.STATE_ATTITUDE, c.STATE_RATE, c.REFERENCE_ATTITUDE, c.REFERENCE_RATE, c.REFERENCE_ACCELERATION, c.CLOCK)}
        self.torques: list[tuple[int, np.ndarray]] = []
        self.diags: list[dict[str, np.ndarray]] = []
        self.outputs = [
            self.node.create_subscription(c.CONTROL_TORQUE.msg_class, c.CONTROL_TORQUE.name, lambda m: self.torques.append((stamp_to_ns(m.header.stamp), torque_from_msg(m))), qos),
            self.node.create_subscription(c.CONTROLLER_DIAGNOSTICS.msg_class, c.CONTROLLER_DIAGNOSTICS.name, lambda m: self.diags.append(diagnostics_from_msg(m)), qos),
        ]
        self.executor = SingleThreadedExecutor(context=context)
        for n in (self.node, *nodes):
            self.executor.add_node(n)

    def spin_until(self, condition, what: str) -> None:  # type: ignore[no-untyped-def]
        deadline = time.monotonic() + DEADLINE_S
        while not condition():
            assert time.monotonic() < deadline, f"timed out waiting for {what}"
            self.executor.spin_once(timeout_sec=0.02)

    def matched(self) -> None:
        """The controller's subscriptions matched, and its outputs offered (once every input has a publisher) and matched."""
        self.spin_until(lambda: all(p.get_subscription_count() >= 1 for n, p in self.pub.items() if n != "/clock"), "the controller's subscriptions")
        self.spin_until(lambda: all(sub.get_publisher_count() >= 1 for sub in self.outputs), "the controller's outputs")

    def send_sample(self, t: float, q=Q0, w=(0.0, 0.0, 0.0), q_d=(0.0, 0.0, 0.0, 1.0), frame=None, clock=True) -> None:  # type: ignore[no-untyped-def]
        att = quaternion_msg(Q0, t, c.STATE_ATTITUDE)  # then the raw fields: the encoder refuses bad values
        att.quaternion.x, att.quaternion.y, att.quaternion.z, att.quaternion.w = (float(v) for v in q)
        rate = vector3_msg([0.0, 0.0, 0.0], t, c.STATE_RATE)
        rate.vector.x, rate.vector.y, rate.vector.z = (float(v) for v in w)
        msgs = {
            c.STATE_ATTITUDE.name: att,
            c.STATE_RATE.name: rate,
            c.REFERENCE_ATTITUDE.name: quaternion_msg(q_d, t, c.REFERENCE_ATTITUDE),
            c.REFERENCE_RATE.name: vector3_msg([0.0, 0.0, 0.0], t, c.REFERENCE_RATE),
            c.REFERENCE_ACCELERATION.name: vector3_msg([0.0, 0.0, 0.0], t, c.REFERENCE_ACCELERATION),
        }
        if frame is not None:
            msgs[c.STATE_ATTITUDE.name].header.frame_id = frame
        if clock:
            self.pub["/clock"].publish(clock_msg(t))
        for name, m in msgs.items():
            self.pub[name].publish(m)


def _controller_overrides(**extra):  # type: ignore[no-untyped-def]
    scenario = load_scenario(SCENARIOS / "paper_tracking.yaml")
    flat = parameters_from_config("sappc", scenario.controller_config("sappc"))
    flat.update(extra)
    return [Parameter(k, value=v) for k, v in flat.items()]


@pytest.fixture
def controller(ros_context):  # type: ignore[no-untyped-def]
    from sappc_controller.node import ControllerNode

    node = ControllerNode(context=ros_context, parameter_overrides=_controller_overrides(stale_timeout_s=0.05))
    driver = Driver(ros_context, [node])
    driver.matched()
    yield node, driver
    driver.executor.shutdown()
    node.destroy_node()
    driver.node.destroy_node()



def test_controller_computes_once_per_complete_sample_and_stamps_the_torque(controller) -> None:  # type: ignore[no-untyped-def]
    node, drv = controller
    for k in range(3):
        drv.send_sample(k * 0.01, q=Q0)
    drv.spin_until(lambda: len(drv.torques) == 3, "three torques")
    assert [ns for ns, _ in drv.torques] == [0, 10_000_000, 20_000_000]
    for _, tq in drv.torques:
        assert np.all(np.isfinite(tq)) and np.all(np.abs(tq) <= 0.5)
    assert node.steps == 3 and node.rejected == 0
    drv.spin_until(lambda: len(drv.diags) == 3, "diagnostics")
    assert drv.diags[0]["status"].tolist() == [0.0, 0.0, 0.0]
    assert drv.diags[0]["rho"][1] == pytest.approx(0.4, abs=1e-12)  # the RPF starts at rho_e0 on the largest axis


BAD = {
    "NaN in the attitude": dict(q=(math.nan, 0.0, 0.0, 1.0)),
    "Inf in the rate": dict(w=(math.inf, 0.0, 0.0)),
    "a zero quaternion": dict(q=(0.0, 0.0, 0.0, 0.0)),
    "a non-unit quaternion": dict(q=(0.0, 0.0, 0.0, 1.1)),
    "a wrong frame id": dict(frame="body"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_inputs_are_rejected_counted_and_never_reach_the_torque(controller, case) -> None:  # type: ignore[no-untyped-def]
    """A bad input is rejected and counted; in lockstep it still completes its sample, which the
    controller answers at once by holding its last torque (not yet stale), so the plant never waits."""
    node, drv = controller
    drv.send_sample(0.0, q=Q0)
    drv.spin_until(lambda: len(drv.torques) == 1, "the first torque")
    kwargs = dict(q=Q0)
    kwargs.update(BAD[case])
    drv.send_sample(0.01, **kwargs)
    drv.spin_until(lambda: len(drv.torques) == 2 and len(drv.diags) == 2, "the bad sample's answer")
    assert drv.torques[1][0] == 10_000_000 and np.array_equal(drv.torques[1][1], drv.torques[0][1])  # held
    assert drv.diags[1]["status"][2] == c.ANSWER_HELD and node.steps == 1  # no control step on it
    drv.send_sample(0.02, q=Q0)  # good inputs again: computed
    drv.spin_until(lambda: len(drv.torques) == 3, "the next torque")
    assert drv.torques[2][0] == 20_000_000 and node.steps == 2
    assert all(np.all(np.isfinite(tq)) for _, tq in drv.torques)
    drv.spin_until(lambda: len(drv.diags) == 3, "diagnostics")
    assert drv.diags[2]["status"][0] == node.rejected >= 1  # counted in diagnostics
    assert node.rejected_by_reason == {"invalid": node.rejected}


@pytest.mark.parametrize(("field", "value", "param"), [
    ("w", (1.0e12, 0.0, 0.0), "max_body_rate_rad_s = 10"),  # the 1e12 rad/s, else commanded as a saturated torque
    ("w", (0.0, 6.0, 8.1), "max_body_rate_rad_s = 10"),  # a magnitude just above the bound (|w| = 10.06)
])
def test_an_implausible_input_is_rejected_as_such_counted_and_never_reaches_the_torque(controller, field, value, param) -> None:  # type: ignore[no-untyped-def]
    """A finite rate beyond ``max_body_rate_rad_s`` (default 10 rad/s) is rejected by reason
    ``implausible``, logged naming the value and the bound, and its sample is answered without the
    law (held: the last state is recent), as the offline loop answers it."""
    node, drv = controller
    drv.send_sample(0.0, q=Q0)
    drv.spin_until(lambda: len(drv.torques) == 1, "the first torque")
    messages: list[str] = []
    original = node._reject
    node._reject = lambda reason, kind: (messages.append(reason), original(reason, kind))  # type: ignore[method-assign]
    drv.send_sample(0.01, q=Q0, **{field: value})
    drv.spin_until(lambda: len(drv.torques) == 2 and len(drv.diags) == 2, "the implausible sample's answer")
    assert drv.diags[1]["status"][2] == c.ANSWER_HELD and node.steps == 1 and node.refused == 0
    assert node.rejected_by_reason == {"implausible": 1} and node.rejected == 1
    assert len(messages) == 1 and param in messages[0] and "implausible" in messages[0], messages
    drv.send_sample(0.02, q=Q0, w=(0.0, 6.0, 7.9))  # |w| = 9.94 rad/s: within the bound, computed
    drv.spin_until(lambda: len(drv.torques) == 3, "the next torque")
    assert node.steps == 2 and node.rejected == 1


def test_before_its_first_valid_sample_the_controller_answers_zero_and_has_no_performance_function(controller) -> None:  # type: ignore[no-untyped-def]
    """No valid state yet (an invalid sample at t = 0): nothing to hold, so the watchdog answers with
    zero torque, and the diagnostics' performance-function rows are NaN (there is none yet); the
    first valid sample (0.01 s) starts the run: the RPF's time origin, rho = rho_e0 = 0.4."""
    node, drv = controller
    drv.send_sample(0.0, q=(math.nan, 0.0, 0.0, 1.0))
    drv.spin_until(lambda: len(drv.torques) == 1 and len(drv.diags) == 1, "the answer of the invalid first sample")
    assert drv.diags[0]["status"][2] == c.ANSWER_WATCHDOG_ZERO and np.all(drv.torques[0][1] == 0.0)
    for row in ("rho", "band_lower", "band_upper", "eps", "z", "lyapunov_V"):
        assert np.isnan(drv.diags[0][row]).all(), row
    drv.send_sample(0.01, q=Q0)
    drv.spin_until(lambda: len(drv.torques) == 2 and len(drv.diags) == 2, "the first computed sample")
    assert drv.diags[1]["status"][2] == c.ANSWER_COMMANDED and node.controller.t0 == 0.01
    assert drv.diags[1]["rho"][1] == pytest.approx(0.4, abs=1e-12)


def test_stamps_in_the_past_or_far_future_are_rejected(controller) -> None:  # type: ignore[no-untyped-def]
    node, drv = controller
    drv.send_sample(1.0, q=Q0)
    drv.spin_until(lambda: len(drv.torques) == 1, "the first torque")
    drv.send_sample(0.5, q=Q0)  # in the past: 5 inputs rejected
    drv.spin_until(lambda: node.rejected >= 5, "past stamps rejected")
    drv.pub[c.STATE_ATTITUDE.name].publish(quaternion_msg(Q0, 100.0, c.STATE_ATTITUDE))  # 99 s ahead of /clock
    drv.spin_until(lambda: node.rejected >= 6, "a far-future stamp rejected")
    assert len(drv.torques) == 1
    assert node.rejected_by_reason == {"stamp_in_past": 5, "stamp_too_far_ahead": 1}  # counted by reason


@pytest.fixture
def controller_without_rate_bound(ros_context):  # type: ignore[no-untyped-def]
    """The controller with the body-rate plausibility bound at the largest double (no bound)."""
    from sappc_controller.node import ControllerNode

    node = ControllerNode(context=ros_context, parameter_overrides=_controller_overrides(stale_timeout_s=0.05, max_body_rate_rad_s=1.7e308))
    driver = Driver(ros_context, [node])
    driver.matched()
    yield node, driver
    driver.executor.shutdown()
    node.destroy_node()
    driver.node.destroy_node()


def test_a_finite_input_that_gives_a_non_finite_torque_is_refused_and_counted(controller_without_rate_bound) -> None:  # type: ignore[no-untyped-def]
    """With the plausibility bound lifted, a rate of 1e300 rad/s passes the input checks, but the
    law's torque is not finite: the core refuses it, the node publishes zero, counts the refused
    step and codes the answer."""
    node, drv = controller_without_rate_bound
    drv.send_sample(0.0, q=Q0)
    drv.spin_until(lambda: len(drv.torques) == 1, "the first torque")
    drv.send_sample(0.01, q=Q0, w=(1e300, 0.0, 0.0))
    drv.spin_until(lambda: len(drv.torques) == 2 and len(drv.diags) == 2, "the refused step's answer")
    assert np.all(drv.torques[1][1] == 0.0) and node.refused == 1 and node.rejected == 0
    assert drv.diags[1]["status"][2] == c.ANSWER_REFUSED


def test_stale_inputs_give_zero_torque_then_control_resumes(controller) -> None:  # type: ignore[no-untyped-def]
    """Lockstep ticks whose inputs never arrive are answered after ``lockstep_grace_s``: the last
    torque held while the last state is within ``stale_timeout_s`` (0.05 s here), zero after;
    the first valid sample is computed and commanded at once."""
    node, drv = controller
    drv.send_sample(0.0, q=Q0)
    drv.spin_until(lambda: len(drv.torques) == 1, "the first torque")
    assert np.any(drv.torques[0][1] != 0.0)
    for t in (0.03, 0.06, 0.09):  # /clock moves on, no inputs
        drv.pub["/clock"].publish(clock_msg(t))
        drv.spin_until(lambda: drv.torques[-1][0] == round(t * 1e9) and len(drv.diags) == len(drv.torques), f"the answer of {t}")
    answers = [d["status"][2] for d in drv.diags[1:]]
    assert answers == [c.ANSWER_HELD, c.ANSWER_WATCHDOG_ZERO, c.ANSWER_WATCHDOG_ZERO]
    assert np.array_equal(drv.torques[1][1], drv.torques[0][1]) and np.all(drv.torques[2][1] == 0.0) and np.all(drv.torques[3][1] == 0.0)
    assert all(d["status"][1] == 1.0 for d in drv.diags[1:])  # not a control step
    assert all(d["input_stamps_state_s"].tolist() == [0.0, 0.0, 0.0] and d["input_stamps_reference_s"].tolist() == [0.0, 0.0, 0.0] for d in drv.diags[1:])  # no input used
    drv.send_sample(0.10, q=Q0)  # valid inputs again: computed and commanded
    drv.spin_until(lambda: drv.torques[-1][0] == 100_000_000, "control resumed")
    assert node.steps == 2 and np.any(drv.torques[-1][1] != 0.0) and node.rejected == 0


@pytest.mark.parametrize("first", ["clock", "state"])
def test_recovery_after_an_outage_does_not_depend_on_the_arrival_order(controller, first) -> None:  # type: ignore[no-untyped-def]
    """Lockstep: after an outage the first complete sample is computed and commanded (no input
    refused as "in the past", the old failure that kept the controller at zero torque for the
    rest of the run), whether its /clock tick or its inputs arrive first."""
    node, drv = controller
    drv.send_sample(0.0, q=Q0)
    drv.spin_until(lambda: len(drv.torques) == 1, "the first torque")
    for t in (0.02, 0.04, 0.06, 0.08):  # an outage: /clock moves on, no state
        drv.pub["/clock"].publish(clock_msg(t))
        drv.spin_until(lambda: drv.torques[-1][0] == round(t * 1e9), f"the answer of {t}")
    if first == "clock":
        drv.pub["/clock"].publish(clock_msg(0.10))
        drv.spin_until(lambda: node._clock_ns == 100_000_000, "/clock 0.10")
        drv.send_sample(0.10, q=Q0, clock=False)
    else:
        drv.send_sample(0.10, q=Q0, clock=False)
        drv.spin_until(lambda: node.steps == 2, "the sample of 0.10 computed")
        drv.pub["/clock"].publish(clock_msg(0.10))
        drv.spin_until(lambda: node._clock_ns == 100_000_000, "/clock 0.10")
    drv.spin_until(lambda: node.steps == 2 and drv.torques[-1][0] == 100_000_000, "the sample of 0.10 computed and answered")
    at_010 = [tq for ns, tq in drv.torques if ns == 100_000_000]
    assert len(at_010) == 1 and np.any(at_010[0] != 0.0)
    assert node.rejected == 0


def test_runtime_gain_changes_are_validated_and_applied_whole(controller) -> None:  # type: ignore[no-untyped-def]
    node, drv = controller
    drv.send_sample(0.0, q=Q0)  # a run in progress: its packed gains must follow the change
    drv.spin_until(lambda: len(drv.torques) == 1, "first torque")
    ok = node.set_parameters([Parameter("sappc.gains.K_q", value=0.25), Parameter("actuator.max_torque_Nm", value=0.4)])
    assert all(r.successful for r in ok)
    assert node.controller.config.gains.K_q == 0.25 and node.controller.config.actuator.max_torque_Nm == 0.4
    np.testing.assert_array_equal(node.controller._prm, pack_params(node.controller.config, 1))  # the compiled law's gains
    bad = node.set_parameters_atomically([Parameter("sappc.gains.K_q", value=0.5), Parameter("sappc.gains.K_omega", value=-1.0)])
    assert not bad.successful and "K_omega" in bad.reason
    assert node.controller.config.gains.K_q == 0.25  # nothing of the rejected change was applied
    fixed = node.set_parameters([Parameter("sappc.rpf.l", value=0.3)])[0]
    assert not fixed.successful and "sappc.rpf.l" in fixed.reason
    assert node.controller.config.rpf.l == 0.49
    huge = node.set_parameters([Parameter("sappc.gains.K_omega", value=1e300)])[0]  # finite, but no gain: refused by its range
    assert not huge.successful and node.controller.config.gains.K_omega != 1e300
    (described,) = node.describe_parameters(["sappc.gains.K_omega"])
    assert described.floating_point_range[0].from_value == 0.0 and described.floating_point_range[0].to_value == PARAMETER_MAX


def test_the_noise_filters_cutoff_changes_at_run_time_and_a_negative_one_is_refused_by_name(controller) -> None:  # type: ignore[no-untyped-def]
    """issue 34: ``<law>.noise_filter.*`` are changeable at run time, applied to the compiled law's
    parameters at the next step; a negative cut-off is refused naming the parameter."""
    node, drv = controller
    drv.send_sample(0.0, q=Q0)
    drv.spin_until(lambda: len(drv.torques) == 1, "first torque")
    ok = node.set_parameters([Parameter("sappc.noise_filter.torque_cutoff_hz", value=1.5)])
    assert all(r.successful for r in ok) and node.controller.config.noise_filter.torque_cutoff_hz == 1.5
    np.testing.assert_array_equal(node.controller._prm, pack_params(node.controller.config, 1))
    bad = node.set_parameters([Parameter("sappc.noise_filter.rate_cutoff_hz", value=-1.0)])[0]
    assert not bad.successful and "sappc.noise_filter.rate_cutoff_hz" in bad.reason
    assert node.controller.config.noise_filter.rate_cutoff_hz == 0.0


def test_a_request_mixing_a_valid_and_an_invalid_gain_is_applied_as_the_docs_say(controller) -> None:  # type: ignore[no-untyped-def]
    """Through the parameter services, as ``ros2 param`` or Foxglove send them (issue 25, defect 9):
    ``set_parameters`` is ROS's per-parameter request (each parameter is validated and applied on
    its own: the valid one is applied, the invalid one refused with its reason), while
    ``set_parameters_atomically`` applies all or nothing.  docs/how-to/nodes.md says exactly that."""
    from rclpy.parameter_client import AsyncParameterClient

    node, drv = controller
    client = AsyncParameterClient(drv.node, node.get_name())
    drv.spin_until(lambda: client.services_are_ready(), "the controller's parameter services")
    mixed = [Parameter("sappc.gains.K_q", value=0.5), Parameter("sappc.gains.K_omega", value=-1.0)]

    atomic = client.set_parameters_atomically(mixed)
    drv.spin_until(atomic.done, "set_parameters_atomically")
    result = atomic.result().result  # type: ignore[union-attr]
    assert not result.successful and "K_omega" in result.reason
    assert node.controller.config.gains.K_q == 0.3 and node.controller.config.gains.K_omega != -1.0  # nothing applied

    each = client.set_parameters(mixed)
    drv.spin_until(each.done, "set_parameters")
    ok_q, bad_omega = each.result().results  # type: ignore[union-attr]
    assert ok_q.successful and not bad_omega.successful and "K_omega" in bad_omega.reason
    assert node.controller.config.gains.K_q == 0.5 and node.controller.config.gains.K_omega != -1.0  # the valid one applied

    page = " ".join((ROOT / "docs" / "how-to" / "nodes.md").read_text().split())
    said = page.split("At run time the gains", 1)[1].split("the rest is read-only during a run", 1)[0]
    assert "nothing half-applied" not in said and "set_parameters_atomically" in said and "each parameter" in said, said


def test_plant_lockstep_waits_for_the_torque_of_each_sample(ros_context) -> None:  # type: ignore[no-untyped-def]
    from spacecraft_sim.core.dynamics import RigidBody, initial_state
    from spacecraft_sim.plant_node import PlantNode

    plant = PlantNode(context=ros_context, parameter_overrides=[Parameter("duration_s", value=0.03), Parameter("q_BN0", value=list(Q0)),
                                                                Parameter("expected_subscribers", value=["state/tf=1"])])  # as sappc run: the recorder
    # read once at start-up, so a change at run time is refused with the reason, not accepted and ignored
    refused = plant.set_parameters([Parameter("max_torque_Nm", value=0.1)])[0]
    assert not refused.successful and "read-only" in refused.reason and plant.max_torque == 0.5
    node = Node("torquer", context=ros_context)
    qos = c.qos_profile()
    pub = node.create_publisher(c.CONTROL_TORQUE.msg_class, c.CONTROL_TORQUE.name, qos)
    states: list[tuple[int, np.ndarray]] = []
    node.create_subscription(c.STATE_ATTITUDE.msg_class, c.STATE_ATTITUDE.name, lambda m: states.append((stamp_to_ns(m.header.stamp), quaternion_from_msg(m, c.STATE_ATTITUDE))), qos)
    node.create_subscription(c.STATE_RATE.msg_class, c.STATE_RATE.name, lambda m: None, qos)  # the plant waits for a subscriber on both
    frames: list[tuple[int, str, str, tuple[float, ...], tuple[float, ...]]] = []  # state/tf: stamp, parent, child, rotation, translation
    node.create_subscription(c.STATE_TF.msg_class, c.STATE_TF.name, lambda m: frames.append(_transform_row(m)), qos)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(plant)
    ex.add_node(node)
    deadline = time.monotonic() + DEADLINE_S
    answered = 0
    torque = np.array([0.1, -0.2, 0.05])
    while not plant.finished:
        assert time.monotonic() < deadline, "the plant did not finish"
        ex.spin_once(timeout_sec=0.02)
        if len(states) > answered:  # answer each published sample with its torque
            pub.publish(torque_msg(torque, states[answered][0] / 1e9))
            answered += 1
    assert [ns for ns, _ in states] == [0, 10_000_000, 20_000_000, 30_000_000]
    while len(frames) < len(states):  # published right after each state
        assert time.monotonic() < deadline, f"state/tf: {len(frames)} of {len(states)} messages"
        ex.spin_once(timeout_sec=0.02)
    # one body frame per sample, with the state's stamp and its q_BN as the rotation, bit for bit
    assert frames == [(ns, "inertial", "body", tuple(q), (0.0, 0.0, 0.0)) for ns, q in states]
    body = RigidBody(np.diag([4.0, 4.0, 4.0]))
    x = initial_state(np.array([Q0]), np.zeros((1, 3)))
    for k in range(3):
        x = body.propagate(x, torque[None], 0.01)
        np.testing.assert_array_equal(states[k + 1][1], x[0, :4])  # the plant core, bit for bit
    ex.shutdown()
    plant.destroy_node()
    node.destroy_node()


def _transform_row(m):  # type: ignore[no-untyped-def]
    r, p = m.transform.rotation, m.transform.translation
    return stamp_to_ns(m.header.stamp), m.header.frame_id, m.child_frame_id, (r.x, r.y, r.z, r.w), (p.x, p.y, p.z)


def test_reference_publishes_its_frame_with_each_sample(ros_context) -> None:  # type: ignore[no-untyped-def]
    """Lockstep: on /clock t_0 the reference node publishes samples 0 and 1; with each attitude
    ``q_RN`` it publishes ``reference/tf``, frame ``reference`` in ``inertial``, same stamp, the
    same quaternion, translation zero."""
    from spacecraft_sim.reference import ReferenceNode

    ref = ReferenceNode(context=ros_context, parameter_overrides=[Parameter("duration_s", value=0.05), Parameter("q_RN0", value=list(Q0))])
    node = Node("listener", context=ros_context)
    qos = c.qos_profile()
    clock = node.create_publisher(c.CLOCK.msg_class, c.CLOCK.name, qos)
    attitudes: list[tuple[int, tuple[float, ...]]] = []
    frames: list[tuple[int, str, str, tuple[float, ...], tuple[float, ...]]] = []
    node.create_subscription(c.REFERENCE_ATTITUDE.msg_class, c.REFERENCE_ATTITUDE.name,
                             lambda m: attitudes.append((stamp_to_ns(m.header.stamp), tuple(quaternion_from_msg(m, c.REFERENCE_ATTITUDE)))), qos)
    for t in (c.REFERENCE_RATE, c.REFERENCE_ACCELERATION):  # the reference waits for a subscriber on each
        node.create_subscription(t.msg_class, t.name, lambda m: None, qos)
    node.create_subscription(c.REFERENCE_TF.msg_class, c.REFERENCE_TF.name, lambda m: frames.append(_transform_row(m)), qos)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(ref)
    ex.add_node(node)
    deadline = time.monotonic() + DEADLINE_S
    while clock.get_subscription_count() < 1 or ref.pub_tf.pub.get_subscription_count() < 1:
        assert time.monotonic() < deadline, "the reference node's subscriptions"
        ex.spin_once(timeout_sec=0.02)
    clock.publish(clock_msg(0.0))
    while len(frames) < 2 or len(attitudes) < 2:
        assert time.monotonic() < deadline, f"reference/tf: {len(frames)} of 2 messages"
        ex.spin_once(timeout_sec=0.02)
    assert [ns for ns, _ in attitudes] == [0, 10_000_000]
    np.testing.assert_allclose(attitudes[0][1], Q0, atol=1e-15)
    assert frames == [(ns, "inertial", "reference", q, (0.0, 0.0, 0.0)) for ns, q in attitudes]
    ex.shutdown()
    ref.destroy_node()
    node.destroy_node()


def test_injector_relays_actuator_and_sensor_faults(ros_context, tmp_path) -> None:  # type: ignore[no-untyped-def]
    from spacecraft_sim.disturbance import InjectorNode

    schedule = tmp_path / "faults.yaml"
    schedule.write_text(
        "disturbances:\n  - {kind: constant, torque_Nm: [0.01, 0.0, 0.0]}\n"
        "faults:\n  - {kind: actuator_effectiveness, effectiveness: [0.5, 1.0, 1.0], start_s: 0.0}\n"
        "  - {kind: sensor_dropout, start_s: 0.015, end_s: 0.025}\n"
    )
    inj = InjectorNode(context=ros_context, parameter_overrides=[Parameter("schedule_file", value=str(schedule))])
    node = Node("probe", context=ros_context)
    qos = c.qos_profile()
    pubs = {t.name: node.create_publisher(t.msg_class, t.name, qos) for t in (c.CONTROL_TORQUE, c.STATE_ATTITUDE, c.STATE_RATE, c.CLOCK)}
    got: dict[str, list] = {"d": [], "tq": [], "att": []}
    node.create_subscription(c.DISTURBANCE_TORQUE.msg_class, c.DISTURBANCE_TORQUE.name, lambda m: got["d"].append(torque_from_msg(m, c.DISTURBANCE_TORQUE)), qos)
    node.create_subscription(c.CONTROL_TORQUE.msg_class, "fault/control/torque", lambda m: got["tq"].append(torque_from_msg(m)), qos)
    node.create_subscription(c.STATE_ATTITUDE.msg_class, "fault/state/attitude",
                             lambda m: got["att"].append((stamp_to_ns(m.header.stamp), math.isnan(m.quaternion.w))), qos)
    node.create_subscription(c.STATE_RATE.msg_class, "fault/state/rate", lambda m: None, qos)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(inj)
    ex.add_node(node)
    deadline = time.monotonic() + DEADLINE_S
    while not all(p.get_subscription_count() >= 1 for p in pubs.values()) or len(got) < 3:
        assert time.monotonic() < deadline
        ex.spin_once(timeout_sec=0.02)
    pubs["/clock"].publish(clock_msg(0.0))
    pubs[c.CONTROL_TORQUE.name].publish(torque_msg([0.2, 0.2, 0.2], 0.0))
    for k in range(4):
        pubs[c.STATE_ATTITUDE.name].publish(quaternion_msg(Q0, k * 0.01, c.STATE_ATTITUDE))
        pubs[c.STATE_RATE.name].publish(vector3_msg([0.0, 0.0, 0.0], k * 0.01, c.STATE_RATE))
    while len(got["d"]) < 2 or len(got["tq"]) < 1 or len(got["att"]) < 4:
        assert time.monotonic() < deadline, got
        ex.spin_once(timeout_sec=0.02)
    np.testing.assert_array_equal(got["d"][0], [0.01, 0.0, 0.0])  # sample 0, then sample 1 ahead
    np.testing.assert_array_equal(got["tq"][0], [0.1, 0.2, 0.2])  # 50 % effectiveness on x
    # the sample at 0.02 s dropped: relayed as "no data" (NaN), so the controller knows it is complete
    assert got["att"] == [(0, False), (10_000_000, False), (20_000_000, True), (30_000_000, False)]
    ex.shutdown()
    inj.destroy_node()
    node.destroy_node()


def test_injector_relays_the_sensors_own_topics_each_tracker_sample_once(ros_context, tmp_path) -> None:  # type: ignore[no-untyped-def]
    """With an estimator (``relay_attitude_epoch``) the injector relays ``sensors/gyro`` and
    ``state/attitude_epoch`` paired by stamp, with the ``sensors/star_tracker`` sample the epoch
    names: a sample whose tracker sample has not arrived waits for it (no order among topics), the
    samples are relayed in order, a tracker sample once (stamped with its epoch); under a freeze
    the frozen epoch is relayed and the tracker's next sample is not, until the freeze ends."""
    from sappc_msgs_py.convert import epoch_msg, gyro_msg, ns_to_stamp, star_tracker_msg
    from spacecraft_sim.disturbance import InjectorNode

    schedule = tmp_path / "faults.yaml"
    schedule.write_text("faults:\n  - {kind: sensor_freeze, start_s: 0.005, end_s: 0.035}\n")  # samples 1 to 3 deliver sample 1
    inj = InjectorNode(context=ros_context, parameter_overrides=[Parameter("schedule_file", value=str(schedule)),
                                                                  Parameter("relay_attitude_epoch", value=True)])
    node = Node("probe", context=ros_context)
    qos = c.qos_profile()
    pubs = {t.name: node.create_publisher(t.msg_class, t.name, qos) for t in (c.SENSOR_GYRO, c.STATE_ATTITUDE_EPOCH, c.SENSOR_STAR_TRACKER)}
    got: dict[str, list] = {"gyro": [], "epoch": [], "tracker": []}  # type: ignore[type-arg]
    node.create_subscription(c.SENSOR_GYRO.msg_class, "fault/sensors/gyro", lambda m: got["gyro"].append(stamp_to_ns(m.header.stamp)), qos)
    node.create_subscription(c.STATE_ATTITUDE_EPOCH.msg_class, "fault/state/attitude_epoch",
                             lambda m: got["epoch"].append((stamp_to_ns(m.header.stamp), stamp_to_ns(m.time_ref))), qos)
    node.create_subscription(c.SENSOR_STAR_TRACKER.msg_class, "fault/sensors/star_tracker",
                             lambda m: got["tracker"].append(stamp_to_ns(m.header.stamp)), qos)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(inj)
    ex.add_node(node)
    deadline = time.monotonic() + DEADLINE_S

    def spin_until(condition, what: str) -> None:  # type: ignore[no-untyped-def]
        while not condition():
            assert time.monotonic() < deadline, (what, got)
            ex.spin_once(timeout_sec=0.02)

    spin_until(lambda: all(p.get_subscription_count() >= 1 for p in pubs.values())
               and all(inj.pub_relay[name].pub.get_subscription_count() >= 1 for name in pubs), "matched both ways")
    ms = 1_000_000

    def sample(k: int, epoch_k: int, *, tracker: bool) -> None:
        ns, epoch = k * 10 * ms, epoch_k * 10 * ms
        pubs[c.SENSOR_GYRO.name].publish(gyro_msg([0.0, 0.0, 1e-3 * k], 1e-8, ns_to_stamp(ns), c.SENSOR_GYRO))
        pubs[c.STATE_ATTITUDE_EPOCH.name].publish(epoch_msg(epoch, ns_to_stamp(ns), c.STATE_ATTITUDE_EPOCH))
        if tracker:
            pubs[c.SENSOR_STAR_TRACKER.name].publish(star_tracker_msg(Q0, 1e-10, ns_to_stamp(epoch), c.SENSOR_STAR_TRACKER))

    sample(0, 0, tracker=False)  # its tracker sample after it: nothing relayed yet
    sample(1, 0, tracker=False)
    for _ in range(20):
        ex.spin_once(timeout_sec=0.01)
    assert got == {"gyro": [], "epoch": [], "tracker": []}
    pubs[c.SENSOR_STAR_TRACKER.name].publish(star_tracker_msg(Q0, 1e-10, ns_to_stamp(0), c.SENSOR_STAR_TRACKER))
    spin_until(lambda: len(got["gyro"]) == 2, "samples 0 and 1, in order")
    sample(2, 2, tracker=True)  # frozen: sample 1's content (epoch 0) again
    sample(3, 2, tracker=False)
    sample(4, 4, tracker=True)  # the freeze over: epoch 40 ms, new
    spin_until(lambda: len(got["gyro"]) == 5 and len(got["tracker"]) == 2, "samples 2 to 4")
    assert got["gyro"] == [k * 10 * ms for k in range(5)]
    assert got["epoch"] == [(0, 0), (10 * ms, 0), (20 * ms, 0), (30 * ms, 0), (40 * ms, 40 * ms)]
    assert got["tracker"] == [0, 40 * ms]  # each once; epoch 20 ms never relayed (frozen over)
    ex.shutdown()
    inj.destroy_node()
    node.destroy_node()


def test_a_start_at_the_singularity_is_refused_as_offline(controller, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """q_e0 = 0 at the first sample (180 deg from the reference): the node refuses the step with
    the offline runner's error (issue 12: every entry point applies the same start check),
    commands zero torque, and starts the run at the next valid sample."""
    from gnc_common.validation import InputError
    from sappc.offline.simulate import run_scenario

    node, drv = controller
    singular = (1.0, 0.0, 0.0, 0.0)
    with pytest.raises(InputError) as offline:
        run_scenario(load_scenario(SCENARIOS / "paper_tracking.yaml"), q_BN0=np.array([singular]))
    errors: list[str] = []
    logger = node.get_logger()

    class _Logger:  # the node's logger, keeping its error lines
        def error(self, msg: str, **kw):  # type: ignore[no-untyped-def]
            errors.append(msg)
            return logger.error(msg, **kw)

        def __getattr__(self, name: str):  # type: ignore[no-untyped-def]
            return getattr(logger, name)

    monkeypatch.setattr(node, "get_logger", lambda: _Logger())
    drv.send_sample(0.0, q=singular)
    drv.spin_until(lambda: len(drv.torques) == 1, "the zero torque")
    assert np.all(drv.torques[0][1] == 0.0) and node.steps == 0 and node.stale
    assert len(errors) == 1 and str(offline.value) in errors[0], errors
    drv.send_sample(0.01, q=Q0)  # a valid start: the run starts here
    drv.spin_until(lambda: len(drv.torques) == 2, "the first computed torque")
    assert node.steps == 1 and np.any(drv.torques[1][1] != 0.0)
    drv.spin_until(lambda: len(drv.diags) == 2, "diagnostics")
    assert drv.diags[1]["rho"][1] == pytest.approx(0.4, abs=1e-12)  # the RPF starts at this sample


def test_watchdog_parameters_take_effect_at_run_time_or_are_refused(controller) -> None:  # type: ignore[no-untyped-def]
    """stale_timeout_s and max_stamp_ahead_s: a valid change applies at once (the watchdog then waits
    5 s, not 0.05 s); a negative, NaN or out-of-range value is refused with the reason; both carry
    their range in the descriptor (what parameter tools show)."""
    node, drv = controller
    for name, bad in (("stale_timeout_s", -1.0), ("stale_timeout_s", float("nan")), ("max_stamp_ahead_s", 1e9)):
        (result,) = node.set_parameters([Parameter(name, value=bad)])
        assert not result.successful and (name in result.reason or "range" in result.reason), result.reason
    assert node.stale_timeout_ns == 50_000_000 and node.max_ahead_ns == 1_000_000_000
    (result,) = node.set_parameters([Parameter("stale_timeout_s", value=5.0)])
    assert result.successful and node.stale_timeout_ns == 5_000_000_000
    assert node.get_parameter("stale_timeout_s").value == 5.0
    rng = node.describe_parameter("stale_timeout_s").floating_point_range[0]
    assert (rng.from_value, rng.to_value) == (1e-6, 3600.0)
    drv.send_sample(0.0, q=Q0)
    drv.spin_until(lambda: len(drv.torques) == 1, "the first torque")
    for t in (0.5, 1.0, 1.5):  # far past the old 0.05 s, within the new 5 s: no zero torque
        drv.pub["/clock"].publish(clock_msg(t))
        drv.spin_until(lambda: node._clock_ns == round(t * 1e9), f"/clock {t}")
    assert not node.stale and len(drv.torques) == 1


# ---- the controller's input checks and watchdogs at their boundaries (issue 14) --------------
# Stamps are integer nanoseconds: each boundary is tested at the stated value and 1 ns beyond it.

NS = 1_000_000_000


def test_lockstep_rejects_a_stamp_equal_to_the_last_computed_sample(controller) -> None:  # type: ignore[no-untyped-def]
    """Lockstep: an input is "in the past" when its stamp is not after the last computed sample:
    the same stamp again is rejected (all five inputs, nothing computed), 1 ns later is computed."""
    node, drv = controller
    drv.send_sample(0.01, q=Q0)
    drv.spin_until(lambda: len(drv.torques) == 1, "the torque of 0.01 s")
    drv.send_sample(0.01, q=Q0, clock=False)  # the stamp of the last computed sample
    drv.spin_until(lambda: node.rejected == 5, "five inputs rejected")
    drv.send_sample(0.010000001, q=Q0, clock=False)  # 1 ns later
    drv.spin_until(lambda: len(drv.torques) == 2, "the torque of the sample 1 ns later")
    assert node.rejected == 5 and node.steps == 2 and [ns for ns, _ in drv.torques] == [10_000_000, 10_000_001]


def test_lockstep_accepts_a_stamp_exactly_max_stamp_ahead_s_after_the_clock(controller) -> None:  # type: ignore[no-untyped-def]
    """"More than max_stamp_ahead_s (1 s) ahead of the controller's time" (the latest /clock) is
    rejected: exactly 1 s ahead is computed, 1 ns more is rejected."""
    node, drv = controller
    drv.pub["/clock"].publish(clock_msg(1.0))
    drv.spin_until(lambda: node._clock_ns == NS, "/clock 1 s")
    drv.send_sample(2.0, q=Q0, clock=False)  # 1 s ahead: accepted
    drv.spin_until(lambda: len(drv.torques) == 1, "the torque of 2 s")
    assert drv.torques[0][0] == 2 * NS and node.rejected == 0
    drv.send_sample(2.000000001, q=Q0, clock=False)  # 1 s + 1 ns ahead
    drv.spin_until(lambda: node.rejected == 5, "five far-future inputs rejected")
    assert node.steps == 1


NO_DATA_Q = (math.nan, math.nan, math.nan, math.nan)


def test_lockstep_outage_begins_more_than_stale_timeout_s_after_the_last_valid_state(controller) -> None:  # type: ignore[no-untyped-def]
    """A sample without valid data (the injector's "no data" relay: NaN values) exactly
    stale_timeout_s (0.05 s) after the last valid sample (at 1 s) is answered at once with the
    last torque held; 1 ns later it is an outage: zero torque, stale in diagnostics.  One torque
    per tick."""
    node, drv = controller
    drv.send_sample(1.0, q=Q0)
    drv.spin_until(lambda: len(drv.torques) == 1 and len(drv.diags) == 1, "the first torque")
    drv.send_sample(1.05, q=NO_DATA_Q)
    drv.spin_until(lambda: len(drv.torques) == 2 and len(drv.diags) == 2, "the answer of 1.05 s")
    assert drv.torques[1][0] == 1_050_000_000 and np.array_equal(drv.torques[1][1], drv.torques[0][1]) and np.any(drv.torques[1][1] != 0.0)
    assert drv.diags[1]["status"][2] == c.ANSWER_HELD and not node.stale
    drv.send_sample(1.050000001, q=NO_DATA_Q)
    drv.spin_until(lambda: len(drv.torques) == 3 and len(drv.diags) == 3, "the answer 1 ns later")
    assert drv.torques[2][0] == 1_050_000_001 and drv.torques[2][1].tolist() == [0.0, 0.0, 0.0]
    assert node.stale and drv.diags[2]["status"][2] == c.ANSWER_WATCHDOG_ZERO and drv.diags[2]["status"][1] == 1.0
    drv.pub["/clock"].publish(clock_msg(1.050000001))  # the same tick again: already answered
    drv.send_sample(1.06, q=NO_DATA_Q)
    drv.spin_until(lambda: any(ns == 1_060_000_000 for ns, _ in drv.torques), "the zero torque of 1.06 s")
    assert [ns for ns, _ in drv.torques] == [1_000_000_000, 1_050_000_000, 1_050_000_001, 1_060_000_000]  # one torque per tick
    assert node.rejected == 0 and node.no_data_inputs == 3 and node.steps == 1  # "no data" is counted apart, not rejected


class _WallClock:
    """The node module's ``time`` as the test sets it (``monotonic_ns``)."""

    def __init__(self, ns: int) -> None:
        self.ns = ns

    def monotonic_ns(self) -> int:
        return self.ns


def test_lockstep_grace_answers_a_tick_whose_inputs_never_arrive_once_lockstep_grace_s_has_passed(controller, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """A /clock tick whose inputs never arrive is answered by the grace check no sooner than
    lockstep_grace_s (1 s) of wall time after the tick arrived, exactly then, and once: here with
    the last torque held (the last valid sample is within stale_timeout_s, 10 s here) and no input
    stamps in diagnostics; inputs arriving later are computed but not answered again."""
    import sappc_controller.node as node_module

    node, drv = controller
    (result,) = node.set_parameters([Parameter("stale_timeout_s", value=10.0)])
    assert result.successful
    wall = _WallClock(7 * NS)
    monkeypatch.setattr(node_module, "time", wall)
    published: list[tuple[int, int]] = []
    publish = node._publish
    monkeypatch.setattr(node, "_publish", lambda t_ns, *rest: (published.append((t_ns, rest[-1])), publish(t_ns, *rest)))
    node._check_grace()  # no tick yet: nothing to answer
    drv.send_sample(0.0, q=Q0)
    drv.spin_until(lambda: len(drv.torques) == 1 and len(drv.diags) == 1, "the first torque")
    drv.pub["/clock"].publish(clock_msg(0.01))  # its inputs never arrive
    drv.spin_until(lambda: node._clock_ns == 10_000_000, "/clock 0.01 s")
    assert node._clock_wall_ns == 7 * NS
    wall.ns = 7 * NS + node.grace_ns - 1
    node._check_grace()
    assert published == [(0, c.ANSWER_COMMANDED)]  # 1 ns short of the grace: not answered
    wall.ns = 7 * NS + node.grace_ns
    node._check_grace()
    assert published == [(0, c.ANSWER_COMMANDED), (10_000_000, c.ANSWER_HELD)]
    wall.ns = 9 * NS
    node._check_grace()  # answered already
    drv.spin_until(lambda: len(drv.torques) == 2 and len(drv.diags) == 2, "the held torque")
    assert drv.torques[1][0] == 10_000_000 and np.array_equal(drv.torques[1][1], drv.torques[0][1])
    assert drv.diags[1]["input_stamps_state_s"].tolist() == [0.0, 0.0, 0.0] and drv.diags[1]["input_stamps_reference_s"].tolist() == [0.0, 0.0, 0.0]
    drv.send_sample(0.01, q=Q0, clock=False)  # the lost inputs arrive after all: computed, not answered
    drv.spin_until(lambda: node.steps == 2, "the late sample computed")
    node._check_grace()
    assert published == [(0, c.ANSWER_COMMANDED), (10_000_000, c.ANSWER_HELD)] and len(drv.torques) == 2



@pytest.fixture
def realtime(ros_context, monkeypatch):  # type: ignore[no-untyped-def]
    """A real-time controller whose frame timer (the watchdog) is cancelled: the test calls the
    timer's callback itself, at the times of a clock it sets."""
    with _realtime_controller(ros_context, monkeypatch) as made:
        yield made


@contextlib.contextmanager
def _realtime_controller(ros_context, monkeypatch, **extra):  # type: ignore[no-untyped-def]
    """(node, driver, clock): a real-time controller (10 ms frames, stale_timeout_s 50 ms, and
    ``extra`` parameters) with its frame timer cancelled and a clock the test sets, matched with
    a driver; both destroyed at the end."""
    from sappc_controller.node import ControllerNode

    overrides = _controller_overrides(mode="realtime", control_period_s=0.01, stale_timeout_s=0.05, **extra)  # type: ignore[no-untyped-call]
    node = ControllerNode(context=ros_context, parameter_overrides=overrides)
    for timer in node._frame_timers:
        timer.cancel()
    clock = FakeClock(10 * NS)
    monkeypatch.setattr(node, "get_clock", lambda: clock)
    driver = Driver(ros_context, [node])  # type: ignore[no-untyped-call]
    try:
        driver.matched()
        yield node, driver, clock
    finally:
        driver.executor.shutdown()
        node.destroy_node()
        driver.node.destroy_node()


_REFERENCE = (c.REFERENCE_ATTITUDE, c.REFERENCE_RATE, c.REFERENCE_ACCELERATION)


def _publish(drv, node, topic, stamp_ns: int, value=None) -> None:  # type: ignore[no-untyped-def]
    """Publish one input stamped ``stamp_ns`` and wait until the controller has taken it."""
    if value is None:
        value = Q0 if topic is c.STATE_ATTITUDE else (0.0, 0.0, 0.0, 1.0) if topic is c.REFERENCE_ATTITUDE else (0.0, 0.0, 0.0)
    msg = quaternion_msg(value, 0.0, topic) if len(value) == 4 else vector3_msg(value, 0.0, topic)
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, NS)
    drv.pub[topic.name].publish(msg)
    drv.spin_until(lambda: node._rt.last_ns(topic.name) == stamp_ns, f"{topic.name} at {stamp_ns}")


def test_realtime_computes_on_each_fresh_state_with_the_reference_of_its_stamp(realtime) -> None:  # type: ignore[no-untyped-def]
    """Real time: a step as soon as the attitude and the rate of a new stamp and the reference of
    the same stamp have arrived (published ahead, or after the state), stamped with it; without
    the reference of its stamp, the newest earlier one is held only at the middle of the state's
    frame (the timer), and counted; a reference stamped after the state is never used; the
    latency is measured from the state's stamp."""
    node, drv, clock = realtime
    t0 = 10 * NS
    _publish(drv, node, c.STATE_ATTITUDE, t0)
    _publish(drv, node, c.STATE_RATE, t0)
    assert node.steps == 0  # no reference yet: it waits
    clock.ns = t0 + 6_000_000
    node._on_timer()  # past its mid-frame, but no reference at all to hold: it keeps waiting
    assert node.steps == 0 and node._rt.waiting_ns == t0
    for k in (1, 2):  # the reference of frames 1 and 2, ahead of their states (frame 0's never comes)
        for topic in _REFERENCE:
            _publish(drv, node, topic, t0 + k * 10_000_000)
    clock.ns = t0 + 10_000_000 + 700_000  # the step runs 0.7 ms after the state's stamp
    _publish(drv, node, c.STATE_ATTITUDE, t0 + 10_000_000)
    assert node.steps == 0  # half a state
    _publish(drv, node, c.STATE_RATE, t0 + 10_000_000)
    drv.spin_until(lambda: len(drv.torques) == 1 and len(drv.diags) == 1, "the torque of frame 1")
    assert drv.torques[0][0] == t0 + 10_000_000 and np.any(drv.torques[0][1] != 0.0)
    assert drv.diags[0]["input_stamps_reference_s"].tolist() == [(t0 + 10_000_000) / NS] * 3  # frame 2's, ahead, not used
    assert node.latency.latency.count == 1 and node.latency.latency.max_s == 700_000 / NS and node.latency.late == 0
    # frame 0's state was never stepped (frame 1's replaced it before any reference had come): the
    # first sample not answered as in lockstep
    assert node.held_reference_steps == 0 and node.first_deviating_sample == 0
    node.first_deviating_sample = None  # forgotten, to see frame 3's own below
    clock.ns = t0 + 30_000_000 + 4_999_999  # just before the middle of frame 3
    _publish(drv, node, c.STATE_ATTITUDE, t0 + 30_000_000)
    _publish(drv, node, c.STATE_RATE, t0 + 30_000_000)  # no reference of frame 3: it waits
    node._on_timer()
    assert node.steps == 1 and node._rt.waiting_ns == t0 + 30_000_000
    clock.ns = t0 + 30_000_000 + 5_000_000  # the middle of frame 3: frame 2's reference held
    node._on_timer()
    drv.spin_until(lambda: len(drv.diags) == 2, "the torque of frame 3")
    assert drv.torques[1][0] == t0 + 30_000_000
    assert drv.diags[1]["input_stamps_state_s"].tolist() == [(t0 + 30_000_000) / NS] * 2 + [0.0]
    assert drv.diags[1]["input_stamps_reference_s"].tolist() == [(t0 + 20_000_000) / NS] * 3
    assert node.steps == 2 and node.latency.late == 0 and node.stale is False and node.held_reference_steps == 1
    assert node.first_deviating_sample == 3  # frame 3's torque is not lockstep's (counted from the first state, frame 0)
    # a state complete more than a frame after its stamp (a missed tick's, published late) is not stepped
    for topic in _REFERENCE:
        _publish(drv, node, topic, t0 + 35_000_000)
    clock.ns = t0 + 35_000_000 + 10_000_001
    _publish(drv, node, c.STATE_ATTITUDE, t0 + 35_000_000)
    _publish(drv, node, c.STATE_RATE, t0 + 35_000_000)
    assert node.steps == 2 and node.late_states == 1 and len(drv.torques) == 2
    clock.ns = t0 + 40_000_000 + 1_000_000  # frame 4's reference arrives after its state: the step waits for it, and takes it
    # (frame 4: its stamp is after the late state's; the reference topics' stamps only increase)
    _publish(drv, node, c.STATE_ATTITUDE, t0 + 40_000_000)
    _publish(drv, node, c.STATE_RATE, t0 + 40_000_000)
    assert node.steps == 2
    for topic in _REFERENCE:
        _publish(drv, node, topic, t0 + 40_000_000)
    drv.spin_until(lambda: len(drv.diags) == 3, "the torque of frame 4")
    assert drv.diags[2]["input_stamps_reference_s"].tolist() == [(t0 + 40_000_000) / NS] * 3 and node.held_reference_steps == 1


def test_realtime_watchdog_commands_zero_torque_when_an_input_is_older_than_stale_timeout_s(realtime) -> None:  # type: ignore[no-untyped-def]
    """Real time: a fresh state is stepped while its oldest input is at most stale_timeout_s old
    (exactly that old included); 1 ns older, it is answered with zero torque at its stamp; and the
    watchdog in the middle of each frame commands zero torque, stamped with the current frame, once
    no state is newer than stale_timeout_s, once per frame; new inputs are computed again."""
    node, drv, clock = realtime
    t0 = 10 * NS
    for topic in _REFERENCE:
        _publish(drv, node, topic, t0)
    s1, s2 = t0 + 45_000_000, t0 + 45_000_001  # two states whose own reference never comes (t0's is held)
    clock.ns = s1 + 5_000_000  # the middle of s1's frame: the reference held, exactly stale_timeout_s old
    _publish(drv, node, c.STATE_ATTITUDE, s1)
    _publish(drv, node, c.STATE_RATE, s1)
    node._on_timer()
    drv.spin_until(lambda: len(drv.torques) == 1, "the first torque")
    assert np.any(drv.torques[0][1] != 0.0) and node.steps == 1 and not node.stale
    clock.ns = s2 + 5_000_000  # the reference 1 ns older than stale_timeout_s (the state itself fresh)
    _publish(drv, node, c.STATE_ATTITUDE, s2)
    _publish(drv, node, c.STATE_RATE, s2)
    node._on_timer()
    drv.spin_until(lambda: len(drv.diags) == 2, "the second answer")
    assert drv.torques[1][0] == s2 and drv.torques[1][1].tolist() == [0.0, 0.0, 0.0]
    assert drv.diags[1]["status"][1] == 1.0 and drv.diags[1]["status"][2] == c.ANSWER_WATCHDOG_ZERO and node.steps == 1 and node.stale
    assert drv.diags[1]["input_stamps_state_s"].tolist() == [0.0, 0.0, 0.0]  # no step: no input used
    # the watchdog: the last state (s2) exactly stale_timeout_s old: nothing
    clock.ns = s2 + 50_000_000
    node._on_timer()
    clock.ns += 1  # 1 ns older: zero torque stamped with the current frame (t0 + 90 ms), once
    node._on_timer()
    node._on_timer()
    drv.spin_until(lambda: len(drv.torques) == 3, "the watchdog's zero torque")
    for topic in _REFERENCE:  # valid inputs again (frame 10)
        _publish(drv, node, topic, t0 + 100_000_000)
    clock.ns = t0 + 100_000_000 + 1_000_000
    _publish(drv, node, c.STATE_ATTITUDE, t0 + 100_000_000)
    _publish(drv, node, c.STATE_RATE, t0 + 100_000_000)
    drv.spin_until(lambda: len(drv.torques) == 4, "control again")
    assert [ns for ns, _ in drv.torques] == [s1, s2, t0 + 90_000_000, t0 + 100_000_000]
    assert drv.torques[2][1].tolist() == [0.0, 0.0, 0.0] and np.any(drv.torques[3][1] != 0.0)
    assert node.steps == 2 and not node.stale and node.rejected == 0


def test_realtime_controller_answers_nothing_past_its_runs_last_frame(ros_context, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """With duration_s (two frames here), the state of the frame duration_s after the first is the
    last answered: a later state is not stepped, and the watchdog, which would command zero torque
    once no state came for stale_timeout_s (the plant has finished), stays silent: no torque is
    published past the run's end (a composed run used to answer 10 s of them)."""
    with _realtime_controller(ros_context, monkeypatch, duration_s=0.02) as (node, drv, clock):
        t0 = 10 * NS
        for k in range(4):
            for topic in _REFERENCE:
                _publish(drv, node, topic, t0 + k * 10_000_000)
        for k in range(3):  # the first state, then the two frames of duration_s
            clock.ns = t0 + k * 10_000_000 + 500_000
            _publish(drv, node, c.STATE_ATTITUDE, t0 + k * 10_000_000)
            _publish(drv, node, c.STATE_RATE, t0 + k * 10_000_000)
            drv.spin_until(lambda: len(drv.torques) == k + 1, f"the torque of frame {k}")
        clock.ns = t0 + 30_000_000 + 500_000  # a state past the end (the node no longer takes it in)
        drv.pub[c.STATE_ATTITUDE.name].publish(quaternion_msg(Q0, (t0 + 30_000_000) / NS, c.STATE_ATTITUDE))
        drv.pub[c.STATE_RATE.name].publish(vector3_msg((0.0, 0.0, 0.0), (t0 + 30_000_000) / NS, c.STATE_RATE))
        bad = vector3_msg((0.0, 0.0, 0.0), (t0 + 10_000_000) / NS, c.STATE_RATE)  # in the past, and Inf: not even looked at
        bad.vector.x = math.inf
        drv.pub[c.STATE_RATE.name].publish(bad)
        drv.executor.spin_once(timeout_sec=0.2)
        drv.executor.spin_once(timeout_sec=0.2)
        assert node.rejected == 0  # nothing after the last frame is counted: no diagnostics could carry it (issue 46)
        clock.ns += 10 * 10_000_000  # long after the last state: the watchdog would answer
        node._on_timer()
        drv.executor.spin_once(timeout_sec=0.2)
        assert [ns for ns, _ in drv.torques] == [t0 + k * 10_000_000 for k in range(3)] and node.steps == 3


def test_realtime_controller_is_silent_past_its_last_frame_even_when_it_did_not_answer_it(ros_context, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """The last frame's state came more than a frame late (not stepped: a loaded machine): the
    watchdog still publishes nothing stamped past the run's last frame."""
    with _realtime_controller(ros_context, monkeypatch, duration_s=0.01) as (node, drv, clock):
        t0 = 10 * NS
        for k in range(2):
            for topic in _REFERENCE:
                _publish(drv, node, topic, t0 + k * 10_000_000)
        clock.ns = t0 + 500_000
        _publish(drv, node, c.STATE_ATTITUDE, t0)
        _publish(drv, node, c.STATE_RATE, t0)
        drv.spin_until(lambda: len(drv.torques) == 1, "the torque of the first frame")
        clock.ns = t0 + 10_000_000 + 10_000_001  # the last frame's state, complete more than a frame late
        _publish(drv, node, c.STATE_ATTITUDE, t0 + 10_000_000)
        _publish(drv, node, c.STATE_RATE, t0 + 10_000_000)
        assert node.late_states == 1 and len(drv.torques) == 1
        for late in (60_000_000, 200_000_000):  # no state newer than stale_timeout_s, past the last frame
            clock.ns = t0 + late
            node._on_timer()
        drv.executor.spin_once(timeout_sec=0.2)
        assert [ns for ns, _ in drv.torques] == [t0] and node.answers["watchdog_zero"] == 0


def test_realtime_input_checks_are_per_topic_and_relative_to_the_node_clock(realtime) -> None:  # type: ignore[no-untyped-def]
    """Real time: "in the past" is not after the topic's previous message (the same stamp again is
    rejected, 1 ns later accepted; another topic may carry the same stamp); "far future" is more
    than max_stamp_ahead_s (1 s) ahead of the node's clock."""
    node, drv, clock = realtime
    att = c.STATE_ATTITUDE.name
    drv.send_sample(10.0, q=Q0, clock=False)
    drv.spin_until(lambda: all(node._rt.last_ns(t.name) == 10 * NS for t in c.CONTROLLER_INPUTS), "the five inputs")
    drv.pub[att].publish(quaternion_msg(Q0, 10.0, c.STATE_ATTITUDE))  # the same stamp on the same topic
    drv.spin_until(lambda: node.rejected == 1, "the repeated stamp rejected")
    drv.pub[att].publish(quaternion_msg(Q0, 10.000000001, c.STATE_ATTITUDE))
    drv.spin_until(lambda: node._rt.last_ns(att) == 10 * NS + 1, "1 ns later accepted")
    drv.pub[att].publish(quaternion_msg(Q0, 11.000000001, c.STATE_ATTITUDE))  # 1 s + 1 ns ahead of the clock
    drv.spin_until(lambda: node.rejected == 2, "the far-future stamp rejected")
    drv.pub[att].publish(quaternion_msg(Q0, 11.0, c.STATE_ATTITUDE))  # exactly 1 s ahead
    drv.spin_until(lambda: node._rt.last_ns(att) == 11 * NS, "1 s ahead accepted")
    assert node.rejected == 2 and node._rt.last_ns(c.STATE_RATE.name) == 10 * NS


def test_watchdog_parameters_accept_the_ends_of_their_range(controller) -> None:  # type: ignore[no-untyped-def]
    """stale_timeout_s and max_stamp_ahead_s take any value in [1e-6, 3600] s, ends included, in
    nanoseconds rounded to the nearest."""
    node, _ = controller
    for name, attr in (("stale_timeout_s", "stale_timeout_ns"), ("max_stamp_ahead_s", "max_ahead_ns")):
        for seconds, ns in ((1e-6, 1_000), (3600.0, 3_600 * NS), (0.0123456789, 12_345_679)):
            (result,) = node.set_parameters([Parameter(name, value=seconds)])
            assert result.successful, (name, seconds, result.reason)
            assert getattr(node, attr) == ns, (name, seconds)


def test_each_stamp_is_answered_once_and_diagnostics_carry_the_input_stamps(controller) -> None:  # type: ignore[no-untyped-def]
    """Lockstep answers each stamp with one torque: a stamp already answered (here with the zero
    torque of a refused singular start) is computed again when its inputs complete again, but not
    answered twice; control torques resume at the next stamp, whose diagnostics carry the inputs'
    stamps [s] (state: attitude, rate, 0; reference: attitude, rate, acceleration)."""
    node, drv = controller
    drv.send_sample(0.0, q=(1.0, 0.0, 0.0, 0.0))  # 180 deg from the reference: the step is refused, zero torque
    drv.spin_until(lambda: len(drv.torques) == 1, "the zero torque of 0 s")
    drv.send_sample(0.0, q=Q0, clock=False)  # the same stamp, valid: computed, not answered again
    drv.spin_until(lambda: node.steps == 1, "the valid sample of 0 s computed")
    drv.send_sample(0.01, q=Q0)
    drv.spin_until(lambda: len(drv.torques) == 2 and len(drv.diags) == 2, "the torque of 0.01 s")
    assert [ns for ns, _ in drv.torques] == [0, 10_000_000] and np.any(drv.torques[1][1] != 0.0)
    assert drv.diags[1]["time_s"].tolist() == [0.01, 0.01, 0.01]
    assert drv.diags[1]["input_stamps_state_s"].tolist() == [0.01, 0.01, 0.0]
    assert drv.diags[1]["input_stamps_reference_s"].tolist() == [0.01, 0.01, 0.01]


def test_grid_cursor_owes_each_sample_once_up_to_the_grid_end() -> None:
    from sappc_msgs_py.runtime import GridCursor

    cursor = GridCursor(last=5)
    assert list(cursor.through(1)) == [0, 1]  # the start: samples 0 and 1, before any tick
    assert list(cursor.through(1)) == []  # tick 0: nothing owed
    assert list(cursor.through(4)) == [2, 3, 4]  # tick 3 after missed ticks 1 and 2: made up
    assert list(cursor.through(2)) == []  # an old tick publishes nothing again
    assert list(cursor.through(9)) == [5]  # capped at the grid's last sample
    assert list(GridCursor(None).through(2)) == [0, 1, 2]


def test_reference_publishes_its_first_samples_before_any_clock_and_makes_up_missed_ticks(ros_context) -> None:  # type: ignore[no-untyped-def]
    """The plant's first /clock tick may be sent before the reference's subscription is matched
    (it used to cost the first two samples 2 s each); samples 0 and 1 therefore go out as soon as
    the controller is matched, and a later tick publishes every sample a missed tick left out."""
    from spacecraft_sim.reference import ReferenceNode

    ref = ReferenceNode(context=ros_context, parameter_overrides=[Parameter("duration_s", value=0.05)])
    node = Node("probe", context=ros_context)
    qos = c.qos_profile()
    got: dict[str, list[int]] = {t.name: [] for t in (c.REFERENCE_ATTITUDE, c.REFERENCE_RATE, c.REFERENCE_ACCELERATION)}
    for t in (c.REFERENCE_ATTITUDE, c.REFERENCE_RATE, c.REFERENCE_ACCELERATION):
        node.create_subscription(t.msg_class, t.name, lambda m, name=t.name: got[name].append(stamp_to_ns(m.header.stamp)), qos)
    clock = node.create_publisher(c.CLOCK.msg_class, c.CLOCK.name, qos)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(ref)
    ex.add_node(node)

    def spin_until(condition, what: str) -> None:  # type: ignore[no-untyped-def]
        deadline = time.monotonic() + DEADLINE_S
        while not condition():
            assert time.monotonic() < deadline, f"timed out waiting for {what}: {got}"
            ex.spin_once(timeout_sec=0.02)

    ms = 1_000_000
    spin_until(lambda: all(len(v) == 2 for v in got.values()), "samples 0 and 1 without a /clock")
    assert all(v == [0, 10 * ms] for v in got.values())
    spin_until(lambda: clock.get_subscription_count() >= 1, "the reference's /clock subscription")
    clock.publish(clock_msg(0.03))  # ticks 0.01 and 0.02 missed: samples 2, 3 and 4 owed
    spin_until(lambda: all(len(v) == 5 for v in got.values()), "the samples the missed ticks left out")
    clock.publish(clock_msg(0.05))  # the last tick: sample 5, nothing beyond the grid
    spin_until(lambda: all(len(v) == 6 for v in got.values()), "the last sample")
    assert all(v == [k * 10 * ms for k in range(6)] for v in got.values())
    ex.shutdown()
    ref.destroy_node()
    node.destroy_node()


def test_plant_publishes_its_first_sample_only_once_a_controller_is_there(ros_context) -> None:  # type: ignore[no-untyped-def]
    """State subscribers alone (a recorder, a viewer) do not start the lockstep loop: a sample
    published before the controller's torque publisher exists would be answered by no one."""
    from spacecraft_sim.plant_node import PlantNode

    plant = PlantNode(context=ros_context, parameter_overrides=[Parameter("duration_s", value=0.02), Parameter("q_BN0", value=list(Q0))])
    node = Node("viewer", context=ros_context)
    qos = c.qos_profile()
    states: list[int] = []
    node.create_subscription(c.STATE_ATTITUDE.msg_class, c.STATE_ATTITUDE.name, lambda m: states.append(stamp_to_ns(m.header.stamp)), qos)
    node.create_subscription(c.STATE_RATE.msg_class, c.STATE_RATE.name, lambda m: None, qos)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(plant)
    ex.add_node(node)
    deadline = time.monotonic() + DEADLINE_S
    while not (plant.pub_att.matched() and plant.pub_rate.matched()):
        assert time.monotonic() < deadline, "the viewer's subscriptions were not matched"
        ex.spin_once(timeout_sec=0.02)
    for _ in range(20):  # 20 start checks (START_CHECK_S each) with everything but a controller
        ex.spin_once(timeout_sec=0.02)
    assert states == [] and plant._not_ready() == ["a publisher of /control/torque"]
    pub = node.create_publisher(c.CONTROL_TORQUE.msg_class, c.CONTROL_TORQUE.name, qos)
    while not states:
        assert time.monotonic() < deadline, "the plant did not start once a controller was there"
        ex.spin_once(timeout_sec=0.02)
    assert states == [0] and pub.get_subscription_count() == 1
    ex.shutdown()
    plant.destroy_node()
    node.destroy_node()


def test_callback_times_counts_every_call_of_each_subscription_and_timer(ros_context, tmp_path) -> None:  # type: ignore[no-untyped-def]
    """The developer aid SAPPC_CALLBACK_TIMES_DIR (runtime.CallbackTimes): each subscription's and
    timer's callback still runs, its calls are counted exactly per node and topic, and the JSON says
    so (the times are wall times: only their sign is certain)."""
    import json

    from rclpy.serialization import serialize_message

    from sappc_msgs_py.runtime import CallbackTimes

    node = Node("timed", context=ros_context)
    taken: list[object] = []
    sub = node.create_subscription(c.STATE_RATE.msg_class, c.STATE_RATE.name, taken.append, c.qos_profile(), raw=True)
    timer = node.create_timer(3600.0, lambda: taken.append("tick"))
    times = CallbackTimes([node])  # type: ignore[list-item]
    raw = serialize_message(c.STATE_RATE.msg_class())
    for _ in range(3):
        sub.callback(raw)
    timer.callback()
    times.write(tmp_path / "times.json")
    doc = json.loads((tmp_path / "times.json").read_text())
    assert taken == [raw, raw, raw, "tick"]
    assert doc["timed"]["/state/rate"]["calls"] == 3 and doc["timed"]["timer"]["calls"] == 1
    assert doc["timed"]["/state/rate"]["total_s"] >= 0.0 and doc["timed"]["/state/rate"]["us_per_call"] >= 0.0
    node.destroy_node()

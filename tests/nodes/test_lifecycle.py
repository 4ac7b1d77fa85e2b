"""The controller as a ROS 2 managed (lifecycle) node (issue 49, item 2), driven the way any ROS 2
tool drives one: a plain rclpy client of ``lifecycle_msgs`` (``ChangeState`` and ``GetState`` on
``/controller/change_state`` and ``/controller/get_state``), no project code on the client's side.

In-process on an isolated domain (the ``ros_context`` fixture), with the lockstep driver of
test_nodes.py standing in for the plant and the reference: every transition and the state after
it, a transition refused from the wrong state, what an inactive controller answers (zero torque,
the answer ``inactive``), the law again once active, a bad parameter failing the configure
transition with the node alive and unconfigured.  Then the same as a process (``python -m
sappc_controller -p managed:=true``, on rclpy's ``EventsExecutor`` as every node runs), stopped by
SIGINT, with no shared memory left behind.  Waits are on conditions with a deadline, never on
fixed sleeps.  The client, the process and the checks every managed node shares: tests/lifecycle_client.py."""

from __future__ import annotations

import math

import numpy as np
import pytest
from lifecycle_msgs.msg import Transition

from sappc_msgs_py import contract as c

from conftest import ROOT
from fake_clock import FakeClock
from lifecycle_client import (ACTIVE, FINALIZED, INACTIVE, UNCONFIGURED, LifecycleClient, assert_configure_fails, assert_not_managed,
                              captured_log, closing, managed_process)
from test_nodes import _REFERENCE, DEADLINE_S, NS, Q0, Driver, _controller_overrides, _publish

#: The actuator limit of the paper's scenario [N m] (config/scenarios/paper_tracking.yaml).
MAX_TORQUE_NM = 0.5
#: The diagnostics' rows of the law's performance function (NaN before its first step).
RPF_ROWS = ("rho", "band_lower", "band_upper", "eps", "z", "lyapunov_V")


@pytest.fixture
def managed(ros_context):  # type: ignore[no-untyped-def]
    """(node, driver, lifecycle client): a managed SAPPC controller (the paper's scenario's gains),
    unconfigured, with the lockstep driver and a lifecycle client on the driver's node."""
    from sappc_controller.node import ControllerNode

    node = ControllerNode(context=ros_context, parameter_overrides=_controller_overrides(stale_timeout_s=0.05, managed=True))  # type: ignore[no-untyped-call]
    driver = Driver(ros_context, [node])  # type: ignore[no-untyped-call]
    with closing(node, driver):
        yield node, driver, LifecycleClient(driver.node, "controller", driver.spin_until)


def _answered(drv: Driver, t: float) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Send the lockstep sample of ``t`` (the paper's initial attitude, identity reference: an
    attitude error of about 50 deg) and return its torque and diagnostics."""
    n = len(drv.torques)
    drv.send_sample(t, q=Q0)
    drv.spin_until(lambda: len(drv.torques) == n + 1 and len(drv.diags) == n + 1, f"the answer of {t} s")
    stamp, torque = drv.torques[-1]
    assert stamp == round(t * 1e9)
    return torque, drv.diags[-1]


def _assert_inactive_answer(torque: np.ndarray, diag: dict[str, np.ndarray]) -> None:
    assert torque.tolist() == [0.0, 0.0, 0.0]
    assert diag["status"][1:].tolist() == [1.0, c.ANSWER_INACTIVE]
    assert diag["torque_cmd_Nm"].tolist() == [0.0, 0.0, 0.0] and diag["saturated"].tolist() == [0.0, 0.0, 0.0]
    assert diag["input_stamps_state_s"].tolist() == [0.0, 0.0, 0.0] and diag["input_stamps_reference_s"].tolist() == [0.0, 0.0, 0.0]


def test_the_lifecycle_through_lifecycle_msgs_services_and_what_each_state_answers(managed) -> None:  # type: ignore[no-untyped-def]
    """unconfigured -> configure -> inactive -> activate -> active -> deactivate -> inactive ->
    activate -> deactivate -> cleanup -> unconfigured -> configure -> inactive -> shutdown ->
    finalized, each state read back with GetState; transitions from the wrong state refused
    (``success: false``, the state unchanged).  Inactive, the controller answers every lockstep
    sample (valid or not) with zero torque and the answer ``inactive``, steps no law, and keeps the
    last computed sample's performance-function rows; active, the law commands a non-zero torque
    on a 50 deg error."""
    node, drv, lc = managed
    assert lc.state() == UNCONFIGURED
    # unconfigured: nothing subscribed, nothing offered, no parameter of the law declared
    assert all(p.get_subscription_count() == 0 for p in drv.pub.values())
    assert all(s.get_publisher_count() == 0 for s in drv.outputs)
    assert not node.has_parameter("controller") and not node.has_parameter("sappc.gains.K_q")
    assert not lc.transition(Transition.TRANSITION_ACTIVATE)  # not from unconfigured
    assert not lc.transition(Transition.TRANSITION_DEACTIVATE)
    assert lc.state() == UNCONFIGURED

    assert lc.transition(Transition.TRANSITION_CONFIGURE)
    assert lc.state() == INACTIVE
    assert node.get_parameter("sappc.gains.K_q").value == 0.3 and node.controller.config.gains.K_q == 0.3  # the law built from them
    drv.matched()  # subscribed, and the outputs offered once every input had a publisher
    # inactive before the first activation: zero torque, no law, no performance function yet
    torque, diag = _answered(drv, 0.0)
    _assert_inactive_answer(torque, diag)
    assert all(np.isnan(diag[row]).all() for row in RPF_ROWS)
    assert node.steps == 0 and node.controller.t0 is None
    assert not lc.transition(Transition.TRANSITION_CONFIGURE)  # configured already
    assert not lc.transition(Transition.TRANSITION_CLEANUP + 100)  # no such transition
    assert lc.state() == INACTIVE

    assert lc.transition(Transition.TRANSITION_ACTIVATE)
    assert lc.state() == ACTIVE
    torque, commanded = _answered(drv, 0.01)
    assert commanded["status"].tolist() == [0.0, 0.0, c.ANSWER_COMMANDED] and node.steps == 1
    assert np.linalg.norm(torque) > 1e-3 and np.all(np.abs(torque) <= MAX_TORQUE_NM)
    assert node.controller.t0 == 0.01  # the law starts at its first valid sample while active
    assert commanded["rho"][1] == pytest.approx(0.4, abs=1e-12)  # the RPF starts at rho_e0 on the largest axis

    assert lc.transition(Transition.TRANSITION_DEACTIVATE)
    assert lc.state() == INACTIVE
    torque, diag = _answered(drv, 0.02)
    _assert_inactive_answer(torque, diag)
    for row in RPF_ROWS:  # the last computed sample's rows, kept (as the offline loop records a sample it does not command)
        np.testing.assert_array_equal(diag[row], commanded[row])
    # a sample without valid inputs: active, the last torque would be held (stale_timeout_s not
    # passed); inactive, zero as every other answer
    n = len(drv.torques)
    drv.send_sample(0.03, q=(math.nan, 0.0, 0.0, 1.0))
    drv.spin_until(lambda: len(drv.torques) == n + 1 and len(drv.diags) == n + 1, "the answer of the invalid sample")
    _assert_inactive_answer(drv.torques[-1][1], drv.diags[-1])
    assert node.steps == 1 and node.rejected == 1

    assert lc.transition(Transition.TRANSITION_ACTIVATE)  # the law starts again, afresh, at its first valid sample while active
    torque, diag = _answered(drv, 0.04)
    assert diag["status"][2] == c.ANSWER_COMMANDED and node.steps == 2 and node.controller.t0 == 0.04
    assert diag["rho"][1] == pytest.approx(0.4, abs=1e-12)  # its RPF from rho_e0 again, as at the first start
    assert np.linalg.norm(torque) > 1e-3 and np.all(np.abs(torque) <= MAX_TORQUE_NM)
    assert not lc.transition(Transition.TRANSITION_CLEANUP)  # not from active
    assert lc.state() == ACTIVE

    assert lc.transition(Transition.TRANSITION_DEACTIVATE)
    assert lc.transition(Transition.TRANSITION_CLEANUP)
    assert lc.state() == UNCONFIGURED
    # everything configure created is gone: the inputs unsubscribed, the outputs withdrawn
    drv.spin_until(lambda: all(p.get_subscription_count() == 0 for p in drv.pub.values()), "the subscriptions destroyed")
    drv.spin_until(lambda: all(s.get_publisher_count() == 0 for s in drv.outputs), "the outputs withdrawn")
    assert node.answers == {"commanded": 2, "watchdog_zero": 0, "held": 0, "refused": 0, "inactive": 3}
    assert node.publish_counts() == {"/control/torque": 5, "/controller/diagnostics": 5}  # counted though the publishers are gone

    assert lc.transition(Transition.TRANSITION_CONFIGURE)  # the same parameters read again: a new law
    assert lc.state() == INACTIVE
    assert node.steps == 0 and node.controller.t0 is None and node.configurations == 2
    assert lc.transition(Transition.TRANSITION_INACTIVE_SHUTDOWN)
    assert lc.state() == FINALIZED
    assert not lc.transition(Transition.TRANSITION_CONFIGURE)  # nothing leaves finalized
    drv.spin_until(lambda: all(p.get_subscription_count() == 0 for p in drv.pub.values()), "the subscriptions destroyed at shutdown")
    assert all(np.all(np.isfinite(tq)) and np.all(np.abs(tq) <= MAX_TORQUE_NM) for _, tq in drv.torques)


@pytest.mark.parametrize(("bad", "named"), [
    ({"control_period_s": -0.01}, "control_period_s"),  # the node's own check
    ({"sappc.gains.K_q": -1.0}, "sappc.gains.K_q"),  # refused by the parameter's declared range
    ({"sappc.gains.K_typo": 1.0}, "sappc.gains.K_typo"),  # unknown: a typo is not ignored
    ({"controller": "pid"}, "controller"),  # not a law
])
def test_a_bad_parameter_fails_the_configure_transition_and_the_node_stays_unconfigured(ros_context, bad, named) -> None:  # type: ignore[no-untyped-def]
    """The same parameters that stop a plain controller at start-up (exit status 2) fail a managed
    one's configure transition: ``success: false``, the reason logged naming the parameter, the
    node alive and unconfigured, nothing of the attempt left (no subscription, timer or publisher);
    a second attempt fails alike."""
    from sappc_controller.node import ControllerNode

    node = ControllerNode(context=ros_context, parameter_overrides=_controller_overrides(managed=True, **bad))  # type: ignore[no-untyped-call]
    driver = Driver(ros_context, [node])  # type: ignore[no-untyped-call]
    with closing(node, driver), captured_log(node) as (errors, _):
        lc = LifecycleClient(driver.node, "controller", driver.spin_until)
        assert_configure_fails(lc, node, errors, named, attempts=2)
        assert node.closing_line().startswith("finished: never configured")


def test_an_inactive_realtime_controller_answers_each_fresh_state_and_its_watchdog_with_zero(ros_context, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """Real time (10 ms frames, stale_timeout_s 50 ms, the frame timer replaced by the test's
    calls at the times of a clock it sets, as test_nodes.py's real-time tests do): inactive, a
    fresh state with its reference is answered at once with zero torque (``inactive``), and so is
    the watchdog's frame once no state is newer than stale_timeout_s; once activated, the next
    fresh state is computed by the law."""
    from sappc_controller.node import ControllerNode

    overrides = _controller_overrides(mode="realtime", control_period_s=0.01, stale_timeout_s=0.05, managed=True)  # type: ignore[no-untyped-call]
    node = ControllerNode(context=ros_context, parameter_overrides=overrides)
    clock = FakeClock(10 * NS)
    monkeypatch.setattr(node, "get_clock", lambda: clock)
    drv = Driver(ros_context, [node])  # type: ignore[no-untyped-call]
    with closing(node, drv):
        lc = LifecycleClient(drv.node, "controller", drv.spin_until)
        assert lc.transition(Transition.TRANSITION_CONFIGURE)
        for timer in node._frame_timers:  # the frame timer (the watchdog) is the test's to call
            timer.cancel()
        drv.matched()
        drv.spin_until(node._gate.open, "the controller's outputs matched")
        t0 = 10 * NS
        for stamp in (t0, t0 + 70_000_000):
            for topic in _REFERENCE:
                _publish(drv, node, topic, stamp)
        clock.ns = t0 + 1_000_000
        _publish(drv, node, c.STATE_ATTITUDE, t0)
        _publish(drv, node, c.STATE_RATE, t0)
        drv.spin_until(lambda: len(drv.torques) == 1 and len(drv.diags) == 1, "the answer of the first state")
        assert drv.torques[0][0] == t0
        _assert_inactive_answer(drv.torques[0][1], drv.diags[0])
        clock.ns = t0 + 60_000_000 + 5_000_000  # the middle of frame 6: the last state 65 ms old
        node._on_timer()
        drv.spin_until(lambda: len(drv.torques) == 2 and len(drv.diags) == 2, "the watchdog's answer")
        assert drv.torques[1][0] == t0 + 60_000_000
        _assert_inactive_answer(drv.torques[1][1], drv.diags[1])
        assert node.steps == 0 and node.answers["inactive"] == 2
        assert lc.transition(Transition.TRANSITION_ACTIVATE)
        clock.ns = t0 + 70_000_000 + 1_000_000
        _publish(drv, node, c.STATE_ATTITUDE, t0 + 70_000_000)
        _publish(drv, node, c.STATE_RATE, t0 + 70_000_000)
        drv.spin_until(lambda: len(drv.torques) == 3 and len(drv.diags) == 3, "the law's answer")
        assert drv.diags[2]["status"][2] == c.ANSWER_COMMANDED and node.steps == 1
        assert np.linalg.norm(drv.torques[2][1]) > 1e-3 and np.all(np.abs(drv.torques[2][1]) <= MAX_TORQUE_NM)


def test_destroying_a_managed_node_withdraws_its_lifecycle_services(ros_context) -> None:  # type: ignore[no-untyped-def]
    """``destroy_node`` takes the lifecycle services with it (rclpy's state machine holds them
    and the node's handle until it is destroyed too): a client of a later node of the same name
    on the domain never meets a server that cannot answer."""
    from sappc_controller.node import ControllerNode

    node = ControllerNode(context=ros_context, parameter_overrides=_controller_overrides(managed=True))  # type: ignore[no-untyped-call]
    driver = Driver(ros_context, [node])  # type: ignore[no-untyped-call]
    try:
        lc = LifecycleClient(driver.node, "controller", driver.spin_until)  # its clients matched with the node's services
        driver.executor.remove_node(node)
        node.destroy_node()
        driver.spin_until(lambda: not lc.change.service_is_ready() and not lc.get.service_is_ready(), "the lifecycle services withdrawn")
    finally:
        driver.executor.shutdown()
        driver.node.destroy_node()


def test_a_controller_not_managed_starts_active_and_offers_no_lifecycle_services(ros_context) -> None:  # type: ignore[no-untyped-def]
    """The default (``managed`` false): configured and active while it is built, as before the
    lifecycle existed; no lifecycle service; its first sample commanded by the law."""
    from sappc_controller.node import ControllerNode

    node = ControllerNode(context=ros_context, parameter_overrides=_controller_overrides())  # type: ignore[no-untyped-call]
    driver = Driver(ros_context, [node])  # type: ignore[no-untyped-call]
    with closing(node, driver):
        assert_not_managed(node, "controller")
        driver.matched()
        torque, diag = _answered(driver, 0.0)
        assert diag["status"][2] == c.ANSWER_COMMANDED and np.linalg.norm(torque) > 1e-3


def _managed_process(ros_context, *params: str):  # type: ignore[no-untyped-def]
    """(process, driver, lifecycle client, its log once stopped): ``python -m sappc_controller``
    managed, with the SAPPC parameters of config/controller_sappc.yaml and ``params`` (``-p``
    entries), a driver (test_nodes.py's) and a lifecycle client on this process's side
    (:func:`lifecycle_client.managed_process`: SIGINT at the end, the shared memory checked)."""
    return managed_process("sappc_controller", ROOT / "config" / "controller_sappc.yaml", params,
                           lambda: Driver(ros_context, []), DEADLINE_S)  # type: ignore[no-untyped-call]


@pytest.mark.slow
def test_the_managed_controller_process_is_brought_up_and_down_through_its_lifecycle_services(ros_context) -> None:  # type: ignore[no-untyped-def]
    """``python -m sappc_controller -p managed:=true`` (rclpy's ``EventsExecutor``, which must take
    the subscriptions and timers a transition creates): unconfigured until configured, a
    transition from the wrong state refused without ending the process; configured, it answers a
    lockstep sample with zero torque (inactive); activated, with the law; deactivated, zero again;
    stopped by SIGINT: exit 0, its closing line counting each answer."""
    with _managed_process(ros_context, "stale_timeout_s:=0.05") as (proc, driver, lc, out):
        assert lc.state() == UNCONFIGURED
        # refused, and the process lives on (rclpy's own handler raises out of the executor here)
        assert not lc.transition(Transition.TRANSITION_ACTIVATE)
        assert lc.state() == UNCONFIGURED and proc.poll() is None
        assert lc.transition(Transition.TRANSITION_CONFIGURE)
        assert lc.state() == INACTIVE
        driver.matched()
        torque, diag = _answered(driver, 0.0)
        _assert_inactive_answer(torque, diag)
        assert lc.transition(Transition.TRANSITION_ACTIVATE)
        torque, diag = _answered(driver, 0.01)
        assert diag["status"][2] == c.ANSWER_COMMANDED and np.linalg.norm(torque) > 1e-3 and np.all(np.abs(torque) <= MAX_TORQUE_NM)
        assert lc.transition(Transition.TRANSITION_DEACTIVATE)
        assert lc.state() == INACTIVE
        torque, diag = _answered(driver, 0.02)
        _assert_inactive_answer(torque, diag)
    log = out["log"]
    assert proc.returncode == 0, log
    assert "finished: answered 3 samples: 1 commanded, 0 held, 0 watchdog zero, 0 refused, 2 inactive (1 control steps computed)" in log, log


@pytest.mark.slow
def test_a_managed_controller_process_with_a_bad_parameter_lives_on_unconfigured(ros_context) -> None:  # type: ignore[no-untyped-def]
    """Not managed, ``control_period_s:=-1.0`` stops the controller at start-up with exit status 2;
    managed, the configure transition fails, the process lives on unconfigured and answers its
    services, and stops cleanly on SIGINT (exit 0)."""
    with _managed_process(ros_context, "control_period_s:=-1.0") as (proc, _driver, lc, out):
        assert not lc.transition(Transition.TRANSITION_CONFIGURE)
        assert lc.state() == UNCONFIGURED and proc.poll() is None
    log = out["log"]
    assert proc.returncode == 0, log
    assert "configure failed: control_period_s" in log and "finished: never configured" in log, log

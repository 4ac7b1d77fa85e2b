"""The mode node as a ROS 2 managed (lifecycle) node (issue 49, item 2), driven the way any ROS 2
tool drives one: a plain rclpy client of ``lifecycle_msgs`` (``ChangeState`` and ``GetState`` on
``/modes/change_state`` and ``/modes/get_state``: tests/lifecycle_client.py's
:class:`~lifecycle_client.LifecycleClient`), no project code on the client's side.

In-process on an isolated domain (the ``ros_context`` fixture), a driver node publishing the
node's nine inputs of one stamp (quick_flight's settings: HOLD goes to TRACK after 0.5 s of a
healthy, converged estimate): every transition and the state after it, a transition refused from
the wrong state, what an inactive node answers (the mode held, reason none, no transition, no
request taken, ``diagnostics`` a warning saying so), the guards' counts restarted at a later
activation, a ground request made while inactive taken at the first active sample and a
scheduled one whose sample passes inactive not taken, a bad parameter failing the configure
transition with the node alive and unconfigured, and the default (not managed) node active from
the start.  Waits are on conditions with a deadline, never on fixed sleeps."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from lifecycle_msgs.msg import Transition
from rclpy.parameter import Parameter

from sappc_modes.core.modes import HOLD, P_HEALTHY_N, R_ACQUIRED, R_NONE, R_REQUEST, S_ERROR_N, S_HEALTHY_N, S_RATE_N, S_RECOVER_N, SAFE, TRACK
from sappc_modes.node import INACTIVE_MESSAGE, INPUTS
from sappc_msgs_py import contract as c
from sappc_msgs_py import wire

from lifecycle_client import (ACTIVE, FINALIZED, INACTIVE, UNCONFIGURED, LifecycleClient, TopicDriver, assert_configure_fails,
                              assert_not_managed, captured_log, closing, diagnostics_report)
from test_mode_node import overrides, sample
from test_nodes import DEADLINE_S

DT_NS = 10_000_000
_COUNTS = (S_RATE_N, S_HEALTHY_N, S_ERROR_N, S_RECOVER_N)
#: diagnostic_msgs/DiagnosticStatus's levels.
OK, WARN, ERROR = b"\x00", b"\x01", b"\x02"


class ModeDriver(TopicDriver):
    """A test node publishing the mode node's inputs of one stamp (as CDR, the node's own layouts)
    and collecting ``mode/status`` by stamp and ``diagnostics`` as published."""

    def __init__(self, context: Any, nodes: list[Any]) -> None:
        super().__init__(context, nodes, "the mode node", DEADLINE_S)
        qos = c.qos_profile()
        self.pub = {t.name: self.node.create_publisher(t.msg_class, t.name, qos) for t in INPUTS}
        self.codecs = {t.name: wire.codec(t) for t in INPUTS if t is not c.STATE_WHEEL_SPEED}
        self.codecs[c.STATE_WHEEL_SPEED.name] = wire.Codec(wire.joint_state(c.STATE_WHEEL_SPEED, 4, "speed", None), c.STATE_WHEEL_SPEED.name)
        self.status: dict[int, tuple[float, int, int]] = {}
        self.health: list[Any] = []
        self.subs = [self.node.create_subscription(c.MODE_STATUS.msg_class, c.MODE_STATUS.name, self._on_status, qos),
                     self.node.create_subscription(c.ESTIMATOR_HEALTH.msg_class, c.ESTIMATOR_HEALTH.name, self.health.append, qos)]

    def _on_status(self, msg: Any) -> None:
        t_s, mode, reason = msg.data
        self.status[round(t_s * 1e9)] = (t_s, int(mode), int(reason))

    def sample(self, k: int) -> tuple[int, int]:
        """Send sample ``k`` (test_mode_node.py's healthy sample: a slow gyro, a converged estimate at
        the reference) and return its (mode, reason) on ``mode/status``."""
        ns = k * DT_NS
        t_s = ns / 1e9
        for name, values in sample().items():
            codec = self.codecs[name]
            if codec._stamp_at is None:  # a float array of the contract: its time in data[0]
                self.pub[name].publish(codec.encode(None, [t_s, *values[1:]]))
            else:
                self.pub[name].publish(codec.encode(ns, list(values)))
        self.spin_until(lambda: ns in self.status, f"the mode of sample {k}")
        t, mode, reason = self.status[ns]
        assert t == t_s
        return mode, reason

    def report(self, since: int, inactive: bool) -> Any:
        """The first ``diagnostics`` status after the first ``since`` that says (or, ``inactive``
        false, does not say) that the node is inactive, once it has come."""
        return diagnostics_report(self, since, INACTIVE_MESSAGE, inactive)


@pytest.fixture
def managed(ros_context):  # type: ignore[no-untyped-def]
    """(node, driver, lifecycle client): a managed mode node (quick_flight, first mode HOLD),
    unconfigured, with the driver and a lifecycle client on the driver's node."""
    from sappc_modes.node import ModeNode

    node = ModeNode(context=ros_context, parameter_overrides=overrides(managed=True, initial_mode="HOLD"))
    driver = ModeDriver(ros_context, [node])
    with closing(node, driver):
        yield node, driver, LifecycleClient(driver.node, "modes", driver.spin_until)


def _counts(node: Any) -> list[float]:
    return [float(node._state[i]) for i in _COUNTS]


def test_the_lifecycle_through_lifecycle_msgs_services_and_what_each_state_answers(managed) -> None:  # type: ignore[no-untyped-def]
    """unconfigured -> configure -> inactive -> activate -> active -> deactivate -> inactive ->
    activate -> deactivate -> inactive -> activate -> deactivate -> cleanup -> unconfigured ->
    configure -> inactive -> shutdown -> finalized, each state read back with GetState;
    transitions from the wrong state refused.  Inactive, every sample is answered with the mode
    held and reason none, however long the guard's condition holds, and ``diagnostics`` warns that
    the node is inactive; a later activation goes on from the mode held with the guards' counts
    restarted (HOLD's 0.5 s of health counted again from there); a ground request made while
    inactive waits for the first active sample, a scheduled one (quick_flight's SAFE at 2.5 s)
    whose sample is answered inactive is not taken."""
    node, drv, lc = managed
    assert lc.state() == UNCONFIGURED
    assert drv.subscribed() == [0] * len(INPUTS) and drv.offered() == [0, 0]
    assert node.has_parameter("managed") and not node.has_parameter("transitions") and not node.has_parameter("request_mode")
    assert not lc.transition(Transition.TRANSITION_ACTIVATE)  # not from unconfigured
    assert lc.state() == UNCONFIGURED

    assert lc.transition(Transition.TRANSITION_CONFIGURE)
    assert lc.state() == INACTIVE
    healthy_n = int(node._prm[P_HEALTHY_N])
    assert healthy_n == 50  # quick_flight: healthy_for_s 0.5 at 10 ms
    drv.matched()
    # inactive: longer than HOLD's persistence of health, and no transition: the mode held, reason none
    assert all(drv.sample(k) == (HOLD, R_NONE) for k in range(healthy_n + 10))
    assert node.transitions == 0 and _counts(node) == [0.0] * 4 and node.samples == node.inactive_samples == healthy_n + 10
    report = drv.report(0, inactive=True)
    assert report is drv.health[0].status[0]  # at once, at the first sample
    assert report.level == WARN and "HOLD since" in report.message, report.message
    assert tuple(kv.key for kv in report.values) == c.MODE_HEALTH_KEYS
    assert not lc.transition(Transition.TRANSITION_CONFIGURE)  # configured already

    assert lc.transition(Transition.TRANSITION_ACTIVATE)
    assert lc.state() == ACTIVE
    reports = len(drv.health)
    first = healthy_n + 10
    assert all(drv.sample(k) == (HOLD, R_NONE) for k in range(first, first + 30))  # 30 of the 50 samples of health
    assert _counts(node)[1] == 30.0
    report = drv.report(reports, inactive=False)  # at once, at the first active sample: no longer inactive
    assert report is drv.health[reports].status[0] and report.level == OK and report.message.startswith("HOLD since"), report.message

    assert lc.transition(Transition.TRANSITION_DEACTIVATE)
    assert lc.state() == INACTIVE
    reports = len(drv.health)
    k = first + 30
    assert all(drv.sample(j) == (HOLD, R_NONE) for j in range(k, k + 5))
    assert _counts(node)[1] == 30.0  # the kernel not stepped
    assert drv.report(reports, inactive=True).level == WARN

    assert lc.transition(Transition.TRANSITION_ACTIVATE)  # the counts restarted: 50 more samples of health, not 20
    assert _counts(node) == [0.0] * 4
    k += 5
    assert all(drv.sample(j) == (HOLD, R_NONE) for j in range(k, k + healthy_n - 1))
    assert drv.sample(k + healthy_n - 1) == (TRACK, R_ACQUIRED)
    k += healthy_n
    assert k < 200 and node.transitions == 1

    assert lc.transition(Transition.TRANSITION_DEACTIVATE)
    result = node.set_parameters([Parameter("request_mode", value="SAFE")])[0]  # the ground's request while inactive: pending
    assert result.successful, result.reason
    assert drv.sample(k) == (TRACK, R_NONE) and node.get_parameter("request_mode").value == "SAFE"
    # quick_flight's scheduled request (SAFE at 2.5 s): its sample answered inactive, not taken
    assert drv.sample(250) == (TRACK, R_NONE) and node.transitions == 1
    assert lc.transition(Transition.TRANSITION_ACTIVATE)
    assert drv.sample(251) == (SAFE, R_REQUEST)  # the ground's request, at the first active sample
    assert node.get_parameter("request_mode").value == "" and node.transitions == 2
    reports = len(drv.health)
    assert lc.transition(Transition.TRANSITION_DEACTIVATE)
    assert drv.sample(252) == (SAFE, R_NONE)
    report = drv.report(reports, inactive=True)
    assert report.level == ERROR and "SAFE since" in report.message  # SAFE stays ERROR

    assert lc.transition(Transition.TRANSITION_CLEANUP)
    assert lc.state() == UNCONFIGURED
    drv.spin_until(lambda: drv.subscribed() == [0] * len(INPUTS), "the subscriptions destroyed")
    drv.spin_until(lambda: drv.offered() == [0, 0], "the outputs withdrawn")
    assert node.publish_counts()["/mode/status"] == node.samples == k + 4  # every sample answered, inactive or not
    assert not node._parameter_callback

    assert lc.transition(Transition.TRANSITION_CONFIGURE)  # a new flight from the same parameters
    assert lc.state() == INACTIVE
    assert node.samples == 0 and node.transitions == 0 and int(node._state[0]) == HOLD and node.configurations == 2
    assert node.set_parameters([Parameter("request_mode", value="SLEEP")])[0].successful is False  # the callback back
    assert lc.transition(Transition.TRANSITION_INACTIVE_SHUTDOWN)
    assert lc.state() == FINALIZED
    drv.spin_until(lambda: drv.subscribed() == [0] * len(INPUTS), "the subscriptions destroyed at shutdown")


@pytest.mark.parametrize(("bad", "named"), [
    ({"transitions": "{not json"}, "transitions must be a JSON mapping"),
    ({"requests_mode": ["SLEEP"], "requests_at_s": [1.0]}, "requests_mode: 'SLEEP' is not a mode"),
    ({"mode": "realtime"}, "lockstep only"),
    ({"inhibit": ["tracked"]}, "inhibit: 'tracked' is not an automatic transition"),
])
def test_a_bad_parameter_fails_the_configure_transition_and_the_node_stays_unconfigured(ros_context, bad, named) -> None:  # type: ignore[no-untyped-def]
    """What stops a plain mode node at start-up fails a managed one's configure transition:
    ``success: false``, logged naming the parameter, the node alive and unconfigured, nothing of
    the attempt left (its parameter callback included); its finish says it was never configured."""
    from sappc_modes.node import ModeNode

    node = ModeNode(context=ros_context, parameter_overrides=overrides(managed=True, **bad))
    driver = ModeDriver(ros_context, [node])
    with closing(node, driver), captured_log(node) as (errors, infos):
        lc = LifecycleClient(driver.node, "modes", driver.spin_until)
        assert_configure_fails(lc, node, errors, named)
        assert not node._parameter_callback
        node.finish()
        assert infos[-1].startswith("finished: never configured"), infos


def test_a_mode_node_not_managed_starts_active_and_offers_no_lifecycle_services(ros_context) -> None:  # type: ignore[no-untyped-def]
    """The default (``managed`` false): configured and active while it is built; no lifecycle
    service; its samples stepped by the kernel (HOLD to TRACK after 0.5 s of health)."""
    from sappc_modes.node import ModeNode

    node = ModeNode(context=ros_context, parameter_overrides=overrides(initial_mode="HOLD"))
    driver = ModeDriver(ros_context, [node])
    with closing(node, driver):
        assert_not_managed(node, "modes")
        driver.matched()
        assert [driver.sample(k) for k in range(50)][-2:] == [(HOLD, R_NONE), (TRACK, R_ACQUIRED)]
        assert driver.report(0, inactive=False).level == OK
        assert np.isfinite(node._health_t_s)

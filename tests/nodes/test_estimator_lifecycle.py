"""The estimator as a ROS 2 managed (lifecycle) node (issue 49, item 2), driven the way any ROS 2
tool drives one: a plain rclpy client of ``lifecycle_msgs`` (``ChangeState`` and ``GetState`` on
``/estimator/change_state`` and ``/estimator/get_state``: tests/lifecycle_client.py's
:class:`~lifecycle_client.LifecycleClient`), no project code on the client's side.

In-process on an isolated domain (the ``ros_context`` fixture), with test_estimator_node.py's
driver standing in for the plant (``sensors/gyro``, ``state/attitude_epoch``,
``sensors/star_tracker``, ``/clock``): every transition and the state after it, a transition
refused from the wrong state, what an inactive estimator answers (the contract's "no data" on every
estimate and figure topic, the status ``inactive``, a health warning saying so), the filter's
estimates once active (the kernel called directly from that sample on, bit for bit), a fresh filter
at a later activation, a bad parameter failing the configure transition with the node alive and
unconfigured.  Then the process (``python -m sappc_estimator -p managed:=true``, on rclpy's
``EventsExecutor`` as every node runs), stopped by SIGINT, with no shared memory left behind.
Waits are on conditions with a deadline, never on fixed sleeps."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from lifecycle_msgs.msg import Transition

from sappc_estimator.core import mekf
from sappc_msgs_py import contract as c

from conftest import ROOT
from fake_clock import FakeClock
from lifecycle_client import (ACTIVE, FINALIZED, INACTIVE, UNCONFIGURED, LifecycleClient, assert_configure_fails, assert_not_managed,
                              captured_log, closing, diagnostics_report, managed_process)
from test_estimator_node import DT_NS, EPOCHS, NO_DATA_W, Driver, Reference, _assert_no_data, measurements, overrides
from test_nodes import DEADLINE_S

#: The estimator's outputs that carry the estimate (the controller's inputs).
ESTIMATE_TOPICS = (c.ESTIMATE_ATTITUDE, c.ESTIMATE_RATE)
#: Its health message while inactive (the node's words; WARN).
INACTIVE_HEALTH = "inactive: the estimator is not active"


@pytest.fixture
def managed(ros_context):  # type: ignore[no-untyped-def]
    """(node, driver, lifecycle client): a managed estimator (the flight scenario's filter,
    test_estimator_node.py's ``overrides``), unconfigured, with the sensors' driver and a lifecycle
    client on the driver's node."""
    from sappc_estimator.node import EstimatorNode

    node = EstimatorNode(context=ros_context, parameter_overrides=overrides(managed=True))
    driver = Driver(ros_context, [node])
    with closing(node, driver):
        yield node, driver, LifecycleClient(driver.node, "estimator", driver.spin_until)


def _inputs_subscribed(drv: Driver) -> list[int]:
    return [p.get_subscription_count() for p in drv.pub.values()]


def _outputs_offered(drv: Driver) -> list[int]:
    return [drv.node.count_publishers(t.name) for t in c.ESTIMATOR_TOPICS]


def _assert_inactive_answer(drv: Driver, ns: int) -> None:
    """Sample ``ns`` answered inactive: "no data" on every estimate and figure topic (the
    covariance too), the status ``inactive``."""
    _assert_no_data(drv, ns)
    assert drv.got[c.ESTIMATOR_DIAGNOSTICS.name][ns]["status"] == c.ESTIMATOR_INACTIVE


def _assert_the_kernels(drv: Driver, ns: int, ref: Reference, status: int, totals: dict[str, float]) -> None:
    """Sample ``ns`` answered by the filter: its estimate and figures are the kernel's (``ref``,
    whose step gave ``status``), bit for bit; the diagnostics' totals are ``ref``'s plus ``totals``
    (an earlier filter's)."""
    diag = drv.got[c.ESTIMATOR_DIAGNOSTICS.name][ns]
    assert diag["status"] == status
    np.testing.assert_array_equal(drv.got[c.ESTIMATE_ATTITUDE.name][ns], ref.out[mekf.EO_Q : mekf.EO_Q + 4])
    np.testing.assert_array_equal(drv.got[c.ESTIMATE_RATE.name][ns], ref.out[mekf.EO_OMEGA : mekf.EO_OMEGA + 3])
    np.testing.assert_array_equal(drv.got[c.ESTIMATOR_GYRO_BIAS.name][ns], ref.out[mekf.EO_B : mekf.EO_B + 3])
    np.testing.assert_array_equal(drv.got[c.ESTIMATOR_COVARIANCE.name][ns][1], ref.P)
    assert (diag["updates"], diag["gate_rejections"]) == (ref.st[mekf.ES_N_UPD] + totals["updates"], ref.st[mekf.ES_N_REJ] + totals["gate_rejections"])


def _health_report(drv: Driver, since: int, inactive: bool) -> Any:
    """The status of the first health report after the first ``since`` that says (or, ``inactive``
    false, does not say) that the estimator is inactive, once it has come."""
    return diagnostics_report(drv, since, INACTIVE_HEALTH, inactive)


def test_the_lifecycle_through_lifecycle_msgs_services_and_what_each_state_answers(managed) -> None:  # type: ignore[no-untyped-def]
    """unconfigured -> configure -> inactive -> activate -> active -> deactivate -> inactive ->
    activate -> deactivate -> cleanup -> unconfigured -> configure -> inactive -> shutdown ->
    finalized, each state read back with GetState; transitions from the wrong state refused
    (``success: false``, the state unchanged).  Inactive, every lockstep sample (valid or not) is
    answered with "no data" and the status ``inactive``, no filter step, the health a warning that
    says so; active, the filter's estimates, equal to the kernel called directly from the first
    active sample on; a later activation starts a fresh filter (the kernel afresh from that sample),
    its totals carried on."""
    node, drv, lc = managed
    q, w = measurements(42)
    assert lc.state() == UNCONFIGURED
    # unconfigured: nothing subscribed, nothing offered, no parameter of the filter declared
    assert _inputs_subscribed(drv) == [0] * len(drv.pub) and _outputs_offered(drv) == [0] * len(c.ESTIMATOR_TOPICS)
    assert node.has_parameter("managed") and not node.has_parameter("tracker_noise_rad") and not node.has_parameter("mode")
    assert not lc.transition(Transition.TRANSITION_ACTIVATE)  # not from unconfigured
    assert not lc.transition(Transition.TRANSITION_DEACTIVATE)
    assert lc.state() == UNCONFIGURED

    assert lc.transition(Transition.TRANSITION_CONFIGURE)
    assert lc.state() == INACTIVE
    assert node.get_parameter("tracker_noise_rad").value == pytest.approx([9.7e-6, 9.7e-6, 7.3e-5])
    assert node.config.tracker_noise_rad == (9.7e-6, 9.7e-6, 7.3e-5)  # the filter's config built from them
    drv.matched(node)  # the inputs subscribed, the outputs offered
    # inactive before the first activation: every sample answered "no data", the filter not stepped
    for k in range(3):
        drv.sample(k * DT_NS, q[k], NO_DATA_W if k == 2 else w[k])  # 2: the injector's "no data" gyro sample: inactive all the same
        _assert_inactive_answer(drv, k * DT_NS)
    assert node.steps == 0 and not node.filter.initialised and node.samples == 3 and node.no_data == 3 and node.withheld == 0
    assert node.no_data_inputs == 1  # inputs are still checked and counted
    health = _health_report(drv, 0, inactive=True)
    assert health.level == b"\x01" and health is drv.health[0].status[0]  # WARN, in words, at the first sample
    assert not lc.transition(Transition.TRANSITION_CONFIGURE)  # configured already
    assert not lc.transition(Transition.TRANSITION_CLEANUP + 100)  # no such transition
    assert lc.state() == INACTIVE

    assert lc.transition(Transition.TRANSITION_ACTIVATE)
    assert lc.state() == ACTIVE
    # active: the filter from the next sample, as the kernel called directly from there (sample 3
    # names the tracker's sample of 0 s, taken while inactive: a provisional start; 10 replaces it;
    # 20 is an update)
    ref = Reference()
    reports = len(drv.health)
    for k in range(3, 22):
        drv.sample(k * DT_NS, q[k], w[k])
        _assert_the_kernels(drv, k * DT_NS, ref, ref.step(k * DT_NS / 1e9, q[k], w[k]), {"updates": 0, "gate_rejections": 0})
    assert np.all(np.isfinite(drv.got[c.ESTIMATE_ATTITUDE.name][21 * DT_NS])) and node.filter.updates == 1 and node.steps == 19
    _health_report(drv, reports, inactive=False)  # active: the inactive warning gone
    first = node.filter
    assert not lc.transition(Transition.TRANSITION_CLEANUP)  # not from active
    assert lc.state() == ACTIVE

    assert lc.transition(Transition.TRANSITION_DEACTIVATE)
    assert lc.state() == INACTIVE
    reports = len(drv.health)
    for k in (22, 23):
        drv.sample(k * DT_NS, q[k], w[k])
        _assert_inactive_answer(drv, k * DT_NS)
        assert drv.got[c.ESTIMATOR_DIAGNOSTICS.name][k * DT_NS]["updates"] == 1  # the filter's totals, as its last step left them
    assert node.steps == 19 and node.filter is first
    assert _health_report(drv, reports, inactive=True).level == b"\x01"  # WARN, from the first inactive sample

    assert lc.transition(Transition.TRANSITION_ACTIVATE)  # a fresh filter from the same config, its totals carried on
    assert node.filter is not first and not node.filter.initialised and node.filter.updates == 1
    ref = Reference()  # the kernel afresh from sample 24 (it names the tracker's sample of 200 ms: provisional; 30 replaces it, 40 updates)
    for k in range(24, 42):
        drv.sample(k * DT_NS, q[k], w[k])
        _assert_the_kernels(drv, k * DT_NS, ref, ref.step(k * DT_NS / 1e9, q[k], w[k]), {"updates": 1, "gate_rejections": 0})
    assert ref.st[mekf.ES_N_UPD] == 1 and node.filter.updates == 2 and node.steps == 37

    assert lc.transition(Transition.TRANSITION_DEACTIVATE)
    assert lc.transition(Transition.TRANSITION_CLEANUP)
    assert lc.state() == UNCONFIGURED
    # everything configure created is gone: the inputs unsubscribed, the outputs withdrawn
    drv.spin_until(lambda: _inputs_subscribed(drv) == [0] * len(drv.pub), "the subscriptions destroyed")
    drv.spin_until(lambda: _outputs_offered(drv) == [0] * len(c.ESTIMATOR_TOPICS), "the outputs withdrawn")
    assert node.statistics()["samples"] == 42 and node.no_data == 5
    counts = node.publish_counts()  # counted though the publishers are gone
    assert counts["/estimate/attitude"] == counts["/estimator/diagnostics"] == 42

    assert lc.transition(Transition.TRANSITION_CONFIGURE)  # the same parameters read again: a new filter
    assert lc.state() == INACTIVE
    assert node.steps == 0 and node.samples == 0 and not node.filter.initialised and node.filter.updates == 0 and node.configurations == 2
    assert lc.transition(Transition.TRANSITION_INACTIVE_SHUTDOWN)
    assert lc.state() == FINALIZED
    assert not lc.transition(Transition.TRANSITION_CONFIGURE)  # nothing leaves finalized
    drv.spin_until(lambda: _inputs_subscribed(drv) == [0] * len(drv.pub), "the subscriptions destroyed at shutdown")


@pytest.mark.parametrize(("bad", "named"), [
    ({"tracker_noise_rad": [0.0, 9.7e-6, 7.3e-5]}, "tracker_noise_rad must be > 0"),  # the config's own check
    ({"max_stamp_ahead_s": -1.0}, "max_stamp_ahead_s"),  # refused by the parameter's declared range
    ({"tracker_noise": [1e-5] * 3}, "unknown parameter 'tracker_noise'"),  # unknown: a typo is not ignored
    ({"mode": "fast"}, "mode must be one of"),
    (None, "missing parameter tracker_noise_rad"),  # no filter parameter at all
])
def test_a_bad_parameter_fails_the_configure_transition_and_the_node_stays_unconfigured(ros_context, bad, named) -> None:  # type: ignore[no-untyped-def]
    """The parameters that stop a plain estimator at start-up (exit status 2) fail a managed one's
    configure transition: ``success: false``, the reason logged naming the parameter, the node alive
    and unconfigured, nothing of the attempt left (no subscription, timer or publisher); a second
    attempt fails alike; its finish says it was never configured."""
    from rclpy.parameter import Parameter

    from sappc_estimator.node import EstimatorNode

    params = [Parameter("managed", value=True)] if bad is None else overrides(managed=True, **bad)
    node = EstimatorNode(context=ros_context, parameter_overrides=params)
    driver = Driver(ros_context, [node])
    with closing(node, driver), captured_log(node) as (errors, infos):
        lc = LifecycleClient(driver.node, "estimator", driver.spin_until)
        assert_configure_fails(lc, node, errors, named, attempts=2)
        node.finish()
        assert infos[-1].startswith("finished: never configured"), infos


def test_an_inactive_realtime_estimator_answers_each_fresh_sample_with_no_data(ros_context, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """Real time (epoch stamps, the node's clock set by the test, as test_estimator_node.py's
    real-time test): inactive, a fresh sample is answered at once with "no data" and the status
    ``inactive`` (its latency measured), its tracker sample taken; once activated, the next fresh
    sample is stepped, the filter's time counted from the first sample's stamp: the kernel's
    estimate, bit for bit (a provisional start on the tracker's sample taken while inactive)."""
    from sappc_estimator.node import EstimatorNode

    node = EstimatorNode(context=ros_context, parameter_overrides=overrides(mode="realtime", managed=True))
    t0 = 1_795_000_000 * 1_000_000_000
    clock = FakeClock(t0)
    monkeypatch.setattr(node, "get_clock", lambda: clock)
    drv = Driver(ros_context, [node])
    with closing(node, drv):
        lc = LifecycleClient(drv.node, "estimator", drv.spin_until)
        assert lc.transition(Transition.TRANSITION_CONFIGURE)
        drv.matched(node)
        drv.spin_until(node._gate.open, "the estimator's outputs matched")
        q, w = measurements(3)
        clock.ns = t0 + 400_000
        drv.send(t0, q[0], w[0], epoch_ns=t0 + EPOCHS[0])
        drv.spin_until(lambda: drv.answered(t0), "the answer of the first sample")
        _assert_inactive_answer(drv, t0)
        assert node.steps == 0 and node.statistics()["latency"]["steps"] == 1
        assert lc.transition(Transition.TRANSITION_ACTIVATE)
        # frame 2 (frame 1 is skipped: the driver dates the float arrays by data[0], exact only at even frames of t0)
        ns = t0 + 2 * DT_NS
        clock.ns = ns + 400_000
        drv.send(ns, q[2], w[2], epoch_ns=t0 + EPOCHS[2 * DT_NS])
        drv.spin_until(lambda: drv.answered(ns), "the estimate of frame 2")
        ref = Reference()
        _assert_the_kernels(drv, ns, ref, ref.step(2 * DT_NS / 1e9, q[2], w[2]), {"updates": 0, "gate_rejections": 0})
        assert drv.got[c.ESTIMATOR_DIAGNOSTICS.name][ns]["status"] == mekf.STATUS_INITIALISED and node.steps == 1


def test_an_estimator_not_managed_starts_active_and_offers_no_lifecycle_services(ros_context) -> None:  # type: ignore[no-untyped-def]
    """The default (``managed`` false): configured and active while it is built, as before the
    lifecycle existed; no lifecycle service; its first sample stepped by the filter."""
    from sappc_estimator.node import EstimatorNode

    node = EstimatorNode(context=ros_context, parameter_overrides=overrides())
    driver = Driver(ros_context, [node])
    with closing(node, driver):
        assert_not_managed(node, "estimator")
        driver.matched(node)
        q, w = measurements(1)
        driver.sample(0, q[0], w[0])
        assert driver.got[c.ESTIMATOR_DIAGNOSTICS.name][0]["status"] == mekf.STATUS_INITIALISED and node.steps == 1


def _managed_process(ros_context):  # type: ignore[no-untyped-def]
    """(process, driver, lifecycle client, its log once stopped): ``python -m sappc_estimator``
    managed, with config/estimator_mekf.yaml, the sensors' driver and a lifecycle client on this
    process's side (:func:`lifecycle_client.managed_process`: SIGINT at the end, the shared memory
    checked)."""
    return managed_process("sappc_estimator", ROOT / "config" / "estimator_mekf.yaml", (), lambda: Driver(ros_context, []), DEADLINE_S)


@pytest.mark.slow
def test_the_managed_estimator_process_is_brought_up_and_down_through_its_lifecycle_services(ros_context) -> None:  # type: ignore[no-untyped-def]
    """``python -m sappc_estimator -p managed:=true`` (rclpy's ``EventsExecutor``, which must take
    the subscriptions a transition creates): unconfigured until configured, a transition from the
    wrong state refused without ending the process; configured, it answers a lockstep sample with
    "no data" (inactive); activated, with the filter's estimate; stopped by SIGINT: exit 0, its
    closing line counting the samples."""
    q, w = measurements(2)
    with _managed_process(ros_context) as (proc, driver, lc, out):
        assert lc.state() == UNCONFIGURED
        assert not lc.transition(Transition.TRANSITION_ACTIVATE)  # refused, and the process lives on
        assert lc.state() == UNCONFIGURED and proc.poll() is None
        assert lc.transition(Transition.TRANSITION_CONFIGURE)
        assert lc.state() == INACTIVE
        driver.spin_until(lambda: all(n >= 1 for n in _inputs_subscribed(driver)) and all(n >= 1 for n in _outputs_offered(driver)),
                          "the estimator's topics matched")
        driver.sample(0, q[0], w[0])
        _assert_inactive_answer(driver, 0)
        assert lc.transition(Transition.TRANSITION_ACTIVATE)
        driver.sample(DT_NS, q[1], w[1])
        # it names the tracker's sample of 0 s (taken while inactive): a provisional start, an estimate
        assert driver.got[c.ESTIMATOR_DIAGNOSTICS.name][DT_NS]["status"] == mekf.STATUS_INITIALISED
        assert all(np.all(np.isfinite(driver.got[t.name][DT_NS])) for t in ESTIMATE_TOPICS)
    log = out["log"]
    assert proc.returncode == 0, log
    assert "finished: 2 samples, 1 filter steps" in log and "1 no-data samples (0 withheld)" in log, log

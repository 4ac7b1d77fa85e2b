"""The momentum-management node as a ROS 2 managed (lifecycle) node (issue 49, item 2), driven the
way any ROS 2 tool drives one: a plain rclpy client of ``lifecycle_msgs`` (``ChangeState`` and
``GetState`` on ``/momentum/change_state`` and ``/momentum/get_state``: tests/lifecycle_client.py's
:class:`~lifecycle_client.LifecycleClient`), no project code on the client's side.

In-process on an isolated domain (the ``ros_context`` fixture), a driver node standing in for the
plant, the controller and the mode node (the node's inputs of one stamp, ``mode/status``
included: flight modes on): every transition and the state after it, a transition refused from
the wrong state, what an inactive node answers (the rods at zero, the controller's torque to the
wheels unchanged, no law stepped), the law's commands once active (the kernels called directly,
bit for bit: the predictive law in TRACK, B-dot in DETUMBLE), the law afresh at a later
activation, a bad parameter failing the configure transition with the node alive and
unconfigured, and the default (not managed) node active from the start.  Waits are on conditions
with a deadline, never on fixed sleeps."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from lifecycle_msgs.msg import Transition

from sappc_modes.core.bdot import bdot_step, new_bdot_state, pack_bdot
from sappc_modes.core.modes import DETUMBLE, R_NONE, TRACK
from sappc_momentum.core.law import dipole_mapping
from sappc_momentum.core.predictive import new_state
from sappc_msgs_py import contract as c
from sappc_msgs_py.convert import dipole_from_msg, magnetic_field_msg, quaternion_msg, stamp_to_ns, torque_from_msg, torque_msg, vector3_msg, wheel_speed_msg
from sappc_msgs_py import wire

from lifecycle_client import (ACTIVE, FINALIZED, INACTIVE, UNCONFIGURED, LifecycleClient, TopicDriver, assert_configure_fails,
                              assert_not_managed, captured_log, closing)
from test_momentum_node import Kernel, overrides
from test_nodes import DEADLINE_S

DT_NS = 10_000_000
#: B-dot's gain in these tests [N m s] (any > 0: the kernel is called with the same).
BDOT_GAIN = 2.0e4
#: The node's inputs of one sample, flight modes on.
INPUTS = (c.STATE_WHEEL_SPEED, c.STATE_MAGNETIC_FIELD, c.STATE_ATTITUDE, c.STATE_RATE, c.CONTROL_TORQUE, c.MODE_STATUS)


def _managed_overrides(**extra: Any) -> list[Any]:
    return overrides(managed=True, flight_modes=True, bdot_gain_N_m_s=BDOT_GAIN, control_period_s=0.01, magnetometer_stride=1, **extra)


class MomentumDriver(TopicDriver):
    """A test node publishing the momentum node's inputs of one stamp and collecting its answers by stamp."""

    def __init__(self, context: Any, nodes: list[Any]) -> None:
        super().__init__(context, nodes, "the momentum node", DEADLINE_S)
        qos = c.qos_profile()
        self.pub = {t.name: self.node.create_publisher(t.msg_class, t.name, qos) for t in INPUTS}
        self.dipole: dict[int, np.ndarray] = {}
        self.wheel_torque: dict[int, np.ndarray] = {}
        self.subs = [self.node.create_subscription(c.CONTROL_DIPOLE.msg_class, c.CONTROL_DIPOLE.name, self._on_dipole, qos),
                     self.node.create_subscription(c.CONTROL_WHEEL_TORQUE.msg_class, c.CONTROL_WHEEL_TORQUE.name, self._on_torque, qos)]
        rng = np.random.default_rng(49)
        self.q = np.array([0.3254, 0.4068, -0.3254, 0.7891]) / np.linalg.norm([0.3254, 0.4068, -0.3254, 0.7891])
        self.omega = np.array([0.01, -0.02, 0.015])
        # each sample's tachometers, field and controller torque (within the motors' budget)
        self.speeds = 20.0 * rng.standard_normal((64, 4))
        self.field = 4e-5 * rng.standard_normal((64, 3))
        self.torque = 0.01 * rng.standard_normal((64, 3))

    def _on_dipole(self, msg: Any) -> None:
        t_s, m = dipole_from_msg(msg, 3)
        self.dipole[round(t_s * 1e9)] = m

    def _on_torque(self, msg: Any) -> None:
        self.wheel_torque[stamp_to_ns(msg.header.stamp)] = torque_from_msg(msg, c.CONTROL_WHEEL_TORQUE)

    def sample(self, k: int, mode: int) -> tuple[np.ndarray, np.ndarray]:
        """Send sample ``k`` (flight mode ``mode``, no transition) and return the node's answer: the
        rods' dipoles and the wheels' torque of that stamp."""
        ns, t = k * DT_NS, k * DT_NS / 1e9
        self.pub[c.CONTROL_TORQUE.name].publish(torque_msg(self.torque[k], t))
        self.pub[c.STATE_RATE.name].publish(vector3_msg(self.omega, t, c.STATE_RATE))
        self.pub[c.STATE_ATTITUDE.name].publish(quaternion_msg(self.q, t, c.STATE_ATTITUDE))
        self.pub[c.STATE_MAGNETIC_FIELD.name].publish(magnetic_field_msg(self.field[k], t))
        self.pub[c.STATE_WHEEL_SPEED.name].publish(wheel_speed_msg(self.speeds[k], t))
        self.pub[c.MODE_STATUS.name].publish(wire.codec(c.MODE_STATUS).encode(None, [t, float(mode), float(R_NONE)]))
        self.spin_until(lambda: ns in self.dipole and ns in self.wheel_torque, f"the answer of sample {k}")
        return self.dipole[ns], self.wheel_torque[ns]


class Bdot:
    """B-dot called directly on the node's rods (a fresh state), as the node calls it in DETUMBLE."""

    def __init__(self, node: Any) -> None:
        from sappc_momentum.node import _M_MAX, _STEERING

        self.steering, self.m_max, self.n = node._mm[_STEERING], node._mm[_M_MAX], node.n_rods
        self.prm, self.state = pack_bdot(BDOT_GAIN), new_bdot_state()

    def step(self, k: int, field: np.ndarray) -> np.ndarray:
        m_B, m = np.zeros(3), np.zeros(self.n)
        bdot_step(self.prm, field, float(k) * 0.01, self.state, m_B)  # the node's time of a magnetometer update: k dt
        dipole_mapping(self.steering, m_B, self.m_max, m)
        return m


@pytest.fixture
def managed(ros_context):  # type: ignore[no-untyped-def]
    """(node, driver, lifecycle client): a managed momentum node (paper_tracking_orbit's tables and
    predictive law, flight modes on), unconfigured, with the driver and a lifecycle client on the driver's node."""
    from sappc_momentum.node import MomentumNode

    node = MomentumNode(context=ros_context, parameter_overrides=_managed_overrides())
    driver = MomentumDriver(ros_context, [node])
    with closing(node, driver):
        yield node, driver, LifecycleClient(driver.node, "momentum", driver.spin_until)


def _assert_inactive_answer(drv: MomentumDriver, k: int, answer: tuple[np.ndarray, np.ndarray]) -> None:
    """Sample ``k`` answered inactive: the rods at zero, the wheels given the controller's torque, bit for bit."""
    m, tau = answer
    assert m.tolist() == [0.0, 0.0, 0.0]
    np.testing.assert_array_equal(tau, drv.torque[k])


def test_the_lifecycle_through_lifecycle_msgs_services_and_what_each_state_answers(managed) -> None:  # type: ignore[no-untyped-def]
    """unconfigured -> configure -> inactive -> activate -> active -> deactivate -> inactive ->
    activate -> deactivate -> cleanup -> unconfigured -> configure -> inactive -> shutdown ->
    finalized, each state read back with GetState; transitions from the wrong state refused.
    Inactive, every sample is answered with zero dipoles and the controller's own torque on the
    wheels, and neither law's state moves; active, the predictive law's commands in TRACK and
    B-dot's in DETUMBLE, equal to the kernels called directly; a later activation starts both
    afresh (fresh kernels from that sample on, bit for bit)."""
    node, drv, lc = managed
    params = {p.name: p.value for p in _managed_overrides()}
    assert lc.state() == UNCONFIGURED
    # unconfigured: nothing subscribed, nothing offered, no parameter of the law declared
    assert drv.subscribed() == [0] * len(INPUTS) and drv.offered() == [0, 0]
    assert node.has_parameter("managed") and not node.has_parameter("gain_per_s") and not node.has_parameter("mode")
    assert not lc.transition(Transition.TRANSITION_ACTIVATE)  # not from unconfigured
    assert not lc.transition(Transition.TRANSITION_DEACTIVATE)
    assert lc.state() == UNCONFIGURED

    assert lc.transition(Transition.TRANSITION_CONFIGURE)
    assert lc.state() == INACTIVE
    assert node.get_parameter("gain_per_s").value == params["gain_per_s"] and node.flight_modes
    drv.matched()
    # inactive before the first activation: every sample answered, no law stepped (its state as built)
    for k, mode in ((0, TRACK), (1, DETUMBLE)):
        _assert_inactive_answer(drv, k, drv.sample(k, mode))
    np.testing.assert_array_equal(node._state, new_state())
    np.testing.assert_array_equal(node._bdot_state, new_bdot_state())
    assert node.samples == 2 and node.inactive_samples == 2 and node.rejected == 0
    assert not lc.transition(Transition.TRANSITION_CONFIGURE)  # configured already
    assert lc.state() == INACTIVE

    assert lc.transition(Transition.TRANSITION_ACTIVATE)
    assert lc.state() == ACTIVE
    law, bdot = Kernel(params), Bdot(node)  # both from their first active sample
    for k in (2, 3):  # TRACK: the predictive law
        m, tau = drv.sample(k, TRACK)
        m_ref, tau_ref = law.step(k * DT_NS / 1e9, drv.speeds[k], drv.field[k], drv.q, drv.omega, drv.torque[k])
        np.testing.assert_array_equal(m, m_ref)
        np.testing.assert_array_equal(tau, tau_ref)
        assert np.abs(m).max() > 0.0 and not np.array_equal(tau, drv.torque[k])  # the law commands
    for k in (4, 5):  # DETUMBLE: B-dot on the rods, nothing on the wheels
        m, tau = drv.sample(k, DETUMBLE)
        np.testing.assert_array_equal(m, bdot.step(k, drv.field[k]))
        assert tau.tolist() == [0.0, 0.0, 0.0]
    assert np.abs(m).max() > 0.0  # the second B-dot sample differentiates

    assert lc.transition(Transition.TRANSITION_DEACTIVATE)
    assert lc.state() == INACTIVE
    held = node._state.copy(), node._bdot_state.copy()
    for k, mode in ((6, DETUMBLE), (7, TRACK)):
        _assert_inactive_answer(drv, k, drv.sample(k, mode))
    np.testing.assert_array_equal(node._state, held[0])  # nothing stepped while inactive
    np.testing.assert_array_equal(node._bdot_state, held[1])

    assert lc.transition(Transition.TRANSITION_ACTIVATE)  # both laws afresh
    bdot = Bdot(node)
    m, tau = drv.sample(8, DETUMBLE)
    assert m.tolist() == [0.0, 0.0, 0.0] and tau.tolist() == [0.0, 0.0, 0.0]  # no previous field sample: B-dot starts again
    np.testing.assert_array_equal(m, bdot.step(8, drv.field[8]))
    np.testing.assert_array_equal(drv.sample(9, DETUMBLE)[0], bdot.step(9, drv.field[9]))
    law = Kernel(params)
    for k in (10, 11):
        m, tau = drv.sample(k, TRACK)
        m_ref, tau_ref = law.step(k * DT_NS / 1e9, drv.speeds[k], drv.field[k], drv.q, drv.omega, drv.torque[k])
        np.testing.assert_array_equal(m, m_ref)
        np.testing.assert_array_equal(tau, tau_ref)
    assert not lc.transition(Transition.TRANSITION_CLEANUP)  # not from active

    assert lc.transition(Transition.TRANSITION_DEACTIVATE)
    assert lc.transition(Transition.TRANSITION_CLEANUP)
    assert lc.state() == UNCONFIGURED
    drv.spin_until(lambda: drv.subscribed() == [0] * len(INPUTS), "the subscriptions destroyed")
    drv.spin_until(lambda: drv.offered() == [0, 0], "the outputs withdrawn")
    assert node.samples == 12 and node.inactive_samples == 4
    counts = node.publish_counts()  # counted though the publishers are gone
    assert counts["/control/dipole"] == counts["/control/wheel_torque"] == 12

    assert lc.transition(Transition.TRANSITION_CONFIGURE)  # the same parameters read again: new counts
    assert lc.state() == INACTIVE
    assert node.samples == 0 and node.configurations == 2
    assert lc.transition(Transition.TRANSITION_INACTIVE_SHUTDOWN)
    assert lc.state() == FINALIZED
    assert not lc.transition(Transition.TRANSITION_CONFIGURE)  # nothing leaves finalized
    drv.spin_until(lambda: drv.subscribed() == [0] * len(INPUTS), "the subscriptions destroyed at shutdown")


@pytest.mark.parametrize(("bad", "named"), [
    ({"gain_per_s": -0.01}, "gain_per_s must be a finite number > 0, got -0.01"),
    ({"rod_steering": [1.0, 0.0, 0.0, 0.0, 1.0, 0.0]}, "rod_steering must be a right inverse of rod_axes_B"),
    ({"mode": "realtime"}, "lockstep only"),
    ({"gain": 1.0}, "unknown parameter 'gain'"),
])
def test_a_bad_parameter_fails_the_configure_transition_and_the_node_stays_unconfigured(ros_context, bad, named) -> None:  # type: ignore[no-untyped-def]
    """What stops a plain node at start-up (exit status 2) fails a managed one's configure
    transition: ``success: false``, logged naming the parameter, the node alive and unconfigured,
    nothing of the attempt left; its finish says it was never configured."""
    from sappc_momentum.node import MomentumNode

    node = MomentumNode(context=ros_context, parameter_overrides=_managed_overrides(**bad))
    driver = MomentumDriver(ros_context, [node])
    with closing(node, driver), captured_log(node) as (errors, infos):
        lc = LifecycleClient(driver.node, "momentum", driver.spin_until)
        assert_configure_fails(lc, node, errors, named)
        node.finish()
        assert infos[-1].startswith("finished: never configured"), infos


def test_a_momentum_node_not_managed_starts_active_and_offers_no_lifecycle_services(ros_context) -> None:  # type: ignore[no-untyped-def]
    """The default (``managed`` false): configured and active while it is built; no lifecycle
    service; its first sample answered by the law."""
    from sappc_momentum.node import MomentumNode

    params = {p.name: p.value for p in overrides()}
    node = MomentumNode(context=ros_context, parameter_overrides=overrides(flight_modes=True, bdot_gain_N_m_s=BDOT_GAIN))
    driver = MomentumDriver(ros_context, [node])
    with closing(node, driver):
        assert_not_managed(node, "momentum")
        driver.matched()
        m, tau = driver.sample(0, TRACK)
        m_ref, tau_ref = Kernel(params).step(0.0, driver.speeds[0], driver.field[0], driver.q, driver.omega, driver.torque[0])
        np.testing.assert_array_equal(m, m_ref)
        np.testing.assert_array_equal(tau, tau_ref)

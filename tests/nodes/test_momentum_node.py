"""The momentum-management node (``python -m sappc_momentum``, issue 36): a sample's five inputs of
one stamp give the rods' commands and the wheels' torque of the compiled kernel, bit for bit (the
predictive law's state carried from sample to sample); a "no data" rate or attitude keeps the
previous one; bad tables stop the node naming the parameter."""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import pytest
from rclpy.parameter import Parameter

from gnc_common.validation import ConfigError
from sappc.graph.launch import _momentum_parameters
from sappc.scenario import load_scenario
from sappc_momentum.core.law import N_MM_WORK, MomentumManagement, momentum_management_step, pack_momentum
from sappc_momentum.core.predictive import new_state
from sappc_msgs_py import contract as c
from sappc_msgs_py.convert import (dipole_from_msg, magnetic_field_msg, no_data_msg, quaternion_msg, torque_from_msg, torque_msg,
                                   vector3_msg, wheel_speed_msg)

from conftest import SCENARIOS

#: How long a test waits for the node's answer [s] (a few milliseconds when the machine is idle).
ANSWER_TIMEOUT_S = 10.0


def overrides(**extra: Any) -> list[Parameter]:
    """The node's parameters for ``paper_tracking_orbit.yaml`` (as ``sappc run`` writes them)."""
    values = {k: v for k, v in _momentum_parameters(load_scenario(SCENARIOS / "paper_tracking_orbit.yaml"), "lockstep", "").items()
              if k not in ("counts_file", "expected_subscribers")}
    values.update(extra)
    return [Parameter(k, value=v) for k, v in values.items()]


class Kernel:
    """The offline loop's kernel on the node's parameters, its state carried from sample to sample."""

    def __init__(self, params: dict[str, Any]) -> None:
        cfg = MomentumManagement(params["gain_per_s"], tuple(params["target_momentum_B_Nms"]), params["gyroscopic_feedforward"],
                                 params["law"], params["horizon_s"], params["replan_s"], params["plan_step_s"],
                                 params["disturbance_time_constant_s"])
        W, self.M = len(params["wheel_spin_inertia_kg_m2"]), len(params["rod_max_dipole_Am2"])
        predictive = params["law"] == "predictive"
        mm = pack_momentum(cfg, 1, np.reshape(params["wheel_axes_B"], (3, W)), params["wheel_spin_inertia_kg_m2"],
                           np.reshape(params["wheel_allocation"], (W, 3)), params["wheel_max_torque_Nm"], np.reshape(params["rod_axes_B"], (3, self.M)),
                           np.reshape(params["rod_steering"], (self.M, 3)), params["rod_max_dipole_Am2"],
                           params["orbit_params"] if predictive else None, params["field_params"] if predictive else None)
        self.arrays = [a[0] for a in mm]
        self.tmp, self.state = np.zeros((N_MM_WORK, 3)), new_state()

    def step(self, t_s: float, speeds: np.ndarray, field: np.ndarray, q: np.ndarray, omega: np.ndarray,
             torque: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        m, tau = np.zeros(self.M), np.zeros(3)
        momentum_management_step(*self.arrays, t_s, speeds, field, q, omega, torque, m, tau, self.tmp, self.state)
        return m, tau


def test_a_sample_is_answered_with_the_kernels_commands_and_no_data_keeps_the_previous_rate_and_attitude(ros_context) -> None:  # type: ignore[no-untyped-def]
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    from sappc_momentum.node import MomentumNode

    params = {p.name: p.value for p in overrides()}
    node = MomentumNode(context=ros_context, parameter_overrides=overrides())
    drv = Node("driver", context=ros_context)
    qos = c.qos_profile()
    pubs = {t.name: drv.create_publisher(t.msg_class, t.name, qos) for t in (c.STATE_WHEEL_SPEED, c.STATE_MAGNETIC_FIELD, c.STATE_ATTITUDE,
                                                                            c.STATE_RATE, c.CONTROL_TORQUE)}
    got: dict[str, list[Any]] = {"dipole": [], "torque": []}
    drv.create_subscription(c.CONTROL_DIPOLE.msg_class, c.CONTROL_DIPOLE.name, got["dipole"].append, qos)
    drv.create_subscription(c.CONTROL_WHEEL_TORQUE.msg_class, c.CONTROL_WHEEL_TORQUE.name, got["torque"].append, qos)
    ex = SingleThreadedExecutor(context=ros_context)
    ex.add_node(node)
    ex.add_node(drv)
    try:
        deadline = time.monotonic() + ANSWER_TIMEOUT_S
        while any(p.get_subscription_count() < 1 for p in pubs.values()) and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.05)
        rng = np.random.default_rng(36)
        omega = np.array([0.01, -0.02, 0.015])
        q = np.array([0.3254, 0.4068, -0.3254, 0.7891]) / np.linalg.norm([0.3254, 0.4068, -0.3254, 0.7891])
        kernel = Kernel(params)
        assert params["law"] == "predictive"  # the bundled scenario's: the attitude is an input
        for k, rate in enumerate([omega, None]):  # sample 1's rate and attitude are "no data": the node keeps sample 0's
            t = 0.01 * (k + 1)
            # within the motors' budget (attitude first would scale the rods to zero otherwise)
            speeds, field, torque = 20.0 * rng.standard_normal(4), 4e-5 * rng.standard_normal(3), 0.01 * rng.standard_normal(3)
            # published in an order other than the node's list: it pairs them by stamp
            pubs[c.CONTROL_TORQUE.name].publish(torque_msg(torque, t))
            pubs[c.STATE_RATE.name].publish(vector3_msg(rate, t, c.STATE_RATE) if rate is not None else no_data_msg(c.STATE_RATE, t))
            pubs[c.STATE_ATTITUDE.name].publish(quaternion_msg(q, t, c.STATE_ATTITUDE) if rate is not None else no_data_msg(c.STATE_ATTITUDE, t))
            pubs[c.STATE_MAGNETIC_FIELD.name].publish(magnetic_field_msg(field, t))
            pubs[c.STATE_WHEEL_SPEED.name].publish(wheel_speed_msg(speeds, t))
            deadline = time.monotonic() + ANSWER_TIMEOUT_S
            while (len(got["dipole"]) <= k or len(got["torque"]) <= k) and time.monotonic() < deadline:
                ex.spin_once(timeout_sec=0.05)
            m, tau = kernel.step(t, speeds, field, q, omega, torque)
            t_s, dipoles = dipole_from_msg(got["dipole"][k], 3)
            assert t_s == t and np.array_equal(dipoles, m)
            assert np.array_equal(torque_from_msg(got["torque"][k], c.CONTROL_WHEEL_TORQUE), tau)
            assert got["torque"][k].header.stamp.nanosec == round(t * 1e9)
            assert np.abs(m).max() > 0.0 and not np.array_equal(tau, torque)  # the rods command, the wheels' torque is not the controller's
        assert node.samples == 2 and node.rejected == 0
    finally:
        ex.shutdown()
        node.destroy_node()
        drv.destroy_node()


@pytest.mark.parametrize(("name", "value", "message"), [
    ("wheel_allocation", [1.0] * 12, "wheel_allocation must be a right inverse of wheel_axes_B"),
    ("rod_steering", [1.0, 0.0, 0.0, 0.0, 1.0, 0.0], "rod_steering must be a right inverse of rod_axes_B"),
    ("wheel_spin_inertia_kg_m2", [0.0796, 0.0796, 0.0796, 0.0], "wheel_spin_inertia_kg_m2 must be 4 values > 0"),
    ("rod_axes_B", [1.0, 0.0, 0.0, 0.0], "rod_axes_B must hold 3 rows"),
    ("gain_per_s", -0.01, "gain_per_s must be a finite number > 0, got -0.01"),
    ("orbit_params", [1.0, 2.0], "the predictive law needs orbit_params .10 values. and field_params .4 values., got .1.0, 2.0."),
    ("law", "lqr", "law must be one of 'cross_product', 'predictive', got 'lqr'"),
])
def test_a_bad_table_stops_the_node_naming_the_parameter_and_value(ros_context, name: str, value: Any, message: str) -> None:  # type: ignore[no-untyped-def]
    from sappc_momentum.node import MomentumNode

    with pytest.raises(ConfigError, match=message.replace("(", r"\(")):
        MomentumNode(context=ros_context, parameter_overrides=overrides(**{name: value}))


def test_real_time_is_refused(ros_context) -> None:  # type: ignore[no-untyped-def]
    from sappc_momentum.node import MomentumNode

    with pytest.raises(ConfigError, match="lockstep only .* got 'realtime'"):
        MomentumNode(context=ros_context, parameter_overrides=overrides(mode="realtime"))

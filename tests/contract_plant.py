"""A plant written only against the topic contract (docs/reference/topics.md) (``sappc_msgs_py``), rclpy and
numpy: no ``spacecraft_sim``.  It integrates a rigid body with its own RK4, publishes /clock, the
state and a constant reference (the identity) each 10 ms step, waits for the torque of the step
(lockstep), and holds the attitude error history."""

from __future__ import annotations

import time

import numpy as np
from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from sappc_msgs_py import contract as c
from sappc_msgs_py.convert import clock_msg, quaternion_msg, stamp_to_ns, torque_from_msg, vector3_msg

J = np.diag([4.0, 4.0, 4.0])
DT = 0.01


def _qmul(p: np.ndarray, q: np.ndarray) -> np.ndarray:  # Hamilton, scalar last
    pv, pw, qv, qw = p[:3], p[3], q[:3], q[3]
    return np.concatenate((pw * qv + qw * pv + np.cross(pv, qv), [pw * qw - pv @ qv]))


def _f(x: np.ndarray, tau: np.ndarray) -> np.ndarray:
    q, w = x[:4], x[4:]
    return np.concatenate((0.5 * _qmul(q, np.concatenate((w, [0.0]))), np.linalg.solve(J, tau - np.cross(w, J @ w))))


def run_contract_plant(context, q0: np.ndarray, steps: int, deadline_s: float = 120.0, subscribers: int = 1) -> tuple[np.ndarray, np.ndarray]:  # type: ignore[no-untyped-def]
    """Fly ``steps`` lockstep samples against whatever controller is on the graph, once each
    topic has ``subscribers`` subscribers (2 with a recorder); returns (attitude q_BN per sample
    (steps, 4), torque per sample (steps, 3))."""
    node = Node("contract_plant", context=context)
    qos = c.qos_profile()
    pubs = {t.name: node.create_publisher(t.msg_class, t.name, qos) for t in
            (c.CLOCK, c.STATE_ATTITUDE, c.STATE_RATE, c.REFERENCE_ATTITUDE, c.REFERENCE_RATE, c.REFERENCE_ACCELERATION)}
    torques: dict[int, np.ndarray] = {}
    node.create_subscription(c.CONTROL_TORQUE.msg_class, c.CONTROL_TORQUE.name, lambda m: torques.__setitem__(stamp_to_ns(m.header.stamp), torque_from_msg(m)), qos)
    ex = SingleThreadedExecutor(context=context)
    ex.add_node(node)
    end = time.monotonic() + deadline_s
    while not all(p.get_subscription_count() >= subscribers for p in pubs.values()) or not node.count_publishers(c.CONTROL_TORQUE.name):
        assert time.monotonic() < end, "no controller on the graph"
        ex.spin_once(timeout_sec=0.02)
    x = np.concatenate((q0, np.zeros(3)))
    q_hist, tq_hist = [], []
    for k in range(steps):
        t = k * DT
        pubs["/clock"].publish(clock_msg(t))
        pubs[c.STATE_ATTITUDE.name].publish(quaternion_msg(x[:4], t, c.STATE_ATTITUDE))
        pubs[c.STATE_RATE.name].publish(vector3_msg(x[4:], t, c.STATE_RATE))
        pubs[c.REFERENCE_ATTITUDE.name].publish(quaternion_msg([0.0, 0.0, 0.0, 1.0], t, c.REFERENCE_ATTITUDE))
        pubs[c.REFERENCE_RATE.name].publish(vector3_msg([0.0, 0.0, 0.0], t, c.REFERENCE_RATE))
        pubs[c.REFERENCE_ACCELERATION.name].publish(vector3_msg([0.0, 0.0, 0.0], t, c.REFERENCE_ACCELERATION))
        ns = round(t * 1e9)
        while ns not in torques:
            assert time.monotonic() < end, f"no torque for t = {t}"
            ex.spin_once(timeout_sec=0.02)
        tau = torques.pop(ns)
        q_hist.append(x[:4].copy())
        tq_hist.append(tau)
        k1 = _f(x, tau)
        k2 = _f(x + DT / 2 * k1, tau)
        k3 = _f(x + DT / 2 * k2, tau)
        k4 = _f(x + DT * k3, tau)
        x = x + DT / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        x[:4] /= np.linalg.norm(x[:4])
    for pub in pubs.values():  # a recorder that lags gets everything before the publishers leave
        pub.wait_for_all_acked(Duration(seconds=10))
    ex.shutdown()
    node.destroy_node()
    return np.array(q_hist), np.array(tq_hist)

"""A plant of your own beside ``python -m sappc_controller``: a rigid body (J = 4 I kg m^2, RK4) that
speaks the topic contract in lockstep; no code of the project but the contract (docs/tutorials/your-plant.md,
the controller alone beside your plant).  Usage: python examples/external_plant.py [--duration S] [--subscribers N]"""
import argparse
import time

import numpy as np
import rclpy
import rclpy.duration
from sappc_msgs_py import contract as c
from sappc_msgs_py.convert import clock_msg, quaternion_msg, stamp_to_ns, torque_from_msg, vector3_msg

cli = argparse.ArgumentParser()
cli.add_argument("--duration", type=float, default=30.0)  # [s], at DT = 0.01 s
cli.add_argument("--subscribers", type=int, default=1)  # each state topic waits for (2 when `sappc run --plant external` records it)
cli.add_argument("--clock-subscribers", type=int, default=2)  # /clock waits for: controller, reference (4 with sappc run: + injector, recorder)
args = cli.parse_args()
J, DT, WAIT_S = np.diag([4.0, 4.0, 4.0]), 0.01, 2.0  # inertia [kg m^2], control period [s], torque wait before holding [s]
def f(x, u):  # d/dt of (q_BN x, y, z, w; omega_BN_B [rad/s]) under body torque u [N m]
    (qx, qy, qz, qw), w = x[:4], x[4:]
    qdot = 0.5 * np.array([qw * w[0] + qy * w[2] - qz * w[1], qw * w[1] + qz * w[0] - qx * w[2], qw * w[2] + qx * w[1] - qy * w[0], -(x[:3] @ w)])
    return np.concatenate((qdot, np.linalg.solve(J, u - np.cross(w, J @ w))))
rclpy.init()
node, qos = rclpy.create_node("my_plant"), c.qos_profile()
pubs = [node.create_publisher(t.msg_class, t.name, qos) for t in (c.CLOCK, c.STATE_ATTITUDE, c.STATE_RATE)]
torques: dict[int, np.ndarray] = {}
sub = node.create_subscription(c.CONTROL_TORQUE.msg_class, c.CONTROL_TORQUE.name, lambda m: torques.update({stamp_to_ns(m.header.stamp): torque_from_msg(m)}), qos)
while sub.get_publisher_count() < 1 or any(p.get_subscription_count() < max(n, node.count_subscribers(p.topic_name))
                                           for p, n in zip(pubs, (args.clock_subscribers, args.subscribers, args.subscribers))):
    rclpy.spin_once(node, timeout_sec=0.01)  # wait for the controller and the subscribers you expect: a sample sent before is lost
x, u, missed = np.array([0.3254, 0.4068, -0.3254, 0.7891, 0.0, 0.0, 0.0]), np.zeros(3), 0  # the paper's start, at rest
x[:4] /= np.linalg.norm(x[:4])
for k in range(round(args.duration / DT) + 1):
    t = k * DT
    for pub, msg in zip(pubs, (clock_msg(t), quaternion_msg(x[:4], t, c.STATE_ATTITUDE), vector3_msg(x[4:], t, c.STATE_RATE))):
        pub.publish(msg)
    give_up = time.monotonic() + WAIT_S
    while round(t * 1e9) not in torques and time.monotonic() < give_up:
        rclpy.spin_once(node, timeout_sec=0.01)
    missed += round(t * 1e9) not in torques  # no answer in time: hold the last torque, as an actuator does
    u = torques.pop(round(t * 1e9), u)
    k1 = f(x, u)
    k2 = f(x + DT / 2 * k1, u)
    k3 = f(x + DT / 2 * k2, u)
    x = x + DT / 6 * (k1 + 2 * k2 + 2 * k3 + f(x + DT * k3, u))
    x[:4] /= np.linalg.norm(x[:4])
print(f"my_plant: {k + 1} samples, {missed} missed (held the last torque); q_BN at t = {t + DT:g} s: {x[:4].tolist()}")
for pub in pubs:  # leave only once every subscriber (a recorder that lags) has what was sent: the rest would be lost
    pub.wait_for_all_acked(rclpy.duration.Duration(seconds=10))
node.destroy_node()
rclpy.try_shutdown()

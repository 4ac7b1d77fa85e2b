"""A plant of your own beside ``python -m sappc_controller``: a template to copy.

A rigid body (J = 4 I kg m^2, RK4) that speaks the topic contract in lockstep, written with
nothing of the project but the contract (``sappc_msgs_py``), rclpy and numpy.  Walkthrough:
docs/tutorials/your-plant.md.

Usage: python examples/external_plant.py [--duration S] [--subscribers N] [--clock-subscribers N]

The lockstep handshake, once per control period of DT seconds:

1. the plant publishes ``/clock`` and the state (``state/attitude``, ``state/rate``), all
   stamped with the sample's time t;
2. the controller answers with ``control/torque`` stamped t (the same stamp: that is how the
   plant knows which sample the torque belongs to);
3. the plant applies that torque for DT and moves on to t + DT.

The plant owns time: nothing happens between two samples until it publishes the next one.
"""

import argparse
import time

import numpy as np
import rclpy
import rclpy.duration
from geometry_msgs.msg import WrenchStamped

from sappc_msgs_py import contract as c
from sappc_msgs_py.convert import (clock_msg, quaternion_msg, stamp_to_ns, torque_from_msg,
                                   vector3_msg)

J = np.diag([4.0, 4.0, 4.0])  # inertia [kg m^2]
DT = 0.01  # control period [s]
TORQUE_WAIT_S = 2.0  # how long to wait for a sample's torque before holding the last one [s]
Q0 = [0.3254, 0.4068, -0.3254, 0.7891]  # the paper's initial attitude q_BN (x, y, z, w), at rest


def parse_args() -> argparse.Namespace:
    cli = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    cli.add_argument("--duration", type=float, default=30.0, help="simulated time [s]")
    cli.add_argument("--subscribers", type=int, default=1,
                     help="subscribers each state topic waits for: the controller "
                          "(2 with `sappc run --plant external`: + the recorder)")
    cli.add_argument("--clock-subscribers", type=int, default=2,
                     help="subscribers /clock waits for: controller and reference "
                          "(4 with `sappc run --plant external`: + injector, recorder)")
    return cli.parse_args()


# ---- the dynamics: state x = (q_BN x, y, z, w; omega_BN_B [rad/s]) ----------------------------

def derivative(x: np.ndarray, u: np.ndarray) -> np.ndarray:
    """dx/dt under the body torque u [N m]: quaternion kinematics and Euler's equation."""
    (qx, qy, qz, qw), w = x[:4], x[4:]
    qdot = 0.5 * np.array([qw * w[0] + qy * w[2] - qz * w[1],
                           qw * w[1] + qz * w[0] - qx * w[2],
                           qw * w[2] + qx * w[1] - qy * w[0],
                           -(x[:3] @ w)])
    wdot = np.linalg.solve(J, u - np.cross(w, J @ w))
    return np.concatenate((qdot, wdot))


def rk4_step(x: np.ndarray, u: np.ndarray) -> np.ndarray:
    """x after DT seconds of the constant torque u (one RK4 step), quaternion renormalised."""
    k1 = derivative(x, u)
    k2 = derivative(x + DT / 2 * k1, u)
    k3 = derivative(x + DT / 2 * k2, u)
    k4 = derivative(x + DT * k3, u)
    x = x + DT / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    x[:4] /= np.linalg.norm(x[:4])
    return x


# ---- the ROS side ------------------------------------------------------------------------------

class Plant:
    """The node, its three publishers, and the torques received, by stamp [ns]."""

    def __init__(self) -> None:
        self.node = rclpy.create_node("my_plant")
        qos = c.qos_profile()  # the contract's QoS: reliable, deep enough that nothing is dropped
        topics = (c.CLOCK, c.STATE_ATTITUDE, c.STATE_RATE)
        self.pubs = [self.node.create_publisher(t.msg_class, t.name, qos) for t in topics]
        self.torques: dict[int, np.ndarray] = {}
        self.torque_sub = self.node.create_subscription(
            c.CONTROL_TORQUE.msg_class, c.CONTROL_TORQUE.name, self.on_torque, qos)

    def on_torque(self, msg: WrenchStamped) -> None:
        # keyed by the stamp: the torque answers the sample published with that stamp
        self.torques[stamp_to_ns(msg.header.stamp)] = torque_from_msg(msg)

    def wait_for_the_graph(self, clock_subscribers: int, state_subscribers: int) -> None:
        """Publish nothing before everyone is there: the topics are volatile, so a sample sent
        before a subscriber is matched is lost to it, and the loop would wait for a torque that
        never comes.  Wait for the controller (the publisher of control/torque) and for the
        subscribers expected on each topic, or more if more were discovered."""
        wanted = (clock_subscribers, state_subscribers, state_subscribers)

        def missing() -> bool:
            if self.torque_sub.get_publisher_count() < 1:
                return True
            for pub, n in zip(self.pubs, wanted):
                discovered = self.node.count_subscribers(pub.topic_name)
                if pub.get_subscription_count() < max(n, discovered):
                    return True
            return False

        while missing():
            rclpy.spin_once(self.node, timeout_sec=0.01)

    def publish_sample(self, t: float, x: np.ndarray) -> None:
        """Step 1 of the handshake: /clock and the state, all stamped t."""
        msgs = (clock_msg(t),
                quaternion_msg(x[:4], t, c.STATE_ATTITUDE),
                vector3_msg(x[4:], t, c.STATE_RATE))
        for pub, msg in zip(self.pubs, msgs):
            pub.publish(msg)

    def torque_for(self, t: float, last: np.ndarray) -> tuple[np.ndarray, bool]:
        """Step 2: the torque stamped t, waiting up to TORQUE_WAIT_S for it; without an answer in
        time, the last torque again, as an actuator holds its command.  (torque, it came)"""
        stamp = round(t * 1e9)
        give_up = time.monotonic() + TORQUE_WAIT_S
        while stamp not in self.torques and time.monotonic() < give_up:
            rclpy.spin_once(self.node, timeout_sec=0.01)
        came = stamp in self.torques
        return self.torques.pop(stamp, last), came

    def finish(self) -> None:
        """Leave only once every subscriber (a recorder that lags) has acknowledged what was sent:
        what is still in flight when a publisher disappears is lost."""
        for pub in self.pubs:
            pub.wait_for_all_acked(rclpy.duration.Duration(seconds=10))
        self.node.destroy_node()


def main() -> None:
    args = parse_args()
    rclpy.init()
    plant = Plant()
    plant.wait_for_the_graph(args.clock_subscribers, args.subscribers)
    x = np.concatenate((np.array(Q0) / np.linalg.norm(Q0), np.zeros(3)))
    u, missed = np.zeros(3), 0
    samples = round(args.duration / DT) + 1
    for k in range(samples):
        t = k * DT
        plant.publish_sample(t, x)
        u, came = plant.torque_for(t, u)
        missed += not came
        x = rk4_step(x, u)  # step 3: apply the torque for one period
    print(f"my_plant: {samples} samples, {missed} missed (held the last torque); "
          f"q_BN at t = {samples * DT:g} s: {x[:4].tolist()}")
    plant.finish()
    rclpy.try_shutdown()


if __name__ == "__main__":
    main()

"""The reference publisher (``python -m spacecraft_sim.reference``): the paper's desired trajectory.

Publishes ``reference/attitude``, ``reference/rate`` and ``reference/acceleration`` (see
:mod:`sappc_msgs_py.contract`), and the reference frame in the inertial frame (``reference/tf``: a
``TransformStamped`` with the attitude's stamp and quaternion ``q_RN``, for tf-style viewers; the
reference node owns frame R as the plant owns B), from :class:`~spacecraft_sim.core.reference.PaperReference`,
sampled on the grid ``k dt``, ``k = 0 .. duration_s / dt``, exactly as the offline runner samples
it (the attitude is integrated once over the whole grid).

``lockstep``: on each ``/clock`` tick ``t_k`` of the grid it publishes sample ``k + 1`` (and, at
``t_0``, sample 0 first), stamped ``t_k+1``: the trajectory is known in advance, so publishing
one sample ahead takes the reference off the loop's critical path; the controller pairs it with
the state of the same stamp.  ``realtime``: a
wall-clock timer of period ``dt`` publishes the sample of the time elapsed since its first tick,
stamped with the node's clock.

Parameters: ``q_RN0``, ``amplitude_deg_s``, ``periods_s`` (the scenario's ``reference``),
``control_period_s``, ``duration_s``, ``mode``, and those of
:class:`~sappc_msgs_py.runtime.ProjectNode`.
"""

from __future__ import annotations

import sys
from typing import Any


from sappc_msgs_py.contract import CLOCK, REFERENCE_ACCELERATION, REFERENCE_ATTITUDE, REFERENCE_RATE, REFERENCE_TF, qos_profile
from sappc_msgs_py.convert import quaternion_msg, stamp_to_ns, time_to_stamp, transform_from_attitude, transform_msg, vector3_msg
from sappc_msgs_py.runtime import LOCKSTEP, ProjectNode, run_node

from spacecraft_sim.core.reference import PaperReference, sample_times
from gnc_common.validation import check_positive

__all__ = ["ReferenceNode", "main"]


class ReferenceNode(ProjectNode):
    """See the module docstring."""

    def __init__(self, node_name: str = "reference", **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        ref = PaperReference(
            q_RN0=tuple(self.param("q_RN0", [0.0, 0.0, 0.0, 1.0])),
            amplitude_deg_s=float(self.param("amplitude_deg_s", 0.573)),
            periods_s=tuple(self.param("periods_s", [40.0, 30.0, 50.0])),
        )
        self.dt = check_positive("control_period_s", self.param("control_period_s", 0.01))
        duration = check_positive("duration_s", self.param("duration_s", 60.0))
        self.mode = self.mode_param()
        self.samples = ref.sample(sample_times(duration, self.dt))
        # stamp (ns) of each grid sample -> index, for exact matching of /clock ticks
        self._stamps = [time_to_stamp(float(t)) for t in self.samples.t]
        self._index = {stamp_to_ns(st): k for k, st in enumerate(self._stamps)}
        self.pubs = [self.counting_publisher(t, 1) for t in (REFERENCE_ATTITUDE, REFERENCE_RATE, REFERENCE_ACCELERATION)]
        self.pub_tf = self.counting_publisher(REFERENCE_TF)  # waits only for expected_subscribers
        self._tf = transform_msg(REFERENCE_TF)  # one message, re-stamped each sample
        if self.mode == LOCKSTEP:
            self.create_subscription(CLOCK.msg_class, CLOCK.name, self._on_clock, qos_profile())
        else:
            self._t0_ns: int | None = None
            self.create_timer(self.dt, self._on_timer)

    def _publish(self, k: int, stamp: Any) -> None:
        s = self.samples
        att = quaternion_msg(s.q_RN[k], stamp, REFERENCE_ATTITUDE)
        self.pubs[0].publish(att)
        self.pubs[1].publish(vector3_msg(s.omega_RN_R[k], stamp, REFERENCE_RATE))
        self.pubs[2].publish(vector3_msg(s.omegadot_RN_R[k], stamp, REFERENCE_ACCELERATION))
        self.pub_tf.publish(transform_from_attitude(self._tf, att))

    def _on_clock(self, msg: Any) -> None:
        ns = stamp_to_ns(msg.clock)
        k = self._index.get(ns)
        if k is None:
            self.get_logger().warning(f"/clock {ns / 1e9:.9f} s is not on the reference grid (dt = {self.dt} s, n = {len(self._index)}); nothing published")
            return
        if k == 0:
            self._publish(0, msg.clock)
        if k + 1 < self.samples.t.size:  # one sample ahead: never on the loop's critical path
            self._publish(k + 1, self._stamps[k + 1])

    def _on_timer(self) -> None:
        now = self.get_clock().now()
        if self._t0_ns is None:
            self._t0_ns = now.nanoseconds
        k = int((now.nanoseconds - self._t0_ns) / 1e9 / self.dt + 0.5)
        if k >= self.samples.t.size:
            return  # past the grid: nothing more to publish (the node stays up until stopped)
        self._publish(k, now.to_msg())


def main(argv: list[str] | None = None) -> int:
    """Run the reference publisher until stopped."""
    return run_node(lambda args: ReferenceNode(), argv)


if __name__ == "__main__":
    sys.exit(main())

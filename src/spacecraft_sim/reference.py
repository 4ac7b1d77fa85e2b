"""The reference publisher (``python -m spacecraft_sim.reference``): the paper's desired trajectory.

Publishes ``reference/attitude``, ``reference/rate`` and ``reference/acceleration`` (see
:mod:`sappc_msgs_py.contract`), and the reference frame in the inertial frame (``reference/tf``: a
``TransformStamped`` with the attitude's stamp and quaternion ``q_RN``, for tf-style viewers; the
reference node owns frame R as the plant owns B), from :class:`~spacecraft_sim.core.reference.PaperReference`,
sampled on the grid ``k dt``, ``k = 0 .. duration_s / dt``, exactly as the offline runner samples
it (the attitude integrated on from one block of samples to the next: the same bits as over the
whole grid at once, in memory bounded whatever the run's length).

``lockstep``: samples 0 and 1 as soon as its subscribers are matched, then on each ``/clock``
tick ``t_k`` of the grid sample ``k + 1`` (and any earlier one a missed tick left out:
:class:`~sappc_msgs_py.runtime.GridCursor`), each stamped with its grid time: the trajectory is
known in advance, so publishing one sample ahead takes the reference off the loop's critical
path, and the first samples do not depend on the plant's first tick reaching this node; the
controller pairs each with the state of the same stamp.  ``realtime``: in the frames of
:mod:`sappc_msgs_py.timeline`, sample ``k`` stamped with frame ``f0 + k``, where ``f0`` is the
frame of the plant's first ``state/attitude`` (the node subscribes to it:
:class:`~sappc_msgs_py.runtime.FramesAhead`); the samples of frames ``f0`` to ``f0 +
AHEAD_FRAMES`` are published on that first state, then a timer in the middle of each frame
publishes up to :data:`~sappc_msgs_py.timeline.AHEAD_FRAMES` frames ahead, so the controller finds
the reference of each state's stamp already there, and the last sample is the plant's last frame's.

Parameters: :data:`PARAMETERS` (the scenario's ``reference``, the grid and the mode;
``python -m spacecraft_sim.reference --help``), and those of :class:`~sappc_msgs_py.runtime.ProjectNode`.
"""

from __future__ import annotations

import sys
from typing import Any

import numpy as np

from sappc_msgs_py.contract import CLOCK, REFERENCE_ACCELERATION, REFERENCE_ATTITUDE, REFERENCE_RATE, REFERENCE_TF, qos_profile
from sappc_msgs_py import wire
from sappc_msgs_py.convert import cdr_stamp_ns, time_to_ns
from sappc_msgs_py.parameters import Param
from sappc_msgs_py.runtime import LOCKSTEP, MODE, FramesAhead, GridCursor, ProjectNode, StartGate, run_node, unmatched

from spacecraft_sim.core.reference import PaperReference, ReferenceSamples, sample_times
from gnc_common.validation import check_positive

__all__ = ["PARAMETERS", "ReferenceNode", "main"]

#: The reference node's parameters (``--help``), in the order the node declares them.
PARAMETERS = (
    Param("q_RN0", [0.0, 0.0, 0.0, 1.0], "initial attitude of the reference frame R relative to the inertial frame N, quaternion (x, y, z, w)",
          check="a unit quaternion"),
    Param("amplitude_deg_s", 0.573, "amplitude of each axis of the reference rate omega_RN_R (the paper: 0.573 deg/s = 0.01 rad/s)", "deg/s"),
    Param("periods_s", [40.0, 30.0, 50.0], "period of each axis's sinusoid of the reference rate (x, y, z)", "s", check="3 values > 0"),
    Param("control_period_s", 0.01, "sample period dt of the grid k dt the samples are published on", "s", check="> 0"),
    Param("duration_s", 60.0, "end of the grid: samples k = 0 .. duration_s / dt", "s", check="> 0"),
    MODE,
)
_P = {p.name: p for p in PARAMETERS}


class ReferenceNode(ProjectNode):
    """See the module docstring."""

    PARAMETERS = PARAMETERS
    COMMAND = "python -m spacecraft_sim.reference"

    def __init__(self, node_name: str = "reference", **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        ref = PaperReference(
            q_RN0=tuple(self.param(_P["q_RN0"])),
            amplitude_deg_s=float(self.param(_P["amplitude_deg_s"])),
            periods_s=tuple(self.param(_P["periods_s"])),
        )
        self.dt = check_positive("control_period_s", self.param(_P["control_period_s"]))
        duration = check_positive("duration_s", self.param(_P["duration_s"]))
        self.mode = self.mode_param()
        self.ref = ref
        self.n_steps = len(sample_times(duration, self.dt)) - 1  # samples k = 0 .. n_steps, the grid k dt
        # the reference is sampled a block at a time as the run goes (bounded memory, whatever the
        # run's length), its attitude integrated on from one block to the next: the same bits as
        # the whole grid in one call (PaperReference.sample's carry)
        self._carry = ref.start()
        self._carry_k = 0  # the next sample the carry's integration reaches
        self._samples: tuple[int, ReferenceSamples | None] = (0, None)  # the block sampled last, from sample lo
        self._sampled(0, min(wire.BLOCK_SAMPLES, self.n_steps + 1))  # the first block now: the compiled integration loaded before the run
        topics = (REFERENCE_ATTITUDE, REFERENCE_RATE, REFERENCE_ACCELERATION, REFERENCE_TF)
        self.pubs = [self.counting_publisher(t, 1) for t in topics[:3]]
        self.pub_tf = self.counting_publisher(REFERENCE_TF)  # waits only for expected_subscribers
        self._wire = [wire.codec(t) for t in topics]  # published as CDR bytes (sappc_msgs_py.wire), a block at a time
        self._all_pubs = [*self.pubs, self.pub_tf]
        self._block: tuple[int, list[int], list[list[bytes]]] = (0, [], [])  # samples lo .. : their stamps, each topic's messages
        if self.mode == LOCKSTEP:
            self._cursor = GridCursor(self.n_steps)
            self.create_subscription(CLOCK.msg_class, CLOCK.name, self._on_clock, qos_profile(), raw=True)
            self.start_when(lambda: unmatched([*self.pubs, self.pub_tf]), lambda: self._publish_through(1))
        else:  # sample k on the plant's frame f0 + k, f0 its first state's (FramesAhead)
            gate = StartGate(self, lambda: unmatched([*self.pubs, self.pub_tf]))  # no publish may block a callback
            self.frames = FramesAhead(self, self.dt, self.n_steps, gate.open, lambda k, ns: self._publish(k, ns))

    def _publish(self, k: int, stamp_ns: int) -> None:
        lo, stamps, messages = self._block
        i = k - lo
        if not (0 <= i < len(stamps) and stamps[i] == stamp_ns):  # the block from k, its stamps on k's
            self._block = lo, stamps, messages = self._encode_block(k, stamp_ns)
            i = 0
        for pub, m in zip(self._all_pubs, messages):
            pub.publish(m[i])

    def _encode_block(self, k: int, stamp_ns: int) -> tuple[int, list[int], list[list[bytes]]]:
        """Samples ``k ..`` (:data:`~sappc_msgs_py.wire.BLOCK_SAMPLES`, to the grid's end), sample
        ``k`` stamped ``stamp_ns``: in lockstep each its grid stamp, in real time the frames after
        ``k``'s (``FramesAhead`` stamps frame ``f0 + j``).  A sample asked for with another stamp
        than its block gave it starts a new block (``_publish`` checks), so a stamp is never guessed."""
        hi = min(k + wire.BLOCK_SAMPLES, self.n_steps + 1)
        s = self._sampled(k, hi)
        stamps = [self._grid_ns(j) for j in range(k, hi)] if self.mode == LOCKSTEP else [stamp_ns + (j - k) * self.frames.dt_ns for j in range(k, hi)]
        stamps[0] = stamp_ns
        w_att, w_rate, w_acc, w_tf = self._wire
        return k, stamps, [w_att.encode_block(stamps, s.q_RN), w_rate.encode_block(stamps, s.omega_RN_R),
                           w_acc.encode_block(stamps, s.omegadot_RN_R), w_tf.encode_block(stamps, s.q_RN)]

    def _sampled(self, k: int, hi: int) -> ReferenceSamples:
        """The reference at samples ``k .. hi - 1`` of the grid: from the block sampled last when it
        holds them, else integrated on from the carry (from the run's start again if ``k`` is
        before it: a block asked for again, which the cursors never do)."""
        lo, block = self._samples
        if block is not None and lo <= k and hi <= lo + block.t.size:
            return ReferenceSamples(*(a[k - lo:hi - lo] for a in (block.t, block.q_RN, block.omega_RN_R, block.omegadot_RN_R)))
        if k < self._carry_k:
            self._carry, self._carry_k = self.ref.start(), 0
        if k > self._carry_k:  # integrated through the samples skipped, unpublished
            self.ref.sample(np.arange(self._carry_k, k, dtype=np.float64) * self.dt, self._carry)
        block = self.ref.sample(np.arange(k, hi, dtype=np.float64) * self.dt, self._carry)  # the grid's k dt (sample_times)
        self._carry_k = hi
        self._samples = (k, block)
        return block

    def _grid_ns(self, k: int) -> int:
        """The stamp [ns] of grid sample ``k`` (``k dt``, as the plant stamps it)."""
        return time_to_ns(float(k) * self.dt)

    def _on_clock(self, raw: bytes) -> None:
        ns = cdr_stamp_ns(CLOCK.type_name, raw)
        k = round(ns / 1e9 / self.dt)
        if not 0 <= k <= self.n_steps or self._grid_ns(k) != ns:
            self.get_logger().warning(f"/clock {ns / 1e9:.9f} s is not on the reference grid (dt = {self.dt} s, n = {self.n_steps + 1}); nothing published")
            return
        self._publish_through(k + 1)  # one sample ahead: never on the loop's critical path

    def _publish_through(self, k: int) -> None:
        for j in self._cursor.through(k):
            self._publish(j, self._grid_ns(j))


def main(argv: list[str] | None = None) -> int:
    """Run the reference publisher until stopped."""
    return run_node(lambda args: ReferenceNode(), argv, ReferenceNode)


if __name__ == "__main__":
    sys.exit(main())

"""``sappc replay``: republish a bag on the ROS 2 graph with its timing, ``/clock`` included.

Messages go out as recorded (raw CDR, no re-serialisation), in the order the recorder wrote
them, on publishers with the contract's QoS (reliable, depth ``QOS_DEPTH``), so any node can consume a
recording as if it were live.

Timing.  A lockstep bag (one with ``/clock``) replays on its *simulated* time: the recorder of
``sappc run`` logs each message at its own stamp (:mod:`sappc.graph.recorder`), and the message
is due then (in a bag recorded on wall time with ``/clock``, at the ``/clock`` value most
recently recorded before it), so at ``--rate 1`` a 60 s experiment takes 60 s of wall time with
``/clock`` advancing in step, and the ``/clock`` messages themselves are republished as recorded.  A bag without ``/clock`` (real time, or a
plant that does not publish one) replays on its recording time (the recorder's receive times),
and ``/clock`` is published from that time at :data:`CLOCK_RATE_HZ`, so nodes with
``use_sim_time`` follow it.  ``--rate X`` divides every interval by ``X``.  A message is never
published before it is due; when publishing cannot keep up (high rates), it goes out as soon as
possible and the largest lag is reported.  With ``--loop`` the bag starts again at its end and
``/clock`` jumps back.

Start-up.  A subscriber that has not matched a publisher misses what it sends, so replay waits
``--start-delay`` seconds after creating its publishers (discovery) or, with
``--wait-subscribers N``, until every replayed topic has ``N`` matched subscribers.  At the end
it waits until every subscriber acknowledged every message, then exits.
"""

from __future__ import annotations

import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from sappc_msgs_py.contract import CLOCK, Topic
from sappc_msgs_py.runtime import ProjectNode, run_node
from gnc_common.validation import ConfigError, check_positive

from sappc.bag.read import BagError, scan_bag
from sappc.bag.cdr import decode

__all__ = ["CLOCK_RATE_HZ", "ReplayPlan", "plan_replay", "replay"]

#: Rate of the ``/clock`` replay publishes for a bag that has none [Hz] (as ``ros2 bag play
#: --clock``'s default order of magnitude; 100 Hz matches the control rate).
CLOCK_RATE_HZ = 100.0
#: Period of the publishing timer [s]: a message goes out at most this late.
TICK_S = 0.001
_NS = 1_000_000_000


@dataclass
class ReplayPlan:
    """What to publish and when."""

    topics: dict[int, tuple[str, str]]  # channel id -> (topic, type)
    channel: NDArray[np.int64]  # (M,) per message, in recording order
    payload: list[bytes]  # (M,) raw CDR
    due_ns: NDArray[np.int64]  # (M,) bag time of each message, from the first one [ns]
    clock_from_bag: bool  # the bag has /clock (republished); else replay publishes one
    clock_ns: NDArray[np.int64]  # (M,) the /clock value to publish before each message (no /clock in the bag)
    time_base: str  # "simulated (/clock)" or "recording"


def plan_replay(path: str | Path, topics: list[str] | None = None) -> ReplayPlan:
    """Read the bag and work out the schedule (see the module docstring).

    Raises
    ------
    BagError
        If the bag is not readable, or ``topics`` names a topic it does not have.
    """
    scan = scan_bag(path)
    present = set(np.unique(scan.channel_id).tolist())  # channels with at least one message
    cdr = {cid: c for cid, c in scan.channels.items() if c.message_encoding == "cdr" and cid in present}
    clock_ids = [cid for cid, c in cdr.items() if c.topic.lstrip("/") == CLOCK.name.lstrip("/")]
    if topics:
        wanted = {t.lstrip("/") for t in topics}
        unknown = wanted - {c.topic.lstrip("/") for c in cdr.values()}
        if unknown:
            raise BagError(f"{path}: no topic {sorted(unknown)[0]!r} in the bag; it has {sorted(c.topic for c in cdr.values())}")
        keep = {cid for cid, c in cdr.items() if c.topic.lstrip("/") in wanted} | set(clock_ids)
    else:
        keep = set(cdr)
    sel = np.isin(scan.channel_id, list(keep))
    if not sel.any():
        raise BagError(f"{path}: nothing to replay" + (f" (reading stopped: {scan.truncated})" if scan.truncated else ""))
    channel = scan.channel_id[sel]
    start, length = scan.start[sel], scan.length[sel]
    buf = scan.buffer
    payload = [buf[s : s + n] for s, n in zip(start.tolist(), length.tolist())]
    on_clock = np.flatnonzero(np.isin(channel, clock_ids))
    clock = decode(CLOCK.type_name, buf, start[on_clock], length[on_clock])
    assert clock is not None, "/clock is one of the contract's types, which decode() always knows"
    is_clock = np.zeros(channel.size, dtype=bool)
    is_clock[on_clock[clock.index]] = True  # an undecodable /clock message is replayed, but times nothing
    log_ns = scan.log_time_ns[sel]
    if is_clock.any() and np.array_equal(log_ns[is_clock], clock.stamps_ns):
        bag_time = log_ns  # recorded on simulated time (the recorder in lockstep): each message at its own time
        clock_ns = np.zeros(0, dtype=np.int64)
        base = "simulated (recorded on /clock time)"
    elif is_clock.any():
        # recorded on wall time (older bags): each message is due at the latest /clock recorded
        # before it (the first clock before any)
        which = np.cumsum(is_clock) - 1
        bag_time = clock.stamps_ns[np.maximum(which, 0)]
        clock_ns = np.zeros(0, dtype=np.int64)
        base = "simulated (/clock)"
    else:
        bag_time = log_ns
        clock_ns = bag_time
        base = "recording"
    return ReplayPlan(
        topics={cid: (cdr[cid].topic, cdr[cid].schema_name) for cid in keep},
        channel=channel,
        payload=payload,
        due_ns=bag_time - bag_time[0],
        clock_from_bag=bool(is_clock.any()),
        clock_ns=clock_ns,
        time_base=base,
    )


class ReplayNode(ProjectNode):
    """Publishes a :class:`ReplayPlan` on a 1 kHz timer (see the module docstring)."""

    def __init__(self, plan: ReplayPlan, *, rate: float, loop: bool, wait_subscribers: int, start_delay_s: float) -> None:
        super().__init__("replay")
        self.plan = plan
        self.rate = check_positive("--rate", rate)
        self.loop = loop
        self.wait_subscribers = int(wait_subscribers)
        if self.wait_subscribers < 0:
            raise ConfigError(f"--wait-subscribers must be >= 0, got {wait_subscribers}")
        self.start_delay_s = check_positive("--start-delay", start_delay_s, allow_zero=True)
        self.pubs: dict[int, Any] = {}
        skipped = []
        for cid, (name, type_name) in plan.topics.items():
            topic = Topic(name, type_name, None)
            try:
                topic.msg_class  # noqa: B018 - imports the message package
            except (ImportError, AttributeError, ValueError):
                skipped.append(f"{name} ({type_name})")
                continue
            self.pubs[cid] = self.counting_publisher(topic)
        if skipped:
            self.get_logger().warning(f"not replayed, message type not installed: {', '.join(skipped)}")
        if not self.pubs:
            raise ConfigError("no topic of the bag can be replayed here (no message type installed)")
        self.clock_pub = None if plan.clock_from_bag else self.counting_publisher(CLOCK)
        self.loops = 0
        self.max_lag_s = 0.0
        self._next = 0
        self._last_clock_ns: int | None = None
        self._created = time.monotonic()
        self._t0: float | None = None  # wall time of the first message of the current pass
        self._waiting_logged = False
        self.create_timer(TICK_S, self._tick)

    def _ready(self) -> bool:
        if time.monotonic() - self._created < self.start_delay_s:
            return False
        if self.wait_subscribers:
            short = [p.resolved_name for p in self.pubs.values() if p.pub.get_subscription_count() < self.wait_subscribers]
            if short:
                if not self._waiting_logged:
                    self.get_logger().info(f"waiting for {self.wait_subscribers} subscriber(s) on {', '.join(short)}")
                    self._waiting_logged = True
                return False
        return True

    def _publish_clock(self, ns: int) -> None:
        from sappc_msgs_py.convert import ns_to_stamp

        msg = CLOCK.msg_class()
        msg.clock = ns_to_stamp(ns)
        self.clock_pub.publish(msg)  # type: ignore[union-attr]  # called only when clock_pub is set (see _tick)
        self._last_clock_ns = ns

    def _tick(self) -> None:
        if self.finished:
            return
        if self._t0 is None:
            if not self._ready():
                return
            self._t0 = time.monotonic()
        plan, now = self.plan, time.monotonic()
        elapsed_ns = (now - self._t0) * self.rate * _NS
        clock_period_ns = _NS / CLOCK_RATE_HZ
        while self._next < plan.due_ns.size and plan.due_ns[self._next] <= elapsed_ns:
            k = self._next
            pub = self.pubs.get(int(plan.channel[k]))
            if self.clock_pub is not None:
                c = int(plan.clock_ns[k])
                if self._last_clock_ns is None or c - self._last_clock_ns >= clock_period_ns or c < self._last_clock_ns:
                    self._publish_clock(c)
            if pub is not None:
                pub.publish(plan.payload[k])
            self.max_lag_s = max(self.max_lag_s, elapsed_ns / _NS / self.rate - plan.due_ns[k] / _NS / self.rate)
            self._next += 1
        if self._next == plan.due_ns.size:
            self.loops += 1
            if self.loop:
                self._next, self._t0 = 0, time.monotonic()
            else:
                self.finished = True


def replay(path: str | Path, *, rate: float = 1.0, topics: list[str] | None = None, loop: bool = False,
           wait_subscribers: int = 0, domain_id: int | None = None, start_delay_s: float = 1.0) -> int:
    """Replay the bag at ``path`` until its end (or Ctrl-C with ``loop``); return the exit status."""
    plan = plan_replay(path, topics)
    if domain_id is not None:
        os.environ["ROS_DOMAIN_ID"] = str(domain_id)
    duration_s = plan.due_ns[-1] / _NS
    print(f"replaying {len(plan.payload)} messages on {len(plan.topics)} topics of {path}: "
          f"{duration_s:.2f} s of {plan.time_base} time at rate {rate:g}" + (", looping" if loop else ""), flush=True)
    holder: dict[str, ReplayNode] = {}

    def make(_args: list[str]) -> ReplayNode:
        holder["node"] = ReplayNode(plan, rate=rate, loop=loop, wait_subscribers=wait_subscribers, start_delay_s=start_delay_s)
        return holder["node"]

    status = run_node(make, [sys.argv[0]])
    node = holder.get("node")
    if node is not None:
        print(f"published {sum(p.count for p in node.pubs.values())} messages ({node.loops} pass(es)); largest lag behind schedule {node.max_lag_s * 1e3:.1f} ms")
    return status

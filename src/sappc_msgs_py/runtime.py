"""How every node of the project runs: start-up, readiness, the spin loop, a clean shutdown.

The facts behind the choices are measured in ``docs/ros2_notes.md``:

- ``EventsExecutor`` is the fastest executor for a lockstep loop (about 3,400 round trips/s
  across processes against 2,200 for ``SingleThreadedExecutor``), but its ``spin()`` without a
  timeout ignores signals; nodes therefore spin with :data:`SPIN_TIMEOUT_S` in a loop.
- rclpy's own SIGINT/SIGTERM handlers shut the context down at once, after which a node can no
  longer publish its last messages nor a recorder drain its queues.  Nodes here install their
  own handlers: a signal sets a flag, the loop ends, the node finishes (publishers wait until
  every subscriber acknowledged what they sent), and only then is the context shut down.
- A publisher only delivers to subscribers it has matched; a run must not start before the
  recorder and the loop partners are matched.  :class:`CountingPublisher` waits for an expected
  number of subscribers before its first message and counts what it publishes, so a bag can be
  checked message for message.
- The nodes publish the loop's messages as CDR bytes (:mod:`sappc_msgs_py.wire`), which
  :meth:`CountingPublisher.publish` hands to rclpy's C publisher directly; :func:`run_nodes`
  spins the executor in C++ (``spin_until_future_complete``) until a node finishes.
- A node may be a ROS 2 managed (lifecycle) node (:class:`ManagedNode`, parameter
  :data:`MANAGED`): it then starts unconfigured and is brought up through the standard lifecycle
  services (docs/design/modes.md, "Managed nodes").  By default it configures and activates itself
  while it is built, exactly as a plain node.
"""

from __future__ import annotations

import json
import os
import signal
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rclpy.lifecycle import LifecycleNodeMixin, LifecycleState, TransitionCallbackReturn
from rclpy.node import Node
from rclpy.parameter import Parameter

from gnc_common.validation import ConfigError
from sappc_msgs_py.parameters import REQUIRED, Param, descriptor, format_help
from sappc_msgs_py.timeline import AHEAD_FRAMES, MID_FRAME_PHASE, PLANT_PHASE, frame_index, period_ns

if TYPE_CHECKING:
    from rclpy.impl.rcutils_logger import RcutilsLogger

__all__ = [
    "ACK_TIMEOUT_S",
    "write_json_whole",
    "LOCKSTEP",
    "MANAGED",
    "MODE",
    "NEVER_CONFIGURED",
    "REALTIME",
    "COMMON_PARAMETERS",
    "CountingPublisher",
    "FramesAhead",
    "GridCursor",
    "MATCH_TIMEOUT_S",
    "ManagedNode",
    "ProjectNode",
    "SPIN_TIMEOUT_S",
    "START_CHECK_S",
    "START_LOG_S",
    "StartGate",
    "unmatched",
    "parse_expected",
    "run_node",
    "run_nodes",
]

#: Timing modes of every node (see docs/how-to/realtime.md): the plant owns time and the
#: others follow its stamped samples, or every node runs on wall-clock timers.
LOCKSTEP = "lockstep"
REALTIME = "realtime"

#: Longest blocking wait of the spin loop [s]: bounds the reaction time to a signal.
SPIN_TIMEOUT_S = 0.05
#: How long a publisher waits for its expected subscribers before giving up [s].  Discovery on
#: one host takes 0.2 to 0.55 s with the project's Fast DDS profile, 2.8 s without it.
MATCH_TIMEOUT_S = 20.0
#: Period of the start check of :meth:`ProjectNode.start_when` [s]: a twentieth of the discovery
#: time with the project's profile, so it adds little to the start.
START_CHECK_S = 0.01
#: Period of the "waiting for" message of a node whose partners are not there yet [s].
START_LOG_S = 5.0
#: How long a finishing node waits for subscribers to acknowledge its last messages [s].
ACK_TIMEOUT_S = 5.0


def parse_expected(entries: list[str], what: str = "expected_subscribers") -> dict[str, int]:
    """``["topic=2", "/clock=4"]`` -> ``{"topic": 2, "/clock": 4}`` (raises ConfigError naming the entry)."""
    out: dict[str, int] = {}
    for entry in entries:
        topic, sep, count = entry.rpartition("=")
        if not sep or not topic or not count.isdigit():
            raise ConfigError(f"{what}: entry {entry!r} must be 'topic=count' with a non-negative integer count")
        out[topic] = int(count)
    return out


class CountingPublisher:
    """A publisher that waits for ``min_subscribers`` matched subscribers before its first
    message, and counts the messages it publishes.  ``msg`` is a message of the topic's type for
    the node to fill and publish each time (the ``out=`` of :mod:`sappc_msgs_py.convert`'s
    encoders): rclpy serializes a message when it is published, so one object serves every publish."""

    def __init__(self, node: Any, topic: Any, min_subscribers: int, qos: Any) -> None:
        self.topic = topic
        self.msg = topic.msg_class()
        self.pub = node.create_publisher(topic.msg_class, topic.name, qos)
        self._publish_raw = self.pub.handle.publish_raw  # serialized messages, without rclpy's per-call type dispatch
        self.min_subscribers = min_subscribers
        self.count = 0
        self._ready = min_subscribers == 0

    @property
    def resolved_name(self) -> str:
        return str(self.pub.topic_name)

    def matched(self) -> bool:
        """Whether the expected subscribers are matched (does not wait)."""
        if not self._ready:
            self._ready = self.pub.get_subscription_count() >= self.min_subscribers
        return self._ready

    def wait_matched(self, timeout_s: float = MATCH_TIMEOUT_S) -> None:
        """Block until the expected subscribers are matched.

        Raises
        ------
        TimeoutError
            Naming the topic and the counts, when they are not matched within ``timeout_s``.
        """
        if self._ready:
            return
        deadline = time.monotonic() + timeout_s
        while self.pub.get_subscription_count() < self.min_subscribers:
            if time.monotonic() > deadline:
                raise TimeoutError(
                    f"{self.resolved_name}: {self.pub.get_subscription_count()} subscriber(s) matched after "
                    f"{timeout_s} s, expected {self.min_subscribers}"
                )
            time.sleep(0.005)
        self._ready = True

    def publish(self, msg: Any) -> None:
        """Publish ``msg``: CDR bytes (:mod:`sappc_msgs_py.wire`) or a message object of the topic's type."""
        if not self._ready:
            self.wait_matched()
        if type(msg) is bytes:
            self._publish_raw(msg)
        else:
            self.pub.publish(msg)
        self.count += 1

    def wait_acked(self, timeout_s: float = ACK_TIMEOUT_S) -> bool:
        """Wait until every matched (reliable) subscriber acknowledged every message."""
        from rclpy.duration import Duration

        return bool(self.pub.wait_for_all_acked(Duration(nanoseconds=int(timeout_s * 1e9))))


def _declare(node: Any, p: Param) -> Any:
    """Declare ``p`` on rclpy node ``node`` and return its value: the given one, else the default
    (``None`` for a :data:`REQUIRED` parameter not given)."""
    if p.dynamic_typing or (p.default is not REQUIRED and not (isinstance(p.default, (list, tuple)) and not p.default)):
        value = node.declare_parameter(p.name, None if p.default is REQUIRED else p.default, descriptor(p)).value
    else:  # no default to take the type from: declared by type
        types = {"double": Parameter.Type.DOUBLE, "integer": Parameter.Type.INTEGER, "bool": Parameter.Type.BOOL, "string": Parameter.Type.STRING,
                 "double[]": Parameter.Type.DOUBLE_ARRAY, "integer[]": Parameter.Type.INTEGER_ARRAY, "string[]": Parameter.Type.STRING_ARRAY}
        value = node.declare_parameter(p.name, types[p.type], descriptor(p)).value
        if value is None and p.default is not REQUIRED:
            value = list(p.default)
    return value


class StartGate:
    """Whether a node's partners are there: ``open()`` is true once ``missing()`` (what the node
    still waits for, in words) has been empty, and stays true; while it is not, what is missing
    is logged every :data:`START_LOG_S` (a node started before its partners waits for them,
    however long).

    A node never waits inside a callback: a publish before its subscribers are matched would block
    the executor (a real-time timer then misses the ticks of the whole discovery, 0.2 to 0.4 s),
    so real-time timers skip their ticks until the gate is open, and lockstep starts with
    :meth:`ProjectNode.start_when`.
    """

    def __init__(self, node: Node, missing: Callable[[], list[str]]) -> None:
        self._node = node
        self._missing = missing
        self._open = False
        self._began = self._logged = time.monotonic()

    def open(self) -> bool:
        if self._open:
            return True
        waiting = self._missing()
        self._open = not waiting
        if waiting and time.monotonic() - self._logged >= START_LOG_S:
            self._logged = time.monotonic()
            self._node.get_logger().info(f"waiting {self._logged - self._began:.0f} s for: {'; '.join(waiting)}")
        return self._open


def unmatched(publishers: list[CountingPublisher]) -> list[str]:
    """What :class:`StartGate` waits for among ``publishers``: those without their expected subscribers."""
    return [f"{p.min_subscribers} subscriber(s) of {p.resolved_name}" for p in publishers if not p.matched()]


class GridCursor:
    """Which samples of a lockstep grid a node that publishes ahead of ``/clock`` still owes.

    The reference and the injector know their samples in advance.  They publish samples 0 and 1
    as soon as their subscribers are matched, without waiting for a ``/clock`` tick (a tick sent
    before their ``/clock`` subscription was matched is never delivered: the plant's first tick
    races discovery), and on each tick ``t_k`` every sample up to ``k + 1`` not yet published, so
    a missed tick is made up at the next one.  ``through(k)`` is the samples to publish now to
    have published ``0 .. k`` (capped at ``last``, the grid's last sample; ``None``: no end).
    """

    def __init__(self, last: int | None) -> None:
        self.next = 0
        self.last = last

    def through(self, k: int) -> range:
        end = k if self.last is None else min(k, self.last)
        owed = range(self.next, max(self.next, end + 1))
        self.next = owed.stop
        return owed


class FramesAhead:
    """Real time: the samples a node that knows them in advance (the reference, the disturbance)
    publishes, on the frames of :mod:`sappc_msgs_py.timeline`, in step with the plant's run.

    The run's sample ``k`` is frame ``f0 + k``, where ``f0`` is the frame of the first state the
    plant publishes (``state/attitude``, stamped with its frame's start): every node of the run
    then stamps sample ``k`` alike, whenever it started, and the reference and the disturbance
    end on the plant's last frame.  (A node that picked its own ``f0`` at its first tick ran a
    few frames ahead of or behind the plant: the last frames of a run then found no reference
    of their stamp.)  The plant waits for this subscription to be matched before its first state
    (``expected_subscribers``), so the first state is never missed.

    On the first state the samples of frames ``f0 .. f0 + AHEAD_FRAMES`` are published at once;
    from then on a timer in the middle of each frame publishes up to
    :data:`~sappc_msgs_py.timeline.AHEAD_FRAMES` frames ahead (a missed tick is made up at the
    next: :class:`GridCursor`), never past the grid's ``last`` sample.  Nothing is published
    before ``ready()`` (the node's publishers matched: a publish must not block a callback).

    ``publish(k, stamp_ns)`` publishes sample ``k`` stamped ``stamp_ns``.
    """

    def __init__(self, node: ProjectNode, dt_s: float, last: int | None, ready: Callable[[], bool],
                 publish: Callable[[int, int], None]) -> None:
        from sappc_msgs_py.contract import STATE_ATTITUDE, qos_profile

        self.dt_ns = period_ns(dt_s)
        self.frame0: int | None = None  # the frame of sample 0: the plant's first state
        self._cursor = GridCursor(last)
        self._node = node
        self._ready = ready
        self._publish = publish
        node.create_subscription(STATE_ATTITUDE.msg_class, STATE_ATTITUDE.name, self._on_state, qos_profile())
        node.create_frame_timer(dt_s, MID_FRAME_PHASE, self._on_timer)

    def start_at(self, stamp_ns: int) -> None:
        """The run starts at the frame of ``stamp_ns`` (the plant's first state), unless it has
        started already; the first samples are published at once."""
        if self.frame0 is not None:
            return
        self.frame0 = frame_index(stamp_ns, self.dt_ns, PLANT_PHASE)
        self._publish_due(self.frame0)

    def run_time_s(self, stamp_ns: int) -> float | None:
        """The run's time [s] of a stamp (since sample 0's frame); ``None`` before the run started."""
        return None if self.frame0 is None else (stamp_ns - self.frame0 * self.dt_ns) / 1e9

    def _on_state(self, msg: Any) -> None:
        if self.frame0 is None:
            from sappc_msgs_py.convert import stamp_to_ns

            self.start_at(stamp_to_ns(msg.header.stamp))

    def _on_timer(self) -> None:
        if self.frame0 is not None:  # before f0 (the plant publishes sample 0 ahead), as at f0
            self._publish_due(max(frame_index(self._node.get_clock().now().nanoseconds, self.dt_ns, MID_FRAME_PHASE), self.frame0))

    def _publish_due(self, frame: int) -> None:
        """Publish every sample owed through ``frame + AHEAD_FRAMES``, once ``ready()``."""
        assert self.frame0 is not None
        if not self._ready():
            return
        for k in self._cursor.through(frame + AHEAD_FRAMES - self.frame0):
            self._publish(k, (self.frame0 + k) * self.dt_ns)


#: The parameters every node declares (:class:`ProjectNode`).
COMMON_PARAMETERS = (
    Param("expected_subscribers", [], "subscribers each publisher waits for before its first message, as 'topic=count' entries "
          "(a topic not listed: the node's default, 1 on the topics of the control loop, else 0)", type="string[]"),
    Param("counts_file", "", "where the node writes the messages it published per topic (JSON) when it finishes; '' for none"),
)
#: Whether a node is a ROS 2 managed (lifecycle) node (:class:`ManagedNode`): listed among the
#: own parameters of each node that can be one.
MANAGED = Param("managed", False, "a ROS 2 managed (lifecycle) node: start unconfigured and wait for the standard "
                "lifecycle services (/<node>/change_state, /<node>/get_state: configure, activate, deactivate, cleanup, "
                "shutdown); false: configured and active from the start (docs/design/modes.md, 'Managed nodes')")
#: The timing mode of every node.
MODE = Param("mode", LOCKSTEP, "lockstep: the plant owns time and the others follow its stamped samples; realtime: wall-clock timers",
             choices=(LOCKSTEP, REALTIME))


class ProjectNode(Node):
    """Base of the project's nodes: declared parameters, publishers that count, a finished flag,
    a counts file.

    Every node declares :data:`COMMON_PARAMETERS` (``expected_subscribers``: the subscribers each
    publisher waits for before its first message; ``counts_file``: where :meth:`finish` writes
    the messages published per topic), and its own, listed in ``PARAMETERS`` and declared with
    :meth:`param` (``python -m <COMMAND> --help`` prints them: :meth:`help_text`).  Subclasses
    create publishers with :meth:`counting_publisher` and set ``self.finished`` when their work
    is done; :func:`run_node` then finishes the node cleanly.
    """

    #: The node's own parameters (after :data:`COMMON_PARAMETERS`), in the order ``--help`` lists them.
    PARAMETERS: tuple[Param, ...] = ()
    #: How the node is run on its own.
    COMMAND = ""

    def __init__(self, node_name: str, **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self._finished = False
        self.finished_future: Any = None  # run_nodes's: done when a node of the process finishes
        self.up_monotonic_s: float | None = None  # run_nodes's: when every node of the process was built (CLOCK_MONOTONIC [s])
        self.callback_times: CallbackTimes | None = None  # run_nodes's developer aid (SAPPC_CALLBACK_TIMES_DIR), when set
        self._expected = parse_expected(list(self.param(COMMON_PARAMETERS[0])))
        self._counts_file = str(self.param(COMMON_PARAMETERS[1]))
        self._counting_pubs: list[CountingPublisher] = []
        self._retired_counts: dict[str, int] = {}  # what counting publishers destroyed early (a cleanup) published
        self._frame_timers: list[Any] = []  # create_frame_timer's timers (kept referenced)

    @property
    def finished(self) -> bool:
        """Whether the node's work is done (:func:`run_nodes` then finishes it)."""
        return self._finished

    @finished.setter
    def finished(self, value: bool) -> None:
        self._finished = value
        if value and self.finished_future is not None and not self.finished_future.done():
            self.finished_future.set_result(True)  # the executor's spin returns at once

    @classmethod
    def parameter_sections(cls) -> list[tuple[str, tuple[Param, ...]]]:
        """The parameters ``--help`` lists, by section."""
        return [("parameters", cls.PARAMETERS), ("parameters of every node", COMMON_PARAMETERS)]

    @classmethod
    def help_text(cls) -> str:
        """``--help``: the module's summary, then every declared parameter (:func:`~sappc_msgs_py.parameters.format_help`)."""
        doc = sys.modules[cls.__module__].__doc__ or ""
        return format_help(cls.COMMAND, doc.strip().split("\n\n", 1)[0], cls.parameter_sections())

    if TYPE_CHECKING:
        # rclpy's Node.get_logger and Node.destroy_node have no annotations, and mypy's
        # untyped_calls_exclude matches the receiver's class (a project node), not the class that
        # defines the method: their types here, for the type checker only (no run-time cost).
        def get_logger(self) -> RcutilsLogger: ...

        def destroy_node(self) -> None: ...

    def param(self, p: Param) -> Any:
        """Declare parameter ``p`` (one of the node's ``PARAMETERS``) and return its value; a
        :data:`~sappc_msgs_py.parameters.REQUIRED` one not given is ``None``.  A read-only
        parameter is read once at start-up, so a change at run time is refused (rclpy says why)
        rather than accepted and never applied.

        Raises
        ------
        ConfigError
            For a value not among ``p.choices``, or one rclpy refuses (of another type than
            declared, outside the descriptor's range): one line naming the parameter and value.
        """
        from rclpy.exceptions import ParameterException

        try:
            # declared already: a managed node configured again after its cleanup reads it again
            value = self.get_parameter(p.name).value if self.has_parameter(p.name) else _declare(self, p)
        except ParameterException as exc:  # rclpy's words name the parameter and the value; not a traceback
            raise ConfigError(" ".join(str(exc).split())) from None
        if value is None and isinstance(p.default, (list, tuple)):  # declared by type, not given (_declare)
            value = list(p.default)
        if p.choices and value not in p.choices:
            raise ConfigError(f"{p.name} must be one of {', '.join(repr(c) for c in p.choices)}, got {value!r}")
        return value

    def check_unknown_overrides(self, ignore_prefixes: tuple[str, ...] = ()) -> None:
        """Refuse a given parameter (``-p``, ``--params-file``) the node did not declare: a typo
        would otherwise be ignored.  Call it after every declaration.

        Raises
        ------
        ConfigError
            Naming the first unknown parameter (those starting with one of ``ignore_prefixes`` are let pass).
        """
        overrides = getattr(self, "_parameter_overrides", {})
        for name in sorted(overrides):
            if name not in self._parameters and not name.startswith(ignore_prefixes):
                listed = f" ({self.COMMAND} --help lists them)" if self.COMMAND else ""
                raise ConfigError(f"unknown parameter {name!r} for the {self.get_name()} node{listed}")

    def mode_param(self) -> str:
        """Declare :data:`MODE` and return it (:data:`LOCKSTEP` or :data:`REALTIME`)."""
        return str(self.param(MODE))

    def counting_publisher(self, topic: Any, default_min_subscribers: int = 0) -> CountingPublisher:
        from sappc_msgs_py.contract import qos_profile

        pub = CountingPublisher(self, topic, self._expected.get(topic.name, default_min_subscribers), qos_profile())
        self._counting_pubs.append(pub)
        return pub

    def start_when(self, missing: Callable[[], list[str]], start: Callable[[], None]) -> None:
        """Call ``start()`` once, as soon as ``missing()`` (what the node still waits for, in
        words) is empty; checked every :data:`START_CHECK_S` without blocking the executor
        (:class:`StartGate`)."""
        gate = StartGate(self, missing)

        def check() -> None:
            if gate.open():
                timer.cancel()
                start()

        timer = self.create_timer(START_CHECK_S, check)

    def create_frame_timer(self, period_s: float, phase: float, callback: Callable[[], None]) -> None:
        """Call ``callback`` every ``period_s`` on the real-time frame grid
        (:mod:`sappc_msgs_py.timeline`), at ``phase`` (a fraction of the period) into each frame.

        An rcl timer ticks at its creation time plus whole periods; a one-shot timer therefore
        waits for the next tick instant of the grid, ticks, and creates the periodic timer there
        (its ticks then trail the grid by the one-shot's dispatch, tens of microseconds).
        """
        dt_ns = period_ns(period_s)
        now_ns = self.get_clock().now().nanoseconds
        first_ns = (now_ns // dt_ns + 1) * dt_ns + round(phase * dt_ns)

        def first_tick() -> None:
            one_shot.cancel()
            self._frame_timers.append(self.create_timer(period_s, callback))
            callback()

        one_shot = self.create_timer((first_ns - now_ns) / 1e9, first_tick)
        self._frame_timers.append(one_shot)

    def publish_counts(self) -> dict[str, int]:
        """Messages published per resolved topic name (those of publishers destroyed since included)."""
        counts = dict(self._retired_counts)
        for p in self._counting_pubs:
            counts[p.resolved_name] = counts.get(p.resolved_name, 0) + p.count
        return counts

    def end_run(self) -> None:
        """Stop every timer of the node: the run has ended, and nothing it would publish belongs
        to it (in a composed run the executor spins on while the recorder drains; a timer would
        publish samples past the run's end)."""
        for timer in list(self.timers):
            timer.cancel()

    def finish(self) -> None:
        """Wait for every subscriber to acknowledge, then write the counts file (if asked)."""
        for pub in self._counting_pubs:
            if pub.count and not pub.wait_acked():
                self.get_logger().warning(f"{pub.resolved_name}: not every subscriber acknowledged within {ACK_TIMEOUT_S} s")
        if self._counts_file:
            write_json_whole(self._counts_file, self.publish_counts(), indent=1, sort_keys=True)


def write_json_whole(path: str | Path, value: Any, **dumps: Any) -> None:
    """``value`` as JSON at ``path``, replaced whole (written beside it, then renamed): a reader in
    another process sees the old file or the new one, never a part (the nodes' files that
    ``sappc run`` polls: counts, progress, the live view's address and verdict)."""
    path = Path(path)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(value, **dumps))
    tmp.replace(path)


#: The closing line of a managed node that was never configured (:meth:`ManagedNode.finished_unconfigured`).
NEVER_CONFIGURED = "finished: never configured (a managed node that received no configure transition, or none succeeded)"


class ManagedNode(LifecycleNodeMixin, ProjectNode):
    """A :class:`ProjectNode` that is a ROS 2 managed (lifecycle) node when its parameter
    :data:`MANAGED` is true, and a plain node, configured and active from the start, when it is
    false (the default).

    A subclass puts what it does at start-up (declare and validate its parameters, load its
    compiled kernels, create its subscriptions, timers and publishers) in :meth:`configure_node`,
    which raises :class:`~gnc_common.validation.ConfigError` (or ``ValueError``) naming a bad
    parameter, and reads :attr:`active` where an inactive node must behave otherwise.

    Not managed: :meth:`configure_node` runs while the node is built (a bad parameter raises out
    of the constructor: the process stops with exit status 2, as every node's does) and the node is
    active; it offers no lifecycle services and has no lifecycle state machine.

    Managed (``managed:=true``; docs/design/modes.md, "Managed nodes"): the node is built with
    only :data:`COMMON_PARAMETERS` and :data:`MANAGED` declared and nothing subscribed or offered,
    in the primary state ``unconfigured``, and offers rclpy's lifecycle services
    (``/<node>/change_state``, ``get_state``, ``get_available_states``,
    ``get_available_transitions``, ``get_transition_graph``; ``lifecycle_msgs/srv``).  A
    transition not allowed from the current state is refused (``success: false``; rclpy's own
    handler would raise out of the executor and end the process).  The transitions:

    configure
        :meth:`configure_node`; the node is then ``inactive``.  A bad parameter fails the
        transition (``success: false``; the reason is logged at error level, naming it) and the
        node stays ``unconfigured``, alive (the process lives on); whatever the attempt had
        created is destroyed.  Any other exception is logged with its traceback and takes the node
        through ``ErrorProcessing`` back to ``unconfigured``.
    activate, deactivate
        :attr:`active` set and cleared; what that means is the subclass's.
    cleanup
        Every subscription, timer and publisher created since the configure transition began is
        destroyed (the counts of the destroyed publishers are kept for the counts file), then
        :meth:`release_node`; back to ``unconfigured``.  The declared parameters stay declared
        (with their values), and a new configure reads them again.
    shutdown
        From any primary state: as cleanup when configured; then ``finalized``.  The process
        keeps spinning until it is stopped as any node is (SIGINT, SIGTERM): ending it inside the
        service call could lose the call's response.

    The transitions run in the executor's thread, between the node's other callbacks, so an input
    is handled either wholly before or wholly after a transition.  rclpy's
    :class:`~rclpy.lifecycle.LifecyclePublisher` (which drops what is published while inactive) is
    not used: what an inactive node publishes is the subclass's decision (an inactive controller
    still answers the plant, with zero torque).
    """

    def __init__(self, node_name: str, **kwargs: Any) -> None:
        ProjectNode.__init__(self, node_name, **kwargs)
        self.managed = bool(self.param(MANAGED))
        #: Whether the node is configured (managed: between configure and cleanup or shutdown).
        self.configured = False
        #: Whether the node is active (not managed: always).
        self.active = False
        #: Successful configurations so far (0: the node never ran; its counters do not exist).
        self.configurations = 0
        self._before_configure: tuple[list[Any], list[Any], list[Any]] | None = None
        if not self.managed:
            self.configure_node()
            self.configured, self.active, self.configurations = True, True, 1
            return
        LifecycleNodeMixin.__init__(self)
        # rclpy's change_state service raises out of the executor (which ends the node) on a
        # transition id the current state does not have: refused instead, as a wrong label is
        self._service_change_state.callback = self._refusing_unknown_transitions(self._service_change_state.callback)
        where = f"{self.get_fully_qualified_name()}/change_state"
        self.get_logger().info(f"managed node: unconfigured; waiting for a configure transition on {where}")

    def destroy_node(self) -> None:
        """Destroy the node, and a managed node's lifecycle state machine with it: the machine owns
        the lifecycle services and holds the node's handle, so rclpy's ``Node.destroy_node`` alone
        leaves them offered until the garbage collector finds the node (another node of the same
        name on the domain would then share its clients with a server that never answers)."""
        super().destroy_node()
        if self.managed:
            self._state_machine.destroy_when_not_in_use()

    def _refusing_unknown_transitions(self, handle: Callable[[Any, Any], Any]) -> Callable[[Any, Any], Any]:
        """rclpy's ``change_state`` handler ``handle``, answering ``success: false`` (and logging
        why) where it would raise: a transition that does not leave the current state."""
        from rclpy.impl.implementation_singleton import rclpy_implementation

        def change_state(request: Any, response: Any) -> Any:
            try:
                return handle(request, response)
            except rclpy_implementation.RCLError as exc:
                self.get_logger().warning(f"transition {request.transition.id} {request.transition.label!r} refused: {exc}")
                response.success = False
                return response

        return change_state

    def finished_unconfigured(self) -> bool:
        """At the end, a managed node that was never configured (it received no configure
        transition, or none succeeded: its counters do not exist): its closing line
        (:data:`NEVER_CONFIGURED`) said and the base's finish done; ``True``.  ``False`` otherwise
        (the node says its own closing line)."""
        if self.configurations:
            return False
        self.get_logger().info(NEVER_CONFIGURED)
        ProjectNode.finish(self)
        return True

    def configure_node(self) -> None:
        """Declare and validate the parameters, load the kernels, create the subscriptions,
        timers and publishers (the subclass's start-up).

        Raises
        ------
        ConfigError
            Naming a missing, unknown, invalid or infeasible parameter (``ValueError`` likewise).
        """

    def release_node(self) -> None:
        """What a cleanup releases beyond the subscriptions, timers and publishers created by
        :meth:`configure_node` (which :class:`ManagedNode` destroys itself): e.g. a parameter callback."""

    # ---- lifecycle transitions (rclpy's LifecycleNodeMixin calls them; managed nodes only) ----
    def _entities(self) -> tuple[list[Any], list[Any], list[Any]]:
        return list(self.subscriptions), list(self.timers), list(self.publishers)

    def _release(self) -> None:
        """Destroy what was created since the configure transition began, then :meth:`release_node`."""
        if self._before_configure is None:
            return
        subs, timers, pubs = self._before_configure
        self._before_configure = None
        for cp in [cp for cp in self._counting_pubs if cp.pub not in pubs]:
            self._retired_counts[cp.resolved_name] = self._retired_counts.get(cp.resolved_name, 0) + cp.count
            self._counting_pubs.remove(cp)
        for timer in [t for t in self.timers if t not in timers]:
            self.destroy_timer(timer)
        self._frame_timers = [t for t in self._frame_timers if t in timers]
        for sub in [s for s in self.subscriptions if s not in subs]:
            self.destroy_subscription(sub)
        for pub in [p for p in self.publishers if p not in pubs]:
            self.destroy_publisher(pub)
        self.release_node()
        self.configured = self.active = False

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._before_configure = self._entities()
        try:
            self.configure_node()
        except (ConfigError, ValueError) as exc:
            self.get_logger().error(f"configure failed: {exc}; the node stays unconfigured")
            self._release()
            return TransitionCallbackReturn.FAILURE
        except Exception:  # a defect, not a parameter: its traceback, then ErrorProcessing (on_error)
            import traceback

            self.get_logger().error(f"configure raised:\n{traceback.format_exc()}")
            return TransitionCallbackReturn.ERROR
        self.configured = True
        self.configurations += 1
        if self.callback_times is not None:  # what configure subscribed is timed too (the developer aid)
            self.callback_times.wrap(self)
        self.get_logger().info("configured: inactive")
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.active = True
        self.get_logger().info("activated")
        return TransitionCallbackReturn.SUCCESS

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.active = False
        self.get_logger().info("deactivated")
        return TransitionCallbackReturn.SUCCESS

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._release()
        self.get_logger().info("cleaned up: unconfigured")
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._release()
        self.get_logger().info("shut down: finalized")
        return TransitionCallbackReturn.SUCCESS

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._release()
        self.get_logger().error(f"a transition from {state.label} failed with an error: what configure made is released; unconfigured")
        return TransitionCallbackReturn.SUCCESS


def run_node(make_node: Callable[[list[str]], ProjectNode], argv: list[str] | None = None, node_class: type[ProjectNode] | None = None) -> int:
    """Initialise rclpy, build the node, spin it until it finishes or a signal arrives, finish.

    ``make_node(args)`` gets the arguments (ROS arguments included) and returns a node using
    :class:`ProjectNode`; ``-h`` or ``--help`` before ``--ros-args`` prints ``node_class``'s
    :meth:`~ProjectNode.help_text` and returns 0 without starting ROS.  See :func:`run_nodes`
    (this is it with one node).
    """
    args = list(sys.argv if argv is None else argv)
    user_args = args[1:args.index("--ros-args")] if "--ros-args" in args else args[1:]
    if node_class is not None and ("-h" in user_args or "--help" in user_args):
        try:
            print(node_class.help_text(), flush=True)
        except BrokenPipeError:  # `--help | head`: the reader has what it wanted
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error when Python flushes at exit
        return 0
    return run_nodes(lambda a: [make_node(a)], args)


class CallbackTimes:
    """Developer aid (``SAPPC_CALLBACK_TIMES_DIR=DIR`` in the environment of :func:`run_nodes`, as
    ``SAPPC_PROFILE_DIR``): the wall time every subscription's and timer's callback of ``nodes``
    takes, summed per node and topic (``timer`` for the timers), written once the nodes finish to
    ``DIR/<the process's node names>.json``: ``{node:
    {topic: {"calls", "total_s", "us_per_call"}}}``.  Where a loop spends its Python, measured in
    the loop: the same code runs about twice as slowly there as alone (docs/performance.md, "What
    the loop spends above the work floor").  Each callback is wrapped once, before the executor
    takes the nodes; the wrapper's own cost (two clock reads) is in the figures."""

    def __init__(self, nodes: list[ProjectNode]) -> None:
        self._sums: dict[tuple[str, str], list[int]] = {}  # (node, topic) -> [calls, total ns]
        self._wrapped: set[int] = set()  # the ids of the subscriptions and timers wrapped
        for node in nodes:
            self.wrap(node)
            node.callback_times = self  # a managed node's configure wraps what it creates (ManagedNode.on_configure)

    def wrap(self, node: ProjectNode) -> None:
        """Time every subscription's and timer's callback of ``node`` not timed yet."""
        entities: list[tuple[Any, str]] = [*((sub, str(sub.topic_name)) for sub in node.subscriptions), *((t, "timer") for t in node.timers)]
        for entity, topic in entities:
            if id(entity) not in self._wrapped:
                self._wrapped.add(id(entity))
                entity.callback = self._wrap(node.get_name(), topic, entity.callback)

    def _wrap(self, node: str, topic: str, callback: Callable[..., Any]) -> Callable[..., Any]:
        acc = self._sums.setdefault((node, topic), [0, 0])
        clock = time.perf_counter_ns

        def timed(*args: Any) -> Any:
            start = clock()
            try:
                return callback(*args)
            finally:
                acc[0] += 1
                acc[1] += clock() - start

        return timed

    def write(self, path: Path) -> None:
        """The sums so far, as JSON, to ``path`` (replaced whole)."""
        doc: dict[str, dict[str, dict[str, float]]] = {}
        for (node, topic), (calls, ns) in sorted(self._sums.items()):
            doc.setdefault(node, {})[topic] = {"calls": calls, "total_s": ns / 1e9, "us_per_call": ns / calls / 1e3 if calls else 0.0}
        path.write_text(json.dumps(doc, indent=1))


def run_nodes(make_nodes: Callable[[list[str]], list[ProjectNode]], argv: list[str] | None = None) -> int:
    """Initialise rclpy, build the nodes, spin them on one ``EventsExecutor`` until one of them
    finishes or a signal arrives, then finish each in list order.

    One node is how every node runs in its own process; several is the composed graph
    (:mod:`sappc.graph.container`), listed in the order they must stop: publishers first (each
    waits until its subscribers acknowledged what it sent), a recorder last.  At the end every
    node's timers stop (:meth:`ProjectNode.end_run`), a recorder drains its queues (spinning the
    executor: what another node of the process still answers is published and counted), and
    then the nodes finish in that order.  A :class:`ConfigError` or
    ``ValueError`` while building them (invalid or infeasible parameters) is printed as one line
    naming the parameter, and the exit status is 2.

    Returns
    -------
    int
        0 on a clean finish (signals included), 2 on a configuration error, 1 on a failure.
    """
    import rclpy
    from rclpy.experimental.events_executor import EventsExecutor
    from rclpy.signals import SignalHandlerOptions
    from rclpy.task import Future
    from rclpy.utilities import try_shutdown

    args = list(sys.argv if argv is None else argv)
    stop = {"signal": 0}

    def on_signal(signum: int, _frame: Any) -> None:
        stop["signal"] = signum

    # before rclpy.init: from here on a signal only sets the flag, so the node finishes cleanly
    # (a KeyboardInterrupt once the participant exists would leave its shared memory behind)
    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    nodes: list[ProjectNode] = []
    status = 0
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
        try:
            nodes = make_nodes(args)
        except (ConfigError, ValueError) as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        up = time.monotonic()  # every node of the process built: what follows is discovery, matching and the run
        times_dir = os.environ.get("SAPPC_CALLBACK_TIMES_DIR", "")  # developer aid: each callback's wall time, in the loop
        times = CallbackTimes(nodes) if times_dir else None
        executor = EventsExecutor()
        for node in nodes:
            node.up_monotonic_s = up
            executor.add_node(node)
        profile_dir = os.environ.get("SAPPC_PROFILE_DIR", "")  # developer aid: cProfile of the spin loop
        profiler = None
        if profile_dir:
            import cProfile

            profiler = cProfile.Profile()
            profiler.enable()
        # spun in C++ until a node finishes, returning every SPIN_TIMEOUT_S to look at the signal
        # flag: no Python between the messages (a spin_once loop cost a few microseconds a message)
        done = Future()
        for node in nodes:
            node.finished_future = done
        while not stop["signal"] and not any(node.finished for node in nodes):
            executor.spin_until_future_complete(done, timeout_sec=SPIN_TIMEOUT_S)
        if profiler is not None:
            profiler.disable()
            profiler.dump_stats(str(Path(profile_dir) / f"{'+'.join(n.get_name() for n in nodes)}.prof"))
        # the run's end: every timer stops; a recorder takes what is still queued (spinning the
        # executor, so a callback of another node of the process still runs and is counted by
        # that node's finish, which comes after); then each node finishes, in list order
        for node in nodes:
            node.end_run()
        for node in nodes:
            if hasattr(node, "drain"):
                node.drain(lambda timeout_s: executor.spin_once(timeout_sec=timeout_s))
        for node in nodes:
            node.finish()
        if times is not None:
            times.write(Path(times_dir) / f"{'+'.join(n.get_name() for n in nodes)}.json")
    except TimeoutError as exc:
        print(f"error: {exc}", file=sys.stderr)
        status = 1
    finally:
        for node in nodes:
            node.destroy_node()
        try_shutdown()
        for s, handler in old.items():
            signal.signal(s, handler)
    return status

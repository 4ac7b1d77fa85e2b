"""What the tests of the managed (lifecycle) nodes share (tests/nodes/test_lifecycle.py, the
controller's, and test_estimator_lifecycle.py, test_momentum_lifecycle.py, test_mode_lifecycle.py).

- :class:`LifecycleClient`: a node driven the way any ROS 2 tool drives one, a plain rclpy client
  of ``lifecycle_msgs`` (``ChangeState`` and ``GetState`` on ``/<node>/change_state`` and
  ``/<node>/get_state``), no project code on the client's side; the primary states it reads back,
  :data:`UNCONFIGURED`, :data:`INACTIVE`, :data:`ACTIVE`, :data:`FINALIZED`.
- :class:`TopicDriver`: the base of a test node that publishes a node's inputs, subscribes to its
  outputs and spins it, waiting on conditions with a deadline, never on fixed sleeps.
- What every managed node shows alike: :func:`assert_configure_fails` (a bad parameter fails the
  configure transition, the node alive and unconfigured, nothing of the attempt left, with what
  :func:`captured_log` caught), :func:`assert_not_managed` (the default node: active from the
  start, no lifecycle service), :func:`closing` (a driver and the node it spins taken down),
  :func:`diagnostics_report` (a report on ``diagnostics`` that says, or no longer says, that the
  node is inactive).
- :func:`managed_process`: ``python -m <package> -p managed:=true`` in the test's isolated
  environment with a lifecycle client, stopped by SIGINT, its shared memory checked
  (tests/shm_watch.py).
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from lifecycle_msgs.msg import State, Transition
from lifecycle_msgs.srv import ChangeState, GetState
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from conftest import ROOT
from shm_watch import ShmWatch

__all__ = ["ACTIVE", "FINALIZED", "INACTIVE", "START_S", "UNCONFIGURED", "LifecycleClient", "TopicDriver", "assert_configure_fails",
           "assert_not_managed", "captured_log", "closing", "diagnostics_report", "managed_process"]

#: The primary states as :meth:`LifecycleClient.state` reads them: (id, label).
UNCONFIGURED = (State.PRIMARY_STATE_UNCONFIGURED, "unconfigured")
INACTIVE = (State.PRIMARY_STATE_INACTIVE, "inactive")
ACTIVE = (State.PRIMARY_STATE_ACTIVE, "active")
FINALIZED = (State.PRIMARY_STATE_FINALIZED, "finalized")
#: Longest wait for a node's process to start (imports, the compiled kernels' cache) [s].
START_S = 120.0


class LifecycleClient:
    """What ``ros2 lifecycle get/set`` does, with plain rclpy: ``ChangeState`` and ``GetState``
    clients of node ``target``'s standard services, on ``node``, spun by ``spin_until``."""

    def __init__(self, node: Node, target: str, spin_until: Callable[[Callable[[], Any], str], None]) -> None:
        self.change = node.create_client(ChangeState, f"/{target}/change_state")
        self.get = node.create_client(GetState, f"/{target}/get_state")
        self.spin_until = spin_until
        spin_until(lambda: self.change.service_is_ready() and self.get.service_is_ready(), f"the lifecycle services of /{target}")

    def _call(self, client: Any, request: Any) -> Any:
        future = client.call_async(request)
        self.spin_until(future.done, f"the answer of {client.srv_name}")
        return future.result()

    def state(self) -> tuple[int, str]:
        s = self._call(self.get, GetState.Request()).current_state
        return s.id, s.label

    def transition(self, transition_id: int) -> bool:
        return bool(self._call(self.change, ChangeState.Request(transition=Transition(id=transition_id))).success)


class TopicDriver:
    """A test node, ``driver``, and an executor spinning it with ``nodes`` (those under test).  A
    subclass creates on :attr:`node` the publishers of their inputs (:attr:`pub`, by topic name)
    and the subscriptions to their outputs (:attr:`subs`); ``what`` names the node under test in
    what a wait that times out says, each wait at most ``deadline_s``."""

    def __init__(self, context: Any, nodes: list[Any], what: str, deadline_s: float) -> None:
        self.node = Node("driver", context=context)
        self.pub: dict[str, Any] = {}
        self.subs: list[Any] = []
        self.what, self.deadline_s = what, deadline_s
        self.executor = SingleThreadedExecutor(context=context)
        for n in (self.node, *nodes):
            self.executor.add_node(n)

    def spin_until(self, condition: Callable[[], Any], what: str) -> None:
        deadline = time.monotonic() + self.deadline_s
        while not condition():
            assert time.monotonic() < deadline, f"timed out waiting for {what}"
            self.executor.spin_once(timeout_sec=0.02)

    def subscribed(self) -> list[int]:
        """Each input's subscribers."""
        return [p.get_subscription_count() for p in self.pub.values()]

    def offered(self) -> list[int]:
        """Each output's publishers."""
        return [s.get_publisher_count() for s in self.subs]

    def matched(self) -> None:
        self.spin_until(lambda: min(self.subscribed()) >= 1 and min(self.offered()) >= 1, f"{self.what}'s topics matched")

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()


@contextlib.contextmanager
def closing(node: Any, driver: Any) -> Iterator[None]:
    """At the end of the block, whatever happened in it: ``driver``'s executor shut down (a
    :class:`TopicDriver` or any driver with ``executor`` and ``node``), ``node`` (the node under
    test) and the driver's node destroyed."""
    try:
        yield
    finally:
        driver.executor.shutdown()
        node.destroy_node()
        driver.node.destroy_node()


@contextlib.contextmanager
def captured_log(node: Any) -> Iterator[tuple[list[str], list[str]]]:
    """(errors, infos): what ``node``'s logger logs at error and at info level inside the block,
    each message logged all the same; the logger as it was afterwards."""
    errors: list[str] = []
    infos: list[str] = []
    logger = node.get_logger()
    original_error, original_info = logger.error, logger.info

    def error(message: str, **kw: Any) -> Any:
        errors.append(message)
        return original_error(message, **kw)

    def info(message: str, **kw: Any) -> Any:
        infos.append(message)
        return original_info(message, **kw)

    logger.error, logger.info = error, info
    try:
        yield errors, infos
    finally:
        logger.error, logger.info = original_error, original_info


def _entities(node: Any) -> tuple[int, int, int]:
    return len(list(node.subscriptions)), len(list(node.timers)), len(list(node.publishers))


def assert_configure_fails(lc: LifecycleClient, node: Any, errors: list[str], named: str, attempts: int = 1) -> None:
    """``attempts`` configure transitions of managed ``node`` (a bad parameter) each fail:
    ``success: false``, the node ``unconfigured``, nothing of the attempt left (no subscription,
    timer or publisher more than before), the reason logged at error level (``errors``, from
    :func:`captured_log`) naming ``named``; the node never configured and not active."""
    before = _entities(node)
    for attempt in range(1, attempts + 1):
        assert not lc.transition(Transition.TRANSITION_CONFIGURE), attempt
        assert lc.state() == UNCONFIGURED
        assert _entities(node) == before
        assert len(errors) == attempt and errors[-1].startswith("configure failed: ") and named in errors[-1], errors
    assert node.configurations == 0 and not node.active


def assert_not_managed(node: Any, name: str) -> None:
    """``node``, named ``name``, built with ``managed`` false (the default): configured and active
    while it was built, ``managed`` in its ``--help``, no lifecycle service offered."""
    assert node.get_parameter("managed").value is False and node.configured and node.active
    assert "  managed  (bool; default False)" in type(node).help_text()
    services = node.get_service_names_and_types_by_node(name, "/")
    assert not any(service.endswith(("/change_state", "/get_state")) for service, _ in services)


def diagnostics_report(driver: Any, since: int, words: str, inactive: bool) -> Any:
    """The status of the first report on ``diagnostics`` after the first ``since`` of
    ``driver.health`` (the ``diagnostic_msgs/DiagnosticArray`` messages as published) whose message
    starts (or, ``inactive`` false, does not start) with ``words``, the node's words for inactive,
    once it has come (a report of the last sample before a transition may still be on its way)."""
    def found() -> Any:
        return next((m.status[0] for m in driver.health[since:] if m.status[0].message.startswith(words) == inactive), None)

    driver.spin_until(lambda: found() is not None, f"a report on diagnostics {'' if inactive else 'not '}saying inactive")
    return found()


@contextlib.contextmanager
def managed_process(package: str, params_file: Path, params: tuple[str, ...], make_driver: Callable[[], Any],
                    deadline_s: float) -> Iterator[tuple[subprocess.Popen[str], Any, LifecycleClient, dict[str, str]]]:
    """(process, driver, lifecycle client, its log once stopped): ``python -m <package>`` managed,
    with the parameters of ``params_file`` and ``params`` (``-p`` entries), in the environment of
    the test (the ``ros_context`` fixture's isolated domain), a driver (``make_driver()``: a test
    node with ``executor`` and ``node``, its ``spin_until`` replaced by one that fails once the
    process has exited) and a lifecycle client on this process's side.  The node is named as the
    package without ``sappc_``; the first wait is at most :data:`START_S` (the process's start),
    each later one ``deadline_s``.  At the end the process gets SIGINT; its shared memory is
    checked (tests/shm_watch.py); a failure inside says what the process logged."""
    name = package.removeprefix("sappc_")
    watch = ShmWatch().__enter__()
    cmd = [sys.executable, "-m", package, "--ros-args", "--params-file", str(params_file),
           "-p", "managed:=true", *[a for p in params for a in ("-p", p)]]
    proc = subprocess.Popen(cmd, env=dict(os.environ), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=ROOT)
    watch.add(proc.pid)
    driver = make_driver()
    limit_s = [START_S]  # the first wait includes the process's start; each later one deadline_s

    def spin_until(condition: Callable[[], Any], what: str) -> None:
        deadline = time.monotonic() + limit_s[0]
        while not condition():
            assert proc.poll() is None, f"the {name} exited while waiting for {what}"
            assert time.monotonic() < deadline, f"timed out waiting for {what}"
            driver.executor.spin_once(timeout_sec=0.02)

    driver.spin_until = spin_until
    out = {"log": ""}
    failure: AssertionError | None = None
    try:
        client = LifecycleClient(driver.node, name, spin_until)
        limit_s[0] = deadline_s
        yield proc, driver, client, out
    except AssertionError as exc:
        failure = exc
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
        out["log"] = proc.communicate(timeout=60)[0]
        driver.executor.shutdown()
        driver.node.destroy_node()
        watch.__exit__(None, None, None)
    if failure is not None:
        raise AssertionError(f"{failure}\n--- the {name}'s log ---\n{out['log']}") from failure
    watch.assert_clean()

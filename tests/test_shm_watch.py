"""The shared-memory check of the ROS tests (:mod:`shm_watch`) looks at what the run's own
processes used: another Fast DDS process on the machine cannot trip it, and a run that leaks
(a node killed with SIGKILL) still fails it.  ``fastdds shm clean`` (what ``sappc run`` calls
after it had to kill a node) removes the leak and leaves a live process's segments alone."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from shm_watch import ShmWatch, fastdds_files

pytestmark = pytest.mark.slow

#: A ROS process: a node with a publisher and a subscription (a participant, its segment and
#: ports), "up" on stdout once they exist, then it waits for a line on stdin and shuts down cleanly.
_NODE = """
import sys, rclpy
from std_msgs.msg import String
rclpy.init()
node = rclpy.create_node("shm_probe")
node.create_publisher(String, "probe", 10)
node.create_subscription(String, "probe", lambda m: None, 10)
print("up", flush=True)
sys.stdin.readline()
node.destroy_node()
rclpy.try_shutdown()
"""
#: Longest a probe may take to start or stop [s] (imports and a participant: about 1 s here).
_PROBE_TIMEOUT_S = 60


@contextmanager
def _probe(tmp_path: Path, name: str) -> Iterator[subprocess.Popen[str]]:
    """A probe process on a domain of its own, up (its participant exists) when this yields."""
    from sappc.graph.launch import claim_domain_id, isolated_environment

    with claim_domain_id() as domain:
        proc = subprocess.Popen([sys.executable, "-c", _NODE], env=isolated_environment(domain, tmp_path / name), text=True,
                                stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
        try:
            assert proc.stdout is not None and proc.stdout.readline().strip() == "up", proc
            yield proc
        finally:
            if proc.poll() is None:
                proc.communicate("\n", timeout=_PROBE_TIMEOUT_S)


def test_another_fast_dds_process_does_not_trip_the_check(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """An unrelated ROS process starts during the run and is still running after it: its
    segments are new in /dev/shm (a whole-directory comparison fails), but they are not the run's."""
    with ShmWatch() as watch:
        with _probe(tmp_path, "ours") as ours:
            watch.add(ours.pid)
            watch.sample()
            with _probe(tmp_path, "other") as other:
                ours.communicate("\n", timeout=_PROBE_TIMEOUT_S)  # the run ends; the other process goes on
                assert ours.returncode == 0
                assert not fastdds_files() <= watch.before  # the old whole-machine check would fail here
                watch.assert_clean()
                assert other.poll() is None


def test_a_killed_node_fails_the_check_and_fastdds_shm_clean_removes_only_its_leftovers(tmp_path) -> None:  # type: ignore[no-untyped-def]
    with _probe(tmp_path, "live") as live:
        live_files = set()
        with ShmWatch() as live_watch:
            live_watch.add(live.pid)
            live_files = set(live_watch.used)
        with ShmWatch() as watch:
            with _probe(tmp_path, "killed") as killed:
                watch.add(killed.pid)
                killed.kill()
                killed.wait()
        left = watch.left_behind()
        assert any(name.startswith("fastrtps_") and not name.startswith("fastrtps_port") for name in left), left  # its own segment
        with pytest.raises(AssertionError, match="left Fast DDS shared memory behind"):
            watch.assert_clean()
        proc = subprocess.run([str(Path(sys.executable).parent / "fastdds"), "shm", "clean"], capture_output=True, text=True)
        assert proc.returncode == 0, proc.stdout + proc.stderr
        assert watch.left_behind() == set()
        assert live_files and live_files <= fastdds_files()  # the live process's segment and ports are untouched
        assert live.poll() is None

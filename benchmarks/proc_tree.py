"""A process tree's memory, read from ``/proc`` (Linux): the benchmarks of issue 47 that measure
commands of several processes (a campaign's workers, the graph's nodes)."""

from __future__ import annotations

import os
import subprocess
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

#: How often a tree is read [s]: a poll reads a few /proc files per process; a process younger than
#: a poll is missed (its peak then only in the ``ru_maxrss`` of the tree).
POLL_S = 0.5


def _children() -> dict[int, list[int]]:
    """Every process's children, from ``/proc/*/stat`` (field 4: the parent's pid)."""
    tree: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            stat = Path(f"/proc/{entry}/stat").read_text()
        except OSError:
            continue
        ppid = int(stat.rsplit(")", 1)[1].split()[1])
        tree.setdefault(ppid, []).append(int(entry))
    return tree


def _status_mb(pid: int, key: str) -> float:
    """``key`` (``VmRSS``, ``VmHWM``: the process's own peak) of ``/proc/PID/status`` [MiB], 0 when gone."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith(f"{key}:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return 0.0


def tree(root: int) -> list[int]:
    """``root`` and its descendants."""
    children, todo, pids = _children(), [root], []
    while todo:
        pid = todo.pop()
        pids.append(pid)
        todo.extend(children.get(pid, []))
    return pids


def run_polled(argv: list[str], cwd: Path, timeout_s: float, env: dict[str, str] | None = None) -> dict[str, Any]:
    """``argv`` with its tree read every :data:`POLL_S`: ``peak_tree_rss_mb`` (the largest sum of the
    tree's resident sets at one poll: a lower bound within what a poll can miss), ``peak_by_pid_mb``
    (each process's own peak, ``VmHWM`` at its last poll; the command's own pid first),
    ``ru_maxrss_mb`` (``os.wait4``'s: the largest single process of the tree, exact), CPU and wall
    time [s], the exit status and the output's tail."""
    peak = [0.0]
    hwm: dict[int, float] = {}
    with tempfile.TemporaryFile() as log:
        t0 = time.perf_counter()
        proc = subprocess.Popen(argv, cwd=cwd, env={**os.environ, **(env or {})}, stdout=log, stderr=subprocess.STDOUT)
        done = threading.Event()

        def poll() -> None:
            while not done.wait(POLL_S):
                pids = tree(proc.pid)
                peak[0] = max(peak[0], sum(_status_mb(p, "VmRSS") for p in pids))
                for p in pids:
                    hwm[p] = max(hwm.get(p, 0.0), _status_mb(p, "VmHWM"))

        poller = threading.Thread(target=poll, daemon=True)
        poller.start()
        killer = threading.Timer(timeout_s, proc.kill)
        killer.start()
        try:
            _, status, usage = os.wait4(proc.pid, 0)
        finally:
            killer.cancel()
            done.set()
            poller.join()
        wall = time.perf_counter() - t0
        log.seek(0)
        tail = log.read().decode(errors="replace")[-2000:]
    by_pid = {str(proc.pid): hwm.pop(proc.pid, 0.0), **{str(p): v for p, v in sorted(hwm.items())}}
    return {"peak_tree_rss_mb": peak[0], "peak_by_pid_mb": by_pid, "ru_maxrss_mb": usage.ru_maxrss / 1024.0,
            "cpu_s": usage.ru_utime + usage.ru_stime, "wall_s": wall, "exit": os.waitstatus_to_exitcode(status), "output_tail": tail}

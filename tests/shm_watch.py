"""Which Fast DDS shared-memory files a test's own processes used, and whether any was left behind.

Fast DDS puts its shared-memory transport in ``/dev/shm``: one segment per participant
(``fastrtps_<16 hex digits>``), ports (``fastrtps_port<N>``: those of the run's domain, and
host-wide ones, ``fastrtps_port7000``, ``7001``, ... one per participant on the machine), a lock
file per segment and port (``<name>_el``, held while its owner lives) and a semaphore per port
(``sem.fastrtps_port<N>_mutex``).  Every ROS 2 process on the machine writes there, so a test
that compares the whole directory before and after its run is tripped by any other Fast DDS
process (issue 25).

:class:`ShmWatch` looks only at the run's own processes instead: while they live it reads the
``/dev/shm`` paths each one maps (``/proc/<pid>/maps``) or holds open (``/proc/<pid>/fd``), for
the processes it was given and every descendant of theirs, every :data:`POLL_PERIOD_S`.  A
participant maps its segment and its ports for its whole life, so a process that lived longer
than a poll period is seen with them (the watch checks that it saw some: :meth:`assert_clean`
cannot pass on an empty set).  After the run, a file the run used is *left behind* when it
still exists, did not exist when the watch started, and no live process maps or holds it: a
file another process still uses is that process's (the host-wide ports are shared), and a file
that was there before the run is not the run's.
"""

from __future__ import annotations

import os
import threading
from pathlib import Path

__all__ = ["POLL_PERIOD_S", "SHM_DIR", "ShmWatch", "fastdds_files", "files_in_use"]

#: Where Fast DDS puts its shared-memory files.
SHM_DIR = Path("/dev/shm")
#: Period of the watch's reading of /proc [s]: a node lives for seconds, its participant's
#: segment and ports are mapped for all of it, so a tenth of a second sees every one.
POLL_PERIOD_S = 0.1
#: The prefixes of Fast DDS's files in /dev/shm (segments and ports; their semaphores are ``sem.`` + these).
_PREFIXES = ("fastrtps_", "fast_datasharing")


def fastdds_files() -> set[str]:
    """Names of the Fast DDS files in :data:`SHM_DIR` now (segments, ports, lock files, semaphores)."""
    return {p.name for p in SHM_DIR.iterdir() if p.name.startswith(_PREFIXES) or p.name.startswith(tuple(f"sem.{x}" for x in _PREFIXES))}


def _shm_paths(pid: int) -> set[str]:
    """Names of the /dev/shm files process ``pid`` maps or holds open (empty if it is gone)."""
    names: set[str] = set()
    prefix = str(SHM_DIR) + "/"
    try:
        with open(f"/proc/{pid}/maps") as f:
            for line in f:
                path = line.rstrip("\n").split(maxsplit=5)[-1]
                if path.startswith(prefix):
                    names.add(path[len(prefix):].removesuffix(" (deleted)"))
        for fd in os.listdir(f"/proc/{pid}/fd"):
            try:
                target = os.readlink(f"/proc/{pid}/fd/{fd}")
            except OSError:
                continue
            if target.startswith(prefix):
                names.add(target[len(prefix):].removesuffix(" (deleted)"))
    except (FileNotFoundError, ProcessLookupError, PermissionError):
        pass
    return names


def _processes() -> dict[int, tuple[int, int]]:
    """pid -> (parent pid, start time in clock ticks since boot) of every live process: a pid and
    its start time name one process, whatever pid reuse does later."""
    out: dict[int, tuple[int, int]] = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            fields = Path(f"/proc/{entry}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if fields[0] != "Z":  # a zombie holds no memory and no file
            out[int(entry)] = (int(fields[1]), int(fields[19]))  # ppid, starttime (proc(5): fields 4 and 22)
    return out


def files_in_use(exclude: set[tuple[int, int]] | None = None) -> set[str]:
    """Names of the /dev/shm files any live process (but those in ``exclude``: (pid, start time)) maps or holds open."""
    used: set[str] = set()
    for pid, (_, started) in _processes().items():
        if (pid, started) not in (exclude or set()):
            used |= _shm_paths(pid)
    return used


def _related(name: str) -> set[str]:
    """``name`` and the files Fast DDS keeps beside it: its lock file and, for a port, its semaphore."""
    base = name.removesuffix("_el")
    out = {base, base + "_el"}
    if base.startswith("fastrtps_port"):
        out.add(f"sem.{base}_mutex")
    return out


class ShmWatch:
    """Watch the /dev/shm files of some processes and their descendants (module docstring).

    Use as a context manager around the run, :meth:`add` each process started (the watch follows
    its children itself), and call :meth:`assert_clean` once every process has exited.
    """

    def __init__(self) -> None:
        self.before = fastdds_files()
        self.used: set[str] = set()
        self.processes: set[tuple[int, int]] = set()  # (pid, start time) of every process of the run seen so far
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._poll, name="shm-watch", daemon=True)

    def __enter__(self) -> ShmWatch:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()
        self.sample()  # what the last processes still held

    def add(self, pid: int) -> None:
        """Watch process ``pid`` and its descendants."""
        procs = _processes()
        if pid in procs:
            with self._lock:
                self.processes.add((pid, procs[pid][1]))
        self.sample()

    def sample(self) -> None:
        """Read /proc once: the run's processes now, and the /dev/shm files each uses."""
        procs = _processes()
        with self._lock:
            tree = {pid for pid, started in self.processes if procs.get(pid, (0, -1))[1] == started}
            grew = True
            while grew:
                children = {pid for pid, (ppid, _) in procs.items() if ppid in tree} - tree
                tree |= children
                grew = bool(children)
            self.processes |= {(pid, procs[pid][1]) for pid in tree}
        used: set[str] = set()
        for pid in tree:
            used |= {n for n in _shm_paths(pid) if n.startswith(_PREFIXES)}
        with self._lock:
            self.used |= used

    def _poll(self) -> None:
        while not self._stop.wait(POLL_PERIOD_S):
            self.sample()

    def alive(self) -> list[int]:
        """The run's processes that are still running."""
        procs = _processes()
        return sorted(pid for pid, started in self.processes if procs.get(pid, (0, -1))[1] == started)

    def left_behind(self, ignore: set[tuple[int, int]] | None = None) -> set[str]:
        """The files the run used that it left: still there, new since the watch started, used by no
        live process (but those of ``ignore``, (pid, start time) pairs)."""
        candidates = set().union(*(_related(n) for n in self.used))
        remaining = (candidates & fastdds_files()) - self.before
        if not remaining:
            return set()
        return remaining - set().union(set(), *(_related(n) for n in files_in_use(exclude=self.processes | (ignore or set()))))

    def remove_left_behind(self) -> set[str]:
        """Delete what :meth:`left_behind` names, this process's mappings of them aside (a process
        of the run killed on purpose cannot clean up, and a node of this process that talked to it
        still maps its segment): only the run's own files, never another process's; returns them."""
        me = os.getpid()
        left = self.left_behind(ignore={(me, _processes()[me][1])})  # this process maps a dead peer's segment to write to it
        for name in left:
            (SHM_DIR / name).unlink(missing_ok=True)
        return left

    def assert_clean(self) -> None:
        """Every process of the run has exited; it used shared memory and left none of it behind."""
        assert not self.alive(), f"processes of the run still alive: {self.alive()}"
        assert self.used, "the watch saw no Fast DDS shared-memory file used by the run's processes (nothing was checked)"
        left = self.left_behind()
        assert not left, f"the run left Fast DDS shared memory behind: {sorted(left)} (it used {sorted(self.used)})"

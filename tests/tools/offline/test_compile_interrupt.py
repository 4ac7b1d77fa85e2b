"""Ctrl-C while a command compiles the numerical core on an empty cache (issue 35, item 6).

``sappc montecarlo`` with several workers compiles in a child process
(:func:`sappc.offline.compiled_loop.ensure_compiled`, ``in_subprocess``) which, with several
CPUs, compiles each group in a child of its own.  A terminal's Ctrl-C goes to the whole
foreground process group; the test sends SIGINT the same way (to the command's group) at two
moments of the compile, and checks what ``sappc simulate`` already did: exit status 130, the
compile's line and one line more on stderr (no traceback from a child), and no process of the
command left afterwards (each is found by the cache directory in its environment, which every
descendant inherits).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from conftest import SAPPC, SCENARIOS

pytestmark = pytest.mark.slow

#: Longest the command may take to end after Ctrl-C [s]: the compile children's own grace
#: (COMPILE_CHILD_EXIT_S, 5 s) and the interpreter's exit, with room for a loaded machine.
_EXIT_TIMEOUT_S = 60.0
#: How long after the command's exit a process of it may still show [s] (the issue's observation:
#: a compile child still alive 1 s after ``sappc`` had exited).
_LEFT_BEHIND_S = 1.0


def _processes_with(env_entry: bytes) -> list[str]:
    """The live processes (not zombies) whose environment holds ``env_entry``, as ``pid cmdline``."""
    found = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            if env_entry not in (d / "environ").read_bytes().split(b"\0"):
                continue
            state = (d / "stat").read_text().rsplit(")", 1)[1].split()[0]
            cmdline = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:  # gone meanwhile, or not ours to read
            continue
        if state != "Z":
            found.append(f"{d.name} {cmdline[:160]}")
    return found


@pytest.mark.skipif(sys.platform != "linux", reason="reads /proc")
@pytest.mark.parametrize("after_s", [1.0, 4.0])
def test_ctrl_c_during_a_campaigns_first_compile_ends_it_with_one_line_and_leaves_nothing(tmp_path: Path, after_s: float) -> None:
    cache = tmp_path / "empty-cache"
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}  # an inherited cache directory would be used
    env["SAPPC_CACHE_DIR"] = str(cache)
    tag = f"SAPPC_CACHE_DIR={cache}".encode()
    proc = subprocess.Popen([*SAPPC, "montecarlo", str(SCENARIOS / "paper_montecarlo.yaml"), "--runs", "4", "--workers", "2",
                             "--no-progress", "--out", str(tmp_path / "out")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, cwd=tmp_path, start_new_session=True)
    assert proc.stderr is not None
    first = proc.stderr.readline().decode()
    assert first.startswith("sappc: compiling the numerical core's loops and batches and lanes once"), first  # the cache is empty: it compiles
    time.sleep(after_s)
    assert proc.poll() is None and len(_processes_with(tag)) >= 2, "no compile child: the compile ended before the test's Ctrl-C"
    os.killpg(proc.pid, signal.SIGINT)  # as a terminal's Ctrl-C: to every process of the foreground group
    out, err = proc.communicate(timeout=_EXIT_TIMEOUT_S)
    deadline = time.monotonic() + _LEFT_BEHIND_S
    while (left := _processes_with(tag)) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert proc.returncode == 130, first + err.decode()
    assert err.decode().splitlines() == ["sappc: interrupted"], err.decode()
    assert not left, f"processes of the command alive {_LEFT_BEHIND_S} s after it ended: {left}"

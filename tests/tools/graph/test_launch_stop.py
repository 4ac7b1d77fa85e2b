"""How ``sappc run`` stops a node (:meth:`sappc.graph.launch._Process.stop`): SIGINT, then SIGKILL
once it has not exited within the timeout, counted from its last progress when the launcher can
see progress (the recorder closing a long bag writes for longer than the timeout: issue 25)."""

from __future__ import annotations

import itertools
import sys
import time

from sappc.graph.launch import _Process

#: The stop's timeout in these tests [s]: short, the node below outlives it on purpose.
TIMEOUT_S = 1.0
#: A node that ignores SIGINT, says it is ready, and exits by itself after 3 timeouts.
_STUBBORN = ["-c", f"import signal, time; signal.signal(signal.SIGINT, signal.SIG_IGN); print('ready', flush=True); time.sleep({3 * TIMEOUT_S})"]


def _stubborn(tmp_path, name: str) -> _Process:  # type: ignore[no-untyped-def]
    proc = _Process(name, [sys.executable, *_STUBBORN], env={}, log_path=tmp_path / f"{name}.log", cwd=tmp_path)
    deadline = time.monotonic() + 60
    while "ready" not in (tmp_path / f"{name}.log").read_text():
        assert time.monotonic() < deadline and proc.proc.poll() is None
        time.sleep(0.01)
    return proc


def test_a_node_without_progress_is_killed_after_the_timeout(tmp_path) -> None:  # type: ignore[no-untyped-def]
    code, killed = _stubborn(tmp_path, "still").stop(timeout_s=TIMEOUT_S)
    assert killed and code == -9


def test_a_node_making_progress_is_not_killed(tmp_path) -> None:  # type: ignore[no-untyped-def]
    counter = itertools.count()  # progress that changes at every look: the node is always working
    code, killed = _stubborn(tmp_path, "busy").stop(timeout_s=TIMEOUT_S, progress=lambda: next(counter))
    assert not killed and code == 0

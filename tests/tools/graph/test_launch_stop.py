"""How ``sappc run`` stops a node (:meth:`sappc.graph.launch._Process.stop`): SIGINT, then SIGKILL
once it has not exited within the timeout, counted from its last progress when the launcher can
see progress (the recorder closing a long bag writes for longer than the timeout: issue 25)."""

from __future__ import annotations

import itertools
import json
import sys
import time
from pathlib import Path

import pytest

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


def test_the_progress_line_knows_when_the_samples_last_grew_and_when_the_last_one_came(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """What the lockstep stall rule reads (``run_graph``: no new sample for ``LOCKSTEP_STALL_S`` fails
    the run, a slow one does not; once the last sample is in, the close has its own budget): the
    time the recorded samples last grew, and the time the last sample was seen."""
    from sappc.graph import launch

    clock = [100.0]
    monkeypatch.setattr(launch.time, "monotonic", lambda: clock[0])
    path = tmp_path / "progress.json"
    line = launch._ProgressLine(path, 10.0, 100.0, lambda _msg: None)
    for now, samples, t_s, advanced, done in ((102.0, None, None, 100.0, None),  # no file yet: the start
                                              (104.0, 5, 0.04, 104.0, None), (106.0, 5, 0.04, 104.0, None),  # the same count: stalled since 104
                                              (400.0, 6, 0.05, 400.0, None),  # slow, not stalled: it grew
                                              (402.0, 1001, 10.0, 402.0, 402.0)):  # the last sample
        clock[0] = now
        if samples is not None:
            path.write_text(json.dumps({"state_samples": samples, "t_s": t_s}))
        line.update()
        assert (line.advanced_at, line.done_at) == (advanced, done), now
    assert launch.LOCKSTEP_STALL_S >= 60.0 and launch.CLOSE_BASE_S + launch.CLOSE_S_PER_SAMPLE * 567_701 > 15 * 60  # an orbit's close (measured 15 min)

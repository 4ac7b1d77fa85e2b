"""How ``sappc run`` stops a node (:meth:`sappc.graph.launch._Process.stop`): SIGINT, then SIGKILL
once it has not exited within the timeout, counted from its last progress when the launcher can
see progress (the recorder closing a long bag writes for longer than the timeout: issue 25)."""

from __future__ import annotations

import itertools
from types import SimpleNamespace
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


class _SlowNode:
    """A :class:`_Process` stand-in whose stop takes ``seconds`` of ``clock``, asking its progress
    every quarter second as the real stop does every :data:`~sappc.graph.launch.STOP_CHECK_S`."""

    def __init__(self, clock, seconds: float, running: bool = True) -> None:  # type: ignore[no-untyped-def]
        self.clock, self.seconds = clock, seconds
        self.proc = SimpleNamespace(poll=lambda: None if running else 0)

    def stop(self, progress=None) -> tuple[int, bool]:  # type: ignore[no-untyped-def]
        for _ in range(round(self.seconds / 0.25)):
            self.clock.advance(0.25)
            if progress is not None:
                progress()
        return 0, False


def test_stopping_the_nodes_says_a_line_at_least_every_2_s_naming_the_node(tmp_path: Path) -> None:
    """Issue 46: the stop (measured 3 to 10 s, the recorder closing its bag the longest) says which
    node it is stopping, at once and every second while it takes its time (the test's clock, moved
    in step with the ticker's thread: no timing luck), the recorder with its bag's size; a node that
    has already exited (the plant, at the end of its run) gets no line."""
    from fake_clock import SteppedClock

    from sappc.bag.read import Ticker
    from sappc.graph import launch

    clock = SteppedClock()
    lines: list[tuple[float, str]] = []
    ticker = Ticker(lambda msg: lines.append((clock.now, msg)), period_s=launch.PROGRESS_PERIOD_S, poll_s=1e-3, clock=clock)
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "bag_0.mcap").write_bytes(b"\0" * 2_500_000)
    procs = {"plant": _SlowNode(clock, 0.0, running=False), "controller": _SlowNode(clock, 0.5), "injector": _SlowNode(clock, 3.0),
             "recorder": _SlowNode(clock, 7.0)}
    with ticker:
        codes, killed = launch._stop_nodes(procs, launch.STOP_ORDER, bag, ticker)
    assert codes == dict.fromkeys(procs, 0) and not killed
    times = [0.0, *(t for t, _ in lines), clock.now]
    assert clock.now == 10.5 and max(b - a for a, b in zip(times, times[1:])) <= launch.PROGRESS_PERIOD_S < 2.0, lines  # issue 46: every 2 s at least
    said = [msg for _, msg in lines]
    assert said[:3] == ["stopping the nodes: controller", "stopping the nodes: injector", "stopping the nodes: injector (1 s)"], said
    assert said[5] == "stopping the nodes: recorder" and said[-1] == "stopping the nodes: recorder, its bag 2.5 MB so far (7 s)", said
    assert not any("plant" in msg for msg in said)

"""The progress line of slow steps (:class:`sappc.bag.read.Ticker`, issue 46: ``sappc run`` was
silent for 7 to 10 s at its end): a step says a line when it starts and one every period until
the next step, from the ticker's own thread while the step itself is blocked; reading a bag back,
aligning it and computing its metrics are steps of it.

The clock is the test's (:class:`fake_clock.SteppedClock`): a slow step is a sequence of advances
of it, each returning once the ticker's thread has polled at the new time, so the line's times are
known exactly and the test needs no timing luck."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from bagmaker import write_bag
from fake_clock import SteppedClock

from sappc.bag import read as bag_read
from sappc.bag.read import TICK_PERIOD_S, Ticker, bag_metrics, bag_run, read_bag
from sappc.evaluation.metrics import MetricsAccumulator
from sappc_msgs_py import contract as c
from sappc_msgs_py.convert import quaternion_msg, torque_msg, vector3_msg

#: The longest ``sappc run`` may go without a line (issue 46) [s].
MAX_SILENCE_S = 2.0
#: The test's clock advances this much at a time while a fake slow step runs [s].
TICK_S = 0.25


def _ticker(clock: SteppedClock) -> tuple[Ticker, list[tuple[float, str]]]:
    """A ticker on ``clock`` whose lines are kept with the clock's time; its thread polls every ms."""
    lines: list[tuple[float, str]] = []
    return Ticker(lambda msg: lines.append((clock.now, msg)), period_s=TICK_PERIOD_S, poll_s=1e-3, clock=clock), lines


def _slow(clock: SteppedClock, seconds: float) -> None:
    """A step that takes ``seconds`` of the clock and says nothing itself (a blocked system call)."""
    for _ in range(round(seconds / TICK_S)):
        clock.advance(TICK_S)


def _silences(start: float, lines: list[tuple[float, str]], end: float) -> list[float]:
    times = [start, *(t for t, _ in lines), end]
    return list(np.diff(times))


def test_a_step_says_its_line_at_once_then_one_every_period_with_its_detail_until_idle() -> None:
    now = [100.0]
    lines: list[str] = []
    ticker = Ticker(lines.append, period_s=1.0, clock=lambda: now[0])
    ticker.poll()
    assert lines == []  # no step: nothing to say
    ticker.step("reading the bag back")
    assert lines == ["reading the bag back"]
    now[0] = 100.9
    ticker.detail("1.0 of 3.0 MB")  # not due yet: kept for the next line
    now[0] = 101.0
    ticker.poll()
    assert lines[-1] == "reading the bag back: 1.0 of 3.0 MB (1 s)"
    now[0] = 102.5
    ticker.detail("3.0 of 3.0 MB")  # due: said by the step's own report, no thread needed
    assert lines[-1] == "reading the bag back: 3.0 of 3.0 MB (2 s)"
    ticker.step("computing the metrics")
    assert lines[-1] == "computing the metrics"
    ticker.idle()
    now[0] = 110.0
    ticker.poll()
    assert len(lines) == 4


def test_the_thread_says_the_lines_while_the_step_is_blocked() -> None:
    clock = SteppedClock(50.0)
    ticker, lines = _ticker(clock)
    with ticker:
        ticker.step("stopping the nodes", "recorder")
        _slow(clock, 10.0)
    assert [t for t, _ in lines] == [50.0 + k for k in range(11)]  # at once, then every second of the 10
    assert lines[-1][1] == "stopping the nodes: recorder (10 s)"
    clock.now += 5.0  # after the with: no thread, no line
    assert len(lines) == 11


def _run_bag(tmp_path: Path, samples: int = 200, dt_s: float = 0.01) -> Path:
    """A small bag of a run: state, reference and torque, one of each per sample."""
    q = np.array([0.0, 0.0, 0.0, 1.0])
    messages = []
    for k in range(samples):
        t, log = k * dt_s, k * round(dt_s * 1e9)
        messages += [(c.STATE_ATTITUDE.name, c.STATE_ATTITUDE.type_name, quaternion_msg(q, t, c.STATE_ATTITUDE), log),
                     (c.STATE_RATE.name, c.STATE_RATE.type_name, vector3_msg(np.zeros(3), t, c.STATE_RATE), log + 1),
                     (c.REFERENCE_ATTITUDE.name, c.REFERENCE_ATTITUDE.type_name, quaternion_msg(q, t, c.REFERENCE_ATTITUDE), log + 2),
                     (c.CONTROL_TORQUE.name, c.CONTROL_TORQUE.type_name, torque_msg(np.full(3, 1e-3), t, c.CONTROL_TORQUE), log + 3)]
    return write_bag(tmp_path / "run.mcap", messages, chunk_size=20_000)


def test_reading_a_run_back_says_a_line_at_least_every_2_s_to_its_end(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``sappc run``'s read-back, each step slow (1.5 s a topic to decode, 6 s of metrics): a line
    at least every 2 s from the start to the end, each naming its step and how far it is."""
    clock = SteppedClock()
    ticker, lines = _ticker(clock)
    decode, add_history = bag_read.decode, MetricsAccumulator.add_history

    def slow_decode(*args, **kwargs):  # type: ignore[no-untyped-def]
        _slow(clock, 1.5)
        return decode(*args, **kwargs)

    def slow_metrics(self, history):  # type: ignore[no-untyped-def]
        _slow(clock, 6.0)
        return add_history(self, history)

    monkeypatch.setattr(bag_read, "decode", slow_decode)
    monkeypatch.setattr(MetricsAccumulator, "add_history", slow_metrics)
    path = _run_bag(tmp_path)
    with ticker:
        bag = read_bag(path, ticker=ticker)
        run = bag_run(bag, duration_s=1.0, ticker=ticker)
        metrics, _ = bag_metrics(bag, steady_from_s=0.5, settle_threshold=1e-3, t2_s=0.5, fault_windows=[], run=run, ticker=ticker)
    assert metrics["steady_max_abs_qev"] == 0.0 and run.history.t.size == 101
    said = [msg for _, msg in lines]
    assert max(_silences(0.0, lines, clock.now)) <= MAX_SILENCE_S, lines
    assert clock.now == 4 * 1.5 + 6.0  # four topics, then the metrics
    assert said[0] == "reading the bag back" and said[-1].startswith("computing the metrics")
    assert any(msg.startswith(f"reading the bag back: decoding {c.CONTROL_TORQUE.name}, topic 4 of 4 (") for msg in said), said
    assert "aligning the samples" in said


def test_the_bag_read_back_says_the_megabytes_read_chunk_by_chunk(tmp_path: Path) -> None:
    """The scan reports (bytes walked, file size): from 0 when the file is read, then after each
    chunk, up to the data's end (the summary section follows); the ticker's detail is in MB."""
    path = _run_bag(tmp_path, samples=2000)
    size = path.stat().st_size
    seen: list[tuple[int, int]] = []
    bag_read.scan_mcap(path, progress=lambda done, total: seen.append((done, total)))
    done = [d for d, _ in seen]
    assert {t for _, t in seen} == {size} and done[0] == 0 and done == sorted(done) and len(done) > 10  # a chunk is 20 kB
    assert size - 20_000 < done[-1] < size
    now = [0.0]
    lines: list[str] = []
    ticker = Ticker(lines.append, period_s=1.0, clock=lambda: now[0])
    ticker.step("reading the bag back")
    now[0] = 1.0
    bag_read._reading(ticker)(1_500_000, 4_000_000)  # type: ignore[misc]
    assert lines[-1] == "reading the bag back: 1.5 of 4.0 MB (1 s)"

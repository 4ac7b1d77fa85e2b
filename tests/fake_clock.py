"""Clocks set by the test: a ROS node's clock in real time (:class:`FakeClock`, a stand-in for
``node.get_clock`` whose ``now().nanoseconds`` is whatever the test last wrote into ``ns``), and
a monotonic clock that moves only when the test moves it, in step with the thread that reads it
(:class:`SteppedClock`, for :class:`sappc.bag.read.Ticker`)."""

from __future__ import annotations

import threading


class FakeClock:
    """``get_clock()``'s result; ``monkeypatch.setattr(node, "get_clock", lambda: clock)``."""

    def __init__(self, ns: int) -> None:
        self.ns = ns

    def now(self) -> FakeClock:
        return self

    @property
    def nanoseconds(self) -> int:
        return self.ns


class SteppedClock:
    """``time.monotonic`` for a ticker under test: :attr:`now` [s] moves only by :meth:`advance`,
    which returns once the ticker's thread has read the clock twice since (the thread polls one
    read at a time, so its first poll at the new time, line included, is over): a slow step is a
    sequence of advances, and what the thread said at each time is known without timing luck."""

    #: How long :meth:`advance` waits for the thread before failing [s] (a thread that stopped).
    TIMEOUT_S = 60.0

    def __init__(self, now: float = 0.0) -> None:
        self.now = now
        self.reads = 0
        self._cond = threading.Condition()

    def __call__(self) -> float:
        with self._cond:
            self.reads += 1
            self._cond.notify_all()
            return self.now

    def advance(self, dt: float) -> None:
        with self._cond:
            self.now += dt
            seen = self.reads
            assert self._cond.wait_for(lambda: self.reads >= seen + 2, timeout=self.TIMEOUT_S), "the ticker's thread stopped reading the clock"

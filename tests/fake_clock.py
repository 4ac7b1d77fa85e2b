"""A ROS node's clock in real time, set by the test: a stand-in for ``node.get_clock`` whose
``now().nanoseconds`` is whatever the test last wrote into ``ns``."""

from __future__ import annotations


class FakeClock:
    """``get_clock()``'s result; ``monkeypatch.setattr(node, "get_clock", lambda: clock)``."""

    def __init__(self, ns: int) -> None:
        self.ns = ns

    def now(self) -> FakeClock:
        return self

    @property
    def nanoseconds(self) -> int:
        return self.ns

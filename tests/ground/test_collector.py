"""The garbage collector during a start-up (gnc_common.collector): thresholds raised while held,
what the start-up made frozen and the thresholds back once settled; ``sappc`` holds at its entry,
every command settles before its work, ``sappc montecarlo`` just before it forks its workers."""

from __future__ import annotations

import gc
from collections.abc import Iterator
from pathlib import Path

import pytest

from conftest import SCENARIOS
from gnc_common import collector


@pytest.fixture
def clean_collector() -> Iterator[tuple[int, int, int]]:
    """The thresholds before the test, given back after it with nothing held or frozen (this
    process is pytest's: its objects must stay collectable)."""
    before = gc.get_threshold()
    assert not collector._held, "a test left a hold open"
    yield before
    collector._held.clear()
    gc.set_threshold(*before)
    gc.unfreeze()


def test_hold_raises_the_thresholds_and_settle_freezes_and_restores(clean_collector: tuple[int, int, int]) -> None:
    gc.unfreeze()
    collector.hold()
    assert gc.get_threshold() == collector.START_UP_THRESHOLDS
    assert gc.isenabled()  # never switched off: cycles made meanwhile are still collected
    made = [[i] for i in range(1000)]  # containers the start-up made (kept alive below)
    collector.settle()
    assert gc.get_threshold() == clean_collector
    assert gc.get_freeze_count() >= len(made)  # at least what the start-up made is in the permanent generation
    frozen = gc.get_freeze_count()
    collector.settle()  # nothing held: nothing happens
    assert gc.get_freeze_count() == frozen and gc.get_threshold() == clean_collector


def test_nested_holds_settle_innermost_first(clean_collector: tuple[int, int, int]) -> None:
    gc.set_threshold(500, 7, 9)
    collector.hold()
    with collector.held():  # a compile inside a command's start-up (sappc.offline.compiled_loop.warm_up)
        assert gc.get_threshold() == collector.START_UP_THRESHOLDS
    assert gc.get_threshold() == collector.START_UP_THRESHOLDS  # the command's hold is still open
    collector.settle()
    assert gc.get_threshold() == (500, 7, 9)


def test_held_settles_after_an_exception(clean_collector: tuple[int, int, int]) -> None:
    with pytest.raises(RuntimeError), collector.held():
        raise RuntimeError("a compile failed")
    assert gc.get_threshold() == clean_collector and not collector._held


def test_a_command_settles_before_its_work(clean_collector: tuple[int, int, int], monkeypatch: pytest.MonkeyPatch) -> None:
    from sappc import cli

    seen: list[tuple[int, int, int]] = []
    monkeypatch.setattr(cli, "_cmd_params", lambda args: seen.append(gc.get_threshold()) or 0)
    collector.hold()  # as sappc.__main__.main does
    assert cli.main(["params", str(SCENARIOS / "paper_tracking.yaml")]) == 0
    assert seen == [clean_collector] and not collector._held


def test_montecarlo_settles_just_before_it_forks_its_workers(clean_collector: tuple[int, int, int], monkeypatch: pytest.MonkeyPatch,
                                                             tmp_path: Path) -> None:
    from sappc import cli
    from sappc.montecarlo import campaign

    seen: dict[str, tuple[int, int, int]] = {}
    monkeypatch.setattr(cli, "_cmd_montecarlo", lambda args: seen.setdefault("command", gc.get_threshold()) and 0)
    collector.hold()
    assert cli.main(["montecarlo", str(SCENARIOS / "paper_montecarlo.yaml"), "--runs", "1", "--out", str(tmp_path / "a")]) == 0
    assert seen["command"] == collector.START_UP_THRESHOLDS  # the command's start-up goes on into the campaign's set-up

    class Forked(Exception):
        pass

    def executor(workers: int, scheduler: str | None) -> None:  # the pool, about to fork the workers
        seen["fork"] = gc.get_threshold()
        raise Forked

    monkeypatch.setattr(campaign, "ChunkExecutor", executor)
    with pytest.raises(Forked):
        campaign.run_campaign(SCENARIOS / "paper_montecarlo.yaml", runs=2, seed=0, out_dir=tmp_path / "b", workers=2)
    assert seen["fork"] == clean_collector and not collector._held and gc.get_freeze_count() > 0

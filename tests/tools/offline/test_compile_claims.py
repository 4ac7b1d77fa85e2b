"""The compile's leaf process and the loop's compile share out the loop's leaves by claims
(:func:`sappc.offline.compiled_loop._leaf_process`): the first of the two processes to claim a
leaf compiles it, the leaf process passes over a leaf the loop has claimed, and the loop waits for
a leaf the leaf process is compiling, then loads it from the cache.

These tests hold the protocol itself (the claim files and the wrapped cache lookup) without a
compile: a stand-in for numba's ``load_overload`` counts its calls, a stand-in for the leaf process
says whether it is alive.  That the cold compile itself goes through it is held by
``tests/test_install.py`` (a cold ``sappc simulate`` whose leaf process typed every leaf as the
loop calls it).
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from sappc.offline import compiled_loop


class _Kernel:
    """A kernel as :func:`compiled_loop._claim` names it (module and qualified name)."""

    def __init__(self) -> None:
        self.__module__ = "somewhere.kernels"
        self.__qualname__ = "leaf"


class _Child:
    """The leaf process as :func:`compiled_loop._claimed_load` asks it: ``poll()`` None while alive;
    ``alive`` None: a wait must not ask it (a lookup that waits fails the test instead of hanging)."""

    def __init__(self, alive: bool | None) -> None:
        self.alive = alive

    def poll(self) -> int | None:
        assert self.alive is not None, "the lookup waited for the leaf process"
        return None if self.alive else 0


class _Load:
    """numba's cache lookup: ``answers`` in turn (None: a miss), each call recorded."""

    def __init__(self, *answers: object) -> None:
        self.answers = list(answers)
        self.calls: list[object] = []

    def __call__(self, sig: object, target_context: object) -> object:
        self.calls.append(sig)
        return self.answers.pop(0)


def test_a_claim_is_exclusive_and_its_done_mark_is_a_claim_of_its_own(tmp_path: Path) -> None:
    k = _Kernel()
    assert compiled_loop._claim(str(tmp_path), k)
    assert not compiled_loop._claim(str(tmp_path), k)  # the other process's claim fails
    assert compiled_loop._claim(str(tmp_path), k, ".done")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["somewhere.kernels.leaf", "somewhere.kernels.leaf.done"]


def test_the_loops_miss_on_an_unclaimed_leaf_claims_it_and_compiles_every_signature_itself(tmp_path: Path) -> None:
    load = _Load(None, None)
    claimed = compiled_loop._claimed_load(load, str(tmp_path), _Kernel(), _Child(alive=None))
    assert claimed("sig1", None) is None  # a miss: this process compiles it
    assert claimed("sig2", None) is None  # its own claim: no wait for a mark nobody will write
    assert load.calls == ["sig1", "sig2"]
    assert not compiled_loop._claim(str(tmp_path), _Kernel())  # the leaf process would pass over it


def test_the_loop_waits_for_a_leaf_the_leaf_process_claimed_then_loads_it(tmp_path: Path) -> None:
    k = _Kernel()
    assert compiled_loop._claim(str(tmp_path), k)  # the leaf process's claim
    compiled = object()
    load = _Load(None, compiled)  # a miss, then the leaf process's compile found in the cache
    claimed = compiled_loop._claimed_load(load, str(tmp_path), k, _Child(alive=True))
    wait_s = 0.2
    marker = threading.Timer(wait_s, compiled_loop._claim, (str(tmp_path), k, ".done"))
    t0 = time.monotonic()
    marker.start()
    try:
        assert claimed("sig", None) is compiled
    finally:
        marker.cancel()
    assert time.monotonic() - t0 >= wait_s  # it waited for the mark, not a compile of its own
    assert load.calls == ["sig", "sig"]


def test_a_leaf_process_gone_ends_the_wait(tmp_path: Path) -> None:
    k = _Kernel()
    assert compiled_loop._claim(str(tmp_path), k)  # claimed by a leaf process that then died
    load = _Load(None, None)
    claimed = compiled_loop._claimed_load(load, str(tmp_path), k, _Child(alive=False))
    assert claimed("sig", None) is None  # looked again, missed: this process compiles it
    assert load.calls == ["sig", "sig"]


def test_a_hit_is_returned_as_it_is_without_a_claim(tmp_path: Path) -> None:
    compiled = object()
    claimed = compiled_loop._claimed_load(_Load(compiled), str(tmp_path), _Kernel(), _Child(alive=None))
    assert claimed("sig", None) is compiled
    assert list(tmp_path.iterdir()) == []


def test_a_claims_folder_whose_process_is_gone_is_removed_and_a_live_ones_kept(tmp_path: Path) -> None:
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True, check=True)
    dead_pid = int(gone.stdout)  # (its process has exited; a pid is not reused within this test in practice: checked below)
    try:
        os.kill(dead_pid, 0)
        pytest.skip(f"pid {dead_pid} was reused meanwhile")
    except ProcessLookupError:
        pass
    stale = tmp_path / f"{compiled_loop._CLAIMS_PREFIX}{dead_pid}-abc"
    live = tmp_path / f"{compiled_loop._CLAIMS_PREFIX}{os.getpid()}-def"
    other = tmp_path / "index-and-cache-files"
    for d in (stale, live, other):
        d.mkdir()
        (d / "somewhere.kernels.leaf").touch()
    (tmp_path / f"{compiled_loop._CLAIMS_PREFIX}not-a-pid").mkdir()
    compiled_loop._remove_stale_claims(str(tmp_path))
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([live.name, other.name, f"{compiled_loop._CLAIMS_PREFIX}not-a-pid"])

"""Python's cyclic garbage collector while a process starts up or numba compiles.

A full collection walks every container object the process holds.  CPython starts one once the
young generations have been collected ``threshold2`` times (10 by default) and the containers that
survived them since the last full one are more than a quarter of the old generation.  A process
that makes hundreds of thousands of lasting containers in a row (numpy, scipy and numba imported,
kernels loaded from the cache, numba's compiler at work) therefore runs full collections again
and again, each over everything made so far, and they free next to nothing.  Measured on machine A
(2-vCPU AMD EPYC, 2026-12-07, ``gc.callbacks``): 32 full collections took 5.2 s of the 39 s of
``sappc simulate`` on an empty numba cache (the compile), 23 took 2.9 s of the compile's leaf
process, and the collector took 0.12 s of the 0.85 s before a 3000-run campaign's workers start.

:func:`hold` and :func:`settle` bracket such a phase: meanwhile the collector runs with
:data:`START_UP_THRESHOLDS` (it is never switched off, so a cycle made meanwhile is still
collected, later); :func:`settle` then moves what the phase made to the permanent generation
(:func:`gc.freeze`: no later collection walks it, nor, in a forked worker, writes to its pages) and
brings the thresholds back.  They bracket ``sappc``'s start-up (its entry holds; the command
settles once its imports and kernels are in: ``sappc montecarlo`` just before it forks its
workers, every other command before its work) and every compile of the numerical core
(:func:`sappc.offline.compiled_loop.warm_up`, the compile's leaf process).
"""

from __future__ import annotations

import contextlib
import gc
from collections.abc import Iterator

__all__ = ["START_UP_THRESHOLDS", "held", "hold", "settle"]

#: The collector's thresholds while a process starts up or compiles: a young collection every
#: 20,000 net container allocations instead of 700, a full one only after 100 middle ones instead
#: of 10.  Measured on a cold compile of the offline loops (machine A, one compile each, the
#: thresholds set for the whole process): the collector's time 6.2 s of 39 s with the defaults,
#: 1.1 s of 33 s with these, 0 s of 32 s switched off; peak memory 426, 511 and 767 MB.
#: (20000, 10, 10) gave 1.7 s and 479 MB: these keep most of the gain of switching it off for a
#: fifth of its memory.
START_UP_THRESHOLDS = (20_000, 10, 100)

#: The thresholds each open :func:`hold` replaced, innermost last.
_held: list[tuple[int, int, int]] = []


def hold() -> None:
    """A start-up begins: the collector's thresholds are :data:`START_UP_THRESHOLDS` until :func:`settle`."""
    _held.append(gc.get_threshold())
    gc.set_threshold(*START_UP_THRESHOLDS)


def settle() -> None:
    """The start-up is over: what it made is frozen (kept for the process's life, walked by no
    later collection) and the thresholds before the last :func:`hold` are back.  Nothing without
    an open hold."""
    if not _held:
        return
    gc.freeze()
    gc.set_threshold(*_held.pop())


@contextlib.contextmanager
def held() -> Iterator[None]:
    """:func:`hold` on entry, :func:`settle` on exit (an exception included)."""
    hold()
    try:
        yield
    finally:
        settle()

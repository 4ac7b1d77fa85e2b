"""Issue 28, row 6: the compile of a first command, paired against a baseline.

    python benchmarks/bench_speed_coldstart.py --baseline DIR [--repeats 3]    # target: compile <= 30 s

``sappc simulate config/scenarios/paper_tracking.yaml --plots DIR`` (the baseline's option; ``--out`` now) with an empty numba cache
(``SAPPC_CACHE_DIR``, and ``NUMBA_CACHE_DIR`` for code that reads only that, a new directory each run): what the first command after the set-up compiles,
then the run.  The venv's creation and pip's install (the rest of "a fresh clone's first command")
depend on the network and pip's cache, and are timed by ``./sappcw``'s own step lines instead.  How
the pairing works and what the JSON holds: :mod:`paired`.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import paired  # noqa: E402


def command(root: Path, tmp: Path) -> tuple[list[str], dict[str, str]]:
    return ([paired.python_of(root), "-m", "sappc", "simulate", str(root / "config/scenarios/paper_tracking.yaml"), "--plots", str(tmp / "sim")],
            {"SAPPC_CACHE_DIR": str(tmp / "cache"), "NUMBA_CACHE_DIR": str(tmp / "cache")})


if __name__ == "__main__":
    paired.main("cold_compile_then_simulate", __doc__, command, target="compile <= 30 s (whole first command <= 2 min with the set-up)")

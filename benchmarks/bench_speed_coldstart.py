"""Issue 28, row 6: the compile of a first command, paired against a baseline.

    python benchmarks/bench_speed_coldstart.py --baseline DIR [--repeats 3]    # target: compile <= 30 s

``sappc simulate config/scenarios/paper_tracking.yaml --plots DIR`` (the baseline's option; ``--out`` now) with an empty numba cache
(``SAPPC_CACHE_DIR``, and ``NUMBA_CACHE_DIR`` for code that reads only that, a new directory each run): what the first command after the set-up compiles,
then the run.  The venv's creation and pip's install (the rest of "a fresh clone's first command")
depend on the network and pip's cache, and are timed by ``./sappcw``'s own step lines instead.  How
the pairing works and what the JSON holds: :mod:`paired`.  The same command is then timed on a
warm cache (one kept per checkout, filled by its warm-up run), and the JSON's
``cold_minus_warm_s`` gives, per side, the difference of the medians: the compile itself.
"""

from __future__ import annotations

import atexit
import hashlib
import shutil
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import paired  # noqa: E402


def command(root: Path, tmp: Path, cache: Path | None = None) -> tuple[list[str], dict[str, str]]:
    cache = tmp / "cache" if cache is None else cache
    return ([paired.python_of(root), "-m", "sappc", "simulate", str(root / "config/scenarios/paper_tracking.yaml"), "--plots", str(tmp / "sim")],
            {"SAPPC_CACHE_DIR": str(cache), "NUMBA_CACHE_DIR": str(cache)})


_WARM = Path(tempfile.mkdtemp(prefix="sappc-coldstart-warm-"))
atexit.register(shutil.rmtree, _WARM, True)


def warm_command(root: Path, tmp: Path) -> tuple[list[str], dict[str, str]]:
    """The same command on a cache of its checkout's own, kept from run to run (filled by the
    warm-up run): the run without the compile."""
    return command(root, tmp, _WARM / hashlib.sha256(str(root).encode()).hexdigest()[:12])


if __name__ == "__main__":
    paired.main("cold_compile_then_simulate", __doc__, command, target="compile <= 30 s (whole first command <= 2 min with the set-up)",
                warm_command=warm_command)

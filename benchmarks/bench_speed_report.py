"""``sappc report`` on the 60 s bag of experiment 1, paired against a baseline (issue 28, row 3;
issue 50, item 3).

    python benchmarks/bench_speed_report.py --baseline DIR [--repeats 3] [--bytecode]    # target <= 0.6 s (issue 50; issue 28's: 1.0 s)

The bag is recorded once, before the timing, by this checkout's ``sappc run
config/scenarios/paper_tracking.yaml``; both sides then run ``sappc report BAG --out DIR`` on it
(a fresh process: interpreter start, imports, reading, metrics, figures, the page).  How the
pairing works and what the JSON holds: :mod:`paired`.

``--bytecode``: both sides with Python's bytecode caches (:mod:`paired`).
"""

from __future__ import annotations

import atexit
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import paired  # noqa: E402

_bag: Path | None = None


def _recorded_bag() -> Path:
    global _bag
    if _bag is None:
        tmp = Path(tempfile.mkdtemp(prefix="sappc-bench-report-"))
        atexit.register(shutil.rmtree, tmp, True)
        subprocess.run([paired.python_of(paired.ROOT), "-m", "sappc", "run", str(paired.ROOT / "config/scenarios/paper_tracking.yaml"),
                        "--out", str(tmp / "run")], check=True, capture_output=True)
        _bag = tmp / "run" / "bag"
    return _bag


def command(root: Path, tmp: Path) -> tuple[list[str], dict[str, str]]:
    return [paired.python_of(root), "-m", "sappc", "report", str(_recorded_bag()), "--out", str(tmp / "report")], {}


if __name__ == "__main__":
    paired.main("report_experiment1_bag", __doc__, command, target="<= 0.6 s")

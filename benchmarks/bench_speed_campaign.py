"""Issue 28, rows 1 and 2: the whole ``sappc montecarlo`` command, paired against a baseline.

    python benchmarks/bench_speed_campaign.py --baseline DIR [--repeats 3]             # 3000 runs (target <= 2.5 s)
    python benchmarks/bench_speed_campaign.py --baseline DIR --runs 100000 [--repeats 3]  # (target <= 60 s, flat memory)

The command as a user types it, figures and table included: ``sappc montecarlo
config/scenarios/paper_montecarlo.yaml --runs N --out DIR``, warm numba cache.  How the pairing
works and what the JSON holds: :mod:`paired`.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import paired  # noqa: E402

RUNS = int(sys.argv[sys.argv.index("--runs") + 1]) if "--runs" in sys.argv else 3000
if "--runs" in sys.argv:  # ours, not paired's
    i = sys.argv.index("--runs")
    del sys.argv[i:i + 2]


def command(root: Path, tmp: Path) -> tuple[list[str], dict[str, str]]:
    return [paired.python_of(root), "-m", "sappc", "montecarlo", str(root / "config/scenarios/paper_montecarlo.yaml"), "--runs", str(RUNS),
            "--out", str(tmp / "mc")], {}


if __name__ == "__main__":
    paired.main(f"montecarlo_{RUNS}_runs_whole_command", __doc__, command,
                target="<= 2.5 s" if RUNS == 3000 else "<= 60 s and flat memory" if RUNS == 100_000 else "none stated",
                timeout_s=900.0)

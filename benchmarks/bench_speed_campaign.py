"""Issue 28, rows 1 and 2, and issue 50's flight row: the whole ``sappc montecarlo`` command, paired against a baseline.

    python benchmarks/bench_speed_campaign.py --baseline DIR [--repeats 3]             # 3000 runs (target <= 2.5 s)
    python benchmarks/bench_speed_campaign.py --baseline DIR --runs 100000 [--repeats 3]  # (target <= 60 s, flat memory)
    python benchmarks/bench_speed_campaign.py --baseline DIR --scenario paper_tracking_flight --runs 500  # (target <= 0.4 of the baseline)
    python benchmarks/bench_speed_campaign.py --baseline DIR --scenario paper_tracking_orbit --runs 1 --workers 1  # a 6 h run (target <= 0.5)

The command as a user types it, figures and table included: ``sappc montecarlo
config/scenarios/SCENARIO.yaml --runs N [--workers W] --out DIR`` (``--scenario``:
``paper_montecarlo`` unless given; ``--workers``: the command's default, one per CPU, unless
given), warm numba cache.  How the pairing works and what the JSON holds: :mod:`paired`.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import paired  # noqa: E402


def _own(flag: str, default: str) -> str:
    """The value of our option ``flag`` (removed from ``sys.argv``: paired's parser does not know it)."""
    if flag not in sys.argv:
        return default
    i = sys.argv.index(flag)
    value = sys.argv[i + 1]
    del sys.argv[i:i + 2]
    return value


RUNS = int(_own("--runs", "3000"))
SCENARIO = _own("--scenario", "paper_montecarlo")
WORKERS = _own("--workers", "")


def command(root: Path, tmp: Path) -> tuple[list[str], dict[str, str]]:
    return [paired.python_of(root), "-m", "sappc", "montecarlo", str(root / f"config/scenarios/{SCENARIO}.yaml"), "--runs", str(RUNS),
            *(["--workers", WORKERS] if WORKERS else []), "--out", str(tmp / "mc")], {}


if __name__ == "__main__":
    flight = SCENARIO == "paper_tracking_flight" and RUNS == 500
    orbit = SCENARIO == "paper_tracking_orbit" and RUNS == 1
    target = ("<= 0.4 of the baseline" if flight else "<= 0.5 of the baseline" if orbit else "<= 2.5 s" if RUNS == 3000 else "<= 60 s and flat memory" if RUNS == 100_000
              else "none stated")
    row = f"montecarlo_{RUNS}_runs_whole_command" if SCENARIO == "paper_montecarlo" else f"montecarlo_{SCENARIO}_{RUNS}_runs{'_' + WORKERS + '_workers' if WORKERS else ''}_whole_command"
    paired.main(row, __doc__, command, target=target, timeout_s=900.0)

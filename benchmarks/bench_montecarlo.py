"""Benchmark of Monte Carlo campaigns (issue: Monte Carlo, "Done means").

Runs ``config/scenarios/paper_montecarlo.yaml`` in this process and prints one JSON document:
wall time, runs/s, peak resident memory (``ru_maxrss``), and the resident memory sampled after
every finished chunk (flat memory means the last samples do not grow with the run count).

    python benchmarks/bench_montecarlo.py [--runs 3000] [--seed 0] [--workers 1] [--repeats 1]

Targets: 3000 runs of 50 s at 100 Hz in <= 15 s with peak memory <= 2 GB; a 100,000-run
campaign with flat memory (``--runs 100000``, about 9 minutes on one core).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from sappc import montecarlo as mc  # noqa: E402

SCENARIO = ROOT / "config" / "scenarios" / "paper_montecarlo.yaml"


def _rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=3000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--repeats", type=int, default=1)
    args = parser.parse_args()

    samples: list[float] = []
    real_save = mc._save_chunk

    def save_and_sample(out, index, result):  # type: ignore[no-untyped-def]
        real_save(out, index, result)
        samples.append(_rss_mb())

    mc._save_chunk = save_and_sample  # type: ignore[assignment]
    walls, summary = [], {}
    for _ in range(args.repeats):
        samples.clear()
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            summary = mc.run_campaign(SCENARIO, runs=args.runs, seed=args.seed, out_dir=tmp, workers=args.workers, progress=False)
            walls.append(time.perf_counter() - t0)
    wall = statistics.median(walls)
    # the largest resident set of this process and of any worker process (ru_maxrss is per process)
    peak_mb = max(resource.getrusage(who).ru_maxrss for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN)) / 1024.0
    n = len(samples)
    result = {
        "machine": {"platform": platform.platform(), "cpu_count": os.cpu_count(), "python": platform.python_version(), "numpy": np.__version__},
        "runs": args.runs,
        "workers": args.workers,
        "repeats": args.repeats,
        "statistic": "median",
        "wall_time_s": wall,
        "campaign_loop_wall_s": summary["wall_time_s"],
        "runs_per_s": args.runs / wall,
        "target_wall_s_for_3000_runs": 15.0,
        "meets_wall_target": (wall <= 15.0) if args.runs == 3000 else None,  # the target is for 3000 runs
        "peak_rss_mb": peak_mb,
        "meets_memory_target": peak_mb <= 2048.0,
        "rss_after_chunk_mb": {"first": samples[0] if n else None, "middle": samples[n // 2] if n else None,
                               "last": samples[-1] if n else None, "max": max(samples) if n else None, "chunks": n},
        "pass_fraction": summary["pass_fraction"],
        "passed": summary["passed"],
    }
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()

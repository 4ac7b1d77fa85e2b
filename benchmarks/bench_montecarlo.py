"""Whole-command benchmarks of the compiled offline runner and Monte Carlo (issue 13).

Each figure is the wall time of a whole `sappc` process (imports, numba cache load, the runs,
the table and the figures), median of ``--repeats``, warm numba cache; peak memory is the
largest resident set of the command and its workers (``ru_maxrss`` of the children).

* ``simulate_paper_tracking_s``: ``sappc simulate config/scenarios/paper_tracking.yaml`` (target <= 1.5 s);
* ``montecarlo_3000_s``: ``sappc montecarlo config/scenarios/paper_montecarlo.yaml --runs 3000``
  with its figures (target <= 4 s);
* ``montecarlo_100000_s`` (``--big``, once): ``--runs 100000`` (target <= 120 s, peak <= 500 MB).

    python benchmarks/bench_montecarlo.py [--repeats 5] [--workers W] [--big]

The numpy core's figures (issue 13, this machine): simulate 1.6-4 s, 3000 runs 6.8-11.8 s,
100,000 runs 680 s on one worker with a 204 MB peak.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCENARIOS = ROOT / "config" / "scenarios"
NUMPY_CORE = {"simulate_s": [1.6, 4.0], "montecarlo_3000_s": [6.8, 11.8], "montecarlo_100000_s": 680.0, "peak_100000_mb": 204.0}


def _run(args: list[str]) -> tuple[float, float, str]:
    """Wall time [s], peak RSS [MB] of the command and its workers, stderr."""
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src") + os.pathsep + os.environ.get("PYTHONPATH", "")}
    before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "sappc", *args], capture_output=True, text=True, cwd=ROOT, env=env)
    wall = time.perf_counter() - t0
    if proc.returncode not in (0, 1):
        raise RuntimeError(proc.stderr)
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    return wall, max(peak, before) / 1024.0, proc.stderr


def _median(args_fn, repeats: int) -> dict[str, object]:  # type: ignore[no-untyped-def]
    walls, peaks = [], []
    for _ in range(repeats):
        with tempfile.TemporaryDirectory() as tmp:
            wall, peak, _ = _run(args_fn(tmp))
        walls.append(wall)
        peaks.append(peak)
    return {"median_s": statistics.median(walls), "all_s": walls, "peak_rss_mb_so_far": max(peaks)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--big", action="store_true", help="also the 100,000-run campaign (once)")
    args = parser.parse_args()
    w = ["--workers", str(args.workers)]
    _run(["simulate", str(SCENARIOS / "paper_tracking.yaml")])  # warm the cache (and the page cache)
    sim = _median(lambda tmp: ["simulate", str(SCENARIOS / "paper_tracking.yaml")], args.repeats)
    mc = _median(lambda tmp: ["montecarlo", str(SCENARIOS / "paper_montecarlo.yaml"), "--runs", "3000", "--out", tmp, "--no-progress", *w],
                 args.repeats)
    result: dict[str, object] = {
        "machine": {"platform": platform.platform(), "cpu_count": os.cpu_count(), "python": platform.python_version(),
                    "numpy": np.__version__, "note": "shared 2-core VM: timings drift 10-50 % between invocations"},
        "repeats": args.repeats, "statistic": "median", "workers": args.workers,
        "simulate_paper_tracking_s": {**sim, "target_s": 1.5, "meets_target": sim["median_s"] <= 1.5},  # type: ignore[operator]
        "montecarlo_3000_s": {**mc, "target_s": 4.0, "meets_target": mc["median_s"] <= 4.0},  # type: ignore[operator]
        "numpy_core_issue13": NUMPY_CORE,
    }
    if args.big:
        with tempfile.TemporaryDirectory() as tmp:
            before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
            wall, peak, _ = _run(["montecarlo", str(SCENARIOS / "paper_montecarlo.yaml"), "--runs", "100000", "--out", tmp, "--no-progress", *w])
        result["montecarlo_100000"] = {"wall_s": wall, "target_s": 120.0, "meets_target": wall <= 120.0,
                                       "peak_rss_mb": peak if peak * 1024 > before else None, "peak_target_mb": 500.0,
                                       "ratio_numpy_over_compiled": NUMPY_CORE["montecarlo_100000_s"] / wall}
    result["simulate_paper_tracking_s"]["ratio_numpy_over_compiled"] = [v / sim["median_s"] for v in NUMPY_CORE["simulate_s"]]  # type: ignore[index, operator]
    result["montecarlo_3000_s"]["ratio_numpy_over_compiled"] = [v / mc["median_s"] for v in NUMPY_CORE["montecarlo_3000_s"]]  # type: ignore[index, operator]
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()

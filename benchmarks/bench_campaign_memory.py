"""Issue 47: the memory and time of a campaign of 6 h orbit runs, from the OS.

    python benchmarks/bench_campaign_memory.py [--runs 4] [--workers 1] [--repeats 1] [--baseline DIR]

One ``sappc montecarlo paper_tracking_orbit --runs N --workers W --out DIR`` in a child process of
its own per repeat (after one uncounted warm-up of one run, which loads or compiles the numba
cache).  Measured: the wall time, the CPU time of the process tree, each process's own peak
resident set (``VmHWM``, read every half second: :func:`proc_tree.run_polled`): the parent's (it
assembles the table and the figures) and the largest worker's (a worker runs its chunks), and
``ru_maxrss`` of ``os.wait4`` (the largest single process of the tree, exact).  The
campaign's ``runs.csv`` is hashed: equal hashes between two checkouts are the same table bit for
bit (``--baseline DIR``: the same cases in the checkout DIR, alternately, as bench_memory.py).

Prints one JSON document (``machine``: where it was measured; save it under
``benchmarks/results_memory/``).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import statistics
import sys
import tempfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
import paired  # noqa: E402
from proc_tree import run_polled  # noqa: E402

#: The campaign's scenario: the 6 h orbit (2,160,001 samples a run, the heaviest bundled campaign).
SCENARIO = "paper_tracking_orbit"
#: The longest a campaign may run [s] (100 runs on one idle worker: about 25 minutes).
CAMPAIGN_TIMEOUT_S = 3600.0


def run_campaign(root: Path, runs: int, workers: int, tmp: Path) -> dict[str, Any]:
    """One campaign in checkout ``root``: peak RSS [MB], CPU and wall [s], the table's hash."""
    out = Path(tempfile.mkdtemp(prefix="campaign_", dir=tmp))
    scenario = root / "src" / "sappc" / "data" / "scenarios" / f"{SCENARIO}.yaml"
    argv = [sys.executable, "-m", "sappc", "montecarlo", str(scenario), "--runs", str(runs), "--workers", str(workers),
            "--out", str(out / "mc"), "--no-progress"]
    run = run_polled(argv, tmp, CAMPAIGN_TIMEOUT_S, {"PYTHONPATH": str(root / "src")})
    if run["exit"] not in (0, 1):  # 1: a run failed the campaign's criteria (a result, not an error)
        raise SystemExit(f"{' '.join(argv)} exited {run['exit']}:\n{run['output_tail']}")
    table = (out / "mc" / "runs.csv").read_bytes()
    peaks = list(run["peak_by_pid_mb"].values())
    return {"peak_rss_mb": run["ru_maxrss_mb"], "parent_peak_mb": peaks[0], "worker_peak_mb": max(peaks[1:], default=0.0),
            "cpu_s": run["cpu_s"], "wall_s": run["wall_s"], "runs_csv_digest": hashlib.sha256(table).hexdigest()[:16]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=4, help="runs of the campaign (default 4; the issue's campaign: 100)")
    parser.add_argument("--workers", type=int, default=1, help="worker processes (default 1)")
    parser.add_argument("--repeats", type=int, default=1, help="counted campaigns of each side (default 1)")
    parser.add_argument("--baseline", type=Path, help="a checkout to pair against (run with this checkout's .venv)")
    args = parser.parse_args()
    roots = {"candidate": ROOT} if args.baseline is None else {"baseline": args.baseline.resolve(), "candidate": ROOT}
    results: dict[str, list[dict[str, Any]]] = {side: [] for side in roots}
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        for root in roots.values():
            run_campaign(root, 1, 1, tmp)  # warm-up: the numba cache
        for i in range(max(1, args.repeats)):
            order = list(roots.items()) if i % 2 == 0 else list(reversed(roots.items()))
            for side, root in order:
                results[side].append(run_campaign(root, args.runs, args.workers, tmp))
    summary = {side: {key: statistics.median(r[key] for r in rs) for key in ("peak_rss_mb", "parent_peak_mb", "worker_peak_mb", "cpu_s", "wall_s")}
               | {"runs_csv_digests": sorted({r["runs_csv_digest"] for r in rs})} for side, rs in results.items()}
    print(json.dumps({"benchmark": "bench_campaign_memory", "machine": paired.machine(), "scenario": SCENARIO, "runs": args.runs,
                      "workers": args.workers, "repeats": args.repeats,
                      "commits": {side: paired.commit(root) for side, root in roots.items()},
                      "summary": summary, "runs_each": results}, indent=1))


if __name__ == "__main__":
    main()

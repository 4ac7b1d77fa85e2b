"""Benchmark of the ROS 2 node graph (issue: node graph, "Done means").

Runs experiment 1 (``config/scenarios/paper_tracking.yaml``, 60 s at 100 Hz) through ``sappc run``
(five processes, recorder included) and prints one JSON document:

- lockstep, in paired rounds of the five processes and of ``--compose`` (one process, one
  executor): the wall time from the plant's first sample to its last (``run_s``; targets <= 6 s
  and <= 3 s) and the start-up time (process start, imports, discovery and matching; targets
  <= 2 s and <= 0.5 s), median of ``--repeats`` rounds, the composed/processes ratio per round,
  whether the two modes recorded the same bag file, and the bag's message count.

Real-time runs are ``benchmarks/bench_realtime.py``'s.

    python benchmarks/bench_graph.py [--repeats 3] [--domain-id N]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from sappc.graph.launch import GraphResult, run_graph  # noqa: E402

SCENARIO = ROOT / "config" / "scenarios" / "paper_tracking.yaml"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--domain-id", type=int, default=None, help="ROS domain id (default: the first free one)")
    args = parser.parse_args()
    out: dict[str, object] = {
        "machine": {"platform": platform.platform(), "python": platform.python_version(), "cpus": os.cpu_count()},
        "scenario": str(SCENARIO.relative_to(ROOT)),
    }
    with tempfile.TemporaryDirectory() as tmp:
        modes: dict[str, list[GraphResult]] = {"processes": [], "composed": []}
        same_bag = []
        for i in range(args.repeats):  # paired rounds: both modes under the same machine load
            for mode, runs in modes.items():
                runs.append(run_graph(SCENARIO, out_dir=Path(tmp) / f"{mode}{i}", progress=False, domain_id=args.domain_id,
                                      compose=mode == "composed"))
            same_bag.append((modes["composed"][i].bag_dir / "bag_0.mcap").read_bytes() == (modes["processes"][i].bag_dir / "bag_0.mcap").read_bytes())
        out["lockstep"] = {
            mode: {
                "run_s": [r.run_s for r in runs],
                "run_s_median": statistics.median(r.run_s for r in runs),
                "startup_s": [r.startup_s for r in runs],
                "startup_s_median": statistics.median(r.startup_s for r in runs),
                "speed_vs_real_time": 60.0 / statistics.median(r.run_s for r in runs),
                "messages_recorded": sum(runs[0].recorded.values()),
                "counts_match": all(r.counts_match for r in runs),
                "target_run_s": 6.0 if mode == "processes" else 3.0,
                "target_startup_s": 2.0 if mode == "processes" else 0.5,
            } for mode, runs in modes.items()
        }
        out["lockstep"]["composed_over_processes_run_s"] = [c.run_s / p.run_s for c, p in zip(modes["composed"], modes["processes"])]
        out["lockstep"]["same_bag_file"] = same_bag
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()

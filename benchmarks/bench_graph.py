"""Benchmark of the ROS 2 node graph (issue: node graph, "Done means").

Runs experiment 1 (``config/scenarios/paper_tracking.yaml``, 60 s at 100 Hz) through ``sappc run``
(five processes, recorder included) and prints one JSON document:

- lockstep, in paired rounds of the five processes and of ``--compose`` (one process, one
  executor): the wall time from the plant's first sample to its last (``run_s``; targets <= 6 s
  and <= 3 s) and the start-up time (process start, imports, discovery and matching; targets
  <= 2 s and <= 0.5 s), median of ``--repeats`` rounds, the composed/processes ratio per round,
  whether the two modes recorded the same bag file, and the bag's message count;
- real time (``--realtime``, ``--repeats`` runs of 60 s, in the frames of
  :mod:`sappc_msgs_py.timeline`): the plant's frame timer (the loop's clock) period error
  |interval - 10 ms| (p50, p99, max; target p99 <= 0.5 ms) and missed ticks (target 0), the
  frames without a tick and the frames integrated with a stale torque (a step that used a stale
  state), the controller's latency from the state's stamp and its late steps, the steady max
  |q_ev| (target <= 4e-5 every run), and the 1-minute load average after each run.  ``--busy N``
  runs N CPU-bound processes beside the real-time runs (the issue's "with 2 busy processes").

    python benchmarks/bench_graph.py [--repeats 3] [--realtime] [--busy N] [--no-lockstep] [--domain-id N]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
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
    parser.add_argument("--realtime", action="store_true", help="also run --repeats times in real time (60 s each)")
    parser.add_argument("--busy", type=int, default=0, help="CPU-bound processes beside the real-time runs")
    parser.add_argument("--no-lockstep", action="store_true")
    parser.add_argument("--domain-id", type=int, default=None, help="ROS domain id (default: the first free one)")
    args = parser.parse_args()
    out: dict[str, object] = {
        "machine": {"platform": platform.platform(), "python": platform.python_version(), "cpus": os.cpu_count()},
        "scenario": str(SCENARIO.relative_to(ROOT)),
    }
    with tempfile.TemporaryDirectory() as tmp:
        if not args.no_lockstep:
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
        if args.realtime:  # --repeats runs: the frames' timing and the steady error of each
            from sappc.bag.read import bag_metrics, read_bag

            busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(args.busy)]
            try:
                rt = []
                for k in range(args.repeats):
                    r = run_graph(SCENARIO, out_dir=Path(tmp) / f"realtime{k}", realtime=True, progress=False, domain_id=args.domain_id)
                    ms = r.scenario.metrics
                    m = bag_metrics(read_bag(r.bag_dir), steady_from_s=ms.steady_from_s, settle_threshold=ms.settle_threshold, t2_s=ms.t2_s,
                                    fault_windows=r.scenario.event_windows())
                    plant = r.plant_timing
                    rt.append({**{k: plant.get(k) for k in ("ticks", "period_error_p50_ms", "period_error_p99_ms", "period_error_max_ms", "missed_ticks",
                                                               "missed_frames", "stale_torque_frames", "state_delay")},
                               "controller_latency": r.controller_timing.get("latency", {}), "run_s": r.run_s, "counts_match": r.counts_match,
                               "steady_max_abs_qev": m["steady_max_abs_qev"], "load_average_1min_after": os.getloadavg()[0]})
            finally:
                for b in busy:
                    b.kill()
                    b.wait()
            out["realtime"] = {
                "busy_processes": args.busy,
                "runs": rt,
                "period_error_p99_ms_median": statistics.median(x.get("period_error_p99_ms") or float("nan") for x in rt),
                "missed_ticks": [x.get("missed_ticks") for x in rt],
                "stale_torque_frames": [x.get("stale_torque_frames") for x in rt],
                "steady_max_abs_qev": [x["steady_max_abs_qev"] for x in rt],
                "target_period_error_p99_ms": 0.5,
                "target_missed_ticks": 0,
                "target_steady_max_abs_qev": 4e-5,
            }
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()

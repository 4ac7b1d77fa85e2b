"""Issue 48: the lockstep graph's loop against rclpy's floor for the same messages, measured in one call.

    python benchmarks/bench_graph_vs_floor.py [--scenario paper_tracking] [--baseline DIR] [--repeats 3]
                                             [--layouts composed,processes]

Each round, for each layout (``composed``: ``sappc run --compose``, every node in one process;
``processes``: one process per node): rclpy's serialized floor of the scenario's message pattern
(``benchmarks/bench_graph_floor.py --scenario S --repeats 1``: every node reduced to its messages,
CDR bytes end to end) and its work floor (``--modes work``: the same with the run's unavoidable
work done by the project's code: codecs, the law, the rigid body, the bag writer), then ``sappc run config/scenarios/S.yaml`` in this checkout and, with
``--baseline``, in the baseline checkout (its own ``.venv``: the main the issue was filed on), the
two checkouts alternating which goes first.  The loop is ``sappc run``'s ``wall_time_s`` (the
plant's first sample to its last); ``first_sample_after_nodes_up_s`` (where the checkout reports
it) is the start once the nodes are built.  Prints one JSON document: per layout the rounds, their
medians and the ratios per round (this checkout / floor, / work floor, baseline / floor, this
checkout / baseline, work floor / floor) with their medians; the machine and the load average before and after.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
import paired  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
#: The longest one command of a round may take [s].
TIMEOUT_S = 1800.0


def floor(scenario: str) -> dict[str, dict[str, float]]:
    """The floors of ``scenario``'s pattern, per layout [s] (one run of each): ``serialized``
    (rclpy's, bare) and ``work`` (Python nodes doing the run's unavoidable work, bench_graph_floor's
    docstring)."""
    out = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bench_graph_floor.py"), "--scenario", scenario, "--repeats", "1",
                          "--modes", "serialized,work"], capture_output=True, text=True, timeout=TIMEOUT_S, cwd=ROOT)
    if out.returncode != 0:
        raise SystemExit(f"bench_graph_floor.py failed:\n{out.stderr[-3000:]}")
    doc = json.loads(out.stdout[out.stdout.index("{"):])
    floors: dict[str, dict[str, float]] = {}
    for mode in ("serialized", "work"):
        processes = next(k for k in doc if k.endswith(f"_processes_{mode}"))  # five_, six_, seven_: one per node
        floors[mode] = {"composed": float(doc[f"composed_{mode}"]["loop_s"]["median"]), "processes": float(doc[processes]["loop_s"]["median"])}
    return floors


def project_loop(root: Path, scenario: str, layout: str) -> dict[str, Any]:
    """``sappc run`` of ``scenario`` in checkout ``root``: its loop, start and exit status."""
    with tempfile.TemporaryDirectory() as tmp:
        report = Path(tmp) / "run.json"
        argv = [paired.python_of(root), "-m", "sappc", "run", str(root / "config" / "scenarios" / f"{scenario}.yaml"),
                *(["--compose"] if layout == "composed" else []), "--out", str(Path(tmp) / "run"), "--json", str(report)]
        proc = subprocess.run(argv, capture_output=True, text=True, timeout=TIMEOUT_S, cwd=root)
        metrics = json.loads(report.read_text()).get("metrics", {}) if report.is_file() else {}
    return {"exit": proc.returncode, "loop_s": metrics.get("wall_time_s"), "startup_s": metrics.get("startup_s"),
            "first_sample_after_nodes_up_s": metrics.get("first_sample_after_nodes_up_s")}


def _local_changes(root: Path) -> str:
    """What a checkout changes against its commit (``git diff --stat``), so a measured baseline says it."""
    return subprocess.run(["git", "-C", str(root), "diff", "--stat"], capture_output=True, text=True).stdout.strip()


def _median(xs: list[float]) -> float | None:
    return statistics.median(xs) if xs else None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenario", default="paper_tracking", help="a scenario of config/scenarios (default paper_tracking)")
    parser.add_argument("--baseline", type=Path, help="a baseline checkout with its own .venv (the main the issue was filed on)")
    parser.add_argument("--repeats", type=int, default=3, help="rounds (default 3)")
    parser.add_argument("--layouts", default="composed,processes", help="composed, processes or both (default both)")
    args = parser.parse_args()
    layouts = [x for x in args.layouts.split(",") if x]
    sides = {"candidate": ROOT, **({"baseline": args.baseline.resolve()} if args.baseline else {})}
    load_before = os.getloadavg()[0]
    rounds: dict[str, list[dict[str, Any]]] = {layout: [] for layout in layouts}
    for r in range(args.repeats):
        floors = floor(args.scenario)
        for layout in layouts:
            order = list(sides) if r % 2 == 0 else list(reversed(sides))  # neither side always first
            entry: dict[str, Any] = {"floor_s": floors["serialized"][layout], "work_floor_s": floors["work"][layout]}
            for side in order:
                entry[side] = project_loop(sides[side], args.scenario, layout)
            rounds[layout].append(entry)
            print(f"round {r + 1} {layout}: " + json.dumps(entry), file=sys.stderr, flush=True)
            time.sleep(1.0)
    result: dict[str, Any] = {"benchmark": "bench_graph_vs_floor", "scenario": args.scenario, "machine": paired.machine(),
                              "commit": paired.commit(ROOT), "baseline_commit": paired.commit(args.baseline) if args.baseline else None,
                              "baseline_local_changes": _local_changes(args.baseline) if args.baseline else None,
                              "load_average_1min": {"before": load_before, "after": os.getloadavg()[0]}, "layouts": {}}
    for layout, entries in rounds.items():
        summary: dict[str, Any] = {"rounds": entries, "floor_s_median": _median([e["floor_s"] for e in entries]),
                                   "work_floor_s_median": _median([e["work_floor_s"] for e in entries]),
                                   "work_floor_over_floor": [e["work_floor_s"] / e["floor_s"] for e in entries]}
        summary["work_floor_over_floor_median"] = _median(summary["work_floor_over_floor"])
        for side in sides:
            loops = [e[side]["loop_s"] for e in entries if e[side]["loop_s"] is not None]
            summary[f"{side}_loop_s_median"] = _median(loops)
            for key in ("floor", "work_floor"):
                summary[f"{side}_over_{key}"] = [e[side]["loop_s"] / e[f"{key}_s"] for e in entries if e[side]["loop_s"] is not None]
                summary[f"{side}_over_{key}_median"] = _median(summary[f"{side}_over_{key}"])
        if "baseline" in sides:
            pairs = [e["candidate"]["loop_s"] / e["baseline"]["loop_s"] for e in entries
                     if e["candidate"]["loop_s"] is not None and e["baseline"]["loop_s"]]
            summary["candidate_over_baseline"] = pairs
            summary["candidate_over_baseline_median"] = _median(pairs)
        result["layouts"][layout] = summary
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()

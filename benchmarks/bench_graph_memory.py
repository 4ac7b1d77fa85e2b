"""Issue 47: the memory of one orbit through the ROS 2 graph, of all its processes together.

    python benchmarks/bench_graph_memory.py [--duration 5677] [--out DIR]

Flies ``paper_tracking_orbit`` cut to ``--duration`` seconds (default one orbit, 5677 s: 567,701
samples) through the graph, composed in lockstep (``sappc run FILE --compose --out DIR``: the
nodes, the recorder, the bag's close and ``sappc run``'s metrics read back from the bag), then
``sappc report`` on its bag.  Measured:

- ``run``: the largest sum of the resident sets of every process of the command's tree at one
  poll (:func:`proc_tree.run_polled`: a lower bound within what a poll can miss), each process's
  own peak, the ``ru_maxrss`` of the tree (the largest single process's exact peak), the wall time
  and the exit status;
- ``report``: ``sappc report BAG``'s peak resident set (``ru_maxrss`` of ``os.wait4``: its largest
  process's, exact) and wall time.

Prints one JSON document (``machine``: where it was measured; save it under
``benchmarks/results_memory/``).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
import paired  # noqa: E402
from proc_tree import run_polled  # noqa: E402

#: One orbit of the 6 h scenario's 500 km orbit [s] (its period, 5676.98 s, rounded up to the sample).
ONE_ORBIT_S = 5677.0
#: The longest the graph's run may take [s] (one orbit: 23 minutes on an idle 2-core machine).
RUN_TIMEOUT_S = 7200.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--duration", type=float, default=ONE_ORBIT_S, help=f"the run's length [s] (default one orbit, {ONE_ORBIT_S:g})")
    parser.add_argument("--out", type=Path, help="where the run's bag goes (default: a temporary directory, removed)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        out = (args.out or tmp / "run").resolve()
        scenario = tmp / "orbit_cut.yaml"
        bundled = ROOT / "src" / "sappc" / "data" / "scenarios" / "paper_tracking_orbit.yaml"
        scenario.write_text(f"extends: {bundled}\nname: paper_tracking_orbit_cut\nduration_s: {args.duration!r}\n")
        sappc = [sys.executable, "-m", "sappc"]
        run = run_polled([*sappc, "run", str(scenario), "--compose", "--out", str(out), "--json", str(tmp / "run.json")], ROOT, RUN_TIMEOUT_S)
        bag = out / "bag"
        report = run_polled([*sappc, "report", str(bag), "--out", str(tmp / "report"), "--json", str(tmp / "report.json")], ROOT, RUN_TIMEOUT_S)
        metrics = {side: json.loads((tmp / f"{side}.json").read_text()).get("metrics", {}) for side in ("run", "report")
                   if (tmp / f"{side}.json").is_file()}
        size = sum(p.stat().st_size for p in bag.glob("*")) if bag.is_dir() else 0
    print(json.dumps({"benchmark": "bench_graph_memory", "machine": paired.machine(), "commit": paired.commit(ROOT),
                      "scenario": "paper_tracking_orbit", "duration_s": args.duration, "bag_bytes": size, "run": run, "report": report,
                      "steady_max_abs_qev": {side: m.get("steady_max_abs_qev") for side, m in metrics.items()}}, indent=1))


if __name__ == "__main__":
    main()

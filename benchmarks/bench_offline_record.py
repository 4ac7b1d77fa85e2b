"""Issue 47 item 4: what writing an offline run's full-rate record as a bag costs
(:class:`sappc.bag.write_offline.OfflineBagWriter`, ``sappc simulate --record DIR``).

    python benchmarks/bench_offline_record.py [--case orbit_1h] [--repeats 3]

Each run is one offline run of the case in a child process of its own, ``simulate(scenario,
history="none")`` as ``sappc simulate`` without ``--out`` runs it, without a sink (``plain``) or with
a writer as its sink (``record``, then ``close()``): the command ``sappc simulate SCENARIO
--record DIR`` will run once its option is wired (``cli.py``).  Measured from the OS: the child's
peak resident set (``ru_maxrss`` of ``os.wait4``), its CPU and wall time; in the child: the time
spent in the writer (its calls and ``close``), the bag's size and its messages.  The two kinds
alternate (plain record, record plain, ...) after one uncounted warm-up of each (which also loads
the numba cache); medians of ``--repeats``.  The cost a message: the writer's time over the
messages written, and the wall time's difference (record minus plain, paired) over them.

Cases: ``orbit_1h`` (``paper_tracking_orbit``, every flight feature: 24 topics, 360,001 samples),
``tracking_1h`` (``paper_tracking``, the paper's 11 topics).

Prints one JSON document (``machine``: where it was measured; save it under
``benchmarks/results_memory/``).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
import paired  # noqa: E402

#: The cases: (bundled scenario, duration [s]).
CASES: dict[str, tuple[str, float]] = {
    "orbit_1h": ("paper_tracking_orbit", 3600.0),
    "tracking_1h": ("paper_tracking", 3600.0),
}
#: The longest a run may take [s] (a 1 h orbit run with its bag: about 30 s on a loaded 2-vCPU machine).
RUN_TIMEOUT_S = 1200.0

#: The child: one run, its figures as JSON into argv[3].
_CHILD = """
import json, sys, time
from pathlib import Path
from sappc.bag.write_offline import OfflineBagWriter
from sappc.offline.simulate import simulate
from sappc.scenario import read_scenario_mapping, scenario_from_mapping

name, duration, out, kind, bag = sys.argv[1], float(sys.argv[2]), sys.argv[3], sys.argv[4], Path(sys.argv[5])
raw = read_scenario_mapping(name)
raw["duration_s"] = duration
scenario = scenario_from_mapping(raw, source=name)
spent = [0.0]
sinks = []
writer = None
if kind == "record":
    writer = OfflineBagWriter(scenario, bag)

    def timed(h):
        t0 = time.perf_counter()
        writer(h)
        spent[0] += time.perf_counter() - t0

    sinks = [timed]
t0 = time.perf_counter()
result = simulate(scenario, history="none", sinks=sinks)
if writer is not None:
    t1 = time.perf_counter()
    writer.close()
    spent[0] += time.perf_counter() - t1
wall = time.perf_counter() - t0
doc = {"run_wall_s": wall, "writer_s": spent[0], "samples": result.controller_summary["samples"],
       "steady_max_abs_qev": result.metrics["steady_max_abs_qev"]}
if writer is not None:
    doc.update(messages=writer.messages, topics=len(writer.channels), row_bytes=writer.row_bytes,
               bag_bytes=sum(p.stat().st_size for p in bag.iterdir()), chunks=writer.chunks)
Path(out).write_text(json.dumps(doc))
"""


def run(case: str, kind: str, tmp: Path) -> dict[str, Any]:
    """One run of ``case``, ``plain`` or ``record``: the OS's figures and the child's."""
    name, duration = CASES[case]
    out = tmp / f"{case}_{kind}.json"
    bag = tmp / f"{case}_bag"
    scenario = ROOT / "src" / "sappc" / "data" / "scenarios" / f"{name}.yaml"
    argv = [sys.executable, "-c", _CHILD, str(scenario), repr(duration), str(out), kind, str(bag)]
    wall, usage = paired.run_with_usage(argv, {"PYTHONPATH": str(ROOT / "src")}, tmp, RUN_TIMEOUT_S)
    doc: dict[str, Any] = json.loads(out.read_text())
    out.unlink()
    if bag.exists():
        for p in bag.iterdir():
            p.unlink()
        bag.rmdir()
    return {"kind": kind, "peak_rss_mb": usage.ru_maxrss / 1024.0, "cpu_s": usage.ru_utime + usage.ru_stime, "wall_s": wall,
            **doc}


def measure(case: str, repeats: int) -> dict[str, Any]:
    runs: dict[str, list[dict[str, Any]]] = {"plain": [], "record": []}
    with tempfile.TemporaryDirectory(prefix="sappc-record-") as tmp_s:
        tmp = Path(tmp_s)
        for i in range(repeats + 1):  # run 0: the warm-up of each
            for kind in (("plain", "record") if i % 2 == 0 else ("record", "plain")):
                r = run(case, kind, tmp)
                print(f"{case} {kind} {'warm-up' if i == 0 else i}: {r['peak_rss_mb']:.0f} MB, cpu {r['cpu_s']:.1f} s, "
                      f"wall {r['wall_s']:.1f} s, "
                      f"writer {r['writer_s']:.1f} s", file=sys.stderr, flush=True)
                if i > 0:
                    runs[kind].append(r)
    plain, record = runs["plain"], runs["record"]

    def median(rs: list[dict[str, Any]], key: str) -> float:
        return float(statistics.median(r[key] for r in rs))

    messages = record[0]["messages"]
    return {
        "case": case, "scenario": CASES[case][0], "duration_s": CASES[case][1], "samples": record[0]["samples"],
        "topics": record[0]["topics"], "messages": messages, "row_bytes": record[0]["row_bytes"],
        "bag_mb": record[0]["bag_bytes"] / 1e6, "bag_bytes_per_message": record[0]["bag_bytes"] / messages,
        "chunks": record[0]["chunks"],
        "same_numbers": len({r["steady_max_abs_qev"] for r in plain + record}) == 1,
        **{f"{kind}_{key}_median": median(rs, key) for kind, rs in runs.items() for key in ("peak_rss_mb", "cpu_s", "wall_s")},
        "writer_s_median": median(record, "writer_s"),
        "writer_ns_per_message": median(record, "writer_s") / messages * 1e9,
        "wall_difference_ns_per_message": statistics.median(r["wall_s"] - p["wall_s"] for r, p in zip(record, plain))
        / messages * 1e9,
        "peak_rss_difference_mb": statistics.median(r["peak_rss_mb"] - p["peak_rss_mb"] for r, p in zip(record, plain)),
        "runs": runs,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--case", default="orbit_1h", choices=sorted(CASES))
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    load_before = os.getloadavg()
    result = measure(args.case, args.repeats)
    doc = {"machine": {**paired.machine(), "commit": paired.commit(ROOT), "load_average_before": load_before,
                       "load_average_after": os.getloadavg()}, "result": result}
    print(json.dumps(doc, indent=1))


if __name__ == "__main__":
    main()

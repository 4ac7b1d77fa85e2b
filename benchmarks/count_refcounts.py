"""Count numba's reference-count calls a sample, kernel by kernel (a profiling aid; needs gdb).

    python benchmarks/count_refcounts.py paper_tracking_orbit                 # the per-run loop
    python benchmarks/count_refcounts.py paper_tracking_flight --lanes 84     # a campaign chunk in lanes

A child process loads the scenario's kernels (a short run), names them for gdb and perf
(:mod:`numba_perf_map`), then runs the workload again and again; gdb attaches to it mid-run with a
breakpoint on numba's ``NRT_incref`` and ``NRT_decref``, records each hit's return address (the
calling kernel) for ``--hits`` hits, and detaches.  The JSON printed gives, for each kernel, its
calls and its call sites; ``per_sample`` divides by the hits of the most-hit site (a site that runs
once a sample: the window's samples, or run-steps in lanes).  Used for docs/performance.md,
"Reference counts, the next lever" (issue 50).
"""

from __future__ import annotations

import argparse
import bisect
import collections
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

_CHILD = r"""
import copy, os, sys, time
sys.path.insert(0, {bench!r})
import numba_perf_map
import numba.core.codegen
numba_perf_map._keep_object_code(numba.core.codegen)
import numba
numba.set_num_threads(1)
from sappc.scenario import load_scenario, scenario_from_mapping
scenario = load_scenario({scenario!r})
lanes = {lanes}
if lanes:
    from sappc.montecarlo.campaign import simulate_runs
    work = lambda: simulate_runs(scenario.raw, 0, list(range(lanes)), 0)
    simulate_runs(scenario.raw, 0, list(range(8)), 0)
else:
    from sappc.offline.compiled_loop import simulate_compiled
    raw = copy.deepcopy(scenario.raw)
    raw["duration_s"] = {duration}
    short = scenario_from_mapping(raw)
    work = lambda: simulate_compiled(short)
    work()
numba_perf_map.write_perf_map()
print("READY", os.getpid(), flush=True)
while True:
    work()
"""

_GDB = r"""
import gdb, json
hits, counts = [0], {{}}
class Count(gdb.Breakpoint):
    def stop(self):
        rsp = int(gdb.parse_and_eval("$rsp"))
        ra = int(gdb.parse_and_eval("*(unsigned long*)%d" % rsp))
        key = (self.number, ra)
        counts[key] = counts.get(key, 0) + 1
        hits[0] += 1
        return hits[0] >= {hits}
Count("*{incref}")
Count("*{decref}")
gdb.execute("continue")
json.dump([[k[0], k[1], v] for k, v in counts.items()], open({out!r}, "w"))
gdb.execute("kill")
"""


def _kernel_name(symbol: str) -> str:
    """The kernel's qualified name from numba's mangled symbol (``_ZN`` then length-prefixed names,
    then numba's ``B...`` tags), e.g. ``sappc.offline.compiled_loop._run_one``."""
    if not symbol.startswith("_ZN"):
        return symbol
    names, i = [], 3
    while i < len(symbol) and symbol[i].isdigit():
        j = i
        while symbol[j].isdigit():
            j += 1
        n = int(symbol[i:j])
        names.append(symbol[j:j + n])
        i = j + n
    return ".".join(names) or symbol


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("scenario", help="a scenario of config/scenarios (its name) or a path")
    parser.add_argument("--lanes", type=int, default=0, help="count a campaign chunk of this many runs in lanes instead of the per-run loop")
    parser.add_argument("--duration", type=float, default=20000.0, help="the per-run loop's run length [s] (default 20000)")
    parser.add_argument("--hits", type=int, default=200_000, help="breakpoint hits to record (default 200000)")
    args = parser.parse_args()
    path = Path(args.scenario)
    scenario = path if path.suffix else ROOT / "config" / "scenarios" / f"{args.scenario}.yaml"
    with tempfile.TemporaryDirectory() as tmp:
        child = subprocess.Popen([sys.executable, "-c", _CHILD.format(bench=str(Path(__file__).parent), scenario=str(scenario),
                                                                       lanes=args.lanes, duration=args.duration)],
                                 stdout=subprocess.PIPE, text=True)
        try:
            assert child.stdout is not None
            line = child.stdout.readline().split()
            if line[:1] != ["READY"]:
                raise SystemExit("the child did not start: " + " ".join(line))
            pid = int(line[1])
            table = Path(f"/tmp/perf-{pid}.map")
            symbols = sorted((int(a, 16), int(s, 16), n) for a, s, n in (row.split(maxsplit=2) for row in table.read_text().splitlines()))
            address = {n.strip(): a for a, _, n in symbols}
            time.sleep(1.0)  # mid-run
            out = os.path.join(tmp, "counts.json")
            script = os.path.join(tmp, "count.py")
            Path(script).write_text(_GDB.format(hits=args.hits, incref=address["NRT_incref"], decref=address["NRT_decref"], out=out))
            subprocess.run(["gdb", "-p", str(pid), "-batch", "-x", script], capture_output=True, check=False, timeout=1800)
            counts = json.loads(Path(out).read_text())
        finally:
            child.kill()
            child.wait()
            Path(f"/tmp/perf-{child.pid}.map").unlink(missing_ok=True)
    starts = [s[0] for s in symbols]
    by_kernel: collections.Counter[str] = collections.Counter()
    sites: collections.Counter[str] = collections.Counter()
    most = 0
    for _, ra, n in counts:
        i = bisect.bisect_right(starts, ra) - 1
        inside = i >= 0 and symbols[i][0] <= ra < symbols[i][0] + symbols[i][1]
        name = _kernel_name(symbols[i][2].strip()) if inside else "(not a kernel)"
        by_kernel[name] += n
        sites[name] += 1
        most = max(most, n)
    print(json.dumps({
        "scenario": str(scenario), "lanes": args.lanes, "hits": sum(n for _, _, n in counts), "samples_in_window": most,
        "per_sample": round(sum(n for _, _, n in counts) / most, 1),
        "kernels": {name: {"calls": n, "sites": sites[name], "per_sample": round(n / most, 1)} for name, n in by_kernel.most_common()},
    }, indent=2))


if __name__ == "__main__":
    main()

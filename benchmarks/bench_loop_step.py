"""Issue 28, the campaign's kernel: microseconds per run-step and reference counts per sample, paired against a baseline.

    python benchmarks/bench_loop_step.py --baseline DIR [--repeats 3] [--runs 200]

What a campaign's time is made of: one thread (``numba.set_num_threads(1)``) runs ``--runs`` runs of
``paper_montecarlo.yaml`` (initial attitudes drawn as the campaign draws them, RPF clamped where
infeasible, no histories) through the compiled batch loop (``run_batch``, stride 0), five times in
one process; the median over the five, divided by runs x samples, is that process's figure.  The
two checkouts alternate process by process (``--repeats`` pairs after one warm-up each: each
process finds its cache warm), and the JSON gives each side's figures and the ratio of each pair.

Reference counts: numba keeps an array alive with an atomic counter that compiled code increments
and decrements through two out-of-line functions (``NRT_incref``, ``NRT_decref``), wherever its
pruning pass cannot pair a count away.  With ``gdb`` on the path, a breakpoint on each counts the
calls of one run of 1 s and of 2 s of the same scenario (1 thread); the difference over the 100
extra samples is the count per sample, a figure that does not depend on the machine's load.
Also prints a hash of the results of both sides (final states and the recorded histories of the
first runs): equal hashes are the same numbers, bit for bit.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import paired  # noqa: E402

#: The child that times the loop (one process per measurement), in the checkout's own interpreter.
_TIMING = r"""
import hashlib, json, statistics, sys, time
import numpy as np, numba
import sappc.offline.compiled_loop as cl
from sappc.scenario import load_scenario
runs = int(sys.argv[1])
sc = load_scenario(sys.argv[2])
from scipy.spatial.transform import Rotation
rng = np.random.default_rng(0)
q = Rotation.from_euler("ZYX", rng.uniform(-85.0, 85.0, (runs, 3)), degrees=True).as_quat()
inp = cl.prepare(sc, q_BN0=q, on_infeasible="clamp")
numba.set_num_threads(1)
cl.run_batch(inp, 0)
walls = []
for _ in range(5):
    t0 = time.perf_counter()
    r = cl.run_batch(inp, 0)
    walls.append(time.perf_counter() - t0)
h = cl.run_batch(inp.subset(0, 8), 10)
digest = hashlib.sha256(r.x_final.tobytes() + h.out.tobytes() + h.x.tobytes()).hexdigest()[:16]
print(json.dumps({"us_per_run_step": statistics.median(walls) / (inp.n_runs * inp.t.size) * 1e6, "results_sha256_16": digest}))
"""

#: The child whose reference counts gdb counts: one run of ``argv[2]`` seconds, after a pause in
#: which gdb attaches (the compiled code is loaded by then).
_COUNTED = r"""
import dataclasses, os, sys, time
import numpy as np, numba
import sappc.offline.compiled_loop as cl
from sappc.scenario import load_scenario
sc = dataclasses.replace(load_scenario(sys.argv[1]), duration_s=float(sys.argv[2]))
inp = cl.prepare(sc, q_BN0=np.array([[0.3, 0.2, 0.1, 0.9273618495495704]]), on_infeasible="clamp")
numba.set_num_threads(1)
cl.run_batch(inp, 0)
print(os.getpid(), flush=True)
time.sleep(4.0)
cl.run_batch(inp, 0)
time.sleep(1.0)
"""


def _scenario(root: Path) -> str:
    for rel in ("src/sappc/data/scenarios/paper_montecarlo.yaml", "config/scenarios/paper_montecarlo.yaml"):
        if (root / rel).is_file():
            return str(root / rel)
    raise SystemExit(f"no paper_montecarlo.yaml in {root}")


def _timing(root: Path, runs: int) -> dict[str, object]:
    out = subprocess.run([paired.python_of(root), "-c", _TIMING, str(runs), _scenario(root)], cwd=root, capture_output=True, text=True,
                         timeout=600)
    if out.returncode != 0:
        raise SystemExit(f"timing in {root} failed:\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def _counts(root: Path, duration_s: float) -> tuple[int, int]:
    """(NRT_incref calls, NRT_decref calls) of one counted run of ``duration_s``."""
    child = subprocess.Popen([paired.python_of(root), "-c", _COUNTED, _scenario(root), str(duration_s)], cwd=root, stdout=subprocess.PIPE,
                             stderr=subprocess.DEVNULL, text=True)
    try:
        assert child.stdout is not None
        pid = child.stdout.readline().strip()
        gdb = subprocess.run(["gdb", "-p", pid, "-batch", "-ex", "break NRT_incref", "-ex", "break NRT_decref", "-ex", "ignore 1 1000000000",
                              "-ex", "ignore 2 1000000000", "-ex", "continue", "-ex", "info breakpoints"],
                             capture_output=True, text=True, timeout=600)
        hits = [int(line.split()[3]) for line in gdb.stdout.splitlines() if "already hit" in line]
        if len(hits) != 2:
            raise SystemExit(f"gdb gave no counts:\n{gdb.stdout[-2000:]}{gdb.stderr[-2000:]}")
        return hits[0], hits[1]
    finally:
        child.wait(timeout=60)


def _per_sample(root: Path) -> dict[str, float]:
    """Reference-count calls per sample: (2 s run - 1 s run) / 100 samples (the scenario's 100 Hz)."""
    a, b = _counts(root, 1.0), _counts(root, 2.0)
    return {"NRT_incref": (b[0] - a[0]) / 100.0, "NRT_decref": (b[1] - a[1]) / 100.0}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", type=Path, required=True, help="a checkout of the baseline commit with its .venv set up")
    parser.add_argument("--repeats", type=int, default=3, help="pairs of processes (default 3)")
    parser.add_argument("--runs", type=int, default=200, help="runs per batch (default 200)")
    args = parser.parse_args()
    roots = {"baseline": args.baseline.resolve(), "candidate": paired.ROOT}
    load_before = os.getloadavg()[0]
    figures: dict[str, list[float]] = {"baseline": [], "candidate": []}
    digests: dict[str, set[str]] = {"baseline": set(), "candidate": set()}
    for i in range(args.repeats + 1):
        for side in (("baseline", "candidate") if i % 2 == 0 else ("candidate", "baseline")):
            r = _timing(roots[side], args.runs)
            digests[side].add(str(r["results_sha256_16"]))
            if i > 0:
                figures[side].append(float(r["us_per_run_step"]))
    ratios = [c / b for c, b in zip(figures["candidate"], figures["baseline"])]
    counts = {side: _per_sample(root) for side, root in roots.items()} if shutil.which("gdb") else None
    print(json.dumps({
        "row": "campaign_kernel_us_per_run_step_one_thread",
        "date": time.strftime("%Y-%m-%d"),
        "machine": paired.machine(),
        "load_average_1min": {"before": load_before, "after": os.getloadavg()[0]},
        "baseline": {"root": str(roots["baseline"]), "commit": paired.commit(roots["baseline"])},
        "candidate": {"root": str(roots["candidate"]), "commit": paired.commit(roots["candidate"])},
        "runs": args.runs,
        "repeats": args.repeats,
        "us_per_run_step": {side: {"median": statistics.median(f), "min": min(f), "max": max(f), "runs": f} for side, f in figures.items()},
        "ratio_candidate_over_baseline": {"median": statistics.median(ratios), "min": min(ratios), "max": max(ratios), "runs": ratios},
        "results_sha256_16": {side: sorted(d) for side, d in digests.items()},
        "reference_counts_per_sample": counts,
    }, indent=2))


if __name__ == "__main__":
    main()

"""Issue 47: the peak memory of long offline runs, from the OS, and where it goes.

    python benchmarks/bench_memory.py [--cases orbit_1h,orbit_6h] [--repeats 3] [--baseline DIR]
    python benchmarks/bench_memory.py --breakdown orbit_6h [--baseline DIR]

Each case is ``sappc simulate SCENARIO --json FILE`` in a child process of its own (``python -m
sappc``), whose peak resident set (``ru_maxrss`` of ``os.wait4``: the largest resident set of the
command, from the kernel), user and system CPU time and wall time are measured; the medians of
``--repeats`` runs after one uncounted warm-up run of each case (which also loads or compiles the
numba cache).  A case is a bundled scenario, or one that ``extends`` it with another
``duration_s`` (written to a temporary file), so the memory's growth with the duration shows:

``orbit_1h``, ``orbit_6h``, ``orbit_24h``, ``orbit_7d``
    ``paper_tracking_orbit`` (wheels, star tracker, gyro, MEKF, orbit, rods, magnetometer) for 1,
    6 (as bundled: 2,160,001 samples), 24 h and 7 days (60,480,001 samples).  ``orbit_24h`` and
    ``orbit_7d`` are never run by default: before issue 47's blocks they needed about 10 and 70 GB
    (and a baseline before them refuses or exhausts the machine: pair them with none).
``orbit_6h_figures``
    ``orbit_6h`` with ``--out DIR``: its eight figures drawn from the run's envelope.
``tracking_6h``
    ``paper_tracking`` (the paper's ideal actuator, exact measurements) for 6 h: the cost of a
    sample without the flight features.

Every case's JSON (metrics and per-orbit table, ``wall_time_s`` left out) is hashed: equal hashes
between two checkouts are the same numbers bit for bit.

``--baseline DIR``: also run each case in the checkout DIR (``git archive COMMIT | tar -x -C DIR``
is enough: it runs with this checkout's ``.venv`` and ``PYTHONPATH=DIR/src``), alternately with
this one (A B, B A, ...), and give the ratio of each pair.  The script measures the checkout it is
in: copied into another export, it measures that one (``--candidate-commit`` names it).

``--breakdown CASE``: where the memory goes, in one child process under ``tracemalloc`` (numpy's
allocations are traced): each array of the loop's inputs and record larger than 1 MB, and the
peak of traced memory within each phase of the command (inputs, loop, history, each metric), so
the phase at the peak and what is alive then can be read off.

Prints one JSON document (``machine``: where it was measured; save it under
``benchmarks/results_memory/``).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
import paired  # noqa: E402

#: The cases: (bundled scenario, duration_s or None for the file's own).
CASES: dict[str, tuple[str, float | None]] = {
    "orbit_1h": ("paper_tracking_orbit", 3600.0),
    "orbit_6h": ("paper_tracking_orbit", None),
    "orbit_6h_figures": ("paper_tracking_orbit", None),
    "orbit_24h": ("paper_tracking_orbit", 86400.0),
    "orbit_7d": ("paper_tracking_orbit", 604800.0),
    "tracking_6h": ("paper_tracking", 21600.0),
}
#: Cases run with ``--out DIR``: the figures (from the envelope of the run, issue 47's item 3).
FIGURE_CASES = ("orbit_6h_figures",)
DEFAULT_CASES = ("orbit_1h", "orbit_6h", "tracking_6h")
#: The longest a case may run [s] (a 6 h run takes about 45 s on a loaded 2-vCPU machine).
CASE_TIMEOUT_S = 1800.0
#: Keys of the command's JSON that vary from run to run, left out of the hash.
_UNSTABLE = ("wall_time_s",)


def scenario_file(root: Path, case: str, tmp: Path) -> Path:
    """The scenario of ``case`` in checkout ``root``: the bundled file, or a file in ``tmp`` that
    extends it with the case's duration."""
    name, duration = CASES[case]
    bundled = root / "src" / "sappc" / "data" / "scenarios" / f"{name}.yaml"
    if duration is None:
        return bundled
    path = tmp / f"{case}.yaml"
    path.write_text(f"extends: {bundled}\nname: {name}_{case}\nduration_s: {duration!r}\n")
    return path


def _digest(report: dict[str, Any]) -> str:
    """sha256 of the report's metrics, per-orbit table and controller summary (stable keys only)."""
    metrics = {k: v for k, v in report.get("metrics", {}).items() if k not in _UNSTABLE}
    doc = {"metrics": metrics, "per_orbit": report.get("per_orbit"), "controller_summary": report.get("controller_summary")}
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:16]


def run_case(root: Path, case: str, tmp: Path, timeout_s: float = CASE_TIMEOUT_S) -> dict[str, Any]:
    """One ``sappc simulate`` of ``case`` in checkout ``root``: peak RSS [MB], CPU and wall [s], the
    JSON's hash and its ``steady_max_abs_qev``."""
    out = tmp / f"{case}.json"
    argv = [sys.executable, "-m", "sappc", "simulate", str(scenario_file(root, case, tmp)), "--json", str(out)]
    if case in FIGURE_CASES:
        argv += ["--out", tempfile.mkdtemp(prefix=f"{case}_", dir=tmp)]
    wall, usage = paired.run_with_usage(argv, {"PYTHONPATH": str(root / "src")}, tmp, timeout_s)
    report = json.loads(out.read_text())
    out.unlink()
    return {"peak_rss_mb": usage.ru_maxrss / 1024.0, "user_s": usage.ru_utime, "sys_s": usage.ru_stime,
            "cpu_s": usage.ru_utime + usage.ru_stime, "wall_s": wall, "digest": _digest(report),
            "steady_max_abs_qev": report["metrics"]["steady_max_abs_qev"], "samples": report["controller_summary"]["samples"]}


def _median(runs: list[dict[str, Any]], key: str) -> float:
    return float(statistics.median(r[key] for r in runs))


def measure(roots: dict[str, Path], cases: list[str], repeats: int) -> dict[str, Any]:
    """Every case on every side, alternately, after one warm-up run of each."""
    results: dict[str, dict[str, list[dict[str, Any]]]] = {c: {s: [] for s in roots} for c in cases}
    with tempfile.TemporaryDirectory(prefix="sappc-mem-") as tmp_s:
        tmp = Path(tmp_s)
        for case in cases:
            for i in range(repeats + 1):  # run 0: the warm-up
                sides = list(roots) if i % 2 == 0 else list(reversed(roots))
                for side in sides:
                    r = run_case(roots[side], case, tmp)
                    print(f"{case} {side} {'warm-up' if i == 0 else i}: {r['peak_rss_mb']:.0f} MB, cpu {r['cpu_s']:.1f} s, wall {r['wall_s']:.1f} s",
                          file=sys.stderr, flush=True)
                    if i > 0:
                        results[case][side].append(r)
    doc: dict[str, Any] = {}
    for case, by_side in results.items():
        doc[case] = {}
        for side, runs in by_side.items():
            doc[case][side] = {
                "scenario": CASES[case][0], "duration_s": CASES[case][1], "samples": runs[0]["samples"],
                **{f"{k}_median": _median(runs, k) for k in ("peak_rss_mb", "cpu_s", "user_s", "sys_s", "wall_s")},
                "peak_rss_bytes_per_sample": _median(runs, "peak_rss_mb") * 2**20 / runs[0]["samples"],
                "digests": sorted({r["digest"] for r in runs}), "steady_max_abs_qev": runs[0]["steady_max_abs_qev"], "runs": runs,
            }
        if len(by_side) == 2:
            cand, base = by_side["candidate"], by_side["baseline"]
            doc[case]["ratio_candidate_over_baseline"] = {
                k: statistics.median(c[k] / b[k] for c, b in zip(cand, base)) for k in ("peak_rss_mb", "cpu_s", "wall_s")}
            doc[case]["same_numbers"] = doc[case]["candidate"]["digests"] == doc[case]["baseline"]["digests"]
    return doc


# ---------------------------------------------------------------------------------- breakdown


def breakdown(root: Path, case: str) -> dict[str, Any]:
    """:func:`_profile` of ``case`` in a child process with checkout ``root``."""
    with tempfile.TemporaryDirectory(prefix="sappc-mem-") as tmp_s:
        scenario = scenario_file(root, case, Path(tmp_s))
        code = f"import sys; sys.path.insert(0, {str(Path(__file__).resolve().parent)!r}); import bench_memory; bench_memory._profile({str(scenario)!r})"
        env = {**os.environ, "PYTHONPATH": str(root / "src")}
        proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=CASE_TIMEOUT_S)
        if proc.returncode != 0:
            raise SystemExit(f"the breakdown of {case} failed:\n{proc.stderr[-3000:]}")
        doc: dict[str, Any] = json.loads(proc.stdout.strip().splitlines()[-1])
        return doc


def _profile(scenario_file: str) -> None:
    """``simulate(scenario)`` under ``tracemalloc``: the arrays of the loop's inputs and record, and
    the peak traced memory of each phase (nested phases' peaks count in their parents'); one JSON
    line on stdout."""
    import functools
    import resource
    import tracemalloc

    import numpy as np

    from sappc.evaluation import metrics as mt
    from sappc.offline import compiled_loop as cl
    from sappc.offline import simulate as sim
    from sappc.scenario import load_scenario

    arrays: dict[str, dict[str, Any]] = {}

    def walk(prefix: str, obj: Any) -> None:
        if isinstance(obj, np.ndarray):
            if obj.nbytes >= 1 << 20:
                arrays[prefix] = {"shape": list(obj.shape), "dtype": str(obj.dtype), "mb": obj.nbytes / 2**20}
        elif hasattr(obj, "_fields"):
            for f in obj._fields:
                walk(f"{prefix}.{f}", getattr(obj, f))

    phases: list[dict[str, Any]] = []
    stack: list[list[float]] = []  # per open phase: [the largest traced memory seen in it]

    def wrap(owner: Any, name: str, label: str, after: Any = None) -> None:
        f = getattr(owner, name, None)
        if f is None:
            return

        @functools.wraps(f)
        def timed(*args: Any, **kwargs: Any) -> Any:
            before, peak = tracemalloc.get_traced_memory()
            if stack:
                stack[-1][0] = max(stack[-1][0], peak)
            tracemalloc.reset_peak()
            stack.append([before])
            entry = {"phase": label, "depth": len(stack) - 1, "before_mb": before / 2**20}
            phases.append(entry)
            try:
                result = f(*args, **kwargs)
            finally:
                after_b, peak = tracemalloc.get_traced_memory()
                top = max(stack.pop()[0], peak)
                if stack:
                    stack[-1][0] = max(stack[-1][0], top)
                tracemalloc.reset_peak()
                entry.update(peak_mb=top / 2**20, after_mb=after_b / 2**20)
            if after is not None:
                after(result)
            return result

        setattr(owner, name, timed)

    wrap(cl, "prepare", "prepare: the loop's inputs", lambda inp: [walk(f"inputs.{m}", getattr(inp, m)) for m in ("grid",) + inp.MODELS])
    wrap(cl, "run_batch", "run_batch: the compiled loop and its record", lambda run: walk("record", run.record))
    wrap(cl.CompiledRun, "history", "CompiledRun.history")
    wrap(sim, "run_scenario", "run_scenario")
    for name in ("add_history", "_update", "update_wheels", "update_estimate", "_update_orbits", "orbit_metrics"):
        wrap(mt.MetricsAccumulator, name, f"MetricsAccumulator.{name}")
    for name in ("attitude_errors", "nees"):
        wrap(mt, name, name)
    scenario = load_scenario(scenario_file)
    tracemalloc.start()
    result = sim.simulate(scenario)
    json.dumps(result.report())  # what --json writes
    current, _ = tracemalloc.get_traced_memory()
    overall = max([p["peak_mb"] for p in phases if "peak_mb" in p] + [0.0])
    # one line per phase (its calls merged, the blocks of the metrics: their largest peak, their count), in order of first call
    merged: dict[tuple[int, str], dict[str, Any]] = {}
    for p in phases:
        m = merged.setdefault((p["depth"], p["phase"]), {**p, "calls": 0})
        m["calls"] += 1
        m["peak_mb"] = max(m["peak_mb"], p["peak_mb"])
        m["after_mb"] = p["after_mb"]
    print(json.dumps({"arrays": arrays, "arrays_total_mb": sum(a["mb"] for a in arrays.values()), "phases": list(merged.values()),
                      "traced_peak_mb": overall, "traced_at_end_mb": current / 2**20,
                      "ru_maxrss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default=",".join(DEFAULT_CASES), help=f"comma-separated, among {', '.join(CASES)}")
    parser.add_argument("--repeats", type=int, default=3, help="counted runs of each case and side (default 3)")
    parser.add_argument("--baseline", type=Path, help="a checkout to pair against (run with this checkout's .venv)")
    parser.add_argument("--baseline-commit", default="", help="the baseline's commit, when DIR is an export (no .git)")
    parser.add_argument("--candidate-commit", default="", help="this checkout's commit, when it is an export (no .git)")
    parser.add_argument("--breakdown", metavar="CASE", choices=sorted(CASES), help="where the memory of CASE goes (tracemalloc)")
    args = parser.parse_args()
    roots = {"candidate": ROOT} if args.baseline is None else {"baseline": args.baseline.resolve(), "candidate": ROOT}
    head: dict[str, Any] = {
        "issue": 47, "date": time.strftime("%Y-%m-%d"), "machine": paired.machine(),
        "memory_total_gb": os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30,
        "load_average_1min_before": os.getloadavg()[0],
        **{side: {"root": str(root), "commit": paired.commit(root) if (root / ".git").exists()
                  else f"export of {(args.baseline_commit if side == 'baseline' else args.candidate_commit) or '?'}"}
           for side, root in roots.items()},
    }
    if args.breakdown:
        body: dict[str, Any] = {"breakdown": args.breakdown, **{side: breakdown(root, args.breakdown) for side, root in roots.items()}}
    else:
        cases = [c.strip() for c in args.cases.split(",") if c.strip()]
        unknown = [c for c in cases if c not in CASES]
        if unknown:
            parser.error(f"unknown case(s) {unknown}; the cases are {', '.join(CASES)}")
        body = {"command": "sappc simulate SCENARIO --json FILE", "repeats": args.repeats, "cases": measure(roots, cases, max(1, args.repeats))}
    print(json.dumps({**head, **body, "load_average_1min_after": os.getloadavg()[0]}, indent=2))


if __name__ == "__main__":
    main()

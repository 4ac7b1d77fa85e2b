"""Real-time runs of a scenario through ``sappc run --realtime``, repeated, in both layouts: the
spread of what a run on the wall clock gives (issue 38's "Done means").

Each run is the command a user types (``sappc run SCENARIO --realtime [--compose] --json F``);
the JSON collects, per run: the exit status, the samples (frames) recorded, whether every
topic's count matches, the steady error, settling and overshoot, the frames the machine made
deviate from lockstep (missed plant ticks, stale torques and disturbances, the first deviating
sample), the frames that lacked an input of their own stamp, the plant's frame timer (period
error |interval - dt| p50, p99, max; missed ticks; the state's delay after its frame's start),
the controller's latency, and the load average before and after.  ``--busy N`` runs N CPU-bound
processes beside the runs; ``--rt-priority N`` runs the nodes under SCHED_FIFO (``sappc run
--rt-priority``).  Then, per layout, the minimum, median and maximum of the steady error and the counts of runs that met the criteria (exit 0, counts match, every frame recorded,
steady max |q_ev| <= ``--bound``).  The machine is noted.

    python benchmarks/bench_realtime.py paper_tracking --runs 10 [--layouts five,composed] [--busy N] [--rt-priority N] [--out FILE]
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

sys.path.insert(0, str(Path(__file__).resolve().parent))
from paired import commit, machine  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
#: The paper's steady-error requirement [rad] (lockstep gives 3.53e-5 on experiment 1).
PAPER_STEADY_BOUND = 4e-5
LAYOUTS = {"five": [], "composed": ["--compose"]}


def one_run(scenario: str, layout: str, scratch: Path, rt_priority: int | None) -> dict[str, object]:
    out, report = scratch / "run", scratch / "m.json"
    load_before = os.getloadavg()[0]
    start = time.monotonic()
    priority = ["--rt-priority", str(rt_priority)] if rt_priority is not None else []
    proc = subprocess.run([sys.executable, "-m", "sappc", "run", scenario, "--realtime", *LAYOUTS[layout], *priority, "--out", str(out),
                           "--json", str(report)], capture_output=True, text=True, cwd=ROOT)
    wall = time.monotonic() - start
    row: dict[str, object] = {"layout": layout, "exit": proc.returncode, "wall_s": round(wall, 2), "load_before": load_before,
                              "load_after": os.getloadavg()[0]}
    if not report.exists():
        row["error"] = (proc.stdout + proc.stderr)[-2000:]
        return row
    r = json.loads(report.read_text())
    rt = r.get("realtime", {})
    m = r["metrics"]
    row.update(counts_match=r["published"] == r["recorded"], frames=rt.get("frames"), samples=r["recorded"].get("/state/attitude"),
               steady_max_abs_qev=m["steady_max_abs_qev"], settling_time_s=m["settling_time_s"], overshoot=m["overshoot"],
               missed_frames=rt.get("missed_frames"), stale_torque_frames=rt.get("stale_torque_frames"),
               stale_disturbance_frames=rt.get("stale_disturbance_frames"), first_deviating_sample=rt.get("first_deviating_sample"),
               frames_lacking_own_stamp=rt.get("frames_lacking_own_stamp"), held_reference_steps=rt.get("held_reference_steps"),
               controller_latency=rt.get("controller_latency"),
               plant_timer={k: rt.get(k) for k in ("ticks", "period_error_p50_ms", "period_error_p99_ms", "period_error_max_ms", "missed_ticks")},
               state_delay=rt.get("state_delay"))
    # issue 46's checks: the verdict line's reasons, the estimator's health on the wall clock (no NaN "no data" estimate
    # sent, gate rejections, tracker epochs dated in the future or late), and the summary's counts against the nodes' own
    logs = out / "logs"
    est = json.loads((logs / "estimator_timing.json").read_text()) if (logs / "estimator_timing.json").exists() else None
    ctrl = json.loads((logs / "controller_timing.json").read_text()) if (logs / "controller_timing.json").exists() else {}
    summary = r.get("controller_summary", {})
    row.update(failed_requirements=r.get("failed_requirements"), degraded=r.get("degraded"),
               rejected_inputs=summary.get("rejected_inputs"), rejected_inputs_node=ctrl.get("rejected_inputs"),
               no_data_inputs_controller=ctrl.get("no_data_inputs"))
    if est is not None:
        row.update(estimator_gate_rejections=est.get("gate_rejections"), estimator_no_data_samples=est.get("no_data_samples"),
                   future_tracker_epochs=est.get("future_tracker_epochs"), late_tracker_samples=est.get("late_tracker_samples"),
                   estimator_updates=est.get("updates"))
    return row


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scenario", help="a bundled scenario's name or a scenario file")
    parser.add_argument("--runs", type=int, default=10, help="runs per layout (default 10)")
    parser.add_argument("--layouts", default="five,composed", help="comma-separated among: five, composed")
    parser.add_argument("--bound", type=float, default=PAPER_STEADY_BOUND, help="steady max |q_ev| criterion [rad] (default 4e-5)")
    parser.add_argument("--busy", type=int, default=0, help="CPU-bound processes beside the runs (default 0)")
    parser.add_argument("--rt-priority", type=int, default=None, help="sappc run --rt-priority N: the nodes under SCHED_FIFO (default: not)")
    parser.add_argument("--out", help="also write the JSON to this file")
    args = parser.parse_args()
    layouts = [x.strip() for x in args.layouts.split(",") if x.strip()]
    unknown = [x for x in layouts if x not in LAYOUTS]
    if unknown:
        parser.error(f"--layouts: unknown {unknown}; choose among {list(LAYOUTS)}")
    rows: list[dict[str, object]] = []
    busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(args.busy)]
    try:
        for i in range(args.runs):
            for layout in layouts:  # alternated, so a drift of the machine's load falls on both
                with tempfile.TemporaryDirectory(prefix="sappc-rt-") as tmp:
                    row = one_run(args.scenario, layout, Path(tmp), args.rt_priority)
                rows.append({"run": i, **row})
                print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
    finally:
        for b in busy:
            b.kill()
            b.wait()
    summary: dict[str, object] = {}
    for layout in layouts:
        mine = [r for r in rows if r["layout"] == layout]
        steady = [float(r["steady_max_abs_qev"]) for r in mine if isinstance(r.get("steady_max_abs_qev"), float)]
        met = [r for r in mine if r["exit"] == 0 and r.get("counts_match") and r.get("samples") == r.get("frames")
               and isinstance(r.get("steady_max_abs_qev"), float) and float(r["steady_max_abs_qev"]) <= args.bound]  # type: ignore[arg-type]
        summary[layout] = {"runs": len(mine), "met": len(met), "steady_max_abs_qev": {"min": min(steady), "median": statistics.median(steady),
                                                                                      "max": max(steady)} if steady else None,
                           "runs_without_deviation": sum(r.get("first_deviating_sample") is None for r in mine),
                           "missed_frames_max": max((int(r.get("missed_frames") or 0) for r in mine), default=0),  # type: ignore[call-overload]
                           "stale_torque_frames_max": max((int(r.get("stale_torque_frames") or 0) for r in mine), default=0),  # type: ignore[call-overload]
                           # issue 46: "no data" estimates, gate rejections, bad tracker epochs; the summary's counts the nodes' own
                           "estimator_no_data_samples_max": max((int(r.get("estimator_no_data_samples") or 0) for r in mine), default=0),  # type: ignore[call-overload]
                           "estimator_gate_rejections_max": max((int(r.get("estimator_gate_rejections") or 0) for r in mine), default=0),  # type: ignore[call-overload]
                           "future_or_late_tracker_samples_max": max((int(r.get("future_tracker_epochs") or 0) + int(r.get("late_tracker_samples") or 0)  # type: ignore[call-overload]
                                                                       for r in mine), default=0),
                           "runs_whose_counts_differ_from_the_nodes": sum(r.get("rejected_inputs") != r.get("rejected_inputs_node") for r in mine)}
    result = {"scenario": args.scenario, "commit": commit(ROOT), "machine": machine(), "busy_processes": args.busy, "rt_priority": args.rt_priority, "bound": args.bound,
              "summary": summary, "rows": rows}
    text = json.dumps(result, indent=1)
    print(text)
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

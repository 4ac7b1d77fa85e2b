"""The fault matrix (issue 14): every fault kind x every controller, offline and through the graph.

Each case is experiment 1 (``config/scenarios/paper_tracking.yaml``, 60 s) with one fault
acting from t = 30 s (a window of 0.5 s, or 5 s for a delay, or to the end for a lasting fault),
or the sudden torque pulse of experiment 3 at the same time.  For every case it prints, as JSON:

* offline (``sappc simulate``'s path): the steady max |q_ev| over the last 20 s (t >= 40 s),
  whether the error left its band after the fault and when it returned, and what the controller
  answered (commanded, watchdog zero, resumed zero, no answer, refused);
* with ``--graph``: the same case through ``sappc run`` (lockstep, five processes), and the
  largest difference of any metric from the offline run (the issue's bound: 1e-9).

    python benchmarks/bench_fault_matrix.py [--graph] [--controllers sappc,trappc,blfppc] [--kinds K,...] > matrix.json
    python benchmarks/bench_fault_matrix.py --table matrix.json     # the table of docs/how-to/faults.md (markdown)

The graph half takes ~15 s a case plus 2 s of wall time per sample the controller does not
answer (the plant's ``lockstep_timeout_s``: 10 per dropout at the default ``stale_timeout_s``).
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

FAULT_START_S = 30.0
#: Steady window of the matrix: the last 20 s of the 60 s run (the issue's "last 20 s").
LAST_S = 40.0

#: One case per fault kind (and the torque pulse of experiment 3), acting from FAULT_START_S.
CASES: dict[str, dict[str, Any]] = {
    "none": {},  # the baseline: experiment 1 as it is
    "sensor_dropout": {"faults": [{"kind": "sensor_dropout", "start_s": 30.0, "end_s": 30.5}]},
    "reference_dropout": {"faults": [{"kind": "reference_dropout", "start_s": 30.0, "end_s": 30.5}]},
    "actuator_dropout": {"faults": [{"kind": "actuator_dropout", "start_s": 30.0, "end_s": 30.5}]},
    "sensor_delay_3": {"faults": [{"kind": "delay", "path": "sensor", "samples": 3, "start_s": 30.0, "end_s": 35.0}]},
    "actuator_delay_3": {"faults": [{"kind": "delay", "path": "actuator", "samples": 3, "start_s": 30.0, "end_s": 35.0}]},
    "sensor_freeze": {"faults": [{"kind": "sensor_freeze", "start_s": 30.0, "end_s": 30.5}]},
    "actuator_stuck": {"faults": [{"kind": "actuator_stuck", "start_s": 30.0, "end_s": 30.5}]},
    "actuator_effectiveness_50pc": {"faults": [{"kind": "actuator_effectiveness", "effectiveness": [0.5, 0.5, 0.5], "start_s": 30.0}]},
    "actuator_bias_20mNm": {"faults": [{"kind": "actuator_bias", "bias_Nm": [0.02, -0.02, 0.02], "start_s": 30.0}]},
    "sensor_bias": {"faults": [{"kind": "sensor_bias", "attitude_bias_rad": [1e-5, 0.0, 0.0], "rate_bias_rad_s": [1e-6, 0.0, 0.0],
                                "start_s": 30.0}]},
    "sensor_noise": {"faults": [{"kind": "sensor_noise", "attitude_std_rad": 1e-5, "rate_std_rad_s": 1e-6, "seed": 3, "start_s": 30.0}]},
    "torque_pulse_1Nm": {"disturbances": [{"kind": "pulse", "start_s": 30.0, "duration_s": 0.5, "torque_Nm": [1.0, 1.0, 1.0]}]},
}


def case_scenario(kind: str, controller: str) -> dict[str, Any]:
    """Experiment 1 with the case's fault (a scenario mapping)."""
    raw = yaml.safe_load((ROOT / "config" / "scenarios" / "paper_tracking.yaml").read_text())
    raw = copy.deepcopy(raw)
    case = CASES[kind]
    raw["name"] = f"fault_matrix_{kind}"
    raw["controller"] = controller
    raw["faults"] = case.get("faults", [])
    raw["name"] = f"fault_matrix_{kind}"
    raw["disturbances"] = list(raw.get("disturbances") or []) + case.get("disturbances", [])
    return raw


def last_window_max(history: Any) -> float:
    t = np.asarray(history.t)
    return float(np.abs(history.q_ev[t >= LAST_S - 1e-9]).max())


def offline(raw: dict[str, Any]) -> dict[str, Any]:
    from sappc.offline.simulate import simulate
    from sappc.scenario import scenario_from_mapping

    result = simulate(scenario_from_mapping(raw))
    m = result.metrics
    return {"last20_max_abs_qev": last_window_max(result.history), "left_band_after_fault": m["left_constraint_after_fault"],
            "returned_at_s": m["returned_at_s"], "returned_to_band": m["returned_to_constraint"], "finite": m["finite"],
            "controller": result.controller_summary, "metrics": {k: v for k, v in m.items() if k != "wall_time_s"}}


def graph(raw: dict[str, Any]) -> dict[str, Any]:
    from sappc.bag.read import bag_run, read_bag

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "scenario.yaml"
        path.write_text(yaml.safe_dump(raw, sort_keys=False))
        env = {**os.environ, "PYTHONPATH": str(ROOT / "src") + os.pathsep + os.environ.get("PYTHONPATH", "")}
        t0 = time.perf_counter()
        proc = subprocess.run([sys.executable, "-m", "sappc", "run", str(path), "--out", str(Path(tmp) / "run"), "--json",
                               str(Path(tmp) / "m.json")], capture_output=True, text=True, cwd=ROOT, env=env)
        wall = time.perf_counter() - t0
        if not (Path(tmp) / "m.json").exists():
            raise RuntimeError(proc.stdout + proc.stderr)
        report = json.loads((Path(tmp) / "m.json").read_text())
        run = bag_run(read_bag(Path(tmp) / "run" / "bag"))
        plant = json.loads((Path(tmp) / "run" / "logs" / "timing.json").read_text())
        return {"exit_status": proc.returncode, "wall_s": wall, "last20_max_abs_qev": last_window_max(run.history),
                "controller": report["controller_summary"], "plant_missed_torque": plant["missed"]["torque"], "metrics": report["metrics"]}


def metric_difference(a: dict[str, Any], b: dict[str, Any]) -> float:
    """Largest |a - b| over the numeric metrics (inf when a non-numeric one differs)."""
    worst = 0.0
    for key, value in a.items():
        if key in ("wall_time_s", "startup_s"):
            continue
        other = b.get(key)
        if isinstance(value, float) and isinstance(other, float):
            worst = max(worst, abs(value - other))
        elif value != other:
            return float("inf")
    return worst


def table(path: str) -> str:
    """The matrix of a JSON output as a markdown table: per case and controller, the last-20-s
    max |q_ev| offline, back in the band at the end, the answers not commanded, and (with the
    graph) the largest metric difference graph - offline and whether the answers agree."""
    data = json.loads(Path(path).read_text())
    rows = ["| fault (from 30 s) | controller | last 20 s max abs q_ev | in band at the end | held / zero answers | graph - offline (max metric diff) |",
            "| --- | --- | --- | --- | --- | --- |"]
    for r in data["cases"]:
        o, g = r["offline"], r.get("graph")
        c = o["controller"]
        agree = "-" if g is None else (f"{g['max_metric_difference']:.1e}" + ("" if g["controller"]["held"] == c["held"] and
                                                                                g["controller"]["watchdog_zero"] == c["watchdog_zero"] else ", answers differ"))
        rows.append(f"| {r['case']} | {r['controller']} | {o['last20_max_abs_qev']:.3g} | {'-' if o['returned_to_band'] is None else 'yes' if o['returned_to_band'] else 'no'} | "
                    f"{c['held']} / {c['watchdog_zero']} | {agree} |")
    return "\n".join(rows)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--graph", action="store_true", help="also run every case through the ROS 2 graph (minutes)")
    ap.add_argument("--controllers", default="sappc,trappc,blfppc")
    ap.add_argument("--kinds", default=",".join(CASES))
    ap.add_argument("--table", metavar="JSON", help="print the markdown table of an earlier output and exit")
    args = ap.parse_args()
    if args.table:
        print(table(args.table))
        return 0
    rows = []
    for kind in args.kinds.split(","):
        for controller in args.controllers.split(","):
            raw = case_scenario(kind, controller)
            row: dict[str, Any] = {"case": kind, "controller": controller, "offline": offline(raw)}
            if args.graph:
                g = graph(raw)
                g["max_metric_difference"] = metric_difference(row["offline"]["metrics"], g["metrics"])
                row["graph"] = g
            for part in ("offline", "graph"):
                row.get(part, {}).pop("metrics", None)
            rows.append(row)
            print(json.dumps(row), file=sys.stderr, flush=True)
    print(json.dumps({"machine": {"platform": platform.platform(), "cpus": os.cpu_count(), "python": platform.python_version()},
                      "fault_start_s": FAULT_START_S, "last_window_from_s": LAST_S, "cases": rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())

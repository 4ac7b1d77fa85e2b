"""A flight with modes through the graph against the offline run (issue 49): bit for bit, sample by sample.

Runs ``sappc run SCENARIO`` in lockstep (``--compose`` for one process), or takes the run directory
of one already made (``--run-dir``), reads its bag back and compares every sample with
``sappc.offline.compiled_loop.simulate_compiled`` of the same scenario: the true state, the error
quaternion, the controller's torque and command and its funnel rows, the wheels' speeds and motor
torques, the estimate, the true and measured fields and the rods' commands, each sample's mode and
the reason of its transition.  Prints JSON: the run's wall time and exit status (when it ran it),
the samples, each quantity equal or not (and where it first differs), the machine.

    .venv/bin/python benchmarks/bench_modes_graph.py flight_separation --compose --out /tmp/sep-composed
    .venv/bin/python benchmarks/bench_modes_graph.py flight_separation --run-dir /tmp/sep-composed

The whole separation (5700 s, 570,001 samples) takes 20 to 60 min of graph and 5 to 20 min of
reading back on a 2-core machine (docs/design/modes.md, "The modes on the graph").
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from sappc.bag.read import bag_run, read_bag
from sappc.files import scenario_path
from sappc.offline.compiled_loop import simulate_compiled
from sappc.scenario import load_scenario

#: The per-sample quantities compared (``History`` fields), then the orbit's columns the bag holds
#: (the true and measured fields, the rods' commands: the environment's torque is not published).
FIELDS = ("q_BN", "omega_BN_B", "q_BR", "torque_B", "torque_cmd_B", "rho", "wheel_speed_rad_s", "wheel_torque_Nm", "mode", "mode_reason")
ORBIT_COLUMNS = {"fields": slice(0, 6), "rods": slice(9, None)}


def _first_difference(a: np.ndarray, b: np.ndarray) -> int | None:
    """The first sample where ``a`` and ``b`` differ (NaN equals NaN), ``None`` when equal."""
    if a.shape != b.shape:
        return 0
    same = (a == b) | (np.isnan(a) & np.isnan(b)) if a.dtype.kind == "f" else a == b
    bad = np.flatnonzero(~same.reshape(a.shape[0], -1).all(axis=1))
    return int(bad[0]) if bad.size else None


def compare(scenario: Any, run_dir: Path) -> dict[str, Any]:
    """Every quantity of the bag in ``run_dir`` against the offline run: ``{name: first differing sample or None}``."""
    off = simulate_compiled(scenario).history()
    h = bag_run(read_bag(run_dir / "bag")).history
    out: dict[str, Any] = {name: _first_difference(np.asarray(getattr(h, name)), np.asarray(getattr(off, name))) for name in FIELDS}
    assert h.orbit is not None and off.orbit is not None and h.estimate is not None and off.estimate is not None
    out.update({name: _first_difference(h.orbit[:, 0, cols], off.orbit[:, 0, cols]) for name, cols in ORBIT_COLUMNS.items()})
    out["estimate_q_BN"] = _first_difference(h.estimate.q_BN, off.estimate.q_BN)
    out["samples"] = int(h.q_BN.shape[0])
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scenario", help="a scenario with modes (a bundled name or a file)")
    parser.add_argument("--compose", action="store_true", help="run the nodes in one process (sappc run --compose)")
    parser.add_argument("--out", type=Path, help="the run directory to make (sappc run --out)")
    parser.add_argument("--run-dir", type=Path, help="compare this run directory instead of running")
    a = parser.parse_args(argv)
    scenario = load_scenario(scenario_path(a.scenario))
    result: dict[str, Any] = {"scenario": scenario.name, "machine": {"cpu": platform.processor() or platform.machine(), "python": platform.python_version()}}
    run_dir = a.run_dir
    if run_dir is None:
        if a.out is None:
            parser.error("give --out (a new run) or --run-dir (an existing one)")
        start = time.monotonic()
        proc = subprocess.run([sys.executable, "-m", "sappc", "run", a.scenario, "--out", str(a.out), "--json", str(a.out) + ".json",
                               *(["--compose"] if a.compose else [])], capture_output=True, text=True)
        result.update(layout="composed" if a.compose else "processes", exit_status=proc.returncode, wall_s=round(time.monotonic() - start, 1))
        run_dir = a.out
    start = time.monotonic()
    differences = compare(scenario, run_dir)
    result["compare_wall_s"] = round(time.monotonic() - start, 1)
    result["samples"] = differences.pop("samples")
    result["first_difference"] = differences
    result["bit_for_bit"] = all(v is None for v in differences.values())
    print(json.dumps(result, indent=1))
    return 0 if result["bit_for_bit"] else 1


if __name__ == "__main__":
    sys.exit(main())

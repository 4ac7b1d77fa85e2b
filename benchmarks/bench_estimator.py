"""Benchmarks of the estimator (issue 26): the MEKF kernel's step, and the flight scenario's
``sappc simulate`` process with the filter against the same process without it.

Prints one JSON document (medians of ``--repeats``, machine noted):

* ``kernel_step_us``: one :func:`sappc_estimator.core.mekf.mekf_step` inside a compiled loop over
  a recorded measurement sequence (the flight scenario's 6001 samples: a 10 Hz tracker held at
  100 Hz and a gyro), the time per step; target <= 5 us.  ``kernel_python_call_us``: the same step
  called from Python per sample (the node's call, with its dispatch).
* ``simulate_process_s``: ``python -m sappc simulate config/scenarios/paper_tracking_flight.yaml``
  as a whole process (imports, set-up, the run, the metrics; warm numba cache), against the same
  scenario with ``estimator: {kind: none}``, the two run alternately, pair by pair, ``--repeats``
  pairs; ``ratio`` = median(with) / median(without); target <= 1.3.

Usage: ``python benchmarks/bench_estimator.py [--repeats N]``.
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
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from gnc_common.compiled import jit  # noqa: E402
from sappc.offline.compiled_loop import prepare  # noqa: E402
from sappc.scenario import load_scenario  # noqa: E402
from sappc_estimator.core import mekf  # noqa: E402
from spacecraft_sim.core.sensors import S_BIAS0, measure  # noqa: E402

FLIGHT = ROOT / "config" / "scenarios" / "paper_tracking_flight.yaml"


@jit
def _steps(prm, t, y, out):  # type: ignore[no-untyped-def]
    st = np.zeros(mekf.N_EST_STATE)
    st[mekf.ES_NIS] = np.nan
    P = np.zeros((6, 6))
    work = np.zeros((mekf.N_EST_WORK, 6))
    for k in range(t.shape[0]):
        mekf.mekf_step(prm, t[k], y[k], st, P, work, out[k])


def _measurements() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The flight scenario's filter parameters, sample times and measurements of its true trajectory."""
    scenario = load_scenario(FLIGHT)
    assert scenario.estimator is not None and scenario.sensors is not None
    inp = prepare(scenario)
    from sappc.offline.compiled_loop import run_single

    run = run_single(inp, 0, 1)
    x = run.x[0]
    prm_s = scenario.sensors.params(scenario.control_period_s)
    draws = scenario.sensors.draws(x.shape[0])
    held, bias, y = np.zeros(4), prm_s[S_BIAS0:S_BIAS0 + 3].copy(), np.zeros((x.shape[0], 7))
    for k in range(x.shape[0]):
        measure(k, inp.t[k], x[k, :4], x[k, 4:], draws[k], prm_s, scenario.sensors.outages(), held, bias, y[k])
    return scenario.estimator.params(), inp.grid.t_ns / 1e9, y


def _kernel(repeats: int) -> dict[str, float]:
    prm, t, y = _measurements()
    out = np.zeros((t.size, mekf.N_EST_OUT))
    _steps(prm, t, y, out)  # compile / load
    per_step = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        _steps(prm, t, y, out)
        per_step.append((time.perf_counter() - t0) / t.size * 1e6)
    python_call = []
    st, P, work, o = mekf.new_state(), np.zeros((6, 6)), np.zeros((mekf.N_EST_WORK, 6)), np.zeros(mekf.N_EST_OUT)
    step = mekf.mekf_step
    for _ in range(repeats):
        st[:], P[:] = mekf.new_state(), 0.0
        t0 = time.perf_counter()
        for k in range(t.size):
            step(prm, float(t[k]), y[k], st, P, work, o)
        python_call.append((time.perf_counter() - t0) / t.size * 1e6)
    return {"kernel_step_us": statistics.median(per_step), "kernel_step_us_runs": per_step,
            "kernel_python_call_us": statistics.median(python_call), "samples": int(t.size)}


def _process(repeats: int) -> dict[str, object]:
    with tempfile.TemporaryDirectory() as tmp:
        without = Path(tmp) / "flight_without_estimator.yaml"
        without.write_text(f"extends: {FLIGHT}\nname: paper_tracking_flight_no_estimator\nestimator: {{kind: none}}\n")
        cmd = [sys.executable, "-m", "sappc", "simulate"]
        env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
        for path in (FLIGHT, without):  # warm the cache and the OS's file cache
            subprocess.run([*cmd, str(path)], check=True, capture_output=True, env=env, cwd=ROOT)
        times: dict[str, list[float]] = {"with_estimator": [], "without_estimator": []}
        for _ in range(repeats):
            for name, path in (("with_estimator", FLIGHT), ("without_estimator", without)):
                t0 = time.perf_counter()
                subprocess.run([*cmd, str(path)], check=True, capture_output=True, env=env, cwd=ROOT)
                times[name].append(time.perf_counter() - t0)
    med = {k: statistics.median(v) for k, v in times.items()}
    return {"simulate_process_s": med, "runs_s": times, "ratio": med["with_estimator"] / med["without_estimator"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    result = {
        "machine": {"platform": platform.platform(), "processor": platform.processor() or platform.machine(),
                    "cpu_count": os.cpu_count(), "python": platform.python_version()},
        "date": time.strftime("%Y-%m-%d"),
        "repeats": args.repeats,
        **_kernel(args.repeats),
        **_process(args.repeats),
        "targets": {"kernel_step_us": 5.0, "ratio": 1.3},
    }
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()

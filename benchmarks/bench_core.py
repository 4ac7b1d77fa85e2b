"""Benchmarks of the numerical cores (issue: numerical core, "Done means").

Prints one JSON document:

* ``experiment1_offline_wall_s``: `sappc simulate` of experiment 1 (60 s simulated, 100 Hz
  control, SAPPC, RK4 plant, full history), closed loop only (target <= 0.5 s).
* ``sappc_step_single_us``: one SAPPC control step for a single run, through the public,
  input-checking ``step`` (target <= 100 us), and through ``step_unchecked`` as the offline runner calls it.
* ``closed_loop_step_batch3000_ms``: one closed-loop step (SAPPC + RK4 plant + disturbance) for a
  batch of 3000 runs with random attitudes, compiled batch loop (target <= 3 ms).
* ``numpy_ufunc_call_us``: the cost of one tiny numpy call measured in the same run, as a
  machine baseline: the single-run figures are also given in units of it.

Each figure is the median of ``--repeats`` runs.  Usage: ``python benchmarks/bench_core.py [--repeats N]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from sappc.offline.compiled_loop import prepare, run_batch  # noqa: E402
from sappc.scenario import load_scenario  # noqa: E402
from sappc.offline.simulate import simulate  # noqa: E402
from sappc_controller.core.rpf import RPFParameters  # noqa: E402
from gnc_common.attitude import euler_to_quaternion  # noqa: E402

SCENARIO = ROOT / "config" / "scenarios" / "paper_tracking.yaml"


def _median_time(fn, repeats: int) -> float:  # type: ignore[no-untyped-def]
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def bench_experiment1(repeats: int) -> float:
    scenario = load_scenario(SCENARIO)
    simulate(scenario)  # warm-up (imports, caches)
    return statistics.median(simulate(scenario).metrics["wall_time_s"] for _ in range(repeats))


def bench_single_step(repeats: int, n_steps: int = 2000) -> tuple[float, float]:
    scenario = load_scenario(SCENARIO)
    ctrl = scenario.build_controller("sappc")
    ref = scenario.reference
    t = np.arange(n_steps) * 0.01
    w_d, wd_d = ref.omega_RN_R(t), ref.omegadot_RN_R(t)
    q_d = ref.sample(t).q_RN
    q = scenario.q_BN0
    w = np.array([0.01, -0.02, 0.005])

    def checked() -> None:
        ctrl.reset()
        for k in range(n_steps):
            ctrl.step(t[k], 0.01, q, w, q_d[k], w_d[k], wd_d[k])

    def unchecked() -> None:
        ctrl.reset()
        for k in range(n_steps):
            err = ctrl.error_state(q[None], w[None], q_d[k : k + 1], w_d[k : k + 1], wd_d[k : k + 1])
            ctrl.step_unchecked(t[k], 0.01, err)

    return _median_time(checked, repeats) / n_steps, _median_time(unchecked, repeats) / n_steps


def bench_batch(repeats: int, n_runs: int = 3000, n_steps: int = 100) -> float:
    """One closed-loop step of ``n_runs`` runs: the compiled batch loop (``prange`` over runs) over
    ``n_steps`` steps, per step (the numpy batch loop has left src/)."""
    scenario = load_scenario(SCENARIO)
    rng = np.random.default_rng(0)
    q0 = euler_to_quaternion(np.radians(rng.uniform(-85.0, 85.0, (n_runs, 3))), "ZYX")
    # Monte Carlo RPF of experiment 4: rho_e0 = |q_ev,i(0)|, l = 0.2
    config = dataclasses.replace(scenario.controller_config("sappc"), rpf=RPFParameters(None, 1e-6, 0.2, 20.0, 3e-5))
    short = dataclasses.replace(scenario, duration_s=n_steps * 0.01)
    inp = prepare(short, config=config, q_BN0=q0, on_infeasible="clamp")
    run_batch(inp)
    return _median_time(lambda: run_batch(inp), repeats) / inp.t.size


def bench_numpy_call(repeats: int) -> float:
    x = np.ones((1, 3))
    n = 100_000

    def run() -> None:
        for _ in range(n):
            np.multiply(x, x)

    return _median_time(run, repeats) / n


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    ufunc = bench_numpy_call(args.repeats)
    exp1 = bench_experiment1(args.repeats)
    step_checked, step_unchecked = bench_single_step(args.repeats)
    batch = bench_batch(args.repeats)
    result = {
        "machine": {
            "platform": platform.platform(),
            "processor": platform.processor() or platform.machine(),
            "cpu_count": os.cpu_count(),
            "python": platform.python_version(),
            "numpy": np.__version__,
        },
        "repeats": args.repeats,
        "statistic": "median",
        "numpy_ufunc_call_us": ufunc * 1e6,
        "experiment1_offline_wall_s": {"value": exp1, "target": 0.5, "meets_target": exp1 <= 0.5},
        "sappc_step_single_us": {
            "value": step_checked * 1e6,
            "unchecked_value": step_unchecked * 1e6,
            "in_numpy_calls": step_checked / ufunc,
            "target": 100.0,
            "meets_target": step_checked * 1e6 <= 100.0,
        },
        "closed_loop_step_batch3000_ms": {"value": batch * 1e3, "target": 3.0, "meets_target": batch * 1e3 <= 3.0},
    }
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()

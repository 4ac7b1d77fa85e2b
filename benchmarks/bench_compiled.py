"""Benchmarks of the compiled core (issue 13) against the numpy core, measured in the same process.

Prints one JSON document (median of ``--repeats``, machine noted):

* ``sappc_step_us``: one SAPPC step of the compiled kernel, called from Python with ready arrays
  (``python_call``, the node's path minus its input checks) and inside a compiled loop
  (``kernel_alone``); the numpy core's checked ``step`` in the same run for the ratio.
* ``experiment1_s``: experiment 1 (60 s at 100 Hz, SAPPC, full histories) in-process with a warm
  cache: the compiled loop alone, and with the set-up (reference by DOP853, RPF by Lambert W,
  tables); the numpy core's ``simulate`` closed loop for the ratio.
* ``montecarlo_3000x50s_s``: 3000 runs of 50 s with the paper's dispersion of initial attitudes
  (paper_montecarlo.yaml, seed 0, SAPPC, RPF clamped where infeasible, no histories): the
  compiled ``prange`` batch on all threads and on one thread, and the numpy batch loop
  (3000 runs per step) measured over ``--numpy-steps`` steps in the same run and scaled to the
  5001 steps of a run (``--numpy-full`` runs it whole once instead).

The compile cost is not measured here (the cache is warmed first); ``compile_or_load_s`` is the
time of the first call in this process (load from cache when warm).
Usage: ``python benchmarks/bench_compiled.py [--repeats N] [--numpy-steps N] [--numpy-full]``.
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

t_import = time.perf_counter()
import numba  # noqa: E402

from sappc.offline.compiled_loop import prepare, run_batch, run_single  # noqa: E402
from sappc_controller.core import kernels as K  # noqa: E402

t_import = time.perf_counter() - t_import

from gnc_common.compiled import jit  # noqa: E402
from sappc.montecarlo.campaign import campaign_config, draw_inputs  # noqa: E402
from sappc.offline.closed_loop import run_closed_loop, step_times  # noqa: E402
from sappc.offline.simulate import simulate  # noqa: E402
from sappc.scenario import load_scenario  # noqa: E402
from sappc_controller.core.sappc import SappcController  # noqa: E402
from spacecraft_sim.core.dynamics import RigidBody, initial_state  # noqa: E402

SCENARIOS = ROOT / "config" / "scenarios"


def _median(fn, repeats: int) -> float:  # type: ignore[no-untyped-def]
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


@jit
def _step_loop(n, t, q, w, q_d, w_d, wd_d, prm, coef, state, work, out):  # type: ignore[no-untyped-def]
    for k in range(n):
        K.controller_step(K.KIND_SAPPC, t[k], 0.01, q, w, q_d[k], w_d[k], wd_d[k], prm, coef, state, work, out)
    return out[K.O_TORQUE, 0]


def bench_step(repeats: int, n_steps: int = 2000) -> dict[str, float]:
    sc = load_scenario(SCENARIOS / "paper_tracking.yaml")
    cfg = sc.controller_config("sappc")
    t = np.arange(n_steps) * 0.01
    q_d = np.ascontiguousarray(sc.reference.sample(t).q_RN)
    w_d, wd_d = np.ascontiguousarray(sc.reference.omega_RN_R(t)), np.ascontiguousarray(sc.reference.omegadot_RN_R(t))
    q, w = sc.q_BN0.copy(), np.array([0.01, -0.02, 0.005])
    prm = K.pack_params(cfg)[0]
    coef = K.start_coef(cfg, K.error_quaternions(q_d[0], q[None]))[0][0]
    work, out = np.zeros((K.N_WORK, 4)), np.zeros((K.N_OUT, 4))
    step = K.controller_step

    def python_call() -> None:
        state = K.new_state(1)[0]
        for k in range(n_steps):
            step(0, t[k], 0.01, q, w, q_d[k], w_d[k], wd_d[k], prm, coef, state, work, out)

    def kernel_alone() -> None:
        _step_loop(n_steps, t, q, w, q_d, w_d, wd_d, prm, coef, K.new_state(1)[0], work, out)

    ctrl = sc.build_controller("sappc")

    def numpy_checked() -> None:
        ctrl.reset()
        for k in range(n_steps // 10):
            ctrl.step(t[k], 0.01, q, w, q_d[k], w_d[k], wd_d[k])

    python_call()
    kernel_alone()
    r = {
        "python_call_us": _median(python_call, repeats) / n_steps * 1e6,
        "kernel_alone_us": _median(kernel_alone, repeats) / n_steps * 1e6,
        "numpy_core_checked_step_us": _median(numpy_checked, repeats) / (n_steps // 10) * 1e6,
    }
    r["ratio_numpy_over_python_call"] = r["numpy_core_checked_step_us"] / r["python_call_us"]
    return r


def bench_experiment1(repeats: int) -> dict[str, float]:
    sc = load_scenario(SCENARIOS / "paper_tracking.yaml")
    inp = prepare(sc, "sappc")
    run_single(inp)
    loop = _median(lambda: run_single(inp), repeats)
    with_setup = _median(lambda: run_single(prepare(sc, "sappc")), repeats)
    simulate(sc)
    numpy_s = statistics.median(simulate(sc).metrics["wall_time_s"] for _ in range(max(1, min(repeats, 3))))
    return {"compiled_loop_s": loop, "compiled_with_setup_s": with_setup, "numpy_simulate_s": numpy_s,
            "ratio_numpy_over_loop": numpy_s / loop, "ratio_numpy_over_with_setup": numpy_s / with_setup,
            "target_s": 0.005, "meets_target": loop <= 0.005}


def bench_montecarlo(repeats: int, numpy_steps: int, numpy_full: bool, n_runs: int = 3000) -> dict[str, object]:
    sc = load_scenario(SCENARIOS / "paper_montecarlo.yaml")
    cfg = campaign_config(sc)
    t_draw = time.perf_counter()
    inputs = draw_inputs(cfg, 0, range(n_runs))
    t_draw = time.perf_counter() - t_draw
    t_prep = time.perf_counter()
    inp = prepare(sc, "sappc", q_BN0=inputs.q_BN0, on_infeasible="clamp")
    t_prep = time.perf_counter() - t_prep
    threads = numba.get_num_threads()
    run_batch(inp)  # warm
    all_threads = _median(lambda: run_batch(inp), repeats)
    numba.set_num_threads(1)
    try:
        one_thread = _median(lambda: run_batch(inp), repeats)
    finally:
        numba.set_num_threads(threads)
    steps = inp.t.size
    finite = bool(np.all(np.isfinite(run_batch(inp).x_final)))

    # the numpy batch loop, 3000 runs per step (the campaign's chunk), same inputs
    config = sc.controller_config("sappc")
    plant = RigidBody(sc.inertia_kg_m2)
    x0 = initial_state(inputs.q_BN0, np.zeros(3))
    n_np = steps if numpy_full else numpy_steps
    t_np = step_times((n_np - 1) * sc.control_period_s, sc.control_period_s)
    ref = sc.reference.sample(t_np)

    def numpy_batch() -> None:
        ctrl = SappcController(config, on_infeasible="clamp")
        with np.errstate(all="ignore"):
            run_closed_loop(plant, ctrl, ref, sc.disturbance, x0, sc.control_period_s, observer=lambda *a: None)

    numpy_per_step = _median(numpy_batch, 1 if numpy_full else max(1, min(repeats, 3))) / t_np.size
    numpy_total = numpy_per_step * steps
    return {
        "runs": n_runs, "steps_per_run": steps, "numba_threads": threads,
        "compiled_batch_s": all_threads, "compiled_batch_one_thread_s": one_thread,
        "compiled_us_per_run_step": all_threads / (n_runs * steps) * 1e6,
        "compiled_one_thread_us_per_run_step": one_thread / (n_runs * steps) * 1e6,
        "setup_draw_inputs_s": t_draw, "setup_prepare_s": t_prep,
        "numpy_batch_s": numpy_total, "numpy_batch_measured_steps": int(t_np.size),
        "numpy_batch_extrapolated": not numpy_full,
        "numpy_us_per_run_step": numpy_per_step / n_runs * 1e6,
        "ratio_numpy_over_compiled": numpy_total / all_threads,
        "ratio_numpy_over_compiled_one_thread": numpy_total / one_thread,
        "all_runs_finite": finite,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--numpy-steps", type=int, default=200)
    parser.add_argument("--numpy-full", action="store_true")
    args = parser.parse_args()
    t0 = time.perf_counter()
    sc = load_scenario(SCENARIOS / "paper_tracking.yaml")
    run_single(prepare(sc, "sappc"))
    first_call = time.perf_counter() - t0
    result = {
        "machine": {"platform": platform.platform(), "processor": platform.processor() or platform.machine(),
                    "cpu_count": os.cpu_count(), "python": platform.python_version(), "numpy": np.__version__,
                    "numba": numba.__version__, "threading_layer": None},
        "repeats": args.repeats,
        "statistic": "median",
        "import_kernels_s": t_import,
        "compile_or_load_s": first_call,
        "sappc_step_us": bench_step(args.repeats),
        "experiment1_s": bench_experiment1(args.repeats),
        "montecarlo_3000x50s_s": bench_montecarlo(args.repeats, args.numpy_steps, args.numpy_full),
    }
    try:
        result["machine"]["threading_layer"] = numba.threading_layer()
    except ValueError:
        pass
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()

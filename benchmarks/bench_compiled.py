"""Benchmarks of the compiled core (issue 13) against the numpy core, measured in the same process.

Prints one JSON document (median of ``--repeats``, machine noted):

* ``sappc_step_us``: one SAPPC step through the node's Python call, ``node_step_us``:
  :func:`sappc_controller.inputs.step_sample` -> ``AttitudeController.step`` with its input checks,
  on the states of experiment 1's compiled offline run (each repeat: reset, the run's first sample
  untimed, then the mean over the other samples; median of ``--repeats``; target <= 20 us); for the
  profile of where the time goes, the compiled step alone called from Python with ready arrays
  (``kernel_python_call_us``) and inside a compiled loop (``kernel_alone_us``).  The numpy core
  left ``src/`` (issue 13); its figure, 143-403 us, is in docs/design/performance-history.md, measured before.
* ``experiment1_s``: experiment 1 (60 s at 100 Hz, SAPPC, full histories) in-process with a warm
  cache: the compiled loop alone, with the set-up (reference by DOP853, RPF by Lambert W,
  tables), and ``simulate`` (loop, History and metrics); ratios against the numpy core's figures
  of issue 13 (the numpy runner has left src/).
* ``montecarlo_3000x50s_s``: 3000 runs of 50 s with the paper's dispersion of initial attitudes
  (paper_montecarlo.yaml, seed 0, SAPPC, RPF clamped where infeasible, no histories): the
  compiled ``prange`` batch on all threads and on one thread; the numpy batch figure of issue 13.
  Whole commands (campaign with figures, 100,000 runs, peak memory): ``bench_montecarlo.py``.

The compile cost is not measured here (the cache is warmed first); ``compile_or_load_s`` is the
time of the first call in this process (load from cache when warm).
Usage: ``python benchmarks/bench_compiled.py [--repeats N]``.
"""

from __future__ import annotations

import argparse
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
from sappc.offline.simulate import simulate  # noqa: E402
from sappc.scenario import load_scenario  # noqa: E402

SCENARIOS = ROOT / "config" / "scenarios"


def _median(fn, repeats: int) -> float:  # type: ignore[no-untyped-def]
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


@jit
def _step_loop(n, t, x, q_d, w_d, wd_d, prm, coef, state, work, out):  # type: ignore[no-untyped-def]
    for k in range(n):
        K.controller_step(K.KIND_SAPPC, t[k], 0.01, x[k, :4], x[k, 4:], q_d[k], w_d[k], wd_d[k], prm, coef, state, work, out)
    return out[K.O_TORQUE, 0]


def bench_step(repeats: int) -> dict[str, object]:
    from sappc_controller.inputs import ControlSample, step_sample

    sc = load_scenario(SCENARIOS / "paper_tracking.yaml")
    inp = prepare(sc, "sappc")
    run = run_single(inp, 0, stride=1)
    x = np.ascontiguousarray(run.x[0])
    n = inp.t.size
    # the node's samples: decoded messages are fresh float64 arrays (sappc_msgs_py.convert)
    samples = [ControlSample(k * 10_000_000, (k * 10_000_000,) * 5, (x[k, :4].copy(), x[k, 4:].copy(), inp.grid.ref_q[k].copy(),
                                                                      inp.grid.ref_w[k].copy(), inp.grid.ref_wd[k].copy())) for k in range(n)]
    ctrl = sc.build_controller("sappc")
    dt = inp.grid.dt

    def node_step() -> float:
        ctrl.reset()
        step_sample(ctrl, dt, samples[0])  # the run's start (RPF set-up), not a step's cost
        t0 = time.perf_counter()
        for s in samples[1:]:
            step_sample(ctrl, dt, s)
        return (time.perf_counter() - t0) / (n - 1)

    node_step()
    node = statistics.median(node_step() for _ in range(repeats))

    prm, coef = inp.controller.prm[0], inp.controller.coef[0]
    work, out = np.zeros((K.N_WORK, 4)), np.zeros((K.N_OUT, 4))
    q_d, w_d, wd_d, t = inp.grid.ref_q, inp.grid.ref_w, inp.grid.ref_wd, inp.t

    def python_call() -> None:
        state = K.new_state(1)[0]
        for k in range(n):
            K.controller_step(0, t[k], 0.01, x[k, :4], x[k, 4:], q_d[k], w_d[k], wd_d[k], prm, coef, state, work, out)

    def kernel_alone() -> None:
        _step_loop(n, t, x, q_d, w_d, wd_d, prm, coef, K.new_state(1)[0], work, out)

    python_call()
    kernel_alone()
    return {
        "node_step_us": node * 1e6,
        "samples": n - 1,
        "target_us": 20.0,
        "meets_target": node * 1e6 <= 20.0,
        "kernel_python_call_us": _median(python_call, repeats) / n * 1e6,
        "kernel_alone_us": _median(kernel_alone, repeats) / n * 1e6,
        "numpy_core_checked_step_us_before": "143-403 (docs/design/performance-history.md; the numpy core left src/)",
    }


#: The numpy core's figures (it has left src/): issue 13's table, this machine.
NUMPY_EXPERIMENT1_S = (1.1, 3.58)
NUMPY_BATCH_US_PER_RUN_STEP = 0.40


def bench_experiment1(repeats: int) -> dict[str, object]:
    """Experiment 1 in-process, warm cache: the whole-run compiled loop; with its set-up; and
    ``simulate`` (set-up, loop, History, metrics: what `sappc simulate` computes)."""
    sc = load_scenario(SCENARIOS / "paper_tracking.yaml")
    inp = prepare(sc, "sappc")
    run_single(inp)
    loop = _median(lambda: run_single(inp), repeats)
    with_setup = _median(lambda: run_single(prepare(sc, "sappc")), repeats)
    simulate(sc)
    sim = _median(lambda: simulate(sc), repeats)
    return {"compiled_loop_s": loop, "compiled_with_setup_s": with_setup, "simulate_s": sim,
            "numpy_core_s_issue13": list(NUMPY_EXPERIMENT1_S), "ratio_numpy_over_loop": [v / loop for v in NUMPY_EXPERIMENT1_S],
            "target_s": 0.005, "meets_target": loop <= 0.005}


def bench_montecarlo(repeats: int, n_runs: int = 3000) -> dict[str, object]:
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

    # the numpy core left src/: its batch figure from issue 13 (0.40 us a run-step, 3000 runs per step)
    numpy_total = NUMPY_BATCH_US_PER_RUN_STEP * 1e-6 * n_runs * steps
    return {
        "runs": n_runs, "steps_per_run": steps, "numba_threads": threads,
        "compiled_batch_s": all_threads, "compiled_batch_one_thread_s": one_thread,
        "compiled_us_per_run_step": all_threads / (n_runs * steps) * 1e6,
        "compiled_one_thread_us_per_run_step": one_thread / (n_runs * steps) * 1e6,
        "setup_draw_inputs_s": t_draw, "setup_prepare_s": t_prep,
        "numpy_batch_s_issue13": numpy_total, "numpy_us_per_run_step_issue13": NUMPY_BATCH_US_PER_RUN_STEP,
        "ratio_numpy_over_compiled": numpy_total / all_threads,
        "ratio_numpy_over_compiled_one_thread": numpy_total / one_thread,
        "all_runs_finite": finite,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--only", choices=("step", "experiment1", "montecarlo"), help="run one benchmark")
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
    }
    if args.only in (None, "step"):
        result["sappc_step_us"] = bench_step(args.repeats)
    if args.only in (None, "experiment1"):
        result["experiment1_s"] = bench_experiment1(args.repeats)
    if args.only in (None, "montecarlo"):
        result["montecarlo_3000x50s_s"] = bench_montecarlo(args.repeats)
    try:
        result["machine"]["threading_layer"] = numba.threading_layer()
    except ValueError:
        pass
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()

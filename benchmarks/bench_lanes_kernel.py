"""Issue 50, item 1: the compiled loop per run-step, one run at a time against SIMD lanes.

    python benchmarks/bench_lanes_kernel.py [--runs 256] [--repeats 5]

The paper's Monte Carlo scenario (``config/scenarios/paper_montecarlo.yaml``, 50 s at 100 Hz), the
same ``--runs`` initial attitudes (within 60 deg of the reference) through
:func:`sappc.offline.compiled_loop._loop` once per run (``sappc simulate``'s loop, a ``prange``
over runs) and once in lanes (:mod:`sappc.offline.lanes`), the whole run in one block, without
records (``stride = 0``: the law, the plant and the input check alone) and with every sample
recorded (``stride = 1``), on one thread (``NUMBA_NUM_THREADS=1``, set here).  Two more rows give
what a campaign pays for its metrics: the lanes recording every sample and the metrics then read
from the record (``lanes_record_then_metrics``: the campaign before issue 50's online metrics),
and the lanes computing the metrics online, sample by sample, recording only their answers
(``lanes_online_metrics``: a campaign's sub-batches now).  Each figure is the median over ``--repeats`` alternating calls, in ns per run-step
(one run, one sample); the ratio lanes / per run is computed from the medians.  Prints JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

os.environ["NUMBA_NUM_THREADS"] = "1"
ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=256)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()

    import numpy as np

    from gnc_common import libm
    from sappc.offline import compiled_loop as cl
    from sappc.offline.simulate import METRICS_BLOCK, metrics_accumulator
    from sappc.scenario import load_scenario

    sc = load_scenario(ROOT / "config/scenarios/paper_montecarlo.yaml")
    rng = np.random.default_rng(3)
    axis = rng.normal(size=(args.runs, 3))
    axis /= np.linalg.norm(axis, axis=1)[:, None]
    angle = rng.uniform(0.05, np.radians(60.0), args.runs)
    q = np.column_stack((axis * np.sin(angle / 2)[:, None], np.cos(angle / 2)))
    inputs = {lanes: cl.prepare(sc, on_infeasible="clamp", q_BN0=q, lanes=lanes) for lanes in (False, True)}
    records = {(lanes, stride): cl._record(inputs[lanes], stride, args.runs) for lanes in (False, True) for stride in (0, 1)}
    T = inputs[False].n_samples
    run_steps = args.runs * T
    lanes_inp, rec1 = inputs[True], records[(True, 1)]

    def loop(lanes: bool, stride: int) -> None:
        cl._loop(False, stride, inputs[lanes], records[(lanes, stride)], cl._state(inputs[lanes], args.runs))

    def record_then_metrics() -> None:
        acc = metrics_accumulator(sc, T, float(sc.control_period_s), args.runs)
        cl._loop(False, 1, lanes_inp, rec1, cl._state(lanes_inp, args.runs))
        acc.add_history(cl.CompiledRun(lanes_inp.t, rec1).history(), block_samples=max(1, METRICS_BLOCK // args.runs))

    def online_metrics() -> None:
        acc = metrics_accumulator(sc, T, float(sc.control_period_s), args.runs)
        cl._loop(False, 1, lanes_inp, rec1, cl._state(lanes_inp, args.runs), acc)

    cases = {f"{'lanes' if lanes else 'per_run'}_stride{stride}": (lambda lanes=lanes, stride=stride: loop(lanes, stride))
             for stride in (0, 1) for lanes in (False, True)}
    cases.update(lanes_record_then_metrics=record_then_metrics, lanes_online_metrics=online_metrics)
    times: dict[str, list[float]] = {key: [] for key in cases}
    for rep in range(args.repeats + 1):  # the first round warms up (kernels loaded, pages touched)
        for name in (list(cases) if rep % 2 == 0 else list(cases)[::-1]):
            t0 = time.perf_counter()
            cases[name]()
            if rep > 0:
                times[name].append((time.perf_counter() - t0) / run_steps * 1e9)
    ns = {name: {"median": statistics.median(v), "min": min(v), "max": max(v), "n": len(v)} for name, v in times.items()}
    commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    print(json.dumps({
        "what": "issue 50 item 1: ns per run-step of the compiled loop, per run against SIMD lanes, one thread",
        "command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]),
        "date": time.strftime("%Y-%m-%d %H:%M"),
        "machine": {"platform": platform.platform(), "python": platform.python_version(), "cpus": os.cpu_count(),
                    "load_average_after": os.getloadavg(), "commit": commit, "libmvec_variants": [f"{i}{w}" for i, w in libm.installed_variants()]},
        "runs": args.runs, "samples_per_run": inputs[False].n_samples,
        "ns_per_run_step": ns,
        "ratio_lanes_over_per_run": {f"stride{s}": ns[f"lanes_stride{s}"]["median"] / ns[f"per_run_stride{s}"]["median"] for s in (0, 1)},
        "ratio_online_over_record_then_metrics": ns["lanes_online_metrics"]["median"] / ns["lanes_record_then_metrics"]["median"],
    }, indent=1))


if __name__ == "__main__":
    main()

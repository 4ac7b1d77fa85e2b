"""The noise filters' trade-off on the flight stack (issue 34; docs/design/noise.md).

SAPPC on ``paper_tracking_flight.yaml`` over the same sensor-noise seeds (the population of
``sappc compare-controllers``: run k's noise from ``SeedSequence(seed, spawn_key=(k,))``), for each
cut-off of each filter: the median and 95th percentile of the steady max ``|q_ev|``, the median
torque sign changes per second, the largest overshoot and settling time.  Three curves: the
torque filter and the rate filter with the flight scenario's gains, and the torque filter with
experiment 1's hand-tuned gains.  Writes ``noise_filter.md`` (the tables) and ``noise_filter.png``
(sign changes against the p95 accuracy, one point per cut-off) into ``--out``.

    .venv/bin/python benchmarks/bench_noise_filter.py --seeds 100 --seed 1 --out runs/bench/noise_filter
"""

from __future__ import annotations

import argparse
import copy
from pathlib import Path
from typing import Any

import numpy as np

from sappc.files import scenario_path
from sappc.montecarlo.campaign import simulate_runs
from sappc.montecarlo.comparison import noise_seed_mapping
from sappc.scenario import read_scenario_mapping

#: The cut-offs swept [Hz]; 0 is the filter off.
CUTOFFS_HZ = (0.0, 0.5, 0.75, 1.0, 1.07, 1.5, 2.0, 3.0, 5.0)
#: Experiment 1's hand-tuned gains (docs/design/gains.md), the flight scenario's before issue 34.
EXPERIMENT1_GAINS = {"K_q": 0.3, "K_omega": 0.35, "D_m_Nm": 0.05, "mu_rad_s": 7.0e-5}
#: The curves: (name, filter key, gains over the flight scenario's, or none).
CURVES: tuple[tuple[str, str, dict[str, float] | None], ...] = (
    ("torque filter, flight gains", "torque_cutoff_hz", None),
    ("rate filter, flight gains", "rate_cutoff_hz", None),
    ("torque filter, experiment 1 gains", "torque_cutoff_hz", EXPERIMENT1_GAINS),
)


def point(base: dict[str, Any], key: str, cutoff_hz: float, gains: dict[str, float] | None, seeds: int, seed: int) -> dict[str, float]:
    raw = copy.deepcopy(base)
    c = raw["controllers"]["sappc"]
    c["noise_filter"] = {key: cutoff_hz}
    c["gains"].update(gains or {})
    _, metrics, _ = simulate_runs(noise_seed_mapping(raw, "sappc"), seed, list(range(seeds)), 0)
    crit = metrics.criteria_arrays()
    q = np.asarray(crit["steady_max_abs_qev"])
    sc = np.asarray(crit["torque_sign_changes_per_s"])
    return {"cutoff_hz": cutoff_hz, "qev_median": float(np.median(q)), "qev_p95": float(np.percentile(q, 95)),
            "sign_median": float(np.median(sc)), "overshoot_max": float(np.max(np.maximum(metrics.overshoot, 0.0))),
            "settling_max_s": float(np.nanmax(crit["settling_time_s"]))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=100)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", default="runs/bench/noise_filter")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    base = read_scenario_mapping(scenario_path("paper_tracking_flight"))
    lines = [f"paper_tracking_flight, SAPPC, {args.seeds} noise seeds (seed {args.seed}):", ""]
    curves: dict[str, list[dict[str, float]]] = {}
    for name, key, gains in CURVES:
        rows = [point(base, key, f, gains, args.seeds, args.seed) for f in CUTOFFS_HZ]
        curves[name] = rows
        lines += [f"{name}:", "", "| cut-off [Hz] | steady max \\|q_ev\\| median | p95 | sign changes/s, median | overshoot, max | settling, max [s] |",
                  "| ---: | ---: | ---: | ---: | ---: | ---: |"]
        lines += [f"| {'off' if r['cutoff_hz'] == 0 else format(r['cutoff_hz'], 'g')} | {r['qev_median']:.3e} | {r['qev_p95']:.3e} | "
                  f"{r['sign_median']:.1f} | {r['overshoot_max']:.2e} | {r['settling_max_s']:.2f} |" for r in rows]
        lines.append("")
        print("\n".join(lines[-len(rows) - 4:]), flush=True)
    (out / "noise_filter.md").write_text("\n".join(lines))
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4.5))
    for name, rows in curves.items():
        x = [r["qev_p95"] for r in rows]
        y = [r["sign_median"] for r in rows]
        ax.plot(x, y, "o-", label=name)
        for r, xi, yi in zip(rows, x, y):
            ax.annotate("off" if r["cutoff_hz"] == 0 else f"{r['cutoff_hz']:g}", (xi, yi), fontsize=7, textcoords="offset points", xytext=(3, 3))
    ax.axvline(4e-5, color="gray", ls="--", lw=0.8)
    ax.axhline(10.0, color="gray", ls="--", lw=0.8)
    ax.set_yscale("log")
    ax.set_xlabel("steady max |q_ev|, 95th percentile over the seeds")
    ax.set_ylabel("torque sign changes per second, median")
    ax.set_title(f"SAPPC on the flight stack: cut-off [Hz] against accuracy and quiet ({args.seeds} seeds)")
    ax.legend(fontsize=8)
    ax.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(out / "noise_filter.png", dpi=110)
    print(f"wrote {out / 'noise_filter.md'} and {out / 'noise_filter.png'}")


if __name__ == "__main__":
    main()

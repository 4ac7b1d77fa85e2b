"""The noise filters' trade-off on the flight stack (issue 34; docs/design/noise.md).

SAPPC on ``paper_tracking_flight.yaml`` over the same sensor-noise seeds (the population of
``sappc compare-controllers``: run k's noise from ``SeedSequence(seed, spawn_key=(k,))``), for each
cut-off of each filter: the median and 95th percentile of the steady max ``|q_ev|``, the median
torque sign changes per second, the largest overshoot and settling time.  Three curves: the
torque filter and the rate filter with the flight scenario's gains, and the torque filter with
experiment 1's hand-tuned gains.  Writes ``noise_filter.md`` (the tables) and ``noise_filter.png``
(the median sign changes and the p95 accuracy against the cut-off) and ``noise_filter.json`` into
``--out``.

    .venv/bin/python benchmarks/bench_noise_filter.py --seeds 100 --seed 1 --out runs/bench/noise_filter
"""

from __future__ import annotations

import argparse
import copy
import json
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


#: The linearised sampled rate loop of the flight scenario's gains (docs/design/noise.md): the
#: robust term's slope D_m / mu = 0.0921 / 1.261e-4 = 730 N m s, times tanh' ~ 0.9 at the
#: disturbance's steady z2, plus K_omega M_omega J ~ 14 N m s, is k ~ 670 N m s; per step
#: a = k dt / J = 1.68 (dt 0.01 s, J 4 kg m^2).
LOOP_GAIN_PER_STEP = 1.68
#: The gyro's white rate noise per sample [rad/s]: angle random walk / sqrt(dt) = 1.45e-6 / sqrt(0.01).
GYRO_SIGMA_RAD_S = 1.45e-5


def linear_loop(a: float, cutoff_hz: float, dt: float = 0.01) -> tuple[float, float, float]:
    """The sampled rate loop ``w[k+1] = w[k] + (dt/J) u[k]``, ``u = -k LPF(w + n)`` (``a = k dt / J``,
    the filter ``g = 1 - exp(-2 pi f_c dt)``, 1 when off): the torque's noise standard deviation per
    unit ``k sigma`` (the closed loop's noise-to-torque gain ``F k / (1 + L)`` integrated over the
    Nyquist band), and the damping ratio and frequency [Hz] of the closed-loop poles, the roots of
    ``z^2 + (g (1 + a) - 2) z + (1 - g)``."""
    g = 1.0 if cutoff_hz == 0.0 else -np.expm1(-2.0 * np.pi * cutoff_hz * dt)
    w = np.linspace(1e-6, np.pi, 200_001)
    z = np.exp(1j * w)
    F = g * z / (z - (1.0 - g))  # the first-order low-pass, matched pole
    L = a * F / (z - 1.0)  # loop gain: k (dt/J) / (z - 1) times the filter
    T = F / (1.0 + L)  # noise -> u / k
    var = float(np.trapezoid(np.abs(T) ** 2, w) / np.pi)
    poles = np.roots([1.0, g * (1.0 + a) - 2.0, 1.0 - g])
    p = poles[np.argmax(np.abs(poles))]
    s = np.log(complex(p)) / dt  # the equivalent continuous pole
    zeta = float(-s.real / abs(s)) if abs(s) > 0 else 1.0
    return float(np.sqrt(var)), zeta, float(abs(s.imag) / (2.0 * np.pi))


def point_runs(base: dict[str, Any], key: str, cutoff_hz: float, gains: dict[str, float] | None, runs: list[int],
               seed: int) -> dict[str, np.ndarray]:
    """Each of ``runs``' metrics at one point of a curve (run k's noise from ``SeedSequence(seed,
    spawn_key=(k,))``): ``qev`` (steady max ``|q_ev|``), ``sign`` (torque sign changes per second),
    ``overshoot`` (0 or more), ``settling_s``."""
    raw = copy.deepcopy(base)
    c = raw["controllers"]["sappc"]
    c["noise_filter"] = {key: cutoff_hz}
    c["gains"].update(gains or {})
    _, metrics, _ = simulate_runs(noise_seed_mapping(raw, "sappc"), seed, list(runs), 0)
    crit = metrics.criteria_arrays()
    return {"qev": np.asarray(crit["steady_max_abs_qev"], dtype=np.float64),
            "sign": np.asarray(crit["torque_sign_changes_per_s"], dtype=np.float64),
            "overshoot": np.maximum(np.asarray(metrics.overshoot, dtype=np.float64), 0.0),
            "settling_s": np.asarray(crit["settling_time_s"], dtype=np.float64)}


def statistics(cutoff_hz: float, runs: dict[str, np.ndarray]) -> dict[str, float]:
    """A point's row of the tables: the median and 95th percentile of the steady max ``|q_ev|``,
    the median sign changes, the largest overshoot and settling time over its runs."""
    return {"cutoff_hz": cutoff_hz, "qev_median": float(np.median(runs["qev"])), "qev_p95": float(np.percentile(runs["qev"], 95)),
            "sign_median": float(np.median(runs["sign"])), "overshoot_max": float(np.max(runs["overshoot"])),
            "settling_max_s": float(np.nanmax(runs["settling_s"]))}


def point(base: dict[str, Any], key: str, cutoff_hz: float, gains: dict[str, float] | None, seeds: int, seed: int) -> dict[str, float]:
    return statistics(cutoff_hz, point_runs(base, key, cutoff_hz, gains, list(range(seeds)), seed))


def flight_base() -> dict[str, Any]:
    """The flight scenario's mapping, which every point modifies."""
    return read_scenario_mapping(scenario_path("paper_tracking_flight"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=100)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", default="runs/bench/noise_filter")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    base = flight_base()
    lines = [f"The linearised rate loop (a = {LOOP_GAIN_PER_STEP} per step):", "",
             "| cut-off [Hz] | torque noise / (k sigma) | poles' damping | poles' frequency [Hz] |", "| ---: | ---: | ---: | ---: |"]
    for f in CUTOFFS_HZ:
        ratio, zeta, freq = linear_loop(LOOP_GAIN_PER_STEP, f)
        lines.append(f"| {'off' if f == 0 else format(f, 'g')} | {ratio:.3f} | {zeta:.3f} | {freq:.2f} |")
    print("\n".join(lines), flush=True)
    lines += ["", f"paper_tracking_flight, SAPPC, {args.seeds} noise seeds (seed {args.seed}):", ""]
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
    (out / "noise_filter.json").write_text(json.dumps({"seeds": args.seeds, "seed": args.seed, "curves": curves}, indent=1) + "\n")
    plot(curves, args.seeds, out / "noise_filter.png")
    print(f"wrote {out / 'noise_filter.md'}, noise_filter.json and noise_filter.png")


def plot(curves: dict[str, list[dict[str, float]]], seeds: int, path: Path) -> None:
    """Two panels against the cut-off (log scale; the filter off drawn at the left edge): the median
    sign changes per second, and the 95th percentile of the steady max ``|q_ev|``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.2))
    off_x = 0.35  # where the filter-off point is drawn [Hz]: left of the smallest cut-off
    for name, rows in curves.items():
        x = [off_x if r["cutoff_hz"] == 0 else r["cutoff_hz"] for r in rows]
        a1.plot(x, [r["sign_median"] for r in rows], "o-", label=name)
        a2.plot(x, [r["qev_p95"] for r in rows], "o-", label=name)
    for ax, ylabel, bound in ((a1, "torque sign changes per second, median", 10.0), (a2, "steady max |q_ev|, p95", 4e-5)):
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.axhline(bound, color="gray", ls="--", lw=0.8)
        ax.axvline(off_x * 1.2, color="gray", ls=":", lw=0.8)
        ax.set_xlabel("cut-off [Hz] (leftmost point: filter off)")
        ax.set_ylabel(ylabel)
        ax.grid(True, which="both", alpha=0.3)
    a1.legend(fontsize=8)
    fig.suptitle(f"SAPPC on the flight stack, {seeds} noise seeds per point: quiet against accuracy over the cut-off")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()

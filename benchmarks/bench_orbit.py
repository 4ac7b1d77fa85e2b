"""The 6 h orbit scenarios (issue 36): per-orbit figures, the run's time, and the report figure.

Runs a scenario with an orbit (default ``paper_tracking_orbit``, 6 h at 100 Hz: 2,160,001 samples)
through the compiled offline loop twice (the first call may compile; the second is timed: wall and
this process's CPU time), and prints one JSON document: per orbit the steady max, 99.9th percentile
and mean of ``max_i |q_ev,i|`` (samples from ``metrics.steady_from_s``), the largest wheel speed as a
fraction of its limit, the largest and last ``|G_s J_s Omega|``, the rods' mean ``|m| / m_max`` and
the share of samples with a rod saturated or a motor at its torque limit; over the run, the first
time a wheel reaches its speed limit and the first time the error passes 1e-3.  ``--figure PATH``
writes the report figure (wheel momentum, the rods' dipoles and the error over the run, one point per
10 s bin: the bin's largest values, so a 6 h run stays readable and no peak is lost; the rods'
duty as the bin's mean).

    python benchmarks/bench_orbit.py [paper_tracking_orbit] [--set momentum_management.gain_per_s=0.02] [--figure docs/assets/orbit.png]
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from sappc.files import scenario_path  # noqa: E402
from sappc.offline.compiled_loop import prepare, run_single  # noqa: E402
from sappc.scenario import read_scenario_mapping, scenario_from_mapping  # noqa: E402

#: Width of the figure's bins [s]: 2160 points for 6 h, each the bin's largest value.
FIGURE_BIN_S = 10.0
#: The error level whose first crossing the document reports (the paper's settling threshold).
LOST_QEV = 1e-3


def _binned_max(t: np.ndarray, y: np.ndarray, width: float) -> tuple[np.ndarray, np.ndarray]:
    idx = (t // width).astype(np.int64)
    n = int(idx[-1]) + 1
    out = np.full(n, -np.inf)
    np.maximum.at(out, idx, y)
    return (np.arange(n) + 0.5) * width, out


def _binned_mean(t: np.ndarray, y: np.ndarray, width: float) -> tuple[np.ndarray, np.ndarray]:
    idx = (t // width).astype(np.int64)
    n = int(idx[-1]) + 1
    return (np.arange(n) + 0.5) * width, np.bincount(idx, weights=y, minlength=n) / np.maximum(np.bincount(idx, minlength=n), 1)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scenario", nargs="?", default="paper_tracking_orbit")
    parser.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE", help="override one key (YAML value)")
    parser.add_argument("--figure", type=Path, help="write the report figure here (PNG)")
    args = parser.parse_args(argv)
    raw = read_scenario_mapping(scenario_path(args.scenario))
    for item in args.set:
        key, value = item.split("=", 1)
        section, name = key.split(".", 1)
        raw[section][name] = yaml.safe_load(value)
    sc = scenario_from_mapping(raw)
    if sc.environment is None or sc.wheels is None:
        raise SystemExit(f"{args.scenario}: needs an orbit and reaction wheels")
    inp = prepare(sc)
    run_single(inp, 0, 1)  # compiles if the cache is cold
    wall0, cpu0 = time.perf_counter(), time.process_time()
    run = run_single(inp, 0, 1)
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    t = run.t
    Js, wmax = sc.wheels.per_wheel("spin_inertia_kg_m2"), sc.wheels.per_wheel("max_speed_rad_s")
    speed, motor = run.wheels[0, :, :, 0], run.wheels[0, :, :, 1]
    frac = (np.abs(speed) / wmax).max(axis=1)
    hB = np.linalg.norm((speed * Js) @ sc.wheels.G.T, axis=1)
    qe = np.abs(run.out[0, :, 3, :3]).max(axis=1)
    rods = sc.environment.magnetorquers
    mmax = rods.max_dipoles() if rods is not None else np.zeros(0)
    dip = np.abs(run.env[0, :, 9:]) / mmax if rods is not None else np.zeros((t.size, 0))
    umax = sc.wheels.per_wheel("max_torque_Nm")
    period = sc.environment.orbit.period_s
    orbits = []
    for k in range(int(np.ceil(sc.duration_s / period))):
        m = (t >= k * period) & (t < (k + 1) * period)
        ms = m & (t >= sc.metrics.steady_from_s)
        orbits.append({
            "orbit": k, "from_s": round(k * period, 1),
            "steady_max_abs_qev": float(qe[ms].max()), "steady_p999_abs_qev": float(np.quantile(qe[ms], 0.999)),
            "steady_mean_abs_qev": float(qe[ms].mean()), "samples_above_1e-3": int(np.sum(qe[ms] > LOST_QEV)),
            "max_wheel_speed_fraction": float(frac[m].max()), "max_wheel_momentum_B_Nms": float(hB[m].max()),
            "end_wheel_momentum_B_Nms": float(hB[m][-1]),
            "rods_mean_dipole_fraction": float(dip[m].mean()) if dip.shape[1] else 0.0,
            "rods_saturated_fraction": float(np.mean(np.any(dip[m] >= 1.0, axis=1))) if dip.shape[1] else 0.0,
            "motor_limited_fraction": float(np.mean(np.any(np.abs(motor[m]) >= umax, axis=1))),
        })
    at_limit = np.flatnonzero(frac >= 1.0)
    lost = np.flatnonzero((qe > LOST_QEV) & (t >= sc.metrics.steady_from_s))
    doc = {
        "scenario": sc.name, "overrides": args.set, "samples": int(t.size), "orbit_period_s": period,
        "run_wall_s": round(wall, 3), "run_cpu_s": round(cpu, 3), "host": platform.node(), "python": platform.python_version(),
        "first_wheel_at_speed_limit_s": float(t[at_limit[0]]) if at_limit.size else None,
        "first_qev_above_1e-3_s": float(t[lost[0]]) if lost.size else None,
        "orbits": orbits,
    }
    if args.figure is not None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, (a1, a3, a2) = plt.subplots(3, 1, sharex=True, figsize=(9, 7.5), constrained_layout=True)
        tb, fb = _binned_max(t, frac * 100.0, FIGURE_BIN_S)
        _, hb = _binned_max(t, hB, FIGURE_BIN_S)
        a1.plot(tb / 3600.0, fb, lw=0.8, label="largest wheel speed [% of limit]")
        a1.plot(tb / 3600.0, hb, lw=0.8, label="|wheels' momentum in B| [N m s]")
        a1.axhline(30.0, color="k", ls=":", lw=0.8, label="30 %")
        a1.legend(loc="upper right", fontsize=8)
        a1.set_ylabel("wheels")
        for i in range(dip.shape[1]):
            tr, rb = _binned_max(t, dip[:, i] * 100.0, FIGURE_BIN_S)
            a3.plot(tr / 3600.0, rb, lw=0.6, label=f"rod {i + 1}: |m| [% of {mmax[i]:g} A m^2] (10 s bins: largest)")
        _, mean_dip = _binned_mean(t, dip.mean(axis=1) * 100.0, FIGURE_BIN_S) if dip.shape[1] else (None, None)
        if mean_dip is not None:
            a3.plot(tr / 3600.0, mean_dip, color="k", lw=0.8, label="the rods' duty, mean |m| / m_max [%] (10 s bins: mean)")
        a3.legend(loc="upper right", fontsize=7)
        a3.set_ylabel("magnetorquers")
        steady = t >= sc.metrics.steady_from_s
        tq, qb = _binned_max(t[steady], qe[steady], FIGURE_BIN_S)
        ok = np.isfinite(qb)
        a2.semilogy(tq[ok] / 3600.0, qb[ok], lw=0.8, label="max_i |q_ev,i| (10 s bins: largest)")
        a2.axhline(4.34e-5, color="k", ls=":", lw=0.8, label="one-minute flight run: 4.34e-5")
        for k in range(1, len(orbits)):
            for ax in (a1, a3, a2):
                ax.axvline(k * period / 3600.0, color="0.7", lw=0.6)
        a2.legend(loc="upper right", fontsize=8)
        a2.set_xlabel("time [h] (grey: orbits)")
        a2.set_ylabel("attitude error")
        fig.suptitle(f"{sc.name}{' ' + ' '.join(args.set) if args.set else ''}", fontsize=9)
        args.figure.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(args.figure, dpi=110)
        doc["figure"] = str(args.figure)
    print(json.dumps(doc, indent=1))
    return doc


if __name__ == "__main__":
    main()

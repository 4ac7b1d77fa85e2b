"""The momentum claim across orbits (issue 47 item 5): the 6 h orbit scenario's dispersed runs in
several orbits, and how long the wheels' motors spend at their torque limit.

For each orbit (a bundled scenario name or a scenario file; default the three of the momentum page:
``paper_tracking_orbit``, 500 km sun-synchronous; ``paper_tracking_orbit_800km``, 800 km at 51.6 deg;
``paper_tracking_orbit_800km_sso``, 800 km sun-synchronous) it flies runs ``0 .. N-1`` of the
scenario's campaign (``sappc montecarlo SCENARIO --runs N --seed S``: the same dispersions and the
same numbers, run ``k`` alone by :func:`sappc.montecarlo.campaign.simulate_runs`, the function of
``sappc simulate --from-campaign``) with the full-rate record kept, and prints one JSON document.
Per run: the campaign's attitude figures (``steady_max_abs_qev``, the steady mean and the error at
``t2``, the worst axis), the largest wheel speed and motor torque (over the run, and from
``metrics.steady_from_s``: after the start's transient), and from the record each motor's time at
its torque limit (``|u_i| >= u_max,i``, samples times the control period), the time with a motor
there and the rods' dipoles all zero (the attitude-first budget gave the rods nothing: the
controller's torque and the gyroscopic term alone pass a motor's limit, and a part of the
controller's torque is not delivered; the rest of the time at the limit is the budget holding a
motor there while it scales the rods' dumping down), the longest stretch of a motor at its limit,
the wheels' peak momentum ``|G_s J_s Omega|`` and the rods' share of saturated samples; with
``--floor`` the run's floor of the peak momentum, whatever the law (``benchmarks/momentum_floor.py``
for its phase and field epoch).  Per orbit: the field along the nominal orbit (:func:`field_stats`)
and the median and largest of each figure across the runs.

    python benchmarks/bench_momentum_orbits.py [--runs 16] [--seed 0] [--orbit paper_tracking_orbit ...]
        [--set momentum_management.gain_per_s=0.0025] [--floor] [--json benchmarks/results_momentum/orbits.json]

A 6 h run holds its 2.7 GB record while it is measured (about 4 GB of peak memory; one run at a
time) and takes 10 to 16 s of loop CPU; ``--floor`` adds a 6 h run at 1 Hz (about 13 s) a run.
"""

from __future__ import annotations

import argparse
import copy
import gc
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT / "benchmarks"))

from gnc_common.ephemeris import dipole_field_N, position_N  # noqa: E402
from momentum_floor import floor_Nms  # noqa: E402
from sappc.files import scenario_path  # noqa: E402
from sappc.montecarlo.campaign import simulate_runs  # noqa: E402
from sappc.scenario import read_scenario_mapping, scenario_from_mapping  # noqa: E402

#: The orbits of the momentum page's campaign (issue 47 item 5: 500 km sun-synchronous, 800 km at
#: 51.6 deg, and a third: 800 km sun-synchronous, the 800 km altitude at the first one's kind of
#: inclination, which separates the altitude's effect from the inclination's).
DEFAULT_ORBITS = ("paper_tracking_orbit", "paper_tracking_orbit_800km", "paper_tracking_orbit_800km_sso")
#: Runs per orbit by default: the momentum page's table (the issue asks at least 8).
DEFAULT_RUNS = 16
#: A motor is at its limit when ``|u| >= (1 - AT_LIMIT_RTOL) u_max``: the plant clips a command at
#: ``u_max`` exactly, and the attitude-first budget's scale puts a motor on its limit to rounding
#: (measured, run 2 of ``paper_tracking_orbit_800km``: 6952 samples at 0.2 N m exactly, 678 within
#: 1e-15 of it, none from there to 1e-6 below): 1e-9 counts both and nothing that is not there.
AT_LIMIT_RTOL = 1e-9
#: The step [s] of the field's statistics over the nominal orbit (:func:`field_stats`): a thousandth
#: of a 100 min orbit, where the field's direction turns by about 0.01 rad.
FIELD_STEP_S = 6.0
#: The per-run figures whose median and largest across runs the summary gives.
SUMMARY_KEYS = ("steady_max_abs_qev", "steady_mean_abs_qev", "rpf_error_at_t2", "max_abs_wheel_speed_rad_s",
                "max_abs_wheel_torque_Nm", "steady_max_abs_wheel_torque_Nm", "any_motor_at_limit_s", "worst_motor_at_limit_s",
                "at_limit_rods_off_s", "longest_at_limit_s",
                "max_wheel_momentum_B_Nms", "rods_saturated_fraction")


def _commit() -> str:
    """The checkout's commit, and its files changed or added since (what the numbers were measured on)."""
    try:
        def git(*args: str) -> str:
            return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, check=True).stdout

        head = git("rev-parse", "--short", "HEAD").strip()
        dirty = git("status", "--porcelain", "--", "src", "benchmarks").split("\n")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    changed = sorted(line[3:] for line in dirty if line.strip())
    return head + (f" + uncommitted: {', '.join(changed)}" if changed else "")


def _finite_or_none(value: Any) -> float | None:
    v = float(value)
    return v if np.isfinite(v) else None


def _longest_run_s(flags: np.ndarray, dt: float) -> float:
    """The longest stretch of consecutive True samples, times ``dt`` [s]."""
    if not flags.any():
        return 0.0
    edges = np.diff(np.concatenate(([0], flags.astype(np.int8), [0])))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    return float((ends - starts).max() * dt)


def measure_run(raw: dict[str, Any], seed: int, run: int) -> dict[str, Any]:
    """Run ``run`` of the campaign of ``raw`` with its record: the figures of the module docstring."""
    cpu0 = time.process_time()
    row, metrics, result = simulate_runs(raw, seed, [run], 0, with_history=True)
    cpu = time.process_time() - cpu0
    sc = scenario_from_mapping(raw)
    assert sc.wheels is not None and sc.environment is not None
    h = result.history
    dt = float(sc.control_period_s)
    u = np.abs(h.wheel_torque_Nm[:, 0, :])  # (T, W)
    u_max = sc.wheels.per_wheel("max_torque_Nm")
    at_limit = u >= (1.0 - AT_LIMIT_RTOL) * u_max
    any_limit = at_limit.any(axis=1)
    steady = h.t >= sc.metrics.steady_from_s
    Js = sc.wheels.per_wheel("spin_inertia_kg_m2")
    hB = np.linalg.norm((h.wheel_speed_rad_s[:, 0, :] * Js) @ sc.wheels.G.T, axis=1)
    rods = sc.environment.magnetorquers
    rods_sat = float(np.mean(np.any(np.abs(h.orbit[:, 0, 9:]) >= rods.max_dipoles(), axis=1))) if rods is not None else 0.0
    # step 6 of sappc_momentum.core.law: when the controller's torque and the gyroscopic term alone
    # pass a motor's limit the rods get nothing (every dipole zero) and the motor is clipped: a part of
    # the attitude's torque is not delivered; otherwise a motor at its limit is the budget holding it
    # there while the rods' dumping is scaled down (the attitude's torque delivered in full)
    rods_off = np.all(h.orbit[:, 0, 9:] == 0.0, axis=1) if rods is not None else np.ones(any_limit.shape, dtype=bool)
    first = np.flatnonzero(any_limit)
    doc = {
        "run": run,
        "mean_anomaly_deg": float(np.ravel(row.get("hw_orbit_mean_anomaly_deg", [np.nan]))[0]),
        "earth_rotation_angle_deg": float(np.ravel(row.get("hw_orbit_earth_rotation_angle_deg", [np.nan]))[0]),
        "steady_max_abs_qev": float(row["steady_max_abs_qev"][0]),
        "steady_mean_abs_qev": float(np.max(row["steady_mean_abs_qev_per_axis"][0])),
        "rpf_error_at_t2": float(np.max(row["rpf_error_at_t2_per_axis"][0])),
        "control_lost_at_s": _finite_or_none(row["control_lost_at_s"][0]),  # None: never lost
        "max_abs_wheel_speed_rad_s": float(row["max_abs_wheel_speed_rad_s"][0]),
        "max_abs_wheel_torque_Nm": float(row["max_abs_wheel_torque_Nm"][0]),
        "steady_max_abs_wheel_torque_Nm": float(u[steady].max()),  # after the start's transient (the controller's own 0.195 N m)
        "motor_at_limit_s": [float(v) for v in at_limit.sum(axis=0) * dt],
        "any_motor_at_limit_s": float(any_limit.sum() * dt),
        "worst_motor_at_limit_s": float(at_limit.sum(axis=0).max() * dt),
        "at_limit_rods_off_s": float(np.sum(any_limit & rods_off) * dt),
        "longest_at_limit_s": max(_longest_run_s(at_limit[:, i], dt) for i in range(at_limit.shape[1])),
        "first_at_limit_s": float(h.t[first[0]]) if first.size else None,
        "max_wheel_momentum_B_Nms": float(hB.max()),
        "rods_saturated_fraction": rods_sat,
        "run_cpu_s": round(cpu, 2),
    }
    del row, metrics, result, h
    gc.collect()
    return doc


def field_stats(raw: dict[str, Any]) -> dict[str, Any]:
    """The dipole field along the scenario's own orbit (its phase and epoch at ``t = 0``) over its
    duration, in N: the mean, smallest and largest ``|B|`` [uT], how far its direction turns per
    orbit [rad] and the eigenvalues of the mean ``b b^T`` (``b = B / |B|``; a smallest one near 0:
    the direction stays near a plane, so a rod can reach every direction normal to it within half
    an orbit; 1/3 each: the direction spreads over all three)."""
    sc = scenario_from_mapping(raw)
    assert sc.environment is not None
    orbit, field = sc.environment.orbit.params(), sc.environment.magnetic_field.params()
    t = np.arange(0.0, sc.duration_s + FIELD_STEP_S / 2, FIELD_STEP_S)
    B, r = np.zeros((t.size, 3)), np.zeros(3)
    for i, ti in enumerate(t):
        position_N(orbit, ti, r)
        dipole_field_N(orbit, field, ti, r, B[i])
    norm = np.linalg.norm(B, axis=1)
    b = B / norm[:, None]
    turn = float(np.linalg.norm(np.diff(b, axis=0), axis=1).sum() / (sc.duration_s / sc.environment.orbit.period_s))
    return {"mean_uT": float(norm.mean() * 1e6), "min_uT": float(norm.min() * 1e6), "max_uT": float(norm.max() * 1e6),
            "direction_turn_rad_per_orbit": turn,
            "direction_spread_eigenvalues": [float(v) for v in np.linalg.eigvalsh(b.T @ b / t.size)]}


def _summary(runs: list[dict[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key in SUMMARY_KEYS:
        v = np.array([r[key] for r in runs], dtype=np.float64)
        out[key] = {"median": float(np.median(v)), "max": float(np.max(v))}
    if all("floor_Nms" in r for r in runs):
        v = np.array([r["floor_Nms"] for r in runs])
        out["floor_Nms"] = {"min": float(v.min()), "median": float(np.median(v)), "max": float(v.max())}
    out["runs_with_a_motor_at_limit"] = int(sum(r["any_motor_at_limit_s"] > 0.0 for r in runs))
    out["runs_lost"] = int(sum(r["control_lost_at_s"] is not None for r in runs))
    return out


def campaign(orbit: str, runs: int, seed: int, overrides: list[str], floor: bool = False) -> dict[str, Any]:
    raw = read_scenario_mapping(scenario_path(orbit))
    for item in overrides:
        key, value = item.split("=", 1)
        *sections, name = key.split(".")
        node = raw
        for section in sections:
            node = node.setdefault(section, {})
        node[name] = yaml.safe_load(value)
    sc = scenario_from_mapping(raw)
    assert sc.environment is not None
    o = sc.environment.orbit
    wall0 = time.perf_counter()
    per_run = []
    for k in range(runs):
        per_run.append(measure_run(raw, seed, k))
        if floor:  # benchmarks/momentum_floor.py's bound for this run's start (its phase and field epoch; the nominal hardware)
            start = copy.deepcopy(raw)
            start["orbit"].update(mean_anomaly_deg=per_run[-1]["mean_anomaly_deg"],
                                  earth_rotation_angle_deg=per_run[-1]["earth_rotation_angle_deg"])
            per_run[-1]["floor_Nms"] = floor_Nms(start)
        print(f"{orbit} run {k}: {json.dumps(per_run[-1])}", file=sys.stderr, flush=True)
    return {
        "scenario": sc.name, "overrides": overrides, "altitude_m": o.altitude_m, "inclination_deg": o.inclination_deg,
        "orbit_period_s": o.period_s, "duration_s": sc.duration_s, "field": field_stats(raw), "runs": runs, "seed": seed,
        "summary": _summary(per_run), "per_run": per_run, "wall_s": round(time.perf_counter() - wall0, 1),
    }


def _machine() -> str:
    """The CPU count and the memory (Linux's /proc/meminfo; else the CPUs alone)."""
    try:
        kb = next(int(line.split()[1]) for line in Path("/proc/meminfo").read_text().splitlines() if line.startswith("MemTotal:"))
        memory = f", {kb / 1024 ** 2:.0f} GiB"
    except (OSError, StopIteration, ValueError):
        memory = ""
    return f"{platform.machine()}, {os.cpu_count()} CPUs{memory}"


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--orbit", action="append",
                        help=f"a scenario with an orbit (repeat; default {', '.join(DEFAULT_ORBITS)})")
    parser.add_argument("--runs", type=int, default=DEFAULT_RUNS, help=f"runs per orbit (default {DEFAULT_RUNS})")
    parser.add_argument("--seed", type=int, default=0, help="the campaign's root seed (default 0)")
    parser.add_argument("--set", action="append", default=[], metavar="[SECTION.]KEY=VALUE",
                        help="override one key of every orbit (YAML value)")
    parser.add_argument("--floor", action="store_true", help="also each run's floor of the peak momentum, whatever the law "
                        "(benchmarks/momentum_floor.py: one more 6 h run at 1 Hz each)")
    parser.add_argument("--json", type=Path, help="also write the document here")
    args = parser.parse_args(argv)
    doc = {
        "commit": _commit(), "host": platform.node(), "machine": _machine(),
        "python": platform.python_version(),
        "at_limit_rtol": AT_LIMIT_RTOL,
        "orbits": [campaign(o, args.runs, args.seed, args.set, args.floor) for o in (args.orbit or DEFAULT_ORBITS)],
    }
    text = json.dumps(doc, indent=1)
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(text + "\n")
    print(text)
    return doc


if __name__ == "__main__":
    main()

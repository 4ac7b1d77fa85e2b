"""The momentum no dumping law can avoid (issue 36): a lower bound on the wheels' peak momentum for
an orbit's field epochs, whatever the law and however large the rods.

With the wheels' momentum ``h`` in N changed by the disturbance ``D`` and the rods' torque normal to
the field (``dh/dt = D + tau``, ``tau . b = 0``, ``b`` the field's direction), the part along the
field obeys ``d(h . b)/dt = D . b + h . db/dt``: over an interval ``[t1, t2]`` it changes by
``integral(D . b) dt`` less at most ``H integral(|db/dt|) dt`` (``H`` the peak ``|h|``), and by at
most ``2 H`` in all, so

    H >= |integral_t1^t2 (D . b) dt| / (2 + integral_t1^t2 |db/dt| dt)

for every interval.  This script flies the scenario with motors strong enough that the attitude
follows its reference (``actuator.wheels.max_torque_Nm`` 5 N m: the bound is about the attitude
the task asks for), records ``D`` and ``b`` in N at 1 Hz, and prints per field epoch the bound
(the largest over intervals on a 10 s grid) beside what the cross-product and the predictive law
store (the same runs' peak ``|G_s J_s Omega|`` with the real motors: ``benchmarks/bench_orbit.py``'s
figure).  Prints one JSON document.

    python benchmarks/momentum_floor.py [--epochs 0,90,180,270] [--phase 0] [--duration 5677]
"""

from __future__ import annotations

import argparse
import copy
import json
import platform
import sys
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from gnc_common.attitude import quat_to_dcm_BN  # noqa: E402
from sappc.files import scenario_path  # noqa: E402
from sappc.offline.compiled_loop import prepare, run_single  # noqa: E402
from sappc.scenario import read_scenario_mapping, scenario_from_mapping  # noqa: E402

#: Motor torque [N m] of the bound's runs: enough that no motor limits the attitude (the real ones: 0.2).
STRONG_MOTOR_NM = 5.0
#: The bound's grid of interval ends [s] (the record is at 1 Hz).
GRID_S = 10


def _run(raw: dict[str, Any], stride: int) -> tuple[Any, Any]:
    sc = scenario_from_mapping(copy.deepcopy(raw))
    return sc, run_single(prepare(sc), 0, stride)


def floor_Nms(raw: dict[str, Any]) -> float:
    """The bound of the module docstring for the scenario ``raw``."""
    strong = copy.deepcopy(raw)
    strong["actuator"]["wheels"]["max_torque_Nm"] = STRONG_MOTOR_NM
    _, r = _run(strong, 100)  # 1 Hz
    C = np.array([quat_to_dcm_BN(q) for q in r.x[0, :, :4]])  # v_B = C v_N
    B_N = np.einsum("nji,nj->ni", C, r.env[0, :, 0:3])
    b = B_N / np.linalg.norm(B_N, axis=1)[:, None]
    D = np.einsum("nji,nj->ni", C, r.d[0])
    dt = float(r.t[1] - r.t[0])
    S = np.concatenate(([0.0], np.cumsum(np.sum(D * b, axis=1)) * dt))[::GRID_S]
    N = np.concatenate(([0.0], np.cumsum(np.linalg.norm(np.gradient(b, dt, axis=0), axis=1)) * dt))[::GRID_S]
    dS = np.abs(S[None, :] - S[:, None])
    dN = np.abs(N[None, :] - N[:, None])
    return float(np.max(dS / (2.0 + dN)))


def peak_Nms(raw: dict[str, Any], law: str) -> tuple[float, bool]:
    """The wheels' peak momentum in B [N m s] with ``law`` on the real hardware, and whether the attitude was lost."""
    r_raw = copy.deepcopy(raw)
    r_raw["momentum_management"]["law"] = law
    sc, r = _run(r_raw, 100)
    assert sc.wheels is not None
    h = (r.wheels[0, :, :, 0] * sc.wheels.per_wheel("spin_inertia_kg_m2")) @ sc.wheels.G.T
    steady = r.t >= sc.metrics.steady_from_s
    return float(np.linalg.norm(h, axis=1).max()), bool(np.abs(r.out[0, steady, 3, :3]).max() > 1e-3)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenario", default="paper_tracking_orbit")
    parser.add_argument("--epochs", default="0,60,120,180,240,300", help="Earth rotation angles at t = 0 [deg], comma-separated")
    parser.add_argument("--phase", type=float, default=0.0, help="mean anomaly at t = 0 [deg]")
    parser.add_argument("--duration", type=float, default=5677.0, help="seconds flown (default: one orbit)")
    args = parser.parse_args(argv)
    rows = []
    for epoch in (float(v) for v in args.epochs.split(",")):
        raw = read_scenario_mapping(scenario_path(args.scenario))
        raw["duration_s"] = args.duration
        raw["orbit"].update(earth_rotation_angle_deg=epoch, mean_anomaly_deg=args.phase)
        row: dict[str, Any] = {"earth_rotation_angle_deg": epoch, "floor_Nms": round(floor_Nms(raw), 2)}
        for law in ("cross_product", "predictive"):
            peak, lost = peak_Nms(raw, law)
            row[law] = {"peak_Nms": round(peak, 2), "attitude_lost": lost}
        rows.append(row)
        print(json.dumps(row), file=sys.stderr, flush=True)
    doc = {"scenario": args.scenario, "phase_deg": args.phase, "duration_s": args.duration, "host": platform.node(), "epochs": rows}
    print(json.dumps(doc, indent=1))
    return doc


if __name__ == "__main__":
    main()

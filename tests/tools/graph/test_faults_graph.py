"""Faults through the lockstep graph against the offline runner (issue 14), one case per fault kind.

Each case is the fault matrix's (``benchmarks/bench_fault_matrix.py``): experiment 1 with one
fault from t = 30 s.  The injector applies the fault to messages, the offline loop to arrays,
through the same compiled fault kernels, and the offline loop models the controller node's
lockstep answers (computed, held, watchdog zero); a dropped measurement or reference reaches the
controller as "no data", so every sample is answered as soon as its inputs are in, whatever the
order of arrival, and no sample waits for a timeout.  So for every kind:

- the same metrics through ``sappc run`` as through ``sappc simulate`` to 1e-9 (the issue's
  bound; the torques agree to ~1e-14, libm's last bit in the nodes' separate processes);
- the same answer at every sample, and no lockstep timeout in the plant;
- the outcome: for SAPPC the error is back in its band at the end, and for the dropouts (the
  issue's case) the last 20 s hold the accuracy of experiment 1 without the fault (the
  no-fault run's steady max |q_ev|, computed here).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from sappc.bag.read import bag_run, read_bag
from sappc.offline import compiled_loop
from sappc.offline.simulate import simulate
from sappc.scenario import load_scenario, scenario_from_mapping

from conftest import ROOT, SAPPC, SCENARIOS

sys.path.insert(0, str(ROOT / "benchmarks"))
from bench_fault_matrix import LAST_S, case_scenario  # noqa: E402

pytestmark = pytest.mark.slow

#: The issue's bound on graph-against-offline metric differences.
METRIC_TOL = 1e-9
def _graph(tmp_path: Path, raw: dict) -> tuple[dict, object, dict]:  # type: ignore[type-arg]
    path = tmp_path / "scenario.yaml"
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    proc = subprocess.run([*SAPPC, "run", str(path), "--out", str(tmp_path / "run"), "--json", str(tmp_path / "m.json")],
                          capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    plant = json.loads((tmp_path / "run" / "logs" / "timing.json").read_text())
    return json.loads((tmp_path / "m.json").read_text()), bag_run(read_bag(tmp_path / "run" / "bag")), plant


@pytest.mark.parametrize("kind", ["sensor_dropout", "reference_dropout", "actuator_dropout", "sensor_delay_3", "actuator_stuck",
                                  "actuator_bias_20mNm", "sensor_noise", "sensor_freeze"])
def test_every_fault_kind_gives_the_offline_run_through_the_graph(tmp_path, kind: str) -> None:  # type: ignore[no-untyped-def]
    raw = case_scenario(kind, "sappc")
    scenario = scenario_from_mapping(raw)
    offline = simulate(scenario)
    report, run, plant = _graph(tmp_path, raw)
    for key, value in offline.metrics.items():
        if key == "wall_time_s":
            continue
        got = report["metrics"][key]
        if isinstance(value, float):
            assert got == pytest.approx(value, abs=METRIC_TOL), key
        else:
            assert got == value, key
    status = compiled_loop.run_single(compiled_loop.prepare(scenario), 0, 1).status[0]
    np.testing.assert_array_equal(run.answer, status)  # type: ignore[attr-defined]
    assert {k: report["controller_summary"][k] for k in offline.controller_summary} == offline.controller_summary
    assert plant["missed"]["torque"] == 0  # every sample answered: no lockstep timeout
    assert report["metrics"]["returned_to_constraint"] is True
    if kind.endswith("dropout"):
        no_fault = simulate(load_scenario(SCENARIOS / "paper_tracking.yaml"))
        h = run.history  # type: ignore[attr-defined]
        last = np.abs(h.q_ev[h.t >= LAST_S - 1e-9]).max()
        assert last <= no_fault.metrics["steady_max_abs_qev"], (last, no_fault.metrics["steady_max_abs_qev"])

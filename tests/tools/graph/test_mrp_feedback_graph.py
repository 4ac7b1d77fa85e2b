"""The MRP feedback controller on the node graph (issue 34): a lockstep ``sappc run`` of experiment 1
cut short records, bit for bit, the offline run of the same scenario (the same compiled law under
the node and in the whole-run loop), and ``sappc rerun`` of its bag reproduces every torque.

The run claims a ROS domain of its own (``sappc run`` without ``--domain-id``: a free one of
``SAPPC_DOMAIN_IDS``, held with a lock file), as every graph test does.
"""

from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest
import yaml

from sappc.bag.read import bag_run, read_bag
from sappc.offline.simulate import simulate
from sappc.scenario import load_scenario

from conftest import ROOT, SAPPC, SCENARIOS, cut_short

pytestmark = pytest.mark.slow

#: Length of the run [s]: through the saturated transient and the integral's start (the controller's
#: integral accumulates from its second sample), short enough for a 2-core machine.
DURATION_S = 3.0


@pytest.fixture(scope="module")
def mrp_run(tmp_path_factory):  # type: ignore[no-untyped-def]
    """(scenario file, run directory) of experiment 1, cut to :data:`DURATION_S`, through the graph."""
    tmp = tmp_path_factory.mktemp("mrp")
    scenario = yaml.safe_load((SCENARIOS / "paper_tracking.yaml").read_text())
    cut_short(scenario, DURATION_S)
    path = tmp / "short.yaml"
    path.write_text(yaml.safe_dump(scenario))
    proc = subprocess.run([*SAPPC, "run", str(path), "--controller", "mrp_feedback", "--out", str(tmp / "run")],
                          capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return path, tmp / "run"


def test_the_lockstep_bag_is_the_offline_run_bit_for_bit(mrp_run) -> None:  # type: ignore[no-untyped-def]
    path, out = mrp_run
    offline = simulate(load_scenario(path), "mrp_feedback").history
    graph = bag_run(read_bag(out / "bag")).history
    assert graph.t.shape == offline.t.shape
    for name in ("q_BN", "omega_BN_B", "q_BR", "torque_B", "torque_cmd_B", "eps", "z", "V"):
        got, want = getattr(graph, name)[:, 0], getattr(offline, name)[:, 0]
        assert np.array_equal(got, want), (name, np.abs(got - want).max())
    assert np.any(offline.z[-1, 0] != 0.0)  # the integral term was on
    assert np.any(offline.saturated[:, 0])  # the run went through the saturated transient


def test_rerun_reproduces_every_recorded_torque(mrp_run, tmp_path) -> None:  # type: ignore[no-untyped-def]
    _, out = mrp_run
    proc = subprocess.run([*SAPPC, "rerun", str(out / "bag"), "--json", str(tmp_path / "rerun.json")],
                          capture_output=True, text=True, cwd=ROOT)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    rerun = json.loads((tmp_path / "rerun.json").read_text())
    assert rerun["mode"] == "lockstep" and rerun["samples"] == rerun["identical"] > 0, proc.stdout

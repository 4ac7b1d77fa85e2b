"""``sappc run`` brings the managed nodes up through their lifecycle (issue 49, item 2): the
controller, estimator, mode and momentum nodes start unconfigured (``managed:=true`` on their
command line, not in ``params.yaml``), and the launcher's plain rclpy client configures each in the
order estimator, modes, controller, momentum, then activates each, before the plant's first sample
(the plant waits for the client's ``state/tf`` subscription, made once every node is active): no
sample is answered by an inactive node.  A transition that fails stops the run with one line naming
the node and the transition, and the node's last log lines; no process is left behind.  The
lockstep results themselves are held to the offline run by the graph's parity tests
(test_modes_graph.py, test_graph.py, ...), unchanged."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import pytest
import yaml

from sappc.graph import launch

from conftest import ROOT

QUICK_FLIGHT = ROOT / "tests" / "modes" / "quick_flight.yaml"
#: quick_flight's managed nodes, in the bring-up's order.
MANAGED = ["estimator", "modes", "controller", "momentum"]


def _processes_in(run_dir: Path) -> list[int]:
    """The processes whose working directory is ``run_dir`` (a run's nodes run there)."""
    pids = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                if Path(os.readlink(entry / "cwd")) == run_dir.resolve():
                    pids.append(int(entry.name))
            except OSError:  # gone meanwhile, or not ours to read
                continue
    return pids


@pytest.mark.slow
@pytest.mark.parametrize("layout", ["processes", "composed"])
def test_the_managed_nodes_are_brought_up_in_order_before_the_first_sample(tmp_path: Path, layout: str) -> None:
    """quick_flight (all four managed nodes): configure estimator, modes, controller, momentum, then
    activate them in that order, each answered before the next is asked and the last before the
    plant's first sample, which comes through the client's gate; every node says so in its log and
    answers no sample inactive; ``params.yaml`` is the plain nodes' (no ``managed``)."""
    compose = layout == "composed"
    result = launch.run_graph(QUICK_FLIGHT, out_dir=tmp_path / "run", progress=False, compose=compose)
    assert result.counts_match, result.mismatched_counts()
    steps = result.bringup
    assert [(s["node"], s["transition"]) for s in steps] == [(n, t) for t in ("configure", "activate") for n in MANAGED]
    assert all(s["success"] for s in steps)
    for before, after in zip(steps, steps[1:]):
        assert before["requested_monotonic_s"] <= before["answered_monotonic_s"] <= after["requested_monotonic_s"]
    record = yaml.safe_load((result.run_dir / launch.BRINGUP_FILE).read_text())
    first_sample = result.plant_timing["first_sample_monotonic_s"]
    assert steps[-1]["answered_monotonic_s"] <= record["active_monotonic_s"] < first_sample <= record["gate_open_monotonic_s"]
    # the plant waited for the gate: one more state/tf subscriber than the recorder
    params = yaml.safe_load((result.run_dir / "params.yaml").read_text())
    assert "state/tf=2" in params["/plant"]["ros__parameters"]["expected_subscribers"]
    assert not any("managed" in p["ros__parameters"] for p in params.values())  # the plain nodes' file
    logs = {name: (result.run_dir / "logs" / f"{'composed' if compose else name}.log").read_text() for name in MANAGED}
    for name, log in logs.items():
        mine = "\n".join(line for line in log.splitlines() if f"[{name}]" in line)
        assert "managed node: unconfigured" in mine and "configured: inactive" in mine and "activated" in mine, mine
        assert mine.index("configured: inactive") < mine.index("activated")
    # no sample answered by an inactive mode or momentum node: their closing lines count none (the
    # controller's 'inactive' answers are those outside TRACK, flight modes' own: test_modes_graph.py)
    assert "samples (0 inactive)" in logs["modes"] and "samples (0 inactive)" in logs["momentum"]
    assert not _processes_in(result.run_dir)


@pytest.mark.parametrize("layout", ["processes", "composed"])
def test_a_failed_transition_stops_the_run_naming_the_node_and_the_transition(tmp_path: Path, layout: str,
                                                                             monkeypatch: pytest.MonkeyPatch) -> None:
    """A parameter the controller refuses at its configure transition (an unknown one, given to it
    through ``params.yaml`` alone: the scenario itself is valid): the run stops with one line naming
    the node and the transition, then the node's last log lines, which say why; the bring-up's
    record ends with the failed transition; every process is stopped."""
    plain = launch.node_parameters

    def with_a_bad_parameter(*args: Any, **kwargs: Any) -> dict[str, Any]:
        params = plain(*args, **kwargs)
        params["/controller"]["ros__parameters"]["bogus"] = 1.0
        return params

    monkeypatch.setattr(launch, "node_parameters", with_a_bad_parameter)
    run_dir = tmp_path / "run"
    with pytest.raises(RuntimeError) as failed:
        launch.run_graph("paper_tracking", out_dir=run_dir, progress=False, compose=layout == "composed", timeout_s=300.0)
    first, *tail = str(failed.value).splitlines()
    assert first == "node controller: its configure transition failed (it stays unconfigured); last log lines:", first
    assert any("configure failed: unknown parameter 'bogus'" in line for line in tail), tail
    record = yaml.safe_load((run_dir / launch.BRINGUP_FILE).read_text())
    assert [(s["node"], s["transition"], s["success"]) for s in record["transitions"]] == [("controller", "configure", False)]
    assert record["active_monotonic_s"] is None and record["gate_open_monotonic_s"] is None  # no sample
    assert not _processes_in(run_dir)

"""The "controller alone beside your plant" walkthrough (docs/tutorials/your-plant.md), run as written: the controller,
the reference and ``examples/external_plant.py`` started by hand, and the same plant driving
``sappc run --plant external``.  No sample may be missed: the nodes wait for one another, so
the start order and discovery time do not matter.

Every start order of the three processes gives the same run (issue 25, defect 6): each process is
started once the previous one is on the graph and has waited :data:`GAP_S` (longer than the
controller's ``lockstep_grace_s`` and the plant's torque wait, so a loop that started without its
third process would have answered samples without the law by then), or all three at once; in
each the controller computes every sample (its closing line counts what it did not compute) and
the plant ends in the same attitude, to the last bit."""

from __future__ import annotations

import itertools
import json
import re
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest
import yaml

from conftest import ROOT, SAPPC, SCENARIOS, cut_short
from shm_watch import ShmWatch

#: The page whose walkthrough block the tests run.
WALKTHROUGH_PAGE = ROOT / "docs" / "tutorials" / "your-plant.md"
#: Longest a walkthrough command may take [s] (30 s of simulation run in about 10 s here).
TIMEOUT_S = 300
#: Wait between one process being on the graph and the start of the next [s]: above the
#: controller's lockstep_grace_s (1 s) and the example plant's torque wait (2 s).
GAP_S = 2.5
#: The node name each walkthrough process has on the graph.
NODE_NAMES = {"controller": "controller", "reference": "reference", "plant": "my_plant"}
#: The start orders checked: every permutation, and all three at once.
ORDERS = [*itertools.permutations(NODE_NAMES), "together"]
#: The plant's closing line: samples, misses, and the attitude it ended in (the numbers as Python prints them).
PLANT_LINE = re.compile(r"my_plant: (\d+) samples, (\d+) missed \(held the last torque\); q_BN at t = \S+ s: (\[.*\])")
#: The controller's closing line when it computed every one of n samples.
ALL_COMPUTED = "finished: answered {n} samples: {n} commanded, 0 held, 0 watchdog zero, 0 refused ({n} control steps computed); 0 input messages rejected"


def _walkthrough() -> tuple[str, list[str]]:
    """(the ``export`` line, the commands of terminals 1 to 3) of the tutorial's walkthrough block."""
    text = WALKTHROUGH_PAGE.read_text()
    block = text.split("<!-- walkthrough: controller-alone", 1)[1].split("```bash\n", 1)[1].split("```", 1)[0]
    lines = [ln for ln in block.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    exports = [ln for ln in lines if ln.startswith("export ")]
    commands = [ln for ln in lines if not ln.startswith("export ")]
    assert len(exports) == 1 and len(commands) == 3, block
    return exports[0], commands


def _as_test(line: str, domain: int) -> str:
    """The walkthrough's line with the two substitutions the test makes: its own domain id (two runs must
    never share one) and the Python running the tests (``.venv/bin/python`` under ``./sappcw``)."""
    assert "ROS_DOMAIN_ID=42" in line or ".venv/bin/python" in line, line
    return line.replace("ROS_DOMAIN_ID=42", f"ROS_DOMAIN_ID={domain}").replace(".venv/bin/python", sys.executable)


def _stop(procs: dict[str, subprocess.Popen[str]], plant_timeout_s: float = TIMEOUT_S) -> dict[str, str]:
    """Wait for the plant to finish, then stop the controller and the reference with SIGINT (Ctrl-C); their outputs."""
    out: dict[str, str] = {}
    try:
        out["plant"] = procs["plant"].communicate(timeout=plant_timeout_s)[0]
    finally:
        for name, p in procs.items():
            if name != "plant":
                p.send_signal(signal.SIGINT)
                out[name] = p.communicate(timeout=60)[0]
        if procs["plant"].poll() is None:
            procs["plant"].kill()
            out["plant"] = procs["plant"].communicate()[0]
    return out


def test_the_controller_alone_walkthrough_runs_verbatim(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from sappc.graph.launch import claim_domain_id

    export, (controller, reference, plant) = _walkthrough()
    with claim_domain_id() as domain, ShmWatch() as watch:
        env_line = _as_test(export, domain) + f" ROS_LOG_DIR={tmp_path / 'log'}"

        def start(command: str) -> subprocess.Popen[str]:
            proc = subprocess.Popen(["bash", "-c", f"{env_line}; exec {_as_test(command, domain)}"], cwd=ROOT, text=True,
                                    stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
            watch.add(proc.pid)
            return proc

        # the plant first: it must wait for the controller, whatever the order
        procs = {"plant": start(plant), "controller": start(controller), "reference": start(reference)}
        out = _stop(procs)
    assert procs["plant"].returncode == 0, out["plant"]
    assert "my_plant: 3001 samples, 0 missed" in out["plant"], out["plant"]
    assert [procs[n].returncode for n in ("controller", "reference")] == [0, 0], out
    assert ALL_COMPUTED.format(n=3001) in out["controller"], out["controller"]
    assert "did not arrive" not in out["controller"], out["controller"]  # no tick answered by the grace: nothing was lost
    watch.assert_clean()


@pytest.fixture(scope="module")
def start_in_order(tmp_path_factory) -> Iterator[Callable[[Any], dict[str, str]]]:  # type: ignore[no-untyped-def]
    """Run the walkthrough (5 s of it) with its processes started in a given order, on a domain
    this module holds, watched by a probe node on that domain; cached per order."""
    import rclpy
    from rclpy.node import Node

    from sappc.graph.launch import claim_domain_id, isolated_environment

    export, commands = _walkthrough()
    commands = [c.replace("--duration 30", "--duration 5") for c in commands]
    tmp = tmp_path_factory.mktemp("orders")
    runs: dict[Any, dict[str, str]] = {}
    with claim_domain_id() as domain:
        with pytest.MonkeyPatch.context() as mp:  # the probe's participant reads them once, when created
            for key, value in isolated_environment(domain, tmp / "probe_log", base={}).items():
                mp.setenv(key, value)
            context = rclpy.context.Context()
            rclpy.init(context=context, domain_id=domain)
            probe = Node("walkthrough_probe", context=context)
        # undone: the tests that follow (sappc run claims its own domain, or ROS_DOMAIN_ID's) see no ROS_DOMAIN_ID

        def on_graph(name: str) -> None:
            deadline = time.monotonic() + TIMEOUT_S
            while NODE_NAMES[name] not in probe.get_node_names():
                assert time.monotonic() < deadline, f"{name} never appeared on the graph"
                time.sleep(0.01)

        def run(order: Any) -> dict[str, str]:
            if order in runs:
                return runs[order]
            env_line = _as_test(export, domain) + f" ROS_LOG_DIR={tmp / 'log'}"
            by_name = dict(zip(("controller", "reference", "plant"), commands))
            procs: dict[str, subprocess.Popen[str]] = {}
            with ShmWatch() as watch:
                for i, name in enumerate(NODE_NAMES if order == "together" else order):
                    procs[name] = subprocess.Popen(["bash", "-c", f"{env_line}; exec {_as_test(by_name[name], domain)}"], cwd=ROOT,
                                                   text=True, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
                    watch.add(procs[name].pid)
                    if order != "together" and i < 2:
                        on_graph(name)
                        time.sleep(GAP_S)
                out = _stop(procs)
            out["codes"] = json.dumps({n: p.returncode for n, p in procs.items()})
            watch.assert_clean()
            runs[order] = out
            return out

        try:
            yield run
        finally:
            probe.destroy_node()
            rclpy.try_shutdown(context=context)


@pytest.mark.slow
@pytest.mark.parametrize("order", ORDERS, ids=["-".join(o) if isinstance(o, tuple) else o for o in ORDERS])
def test_every_start_order_gives_the_same_run(start_in_order, order) -> None:  # type: ignore[no-untyped-def]
    out = start_in_order(order)
    assert json.loads(out["codes"]) == {"controller": 0, "reference": 0, "plant": 0}, out
    m = PLANT_LINE.search(out["plant"])
    assert m is not None and m.group(1, 2) == ("501", "0"), out["plant"]
    assert ALL_COMPUTED.format(n=501) in out["controller"], out["controller"]
    assert "did not arrive" not in out["controller"] and "rejected a message" not in out["controller"], out["controller"]
    first = start_in_order(ORDERS[0])
    assert m.group(3) == PLANT_LINE.search(first["plant"]).group(3), (order, ORDERS[0])  # the same attitude, to the last bit


def test_sappc_run_records_a_run_driven_by_an_external_plant(tmp_path) -> None:  # type: ignore[no-untyped-def]
    scenario = tmp_path / "short.yaml"
    scenario.write_text(yaml.safe_dump(cut_short(yaml.safe_load((SCENARIOS / "paper_tracking.yaml").read_text()), 5.0)))
    out, summary = tmp_path / "run", tmp_path / "run.json"
    watch = ShmWatch().__enter__()
    run = subprocess.Popen([*SAPPC, "run", str(scenario), "--plant", "external", "--out", str(out), "--json", str(summary)],
                           cwd=ROOT, text=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    watch.add(run.pid)
    assert run.stderr is not None
    try:
        said = []
        domain = None
        for line in run.stderr:  # the user reads the domain sappc run claimed, and starts the plant on it
            said.append(line)
            if (m := re.search(r"waiting for your plant on ROS_DOMAIN_ID=(\d+)", line)) is not None:
                domain = int(m.group(1))
                break
        assert domain is not None, "".join(said)
        export, (_, _, plant) = _walkthrough()
        command = _as_test(export, domain) + f" ROS_LOG_DIR={tmp_path / 'log'}; exec " \
            + _as_test(plant, domain).replace("--duration 30", "--duration 5 --subscribers 2 --clock-subscribers 4")
        plant_proc = subprocess.Popen(["bash", "-c", command], cwd=ROOT, text=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        watch.add(plant_proc.pid)
        plant_out, plant_err = plant_proc.communicate(timeout=TIMEOUT_S)
        stdout, stderr = run.communicate(timeout=TIMEOUT_S)
    finally:  # an external plant's run has no time limit: never leave it waiting
        if run.poll() is None:
            run.send_signal(signal.SIGINT)
            run.communicate(timeout=60)
        watch.__exit__(None, None, None)
    assert plant_proc.returncode == 0 and "my_plant: 501 samples, 0 missed" in plant_out, plant_out + plant_err
    assert run.returncode == 0, stdout + stderr
    result = json.loads(summary.read_text())
    assert result["controller_summary"]["commanded"] == 501, result["controller_summary"]
    assert result["recorded"]["/state/attitude"] == 501 and result["recorded"]["/control/torque"] == 501
    assert result["recorded"]["/controller/diagnostics"] == result["published"]["/controller/diagnostics"] == 501
    assert "startup_s" not in result["metrics"] and "first_sample_after_nodes_up_s" not in result["metrics"]  # the plant's start is the user's
    watch.assert_clean()

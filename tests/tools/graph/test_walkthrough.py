"""The "controller alone beside your plant" walkthrough (docs/tutorials/your-plant.md), run as written: the controller,
the reference and ``examples/external_plant.py`` started by hand, and the same plant driving
``sappc run --plant external``.  No sample may be missed: the nodes wait for one another, so
the start order and discovery time do not matter."""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys

from conftest import ROOT, SAPPC, SCENARIOS, shm_files

#: The page whose walkthrough block the tests run.
WALKTHROUGH_PAGE = ROOT / "docs" / "tutorials" / "your-plant.md"
#: Longest a walkthrough command may take [s] (30 s of simulation run in about 10 s here).
TIMEOUT_S = 300


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


def test_the_controller_alone_walkthrough_runs_verbatim(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from sappc.graph.launch import claim_domain_id

    export, (controller, reference, plant) = _walkthrough()
    before = shm_files()
    with claim_domain_id() as domain:
        env_line = _as_test(export, domain) + f" ROS_LOG_DIR={tmp_path / 'log'}"

        def start(command: str) -> subprocess.Popen[str]:
            return subprocess.Popen(["bash", "-c", f"{env_line}; exec {_as_test(command, domain)}"], cwd=ROOT, text=True,
                                    stdout=subprocess.PIPE, stderr=subprocess.STDOUT)

        # the plant first: it must wait for the controller, whatever the order
        my_plant = start(plant)
        nodes = [start(controller), start(reference)]
        try:
            plant_out = my_plant.communicate(timeout=TIMEOUT_S)[0]
        finally:
            for p in nodes:
                p.send_signal(signal.SIGINT)
            logs = [p.communicate(timeout=60)[0] for p in nodes]
            if my_plant.poll() is None:
                my_plant.kill()
                my_plant.wait()
    assert my_plant.returncode == 0, plant_out
    assert "my_plant: 3001 samples, 0 missed" in plant_out, plant_out
    assert [p.returncode for p in nodes] == [0, 0], logs
    assert "finished: 3001 control steps (0 refused), 0 rejected messages" in logs[0], logs[0]
    assert "did not arrive" not in logs[0], logs[0]  # no tick answered by the grace: nothing was lost
    assert shm_files() <= before


def test_sappc_run_records_a_run_driven_by_an_external_plant(tmp_path) -> None:  # type: ignore[no-untyped-def]
    scenario = tmp_path / "short.yaml"
    scenario.write_text(re.sub(r"(?m)^duration_s:.*$", "duration_s: 5.0", (SCENARIOS / "paper_tracking.yaml").read_text()))
    out, summary = tmp_path / "run", tmp_path / "run.json"
    before = shm_files()
    run = subprocess.Popen([*SAPPC, "run", str(scenario), "--plant", "external", "--out", str(out), "--json", str(summary)],
                           cwd=ROOT, text=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
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
            + _as_test(plant, domain).replace("--duration 30", "--duration 5 --subscribers 2")
        my_plant = subprocess.run(["bash", "-c", command], cwd=ROOT, text=True, capture_output=True, timeout=TIMEOUT_S)
        stdout, stderr = run.communicate(timeout=TIMEOUT_S)
    finally:  # an external plant's run has no time limit: never leave it waiting
        if run.poll() is None:
            run.send_signal(signal.SIGINT)
            run.communicate(timeout=60)
    assert my_plant.returncode == 0 and "my_plant: 501 samples, 0 missed" in my_plant.stdout, my_plant.stdout + my_plant.stderr
    assert run.returncode == 0, stdout + stderr
    result = json.loads(summary.read_text())
    assert result["controller_summary"]["commanded"] == 501, result["controller_summary"]
    assert result["recorded"]["/state/attitude"] == 501 and result["recorded"]["/control/torque"] == 501
    assert result["recorded"]["/controller/diagnostics"] == result["published"]["/controller/diagnostics"] == 501
    assert "startup_s" not in result["metrics"]  # the plant's start is the user's
    assert shm_files() <= before

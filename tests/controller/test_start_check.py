"""A run that starts at the 180 deg singularity (q_e0 = 0) is refused by every entry point with
the same error (issue 12): the check belongs to the start of a run in the controller core, which
the offline runner, Monte Carlo, the node and rerun all go through.

- ``sappc simulate``: one line on stderr, exit status 2;
- the batch path of Monte Carlo (:func:`sappc.offline.simulate.run_scenario` with (N, 4) initial
  attitudes): the error names the singular run; ``sappc montecarlo``: one line, exit status 2;
- rerun: the controller it builds from a bag's parameters refuses the same first sample with the
  same error, and :func:`sappc.analysis.rerun.rerun_bag` counts the step as refused;
- the node: ``tests/nodes/test_nodes.py::test_a_start_at_the_singularity_is_refused_as_offline``.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import numpy as np
import pytest
import yaml

from gnc_common.validation import InputError
from sappc.offline.simulate import run_scenario
from sappc.scenario import load_scenario
from sappc_controller.core.base import SINGULAR_Q0_AT_START

from conftest import ROOT, SAPPC, SCENARIOS

#: 180 deg about x from the reference's identity q_RN0 (scalar last): q_e0 = 0.
Q_SINGULAR = [1.0, 0.0, 0.0, 0.0]
#: The paper's initial attitude (as in paper_tracking.yaml, normalised on load).
Q_PAPER = np.array([0.3254, 0.4068, -0.3254, 0.7891]) / np.linalg.norm([0.3254, 0.4068, -0.3254, 0.7891])


def singular_scenario(tmp_path: Path) -> Path:
    """paper_tracking.yaml with the initial attitude 180 deg away from the reference's."""
    raw = yaml.safe_load((SCENARIOS / "paper_tracking.yaml").read_text())
    assert raw["reference"]["q_RN0"] == [0.0, 0.0, 0.0, 1.0]
    raw["name"] = "singular_start"
    raw["initial_state"]["q_BN"] = Q_SINGULAR
    path = tmp_path / "singular_start.yaml"
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    return path


def offline_error(scenario_path: Path) -> str:
    """The error of the offline runner on the scenario (the reference message for the others)."""
    with pytest.raises(InputError) as exc:
        run_scenario(load_scenario(scenario_path))
    return str(exc.value)


def test_the_offline_runner_refuses_a_start_at_the_singularity(tmp_path) -> None:  # type: ignore[no-untyped-def]
    message = offline_error(singular_scenario(tmp_path))
    assert "180 deg singularity" in message and "q_e0 = 0 " in message and "(run 0)" in message
    assert f"q_e0 >= {SINGULAR_Q0_AT_START}" in message


def test_sappc_simulate_prints_the_error_in_one_line_and_exits_2(tmp_path) -> None:  # type: ignore[no-untyped-def]
    scenario = singular_scenario(tmp_path)
    proc = subprocess.run([*SAPPC, "simulate", str(scenario)], capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert proc.stderr == f"sappc: error: {offline_error(scenario)}\n"  # one line, no traceback
    assert "180 deg singularity" in proc.stderr and proc.stdout == ""  # no metrics of a run that did not start


def test_the_batch_path_names_the_singular_run(tmp_path) -> None:  # type: ignore[no-untyped-def]
    scenario = load_scenario(singular_scenario(tmp_path))
    q0 = np.tile(Q_PAPER, (4, 1))
    q0[2] = Q_SINGULAR
    with pytest.raises(InputError, match=r"q_e0 = 0 \(run 2\) is at the 180 deg singularity"):
        run_scenario(scenario, q_BN0=q0)
    q0[2] = [np.sin(np.pi / 2 - 1e-7), 0.0, 0.0, np.cos(np.pi / 2 - 1e-7)]  # 179.99999 deg: q_e0 = 1e-7 < 1e-6
    with pytest.raises(InputError, match=r"q_e0 = 1e-07 \(run 2\)"):
        run_scenario(scenario, q_BN0=q0)


def test_sappc_montecarlo_stops_with_the_same_error(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """Euler angles (-90, -90, -90) deg in ZYX order: q_e0 = cos^3(45) - sin^3(45) = 0."""
    raw = yaml.safe_load((SCENARIOS / "paper_montecarlo.yaml").read_text())
    raw["montecarlo"]["initial_attitude"].update(sequence="ZYX", low_deg=-90.0, high_deg=-90.0)
    path = tmp_path / "mc_singular.yaml"
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    proc = subprocess.run([*SAPPC, "montecarlo", str(path), "--runs", "2", "--workers", "1", "--no-progress", "--out", str(tmp_path / "mc")],
                          capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert proc.stderr.startswith("sappc: error: initial error quaternion scalar part q_e0 = ") and proc.stderr.count("\n") == 1
    assert "(run 0) is at the 180 deg singularity" in proc.stderr


def test_a_campaign_chunk_names_the_campaign_run_number() -> None:
    """Run 7 simulated alone in its chunk is run 0 of the batch; the error names run 7."""
    from sappc.montecarlo.campaign import simulate_runs

    raw = yaml.safe_load((SCENARIOS / "paper_montecarlo.yaml").read_text())
    raw["montecarlo"]["initial_attitude"].update(sequence="ZYX", low_deg=-90.0, high_deg=-90.0)
    with pytest.raises(InputError, match=r"\(run 7\) is at the 180 deg singularity"):
        simulate_runs(raw, 3, [7], 0)


def _rerun_bag(tmp_path: Path, scenario_path: Path, q_first: list[float]) -> Path:
    """A lockstep bag of three control samples (the first at ``q_first``, then the paper's
    attitude) with the controller's parameters, as ``sappc run`` records them."""
    from bagmaker import write_bag

    from sappc.bag.read import PARAMS_RECORD
    from sappc.scenario import controller_params_yaml
    from sappc_msgs_py import contract as c
    from sappc_msgs_py.convert import clock_msg, quaternion_msg, torque_msg, vector3_msg

    messages = []
    for k in range(3):
        t, log = 0.01 * k, 10_000_000 * k
        q = q_first if k == 0 else Q_PAPER
        messages += [
            (c.CLOCK.name, c.CLOCK.type_name, clock_msg(t), log),
            (c.STATE_ATTITUDE.name, c.STATE_ATTITUDE.type_name, quaternion_msg(q, t, c.STATE_ATTITUDE), log + 1),
            (c.STATE_RATE.name, c.STATE_RATE.type_name, vector3_msg([0.0, 0.0, 0.0], t, c.STATE_RATE), log + 2),
            (c.REFERENCE_ATTITUDE.name, c.REFERENCE_ATTITUDE.type_name, quaternion_msg([0.0, 0.0, 0.0, 1.0], t, c.REFERENCE_ATTITUDE), log + 3),
            (c.REFERENCE_RATE.name, c.REFERENCE_RATE.type_name, vector3_msg([0.0, 0.0, 0.0], t, c.REFERENCE_RATE), log + 4),
            (c.REFERENCE_ACCELERATION.name, c.REFERENCE_ACCELERATION.type_name, vector3_msg([0.0, 0.0, 0.0], t, c.REFERENCE_ACCELERATION), log + 5),
            (c.CONTROL_TORQUE.name, c.CONTROL_TORQUE.type_name, torque_msg([0.0, 0.0, 0.0], t, c.CONTROL_TORQUE), log + 6),
        ]
    params = controller_params_yaml(load_scenario(scenario_path))
    return write_bag(tmp_path / "rerun.mcap", messages, metadata={PARAMS_RECORD: {"text": params}})


def test_rerun_refuses_the_singular_start_with_the_same_error(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from sappc.analysis.rerun import rerun_bag
    from sappc.bag.read import PARAMS_RECORD, read_bag
    from sappc_controller.params import CONTROLLER_CLASSES, controller_from_parameters_file

    scenario = singular_scenario(tmp_path)
    bag = read_bag(_rerun_bag(tmp_path, scenario, Q_SINGULAR))
    # the controller rerun builds from the bag, stepped on the bag's first sample: the offline error
    kind, config, dt = controller_from_parameters_file(bag.metadata[PARAMS_RECORD]["text"])
    controller = CONTROLLER_CLASSES[kind](config)
    with pytest.raises(InputError) as exc:
        controller.step(0.0, dt, Q_SINGULAR, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    assert str(exc.value) == offline_error(scenario)
    assert controller.t0 is None  # refused: the run has not started
    # rerun_bag: the first step is refused (the node commanded zero torque); the run starts at the next
    r = rerun_bag(bag)
    assert r.failed_steps == 1 and r.stamps_ns.tolist() == [0, 10_000_000, 20_000_000]
    assert np.all(r.recomputed[0] == 0.0) and np.all(np.isfinite(r.recomputed)) and np.any(r.recomputed[1] != 0.0)
def test_sappc_run_stops_before_launching_with_the_same_error(tmp_path) -> None:  # type: ignore[no-untyped-def]
    scenario = singular_scenario(tmp_path)
    proc = subprocess.run([*SAPPC, "run", str(scenario), "--out", str(tmp_path / "run")], capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert proc.stderr == f"sappc: error: {offline_error(scenario)}\n"
    assert not (tmp_path / "run").exists()  # no process started, nothing recorded

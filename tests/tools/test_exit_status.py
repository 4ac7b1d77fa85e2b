"""The exit statuses of ``sappc simulate`` and ``sappc run`` (:mod:`sappc.cli`), when several
outcomes of a run apply at once (issue 25, section 3).

The documented order (the module docstring of :mod:`sappc.cli`, ``docs/how-to/faults.md``): a
controller that never commanded a torque (3) says more than a requirement the run broke (4), which
says more than a topic recorded with another count than was published (1); 0 only when none
applies.  A run whose controller reported nothing (``commanded`` unknown: a plant of one's own
without the controller's diagnostics) is not a run that never commanded."""

from __future__ import annotations

import copy
import itertools
import subprocess

import pytest
import yaml

from conftest import ROOT, SAPPC, SCENARIOS
from sappc.cli import EXIT_CONTROLLER_NEVER_COMMANDED, EXIT_INVALID_INPUT, EXIT_REQUIREMENT_FAILED, main, run_exit_status

#: The documented numbers (the command's users compare against them, not against the names).
DOCUMENTED = {"invalid input": 2, "never commanded": 3, "requirement failed": 4}


def test_the_exit_status_constants_are_the_documented_numbers() -> None:
    assert (EXIT_INVALID_INPUT, EXIT_CONTROLLER_NEVER_COMMANDED, EXIT_REQUIREMENT_FAILED) == tuple(DOCUMENTED.values())


@pytest.mark.parametrize(("mismatch", "commanded", "failed"), list(itertools.product([False, True], [None, 0, 1, 250], [False, True])))
def test_every_combination_of_outcomes_gives_the_documented_status(mismatch: bool, commanded: int | None, failed: bool) -> None:
    """All 16 combinations: a count mismatch or not; the controller's commanded samples unknown,
    none, one or many; a requirement broken or not."""
    mismatched = {"/state/rate": (6001, 6000)} if mismatch else {}
    controller = {"samples": 6001, "commanded": commanded}
    broken = ["steady_max_abs_qev = 2.7e-4 > 1e-4"] if failed else []
    if commanded == 0:
        expected = 3
    elif failed:
        expected = 4
    elif mismatch:
        expected = 1
    else:
        expected = 0
    assert run_exit_status(mismatched, controller, broken) == expected
    assert run_exit_status(mismatched, controller, tuple(broken)) == expected  # any sequence of failed requirements


def _never_commanding(tmp_path, requirements: dict[str, float]):  # type: ignore[no-untyped-def]
    """Experiment 1, 2 s long, its state lost from 0 s to the end: the controller never has a
    valid state, so the watchdog answers every sample with zero torque."""
    raw = copy.deepcopy(yaml.safe_load((SCENARIOS / "paper_tracking.yaml").read_text()))
    raw["duration_s"] = 2.0
    raw["faults"] = [{"kind": "sensor_dropout", "start_s": 0.0}]
    raw["metrics"] = {**raw["metrics"], "requirements": requirements}
    path = tmp_path / "never.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


def test_simulate_of_a_run_that_never_commands_and_breaks_a_requirement_exits_3(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    """Both outcomes at once, through the command: it prints both (the controller's answers and the
    broken requirement) and exits with the status of "never commanded"."""
    path = _never_commanding(tmp_path, {"time_outside_constraint_s_max": 0.0})
    assert main(["simulate", str(path)]) == DOCUMENTED["never commanded"]
    out = capsys.readouterr().out
    assert "computed the torque of 0 of 201 samples; not commanded: watchdog zero 201" in out
    assert out.splitlines()[-1] == ("FAILED: control lost: the controller computed the torque of 0 of 201 samples (0%, fewer than 50%); "
                                    "time_outside_constraint_s = 2.01 > 0")


def test_simulate_of_a_run_that_never_commands_and_meets_its_requirements_exits_3(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    """A requirement the zero torque meets (no torque at all) does not hide that the controller never
    commanded: the status says so, and the verdict line names the loss of control (the run flew open loop)."""
    path = _never_commanding(tmp_path, {"max_abs_torque_Nm_max": 0.0})
    assert main(["simulate", str(path)]) == DOCUMENTED["never commanded"]
    assert capsys.readouterr().out.splitlines()[-1] == \
        "FAILED: control lost: the controller computed the torque of 0 of 201 samples (0%, fewer than 50%)"


def test_invalid_input_exits_2_with_one_line(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    path = tmp_path / "bad.yaml"
    path.write_text("duration_s: true\n")
    assert main(["simulate", str(path)]) == DOCUMENTED["invalid input"]
    err = capsys.readouterr().err
    assert err.startswith("sappc: error: ") and err.count("\n") == 1 and "Traceback" not in err


def test_sappc_alone_exits_2_with_the_usage_and_a_hint(capsys) -> None:  # type: ignore[no-untyped-def]
    """In-process twin of test_cli_conventions' check of the process: no command is invalid input
    (status 2), answered with the usage line and the hint, nothing on stdout."""
    from sappc.cli import NO_COMMAND_HINT

    assert main([]) == DOCUMENTED["invalid input"]
    out, err = capsys.readouterr()
    lines = err.splitlines()
    assert out == "" and len(lines) == 2 and lines[0].startswith("usage: sappc ") and lines[1] == NO_COMMAND_HINT, err


def test_output_into_a_closed_pipe_stops_quietly_with_status_1() -> None:
    """``sappc params ... | head -c 0``: the reader is gone before the command writes; it stops
    with status 1 and no traceback (Python's recipe for SIGPIPE)."""
    proc = subprocess.Popen([*SAPPC, "params", str(SCENARIOS / "paper_tracking.yaml")], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            cwd=ROOT)
    assert proc.stdout is not None and proc.stderr is not None
    proc.stdout.close()  # the reader goes away before the first write
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=120) == 1, err
    assert "Traceback" not in err and "BrokenPipeError" not in err, err


def test_a_degraded_real_time_run_says_why_in_its_verdict(capsys) -> None:  # type: ignore[no-untyped-def]
    """The real-time summary's missed and stale frames and the controller's held and zeroed samples
    end the FAILED line (issue 46's loaded run: 272 missed frames, 1,456 held torques); a clean run
    adds nothing."""
    from types import SimpleNamespace

    from sappc.cli import _print_verdict, _realtime_degraded

    realtime = {"missed_frames": 272, "stale_torque_frames": 0}
    controller = {"samples": 6001, "commanded": 4545, "held": 1456, "watchdog_zero": 0}
    why = _realtime_degraded(realtime, controller)
    assert why == "real time degraded: 272 missed frames, 1456 held torques"
    assert _realtime_degraded({"missed_frames": 0, "stale_torque_frames": 0}, {"held": 0, "watchdog_zero": 0}) == ""
    scenario = SimpleNamespace(metrics=SimpleNamespace(requirements={"settling_time_s_max": 20.0}))
    _print_verdict(scenario, ["settling_time_s = 57 > 20"], why)
    assert capsys.readouterr().out == "FAILED: settling_time_s = 57 > 20 (real time degraded: 272 missed frames, 1456 held torques)\n"

"""Scenario files and the `sappc simulate` command: strict loading, clear errors, outputs."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest
import yaml

from conftest import ROOT, SAPPC, SCENARIOS, cut_short
from figure_checks import NO_EMPTY_LOG_AXES, assert_every_axes_shows_data, capture_figures
from sappc.cli import main
from sappc.scenario import load_scenario, scenario_from_mapping
from gnc_common.validation import ConfigError

PAPER = sorted(SCENARIOS.glob("paper_*.yaml"))


def _raw(name: str = "paper_tracking.yaml") -> dict:
    return yaml.safe_load((SCENARIOS / name).read_text())


@pytest.mark.parametrize("path", PAPER, ids=lambda p: p.name)
def test_paper_scenarios_load_and_validate_every_controller(path) -> None:
    s = load_scenario(path)
    for kind in s.controllers:
        s.controller_config(kind)
    assert abs(sum(s.q_BN0**2) - 1.0) < 1e-15


def test_table1_l_gives_the_infeasibility_error_through_the_cli(tmp_path, capsys) -> None:
    raw = _raw()
    raw["controllers"]["sappc"]["rpf"]["l"] = 0.5
    bad = tmp_path / "table1.yaml"
    bad.write_text(yaml.safe_dump(raw))
    assert main(["simulate", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "rpf.l = 0.5 is infeasible" in err and "0.0999927 <= l <= 0.491939" in err and "Traceback" not in err


@pytest.mark.parametrize(
    "mutate, fragment",
    [
        (lambda r: r.update(durration_s=5), "unknown key durration_s"),
        (lambda r: r["controllers"]["sappc"]["gains"].update(Kq=1.0), "unknown key controllers.sappc.gains.Kq"),
        (lambda r: r["controllers"]["sappc"].update(B0=-1.0), "B0 must be finite and > 0"),
        (lambda r: r["plant"].update(inertia_kg_m2=[[1, 0, 0], [0, -2, 0], [0, 0, 1]]), "plant.inertia_kg_m2 must be positive definite"),
        (lambda r: r["initial_state"].update(q_BN=[0, 0, 0, 0]), "initial_state.q_BN .* has norm 0"),
        (lambda r: r["initial_state"].update(q_BN=[0, float("nan"), 0, 1]), "initial_state.q_BN contains a non-finite value nan"),
        (lambda r: r.update(control_period_s=0), "control_period_s must be finite and > 0"),
        (lambda r: r["disturbances"].append({"kind": "gust"}), r"disturbances\[1\].kind = 'gust' is unknown"),
        (lambda r: r["disturbances"].append({"kind": "pulse", "start_s": 1.0, "torque_Nm": [1, 1, 1]}), r"missing key disturbances\[1\].duration_s"),
        (lambda r: r["controllers"].update(pid={}), "unknown key controllers.pid"),
        (lambda r: r["actuator"].update(max_torque_Nm=0.0), "actuator.max_torque_Nm"),
        (lambda r: r.update(controller="lqr"), r"^controller: unknown controller 'lqr' \(choose from sappc, trappc, blfppc, mrp_feedback\)$"),
        (lambda r: r.update(controller="sapc"), r"^controller: unknown controller 'sapc', did you mean 'sappc'\? \(choose from "),  # issue 46
    ],
)
def test_bad_scenarios_name_the_offending_key(mutate, fragment) -> None:
    raw = _raw()
    mutate(raw)
    with pytest.raises(ConfigError, match=fragment):
        scenario_from_mapping(raw)


@pytest.mark.parametrize("mutate", [lambda r: r.update(durration_s=5), lambda r: r.pop("plant"), lambda r: r["controllers"].update(pid={})],
                         ids=["unknown_top_key", "missing_key", "nested_key"])
def test_an_error_in_a_scenario_file_names_the_file_once(tmp_path, mutate) -> None:
    """The loader prefixes the file's path to the validator's message, unless it is there."""
    raw = _raw()
    mutate(raw)
    path = tmp_path / "typo.yaml"
    path.write_text(yaml.safe_dump(raw))
    with pytest.raises(ConfigError) as err:
        load_scenario(path)
    assert str(err.value).startswith(f"{path}: ") and str(err.value).count(str(path)) == 1, str(err.value)


def test_missing_and_malformed_files_are_clear(tmp_path) -> None:
    with pytest.raises(ConfigError, match="nope.yaml.*: no such file"):
        load_scenario(tmp_path / "nope.yaml")
    (tmp_path / "bad.yaml").write_text("name: [unclosed\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_scenario(tmp_path / "bad.yaml")


@pytest.mark.parametrize("command", [["simulate"], ["params"], ["run", "--out", "RUN"]])
def test_a_file_that_is_not_utf8_is_one_line_naming_it_and_the_config_error_status(tmp_path, command) -> None:  # type: ignore[no-untyped-def]
    """A scenario saved in Latin-1 (issue 25, 2.3: an 18-line UnicodeDecodeError traceback, exit 1):
    one line naming the file and the byte, exit status 2, in every command that reads a scenario."""
    path = tmp_path / "latin1.yaml"
    path.write_bytes(yaml.safe_dump(_raw("paper_tracking.yaml")).encode() + "# réglage\n".encode("latin-1"))
    argv = [str(tmp_path / "run") if a == "RUN" else a for a in command]
    proc = subprocess.run([*SAPPC, argv[0], str(path), *argv[1:]], capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and str(path) in lines[0] and "UTF-8" in lines[0] and "0xe9" in lines[0], proc.stderr
    assert not (tmp_path / "run").exists()


def test_simulate_writes_json_and_plots(tmp_path) -> None:
    raw = _raw("paper_fault.yaml")
    cut_short(raw, 52.0)
    raw["metrics"]["steady_from_s"] = 25.0
    path = tmp_path / "short.yaml"
    path.write_text(yaml.safe_dump(raw))
    out = subprocess.run(
        [sys.executable, "-m", "sappc", "simulate", str(path), "--controller", "blfppc", "--json", str(tmp_path / "m.json"), "--out", str(tmp_path / "fig")],
        capture_output=True, text=True, cwd=ROOT, env={**os.environ, "PYTHONWARNINGS": "error:Data has no positive values"},
    )
    # the cut ends 2 s into the 1 N m fault's transient, its error beyond the loss bound: lost, by the rule (exit 4, one line)
    assert out.returncode == 4 and out.stdout.splitlines()[-1].startswith("FAILED: control lost: max |q_ev,i| above 0.01"), out.stdout + out.stderr
    assert "controller blfppc" in out.stdout
    report = json.loads((tmp_path / "m.json").read_text())
    m = report["metrics"]
    for key in ("settling_time_s", "steady_max_abs_qev", "steady_mean_abs_qev", "rpf_error_at_t2", "overshoot", "max_abs_torque_Nm",
                "saturation_fraction", "time_outside_constraint_s", "returned_to_constraint", "wall_time_s"):
        assert key in m
    assert m["left_constraint_after_fault"] is True
    assert report["parameters"]["controller"]["gains"]["K1"] == raw["controllers"]["blfppc"]["gains"]["K1"]
    assert report["parameters"]["scenario"]["duration_s"] == 52.0
    for name in ("qev.png", "qev_zoom.png", "qev_log.png", "torque.png"):
        assert (tmp_path / "fig" / name).stat().st_size > 10_000


@NO_EMPTY_LOG_AXES
def test_the_run_figures_show_what_they_draw(tmp_path, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """Every panel of a run's figures has data in view, a run whose controller starts at 0.5 s (no
    performance function before: NaN rows) and one with a sudden fault included."""
    from sappc.analysis.plots import plot_run
    from sappc.offline.simulate import simulate

    figures = capture_figures(monkeypatch)
    for name, faults in (("paper_tracking.yaml", [{"kind": "sensor_dropout", "start_s": 0.0, "end_s": 0.5}]), ("paper_fault.yaml", [])):
        raw = _raw(name)
        raw["duration_s"], raw["faults"] = 52.0, faults
        scenario = scenario_from_mapping(raw)
        result = simulate(scenario)
        plot_run(result.history, tmp_path / name, title=name, fault_windows=scenario.event_windows())
    assert len(figures) == 10
    assert_every_axes_shows_data(figures, at_least=100)


def test_a_whole_record_too_long_for_this_machine_is_refused_before_anything_is_allocated() -> None:
    """duration_s = 1e9 s at 100 Hz is 1e11 samples: the scenario loads (a run in blocks, what
    ``sappc simulate`` and campaigns fly, holds nothing of its length), but keeping its whole record
    (``run_scenario(keep_history=True)``, the tests' and ``simulate()``'s full history) is refused in
    one line naming the key and the longest duration that fits, in well under a second (nothing is
    allocated)."""
    import time

    from sappc.offline.simulate import run_scenario
    from sappc.scenario import RUN_BYTES_PER_SAMPLE, RUN_MEMORY_SHARE, check_run_fits_in_memory, machine_memory_bytes

    raw = yaml.safe_load((SCENARIOS / "paper_tracking.yaml").read_text())
    raw["duration_s"] = 1.0e9
    scenario = scenario_from_mapping(raw)
    start = time.perf_counter()
    with pytest.raises(ConfigError) as err:
        run_scenario(scenario, keep_history=True)
    assert time.perf_counter() - start < 5.0
    longest = (RUN_MEMORY_SHARE * machine_memory_bytes() / RUN_BYTES_PER_SAMPLE - 1) * 0.01
    assert str(err.value).startswith("duration_s = 1000000000.0 at control_period_s = 0.01 is 1e+11 control samples")
    assert f"duration_s <= {longest:.6g} s" in str(err.value) and "\n" not in str(err.value)
    check_run_fits_in_memory(0.9 * longest, 0.01)  # just inside the bound: accepted


@pytest.mark.parametrize("moments", [(1.0, 1.0, 4.0), (1.0, 2.0, 3.5)])
def test_an_inertia_that_no_body_has_is_refused(moments) -> None:  # type: ignore[no-untyped-def]
    """Positive definite but violating I1 + I2 >= I3 (e.g. diag(1, 1, 4)): not a rigid body."""
    raw = yaml.safe_load((SCENARIOS / "paper_tracking.yaml").read_text())
    raw["plant"]["inertia_kg_m2"] = [[moments[0], 0, 0], [0, moments[1], 0], [0, 0, moments[2]]]
    with pytest.raises(ConfigError, match=r"plant.inertia_kg_m2 is not the inertia of a rigid body: its principal moments .* violate the triangle inequality"):
        scenario_from_mapping(raw)
    raw["plant"]["inertia_kg_m2"] = [[1.0, 0, 0], [0, 1.0, 0], [0, 0, 2.0]]  # a flat plate: the limit, accepted
    scenario_from_mapping(raw)


def test_the_run_commands_plant_choices_are_the_launchers() -> None:
    """``sappc run --plant`` lists its choices without importing the launcher (the parser is built
    for every command); they must stay the launcher's ``PLANTS``."""
    from sappc.cli import _parser
    from sappc.graph.launch import PLANTS

    run = next(a for a in _parser()._subparsers._group_actions[0].choices["run"]._actions if "--plant" in a.option_strings)  # type: ignore[index, union-attr]
    assert tuple(run.choices) == PLANTS and run.default == "native"


def _padded(path, size: int) -> None:  # type: ignore[no-untyped-def]
    """``path``: experiment 1's scenario followed by one comment line, ``size`` bytes in all (a valid scenario)."""
    text = (SCENARIOS / "paper_tracking.yaml").read_bytes()
    path.write_bytes(text + b"#" + b"x" * (size - len(text) - 2) + b"\n")
    assert path.stat().st_size == size


def test_a_scenario_file_above_the_size_limit_is_refused_before_it_is_parsed(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    """A file of MAX_SCENARIO_BYTES loads; one byte more is refused with one line naming its size and
    the limit (status 2), not parsed (a 50 MB file of keys took 66 s and 3.2 GB to be refused)."""
    from sappc.scenario import MAX_SCENARIO_BYTES

    assert MAX_SCENARIO_BYTES >= 100 * max(p.stat().st_size for p in SCENARIOS.glob("*.yaml"))  # room for any hand-written one
    at_limit, above = tmp_path / "at_limit.yaml", tmp_path / "above.yaml"
    _padded(at_limit, MAX_SCENARIO_BYTES)
    _padded(above, MAX_SCENARIO_BYTES + 1)
    assert load_scenario(at_limit).raw == load_scenario(SCENARIOS / "paper_tracking.yaml").raw
    assert main(["params", str(above)]) == 2
    err = capsys.readouterr().err
    assert err == (f"sappc: error: {above} is {MAX_SCENARIO_BYTES + 1:,} bytes, more than a scenario file may be "
                   f"({MAX_SCENARIO_BYTES:,} bytes): is it the right file?\n"), err


def test_simulate_duration_flies_the_scenario_longer_and_draws_its_figures_from_the_envelope(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    """``--duration 250``: the paper's task for 25001 samples (beyond the envelope's full-rate
    threshold: the figures come from the bounded envelope), every figure written, the JSON's
    scenario the file's with the new duration; a bad duration is one line naming the option."""
    from sappc.evaluation.envelope import FULL_RATE_MAX_SAMPLES

    out, js = tmp_path / "figs", tmp_path / "m.json"
    assert main(["simulate", "paper_tracking", "--duration", "250", "--out", str(out), "--json", str(js), "--no-progress"]) == 0
    report = json.loads(js.read_text())
    assert report["controller_summary"]["samples"] == 25001 > FULL_RATE_MAX_SAMPLES
    assert report["parameters"]["scenario"]["duration_s"] == 250.0
    assert {p.name for p in out.glob("*.png")} >= {"qev.png", "qev_zoom.png", "qev_log.png", "torque.png", "eps_lyapunov.png"}
    capsys.readouterr()
    assert main(["simulate", "paper_tracking", "--duration", "-1"]) == 2
    err = capsys.readouterr().err
    assert "--duration -1.0" in err and "duration_s" in err and err.count("\n") == 1


def test_simulate_record_writes_a_bag_that_report_reads(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    """``--record DIR``: the run's bag (rosbag2 MCAP of the graph's topics), which ``sappc report``
    reads with the run's metrics; a DIR that exists is refused before the run (exit 2, one line)."""
    bag, sim_json, rep_json = tmp_path / "bag", tmp_path / "sim.json", tmp_path / "rep.json"
    assert main(["simulate", "paper_tracking", "--duration", "3", "--record", str(bag), "--json", str(sim_json), "--no-progress"]) in (0, 4)
    assert (bag / "metadata.yaml").is_file() and list(bag.glob("*.mcap"))
    assert main(["report", str(bag), "--out", str(tmp_path / "report"), "--json", str(rep_json)]) == 0
    simulated, reported = json.loads(sim_json.read_text())["metrics"], json.loads(rep_json.read_text())["metrics"]
    assert reported["steady_max_abs_qev"] == simulated["steady_max_abs_qev"] and reported["max_abs_torque_Nm"] == simulated["max_abs_torque_Nm"]
    capsys.readouterr()
    assert main(["simulate", "paper_tracking", "--duration", "3", "--record", str(bag)]) == 2
    assert capsys.readouterr().err.count("\n") == 1

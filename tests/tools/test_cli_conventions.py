"""The command line's conventions: ``--version``, ``sappc`` alone, exit statuses in every
``--help``, ``--json -`` on stdout with nothing else there, the one default output root
(``runs/<command>/<name>``), ``--out`` everywhere (``simulate --plots`` a deprecated alias), and
the bundled scenarios by name (``sappc scenarios``, ``sappc scenarios copy``)."""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
from importlib.metadata import version
from pathlib import Path

import pytest
import yaml

from conftest import ROOT, SAPPC, SCENARIOS, cli_commands, cut_short
from gnc_common.validation import ConfigError
from sappc import cli
from sappc import scenario as scenario_module
from sappc.files import OUTPUT_ROOT, SCENARIOS_DIR, bag_run_name, bundled_scenarios, copy_scenario, default_output_dir, scenario_path
from sappc.scenario import load_scenario, read_scenario_mapping


def _sappc(*args: str, cwd: Path = ROOT, timeout: float = 300) -> subprocess.CompletedProcess[str]:
    return subprocess.run([*SAPPC, *args], capture_output=True, text=True, cwd=cwd, timeout=timeout)


def _short_scenario(tmp_path: Path, name: str = "paper_tracking", duration_s: float = 0.5) -> Path:
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(cut_short(read_scenario_mapping(SCENARIOS / f"{name}.yaml"), duration_s)))
    return path


# ---- --version, sappc alone, --help ------------------------------------------------------


def test_version_prints_the_installed_version() -> None:
    proc = _sappc("--version")
    assert proc.returncode == 0 and proc.stdout == f"sappc {version('sappc')}\n", proc.stdout + proc.stderr


def test_the_command_line_parses_without_the_scenario_models_or_the_package_metadata() -> None:
    # what every command pays before its own work (sappc report forks its figure worker right
    # after): the parser, with its --controller choices, needs neither sappc.scenario (its models,
    # ~60 ms) nor importlib.metadata (--version looks the version up only when asked, ~17 ms)
    code = ("import sys; from sappc import cli; cli._parser().parse_args(['report', 'x']); "
            "print(sorted(m for m in ('sappc.scenario', 'importlib.metadata', 'yaml') if m in sys.modules))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert proc.returncode == 0 and proc.stdout == "[]\n", proc.stdout + proc.stderr
    assert cli.ControllerKind is scenario_module.ControllerKind  # one class: the scenario's kinds are the choices


def test_sappc_alone_prints_the_usage_and_a_hint_without_a_traceback() -> None:
    proc = _sappc()
    assert proc.returncode == 2 and proc.stdout == "", proc.stdout
    lines = proc.stderr.splitlines()
    assert len(lines) == 2 and lines[0].startswith("usage: sappc ") and lines[1] == cli.NO_COMMAND_HINT, proc.stderr


def test_every_command_has_exit_statuses_and_its_help_lists_them() -> None:
    commands = cli_commands(cli._parser())
    top = {name.split(" ")[0] for name in commands}
    assert top == set(cli.EXIT_STATUSES), "a command without its exit statuses, or statuses of no command"
    for name, sub in commands.items():
        text = sub.format_help()
        statuses = cli.EXIT_STATUSES[name.split(" ")[0]]
        assert "exit status:" in text, name
        for code, meaning in statuses:
            assert f"  {code:<4} {meaning}" in text, (name, code)
        assert {0, 2, 130} <= {code for code, _ in statuses}, name


def test_the_help_as_printed_keeps_one_status_per_line() -> None:
    proc = _sappc("run", "--help")
    assert proc.returncode == 0
    section = proc.stdout.split("exit status:\n", 1)[1].splitlines()
    assert [int(ln.split()[0]) for ln in section[:-1]] == [0, 1, 2, 3, 4, 130], proc.stdout
    assert section[-1] == "several statuses at once: the first of 3, 4, 1", proc.stdout


def test_every_argument_says_what_it_is_and_states_its_default() -> None:
    """What ``--help`` and the reference page show of each argument: a help text, which names
    the default when the argument has one (argparse prints none of its own)."""
    for name, sub in cli_commands(cli._parser()).items():
        for a in sub._actions:
            if isinstance(a, (argparse._HelpAction, argparse._SubParsersAction)) or a.help == argparse.SUPPRESS:
                continue
            what = f"sappc {name} {'/'.join(a.option_strings) or a.dest}"
            assert a.help, f"{what}: no help"
            if a.default not in (None, False):
                assert "default" in a.help, f"{what}: default {a.default!r} not stated in its help"


@pytest.mark.parametrize(("argv", "line"), [
    (["simulat", "paper_tracking"], "sappc: error: argument COMMAND: invalid choice: 'simulat', did you mean 'simulate'? (choose from 'simulate', "),
    (["simulate", "paper_trackin"], "sappc: error: scenario 'paper_trackin': no such file, and no bundled scenario of that name, "
                                    "did you mean 'paper_tracking'? (bundled: "),
    (["simulate", "paper-tracking"], "sappc: error: scenario 'paper-tracking': no such file, and no bundled scenario of that name, "
                                     "did you mean 'paper_tracking'? (bundled: "),
    (["simulate", "paper_tracking", "--controller", "sapc"],
     "sappc simulate: error: argument --controller: invalid choice: 'sapc', did you mean 'sappc'? (choose from 'sappc', 'trappc', 'blfppc', 'mrp_feedback')"),
    (["frobnicate"], "sappc: error: argument COMMAND: invalid choice: 'frobnicate' (choose from 'simulate', "),  # nothing close: no guess
])
def test_a_typo_gets_the_closest_valid_name(tmp_path: Path, argv: list[str], line: str) -> None:
    proc = _sappc(*argv, cwd=tmp_path)
    assert proc.returncode == 2 and proc.stderr.splitlines()[-1].startswith(line), proc.stderr


def test_a_nested_commands_usage_names_its_own_path_once() -> None:
    proc = _sappc("scenarios", "copy", "--help")
    assert proc.returncode == 0 and proc.stdout.splitlines()[0] == "usage: sappc scenarios copy [-h] [--force] NAME [DEST]", proc.stdout


# ---- --json - ------------------------------------------------------------------------------


def test_json_to_stdout_pipes_into_json_tool_and_prints_nothing_else_there(tmp_path: Path) -> None:
    """The issue's command as a user types it, by the bundled scenario's name, in a directory of its own."""
    proc = subprocess.run(["bash", "-o", "pipefail", "-c", f"{' '.join(SAPPC)} simulate paper_tracking --json - | {sys.executable} -m json.tool"],
                          capture_output=True, text=True, cwd=tmp_path, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    report = json.loads(proc.stdout)
    assert report["scenario"] == "paper_tracking" and report["metrics"]["settling_time_s"] == pytest.approx(12.24)
    assert "scenario paper_tracking, controller sappc" in proc.stderr and "computed the torque of 6001" in proc.stderr
    assert list(tmp_path.iterdir()) == [], "a file named '-' or a directory was written"


def test_json_to_a_file_still_says_where_it_went(tmp_path: Path) -> None:
    proc = _sappc("simulate", str(_short_scenario(tmp_path)), "--json", str(tmp_path / "m.json"))
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.splitlines()[-2:] == [f"wrote {tmp_path / 'm.json'}", "kept control (the scenario states no requirements)"]  # the verdict last
    assert json.loads((tmp_path / "m.json").read_text())["scenario"] == "paper_tracking"


def test_json_to_stdout_restores_stdout_for_the_caller(tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    """In-process (``sappc.cli.main``): the JSON on fd 1, the table on fd 2, fd 1 as before afterwards."""
    assert cli.main(["simulate", str(_short_scenario(tmp_path)), "--json", "-"]) == 0
    print("after")
    out, err = capfd.readouterr()
    assert json.loads(out[: -len("after\n")])["scenario"] == "paper_tracking" and out.endswith("after\n")
    assert "scenario paper_tracking, controller sappc" in err


# ---- outputs --------------------------------------------------------------------------------


def test_default_outputs_share_one_root_with_a_folder_per_command() -> None:
    assert default_output_dir("report", "x") == OUTPUT_ROOT / "report" / "x" == Path("runs/report/x")
    assert bag_run_name("runs/run/paper_tracking-sappc-20260101-120000/bag") == "paper_tracking-sappc-20260101-120000"
    assert bag_run_name("runs/run/paper_tracking-sappc-20260101-120000/bag/bag_0.mcap") == "paper_tracking-sappc-20260101-120000"
    assert bag_run_name("data/flight3.mcap") == "flight3" and bag_run_name("data/mybag/") == "mybag"
    assert cli._comparison_name(["a/bag", "b/bag"]) == "a_vs_b"
    assert cli._comparison_name([f"r{i}/bag" for i in range(5)]) == "r0_vs_r1_vs_r2+2"


def test_montecarlo_writes_under_runs_by_default(tmp_path: Path) -> None:
    scenario = _short_scenario(tmp_path, "paper_montecarlo", 0.5)
    work = tmp_path / "work"
    work.mkdir()
    proc = _sappc("montecarlo", str(scenario), "--runs", "2", "--workers", "1", "--no-progress", cwd=work)
    assert proc.returncode == 1, proc.stderr  # 0.5 s ends before t2: no run meets the criteria
    assert "rpf_error_at_t2      p50 -  p99 -  max -" in proc.stdout, proc.stdout  # no run measured it (was a traceback)
    out = work / "runs" / "montecarlo" / "paper_montecarlo-seed0"
    assert (out / "summary.json").exists() and proc.stdout.splitlines()[-1] == f"results in {Path('runs/montecarlo/paper_montecarlo-seed0')}"
    assert sorted(p.name for p in work.iterdir()) == ["runs"]


def test_simulate_out_writes_the_figures_and_plots_is_a_deprecated_alias(tmp_path: Path) -> None:
    scenario = str(_short_scenario(tmp_path))
    new = _sappc("simulate", scenario, "--out", str(tmp_path / "new"))
    old = _sappc("simulate", scenario, "--plots", str(tmp_path / "old"))
    assert new.returncode == old.returncode == 0, new.stderr + old.stderr
    assert sorted(p.name for p in (tmp_path / "new").iterdir()) == sorted(p.name for p in (tmp_path / "old").iterdir()) != []
    assert "deprecated" not in new.stderr
    assert [ln for ln in old.stderr.splitlines() if "deprecated" in ln] == ["sappc: warning: --plots is deprecated, use --out (it does the same)"]
    assert "--plots" not in _sappc("simulate", "--help").stdout  # the old spelling is not offered


def _small_run_bag(path: Path) -> Path:
    """A bag of a 0.2 s run: state, reference and torque at 100 Hz."""
    from bagmaker import write_bag

    from sappc_msgs_py import contract as c
    from sappc_msgs_py.convert import quaternion_msg, torque_msg, vector3_msg

    q, messages = [0.0, 0.0, 0.0, 1.0], []
    for k in range(21):
        t, log = k * 0.01, k * 10_000_000
        messages += [(c.STATE_ATTITUDE.name, c.STATE_ATTITUDE.type_name, quaternion_msg(q, t, c.STATE_ATTITUDE), log),
                     (c.STATE_RATE.name, c.STATE_RATE.type_name, vector3_msg([0.0, 0.0, 0.0], t, c.STATE_RATE), log + 1),
                     (c.REFERENCE_ATTITUDE.name, c.REFERENCE_ATTITUDE.type_name, quaternion_msg(q, t, c.REFERENCE_ATTITUDE), log + 2),
                     (c.CONTROL_TORQUE.name, c.CONTROL_TORQUE.type_name, torque_msg([0.0, 0.0, 0.0], t, c.CONTROL_TORQUE), log + 3)]
    return write_bag(path, messages)


@pytest.mark.parametrize("command", ["report", "rerun"])
def test_a_used_out_is_refused_as_sappc_run_refuses_it(tmp_path: Path, command: str, capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 46: ``sappc run`` refuses an ``--out`` that holds files (launch.run_graph); ``report``
    overwrote one, mixing two bags' figures. Refused before the bag is read: exit 2, one line,
    nothing written; an empty directory is a new one."""
    bag = _small_run_bag(tmp_path / "run.mcap")
    used = tmp_path / "used"
    used.mkdir()
    (used / "report.html").write_text("another bag's report")
    extra = ["--params", str(ROOT / "config" / "controller_sappc.yaml")] if command == "rerun" else []
    assert cli.main([command, str(bag), "--out", str(used), *extra]) == 2
    assert capsys.readouterr().err.splitlines() == [f"sappc: error: --out {used} exists and is not empty; choose a new directory"]
    assert [p.name for p in used.iterdir()] == ["report.html"]
    empty = tmp_path / "empty"
    empty.mkdir()
    cli.main([command, str(bag), "--out", str(empty), *extra])  # (this bag has no inputs for rerun: exit 2, naming them)
    assert "--out" not in capsys.readouterr().err
    assert command == "rerun" or (empty / "report.html").exists()


# ---- bundled scenarios ---------------------------------------------------------------------------


def test_a_bundled_scenario_loads_by_name_as_by_path() -> None:
    for s in bundled_scenarios():
        assert scenario_path(s.name) == scenario_path(f"{s.name}.yaml") == s.path
        assert load_scenario(s.name).raw == load_scenario(SCENARIOS / f"{s.name}.yaml").raw
    assert SCENARIOS.resolve() == SCENARIOS_DIR  # the checkout's config/ is the package's data


def test_a_file_wins_over_a_bundled_name_and_a_missing_one_is_named(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    Path("paper_tracking").write_text("a file of that name\n")
    assert scenario_path("paper_tracking") == Path("paper_tracking")
    for typo in ("paper_trackin", "paper-tracking"):
        with pytest.raises(ConfigError, match=rf"scenario '{typo}': no such file, and no bundled scenario of that name, "
                                              r"did you mean 'paper_tracking'\? \(bundled: .*paper_tracking,"):
            scenario_path(typo)
    with pytest.raises(ConfigError, match=r"scenario 'sub/paper_tracking.yaml': no such file \("):
        scenario_path("sub/paper_tracking.yaml")  # a path is a path: never the bundled file of its name


def test_scenarios_lists_every_bundled_one_with_its_description(tmp_path: Path) -> None:
    proc = _sappc("scenarios", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    names = [ln.split()[0] for ln in proc.stdout.splitlines()]
    assert names == sorted(p.stem for p in SCENARIOS.glob("*.yaml"))
    assert re.search(r"(?m)^flight_gyro_bias_step\s+\[extends paper_tracking_flight\] Experiment 1", proc.stdout), proc.stdout
    assert all(len(ln) <= cli._LIST_COLUMNS for ln in proc.stdout.splitlines())


def test_scenarios_copy_brings_the_files_a_scenario_extends_and_never_overwrites_unasked(tmp_path: Path) -> None:
    proc = _sappc("scenarios", "copy", "flight_tracker_outage", "edit/here", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    copied = tmp_path / "edit" / "here"
    assert proc.stdout.splitlines() == [f"wrote {Path('edit/here/flight_tracker_outage.yaml')}", f"wrote {Path('edit/here/paper_tracking_flight.yaml')}"]
    assert load_scenario(copied / "flight_tracker_outage.yaml").raw == load_scenario("flight_tracker_outage").raw
    (copied / "paper_tracking_flight.yaml").write_text("# mine\n")
    again = _sappc("scenarios", "copy", "flight_tracker_outage", "edit/here", cwd=tmp_path)
    assert again.returncode == 2 and again.stderr.strip() == \
        f"sappc: error: {Path('edit/here/flight_tracker_outage.yaml')} exists already; give another DEST, or --force to overwrite it"
    assert (copied / "paper_tracking_flight.yaml").read_text() == "# mine\n"
    assert copy_scenario("flight_tracker_outage", copied, force=True)[1].read_text() == (SCENARIOS / "paper_tracking_flight.yaml").read_text()
    default = _sappc("scenarios", "copy", "paper_tracking.yaml", cwd=tmp_path)  # default DEST: here; the name with its suffix too
    assert default.returncode == 0 and (tmp_path / "paper_tracking.yaml").read_bytes() == (SCENARIOS / "paper_tracking.yaml").read_bytes()
    unknown = _sappc("scenarios", "copy", "paper_trackin", cwd=tmp_path)
    assert unknown.returncode == 2 and "no bundled scenario 'paper_trackin', did you mean 'paper_tracking'? (bundled: " in unknown.stderr


def test_a_file_anywhere_extends_a_bundled_scenario_by_its_file_name_and_a_file_beside_it_wins(tmp_path: Path) -> None:
    own = tmp_path / "one_orbit.yaml"
    own.write_text("extends: paper_tracking_orbit.yaml\nname: one_orbit\nduration_s: 5677.0\n")
    raw = read_scenario_mapping(own)
    assert raw == {**read_scenario_mapping(SCENARIOS / "paper_tracking_orbit.yaml"), "name": "one_orbit", "duration_s": 5677.0}
    (tmp_path / "paper_tracking_orbit.yaml").write_text("name: mine\n")  # a file of that name beside it: that file
    assert read_scenario_mapping(own) == {"name": "one_orbit", "duration_s": 5677.0}
    own.write_text("extends: sub/paper_tracking_orbit.yaml\n")  # a path is a path: never a bundled file
    with pytest.raises(ConfigError, match=r"cannot read scenario .*sub/paper_tracking_orbit.yaml"):
        read_scenario_mapping(own)


def test_every_bundled_scenario_extends_only_bundled_files_beside_it() -> None:
    """What ``copy`` relies on: a chain of ``extends`` stays in the scenarios' directory."""
    for s in bundled_scenarios():
        if s.extends is not None:
            assert (SCENARIOS_DIR / f"{s.extends}.yaml").is_file(), s.name
            assert yaml.safe_load(s.path.read_text())["extends"] == f"{s.extends}.yaml", s.name

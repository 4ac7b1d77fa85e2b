"""Bad YAML gets exit 2 and one line (issue 46, item 3), from every command that reads YAML, on
the small files of the issue (``tests/bad_yaml.py``: 30,000 brackets, 1,000 unclosed, ``q_BN``
400 deep, ten aliases a level six and eight levels deep), each run as its own process; and a
scenario path that exists but is not a file says what it is (item 7).

What is asserted of each process, and why it cannot be flaky:

- exit status 2 and exactly one line on stderr, under 300 characters, naming the file and the
  limit (each file is given by its bare name, the command run in its directory, so the line's
  length does not depend on where the temporary directory is);
- a peak resident memory under 300 MB (the issue's bound; measured by the wrapper process that
  starts the command alone, ``RUSAGE_CHILDREN``): these commands take 50 to 170 MB, most of it
  imports, whatever the file, where the six-level file took 332 MB before the limits;
- an end within :data:`TIMEOUT_S`, 60 times what the commands take here (0.3 to 0.6 s, mostly
  imports): no loaded machine is that slow, while the eight-level file ran for more than a
  minute before the limits.  The time of the refusal itself is measured, not asserted, by
  ``benchmarks/bench_yaml_limits.py`` (docs/performance.md);
- an address-space limit (:data:`ADDRESS_SPACE_BYTES`, ten times what the commands map here,
  with the BLAS and OpenMP pools held to one thread so that the count of CPUs does not change
  it) stops a regression that expands the aliases before it takes the machine's memory.
"""

from __future__ import annotations

import os
import re
import resource
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from bad_yaml import COMMANDS, LIMIT, MEASURE, command_args, write_bad_yaml
import gnc_common.validation as v
from conftest import SAPPC, cli_commands
from gnc_common.validation import ConfigError
from sappc import cli
from sappc.files import SCENARIOS_DIR, scenario_path

#: Longest a command may take on a bad file [s] (see the module docstring).
TIMEOUT_S = 30.0
#: Largest peak resident memory of a command on a bad file [bytes] (the issue's bound).
PEAK_RSS_BYTES = 300 << 20
#: Address space each command may map [bytes]: a guard for the machine, not the measurement.
ADDRESS_SPACE_BYTES = 4 << 30
#: The environment's thread pools held to one thread (their per-thread buffers are address space).
ONE_THREAD = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"}

def _limit_address_space() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (ADDRESS_SPACE_BYTES, ADDRESS_SPACE_BYTES))


def _measured(args: list[str], cwd: Path) -> tuple[subprocess.CompletedProcess[str], float, int]:
    """``sappc ARGS`` run in ``cwd``: the process, its wall time [s] and its peak resident memory [bytes]."""
    rss_file = cwd / ".peak_rss_kib"
    start = time.monotonic()
    proc = subprocess.Popen([sys.executable, "-c", MEASURE, str(rss_file), *SAPPC, *args], cwd=cwd, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env={**os.environ, **ONE_THREAD},
                            preexec_fn=_limit_address_space, start_new_session=True)
    try:
        out, err = proc.communicate(timeout=TIMEOUT_S)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, 9)  # the wrapper and the command
        proc.communicate()
        pytest.fail(f"sappc {' '.join(args)} ran for more than {TIMEOUT_S:g} s")
    wall = time.monotonic() - start
    peak = int(rss_file.read_text().split()[0]) * 1024
    rss_file.unlink()
    return subprocess.CompletedProcess(args, proc.returncode, out, err), wall, peak


@pytest.fixture(scope="module")
def bad_files(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The issue's files, and a bag with one clock message, in one directory."""
    where = tmp_path_factory.mktemp("bad_yaml")
    write_bad_yaml(where)
    return where


def _one_line(proc: subprocess.CompletedProcess[str], name: str) -> str:
    err = proc.stderr
    assert proc.returncode == 2, (proc.returncode, err[-2000:])
    assert err.count("\n") == 1 and err.endswith("\n"), err[:2000]
    line = err.rstrip("\n")
    assert line.startswith("sappc: error: ") and len(line) < 300, line
    assert f"{name}.yaml" in line or "sappc/params.yaml" in line, line
    return line


@pytest.mark.parametrize("name", sorted(LIMIT))
@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_each_command_refuses_each_bad_file_with_exit_2_and_one_short_line(bad_files: Path, command: str, name: str) -> None:
    args = command_args(command, name)
    proc, wall, peak = _measured(args, bad_files)
    line = _one_line(proc, name)
    assert LIMIT[name] in line, line
    assert peak < PEAK_RSS_BYTES, f"sappc {' '.join(args)}: peak resident memory {peak / 2**20:.0f} MiB ({wall:.2f} s)"


@pytest.mark.parametrize("name", sorted(LIMIT))
def test_rerun_refuses_each_bad_text_recorded_in_the_bag_as_its_parameters(bad_files: Path, tmp_path: Path, name: str) -> None:
    from bagmaker import write_bag
    from sappc.bag.read import PARAMS_RECORD
    from sappc_msgs_py.contract import CLOCK
    from sappc_msgs_py.convert import clock_msg

    write_bag(tmp_path / "recorded.mcap", [(CLOCK.name, CLOCK.type_name, clock_msg(0.0), 0)],
              metadata={PARAMS_RECORD: {"text": (bad_files / f"{name}.yaml").read_text()}})
    proc, wall, peak = _measured(["rerun", "recorded.mcap"], tmp_path)
    assert LIMIT[name] in _one_line(proc, name)
    assert peak < PEAK_RSS_BYTES, f"peak resident memory {peak / 2**20:.0f} MiB ({wall:.2f} s)"


def test_a_report_notes_a_recorded_scenario_past_a_limit_on_one_line_and_goes_on(bad_files: Path, tmp_path: Path) -> None:
    """The report of a bag reads the scenario the bag records to set its metrics; one past a limit
    is a note (one line, short), and the report is written with the default settings."""
    from bagmaker import write_bag
    from sappc.bag.read import SCENARIO_RECORD
    from sappc_msgs_py.contract import CLOCK
    from sappc_msgs_py.convert import clock_msg

    write_bag(tmp_path / "recorded.mcap", [(CLOCK.name, CLOCK.type_name, clock_msg(0.0), 0)],
              metadata={SCENARIO_RECORD: {"text": (bad_files / "aliases_8_levels.yaml").read_text()}})
    proc, wall, peak = _measured(["report", "recorded.mcap", "--out", "report"], tmp_path)
    notes = [line for line in proc.stdout.splitlines() if "scenario embedded in the bag" in line]
    assert len(notes) == 1 and "MAX_YAML_NODES" in notes[0] and len(notes[0]) < 400, proc.stdout
    assert (tmp_path / "report" / "report.html").is_file() and peak < PEAK_RSS_BYTES


def test_every_command_that_takes_a_scenario_or_a_yaml_file_is_tested() -> None:
    """A command added later with a scenario argument, or a ``--params``/``--scenario`` file, must
    join :data:`COMMANDS`."""
    reading = set()
    for name, sub in cli_commands(cli._parser()).items():
        for action in sub._actions:
            if action.dest == "scenario" and not action.option_strings:
                reading.add(name)
            elif action.option_strings in (["--params"], ["--scenario"]):
                reading.add(f"{name} {action.option_strings[0]}")
    assert reading == set(COMMANDS)


# ---- a path that exists but is not a regular file (issue 46, item 7) ----------------------


@pytest.mark.parametrize(("make", "what"), [(lambda p: p.mkdir(), "is a directory, not a file"),
                                            (lambda p: os.mkfifo(p), "is a pipe (a FIFO, or /dev/fd/N")])
def test_a_scenario_that_is_not_a_regular_file_says_what_it_is(tmp_path: Path, make: Callable[[Path], None], what: str) -> None:
    make(tmp_path / "exp1.yaml")
    proc = subprocess.run([*SAPPC, "simulate", "exp1.yaml"], capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1, proc.stderr
    assert proc.stderr.startswith(f"sappc: error: scenario 'exp1.yaml' {what}") and "no such file" not in proc.stderr


def test_dev_fd_and_a_device_say_what_they_are() -> None:
    read_end, write_end = os.pipe()  # what bash's <(...) gives
    try:
        with pytest.raises(ConfigError, match=rf"^scenario '/dev/fd/{read_end}' is a pipe \(.*\), not a file: give a scenario file"):
            scenario_path(f"/dev/fd/{read_end}")
    finally:
        os.close(read_end)
        os.close(write_end)
    with pytest.raises(ConfigError, match=r"^scenario '/dev/null' is a character device, not a file"):
        scenario_path("/dev/null")


def test_a_bundled_name_still_wins_over_a_directory_of_that_name(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``sappc scenarios copy paper_tracking paper_tracking`` makes such a directory; the name
    still runs the bundled scenario, a path to the directory is refused as one."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "paper_tracking").mkdir()
    assert scenario_path("paper_tracking") == SCENARIOS_DIR / "paper_tracking.yaml"
    with pytest.raises(ConfigError, match=r"is a directory"):
        scenario_path(str(tmp_path / "paper_tracking"))
    with pytest.raises(ConfigError, match=r"no such file"):
        scenario_path(str(tmp_path / "missing.yaml"))


def test_the_bad_files_are_as_small_as_the_issue_says() -> None:
    """The sizes the issue gives: 60 kB, 1 kB and a few hundred bytes for the aliases."""
    from bad_yaml import bad_yaml_texts

    sizes = {k: len(t) for k, t in bad_yaml_texts().items()}
    assert 60_000 <= sizes["brackets_30000"] < 61_000 and 1000 <= sizes["open_brackets_1000"] < 1100
    assert sizes["aliases_8_levels"] < 1000


# ---- one loader, documented as it is ------------------------------------------------------


def test_no_module_but_the_loader_parses_yaml_itself() -> None:
    """Every YAML read goes through :func:`gnc_common.validation.safe_load_yaml` (its limits)."""
    parsing = re.compile(r"\byaml\.(?:safe_load|load|full_load|unsafe_load|load_all|safe_load_all|compose|parse)\(")
    src = Path(cli.__file__).resolve().parents[1]
    callers = sorted(str(p.relative_to(src)) for p in src.rglob("*.py") if parsing.search(p.read_text(encoding="utf-8")))
    assert callers == ["gnc_common/validation.py"]


def test_the_scenario_reference_states_each_limit_as_the_code_has_it() -> None:
    page = " ".join((Path(cli.__file__).resolve().parents[2] / "docs" / "reference" / "scenario.md").read_text().split())
    for stated, name in [(f"{v.MAX_YAML_DEPTH} levels deep", "MAX_YAML_DEPTH"), (f"{v.MAX_YAML_NODES:,} nodes", "MAX_YAML_NODES"),
                         (f"{v.MAX_YAML_BYTES:,} characters", "MAX_YAML_BYTES"), (f"{v.MAX_QUOTED_CHARS} characters", "quoted"),
                         (f"{v.MAX_MESSAGE_CHARS:,} characters", None)]:
        pattern = re.escape(stated) + (rf"[^`]*`gnc_common\.validation\.{name}`" if name else "")
        assert re.search(pattern, page), (stated, name)

"""Mutation testing of the cores, the node's input checks and watchdogs, the metrics and the Monte
Carlo seeding (issue 14): how many injected faults the tests catch, measured.

Prints one JSON document: the tool and its version, the date and machine, per module the mutants
killed, survived and timed out and the score ``(killed + timeout) / total``, the overall score,
and every surviving mutant (module, line, operator, diff).  The results and why each survivor
survives: ``docs/mutation.md``.

Tool
----
cosmic-ray, pinned in the ``mutation`` extra (``.venv/bin/pip install -e '.[mutation]'``, or any
Python with it: ``--tool-python``).  Chosen because it mutates any function, the numba kernels
included (mutmut 3 skips decorated functions, i.e. every ``@jit`` kernel), and runs any test
command.  Per module this script writes a cosmic-ray config, enumerates the mutants (``cosmic-ray
init``), drops those out of scope with cosmic-ray's filters (``operators_filter``,
``line_filter``), then has one persistent cosmic-ray worker per private copy of the tree (never the
checkout) apply each mutant, run the test command and restore the file
(``cosmic_ray.mutating.mutate_and_test``, what cosmic-ray's own distributors call), ``--jobs`` at
a time.

How the tests run
-----------------
* ``NUMBA_DISABLE_JIT=1``: the kernels run as plain Python.  A mutant of a kernel module would
  otherwise change the numba cache digest (``gnc_common.compiled.KERNEL_MODULES``) and cost a
  recompile of about a minute; the suite passes the same way with the JIT off.  The numba cache
  directory is a temporary one (``SAPPC_CACHE_DIR``): no cache of a mutant is kept.
* The test command is this script as a client (``--run-tests``) of a test server (``--serve``)
  that has imported numpy, scipy, numba, pytest, hypothesis and rclpy once and forks a child per
  run, which imports the project from the mutated copy and runs pytest there: 1-2 s per mutant
  instead of 4-5 s.
* Per module (:data:`TARGETS`) two stages of fast tests: ``quick`` (the sharpest, e.g. the law
  against its numpy oracle), then ``more`` only if ``quick`` passes; never the ``slow`` marker;
  ``-x`` (a mutant is killed at its first failing test), ``--hypothesis-seed=0`` (property tests
  draw the same examples for every mutant), no pytest cache.  The node tests run the node's
  callbacks in-process on an isolated ROS domain, their wait for a message shortened to
  :data:`NODE_TEST_DEADLINE_S`.
* A mutant is *killed* when a stage fails, *timeout* when the tests run past ``max(20 s, 4 x``
  the unmutated time) (counted as detected, as cosmic-ray does), *survived* otherwise.  The
  unmutated copy must pass every selection first, else the script stops.

Scope: what is mutated
----------------------
Operators (cosmic-ray's names in :data:`KEPT_OPERATORS`), one or two replacements per site rather
than every permutation: ``+ -> -``, ``- -> +``, ``* -> /``, ``/ -> *``, ``** -> *``, ``// -> /``,
``% -> /``, ``| <-> &``; comparisons to their boundary (``< <-> <=``, ``> <-> >=``) and to their
negation (``< -> >=``, ``<= -> >``, ``> -> <=``, ``>= -> <``, ``== <-> !=``, ``is <-> is not``);
unary minus and ``not`` deleted; ``not`` added to a condition; ``True <-> False``; ``and <-> or``;
``break <-> continue``; a number plus one (cosmic-ray also makes minus one; dropped, as mutmut
does, to halve the count); a ``for`` loop run zero times; an ``except`` that catches nothing; a
decorator removed.  Lines (by the module's syntax tree): the whole module, or for the node only its
input checks and watchdogs (:data:`NODE_FUNCTIONS`), less the plant's ``warm_up`` (it compiles the
kernels; what it computes is thrown away), docstrings, imports, ``__all__``, log calls and
f-strings (message text, not behaviour), and the decorators and signatures of ``@jit``
kernels (the decorator is the identity with the JIT off); and no mutant inside an annotation
(never evaluated: ``from __future__ import annotations``).

Time: see ``docs/mutation.md`` (measured wall time, with ``--jobs 2`` on the project's 2-core machine).

Usage: ``python benchmarks/bench_mutation.py [--modules NAME,...] [--jobs N] [--tool-python PY]
[--dry-run] [--keep DIR]``; ``--dry-run`` counts the mutants in scope without testing them;
``--keep DIR`` keeps the copies, the cosmic-ray sessions and ``results.jsonl`` (every mutant).
"""

from __future__ import annotations

import argparse
import ast
import concurrent.futures
import hashlib
import json
import os
import platform
import queue
import re
import shlex
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]

#: The pinned tool (pyproject.toml, extra ``mutation``).
TOOL, TOOL_VERSION = "cosmic-ray", "8.7.0"
INSTALL_HINT = ".venv/bin/pip install -e '.[mutation]'"

#: What each copy of the tree holds: the sources, the tests and what they read (the README and the docs: tests check their claims).
COPIED = ("src", "tests", "config", "pyproject.toml", "README.md", "docs", "examples")

#: The node's input checks and watchdogs (methods of ``ControllerNode`` and the module's helpers).
NODE_FUNCTIONS = ("_seconds_to_ns", "_apply_watchdog", "_reject", "_now_ns", "_decode", "_on_input", "_outage_at", "_answered",
                  "_answer_without_inputs", "_on_clock", "_check_grace", "_on_timer", "_compute", "_publish_zero", "_publish")

#: The CLI's exit statuses: the constants and the functions that map a command's outcome to its status.
CLI_EXIT_STATUS = ("EXIT_INVALID_INPUT", "EXIT_CONTROLLER_NEVER_COMMANDED", "EXIT_REQUIREMENT_FAILED", "run_exit_status", "main")

#: cosmic-ray operators run (a regular expression on the operator name); every other one is filtered out.
KEPT_OPERATORS = (
    r"core/ReplaceBinaryOperator_(Add_Sub|Sub_Add|Mul_Div|Div_Mul|Pow_Mul|FloorDiv_Div|Mod_Div|BitOr_BitAnd|BitAnd_BitOr)",
    r"core/ReplaceComparisonOperator_(Lt_LtE|LtE_Lt|Gt_GtE|GtE_Gt|Lt_GtE|LtE_Gt|Gt_LtE|GtE_Lt|Eq_NotEq|NotEq_Eq|Is_IsNot|IsNot_Is)",
    r"core/ReplaceUnaryOperator_(Delete_USub|Delete_Not)",
    r"core/(AddNot|ReplaceTrueWithFalse|ReplaceFalseWithTrue|ReplaceAndWithOr|ReplaceOrWithAnd)",
    r"core/(ReplaceBreakWithContinue|ReplaceContinueWithBreak|NumberReplacer|ZeroIterationForLoop|ExceptionReplacer|RemoveDecorator)",
)
#: Log calls: their arguments are message text.
_LOG_METHODS = {"debug", "info", "warning", "error", "fatal"}
#: Decorators that are the identity with ``NUMBA_DISABLE_JIT=1``.
_JIT_DECORATORS = {"jit", "jit_parallel"}


@dataclass(frozen=True)
class Target:
    """One module under mutation: its path, the tests that should kill its mutants in two stages
    (``quick``: a few sharp tests that kill most; ``more``: run only when ``quick`` passes) and,
    optionally, the only functions mutated."""

    path: str
    quick: tuple[str, ...]
    more: tuple[str, ...] = ()
    functions: tuple[str, ...] | None = None
    #: Functions (or classes) left out of scope, each with its reason beside the target.
    skip_functions: tuple[str, ...] = ()


_PARITY = "tests/controller/test_kernels_parity.py::"
_TUNING = "tests/tools/montecarlo/test_tuning.py::"
_START = "tests/controller/test_start_check.py::"
_MEKF = "tests/estimator/test_mekf.py::"
_EST_NODE = "tests/nodes/test_estimator_node.py::"

TARGETS: dict[str, Target] = {
    "sappc.montecarlo.draws": Target(
        "src/sappc/montecarlo/draws.py",
        ("tests/tools/montecarlo/test_draws.py",),
        ("tests/tools/montecarlo/test_montecarlo.py::test_dispersion_statistics_and_per_run_reproducibility",
         "tests/tools/montecarlo/test_montecarlo.py::test_sensor_noise_draws_are_the_campaigns_block_sequence",
         "tests/tools/montecarlo/test_montecarlo.py::test_bad_dispersions_are_rejected_before_any_run",  # the hardware and fault draws (issue 26)
         "tests/tools/montecarlo/test_montecarlo.py::test_a_campaign_with_the_scenarios_sensors_and_wheels_draws_each_runs_sensors_and_matches_the_run_alone",
         "tests/tools/montecarlo/test_montecarlo.py::test_a_campaign_disperses_fault_kinds_times_and_lengths_and_run_k_is_the_fault_alone"),
    ),
    "sappc_controller.inputs": Target(
        "src/sappc_controller/inputs.py",
        ("tests/controller/test_inputs.py",), ("tests/tools/bag/test_rerun_pairing.py", "tests/nodes/test_nodes.py"),
    ),
    "sappc_controller.node": Target(  # its input checks and watchdogs only
        "src/sappc_controller/node.py", ("tests/nodes/test_nodes.py",), (), NODE_FUNCTIONS,
    ),
    "sappc.evaluation.metrics": Target(
        "src/sappc/evaluation/metrics.py",
        ("tests/tools/evaluation/test_metrics.py", "tests/tools/evaluation/test_estimation_metrics.py"),  # the estimation metrics (issue 26)
        ("tests/tools/bag/test_bag_tools.py::test_time_outside_the_band_on_a_jittered_grid_sums_the_hold_intervals",),
    ),
    "spacecraft_sim.core.kernels": Target(
        "src/spacecraft_sim/core/kernels.py",
        ("tests/sim/test_dynamics.py", "tests/sim/test_disturbance.py"),
        ("tests/sim/test_reference.py", "tests/sim/test_faults.py", f"{_PARITY}test_plant_and_reference_kernels_equal_numpy",
         f"{_PARITY}test_every_disturbance_kind_equals_numpy_model"),
        skip_functions=("warm_up",),  # compiles the kernels once; what it computes is thrown away
    ),
    "sappc_controller.core.kernels": Target(
        "src/sappc_controller/core/kernels.py",
        (f"{_PARITY}test_step_equals_the_numpy_oracle", "tests/controller/test_kernel_setup.py"),
        ("tests/controller/test_controllers.py", "tests/controller/test_smetf.py", "tests/controller/test_rpf.py",
         f"{_START}test_the_offline_runner_refuses_a_start_at_the_singularity", f"{_START}test_the_batch_path_names_the_singular_run",
         f"{_START}test_a_campaign_chunk_names_the_campaign_run_number"),
    ),
    "sappc.bag.rosbag2": Target(  # the bag writer's metadata, repair and the closing sort
        "src/sappc/bag/rosbag2.py",
        ("tests/tools/bag/test_rosbag2.py",),
        ("tests/tools/bag/test_sort.py",),
    ),
    "sappc.graph.recorder": Target(  # the node's callbacks in-process on an isolated domain
        "src/sappc/graph/recorder.py",
        ("tests/tools/graph/test_recorder.py",),
        # main: the process entry (run_node), run only by the graph tests (slow); _peak_rss_mib: its value goes only into
        # the closing log line (log calls are out of scope)
        skip_functions=("main", "_peak_rss_mib"),
    ),
    "sappc.cli": Target(  # the exit statuses only
        "src/sappc/cli.py",
        ("tests/tools/test_exit_status.py",),
        functions=CLI_EXIT_STATUS,
    ),
    "sappc_msgs_py.timeline": Target(
        "src/sappc_msgs_py/timeline.py",
        ("tests/nodes/test_realtime_frames.py",),
    ),
    "sappc.montecarlo.tuning": Target(  # the study on a stand-in campaign, then a study on real campaigns; not the `sappc tune`
        # processes nor the 14- and 27-s studies of test_tuning.py (a minute a mutant on this machine)
        "src/sappc/montecarlo/tuning.py",
        (f"{_TUNING}test_a_bad_tuning_section_stops_with_an_error_naming_the_key", f"{_TUNING}test_requirements_the_run_cannot_measure_are_infeasible",
         f"{_TUNING}test_score_is_the_percentile_of_the_objective_and_each_requirements_worst_relative_margin",
         f"{_TUNING}test_the_wheel_speed_requirement_is_usable_in_tuning", "tests/tools/montecarlo/test_tuning_config.py",
         "tests/tools/montecarlo/test_tuning_study.py"),
        (f"{_TUNING}test_the_output_directory_refuses_another_study_and_a_resume_of_nothing",),
        # presentation, as log calls are: _figures draws history.png and tradeoff.png (their content is checked by the command
        # tests' empty-axes check), _Progress the progress line on stderr
        skip_functions=("_figures", "_Progress"),
    ),
    # The estimator (issue 33 item 6).  Its kernel against the oracle on the 8-s sequence through every branch first; the
    # longer parity sequences and the behaviour tests after; never the 200 s, 300 s, 3 h and 4 h runs (minutes a mutant
    # with the JIT off).
    "sappc_estimator.core.mekf": Target(  # the whole module (issue 33 item 6)
        "src/sappc_estimator/core/mekf.py",
        (f"{_MEKF}test_kernel_equals_oracle[every_branch_8s]", f"{_MEKF}test_kernel_equals_oracle[monitor_fails_twice_6s]",
         f"{_MEKF}test_kernel_equals_oracle[overconfident_6s]", f"{_MEKF}test_a_sample_that_is_not_finite_changes_nothing_and_gives_no_estimate",
         f"{_MEKF}test_an_implausible_sample_is_no_measurement", f"{_MEKF}test_initialises_at_the_first_tracker_sample",
         f"{_MEKF}test_a_tracker_sample_is_new_by_its_epoch_never_by_its_value",
         f"{_MEKF}test_the_kernels_arrays_are_packed_as_documented_without_gaps_or_overlaps", f"{_MEKF}test_kernel_equals_oracle[exact_rest_2s]",
         f"{_MEKF}test_kernel_equals_oracle[fast_tumble_4s]", f"{_MEKF}test_the_transition_is_the_matrix_exponential_on_both_sides_of_the_series",
         f"{_MEKF}test_oracle_rotations_agree_with_scipy_and_the_kernels_helpers",
         f"{_MEKF}test_the_plausibility_bounds_accept_a_sample_at_the_bound_and_refuse_the_next_float",
         f"{_MEKF}test_a_state_reset_in_place_over_used_arrays_steps_as_fresh_ones_and_keeps_p_exactly_symmetric",
         f"{_MEKF}test_the_estimators_arrays_slice_along_their_run_axis",
         # the drift test (issue 46): alarms with a full window and twice before one fills, the threshold's edge
         f"{_MEKF}test_kernel_equals_oracle[drift_alarm_z_12s]", f"{_MEKF}test_kernel_equals_oracle[drift_fails_twice_8s]",
         f"{_MEKF}test_the_drift_test_fails_the_monitor_above_its_threshold_not_at_it"),
        # then the paths the short sequences do not take: a prior's start, a burst that re-initialises, the reset, a 20 s
        # outage (in a first full run this stage killed 2 of 105 mutants and cost every survivor ~17 s more: the sequences
        # that repeat the quick stage's branches, the recovery's and the outliers', are left to the suite, with the 17-s
        # convergence test and the multi-hour runs)
        (f"{_MEKF}test_kernel_equals_oracle[from_prior_10deg]", f"{_MEKF}test_burst_reinitialises_from_the_tracker",
         f"{_MEKF}test_multiplicative_reset", f"{_MEKF}test_kernel_equals_oracle[outage_20s]",
         "tests/estimator/test_config.py::test_a_bad_setting_is_refused_with_its_name"),  # the window's bound, MON_MAX_WINDOW
    ),
    "sappc_estimator.core.config": Target(
        "src/sappc_estimator/core/config.py",
        ("tests/estimator/test_config.py", f"{_MEKF}test_the_gate_threshold_is_the_chi_square_quantile",
         f"{_MEKF}test_the_monitor_bands_are_the_chi_square_quantiles_at_their_stated_probabilities"),
        (f"{_MEKF}test_the_drift_tests_false_alarms_come_at_its_stated_probability", f"{_MEKF}test_kernel_equals_oracle[every_branch_8s]", f"{_EST_NODE}test_parameters_round_trip_through_the_config_and_accept_one_number_for_three_axes",
         f"{_EST_NODE}test_a_bad_parameter_stops_the_node_naming_itself_and_its_value",
         f"{_EST_NODE}test_a_missing_tracker_noise_or_a_prior_without_its_sigma_is_named",
         f"{_MEKF}test_kernel_equals_oracle[from_prior_10deg]", f"{_MEKF}test_initialises_at_the_first_tracker_sample"),
    ),
    "sappc_estimator.core.estimator": Target(
        "src/sappc_estimator/core/estimator.py",
        ("tests/estimator/test_config.py",),
        ("tests/nodes/test_estimator_node.py",),
        skip_functions=("warm_up",),  # loads the compiled kernel once; what its step computes is thrown away
    ),
    "sappc_estimator.node": Target(  # the node's callbacks in-process on an isolated domain
        "src/sappc_estimator/node.py",
        ("tests/nodes/test_estimator_node.py",),
        # main: the process entry (run_node), run only by the process tests (tests/nodes/test_estimator_process.py, slow)
        skip_functions=("main",),
    ),
}


# ----------------------------------------------------------------------------- scope


def _span(node: ast.AST) -> range:
    return range(node.lineno, (node.end_lineno or node.lineno) + 1)  # type: ignore[attr-defined]


def mutable_lines(source: str, functions: tuple[str, ...] | None, skip_functions: tuple[str, ...] = ()) -> set[int]:
    """Lines of ``source`` in scope (module docstring): the named functions' and module constants' (or all), less
    ``skip_functions``, docstrings, imports, ``__all__``, log calls, f-strings, ``@jit`` decorators and the
    ``if __name__ == "__main__":`` entry."""
    tree = ast.parse(source)
    n_lines = len(source.splitlines())
    if functions is None:
        keep = set(range(1, n_lines + 1))
    else:
        keep = set()
        found = set()
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.name in functions:
                keep.update(_span(node))
                found.add(node.name)
        for node in tree.body:  # module constants named in ``functions`` (e.g. the exit statuses)
            if isinstance(node, ast.Assign):
                names = {t.id for t in node.targets if isinstance(t, ast.Name)} & set(functions)
                if names:
                    keep.update(_span(node))
                    found.update(names)
        missing = set(functions) - found
        if missing:
            raise SystemExit(f"bench_mutation: functions not found: {sorted(missing)}")
    drop: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)) and node.name in skip_functions:
            drop.update(range(min([node.lineno, *(d.lineno for d in node.decorator_list)]), (node.end_lineno or node.lineno) + 1))
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant) and isinstance(body[0].value.value, str):
                drop.update(_span(body[0]))
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and any(
                isinstance(f := (d.func if isinstance(d, ast.Call) else d), ast.Name) and f.id in _JIT_DECORATORS for d in node.decorator_list):
            # decorators and signature (a removed decorator's mutation spans both; a kernel has no defaults)
            drop.update(range(node.decorator_list[0].lineno, node.body[0].lineno))
        if isinstance(node, (ast.Import, ast.ImportFrom, ast.JoinedStr)):
            drop.update(_span(node))
        if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "__all__" for t in node.targets):
            drop.update(_span(node))
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr in _LOG_METHODS:
            drop.update(_span(node))
    for node in tree.body:  # the script entry (``if __name__ == "__main__":``): only a process started as a script runs it
        if isinstance(node, ast.If) and isinstance(node.test, ast.Compare) and isinstance(node.test.left, ast.Name) \
                and node.test.left.id == "__name__":
            drop.update(_span(node))
    return keep - drop


def annotation_spans(source: str) -> list[tuple[tuple[int, int], tuple[int, int]]]:
    """``((line, col), (end_line, end_col))`` of every annotation (characters, as cosmic-ray's positions):
    with ``from __future__ import annotations`` they are never evaluated, so a mutant there is
    equivalent; the line filter cannot drop them (a signature line may hold a default)."""
    lines = source.splitlines()

    def char_col(line: int, byte_col: int) -> int:
        return len(lines[line - 1].encode()[:byte_col].decode(errors="replace"))

    spans = []
    for node in ast.walk(ast.parse(source)):
        notes: list[ast.expr | None] = []
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            a = node.args
            notes = [x.annotation for x in (*a.posonlyargs, *a.args, *a.kwonlyargs, a.vararg, a.kwarg) if x is not None] + [node.returns]
        elif isinstance(node, ast.AnnAssign):
            notes = [node.annotation]
        for n in notes:
            if n is not None:
                spans.append(((n.lineno, char_col(n.lineno, n.col_offset)),
                              (n.end_lineno or n.lineno, char_col(n.end_lineno or n.lineno, n.end_col_offset or 0))))
    return spans


def _ranges(lines: set[int]) -> list[str]:
    """``["a-b", ...]`` of sorted line numbers."""
    out: list[str] = []
    start = prev = None
    for n in sorted(lines):
        if start is None:
            start = prev = n
        elif n == prev + 1:  # type: ignore[operator]
            prev = n
        else:
            out.append(f"{start}-{prev}")
            start = prev = n
    if start is not None:
        out.append(f"{start}-{prev}")
    return out


def _toml_str(s: str) -> str:
    return json.dumps(s)  # a JSON string is a valid TOML basic string for these (ASCII) values


def write_config(path: Path, target: Target, lines: set[int], test_command: str, timeout_s: float) -> None:
    """The cosmic-ray session config of one module (the distributor is unused: this script dispatches)."""
    exclude = "^(?!(" + "|".join(KEPT_OPERATORS) + ")$)"
    path.write_text(
        "[cosmic-ray]\n"
        f"module-path = {_toml_str(target.path)}\n"
        f"timeout = {timeout_s:.1f}\n"
        "excluded-modules = []\n"
        f"test-command = {_toml_str(test_command)}\n"
        "\n[cosmic-ray.distributor]\nname = \"local\"\n"
        "\n[cosmic-ray.filters.operators-filter]\n"
        f"exclude-operators = [{_toml_str(exclude)}]\n"
        "\n[cosmic-ray.filters.line-filter]\n"
        f"lines = {{ {_toml_str(target.path)} = [{', '.join(_toml_str(r) for r in _ranges(lines))}] }}\n"
    )


# ----------------------------------------------------------------------------- the test server


def _serve(sock_path: str) -> int:
    """The test server (``--serve``): imports the heavy third-party packages once, then forks a child
    per request, which runs pytest in the request's tree and streams its output back, ending with
    ``RC=<exit status>``.  The project is never imported here, only in the children, from the tree
    of their request (its mutant).  A child whose client goes away (cosmic-ray's timeout killed it)
    kills its own process group."""
    import importlib
    import socket

    for name in PREIMPORTED:
        try:
            importlib.import_module(name)
        except ImportError:
            pass
    leaked = sorted(m for m in sys.modules if m.split(".")[0] in PROJECT_PACKAGES)
    if leaked:
        raise SystemExit(f"bench_mutation: the test server imported project modules: {leaked}")
    server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    server.bind(sock_path)
    server.listen(16)
    server.settimeout(0.5)
    while True:
        try:
            while os.waitpid(-1, os.WNOHANG)[0]:
                pass
        except ChildProcessError:
            pass
        try:
            conn, _ = server.accept()
        except TimeoutError:
            continue
        pid = os.fork()
        if pid:
            conn.close()
            continue
        server.close()
        os.setpgid(0, 0)
        try:
            _serve_one(conn)
        finally:
            os._exit(70)


def _serve_one(conn: Any) -> None:
    """One request in a forked child: ``{"cwd": tree, "args": [pytest args]}``."""
    data = b""
    while not data.endswith(b"\n"):
        chunk = conn.recv(65536)
        if not chunk:
            os._exit(71)
        data += chunk
    request = json.loads(data)
    tree = request["cwd"]

    def watch() -> None:  # the client went away: stop everything this test run started
        while True:
            try:
                if not conn.recv(1):
                    break
            except OSError:
                break
        os.killpg(0, signal.SIGKILL)

    threading.Thread(target=watch, daemon=True).start()
    os.chdir(tree)
    sys.path.insert(0, os.path.join(tree, "src"))
    os.environ["PYTHONPATH"] = os.path.join(tree, "src")  # for the subprocesses of the tests
    os.dup2(conn.fileno(), 1)
    os.dup2(conn.fileno(), 2)
    import pytest

    rc = int(pytest.main(request["args"]))
    sys.stdout.flush()
    sys.stderr.flush()
    os.write(1, f"\nRC={rc}\n".encode())
    os._exit(0)


def _run_tests_client(sock_path: str, args: list[str]) -> int:
    """The test command given to cosmic-ray (``--run-tests``): pytest in the current directory, run
    by the test server, stage after stage (``args`` split at ``:::``; common options first) while
    they pass; exits with the first failing stage's status."""
    import socket

    common, *stages = " ".join(shlex.quote(a) for a in args).split(" ::: ")
    for stage_no, stage in enumerate(stages, 1):
        conn = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        conn.connect(sock_path)
        conn.sendall(json.dumps({"cwd": os.getcwd(), "args": shlex.split(common) + shlex.split(stage)}).encode() + b"\n")
        out = b""
        while True:
            chunk = conn.recv(65536)
            if not chunk:
                break
            out += chunk
        conn.close()
        text = out.decode(errors="replace")
        m = re.search(r"\nRC=(\d+)\n$", text)
        sys.stdout.write(text[: m.start()] if m else text)
        rc = int(m.group(1)) if m else 99
        if rc != 0:
            sys.stdout.write(f"\nbench_mutation: stage {stage_no} failed\n")
            return rc
    return 0


#: Third-party packages the test server imports once (the children inherit them).
PREIMPORTED = ("numpy", "scipy", "scipy.special", "scipy.integrate", "scipy.optimize", "scipy.spatial.transform", "scipy.interpolate",
               "numba", "yaml", "pytest", "_pytest.assertion.rewrite", "hypothesis", "hypothesis.strategies", "hypothesis.extra.numpy",
               "rclpy", "rclpy.node", "rclpy.executors", "rclpy.parameter", "geometry_msgs.msg", "std_msgs.msg", "rosgraph_msgs.msg",
               "rcl_interfaces.msg", "builtin_interfaces.msg", "sensor_msgs.msg", "diagnostic_msgs.msg", "mcap", "mcap.reader", "mcap.writer", "rosbags", "zstandard", "lz4.frame")
#: The node tests' wait for a message [s] (``SAPPC_TEST_DEADLINE_S``; 20 s by default): a mutant that
#: never publishes fails in seconds; discovery and a step take well under a second.
NODE_TEST_DEADLINE_S = 5.0
#: The project's top-level packages (never imported by the test server).
PROJECT_PACKAGES = {"sappc", "sappc_controller", "sappc_estimator", "sappc_momentum", "spacecraft_sim", "gnc_common", "sappc_msgs_py"}


# ----------------------------------------------------------------------------- cosmic-ray workers

#: A persistent cosmic-ray worker (run by the tool's interpreter in one copy of the tree): one JSON
#: request per line -> ``cosmic_ray.mutating.mutate_and_test`` (what cosmic-ray's local and http
#: distributors call: write the mutant, run the test command with the timeout, restore the file)
#: -> one JSON result per line.
_WORKER = r"""
import json, sys
from pathlib import Path
from cosmic_ray.mutating import mutate_and_test
from cosmic_ray.work_item import MutationSpec
for line in sys.stdin:
    q = json.loads(line)
    r = mutate_and_test([MutationSpec(Path(q["module_path"]), q["operator"], q["occurrence"], (0, 0), (0, 1))], q["test_command"], q["timeout"])
    sys.stdout.write("RESULT " + json.dumps({"worker_outcome": r.worker_outcome.value, "test_outcome": None if r.test_outcome is None
                     else r.test_outcome.value, "output": r.output, "diff": r.diff}) + "\n")
    sys.stdout.flush()
"""


class Worker:
    """One persistent cosmic-ray worker and its private copy of the tree."""

    def __init__(self, tool_python: str, tree: Path) -> None:
        self.tree = tree
        self.proc = subprocess.Popen([tool_python, "-c", _WORKER], cwd=tree, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                                     start_new_session=True)

    def mutate_and_test(self, mutation: dict[str, Any], test_command: str, timeout_s: float) -> dict[str, Any]:
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write(json.dumps({"module_path": mutation["module_path"], "operator": mutation["operator_name"],
                                          "occurrence": mutation["occurrence"], "test_command": test_command, "timeout": timeout_s}) + "\n")
        self.proc.stdin.flush()
        while True:
            line = self.proc.stdout.readline()
            if not line:
                raise SystemExit(f"bench_mutation: the cosmic-ray worker in {self.tree} stopped")
            if line.startswith("RESULT "):
                result: dict[str, Any] = json.loads(line[len("RESULT "):])
                return result

    def stop(self) -> None:
        _kill_group(self.proc)


def _kill_group(proc: subprocess.Popen[Any]) -> None:
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    proc.wait()


# ----------------------------------------------------------------------------- the campaign


def _run(cmd: list[str], **kwargs: Any) -> subprocess.CompletedProcess[str]:
    proc = subprocess.run(cmd, capture_output=True, text=True, **kwargs)
    if proc.returncode != 0:
        raise SystemExit(f"bench_mutation: {' '.join(cmd)} failed ({proc.returncode}):\n{proc.stdout}{proc.stderr}")
    return proc


def _copy_tree(dest: Path) -> None:
    dest.mkdir(parents=True)
    ignore = shutil.ignore_patterns("__pycache__", ".mypy_cache", ".hypothesis", "*.pyc")
    for name in COPIED:
        src = ROOT / name
        if src.is_dir():
            shutil.copytree(src, dest / name, ignore=ignore)  # copy2: the sources keep their mtimes
        else:
            shutil.copy2(src, dest / name)
    # byte-code of the unmutated tree, written once; a mutant (a newer mtime) is compiled afresh, never written
    _run([sys.executable, "-m", "compileall", "-q", str(dest / "src"), str(dest / "tests")])


def pytest_args(target: Target) -> list[str]:
    """The client's arguments: pytest's options, then the stages."""
    args = ["-x", "-q", "-p", "no:cacheprovider", "--hypothesis-seed=0", "-m", "not slow", ":::", *target.quick]
    return args + ([":::", *target.more] if target.more else [])


def _line_of(diff: str) -> int | None:
    """The first changed line of a unified diff (old numbering)."""
    m = re.search(r"^@@ -(\d+)", diff, re.M)
    if not m:
        return None
    n = int(m.group(1))
    for text in diff[m.end():].splitlines()[1:]:
        if text.startswith("-"):
            return n
        if not text.startswith("+"):
            n += 1
    return None


def _pending(tool: list[str], session: Path) -> list[dict[str, Any]]:
    """The mutations the filters left (``cosmic-ray dump``: a null result is pending)."""
    items = []
    for line in _run([*tool, "dump", str(session)]).stdout.splitlines():
        if line.strip():
            item, result = json.loads(line)
            if result is None:
                items.append(item["mutations"][0])
    return items


def main() -> int:
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))  # clean up (children, copies) as on Ctrl-C
    if len(sys.argv) > 2 and sys.argv[1] == "--serve":
        return _serve(sys.argv[2])
    if len(sys.argv) > 3 and sys.argv[1] == "--run-tests" and sys.argv[3] == "--":
        return _run_tests_client(sys.argv[2], sys.argv[4:])
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--modules", default="", help="comma-separated subset of: " + ", ".join(TARGETS))
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="mutants tested at once, each in its own copy (default: CPUs)")
    ap.add_argument("--tool-python", default=sys.executable, help=f"the Python with {TOOL} {TOOL_VERSION} installed (default: this one)")
    ap.add_argument("--dry-run", action="store_true", help="count the mutants in scope, test none")
    ap.add_argument("--keep", default="", help="keep the sessions and copies in this directory")
    ap.add_argument("--results", default="", help="also merge the modules measured into this results file (e.g. "
                    "benchmarks/results_mutation.json: the other modules' entries are kept; docs/mutation.md is generated from it)")
    args = ap.parse_args()
    names = [n.strip() for n in args.modules.split(",") if n.strip()] or list(TARGETS)
    unknown = [n for n in names if n not in TARGETS]
    if unknown:
        ap.error(f"unknown module(s) {unknown}; choose from {list(TARGETS)}")
    probe = subprocess.run([args.tool_python, "-c", "import importlib.metadata as m; print(m.version('cosmic-ray'))"], capture_output=True, text=True)
    if probe.returncode != 0:
        print(f"bench_mutation: {TOOL} is not installed for {args.tool_python}; install the pinned tool with: {INSTALL_HINT}", file=sys.stderr)
        return 2
    version = probe.stdout.strip()
    if version != TOOL_VERSION:
        print(f"bench_mutation: warning: {TOOL} {version} found, {TOOL_VERSION} pinned ({INSTALL_HINT})", file=sys.stderr)
    t_start = time.perf_counter()
    # what is measured: the commit, and whether the measured paths differ from it (read now, before the copies)
    args.commit = _git("rev-parse", "--short=12", "HEAD") or None
    args.tree_clean = not _git("status", "--porcelain", "--", *COPIED, "benchmarks/bench_mutation.py")
    work = Path(args.keep).resolve() if args.keep else Path(tempfile.mkdtemp(prefix="sappc-mutation-"))
    work.mkdir(parents=True, exist_ok=True)
    children: list[subprocess.Popen[Any]] = []
    workers: list[Worker] = []
    try:
        return _campaign(args, names, version, work, t_start, children, workers)
    finally:
        for w in workers:
            w.stop()
        for c in children:
            _kill_group(c)
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)


def _campaign(args: argparse.Namespace, names: list[str], version: str, work: Path, t_start: float,
              children: list[subprocess.Popen[Any]], workers: list[Worker]) -> int:
    jobs = max(1, args.jobs)
    tool = [args.tool_python, "-m", "cosmic_ray.cli"]
    copies = [work / f"tree{i}" for i in range(1 if args.dry_run else jobs)]
    for c in copies:
        if not c.exists():
            _copy_tree(c)
    sock = work / "pytest.sock"
    if not args.dry_run:
        sock.unlink(missing_ok=True)
        env = dict(os.environ, NUMBA_DISABLE_JIT="1", SAPPC_CACHE_DIR=str(work / "numba-cache"), PYTHONDONTWRITEBYTECODE="1",
                   SAPPC_TEST_DEADLINE_S=str(NODE_TEST_DEADLINE_S))
        env.pop("PYTHONPATH", None)
        env.pop("NUMBA_CACHE_DIR", None)
        children.append(subprocess.Popen([sys.executable, str(Path(__file__).resolve()), "--serve", str(sock)], env=env, cwd=work,
                                         start_new_session=True))
        deadline = time.monotonic() + 120
        while not sock.exists():
            if children[0].poll() is not None or time.monotonic() > deadline:
                raise SystemExit("bench_mutation: the test server did not start")
            time.sleep(0.1)
        workers.extend(Worker(args.tool_python, c) for c in copies)
    free: queue.Queue[Worker] = queue.Queue()
    for w in workers:
        free.put(w)

    modules: dict[str, Any] = {}
    survivors: list[dict[str, Any]] = []
    lock = threading.Lock()
    for name in names:
        target = TARGETS[name]
        pristine = (copies[0] / target.path).read_bytes()
        lines = mutable_lines(pristine.decode(), target.functions, target.skip_functions)
        command = shlex.join([sys.executable, str(Path(__file__).resolve()), "--run-tests", str(sock), "--", *pytest_args(target)])
        sess_dir = work / "sessions" / re.sub(r"[^A-Za-z0-9_.]+", "_", name)
        sess_dir.mkdir(parents=True, exist_ok=True)
        config, session = sess_dir / "config.toml", sess_dir / "session.sqlite"

        baseline_s = 0.0
        if not args.dry_run:  # the unmutated tree must pass the selection
            t0 = time.perf_counter()
            base = subprocess.run(shlex.split(command), cwd=copies[0], capture_output=True, text=True, timeout=1800)
            baseline_s = time.perf_counter() - t0
            if base.returncode != 0:
                raise SystemExit(f"bench_mutation: the tests of {name} fail without a mutant:\n{base.stdout[-4000:]}{base.stderr[-2000:]}")
        timeout_s = max(20.0, 4.0 * baseline_s)
        write_config(config, target, lines, command, timeout_s)
        _run([*tool, "init", "--force", str(config), str(session)], cwd=copies[0])
        _run([args.tool_python, "-m", "cosmic_ray.tools.filters.operators_filter", str(session), str(config)], cwd=copies[0])
        _run([args.tool_python, "-m", "cosmic_ray.tools.filters.line_filter", str(session), "--config", str(config)], cwd=copies[0])
        notes = annotation_spans(pristine.decode())
        pending = [m for m in _pending(tool, session) if not any(a <= tuple(m["start_pos"]) < b for a, b in notes)
                   and not (m["operator_name"] == "core/NumberReplacer" and m["occurrence"] % 2)]  # +1 only (odd: -1)
        print(f"bench_mutation: {name}: {len(pending)} mutants in scope; tests {baseline_s:.1f} s unmutated", file=sys.stderr, flush=True)
        if args.dry_run:
            modules[name] = {"mutants": len(pending), "lines_in_scope": len(lines)}
            continue
        counts = {"killed": 0, "survived": 0, "timeout": 0, "error": 0}
        kills_by_stage: dict[int, int] = {}
        t_mod = time.perf_counter()
        mtime_ns = os.stat(copies[0] / target.path).st_mtime_ns

        def one(m: dict[str, Any]) -> None:
            w = free.get()
            try:
                result = w.mutate_and_test(m, command, timeout_s)
                path = w.tree / target.path
                if path.read_bytes() != pristine:  # cosmic-ray restores the file; make sure
                    path.write_bytes(pristine)
                os.utime(path, ns=(mtime_ns, mtime_ns))  # the unmutated byte-code is valid again
                shutil.rmtree(w.tree / ".hypothesis", ignore_errors=True)
            finally:
                free.put(w)
            if result.get("test_outcome") == "killed" and result.get("output") == "timeout":
                outcome = "timeout"
            elif result.get("worker_outcome") == "normal" and result.get("test_outcome") in ("killed", "survived"):
                outcome = result["test_outcome"]
            else:
                outcome = "error"
            stage = re.search(r"bench_mutation: stage (\d+) failed", result.get("output") or "")
            record = {"module": name, "operator": m["operator_name"].removeprefix("core/"), "occurrence": m["occurrence"],
                      "line": _line_of(result.get("diff") or "") or m["start_pos"][0], "outcome": outcome,
                      "stage": int(stage.group(1)) if stage else None}
            with lock:
                with open(work / "results.jsonl", "a") as log:
                    log.write(json.dumps({**record, "diff": result.get("diff")}) + "\n")
                if record["stage"]:
                    kills_by_stage[record["stage"]] = kills_by_stage.get(record["stage"], 0) + 1
                counts[outcome] += 1
                if outcome in ("survived", "error"):
                    diff = result.get("diff") or ""
                    changed = [d for d in diff.splitlines() if d[:1] in "+-" and not d.startswith(("+++", "---"))]
                    operator = m["operator_name"].removeprefix("core/")
                    survivors.append({"module": name, "id": mutant_id(name, operator, changed), "outcome": outcome,
                                      "line": _line_of(diff) or m["start_pos"][0], "operator": operator, "occurrence": m["occurrence"],
                                      "diff": changed,
                                      **({"output": (result.get("output") or "")[-3000:]} if outcome == "error" else {})})
                done = sum(counts.values())
                if done % 50 == 0 or done == len(pending):
                    print(f"bench_mutation: {name}: {done}/{len(pending)} {counts} ({time.perf_counter() - t_mod:.0f} s)", file=sys.stderr,
                          flush=True)

        pool = concurrent.futures.ThreadPoolExecutor(jobs)
        try:
            for f in [pool.submit(one, m) for m in pending]:
                f.result()
        finally:  # on an error or a signal, drop the queued mutants (the workers are stopped by main)
            pool.shutdown(wait=False, cancel_futures=True)
        total = sum(counts.values())
        modules[name] = {**counts, "total": total,
                         "score": round((counts["killed"] + counts["timeout"]) / total, 4) if total else None,
                         "killed_by_stage": {"quick": kills_by_stage.get(1, 0), "more": kills_by_stage.get(2, 0)},
                         "tests_unmutated_s": round(baseline_s, 1), "wall_s": round(time.perf_counter() - t_mod, 1),
                         "path": target.path, "scope": scope_text(target), "lines_in_scope": len(lines),
                         "tests": {"quick": list(target.quick), "more": list(target.more)},
                         "source_sha256": hashlib.sha256(pristine).hexdigest()}

    report: dict[str, Any] = {
        "tool": TOOL, "tool_version": version, "pinned_version": TOOL_VERSION,
        "date": time.strftime("%Y-%m-%d"),
        "machine": {"platform": platform.platform(), "python": platform.python_version(), "cpu_count": os.cpu_count(), "jobs": jobs},
        "numba_disable_jit": True,
        "operators": list(KEPT_OPERATORS),
        "modules": modules,
    }
    if args.dry_run:
        report["overall"] = {"mutants": sum(m["mutants"] for m in modules.values())}
    else:
        tot = {k: sum(m[k] for m in modules.values()) for k in ("killed", "survived", "timeout", "error", "total")}
        tot["score"] = round((tot["killed"] + tot["timeout"]) / tot["total"], 4) if tot["total"] else None
        report["overall"] = tot
        report["survivors"] = sorted(survivors, key=lambda s: (s["module"], s["line"], s["operator"], s["occurrence"]))
    report["wall_s"] = round(time.perf_counter() - t_start, 1)
    print(json.dumps(report, indent=1))
    if args.results and not args.dry_run:
        merge_results(Path(args.results), report, args.commit, args.tree_clean)
    return 0


def mutant_id(module: str, operator: str, diff: list[str]) -> str:
    """A survivor's identity across runs: its module, operator and changed lines (not its line
    number, which moves with edits elsewhere in the file); the key of its classification."""
    text = "\n".join([module, operator, *(d.rstrip() for d in diff)])
    return hashlib.sha1(text.encode()).hexdigest()[:10]


def scope_text(target: Target) -> str:
    """What of the module is mutated, in words (the results file and the generated page)."""
    if target.functions is not None:
        return f"only {', '.join(f'`{f}`' for f in target.functions)}"
    return "whole module" + (f" but {', '.join(f'`{f}`' for f in target.skip_functions)}" if target.skip_functions else "")


def _git(*args: str) -> str:
    proc = subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True)
    return proc.stdout.strip() if proc.returncode == 0 else ""


def _measuring_args(argv: list[str]) -> list[str]:
    """The arguments that decide what is measured (``--keep`` and ``--results`` only say where things go)."""
    out, skip = [], False
    for a in argv:
        if skip:
            skip = False
        elif a in ("--keep", "--results"):
            skip = True
        elif not a.startswith(("--keep=", "--results=")):
            out.append(a)
    return out


def merge_results(path: Path, report: dict[str, Any], commit: str | None, tree_clean: bool) -> None:
    """Merge ``report``'s modules into the results file ``path`` (``--results``): each module's
    entry replaced, with how it was measured (date, the commit and whether the measured tree
    differed from it when the run started, command, machine, tool); the other modules' entries
    kept as they were measured."""
    results: dict[str, Any] = json.loads(path.read_text()) if path.exists() else {}
    results.setdefault("about", "mutation testing results, one entry per module as last measured (benchmarks/bench_mutation.py "
                                "--results); docs/mutation.md is generated from this file and benchmarks/mutation_survivors.yaml "
                                "(python benchmarks/mutation_table.py --write)")
    modules = results.setdefault("modules", {})
    measured = {"date": report["date"], "commit": commit, "tree_clean": tree_clean,
                "command": shlex.join(["python", "benchmarks/bench_mutation.py", *_measuring_args(sys.argv[1:])]),
                "machine": report["machine"], "tool": f"{report['tool']} {report['tool_version']}",
                "numba_disable_jit": report["numba_disable_jit"], "wall_s_all_modules_of_the_command": report["wall_s"]}
    for name, entry in report["modules"].items():
        modules[name] = {**entry, "measured": measured,
                         "survivors": [{k: v for k, v in s.items() if k != "module"} for s in report["survivors"] if s["module"] == name]}
    order = {n: i for i, n in enumerate(TARGETS)}
    results["modules"] = dict(sorted(modules.items(), key=lambda kv: (order.get(kv[0], len(order)), kv[0])))
    path.write_text(json.dumps(results, indent=1) + "\n")
    print(f"bench_mutation: merged {', '.join(report['modules'])} into {path}", file=sys.stderr)


if __name__ == "__main__":
    sys.exit(main())

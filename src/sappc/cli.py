"""The ``sappc`` command line.

    sappc simulate SCENARIO [--controller sappc|trappc|blfppc|mrp_feedback] [--json FILE] [--out DIR] [--record DIR]
    sappc simulate --from-campaign DIR --run K [--json FILE] [--out DIR]
    sappc montecarlo SCENARIO --runs N [--seed S] [--workers W] [--scheduler ADDRESS] [--out DIR] [--json FILE] [--resume]
    sappc tune SCENARIO [--controller K] [--trials N] [--runs-per-trial M] [--seed S] [--workers W | --scheduler ADDRESS] [--out DIR] [--resume]
    sappc run SCENARIO [--out DIR] [--realtime] [--compose] [--plant native|basilisk|external] [--controller K] [--json FILE] [--domain-id N] [--live [PORT] [--host ADDRESS] [--wait-subscribers N]]
    sappc params SCENARIO [--controller K | --estimator]
    sappc scenarios [copy NAME [DEST] [--force]]
    sappc report BAG [--json FILE] [--out DIR] [--scenario FILE]
    sappc compare BAG... [--out DIR] [--json FILE]
    sappc rerun BAG [--params FILE] [--json FILE] [--out DIR]
    sappc replay BAG [--rate X] [--topics T...] [--loop] [--wait-subscribers N] [--start-delay S] [--domain-id N]
    sappc replay BAG --live [PORT] [--host ADDRESS] [--rate X] [--topics T...] [--loop] [--wait-subscribers N] [--start-delay S] [--linger S]

A SCENARIO is a scenario file or the name of a bundled one (``paper_tracking``; ``sappc
scenarios`` lists them). A command given no output directory writes into ``runs/<command>/<name>``.
``--json -`` writes the JSON to stdout, and everything else the command prints to stderr.

Errors in the input (bad scenario, infeasible parameters, bad values) print one line naming the
problem and exit with status 2; no traceback. Each command's ``--help`` lists its exit statuses;
Ctrl-C ends any command with one line and status 130
(:mod:`sappc.__main__`, the command's entry: also during the imports and when started with
SIGINT ignored). When several statuses apply to one run of ``simulate`` or ``run``, the first of
3, 4, 1 in this order: a controller that never commanded says more than a broken requirement,
which says more than a count mismatch.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys
import textwrap
from typing import Any, TextIO
from pathlib import Path
from collections.abc import Iterator, Sequence

from gnc_common import collector
from gnc_common.validation import ConfigError, InputError, did_you_mean

from sappc.files import bag_run_name, default_output_dir
from sappc.controllers import ControllerKind

__all__ = ["EXIT_STATUSES", "main"]

#: Exit status for invalid input (argparse uses the same).
EXIT_INVALID_INPUT = 2
#: Exit status of ``sappc run`` / ``simulate`` when the controller commanded no torque in the whole run.
EXIT_CONTROLLER_NEVER_COMMANDED = 3
#: Exit status of ``sappc run`` / ``simulate`` when the run broke a requirement of the scenario.
EXIT_REQUIREMENT_FAILED = 4
#: Exit status after Ctrl-C (128 + SIGINT; :data:`sappc.__main__.EXIT_INTERRUPTED`, not imported:
#: that module is the command's entry, above this one).
EXIT_INTERRUPTED = 130

#: The meaning of 2 and 130, which every command shares.
_SHARED_EXITS = ((EXIT_INVALID_INPUT, "invalid input: a bad scenario, option, file or value (one line names it)"),
                 (EXIT_INTERRUPTED, "interrupted by Ctrl-C (one line; sappc run stops its nodes and closes the bag first)"))
_RUN_EXITS = ((EXIT_CONTROLLER_NEVER_COMMANDED, "the controller never commanded a torque"),
              (EXIT_REQUIREMENT_FAILED, "the run lost control (the rule of sappc.evaluation.requirements, whatever the scenario "
                                        "states), broke a requirement of the scenario's metrics.requirements, or became non-finite; "
                                        "the last line names why"))
#: When several statuses apply to one run, the first of these is the one returned (a controller
#: that never commanded says more than a broken requirement, which says more than a count mismatch).
_PRECEDENCE = (EXIT_CONTROLLER_NEVER_COMMANDED, EXIT_REQUIREMENT_FAILED, 1)
#: Each command's exit statuses and what they mean (every ``--help`` lists its own, and the
#: reference page all of them).
EXIT_STATUSES: dict[str, tuple[tuple[int, str], ...]] = {
    "simulate": ((0, "the run met the scenario's requirements (--from-campaign: the run was re-run)"), *_RUN_EXITS, *_SHARED_EXITS),
    "montecarlo": ((0, "every run passed the campaign's criteria"), (1, "a run failed the campaign's criteria or lost control"),
                   *_SHARED_EXITS),
    "tune": ((0, "a best trial was found and its confirmation campaign passed"),
             (1, "no trial met every requirement, or the best gains failed their confirmation campaign"), *_SHARED_EXITS),
    "run": ((0, "the run met the scenario's requirements and every topic's recorded count matches what was published"),
            (1, "a node failed or the run timed out (the line names it), or a topic's recorded count differs from what was published"),
            *_RUN_EXITS, *_SHARED_EXITS),
    "params": ((0, "the parameters file was printed"), *_SHARED_EXITS),
    "scenarios": ((0, "listed, or copied"), *_SHARED_EXITS),
    "report": ((0, "the bag gave metrics, figures and the page"),
               (1, "the bag holds no run to compute metrics from (no state or reference): a partial report was written"),
               *_SHARED_EXITS),
    "compare": ((0, "the comparison was written"), *_SHARED_EXITS),
    "compare-controllers": ((0, "the comparison was written; no run lost control and every run of the scenario's own controller met "
                                "its requirements"),
                            (EXIT_REQUIREMENT_FAILED, "the comparison was written, but a run lost control, or a run of the scenario's "
                             "own controller broke its requirements (one line names them)"), *_SHARED_EXITS),
    "rerun": ((0, "every recomputed torque equals the recorded one, bit for bit"),
              (1, "a recomputed torque differs from the recorded one, or no sample was re-run (as diff: expected with --params of "
                  "other gains or another controller)"), *_SHARED_EXITS),
    "repair": ((0, "the bag was rewritten readable"), *_SHARED_EXITS),
    "replay": ((0, "the bag was replayed to its end, or stopped by Ctrl-C or SIGTERM once replaying (--loop ends that way); "
                   "--live: the bag was served to its end"),
               (1, "a publisher timed out waiting for its subscribers' acknowledgements"), (EXIT_INVALID_INPUT, _SHARED_EXITS[0][1]),
               (EXIT_INTERRUPTED, "interrupted by Ctrl-C before the replay started; --live: at any time (the server is stopped first)")),
}


def exit_status_text(command: str | None = None) -> str:
    """The ``exit status`` section of a ``--help``: ``command``'s statuses, or (``None``) those
    every command shares."""
    rows = EXIT_STATUSES[command] if command is not None else _SHARED_EXITS
    head = "exit status:" if command is not None else "exit status (each command's --help lists its own):"
    text = head + "\n" + "\n".join(f"  {code:<4} {meaning}" for code, meaning in sorted(rows))
    if command in ("simulate", "run"):
        text += "\nseveral statuses at once: the first of " + ", ".join(str(c) for c in _PRECEDENCE if c in dict(rows))
    return text


#: Where ``--json -`` writes the JSON: the process's stdout, while everything else a command prints
#: goes to stderr (:func:`_stdout_to_stderr`); ``None``: ``-`` is not in use.
_json_stdout: TextIO | None = None


@contextlib.contextmanager
def _stdout_to_stderr() -> Iterator[TextIO]:
    """For ``--json -``: while the command runs, ``sys.stdout`` is ``sys.stderr`` and file
    descriptor 1 points where 2 does (its tables, progress and the output of the processes it
    starts all go to stderr); the JSON is written to a duplicate of the original descriptor 1,
    which is yielded.  Both are restored afterwards."""
    sys.stdout.flush()
    saved = os.dup(1)
    os.dup2(2, 1)
    out = os.fdopen(os.dup(saved), "w", encoding="utf-8")
    try:
        with contextlib.redirect_stdout(sys.stderr):
            yield out
    finally:
        sys.stderr.flush()
        os.dup2(saved, 1)
        os.close(saved)
        out.close()


def _format_value(value: object) -> str:
    if isinstance(value, float):
        return f"{value:.6g}"
    return "-" if value is None else str(value)


def first_deviating_sample(plant_timing: dict[str, Any], controller_timing: dict[str, Any]) -> int | None:
    """The first sample of a real-time run that may not be the lockstep run's: the plant's first
    missed or stale frame, or the controller's first sample answered unlike lockstep (a step on a
    held reference, a state too late to step: that sample's torque is not lockstep's), whichever is
    first (``first_deviating_sample`` of each one's timing file); ``None``: the whole run is the
    lockstep run."""
    found = [v for v in (plant_timing.get("first_deviating_sample"), controller_timing.get("first_deviating_sample")) if v is not None]
    return min(found) if found else None


def _realtime_summary(result: Any, lacking: dict[str, int]) -> dict[str, Any]:
    """A real-time run's frames (:mod:`sappc_msgs_py.timeline`): the plant's ticks, missed frames
    and frames integrated with a stale torque or disturbance, the controller's latency and held
    references, and ``lacking``: the frames without an input of their own stamp in the bag
    (:func:`~sappc.bag.read.frames_lacking_inputs`)."""
    plant = result.plant_timing
    keys = ("ticks", "period_error_p50_ms", "period_error_p99_ms", "period_error_max_ms", "missed_ticks", "missed_frames", "stale_torque_frames",
            "stale_disturbance_frames", "first_deviating_sample")
    summary = {"frames": lacking["frames"], **{k: plant[k] for k in keys if k in plant}}
    if "first_deviating_sample" in summary:  # the plant's (a missed or stale frame) or the controller's (a held reference, a late state)
        summary["first_deviating_sample"] = first_deviating_sample(plant, result.controller_timing)
    return {**summary,
            "frames_lacking_own_stamp": {k: v for k, v in lacking.items() if k != "frames"},
            "held_reference_steps": result.controller_timing.get("held_reference_steps", 0),
            "state_delay": plant.get("state_delay", {}), "controller_latency": result.controller_timing.get("latency", {})}


def _print_metrics(scenario_name: str, controller: str, metrics: dict[str, object]) -> None:
    print(f"scenario {scenario_name}, controller {controller}")
    width = max(len(k) for k in metrics)
    for key, value in metrics.items():
        print(f"  {key:<{width}}  {_format_value(value)}")


#: The per-orbit table's columns: (metric key, heading, format).
_ORBIT_COLUMNS = (("steady_max_abs_qev", "steady max |q_ev|", ".3e"), ("steady_mean_abs_qev", "steady mean |q_ev|", ".3e"),
                  ("max_wheel_momentum_B_Nms", "max |h_B| [N m s]", ".3f"), ("end_wheel_momentum_B_Nms", "end |h_B| [N m s]", ".3f"),
                  ("max_abs_wheel_speed_rad_s", "max wheel speed [rad/s]", ".1f"), ("rods_mean_dipole_fraction", "rods' duty", ".3f"))


def _print_orbits(per_orbit: list[dict[str, Any]]) -> None:
    """The per-orbit metrics as a table (a scenario in orbit; nothing otherwise)."""
    if not per_orbit:
        return
    cols = [c for c in _ORBIT_COLUMNS if c[0] in per_orbit[0]]
    print("per orbit:")
    print("  " + "  ".join(["orbit", "from [s]".rjust(9)] + [h.rjust(max(len(h), 9)) for _, h, _ in cols]))
    for e in per_orbit:
        cells = [str(e["orbit"]).rjust(5), f"{e['from_s']:9.1f}"]
        cells += [("-" if e[k] is None else format(e[k], f)).rjust(max(len(h), 9)) for k, h, f in cols]
        print("  " + "  ".join(cells))


def _write_json(path_str: str, data: object) -> None:
    """``data`` as JSON into the file ``path_str``, or to stdout for ``-`` (:func:`_stdout_to_stderr`)."""
    text = json.dumps(data, indent=2) + "\n"
    if path_str == "-":
        out = _json_stdout if _json_stdout is not None else sys.stdout
        out.write(text)
        out.flush()
        return
    path = Path(path_str)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    print(f"wrote {path}")


def _cmd_simulate(args: argparse.Namespace) -> int:
    from sappc.analysis.plots import plot_run

    if args.from_campaign is not None:
        return _simulate_from_campaign(args)
    if args.scenario is None:
        raise ConfigError("give a SCENARIO file, or --from-campaign DIR --run K")
    if args.run is not None:
        raise ConfigError("--run needs --from-campaign DIR")
    from sappc.offline.simulate import simulate
    from sappc.scenario import load_scenario

    scenario = load_scenario(args.scenario) if args.duration is None else _with_duration(args.scenario, args.duration)
    writer = None
    if args.record is not None:  # the bag's directory before the run: one that exists stops here
        from sappc.bag.write_offline import OfflineBagWriter

        writer = OfflineBagWriter(scenario, args.record, controller=args.controller)
    import time

    from sappc.bag.read import Ticker

    with Ticker(lambda msg: print(f"sappc simulate: {msg}", file=sys.stderr, flush=True)) as ticker:
        started = time.monotonic()
        stepped: list[bool] = []  # whether the progress line has started

        def progress(samples: int) -> None:  # after each block of samples
            if args.no_progress or time.monotonic() - started < SIMULATE_PROGRESS_AFTER_S:
                return
            if not stepped:
                ticker.step("simulating")
                stepped.append(True)
            ticker.detail(f"{samples * scenario.control_period_s:.0f} of {scenario.duration_s:.0f} s")

        # memory flat in the run's length: the figures from the envelope, no history without them;
        # with --record each block of the run written to the bag as it comes
        try:
            result = simulate(scenario, args.controller, history="envelope" if args.out else "none", progress=progress,
                              sinks=() if writer is None else (writer,))
        finally:
            if writer is not None:
                writer.close()  # (a failed run: what was written, a whole file)
        ticker.idle()
    if writer is not None:
        from sappc.bag.live import write_layout

        write_layout(writer.dir)  # beside the bag: Foxglove's layout for it
        print(f"wrote {writer.dir} ({writer.samples} samples of {len(writer.channels)} topics, and its Foxglove layout)")
    _print_metrics(scenario.name, result.controller.value, result.metrics)
    _print_orbits(result.per_orbit)
    failed = _print_outcome(scenario, result.metrics, result.controller_summary)
    if args.out and result.history is not None:
        for p in plot_run(result.history, Path(args.out), title=f"{scenario.name} ({result.controller.value})",
                          fault_windows=scenario.event_windows(), wheels=scenario.wheels):
            print(f"wrote {p}")
    if args.json:
        _write_json(args.json, {**result.report(), "failed_requirements": failed})
    _print_verdict(scenario, failed)
    return run_exit_status({}, result.controller_summary, failed)


#: A ``sappc simulate`` run shows a progress line once it has run this long [s]: the paper's runs
#: (under a second) print none, a 6 h orbit run (tens of seconds) one a second.
SIMULATE_PROGRESS_AFTER_S = 2.0


def _with_duration(path: str, duration_s: float) -> Any:
    """The scenario at ``path`` flown for ``duration_s`` (``simulate --duration``): its mapping with
    ``duration_s`` replaced, validated as the file is (the message names the file)."""
    from sappc.files import scenario_path
    from sappc.scenario import read_scenario_mapping, scenario_from_mapping

    p = scenario_path(path)
    raw = read_scenario_mapping(p)
    raw["duration_s"] = duration_s
    try:
        return scenario_from_mapping(raw, source=str(p))
    except ConfigError as exc:
        raise ConfigError(f"{p} with --duration {duration_s!r}: {exc}") from None


def _print_outcome(scenario: Any, metrics: dict[str, Any], controller: dict[str, Any]) -> list[str]:
    """Print what the controller did; return the ways the run failed (:mod:`sappc.evaluation.requirements`:
    non-finite, the loss-of-control rule, the scenario's requirements; empty: it passed), which
    :func:`_print_verdict` prints as the command's last line."""
    from sappc.evaluation.requirements import failed_requirements

    if controller.get("commanded") is not None:
        others = ", ".join(f"{k.replace('_', ' ')} {controller[k]}" for k in ("watchdog_zero", "held", "refused") if controller.get(k))
        if controller.get("inactive"):
            others += (", " if others else "") + f"inactive (another mode's law) {controller['inactive']}"
        rejected = controller.get("rejected_inputs")
        print(f"controller: computed the torque of {controller['commanded']} of {controller['samples']} samples"
              + (f"; not commanded: {others}" if others else "")
              + (f"; {rejected} input messages rejected" if rejected is not None else ""))
    _print_modes(metrics)
    return failed_requirements(metrics, scenario.metrics.requirements, controller, settle_threshold=scenario.metrics.settle_threshold)


def _print_modes(metrics: dict[str, Any]) -> None:
    """The flight modes' line of a run with flight modes (``sappc simulate``, ``run``, ``report``): the
    modes flown, the transitions, TRACK's start and the time in each mode; nothing without modes."""
    if "mode_sequence" in metrics:
        times = metrics["time_in_mode_s"]
        print("modes: " + " -> ".join(metrics["mode_sequence"]) + f" ({metrics['mode_transitions']} transitions"
              + ("" if metrics["time_to_track_s"] is None else f"; TRACK from {metrics['time_to_track_s']:.2f} s")
              + "; time in " + ", ".join(f"{name} {s:.1f} s" for name, s in times.items() if s > 0.0) + ")")


def _print_verdict(scenario: Any, failed: Sequence[str], degraded: str = "") -> None:
    """The run's verdict in one line: ``FAILED: ...`` naming every failure (and, after a degraded
    real-time run, ``degraded``: why), else that it met the scenario's requirements."""
    print(_verdict_line(scenario, failed, degraded))


def _verdict_line(scenario: Any, failed: Sequence[str], degraded: str = "") -> str:
    """:func:`_print_verdict`'s line (also ``sappc run --live``'s last message to the view)."""
    if failed:
        return "FAILED: " + "; ".join(failed) + (f" ({degraded})" if degraded else "")
    if scenario.metrics.requirements:
        return (f"met every requirement of the scenario ({', '.join(f'{k} {v:g}' for k, v in scenario.metrics.requirements.items())}) "
                "and kept control")
    return "kept control (the scenario states no requirements)"


def _simulate_from_campaign(args: argparse.Namespace) -> int:
    from sappc.montecarlo.campaign import load_campaign_run
    from sappc.montecarlo.config import campaign_config
    from sappc.montecarlo.results import run_criteria
    from sappc.analysis.plots import plot_run

    if args.scenario is not None or args.controller is not None:
        raise ConfigError("--from-campaign takes the scenario and controller from the campaign; give neither")
    if args.record is not None:
        raise ConfigError("--record records a scenario's run, not a campaign's: give SCENARIO")
    if args.duration is not None:
        raise ConfigError("--duration changes a scenario's run, not a campaign's: give SCENARIO")
    if args.run is None:
        raise ConfigError("--from-campaign needs --run K")
    scenario, row, metrics, history = load_campaign_run(args.from_campaign, args.run, with_history=bool(args.out))
    crit = run_criteria(row, campaign_config(scenario).criteria)
    campaign_row = {
        "run": int(row["run"][0]),
        "passed": bool(crit.passed[0]),
        "rpf_error_at_t2": float(crit.rpf_error_at_t2[0]),
        "steady_mean_abs_qev": float(crit.steady_mean_abs_qev[0]),
        "steady_max_abs_qev": float(row["steady_max_abs_qev"][0]),
        "max_abs_torque_Nm": float(row["max_abs_torque_Nm"][0]),
    }
    _print_metrics(f"{scenario.name} run {args.run} (from {args.from_campaign})", scenario.controller.value, metrics)
    if history is not None:
        for p in plot_run(history, Path(args.out), title=f"{scenario.name} run {args.run}",
                          fault_windows=scenario.event_windows()):
            print(f"wrote {p}")
    if args.json:
        _write_json(args.json, {"scenario": scenario.name, "run": args.run, "metrics": metrics, "campaign_row": campaign_row})
    return 0


def _cmd_montecarlo(args: argparse.Namespace) -> int:
    from sappc.analysis.plots import CAMPAIGN_FIGURE_SHAPES, FigureWorker

    # forked first, before numba is imported (sappc.montecarlo.campaign imports it): the child
    # imports matplotlib and makes the trajectory and error figures in advance while the runs go, then draws
    # the campaign's figures in two processes (this process never imports matplotlib)
    with FigureWorker(prepare=CAMPAIGN_FIGURE_SHAPES) as figures:
        return _montecarlo(args, figures)


def _montecarlo(args: argparse.Namespace, figures: Any) -> int:
    from sappc.montecarlo.campaign import run_campaign

    out = args.out or str(default_output_dir("montecarlo", f"{Path(args.scenario).stem}-seed{args.seed}"))
    summary = run_campaign(args.scenario, runs=args.runs, seed=args.seed, out_dir=out, workers=args.workers,
                           scheduler=args.scheduler, resume=args.resume, progress=not args.no_progress, figure_worker=figures)
    print(f"campaign {summary['scenario']}: {summary['passed']}/{summary['runs']} runs pass "
          f"(rpf_error_at_t2 < {summary['criteria']['rpf_error_at_t2_max']:g}, "
          f"steady_mean_abs_qev < {summary['criteria']['steady_mean_abs_qev_max']:g})")
    for key in ("rpf_error_at_t2", "steady_mean_abs_qev"):  # None: no run measured it (e.g. runs shorter than t2)
        print(f"  {key:<19}  " + "  ".join(f"{q} {_fmt(summary[key][q], '.3g')}" for q in ("p50", "p99", "max")))
    switching = summary["torque_sign_changes_per_s"]
    if switching["max"] is not None:  # None: no steady window with two samples
        print(f"  torque_sign_changes_per_s  p50 {switching['p50']:.3g}  p99 {switching['p99']:.3g}  max {switching['max']:.3g}")
    print(f"  non-finite runs {summary['non_finite_runs']}, runs that lost control {summary['runs_lost_control']}, "
          f"RPF components clamped {summary['rpf_clamped_components']}, "
          f"flat {summary['rpf_flat_components']}; wall {summary['wall_time_s']:.1f} s")
    answers = summary["controller_answers"]
    not_commanded = {k: v for k, v in answers.items() if k != "commanded" and v["samples"]}
    if not_commanded or summary["runs_never_commanded"]:
        print("  controller answers not commanded: " + ", ".join(f"{k.replace('_', ' ')} {v['samples']} samples in {v['runs']} runs"
                                                             for k, v in not_commanded.items())
              + f"; runs never commanded {summary['runs_never_commanded']}")
    if "modes" in summary:
        tt = summary["modes"]["time_to_track_s"]
        print(f"  modes: time to TRACK p50 {_fmt(tt['p50'], '.1f')} s, p95 {_fmt(tt['p95'], '.1f')} s, max {_fmt(tt['max'], '.1f')} s; "
              f"runs that never reached TRACK {summary['modes']['runs_never_tracked']}")
    for f in summary["failed_runs"][:10]:
        print(f"  failed run {f['run']}: {f['why']}")
    print(f"results in {out}")
    if args.json:
        _write_json(args.json, summary)
    return 0 if summary["passed"] == summary["runs"] else 1


def _measure_run(scenario: Any, bag_dir: Path, realtime: bool) -> tuple[Any, dict[str, Any], Any, Any]:
    """``sappc run``'s reading of its bag: (the run, its metrics, per orbit, the real-time frames
    lacking an input of their own stamp, None in lockstep), with a line at least every 2 s to the
    last (issue 46): reading the bag back, aligning it, its metrics."""
    from sappc.bag.read import Ticker, bag_metrics, bag_run, frames_lacking_inputs, read_bag

    ms = scenario.metrics
    with Ticker(lambda msg: print(f"sappc run: {msg}", file=sys.stderr, flush=True)) as ticker:
        settings: dict[str, Any] = {"steady_from_s": ms.steady_from_s, "settle_threshold": ms.settle_threshold, "t2_s": ms.t2_s,
                    "fault_windows": scenario.event_windows(), "orbit_bins": scenario.orbit_bins(), "origin": ms.origin}
        frames_lacking = None
        if realtime:  # the frames' own-stamp check reads every message: the bag whole (a real-time run is minutes)
            bag = read_bag(bag_dir, ticker=ticker)
            run = bag_run(bag, duration_s=scenario.duration_s, ticker=ticker)  # the run's span, [0, duration_s]: no sample after it
            metrics, per_orbit = bag_metrics(bag, run=run, ticker=ticker, **settings)
            frames_lacking = frames_lacking_inputs(bag, run, scenario.control_period_s, scenario.duration_s)
        else:  # lockstep: the bag a block at a time, memory flat in the run's length (issue 47), the same metrics
            from sappc.bag.blocks import BagBlocks, NoFigures
            from sappc.bag.errors import BagError

            measured = BagBlocks(bag_dir, duration_s=scenario.duration_s, ticker=ticker).measure(figures=lambda t_end_s: NoFigures(),
                                                                                             **settings)
            if measured.run is None or measured.metrics is None:
                raise BagError(measured.problem or f"{bag_dir}: no run in the bag")  # bag_run's own message (it names the bag)
            run, metrics, per_orbit = measured.run, measured.metrics, measured.per_orbit
    return run, metrics, per_orbit, frames_lacking


def _node_counts(controller_timing: dict[str, Any]) -> dict[str, Any]:
    """The controller node's own counts (a rejection in the last frame reaches no diagnostics
    message the bag could hold)."""
    return {k: controller_timing[k] for k in ("refused_steps", "rejected_by_reason", "rejected_inputs") if k in controller_timing}


def _cmd_run(args: argparse.Namespace) -> int:
    from sappc.graph.launch import run_graph

    if args.live is None:
        for option, value in (("--host", args.host), ("--wait-subscribers", args.wait_subscribers)):
            if value is not None:
                raise InputError(f"{option} is an option of --live (the Foxglove WebSocket server); give --live too")
    measured: list[tuple[Any, dict[str, Any], Any, Any]] = []  # the bag's reading, made once: for the live view, then here

    def live_verdict(scenario: Any, run_dir: Path) -> tuple[bool, str]:
        """--live: the verdict while the recorder still serves (the same reading as below, kept)."""
        from sappc.evaluation.requirements import failed_requirements

        measured.append(_measure_run(scenario, run_dir / "bag", args.realtime))
        run, metrics = measured[0][0], dict(measured[0][1])
        timing = run_dir / "logs" / "controller_timing.json"
        ctrl = {**run.controller_summary(), **_node_counts(json.loads(timing.read_text()) if timing.exists() else {})}
        failed = failed_requirements(metrics, scenario.metrics.requirements, ctrl, settle_threshold=scenario.metrics.settle_threshold)
        return bool(failed), _verdict_line(scenario, failed)

    try:
        result = run_graph(args.scenario, out_dir=args.out, controller=args.controller, realtime=args.realtime, domain_id=args.domain_id,
                           compose=args.compose, plant=args.plant, rt_priority=args.rt_priority, live_port=args.live,
                           live_host=args.host or "127.0.0.1", verdict=live_verdict if args.live is not None else None,
                           live_wait_subscribers=args.wait_subscribers or 0)
    except RuntimeError as exc:
        if isinstance(exc, RecursionError):  # a bug, not a failed run: its traceback, not "failed"
            raise
        print(f"sappc run: failed: {exc}", file=sys.stderr)
        return 1
    scenario, kind = result.scenario, result.controller
    run, metrics, per_orbit, frames_lacking = measured[0] if measured else _measure_run(scenario, result.bag_dir, args.realtime)
    metrics["wall_time_s"] = result.run_s
    if result.startup_s is not None:  # from the plant's own timing: none with an external plant
        metrics["startup_s"] = result.startup_s
    if result.first_sample_after_up_s is not None:
        metrics["first_sample_after_nodes_up_s"] = result.first_sample_after_up_s
    _print_metrics(scenario.name, f"{kind.value}, {'real time' if args.realtime else 'lockstep'}, through the ROS 2 graph{' (composed)' if args.compose else ''}", metrics)
    _print_orbits(per_orbit)
    mismatched = result.mismatched_counts()
    ctrl = {**run.controller_summary(), **_node_counts(result.controller_timing)}
    failed = _print_outcome(scenario, metrics, ctrl)
    missed = int(result.plant_timing.get("missed", {}).get("torque", 0))
    if missed:
        print(f"plant: {missed} sample(s) integrated with the last torque after lockstep_timeout_s without an answer "
              "(a message lost outside the fault injector, or a machine too loaded to answer in time): see logs/plant.log")
    realtime = _realtime_summary(result, frames_lacking) if frames_lacking is not None else None
    if realtime:
        lat = realtime["controller_latency"]
        lacking = realtime["frames_lacking_own_stamp"]
        print(f"real time: {realtime['frames']} frames of {scenario.control_period_s * 1e3:g} ms, {realtime['missed_frames']} without a plant tick, "
              f"{realtime['stale_torque_frames']} with a stale torque; frames without an input of their own stamp: state {lacking['state']}, "
              f"reference {lacking['reference']}, torque {lacking['torque']}; controller latency from the state's stamp p50 "
              f"{lat.get('latency_p50_ms', float('nan')):.2f} ms, p99 {lat.get('latency_p99_ms', float('nan')):.2f} ms, "
              f"{lat.get('late_steps', 0)} step(s) later than a frame")
    print(f"bag {result.bag_dir}: {sum(result.recorded.values())} messages on {sum(1 for n in result.recorded.values() if n)} topics; "
          + ("every topic's count matches what was published" if not mismatched else f"COUNT MISMATCH (published, recorded): {mismatched}"))
    degraded = _realtime_degraded(realtime, ctrl) if realtime else ""
    if args.json:
        _write_json(args.json, {
            "scenario": scenario.name,
            "controller": kind.value,
            "mode": "realtime" if args.realtime else "lockstep",
            "composed": args.compose,
            "metrics": metrics,
            **({"per_orbit": per_orbit} if per_orbit else {}),
            "bag": str(result.bag_dir),
            "published": result.published,
            "recorded": result.recorded,
            "controller_summary": ctrl,
            **({"realtime": realtime} if realtime else {}),
            "failed_requirements": failed,
            **({"degraded": degraded} if degraded else {}),
            "parameters": {"scenario": scenario.raw, "nodes": str(result.run_dir / "params.yaml")},
        })
    _print_verdict(scenario, failed, degraded)
    return run_exit_status(mismatched, ctrl, failed)


def _realtime_degraded(realtime: dict[str, Any], controller: dict[str, Any]) -> str:
    """Why a real-time run was degraded, for its verdict line: the frames the plant missed or
    integrated with a stale torque, and the samples the controller held or zeroed ('' when none)."""
    parts = [f"{realtime[k]} {label}" for k, label in (("missed_frames", "missed frames"), ("stale_torque_frames", "stale-torque frames"))
             if realtime.get(k)]
    parts += [f"{controller[k]} {label}" for k, label in (("held", "held torques"), ("watchdog_zero", "zero torques from the watchdog"))
              if controller.get(k)]
    return "real time degraded: " + ", ".join(parts) if parts else ""


def run_exit_status(mismatched: dict[str, tuple[int, int]], controller: dict[str, Any], failed: Sequence[str] = ()) -> int:
    """The exit status of ``sappc run`` and ``simulate`` (module docstring):
    :data:`EXIT_CONTROLLER_NEVER_COMMANDED` when the controller never commanded a torque,
    :data:`EXIT_REQUIREMENT_FAILED` when the run broke a requirement (``failed``), 1 when a topic's
    recorded count differs from what was published, else 0."""
    if controller.get("commanded") == 0:
        return EXIT_CONTROLLER_NEVER_COMMANDED
    if failed:
        return EXIT_REQUIREMENT_FAILED
    return 0 if not mismatched else 1


def _fmt(value: Any, spec: str = ".4g") -> str:
    """A number as the tables print it; ``-`` for ``None`` (a metric no run measured)."""
    return "-" if value is None else format(value, spec)


def _cmd_tune(args: argparse.Namespace) -> int:
    from sappc.montecarlo.tuning import run_tuning

    out = args.out or str(default_output_dir("tune", Path(args.scenario).stem))
    summary = run_tuning(args.scenario, out_dir=out, controller=args.controller, trials=args.trials, runs_per_trial=args.runs_per_trial,
                         seed=args.seed, workers=args.workers, scheduler=args.scheduler, resume=args.resume, progress=not args.no_progress)
    print(f"study {summary['scenario']} ({summary['controller']}): {summary['trials']} trials of {summary['runs_per_trial']} runs, "
          f"{summary['feasible_trials']} feasible, {summary['invalid_trials']} invalid; {summary['wall_time_s']:.1f} s")
    best = summary["best"]
    if best is None:
        print("no trial met every requirement: widen the ranges, relax the requirements or add trials (see history.png)")
        for name, b in summary["blocking"].items():
            if not b["trials_blocked"]:
                continue
            closest = "no run measured it" if b["best_value"] is None else \
                f"closest: trial {b['best_trial']}, worst run {b['best_value']:.4g} against the bound {b['bound']:.4g}"
            print(f"  {name} blocked {b['trials_blocked']} of {b['trials']} trials; {closest}")
        print(f"results in {out}")
        if args.json:
            _write_json(args.json, summary)
        return 1
    obj = summary["objective"]
    print(f"best: trial {best['trial']}, p{obj['percentile']:g} {obj['metric']} {best['value']:.4g}")
    sets = best["gain_sets"]
    print("  " + f"{'':<28}" + "".join(f"{name:>14}" for name in sets))
    for path in best["parameters"]:
        print("  " + f"{path:<28}" + "".join(f"{g[path]:>14.6g}" for g in sets.values()))
    print("  the scenario's own case (undispersed):")
    for key in ("steady_max_abs_qev", "settling_time_s", "overshoot", "torque_sign_changes_per_s"):
        print("  " + f"  {key:<26}" + "".join(f"{_fmt(best['nominal_run'][name][key]):>14}" for name in sets))
    conf = summary.get("confirmation")
    if conf:
        print(f"  confirmation campaign ({conf['runs']} runs the study never saw):")
        print("  " + f"  p{obj['percentile']:g} {obj['metric']}".ljust(28) + "".join(f"{conf[name]['objective']:>14.4g}" for name in sets))
        print("  " + "  pass fraction".ljust(28) + "".join(f"{conf[name]['pass_fraction']:>14.3f}" for name in sets))
        for name in sets:
            if conf[name]["runs_failing"]:
                print(f"  {name}: runs failing {conf[name]['runs_failing']}")
    print(f"gains in {best['scenario_file']} and {best['controller_params_file']}; figures and summary.json in {out}")
    if args.json:
        _write_json(args.json, summary)
    return 0 if not conf or conf["tuned"]["feasible"] else 1


def _cmd_compare_controllers(args: argparse.Namespace) -> int:
    from sappc.montecarlo.comparison import compare_controllers, exit_failures

    out = args.out or str(default_output_dir("compare-controllers", f"{Path(args.scenario).stem}-seed{args.seed}"))
    summary = compare_controllers(args.scenario, seeds=args.seeds, seed=args.seed, controllers=args.controllers, out_dir=out)
    print((Path(out) / "comparison.md").read_text(), end="")
    for kind, v in summary["verdict"].items():
        held = " (the scenario's controller)" if kind == summary["scenario_controller"] else ""
        print(f"  {kind}{held}: {summary['seeds'] - v['runs_failing_requirements']} of {summary['seeds']} runs met the scenario's "
              f"requirements and kept control; {v['runs_lost_control']} lost control")
    print(f"wall {summary['wall_time_s']:.1f} s; comparison.md, comparison.csv, runs.csv, comparison.png and summary.json in {out}")
    if args.json:
        _write_json(args.json, summary)
    failures = exit_failures(summary)
    if failures:
        print("FAILED: " + "; ".join(failures))
        return EXIT_REQUIREMENT_FAILED
    return 0


def _cmd_params(args: argparse.Namespace) -> int:
    from sappc.scenario import controller_params_yaml, estimator_params_yaml, load_scenario

    scenario = load_scenario(args.scenario)
    print(estimator_params_yaml(scenario) if args.estimator else controller_params_yaml(scenario, args.controller), end="")
    return 0


#: The width of ``sappc scenarios``' lines (a description is shortened to fit).
_LIST_COLUMNS = 110


def _cmd_scenarios(args: argparse.Namespace) -> int:
    from sappc.files import DATA_DIR, bundled_scenarios, copy_scenario

    if args.action == "copy":
        for path in copy_scenario(args.name, args.dest, force=args.force):
            print(f"wrote {path}")
        return 0
    scenarios = bundled_scenarios()
    width = max(len(s.name) for s in scenarios)
    for s in scenarios:
        text = (f"[extends {s.extends}] " if s.extends else "") + s.description
        print(f"{s.name:<{width}}  {textwrap.shorten(text, _LIST_COLUMNS - width - 2, placeholder=' ...')}")
    print(f"\nrun one by name (sappc simulate paper_tracking), or copy it out to edit: sappc scenarios copy NAME [DEST]\n"
          f"the nodes' parameter files and the Foxglove layout are in {DATA_DIR}", file=sys.stderr)
    return 0


def _refuse_used_out(out: str | None) -> None:
    """Refuse an ``--out`` directory that already holds files, as ``sappc run`` does (two outputs never mix)."""
    if out and Path(out).is_dir() and any(Path(out).iterdir()):
        raise ConfigError(f"--out {out} exists and is not empty; choose a new directory")


def _cmd_report(args: argparse.Namespace) -> int:
    import gc

    from sappc.analysis.plots import RUN_FIGURE_SHAPES, FigureWorker

    _refuse_used_out(args.out)
    # No cyclic garbage collection in this short command (nor in its figure processes, forked with
    # it off): its passes over matplotlib's many young objects cost 0.1-0.2 s of a report's ~1 s,
    # while the cycles left (closed figures) are a few MB (peak memory measured unchanged, 95 MB).
    gc.disable()
    try:
        # forked first: it imports matplotlib and makes the figures' axes while this process
        # imports the analysis and reads the bag, then draws every figure (this process never
        # imports matplotlib)
        with FigureWorker(prepare=RUN_FIGURE_SHAPES) as worker:
            from sappc.analysis.report import analyse_bag, write_report

            return _report(args, analyse_bag, write_report, worker)
    finally:
        gc.enable()


def _report(args: argparse.Namespace, analyse_bag: Any, write_report: Any, worker: Any) -> int:
    a = analyse_bag(args.bag, scenario=args.scenario)
    print(f"bag {a.path}: {sum(a.bag.counts.values())} messages on {len(a.bag.counts)} topics"
          + (f", data to t = {a.run.end_s:.3f} s" if a.run is not None else ""))  # (a long run's history is the figures' envelope)
    for line in a.problems:
        print(f"  problem: {line}")
    for line in a.notes:
        print(f"  note: {line}")
    if a.metrics is not None:
        _print_metrics(a.scenario.name if a.scenario else a.path.name, a.label, a.metrics)
        _print_modes(a.metrics)
    out = Path(args.out) if args.out else default_output_dir("report", bag_run_name(args.bag))
    paths = write_report(a, out, worker=worker)
    print(f"wrote {paths[-1]} and {len(paths) - 1} figure(s) in {out}")
    if args.json:
        _write_json(args.json, a.summary())
    return 0 if a.metrics is not None else 1


#: The most run names a comparison's default directory is named by (then ``+N``).
_COMPARISON_NAMES = 3


def _comparison_name(bags: Sequence[str]) -> str:
    """The default directory name of a comparison: its runs' names joined by ``_vs_`` (the first
    :data:`_COMPARISON_NAMES`, then how many more)."""
    names = [bag_run_name(b) for b in bags]
    shown = "_vs_".join(names[:_COMPARISON_NAMES])
    return shown + (f"+{len(names) - _COMPARISON_NAMES}" if len(names) > _COMPARISON_NAMES else "")


def _cmd_compare(args: argparse.Namespace) -> int:
    from sappc.analysis.report import analyse_bag, compare_bags

    analyses = [analyse_bag(b) for b in args.bags]
    out = Path(args.out) if args.out else default_output_dir("compare", _comparison_name(args.bags))
    header, rows, paths = compare_bags(analyses, out)
    cells = [[_format_value(v) for v in row] for row in [header] + rows]
    widths = [max(len(row[c]) for row in cells) for c in range(len(header))]
    for row in cells:
        print("  ".join(v.ljust(w) for v, w in zip(row, widths)).rstrip())
    print(f"wrote {paths[-1]} and {len(paths) - 1} figure(s) in {out}")
    if args.json:
        _write_json(args.json, {"runs": [a.summary() for a in analyses]})
    return 0


def _cmd_rerun(args: argparse.Namespace) -> int:
    from sappc.analysis.report import write_rerun_report
    from sappc.analysis.rerun import rerun_blocks

    _refuse_used_out(args.out)
    r = rerun_blocks(args.bag, args.params)  # the bag a block at a time (issue 47 item 6): the same result
    s = r.summary()
    print(f"re-ran {s['samples']} control steps of {args.bag} through the {r.controller} core ({r.mode} bag; inputs paired by {r.pairing}), parameters from {r.params_source}")
    for why, n in r.skipped.items():
        print(f"  skipped {n}: {why}")
    if r.failed_steps:
        print(f"  {r.failed_steps} step(s) refused by the core (the node would command zero torque)")
    print(f"  identical torques: {s['identical']} of {s['samples']}; largest difference {s['max_abs_diff_Nm']:.3g} N m")
    if args.out:
        paths = write_rerun_report(r, args.bag, Path(args.out))
        print(f"wrote {paths[-1]} and {len(paths) - 1} figure(s)")
    if args.json:
        _write_json(args.json, s)
    # as diff: 1 when the torques differ, whatever the parameters (the bag's own: a determinism
    # check; --params: the same answer for a script, e.g. "are these the parameters it flew with?")
    return 0 if s["all_identical"] else 1


def _cmd_repair(args: argparse.Namespace) -> int:
    from sappc.bag.rosbag2 import repair

    r = repair(args.bag)
    if r.was_complete:
        print(f"{r.path}: already complete ({r.messages} messages); metadata.yaml rewritten")
    else:
        span = (r.last_ns - r.first_ns) / 1e9
        print(f"{r.path}: rewritten complete with {r.messages} messages over {span:.3f} s of recording time "
              f"({'; '.join(f'{t} {n}' for t, n in sorted(r.counts.items()))})")
        if r.stopped_at:
            print(f"  reading stopped at the torn end of the file: {r.stopped_at}")
    if args.json:
        _write_json(args.json, {"path": str(r.path), "was_complete": r.was_complete, "messages": r.messages, "counts": r.counts,
                                "stopped_at": r.stopped_at, "first_log_time_ns": r.first_ns, "last_log_time_ns": r.last_ns})
    return 0


def _cmd_replay(args: argparse.Namespace) -> int:
    if args.live is None:
        for option, value in (("--host", args.host), ("--linger", args.linger)):
            if value is not None:
                raise InputError(f"{option} is an option of --live (the Foxglove WebSocket server); give --live too")
        from sappc.graph.replay import replay

        return replay(args.bag, rate=args.rate, topics=args.topics, loop=args.loop, wait_subscribers=args.wait_subscribers,
                      domain_id=args.domain_id, start_delay_s=1.0 if args.start_delay is None else args.start_delay)
    if args.domain_id is not None:
        raise InputError("--domain-id is an option of the ROS 2 replay; --live serves Foxglove without ROS")
    from sappc.bag.live import DEFAULT_HOST, serve_bag

    return serve_bag(args.bag, rate=args.rate, topics=args.topics, loop=args.loop, wait_subscribers=args.wait_subscribers,
                     start_delay_s=0.0 if args.start_delay is None else args.start_delay,
                     linger_s=2.0 if args.linger is None else args.linger, host=args.host or DEFAULT_HOST, port=args.live)


class _DeprecatedAlias(argparse.Action):
    """An old spelling of an option: stores into the new one's ``dest`` and prints one warning."""

    def __init__(self, option_strings: Sequence[str], dest: str, *, new: str, **kwargs: Any) -> None:
        self.new = new
        super().__init__(option_strings, dest, **kwargs)

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any, option_string: str | None = None) -> None:
        print(f"sappc: warning: {option_string} is deprecated, use {self.new} (it does the same)", file=sys.stderr)
        setattr(namespace, self.dest, values)


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("sappc")
    except PackageNotFoundError:  # the sources on sys.path without an install
        return "unknown (not installed)"


class _Version(argparse.Action):
    """``--version``: the installed package's version, looked up only when asked (importing
    :mod:`importlib.metadata` and reading the installed packages' metadata cost every command
    about 17 ms of its start when the parser looked it up)."""

    def __init__(self, option_strings: Sequence[str], dest: str = argparse.SUPPRESS, **kwargs: Any) -> None:
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS, **kwargs)

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any, option_string: str | None = None) -> None:
        print(f"{parser.prog} {_version()}")
        parser.exit()


#: What ``sappc`` alone prints after the usage.
NO_COMMAND_HINT = "sappc: give a command; `sappc --help` describes them, `sappc COMMAND --help` one of them"
#: An argument that names a scenario (``help`` of each command's positional argument).
_SCENARIO_HELP = "a scenario file, or the name of a bundled scenario (`sappc scenarios` lists them), e.g. {}"
#: An argument that names a recorded bag (``help`` of the positional argument of the bag commands).
_BAG_HELP = "a rosbag2 directory (e.g. runs/run/<run>/bag) or an .mcap file"
#: The ``help`` of ``--controller`` where it picks the controller a scenario runs with.
_CONTROLLER_HELP = "controller to {} (default: the scenario's 'controller' key)"


class _Parser(argparse.ArgumentParser):
    """argparse's parser, whose "invalid choice" (a command, ``--controller``) also suggests the
    closest valid one (:func:`~gnc_common.validation.did_you_mean`); its subcommands' parsers
    are of this class too (argparse makes them of the parent's class)."""

    def _check_value(self, action: argparse.Action, value: Any) -> None:
        if action.choices is not None and value not in action.choices and isinstance(value, str):
            choices = ", ".join(repr(c) for c in action.choices)
            raise argparse.ArgumentError(action, f"invalid choice: {value!r}{did_you_mean(value, action.choices)} (choose from {choices})")
        super()._check_value(action, value)



def _add_live_options(p: argparse.ArgumentParser, live_help: str) -> None:
    """``--live [PORT]`` and ``--host ADDRESS``: the Foxglove WebSocket view (``sappc run`` and ``sappc replay``)."""
    p.add_argument("--live", type=int, nargs="?", const=8765, default=None, metavar="PORT",
                   help=live_help + "; clients too slow lose the oldest queued messages")
    p.add_argument("--host", metavar="ADDRESS", default=None,
                   help="with --live: the address to listen on (default 127.0.0.1, this machine only; the view is "
                        "unauthenticated: 0.0.0.0 lets anyone who reaches the port read every message)")

def _parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="sappc", description="SAPPC spacecraft attitude control: offline runs and tools.",
                                     epilog=exit_status_text(), formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action=_Version, help="show the version of sappc and exit")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def command(name: str, help_text: str) -> argparse.ArgumentParser:
        return sub.add_parser(name, help=help_text, description=help_text[0].upper() + help_text[1:] + ".",
                              epilog=exit_status_text(name), formatter_class=argparse.RawDescriptionHelpFormatter)

    sim = command("simulate", "run a scenario offline (no ROS) and print its metrics")
    sim.add_argument("scenario", nargs="?", help=_SCENARIO_HELP.format("paper_tracking"))
    sim.add_argument("--from-campaign", metavar="DIR", help="re-run one run of a Monte Carlo campaign (with --run)")
    sim.add_argument("--run", type=int, metavar="K", help="the run to re-run with --from-campaign")
    sim.add_argument("--controller", choices=[c.value for c in ControllerKind], default=None,
                     help=_CONTROLLER_HELP.format("run"))
    sim.add_argument("--json", metavar="FILE", help="write metrics and all parameters used as JSON ('-': to stdout)")
    sim.add_argument("--out", metavar="DIR", help="write paper-style PNG figures to DIR (default: no figures)")
    sim.add_argument("--plots", metavar="DIR", dest="out", action=_DeprecatedAlias, new="--out", help=argparse.SUPPRESS)
    sim.add_argument("--record", metavar="DIR",
                     help="write the run's full-rate record to the new directory DIR as a bag (rosbag2, MCAP) of the graph's topics, "
                          "types and stamps, block by block (memory does not grow with the run): sappc report, compare, rerun and "
                          "Foxglove read it as a run of sappc run")
    sim.add_argument("--duration", type=float, metavar="SECONDS",
                     help="fly the scenario for this long instead of its duration_s (e.g. 86400 or 604800: a day or a week of "
                          "paper_tracking_orbit); memory does not grow with it")
    sim.add_argument("--no-progress", action="store_true", help=f"no progress line on stderr (shown once a run takes over "
                                                                 f"{SIMULATE_PROGRESS_AFTER_S:g} s)")
    sim.set_defaults(func=_cmd_simulate)
    mc = command("montecarlo", "run a Monte Carlo campaign (scenario with a 'montecarlo' section)")
    mc.add_argument("scenario", help=_SCENARIO_HELP.format("paper_montecarlo"))
    mc.add_argument("--runs", type=int, required=True, help="number of runs")
    mc.add_argument("--seed", type=int, default=0, help="root seed (default 0); run k uses SeedSequence(seed, spawn_key=(k,))")
    mc.add_argument("--workers", type=int, default=os.cpu_count() or 1,
                    help="local worker processes (default: the number of CPUs); results do not depend on it")
    mc.add_argument("--scheduler", metavar="ADDRESS", help="Dask scheduler address, e.g. tcp://10.0.0.5:8786")
    mc.add_argument("--out", metavar="DIR", help="results directory (default runs/montecarlo/<scenario>-seed<S>)")
    mc.add_argument("--json", metavar="FILE", help="also write the summary here ('-': to stdout)")
    mc.add_argument("--resume", action="store_true", help="continue an interrupted campaign in --out")
    mc.add_argument("--no-progress", action="store_true", help="no progress line on stderr")
    mc.set_defaults(func=_cmd_montecarlo, settles_start_up=True)
    tn = command("tune", "find the controller's free gains with a Monte Carlo campaign in the loop (a 'tuning' section)")
    tn.add_argument("scenario", help=_SCENARIO_HELP.format("paper_tracking_tune"))
    tn.add_argument("--controller", choices=[c.value for c in ControllerKind], default=None,
                    help=_CONTROLLER_HELP.format("tune"))
    tn.add_argument("--trials", type=int, default=None, help="trials in the study (default: tuning.trials)")
    tn.add_argument("--runs-per-trial", type=int, default=None, help="runs of each trial's campaign (default: tuning.runs_per_trial)")
    tn.add_argument("--seed", type=int, default=None, help="seed of the campaign's draws and of the sampler (default: tuning.seed)")
    tn.add_argument("--workers", type=int, default=1, help="local worker processes for each trial's campaign (default 1: this "
                    "process, in parallel over runs on its threads)")
    tn.add_argument("--scheduler", metavar="ADDRESS", help="Dask scheduler address: each trial's campaign in chunks on the cluster")
    tn.add_argument("--out", metavar="DIR", help="study directory (default runs/tune/<scenario>)")
    tn.add_argument("--resume", action="store_true", help="continue an interrupted study in --out")
    tn.add_argument("--json", metavar="FILE", help="also write the summary here ('-': to stdout)")
    tn.add_argument("--no-progress", action="store_true", help="no progress line on stderr")
    tn.set_defaults(func=_cmd_tune)
    cc = command("compare-controllers", "fly every controller of a scenario over the same sensor-noise seeds and tabulate "
                 "accuracy, settling, overshoot, torque sign changes and wheel effort")
    cc.add_argument("scenario", help=_SCENARIO_HELP.format("paper_tracking_flight"))
    cc.add_argument("--seeds", type=int, default=100, help="noise seeds per controller (default 100): run k draws its sensors' noise "
                    "from SeedSequence(SEED, spawn_key=(k,))")
    cc.add_argument("--seed", type=int, default=0, help="root seed (default 0)")
    cc.add_argument("--controllers", nargs="+", choices=[c.value for c in ControllerKind], default=None, metavar="CONTROLLER",
                    help="the controllers to compare (default: every one the scenario has parameters for)")
    cc.add_argument("--out", metavar="DIR", help="comparison.md/.csv, runs.csv, comparison.png, summary.json "
                    "(default runs/compare-controllers/<scenario>-seed<S>)")
    cc.add_argument("--json", metavar="FILE", help="also write the summary here ('-': to stdout)")
    cc.set_defaults(func=_cmd_compare_controllers)
    run = command("run", "run a scenario through the ROS 2 node graph (five processes, or one with --compose), record an MCAP bag; "
                  "a progress line on stderr every second (the run's time, the samples recorded and their rate)")
    run.add_argument("scenario", help=_SCENARIO_HELP.format("paper_tracking"))
    run.add_argument("--out", metavar="DIR", help="run directory: bag/, params.yaml, scenario.yaml, logs/ "
                     "(default runs/run/<scenario>-<controller>-<time>)")
    run.add_argument("--realtime", action="store_true", help="wall-clock timers instead of lockstep (the run takes duration_s)")
    run.add_argument("--rt-priority", type=int, metavar="N", default=None,
                     help="with --realtime: run the nodes under SCHED_FIFO at priority N (1 to 99; root or CAP_SYS_NICE), so that "
                          "other work on the host cannot delay their frames (default: the normal scheduler)")
    run.add_argument("--compose", action="store_true",
                     help="every node in one process on one executor (faster; the same topics, parameters, bag and metrics)")
    run.add_argument("--controller", choices=[c.value for c in ControllerKind], default=None,
                     help=_CONTROLLER_HELP.format("run"))
    run.add_argument("--plant", choices=["native", "basilisk", "external"], default="native",  # sappc.graph.launch.PLANTS (not imported to build the parser)
                     help="native: the bundled plant; basilisk: the plant node on Basilisk's dynamics (pip install '.[basilisk]'); "
                          "external: start everything but the plant and record a run driven by "
                          "a plant you start yourself on the printed domain (it ends once the last sample's torque is recorded); "
                          "default native")
    run.add_argument("--json", metavar="FILE", help="write metrics, counts and parameters as JSON ('-': to stdout)")
    _add_live_options(run, "watch the run in Foxglove: the recorder also serves every recorded topic on a Foxglove WebSocket server "
                           "at ws://HOST:PORT (default port 8765; 0: any free port), the bytes it records with their ros2msg schemas, "
                           "and the run's progress and verdict (status messages, and JSON on /sappc/run); prints the address; "
                           "the bag and lockstep are unchanged")
    run.add_argument("--wait-subscribers", type=int, default=None, metavar="N",
                     help="with --live, lockstep: start the run only once every recorded topic has N Foxglove subscriptions "
                          "(default 0: at once)")
    run.add_argument("--domain-id", type=int, default=None, help="ROS domain id (default: ROS_DOMAIN_ID from the environment, else the first free one of "
                     "SAPPC_DOMAIN_IDS, default 1-101); claimed with a lock file")
    run.set_defaults(func=_cmd_run)
    par = command("params", "print the ROS parameters file of python -m sappc_controller (or, --estimator, of python -m sappc_estimator) for a scenario")
    par.add_argument("scenario", help=_SCENARIO_HELP.format("paper_tracking"))
    par.add_argument("--controller", choices=[c.value for c in ControllerKind], default=None,
                     help=_CONTROLLER_HELP.format("print the parameters of"))
    par.add_argument("--estimator", action="store_true",
                     help="the file of python -m sappc_estimator instead: the scenario's estimator section, else the MEKF of its sensors")
    par.set_defaults(func=_cmd_params)
    scn = command("scenarios", "list the bundled scenarios, or copy one out to edit (scenarios copy NAME [DEST])")
    scn.usage = "sappc scenarios [-h] [copy NAME [DEST] [--force]]"
    scn.set_defaults(func=_cmd_scenarios, action=None)
    # prog: argparse would build the nested commands' usage from `scn.usage` above (the whole synopsis)
    scn_sub = scn.add_subparsers(dest="action", metavar="ACTION", prog="sappc scenarios")
    cp = scn_sub.add_parser("copy", help="copy a bundled scenario, with the files it extends, into DEST",
                            description="Copy a bundled scenario, with the files it extends, into DEST.",
                            epilog=exit_status_text("scenarios"), formatter_class=argparse.RawDescriptionHelpFormatter)
    cp.add_argument("name", metavar="NAME", help="a bundled scenario, e.g. paper_tracking")
    cp.add_argument("dest", metavar="DEST", nargs="?", default=".", help="the directory to copy into (created if missing; default: here)")
    cp.add_argument("--force", action="store_true", help="overwrite files of the same name")
    rep = command("report", "metrics, figures and an HTML page from a recorded bag")
    rep.add_argument("bag", help=_BAG_HELP)
    rep.add_argument("--out", metavar="DIR", help="figures and report.html, into a new or empty directory (default runs/report/<run>, "
                     "rewritten by each report of that run)")
    rep.add_argument("--json", metavar="FILE", help="write the metrics and what the bag holds as JSON ('-': to stdout)")
    rep.add_argument("--scenario", metavar="FILE", help="metric settings and events from this scenario (default: the one in the bag)")
    rep.set_defaults(func=_cmd_report)
    cmp = command("compare", "overlaid figures and one metrics table for several bags")
    cmp.add_argument("bags", nargs="+", metavar="BAG", help="the bags to compare, each " + _BAG_HELP)
    cmp.add_argument("--out", metavar="DIR", help="figures and compare.html (default runs/compare/<run>_vs_<run>...)")
    cmp.add_argument("--json", metavar="FILE", help="write every bag's metrics as JSON ('-': to stdout)")
    cmp.set_defaults(func=_cmd_compare)
    rr = command("rerun", "feed a bag's recorded inputs to the controller core and compare the torques")
    rr.add_argument("bag", help="the bag of a run, " + _BAG_HELP)
    rr.add_argument("--params", metavar="FILE", help="ROS parameters file of the controller (default: the bag's own); with either, "
                    "the exit status is 1 unless every torque matches")
    rr.add_argument("--json", metavar="FILE", help="write the comparison as JSON ('-': to stdout)")
    rr.add_argument("--out", metavar="DIR", help="write rerun_torque.png (recorded and recomputed) and rerun.html into a new or "
                    "empty directory (default: none)")
    rr.set_defaults(func=_cmd_rerun)
    rpr = command("repair", "make a bag whose recorder was killed readable by every MCAP/rosbag2 reader (as ros2 bag reindex)")
    rpr.add_argument("bag", help="the bag to rewrite in place, " + _BAG_HELP)
    rpr.add_argument("--json", metavar="FILE", help="write what was recovered as JSON ('-': to stdout)")
    rpr.set_defaults(func=_cmd_repair)
    rp = command("replay", "republish a bag on the ROS 2 graph with its timing and /clock, or (--live) serve it to Foxglove "
                           "over a Foxglove WebSocket, without ROS")
    rp.add_argument("bag", help="the bag to republish, " + _BAG_HELP)
    rp.add_argument("--rate", type=float, default=1.0, help="speed factor (default 1: the recorded timing)")
    rp.add_argument("--topics", nargs="+", metavar="TOPIC", help="only these topics (default: all; /clock is always published, "
                    "except with --live)")
    rp.add_argument("--loop", action="store_true", help="start again at the end, until Ctrl-C")
    rp.add_argument("--wait-subscribers", type=int, default=0, metavar="N",
                    help="before starting, wait until every replayed topic has N subscribers (default 0)")
    rp.add_argument("--start-delay", type=float, default=None, metavar="S",
                    help="seconds between creating the publishers and the first message, for discovery (default 1; "
                         "with --live: between starting the server and the first message, default 0)")
    rp.add_argument("--domain-id", type=int, default=None, help="ROS domain id (default: ROS_DOMAIN_ID from the environment)")
    _add_live_options(rp, "no ROS graph: serve the bag to Foxglove on a Foxglove WebSocket server at ws://HOST:PORT (default "
                          "port 8765; 0: any free port), its messages as recorded (CDR, ros2msg schemas), at the bag's pace "
                          "times --rate; prints the address")
    rp.add_argument("--linger", type=float, default=None, metavar="S",
                    help="with --live: after the last message, keep serving until no client subscribes, at most S seconds "
                         "(default 2), so that clients receive what is queued")
    rp.set_defaults(func=_cmd_replay)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """The ``sappc`` command's work; Ctrl-C propagates as :class:`KeyboardInterrupt`, which the
    command's entry (:mod:`sappc.__main__`) turns into one line and exit status 130."""
    global _json_stdout
    parser = _parser()
    args_list = list(sys.argv[1:] if argv is None else argv)
    if not args_list:  # `sappc` alone: what to type, not an error message
        print(parser.format_usage().rstrip() + "\n" + NO_COMMAND_HINT, file=sys.stderr)
        return EXIT_INVALID_INPUT
    args = parser.parse_args(args_list)
    to_stdout = getattr(args, "json", None) == "-"
    try:
        with _stdout_to_stderr() if to_stdout else contextlib.nullcontext(None) as json_out:
            _json_stdout = json_out
            if not getattr(args, "settles_start_up", False):  # (sappc montecarlo settles just before it forks its workers)
                collector.settle()  # the start-up's garbage collector thresholds (sappc.__main__) end here
            return int(args.func(args))
    except (ConfigError, InputError) as exc:
        print(f"sappc: error: {exc}", file=sys.stderr)
        return EXIT_INVALID_INPUT
    except BrokenPipeError:  # output piped into `head` and the like: stop quietly (Python docs' recipe)
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1
    finally:
        _json_stdout = None


if __name__ == "__main__":
    sys.exit(main())

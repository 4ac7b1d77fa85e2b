"""Reports from recorded bags: ``sappc report`` (one bag) and ``sappc compare`` (several).

A bag is analysed as far as its data goes (:func:`analyse_bag`): the metrics of
:mod:`sappc.evaluation.metrics` when it has the state and the reference, the paper-style figures of
:mod:`sappc.analysis.plots`, and a list of what is missing or suspicious (cut short, undecodable
messages, unexpected frame ids, rejected inputs, stale samples).  The scenario and the
controller parameters embedded by ``sappc run`` (metadata records ``sappc/scenario.yaml`` and
``sappc/params.yaml``) give the metric settings, the controller's name and the injected events to
mark; a bag from another plant has none, and the default settings apply (or ``--scenario``).

The HTML page (:func:`html_page`) is one self-contained file: the figures are embedded.
"""

from __future__ import annotations

import base64
import html
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sappc_msgs_py.contract import (CLOCK, ESTIMATOR_TOPICS, FAULT_TOPICS, MODE_STATUS, MOMENTUM_TOPICS, OPTIONAL_TOPICS, TOPICS, TRANSFORM_TOPICS,
                                    WHEEL_STATES, Topic)
from sappc_controller.params import parameters_from_yaml
from gnc_common.validation import ConfigError, safe_load_yaml

from sappc.bag.blocks import BLOCK_BYTES, BagBlocks, figure_sink
from sappc.bag.read import PARAMS_RECORD, SCENARIO_RECORD, Bag, BagError, BagRun, find_topic
from sappc.scenario import MetricSettings, Scenario, load_scenario, scenario_from_mapping

__all__ = ["METRIC_SENTENCES", "NOT_APPLICABLE", "BagAnalysis", "analyse_bag", "compare_bags", "html_page", "metric_meanings", "parameters_block",
           "write_report", "write_rerun_report"]

#: Every topic the contract names, the fault relays' included, by name.
_CONTRACT: dict[str, Topic] = {t.name.lstrip("/"): t for t in TOPICS + FAULT_TOPICS}


@dataclass
class BagAnalysis:
    """What a bag says, as far as its data goes."""

    path: Path
    bag: Bag
    label: str  # a short name for tables and legends
    scenario: Scenario | None
    controller: str | None
    run: BagRun | None
    metrics: dict[str, Any] | None
    fault_windows: list[tuple[float, float]]
    problems: list[str] = field(default_factory=list)  # what could not be computed, and why
    notes: list[str] = field(default_factory=list)  # what is worth knowing about the data
    per_orbit: list[dict[str, Any]] = field(default_factory=list)  # a run in orbit: each orbit's metrics
    read_whole: str | None = None  # why the bag was read whole, not in blocks (sappc.bag.blocks); None: in blocks

    def summary(self) -> dict[str, Any]:
        """JSON-ready: metrics, where the data ends, counts, problems and notes."""
        r = self.run
        return {
            "bag": str(self.path),
            "label": self.label,
            "scenario": self.scenario.name if self.scenario else None,
            "controller": self.controller,
            "metrics": self.metrics,
            **({"per_orbit": self.per_orbit} if self.per_orbit else {}),
            "samples": r.samples if r is not None else 0,
            "end_s": r.end_s if r is not None else None,
            "truncated": self.bag.truncated,
            "messages": self.bag.counts,
            "undecodable": self.bag.undecodable,
            "problems": self.problems,
            "notes": self.notes,
        }


def _embedded_scenario(bag: Bag) -> Scenario | None:
    record = bag.metadata.get(SCENARIO_RECORD)
    if not record or "text" not in record:
        return None
    source = f"{bag.path} ({SCENARIO_RECORD})"
    return scenario_from_mapping(safe_load_yaml(record["text"], source=source), source=source)


def _embedded_controller(bag: Bag) -> str | None:
    record = bag.metadata.get(PARAMS_RECORD)
    if not record or "text" not in record:
        return None
    try:
        return str(parameters_from_yaml(record["text"], "controller", source=PARAMS_RECORD).get("controller", "sappc"))
    except ConfigError:
        return None


def analyse_bag(path: str | Path, *, scenario: str | Path | None = None, block_bytes: int = BLOCK_BYTES) -> BagAnalysis:
    """Read the bag at ``path`` and compute what its data allows (see the module docstring).

    ``scenario``: a scenario file whose metric settings and events apply (default: the one
    embedded in the bag, else :class:`~sappc.scenario.MetricSettings` defaults and no events).
    The bag is read in blocks of ``block_bytes`` (:class:`~sappc.bag.blocks.BagBlocks`: the
    memory is set by the block, not by the bag); the figures' History is
    :func:`~sappc.bag.blocks.figure_sink`'s.

    Raises
    ------
    BagError
        If ``path`` is not a bag or holds no message of the contract's types.
    """
    blocks = BagBlocks(path, block_bytes=block_bytes)
    bag = blocks.bag  # its metadata records; its counts once the blocks are read
    notes: list[str] = []
    problems: list[str] = []
    sc: Scenario | None
    if scenario is not None:
        sc = load_scenario(scenario)
    else:
        try:
            sc = _embedded_scenario(bag)
        except ConfigError as exc:
            sc = None
            notes.append(f"the scenario embedded in the bag is not valid here ({exc}); default metric settings used")
    controller = _embedded_controller(bag)
    label = controller or Path(path).name
    settings = sc.metrics if sc else MetricSettings()
    windows = sc.event_windows() if sc else []
    wheels = sc.wheels if sc else None
    measured = blocks.measure(steady_from_s=settings.steady_from_s, settle_threshold=settings.settle_threshold, t2_s=settings.t2_s,
                              fault_windows=windows, orbit_bins=sc.orbit_bins() if sc else None, origin=settings.origin,
                              figures=lambda t_end_s: figure_sink(t_end_s, wheels=wheels))
    bag = measured.bag

    for undecodable, n in bag.undecodable.items():
        notes.append(f"{undecodable}: {n} message(s) do not fit their type's layout and were skipped")
    for name, spec in _CONTRACT.items():
        topic = find_topic(bag, name)
        frames = bag.frame_ids.get(topic, ()) if topic else ()
        if spec.frame_id is not None and frames and set(frames) != {spec.frame_id}:
            notes.append(f"{topic}: frame id(s) {list(frames)}, the contract says {spec.frame_id!r}")
    # /clock and the frames (state/tf, reference/tf: for viewers, not decoded here) are no input of the analysis
    # joint_states only from a plant with reaction wheels, truth/* only from one with sensor models
    # (the orbit's topics, MOMENTUM_TOPICS, each only from a run that has its model: optional here;
    # mode/status only from a run with flight modes)
    optional = tuple(t for t in OPTIONAL_TOPICS if sc is None or t in MOMENTUM_TOPICS or (t is WHEEL_STATES and sc.wheels is None)
                     or (t is MODE_STATUS and sc.modes is None)
                     or (t is not WHEEL_STATES and t is not MODE_STATUS and sc.sensors is None)
                     or (t in ESTIMATOR_TOPICS and sc.estimator is None))
    missing = [t.name for t in TOPICS if t.name != CLOCK.name and t not in TRANSFORM_TOPICS + optional and find_topic(bag, t.name) is None]
    if missing:
        notes.append(f"topics absent from the bag: {', '.join(missing)}")

    run, metrics, per_orbit = measured.run, measured.metrics, measured.per_orbit
    if measured.read_whole is not None:
        notes.append(f"the bag was read whole, not in blocks ({measured.read_whole}): its memory grows with its length")
    if measured.problem is not None:
        problems.append(f"no metrics and no figures of the run: {measured.problem}")
    if run is not None:
        if not run.has_diagnostics:
            problems.append("no controller/diagnostics: rho, the constraint band, saturation and the Lyapunov values are "
                            "unknown, so the metrics that need them are null")
        end = run.end_s
        if bag.truncated:
            of = f" of the scenario's {sc.duration_s:g} s" if sc else ""
            notes.insert(0, f"the bag is cut short ({bag.truncated}); its data ends at t = {end:.3f} s{of}: "
                            "the metrics describe the run up to there")
        elif sc is not None and end + 0.5 * sc.control_period_s < sc.duration_s:
            notes.insert(0, f"the run ends at t = {end:.3f} s, before the scenario's {sc.duration_s:g} s")
        if run.rejected:
            notes.append(f"the controller rejected {run.rejected} input message(s) (diagnostics status[0])")
        summary = run.controller_summary()
        zero = {k: summary[k] for k in ("watchdog_zero", "refused", "held") if summary[k]}
        if zero:
            notes.append("samples the controller did not command: " + ", ".join(f"{k} {v}" for k, v in zero.items())
                         + " (diagnostics status[2]; held: the last torque again)")
    elif bag.truncated:
        notes.insert(0, f"the bag is cut short ({bag.truncated})")
    return BagAnalysis(path=Path(path), bag=bag, label=label, scenario=sc, controller=controller, run=run,
                       metrics=metrics, fault_windows=windows, problems=problems, notes=notes, per_orbit=per_orbit,
                       read_whole=measured.read_whole)


# ---- HTML -------------------------------------------------------------------------------------

_CSS = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 980px; color: #222; }
h1 { font-size: 1.5em; } h2 { font-size: 1.2em; margin-top: 1.6em; }
table { border-collapse: collapse; margin: 0.6em 0; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.7em; text-align: left; font-variant-numeric: tabular-nums; }
th { background: #f3f3f3; }
.problem { color: #a00; } .note { color: #865; }
img { max-width: 100%; border: 1px solid #eee; margin: 0.5em 0; }
"""


def _fmt(value: Any) -> str:
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return "nan" if math.isnan(value) else f"{value:.6g}"
    return str(value)


#: One sentence per run metric, as the report page shows it beside the value (the full definitions,
#: with their formulas, are in :mod:`sappc.evaluation.metrics`' docstring; a test keeps the two
#: lists of names equal).  A value shown as ``-`` does not apply to the run (:data:`NOT_APPLICABLE`).
METRIC_SENTENCES: dict[str, str] = {
    "settling_time_s": "When the largest attitude-error component |q_ev,i| fell below the scenario's settle_threshold for good [s].",
    "steady_max_abs_qev": "The largest attitude-error component |q_ev,i| in the steady window (t >= steady_from_s).",
    "steady_mean_abs_qev": "The time-mean of |q_ev,i| over the steady window, on the worst axis (the paper's Monte Carlo criterion).",
    "rpf_error_at_t2": "How far the attitude error is from the controller's performance function at t2, max_i |q_ev,i - rho_i| "
                       "(the paper's other Monte Carlo criterion).",
    "overshoot": "The largest excursion of any error component to the side opposite its initial error (0: none).",
    "max_abs_torque_Nm": "The largest torque the actuator produced on any axis [N m].",
    "torque_sign_changes_per_s": "How often a torque component changed sign or switched on or off in the steady window, "
                                 "on the worst axis [1/s].",
    "torque_reversals_per_s": "How often a torque component reversed from one sign to the other in the steady window, "
                              "on the worst axis (on/off pulses not counted) [1/s].",
    "saturation_fraction": "The fraction of control samples with at least one axis at the actuator's torque limit.",
    "time_outside_constraint_s": "How long any error component was outside its constraint band [s].",
    "returned_to_constraint": "Whether every error component was back inside its constraint band at the end of the run "
                              "(a run with faults).",
    "left_constraint_after_fault": "Whether the error left its constraint band at or after the start of the first fault "
                                   "(a run with faults).",
    "returned_at_s": "When the error re-entered its constraint band for good after a fault made it leave [s].",
    "finite": "Whether the state and the torque stayed finite (no: the run failed, and the other metrics describe it up to then).",
    "control_lost_at_s": "When the run lost control: from then to its end the largest |q_ev,i| stayed beyond ten times the "
                         "settling band, in the steady window (-: it kept control).",
    "steady_max_abs_attitude_estimation_error_rad": "The largest error of the estimated attitude on any axis in the steady window [rad].",
    "steady_rms_attitude_estimation_error_rad": "The root mean square of the estimated attitude's error in the steady window, "
                                                "on the worst axis [rad].",
    "final_abs_bias_estimation_error_rad_s": "The largest error of the estimated gyro bias on any axis at the last estimate [rad/s].",
    "mean_nees": "The time-mean of the filter's normalised estimation error squared: 6 for a consistent filter.",
    "estimator_updates": "How many steps the filter corrected with a star-tracker measurement.",
    "estimator_gate_rejections": "How many star-tracker measurements the filter's gate rejected as outliers.",
    "estimator_reinitialisations": "How many times the filter started again from a measurement.",
    "filter_inconsistent_fraction": "The share of the filter's samples at which its health monitor said ERROR (its innovations "
                                    "inconsistent with its covariance).",
    "estimator_recoveries": "How many times the filter let its gyro bias move after its health monitor failed.",
    "estimate_withheld_samples": "How many samples the filter withheld its estimate from the controller (a prior or a "
                                 "re-initialisation not yet confirmed by the tracker).",
    "max_abs_wheel_speed_rad_s": "The largest speed of any reaction wheel relative to the body [rad/s].",
    "max_abs_wheel_torque_Nm": "The largest motor torque of any reaction wheel [N m].",
    "wheel_energy_J": "The wheels' motors' mechanical work in magnitude over the run, braking counted as spent [J].",
    "mode_sequence": "The flight modes in the order the run flew them (a scenario with flight modes).",
    "time_to_track_s": "When the run first entered TRACK, the mode in which the scenario's controller flies [s].",
    "time_in_mode_s": "How long the run flew in each flight mode [s].",
    "mode_transitions": "How many transitions between flight modes the run took.",
    "wall_time_s": "The wall-clock time the run took [s]: a property of the machine, not of the controller.",
    "startup_s": "The wall-clock time before the first sample: processes, imports and discovery [s].",
    "first_sample_after_nodes_up_s": "The wall-clock time from the plant's process having built its nodes (composed: every node) to the "
                                     "first sample: discovery and matching [s].",
}
#: What a ``-`` in a table of metrics means.
NOT_APPLICABLE = ("A - marks a metric that does not apply to this run: the returned_* metrics without a fault, "
                  "the settling time of a run that never settles, the error at t2 of a run that ends before t2.")


def metric_meanings() -> dict[str, str]:
    """What each run metric means: :data:`METRIC_SENTENCES`."""
    return dict(METRIC_SENTENCES)


def html_table(header: list[str], rows: list[list[Any]]) -> str:
    """An HTML table; values formatted as the command line prints them."""
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(_fmt(v))}</td>" for v in row) + "</tr>" for row in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def html_page(title: str, blocks: list[str]) -> str:
    """A self-contained HTML page: ``blocks`` are HTML fragments (see :func:`html_figure`)."""
    return (f"<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{html.escape(title)}</title>"
            f"<style>{_CSS}</style></head><body><h1>{html.escape(title)}</h1>\n" + "\n".join(blocks) + "\n</body></html>\n")


def html_figure(path: Path) -> str:
    """The PNG at ``path`` embedded in the page."""
    data = base64.b64encode(path.read_bytes()).decode("ascii")
    return f'<img alt="{html.escape(path.stem)}" src="data:image/png;base64,{data}">'


def html_list(items: list[str], css: str) -> str:
    return "<ul>" + "".join(f'<li class="{css}">{html.escape(i)}</li>' for i in items) + "</ul>" if items else ""


#: Parameters of a node that say where its files go and whom it waits for, not how it behaves.
_PLUMBING = ("counts_file", "timing_file", "expected_subscribers", "expected_publishers")


def _flat(mapping: dict[str, Any], prefix: str = "") -> list[list[Any]]:
    """``[[dotted key, value], ...]`` of a nested mapping; lists shown as written."""
    rows: list[list[Any]] = []
    for key, value in mapping.items():
        if isinstance(value, dict):
            rows += _flat(value, f"{prefix}{key}.")
        elif f"{prefix}{key}" not in _PLUMBING:
            rows.append([f"{prefix}{key}", value if not isinstance(value, list) else ", ".join(map(_fmt, value))])
    return rows


def parameters_block(bag: Bag) -> str:
    """The run's parameters as the bag records them (``sappc run``'s :data:`~sappc.bag.read.PARAMS_RECORD`
    and :data:`~sappc.bag.read.SCENARIO_RECORD` metadata records): the controller's in a table,
    then both files as recorded, folded; a sentence when the bag has neither."""
    texts = {name: str(bag.metadata.get(name, {}).get("text", "")) for name in (PARAMS_RECORD, SCENARIO_RECORD)}
    if not any(texts.values()):
        return (f"<h2>Parameters</h2><p>The bag records no parameters (no {PARAMS_RECORD} or {SCENARIO_RECORD} metadata "
                "record: it was not recorded by sappc run).</p>")
    parts = ["<h2>Parameters</h2>"]
    try:
        nodes = safe_load_yaml(texts[PARAMS_RECORD], source=PARAMS_RECORD) or {}
    except ConfigError:  # not YAML, or past a limit: the record is still shown as text below
        nodes = {}
    node = nodes.get("/controller") if isinstance(nodes, dict) else None
    controller = node.get("ros__parameters") if isinstance(node, dict) else None
    if isinstance(controller, dict):
        parts.append("<p>The controller node's parameters:</p>" + html_table(["parameter", "value"], _flat(controller)))
    for name, text in texts.items():
        if text:
            parts.append(f"<details><summary>{html.escape(name)} as recorded</summary><pre>{html.escape(text)}</pre></details>")
    return "".join(parts)


def _run_title(a: BagAnalysis) -> str:
    return f"{a.scenario.name if a.scenario else a.path.name} ({a.label})"


def write_report(a: BagAnalysis, out_dir: Path, *, worker: Any = None) -> list[Path]:
    """The figures of the run and ``report.html`` in ``out_dir``; return their paths.  ``worker``: a
    :class:`sappc.analysis.plots.FigureWorker` that draws some of the figures."""
    from sappc.analysis.plots import plot_run

    out_dir.mkdir(parents=True, exist_ok=True)
    figures = plot_run(a.run.history, out_dir, title=_run_title(a), fault_windows=a.fault_windows,
                       wheels=a.scenario.wheels if a.scenario else None, worker=worker) if a.run is not None else []
    s = a.summary()
    info = [
        ["bag", s["bag"]],
        ["scenario", s["scenario"]],
        ["controller", s["controller"]],
        ["aligned samples", s["samples"]],
        ["data ends at [s]", s["end_s"]],
        ["whole file", a.bag.truncated is None],
    ] + [[f"messages on {t}", n] for t, n in s["messages"].items()]
    blocks = [
        "<h2>Bag</h2>" + html_table(["item", "value"], info),
        html_list(a.problems, "problem") + html_list(a.notes, "note"),
    ]
    if a.metrics is not None:
        blocks.append("<h2>Metrics</h2>" + html_table(["metric", "value", "meaning"], [[k, v, METRIC_SENTENCES.get(k, "")] for k, v in a.metrics.items()])
                      + f"<p>{html.escape(NOT_APPLICABLE)}</p>")
    if a.per_orbit:
        keys = list(a.per_orbit[0])
        blocks.append("<h2>Per orbit</h2>" + html_table(keys, [[e[k] for k in keys] for e in a.per_orbit])
                      + "<p>Each orbit's samples (orbit j: j T &lt;= t &lt; (j + 1) T); the definitions: sappc.evaluation.metrics, "
                        "\"Per orbit\".</p>")
    blocks.append(parameters_block(a.bag))
    if a.fault_windows:
        blocks.append("<p>Injected disturbance events and faults are shaded red: "
                      + ", ".join(f"{s0:g} to {s1:g} s" for s0, s1 in a.fault_windows) + ".</p>")
    blocks += ["<h2>Figures</h2>"] + [html_figure(p) for p in figures]
    page = out_dir / "report.html"
    page.write_text(html_page(f"Report: {_run_title(a)}", blocks))
    return figures + [page]


def compare_bags(analyses: list[BagAnalysis], out_dir: Path) -> tuple[list[str], list[list[Any]], list[Path]]:
    """Overlaid figures, one metrics table (a row per metric, a column per bag) and
    ``compare.html`` in ``out_dir``; return (header, rows, written paths).

    Raises
    ------
    BagError
        If a bag has no run to compare (no state or reference).
    """
    from sappc.analysis.plots import plot_compare

    unusable = [f"{a.path}: {a.problems[0]}" for a in analyses if a.run is None]
    if unusable:
        raise BagError("cannot compare: " + "; ".join(unusable))
    runs = [a.run for a in analyses if a.run is not None]  # every one of them: none is unusable
    labels = [a.label for a in analyses]
    for i, a in enumerate(analyses):  # the same controller twice: tell the runs apart by their bag
        if labels.count(a.label) > 1:
            labels[i] = f"{a.label} ({a.path.parent.name if a.path.name == 'bag' else a.path.name})"
    keys = list(dict.fromkeys(k for a in analyses for k in (a.metrics or {})))
    header = ["metric"] + labels
    rows = [[k] + [(a.metrics or {}).get(k) for a in analyses] for k in keys]
    names = {a.scenario.name for a in analyses if a.scenario}
    title = names.pop() if len(names) == 1 else "comparison"
    windows = sorted({w for a in analyses for w in a.fault_windows})
    out_dir.mkdir(parents=True, exist_ok=True)
    figures = plot_compare([(lab, run.history) for lab, run in zip(labels, runs)], out_dir, title=title,
                           fault_windows=windows)
    notes = [f"{lab}: {n}" for lab, a in zip(labels, analyses) for n in a.problems + a.notes]
    blocks = [
        "<h2>Runs</h2>" + html_table(["run", "bag", "scenario", "samples"],
                                     [[lab, str(a.path), a.scenario.name if a.scenario else None, run.samples]
                                      for lab, a, run in zip(labels, analyses, runs)]),
        html_list(notes, "note"),
        "<h2>Metrics</h2>" + html_table(header, rows) + f"<p>{html.escape(NOT_APPLICABLE)}</p>",
        "<h2>Figures</h2>",
    ] + [html_figure(p) for p in figures]
    page = out_dir / "compare.html"
    page.write_text(html_page(f"Comparison: {title}", blocks))
    return header, rows, figures + [page]


def write_rerun_report(result: Any, bag_name: str, out_dir: Path) -> list[Path]:
    """``rerun_torque.png`` (recorded, recomputed and their difference) and ``rerun.html`` for a
    :class:`~sappc.analysis.rerun.RerunResult`; return their paths."""
    from sappc.analysis.plots import plot_torque_rerun

    stamps = result.stamps_ns
    t = (stamps - stamps[0]) / 1e9 if stamps.size else stamps.astype(float)
    figures = plot_torque_rerun(t, result.recorded, result.recomputed, out_dir, title=f"{bag_name} ({result.controller})")
    page = out_dir / "rerun.html"
    page.write_text(html_page(f"Re-run: {bag_name}", [html_table(["item", "value"], [[k, v] for k, v in result.summary().items()])]
                              + [html_figure(p) for p in figures]))
    return figures + [page]

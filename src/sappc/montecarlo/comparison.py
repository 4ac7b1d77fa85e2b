"""``sappc compare-controllers``: every controller on one scenario over the same sensor-noise seeds.

The comparison a GNC engineer asks for (issue 34, item 4): each controller of the scenario flies the
scenario's own case ``seeds`` times, run ``k`` with its own draws of the star tracker's and the
gyro's noise (``SeedSequence(seed, spawn_key=(k,))``, as a campaign draws them; the scenario's
``sensors.seed`` is not used), nothing else dispersed, so every controller meets the same noise.
The runs go through the compiled loop of a campaign (:func:`sappc.montecarlo.campaign.simulate_runs`,
in parallel over runs in this process).

Per controller, over the runs (:data:`COLUMNS`): the steady max ``|q_ev|`` (median and 95th
percentile), the settling time and the overshoot (median and largest), the torque's sign changes
per second (median and 95th percentile), the peak wheel speed and the wheels' energy (median; with
reaction wheels).  Written to ``--out``: ``comparison.md`` (the table, Markdown), ``comparison.csv``
(the same figures), ``runs.csv`` (every run's metrics), ``comparison.png`` (each metric's
distribution per controller) and ``summary.json``.
"""

from __future__ import annotations

import copy
import csv
import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from gnc_common.validation import ConfigError
from sappc.analysis.plots import house_style
from sappc.evaluation.requirements import failed_requirements, loss_of_control
from sappc.montecarlo.campaign import simulate_runs
from sappc_msgs_py.contract import ANSWER_NAMES
from sappc.scenario import ControllerKind, load_scenario

__all__ = ["COLUMNS", "Column", "compare_controllers", "exit_failures", "noise_seed_mapping"]

#: Runs per call of the compiled loop (memory: each run's whole history feeds the metrics, about
#: 1.5 MB per 60 s run at 100 Hz with wheels and an estimator); the figures do not depend on it.
CHUNK_RUNS = 100


@dataclass(frozen=True)
class Column:
    """A column of the table: ``metric`` (a per-run metric of :mod:`sappc.evaluation.metrics`) summarised
    by ``statistic`` (``"median"``, ``"p95"`` or ``"max"``), shown as ``label`` in ``unit`` with ``fmt``."""

    metric: str
    statistic: str
    label: str
    unit: str
    fmt: str
    wheels_only: bool = False

    @property
    def key(self) -> str:
        """The column's name in ``comparison.csv`` and ``summary.json``: ``<metric>_<statistic>``."""
        return f"{self.metric}_{self.statistic}"


#: The table's columns, in order.
COLUMNS = (
    Column("steady_max_abs_qev", "median", "steady max abs q_ev, median", "", ".3e"),
    Column("steady_max_abs_qev", "p95", "steady max abs q_ev, p95", "", ".3e"),
    Column("settling_time_s", "median", "settling, median", "s", ".2f"),
    Column("settling_time_s", "max", "settling, max", "s", ".2f"),
    Column("overshoot", "max", "overshoot, max", "", ".2e"),
    Column("torque_sign_changes_per_s", "median", "torque sign changes, median", "1/s", ".1f"),
    Column("torque_sign_changes_per_s", "p95", "torque sign changes, p95", "1/s", ".1f"),
    Column("max_abs_wheel_speed_rad_s", "median", "peak wheel speed, median", "rad/s", ".1f", wheels_only=True),
    Column("wheel_energy_J", "median", "wheel energy, median", "J", ".3f", wheels_only=True),
)
#: The per-run metrics the table summarises (and ``runs.csv`` lists).
RUN_METRICS = tuple(dict.fromkeys(c.metric for c in COLUMNS))


def _statistic(values: NDArray[np.float64], statistic: str) -> float | None:
    """The statistic of a metric over the runs; NaN (a run that never settled, or diverged) counts
    as the worst value (+inf), so a median or p95 over such runs says so; ``None`` with no run."""
    v = np.where(np.isnan(values), np.inf, values)
    if v.size == 0:
        return None
    with np.errstate(invalid="ignore"):  # interpolating between two infinite values: inf - inf
        if statistic == "median":
            out = float(np.median(v))
        elif statistic == "p95":
            out = float(np.percentile(v, 95.0))
        else:
            out = float(np.max(v))
    return np.inf if np.isnan(out) else out


def noise_seed_mapping(raw: dict[str, Any], controller: str) -> dict[str, Any]:
    """The scenario mapping ``raw`` as a campaign of its own case in which only the sensors' noise
    changes from run to run, flown by ``controller``: ``montecarlo`` replaced (no initial attitude
    drawn, nothing dispersed; the scenario's pass criteria kept), no ``tuning`` section.

    Raises
    ------
    ConfigError
        If the scenario has no ``sensors`` section: without noise every seed is the same run.
    """
    if not raw.get("sensors"):
        raise ConfigError(f"scenario {raw.get('name')!r} has no sensors section: without sensor noise every seed flies the same run")
    out = copy.deepcopy(raw)
    out["controller"] = controller
    out.pop("tuning", None)
    criteria = (raw.get("montecarlo") or {}).get("criteria")
    out["montecarlo"] = {"initial_attitude": None, "chunk_runs": CHUNK_RUNS, "trajectory_runs": 0,
                         **({"criteria": criteria} if criteria is not None else {})}
    return out


def compare_controllers(scenario_path: str | Path, *, seeds: int = 100, seed: int = 0, controllers: list[str] | None = None,
                        out_dir: str | Path) -> dict[str, Any]:
    """Fly every controller of ``controllers`` (default: each the scenario has parameters for, in
    :class:`~sappc.scenario.ControllerKind` order) over noise seeds ``0 .. seeds - 1`` of ``seed``;
    write the table, the figure and the per-run metrics into ``out_dir``; return the summary.

    Raises
    ------
    ConfigError
        Naming the problem: ``seeds`` below 1, an unknown controller or one without parameters in
        the scenario, a scenario without sensors.
    """
    if isinstance(seeds, bool) or not isinstance(seeds, int) or seeds < 1:
        raise ConfigError(f"--seeds must be a positive integer, got {seeds!r}")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ConfigError(f"--seed must be a non-negative integer, got {seed!r}")
    scenario = load_scenario(scenario_path)
    kinds: list[str] = [str(k.value) for k in ControllerKind if k.value in scenario.controllers] if controllers is None else \
        [str(ControllerKind(c).value) for c in controllers]
    for kind in kinds:
        scenario.controller_config(kind)  # its errors now, naming controllers.<kind>, before any run
    wheels = scenario.wheels is not None
    columns = [c for c in COLUMNS if wheels or not c.wheels_only]
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    started = time.perf_counter()
    per_run: dict[str, dict[str, NDArray[np.float64]]] = {}
    verdicts: dict[str, dict[str, Any]] = {}
    for kind in kinds:
        raw = noise_seed_mapping(scenario.raw, kind)
        parts: list[dict[str, NDArray[np.float64]]] = []
        verdict: dict[str, Any] = {"runs_lost_control": 0, "runs_failing_requirements": 0, "failed_runs": []}
        for lo in range(0, seeds, CHUNK_RUNS):
            table, metrics, _ = simulate_runs(raw, seed, list(range(lo, min(lo + CHUNK_RUNS, seeds))), 0)
            crit = metrics.criteria_arrays()
            values = {"run": np.asarray(table["run"], dtype=np.float64),
                      "overshoot": np.maximum(np.asarray(metrics.overshoot, dtype=np.float64), 0.0)}
            values.update({m: np.asarray(crit[m], dtype=np.float64) for m in RUN_METRICS if m in crit})
            parts.append(values)
            _judge(verdict, scenario, table, metrics)
        per_run[kind] = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
        verdicts[kind] = verdict
    rows = {kind: {c.key: _statistic(per_run[kind][c.metric], c.statistic) for c in columns} for kind in kinds}
    summary: dict[str, Any] = {
        "scenario": scenario.name, "seeds": seeds, "seed": seed, "controllers": kinds,
        "noise_seeds": f"run k draws its sensors' noise from SeedSequence({seed}, spawn_key=(k,)), k = 0 .. {seeds - 1}",
        "columns": [{"key": c.key, "label": c.label, "unit": c.unit} for c in columns],
        "table": rows, "verdict": verdicts, "scenario_controller": scenario.controller.value,
        "requirements": dict(scenario.metrics.requirements), "wall_time_s": time.perf_counter() - started,
    }
    _write_table(out, scenario.name, seeds, seed, kinds, columns, rows)
    _write_runs(out / "runs.csv", kinds, per_run)
    _plot(out / "comparison.png", scenario.name, seeds, kinds, per_run, wheels)
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    return summary


#: How many failed runs per controller ``summary.json`` lists with their reasons.
LISTED_FAILURES = 10


def _judge(verdict: dict[str, Any], scenario: Any, table: dict[str, Any], metrics: Any) -> None:
    """Add a chunk's runs to a controller's ``verdict``: the runs that lost control and those that
    broke the scenario's requirements (:func:`sappc.evaluation.requirements.failed_requirements`,
    the check ``sappc simulate`` makes of one run), with the first :data:`LISTED_FAILURES` reasons."""
    for i, run in enumerate(np.asarray(table["run"])):
        answers = {name: int(table[f"answers_{name}"][i]) for name in ANSWER_NAMES}
        controller = {**answers, "samples": sum(answers.values())}
        m = metrics.run_metrics(i)
        lost = loss_of_control(m, controller, settle_threshold=scenario.metrics.settle_threshold)
        failed = failed_requirements(m, scenario.metrics.requirements, controller, settle_threshold=scenario.metrics.settle_threshold)
        verdict["runs_lost_control"] += bool(lost)
        verdict["runs_failing_requirements"] += bool(failed)
        if failed and len(verdict["failed_runs"]) < LISTED_FAILURES:
            verdict["failed_runs"].append({"run": int(run), "why": "; ".join(failed)})


def exit_failures(summary: dict[str, Any]) -> list[str]:
    """What makes ``sappc compare-controllers`` fail, one line each (empty: it passes): a run of any
    controller that lost control, and a run of the scenario's own controller (its ``controller``
    key) that broke the scenario's requirements; the other controllers are benchmarks, measured
    against the requirements but not held to them."""
    out = []
    for kind, v in summary["verdict"].items():
        if v["runs_lost_control"]:
            out.append(f"{kind}: {v['runs_lost_control']} of {summary['seeds']} runs lost control")
        if kind == summary["scenario_controller"] and v["runs_failing_requirements"]:
            first = v["failed_runs"][0]
            out.append(f"{kind}: {v['runs_failing_requirements']} of {summary['seeds']} runs broke the scenario's requirements "
                       f"(run {first['run']}: {first['why']})")
    return out


def _cell(value: float | None, fmt: str) -> str:
    if value is None:
        return "-"
    if not np.isfinite(value):
        return "never" if value > 0 else "-"
    return format(value, fmt)


def _write_table(out: Path, name: str, seeds: int, seed: int, kinds: list[str], columns: list[Column],
                 rows: dict[str, dict[str, float | None]]) -> None:
    """``comparison.md`` (a Markdown table, one row per controller) and ``comparison.csv``."""
    head = ["controller"] + [f"{c.label} [{c.unit}]" if c.unit else c.label for c in columns]
    lines = [f"{name}, {seeds} noise seeds (seed {seed}):", "",
             "| " + " | ".join(h.replace("abs q_ev", "\\|q_ev\\|") for h in head) + " |",
             "|" + "|".join([" --- "] + [" ---: "] * len(columns)) + "|"]
    for kind in kinds:
        lines.append("| " + " | ".join([kind] + [_cell(rows[kind][c.key], c.fmt) for c in columns]) + " |")
    (out / "comparison.md").write_text("\n".join(lines) + "\n")
    with (out / "comparison.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["controller"] + [c.key for c in columns])
        for kind in kinds:
            w.writerow([kind] + ["" if rows[kind][c.key] is None else repr(rows[kind][c.key]) for c in columns])


def _write_runs(path: Path, kinds: list[str], per_run: dict[str, dict[str, NDArray[np.float64]]]) -> None:
    """``runs.csv``: one row per controller and run, every metric of the table."""
    metrics = [m for m in RUN_METRICS if m in per_run[kinds[0]]]
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["controller", "run"] + metrics)
        for kind in kinds:
            cols = per_run[kind]
            for i in range(cols["run"].size):
                w.writerow([kind, int(cols["run"][i])] + [repr(float(cols[m][i])) for m in metrics])


#: The figure's panels: (metric, title, log scale).
_PANELS = (("steady_max_abs_qev", "steady max |q_ev|", True), ("torque_sign_changes_per_s", "torque sign changes [1/s]", False),
           ("settling_time_s", "settling time [s]", False), ("overshoot", "overshoot", False),
           ("max_abs_wheel_speed_rad_s", "peak wheel speed [rad/s]", False), ("wheel_energy_J", "wheel energy [J]", True))


@house_style
def _plot(path: Path, name: str, seeds: int, kinds: list[str], per_run: dict[str, dict[str, NDArray[np.float64]]], wheels: bool) -> None:
    """``comparison.png``: one panel per metric, each controller's runs as a box (median, quartiles,
    whiskers to the 5th and 95th percentiles) over its points."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [p for p in _PANELS if wheels or not p[0].startswith(("max_abs_wheel", "wheel_"))]
    cols = 3
    nrows = (len(panels) + cols - 1) // cols
    fig, axes = plt.subplots(nrows, cols, figsize=(12, 3.6 * nrows), squeeze=False)
    rng = np.random.default_rng(0)  # the points' horizontal jitter only
    for ax, (metric, title, log) in zip(axes.ravel(), panels):
        data = [per_run[k][metric][np.isfinite(per_run[k][metric])] for k in kinds]
        ax.boxplot(data, whis=(5, 95), showfliers=False)
        for i, d in enumerate(data):
            ax.plot(i + 1 + rng.uniform(-0.15, 0.15, d.size), d, ".", ms=2.5, alpha=0.5, color="tab:blue")
        ax.set_xticks(range(1, len(kinds) + 1), kinds)
        ax.set_title(title, fontsize=10)
        if log and all(d.size and np.all(d > 0) for d in data):
            ax.set_yscale("log")
        ax.grid(True, axis="y", alpha=0.3)
    for ax in axes.ravel()[len(panels):]:
        ax.set_visible(False)
    fig.suptitle(f"{name}: {len(kinds)} controllers, {seeds} noise seeds each")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)

"""The figures the documentation publishes from long commands, produced by those commands and
written into the pages (issue 46: README, CHANGELOG and docs/design/noise.md quoted 3.956e-5 and
7.2 sign changes a second where the code gave 3.985e-5 and 7.1).

Two commands, each recorded with the commit it ran at in ``benchmarks/results_published_figures.json``:

* ``flight_comparison``: ``sappc compare-controllers config/scenarios/paper_tracking_flight.yaml
  --seeds 100 --seed 1`` (:func:`sappc.montecarlo.comparison.compare_controllers`): the four
  controllers over 100 sensor-noise seeds, 400 runs, about 30 s on two idle cores;
* ``noise_filter_sweep``: ``benchmarks/bench_noise_filter.py --seeds 100 --seed 1``: SAPPC with
  each filter at each cut-off, 2700 runs, about 55 s.

Each record holds the statistics the pages quote, and the sweep's also every metric of the first
:data:`SLICE_RUNS` runs of each of its 27 points as the whole command computed them (runs are
independent: run k's noise is drawn from ``SeedSequence(1, spawn_key=(k,))`` whatever else the
command flies).  ``tests/test_docs.py`` checks that every page quotes the record, and that the
code gives the record: the whole comparison again (12 to 30 s), the sweep's first runs bit for
bit (about 10 s; the whole sweep would take one to two and a half minutes): a change of the code
that moves the figures fails there.

In a page, a generated region is either a block,

    <!-- figures: NAME -->
    ...                     (the whole region: a table, written by RENDERERS[NAME])
    <!-- /figures -->

or one value, ``<!-- figure: KEY FORMAT -->VALUE`` (``FORMAT`` a Python format spec, ``.2e``
written ``3.99e-5``; none for text such as the commit); the keys are those of :func:`figures`.

Usage::

    python benchmarks/published_figures.py --measure   # run both commands (about 1.5 min), rewrite the record
    python benchmarks/published_figures.py --write     # rewrite every page's regions from the record
    python benchmarks/published_figures.py --check     # exit 1 naming each page the record would change

``--measure`` runs on the checkout's code and refuses a tree whose ``src/`` or ``config/`` differs
from its commit (the record names that commit; ``--allow-dirty`` records ``<commit>+dirty``).
"""

from __future__ import annotations

import argparse
import datetime
import importlib.util
import json
import os
import platform
import re
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
RECORD = ROOT / "benchmarks" / "results_published_figures.json"
#: The pages that may hold generated regions.
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
#: The runs of each sweep point whose every metric the record keeps, for the check that recomputes
#: them (tests/test_docs.py).
SLICE_RUNS = (0, 1)
FLIGHT = "config/scenarios/paper_tracking_flight.yaml"
SEEDS, SEED = 100, 1
COMMANDS = {
    "flight_comparison": f"./sappcw compare-controllers {FLIGHT} --seeds {SEEDS} --seed {SEED}",
    "noise_filter_sweep": f".venv/bin/python benchmarks/bench_noise_filter.py --seeds {SEEDS} --seed {SEED} --out runs/bench/noise_filter",
}
#: The sweep's curves by a short id (bench_noise_filter.CURVES' names).
CURVE_IDS = {"torque filter, flight gains": "torque_flight", "rate filter, flight gains": "rate_flight",
             "torque filter, experiment 1 gains": "torque_exp1"}
#: The controllers' names in prose tables.
DISPLAY = {"sappc": "SAPPC", "trappc": "TraPPC", "blfppc": "BLFPPC", "mrp_feedback": "MRP feedback"}
#: Issue 34's bound on SAPPC's p95 steady max |q_ev| on the flight stack.
P95_BOUND = 4e-5

BLOCK = re.compile(r"(?ms)^<!-- figures: (?P<name>[\w-]+) -->\n(?P<body>.*?)^<!-- /figures -->$")
INLINE = re.compile(r"<!-- figure: (?P<key>[\w.@-]+)(?: (?P<fmt>\.\d+[ef]))? -->(?P<value>`[0-9a-f]+(?:\+dirty)?`|[-+]?\d[\d.]*(?:e[-+]?\d+)?)")


class FigureError(ValueError):
    """A page names a region or a key the record has no figure for."""


def bench_noise_filter() -> ModuleType:
    spec = importlib.util.spec_from_file_location("_bench_noise_filter", ROOT / "benchmarks" / "bench_noise_filter.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def cutoff_name(cutoff_hz: float) -> str:
    """A sweep point's name in keys and tables: ``off``, ``0.5``, ``1.0``, ``1.07``."""
    text = format(cutoff_hz, "g")
    return "off" if cutoff_hz == 0.0 else text if "." in text else text + ".0"


# ---- measuring ------------------------------------------------------------------------------------


def _commit(allow_dirty: bool) -> str:
    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True, check=True).stdout.strip()
    dirty = subprocess.run(["git", "status", "--porcelain", "--", "src", "config"], cwd=ROOT, capture_output=True, text=True,
                           check=True).stdout.strip()
    if dirty and not allow_dirty:
        raise SystemExit(f"published_figures: src/ or config/ differ from {head} (git status: {dirty.splitlines()[0]} ...): "
                         "commit first, measure in a clean worktree, or pass --allow-dirty")
    return head + ("+dirty" if dirty else "")


def comparison(seeds: int, out_dir: Path) -> dict[str, Any]:
    """``compare-controllers`` of the flight scenario over ``seeds`` seeds of :data:`SEED` into
    ``out_dir`` (the command's own function): its summary."""
    from sappc.montecarlo.comparison import compare_controllers

    summary: dict[str, Any] = compare_controllers(str(ROOT / FLIGHT), seeds=seeds, seed=SEED, out_dir=out_dir)
    return summary


def sweep_slice_runs(module: ModuleType, runs: list[int]) -> list[dict[str, Any]]:
    """Every sweep point's per-run metrics of ``runs``."""
    base = module.flight_base()
    out = []
    for name, key, gains in module.CURVES:
        for f in module.CUTOFFS_HZ:
            values = module.point_runs(base, key, f, gains, runs, SEED)
            out.append({"curve": CURVE_IDS[name], "cutoff": cutoff_name(f), **{k: [float(x) for x in v] for k, v in values.items()}})
    return out


def measure(allow_dirty: bool) -> dict[str, Any]:
    """Run both commands on this checkout; the record."""
    import sappc

    if Path(sappc.__file__).resolve().parents[1] != ROOT / "src":  # e.g. a worktree run with another checkout's editable install
        raise SystemExit(f"published_figures: sappc is imported from {Path(sappc.__file__).parent}, not this checkout's src/: "
                         f"PYTHONPATH={ROOT / 'src'}")
    commit = _commit(allow_dirty)
    record: dict[str, Any] = {
        "measured": {"commit": commit, "date": datetime.date.today().isoformat(), "machine": f"{platform.machine()}, {os.cpu_count()} CPUs",
                     "load_average_1min": round(os.getloadavg()[0], 2), "python": platform.python_version()},
        "slice_runs": list(SLICE_RUNS), "sources": {}}
    with tempfile.TemporaryDirectory() as tmp:
        comparison(1, Path(tmp) / "warm-up")  # the numerical core compiled (or loaded) before the clock starts
        started = time.perf_counter()
        summary = comparison(SEEDS, Path(tmp) / "comparison")
        wall = time.perf_counter() - started
        record["sources"]["flight_comparison"] = {"command": COMMANDS["flight_comparison"], "wall_time_s": round(wall, 1), "table": summary["table"]}
    module = bench_noise_filter()
    base = module.flight_base()
    started = time.perf_counter()
    curves: dict[str, list[dict[str, float]]] = {}
    points = []
    for name, key, gains in module.CURVES:
        rows = []
        for f in module.CUTOFFS_HZ:
            values = module.point_runs(base, key, f, gains, list(range(SEEDS)), SEED)
            rows.append(module.statistics(f, values))
            points.append({"curve": CURVE_IDS[name], "cutoff": cutoff_name(f), **{k: [float(v[i]) for i in SLICE_RUNS] for k, v in values.items()}})
        curves[CURVE_IDS[name]] = rows
    record["sources"]["noise_filter_sweep"] = {"command": COMMANDS["noise_filter_sweep"], "wall_time_s": round(time.perf_counter() - started, 1),
                                               "curves": curves, "slice": points}
    return record


def load() -> dict[str, Any]:
    data: dict[str, Any] = json.loads(RECORD.read_text())
    return data


# ---- the figures a page may quote -------------------------------------------------------------------


def figures(record: dict[str, Any]) -> dict[str, Any]:
    """Every key a page may quote (``<!-- figure: KEY FORMAT -->``):

    - ``flight.commit``, ``flight.wall_time_s``; ``flight.<controller>.<column>`` for each
      controller and column of ``compare-controllers`` (``flight.sappc.steady_max_abs_qev_p95``);
      ``flight.sappc.p95_margin_pct``, SAPPC's p95 below the 4e-5 bound [%];
    - ``sweep.commit``; ``sweep.<curve>.<cut-off>.<statistic>`` (``sweep.torque_flight.1.07.sign_median``;
      curves ``torque_flight``, ``rate_flight``, ``torque_exp1``; statistics of
      ``bench_noise_filter.statistics``); ``sweep.torque_flight.p95_excess_pct``, the most the p95
      of a cut-off of 0.75 Hz or more exceeds the filter off's [%].
    """
    flight = record["sources"]["flight_comparison"]
    out: dict[str, Any] = {"flight.commit": record["measured"]["commit"], "flight.wall_time_s": flight["wall_time_s"],
                           "sweep.commit": record["measured"]["commit"]}
    for kind, row in flight["table"].items():
        out.update({f"flight.{kind}.{k}": v for k, v in row.items()})
    out["flight.sappc.p95_margin_pct"] = 100.0 * (P95_BOUND - flight["table"]["sappc"]["steady_max_abs_qev_p95"]) / P95_BOUND
    curves = record["sources"]["noise_filter_sweep"]["curves"]
    for curve, rows in curves.items():
        for r in rows:
            out.update({f"sweep.{curve}.{cutoff_name(r['cutoff_hz'])}.{k}": v for k, v in r.items() if k != "cutoff_hz"})
    off = curves["torque_flight"][0]["qev_p95"]
    out["sweep.torque_flight.p95_excess_pct"] = max(100.0 * (r["qev_p95"] / off - 1.0) for r in curves["torque_flight"] if r["cutoff_hz"] >= 0.75)
    return out


def number(value: float, fmt: str) -> str:
    """``value`` in ``fmt``, an exponent without its padding: ``3.99e-5``, not ``3.99e-05``."""
    return re.sub(r"e([-+])0*(\d)", lambda m: "e" + ("-" if m.group(1) == "-" else "") + m.group(2), format(value, fmt))


def _controller_table(record: dict[str, Any]) -> str:
    """docs/how-to/wheels-and-sensors.md: the table ``compare-controllers`` prints (``comparison.md``)."""
    from sappc.montecarlo.comparison import COLUMNS

    table = record["sources"]["flight_comparison"]["table"]
    columns = [c for c in COLUMNS if c.key in next(iter(table.values()))]
    head = ["controller"] + [f"{c.label} [{c.unit}]" if c.unit else c.label for c in columns]
    lines = ["| " + " | ".join(h.replace("abs q_ev", "\\|q_ev\\|") for h in head) + " |", "|" + "|".join([" --- "] + [" ---: "] * len(columns)) + "|"]
    for kind, row in table.items():
        lines.append("| " + " | ".join([kind] + [_cell(row[c.key], c.fmt) for c in columns]) + " |")
    return "\n".join(lines)


def _cell(value: float | None, fmt: str) -> str:
    """A cell as ``comparison.md`` writes it."""
    if value is None:
        return "-"
    if value != value or value in (float("inf"), float("-inf")):
        return "never" if value > 0 else "-"
    return format(value, fmt)


def _readme_table(record: dict[str, Any]) -> str:
    """README.md's flight table: the comparison in short."""
    lines = ["| controller | steady max \\|q_ev\\| median / p95 | settling (max) | overshoot | torque sign changes/s (median) | peak wheel speed | wheel energy |",
             "| --- | --- | --- | --- | --- | --- | --- |"]
    for kind, r in record["sources"]["flight_comparison"]["table"].items():
        settling = r["settling_time_s_max"]
        overshoot = r["overshoot_max"]
        lines.append(f"| {DISPLAY.get(kind, kind)} | {number(r['steady_max_abs_qev_median'], '.2e')} / {number(r['steady_max_abs_qev_p95'], '.2e')} | "
                     + ("never" if settling == float("inf") else f"{settling:.1f} s") + " | "
                     + ("0" if overshoot == 0 else number(overshoot, ".1e")) + f" | {r['torque_sign_changes_per_s_median']:.1f} | "
                     f"{r['max_abs_wheel_speed_rad_s_median']:.1f} rad/s | {r['wheel_energy_J_median']:.1f} J |")
    return "\n".join(lines)


def _result_table(record: dict[str, Any]) -> str:
    """docs/design/noise.md, "The result": SAPPC's row against issue 34's requirements."""
    r = record["sources"]["flight_comparison"]["table"]["sappc"]
    settling, overshoot = r["settling_time_s_max"], r["overshoot_max"]
    return "\n".join([
        "| | required | measured |", "| --- | --- | --- |",
        f"| steady max \\|q_ev\\|, p95 | <= 4e-5 | {number(r['steady_max_abs_qev_p95'], '.3e')} |",
        f"| steady max \\|q_ev\\|, median | <= 3.7e-5 | {number(r['steady_max_abs_qev_median'], '.3e')} |",
        f"| torque sign changes per second, median | <= 10 | {r['torque_sign_changes_per_s_median']:.1f} |",
        f"| settling time | <= 25 s | {settling:.2f} s " + ("(every run)" if settling == r["settling_time_s_median"] else "(the latest run)") + " |",
        "| overshoot | none | " + ("0 (every run)" if overshoot == 0 else f"{number(overshoot, '.1e')} at most") + " |"])


def _sweep_table(record: dict[str, Any]) -> str:
    """docs/design/noise.md, "Measured: which filter, which cut-off": the three curves side by side
    (median / p95 of the steady max |q_ev|, median sign changes; a non-zero overshoot in brackets);
    the flight scenario's cut-off in bold."""
    curves = record["sources"]["noise_filter_sweep"]["curves"]
    lines = ["| cut-off [Hz] | torque filter, flight gains: steady max \\|q_ev\\| median / p95, sign changes/s | rate filter, flight gains | "
             "torque filter, experiment 1 gains |", "| ---: | --- | --- | --- |"]
    for i, first in enumerate(curves["torque_flight"]):
        cells = []
        for curve in ("torque_flight", "rate_flight", "torque_exp1"):
            r = curves[curve][i]
            cell = f"{number(r['qev_median'], '.3e')} / {number(r['qev_p95'], '.3e')}, {r['sign_median']:.1f}"
            cells.append(cell + (f" (overshoot {number(r['overshoot_max'], '.1e')})" if r["overshoot_max"] > 0 else ""))
        name = cutoff_name(first["cutoff_hz"])
        if name == "1.07":  # the flight scenario's cut-off (1.069 Hz, its study's)
            name, cells[0] = f"**{name}**", f"**{cells[0]}**"
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


#: The block regions' writers.
RENDERERS: dict[str, Callable[[dict[str, Any]], str]] = {
    "flight-comparison": _controller_table,
    "flight-comparison-readme": _readme_table,
    "flight-comparison-result": _result_table,
    "noise-filter-sweep": _sweep_table,
}


def render(text: str, record: dict[str, Any], where: str = "page") -> str:
    """``text`` with every region written from ``record``.

    Raises
    ------
    FigureError
        Naming ``where`` and the unknown region or key.
    """
    values = figures(record)

    def block(m: re.Match[str]) -> str:
        name = m.group("name")
        if name not in RENDERERS:
            raise FigureError(f"{where}: no region {name!r} (known: {', '.join(RENDERERS)})")
        return f"<!-- figures: {name} -->\n{RENDERERS[name](record)}\n<!-- /figures -->"

    def inline(m: re.Match[str]) -> str:
        key, fmt = m.group("key"), m.group("fmt")
        if key not in values:
            raise FigureError(f"{where}: no figure {key!r} in {RECORD.name}")
        value = values[key]
        shown = f"`{value}`" if isinstance(value, str) else number(value, fmt or "g")
        return f"<!-- figure: {key}{' ' + fmt if fmt else ''} -->{shown}"

    return INLINE.sub(inline, BLOCK.sub(block, text))


def stale_pages(record: dict[str, Any]) -> list[Path]:
    """The pages whose regions differ from what ``record`` gives."""
    return [p for p in PAGES if render(text := p.read_text(encoding="utf-8"), record, str(p.relative_to(ROOT))) != text]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    mode = ap.add_mutually_exclusive_group(required=True)
    mode.add_argument("--measure", action="store_true", help="run both commands and rewrite the record (about 1.5 min)")
    mode.add_argument("--write", action="store_true", help="rewrite the pages' regions from the record")
    mode.add_argument("--check", action="store_true", help="exit 1 if a page's regions are not what the record gives")
    ap.add_argument("--allow-dirty", action="store_true", help="with --measure: measure a tree whose src/ or config/ differ from HEAD")
    args = ap.parse_args(argv)
    if args.measure:
        record = measure(args.allow_dirty)
        RECORD.write_text(json.dumps(record, indent=1) + "\n")
        print(f"wrote {RECORD.relative_to(ROOT)} (commit {record['measured']['commit']})")
        return 0
    record = load()
    stale = stale_pages(record)
    if args.check:
        for p in stale:
            print(f"{p.relative_to(ROOT)}: its published figures are not the record's: python benchmarks/published_figures.py --write")
        return 1 if stale else 0
    for p in stale:
        p.write_text(render(p.read_text(encoding="utf-8"), record, str(p.relative_to(ROOT))), encoding="utf-8")
        print(f"wrote {p.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

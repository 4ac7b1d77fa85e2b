"""``docs/mutation.md``, generated: the mutation scores per module and every surviving mutant with
why it survives, from the measured results and the classification of the survivors.

Inputs (both committed):

* ``benchmarks/results_mutation.json``: what ``benchmarks/bench_mutation.py --results`` measured,
  one entry per module as last measured (counts, scope, tests, every survivor with its id and
  diff, and how it was measured: date, commit, command, machine, wall time);
* ``benchmarks/mutation_survivors.yaml``: per module, each survivor's id with its class and the
  reason it survives (a reason may name a shared one of ``reasons:`` as ``@name``).

Usage::

    python benchmarks/mutation_table.py            # print the page
    python benchmarks/mutation_table.py --write    # write docs/mutation.md
    python benchmarks/mutation_table.py --check    # exit 1 if docs/mutation.md is not what the inputs give
    python benchmarks/mutation_table.py --stubs    # YAML entries for the survivors not yet classified

The page is refused (exit 2, naming them) while a survivor is not classified, a classification
names a mutant the results do not hold, or a class is not one of :data:`CLASSES`.
``tests/test_mutation_doc.py`` checks that the committed page is what this script writes.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import yaml

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results_mutation.json"
SURVIVORS = ROOT / "benchmarks" / "mutation_survivors.yaml"
PAGE = ROOT / "docs" / "mutation.md"
#: The score every module must reach (issue 25, section 3).
TARGET = 0.90

#: The classes of a surviving mutant, and what each means.
CLASSES = {
    "equivalent": "nothing the program computes, writes, publishes or returns changes, for any input it can get (why, for each)",
    "performance": "only time, memory or other resources change, within the documented bounds (a budget, a buffer, a chunk size); "
                   "the results are the same",
    "defensive": "the mutated code acts only on a failure path the tests do not create (explained); a normal run is the same",
    "gap": "a behaviour changes and no test notices: a real gap, open (with the test that would close it)",
}


class TableError(Exception):
    """The inputs do not make a page (an unclassified survivor, a stale classification, ...)."""


def _mutant_text(survivor: dict[str, Any]) -> str:
    """The mutated line as it reads after the mutation (the first ``+`` line of the diff)."""
    plus = [d[1:] for d in survivor["diff"] if d.startswith("+")]
    return " ".join(plus[0].split()) if plus else "(no diff)"


def _cell(text: str, limit: int = 110) -> str:
    text = text if len(text) <= limit else text[: limit - 3] + "..."
    return text.replace("|", "\\|")


def load(results_path: Path = RESULTS, survivors_path: Path = SURVIVORS) -> tuple[dict[str, Any], dict[str, Any]]:
    results = json.loads(results_path.read_text())
    classified = yaml.safe_load(survivors_path.read_text()) or {}
    return results, classified


def classify(results: dict[str, Any], classified: dict[str, Any]) -> dict[str, list[dict[str, Any]]]:
    """Each module's survivors with their class and reason; :class:`TableError` naming every problem."""
    reasons: dict[str, str] = classified.get("reasons") or {}
    problems: list[str] = []
    out: dict[str, list[dict[str, Any]]] = {}
    for name, module in results["modules"].items():
        entries = {str(e["id"]): e for e in (classified.get(name) or [])}
        used: set[str] = set()
        rows = []
        for s in module.get("survivors", []):
            # the same change of the same text in two places has one id: one entry classifies both
            e = entries.get(s["id"])
            used.add(s["id"])
            if e is None:
                problems.append(f"{name}: survivor {s['id']} (line {s['line']}, {s['operator']}: {_mutant_text(s)}) is not classified")
                continue
            cls, reason = e.get("class"), str(e.get("reason") or "")
            if cls not in CLASSES:
                problems.append(f"{name}: {s['id']}: class {cls!r} is not one of {', '.join(CLASSES)}")
            if reason.startswith("@"):
                if reason[1:] not in reasons:
                    problems.append(f"{name}: {s['id']}: no shared reason {reason!r}")
                reason = reasons.get(reason[1:], reason)
            if not reason.strip():
                problems.append(f"{name}: {s['id']}: no reason given")
            if "mutant" in e and " ".join(str(e["mutant"]).split()) != _mutant_text(s):
                problems.append(f"{name}: {s['id']}: the mutant noted ({e['mutant']!r}) is not the measured one ({_mutant_text(s)!r})")
            rows.append({**s, "class": cls, "reason": " ".join(reason.split())})
        problems += [f"{name}: classification {i} names no surviving mutant of the results" for i in entries if i not in used]
        out[name] = rows
    problems += [f"{m}: classified, but not in the results" for m in classified if m != "reasons" and m not in results["modules"]]
    if problems:
        raise TableError("\n".join(problems))
    return out


def stubs(results: dict[str, Any], classified: dict[str, Any]) -> str:
    """YAML entries (class and reason to fill in) for the survivors not yet classified."""
    lines = []
    for name, module in results["modules"].items():
        known = {str(e["id"]) for e in (classified.get(name) or [])}
        todo = [s for s in module.get("survivors", []) if s["id"] not in known]
        if todo:
            lines.append(f"{name}:")
            for s in todo:
                lines += [f"  - id: {s['id']}  # line {s['line']}, {s['operator']}", f"    mutant: {json.dumps(_mutant_text(s))}",
                          "    class: ", "    reason: "]
    return "\n".join(lines) + ("\n" if lines else "")


def targets() -> list[str]:
    """The modules ``benchmarks/bench_mutation.py`` mutates (its ``TARGETS``), in its order."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("_bench_mutation_targets", ROOT / "benchmarks" / "bench_mutation.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look their module up
    spec.loader.exec_module(module)
    return list(module.TARGETS)


def _pct(x: float | None) -> str:
    return "-" if x is None else f"{100 * x:.1f} %"


def _minutes(s: float) -> str:
    return f"{int(s // 60)} min {int(round(s % 60)):02d} s" if s >= 60 else f"{s:.0f} s"


def _less(counts: dict[str, Any], by_class: dict[str, int]) -> float | None:
    """(killed + timeout) over the mutants that are not equivalent or performance ones: how many
    of the mutants that change a behaviour the tests notice."""
    n = counts["total"] - by_class["equivalent"] - by_class["performance"]
    return (counts["killed"] + counts["timeout"]) / n if n else None


def render(results: dict[str, Any], classified: dict[str, Any]) -> str:
    """The page (Markdown)."""
    rows = classify(results, classified)
    modules = results["modules"]
    out = [
        "# Mutation testing",
        "",
        "<!-- Generated by `python benchmarks/mutation_table.py --write` from benchmarks/results_mutation.json and",
        "     benchmarks/mutation_survivors.yaml: edit those, not this page (tests/test_mutation_doc.py checks it). -->",
        "",
        "How strong the tests are, measured: faults injected one at a time into the code (a mutant), the",
        "module's tests run against each; a mutant the tests do not notice survives. The score is",
        "(killed + timeout) / mutants, the target 90 % per module (issue 25). Every surviving mutant is",
        "listed below with its class and why it survives; the last column leaves out the equivalent and",
        "performance mutants, which no test can notice by what the program does.",
        "",
        "The tool, what is mutated and how the tests run: the docstring of `benchmarks/bench_mutation.py`",
        "(cosmic-ray 8.7.0, the `mutation` extra; the JIT off; per module a `quick` then a `more` stage of",
        "tests, never the `slow` ones; docstrings, imports, log calls, f-strings and annotations are out of",
        "scope everywhere). To measure modules and update this page:",
        "",
        "```",
        ".venv/bin/pip install -e '.[mutation]'",
        ".venv/bin/python benchmarks/bench_mutation.py --modules MODULE[,MODULE...] --jobs 2 --results benchmarks/results_mutation.json > /dev/null",
        ".venv/bin/python benchmarks/mutation_table.py --stubs     # classify each new survivor in benchmarks/mutation_survivors.yaml",
        ".venv/bin/python benchmarks/mutation_table.py --write",
        "```",
        "",
        "## Scores",
        "",
        "| module | scope | mutants | killed | timeout | survived | error | score | survivors: equivalent, performance, defensive, gap "
        "| score less equivalent and performance |",
        "|---|---|---:|---:|---:|---:|---:|---:|---|---:|",
    ]
    tot = {k: 0 for k in ("total", "killed", "timeout", "survived", "error")}
    by_class_all = {c: 0 for c in CLASSES}
    below = []
    for name, m in modules.items():
        by_class = {c: sum(r["class"] == c for r in rows[name]) for c in CLASSES}
        for c in CLASSES:
            by_class_all[c] += by_class[c]
        for k in tot:
            tot[k] += m[k]
        score = m["score"]
        if score is None or score < TARGET:
            below.append(name)
        mark = "" if score is not None and score >= TARGET else " (below 90 %)"
        out.append(f"| `{name}` | {m['scope']} | {m['total']} | {m['killed']} | {m['timeout']} | {m['survived']} | {m['error']} | "
                   f"**{_pct(score)}**{mark} | {', '.join(str(by_class[c]) for c in CLASSES)} | {_pct(_less(m, by_class))} |")
    overall = (tot["killed"] + tot["timeout"]) / tot["total"] if tot["total"] else None
    out.append(f"| **all** | | **{tot['total']}** | **{tot['killed']}** | **{tot['timeout']}** | **{tot['survived']}** | **{tot['error']}** | "
               f"**{_pct(overall)}** | {', '.join(str(by_class_all[c]) for c in CLASSES)} | {_pct(_less(tot, by_class_all))} |")
    out.append("")
    if below:
        out.append("Below the 90 % target: " + ", ".join(f"`{n}`" for n in below) + " (their survivors below say why).")
    else:
        out.append("Every module measured reaches the 90 % target.")
    missing = [n for n in targets() if n not in modules]
    if missing:
        out += ["", "Not measured in these results (no score is claimed for them): " + ", ".join(f"`{n}`" for n in missing) + "."]
    out += ["", "Classes of a surviving mutant:", ""]
    out += [f"- **{c}**: {text}." for c, text in CLASSES.items()]
    out += ["", "## How each module was measured", "",
            "| module | date | commit | tests (`quick`; `more`) | unmutated tests | wall time | machine, jobs |",
            "|---|---|---|---|---:|---:|---|"]
    for name, m in modules.items():
        meas = m["measured"]
        commit = f"`{meas['commit']}`" + ("" if meas.get("tree_clean", True) else " (with changes not committed)")
        mach = meas["machine"]
        tests = "; ".join(", ".join(f"`{t}`" for t in m["tests"][stage]) or "-" for stage in ("quick", "more"))
        out.append(f"| `{name}` | {meas['date']} | {commit} | {tests} | {m['tests_unmutated_s']:.1f} s | {_minutes(m['wall_s'])} | "
                   f"{mach['platform']}, Python {mach['python']}, {mach['cpu_count']} CPUs, `--jobs {mach['jobs']}` |")
    commands = sorted({m["measured"]["command"] for m in modules.values()})
    out += ["", "Commands (`--results` and `--keep` left out: they say only where the results go):", ""]
    out += [f"- `{c}`" for c in commands]
    out += ["", "## Surviving mutants", ""]
    for name, m in modules.items():
        rs = rows[name]
        if not rs:
            out += [f"### `{name}`", "", "None: every mutant was killed.", ""]
            continue
        out += [f"### `{name}`", "", f"`{m['path']}`, {len(rs)} survivor{'s' if len(rs) != 1 else ''}.", "",
                "| line | mutant | class | why it survives |", "|---:|---|---|---|"]
        for r in sorted(rs, key=lambda r: (r["line"], r["operator"], r["occurrence"])):
            out.append(f"| {r['line']} | `{_cell(_mutant_text(r))}` | {r['class']} | {_cell(r['reason'], 10_000)} |")
        out.append("")
    return "\n".join(out).rstrip() + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--write", action="store_true", help=f"write {PAGE.relative_to(ROOT)}")
    ap.add_argument("--check", action="store_true", help=f"exit 1 unless {PAGE.relative_to(ROOT)} is what the inputs give")
    ap.add_argument("--stubs", action="store_true", help="print YAML entries for the survivors not yet classified")
    ap.add_argument("--results", type=Path, default=RESULTS)
    ap.add_argument("--survivors", type=Path, default=SURVIVORS)
    args = ap.parse_args(argv)
    results, classified = load(args.results, args.survivors)
    if args.stubs:
        sys.stdout.write(stubs(results, classified))
        return 0
    try:
        page = render(results, classified)
    except TableError as exc:
        print(f"mutation_table: {exc}", file=sys.stderr)
        return 2
    if args.check:
        if not PAGE.exists() or PAGE.read_text() != page:
            print(f"mutation_table: {PAGE.relative_to(ROOT)} is not what the results give; run: python benchmarks/mutation_table.py --write",
                  file=sys.stderr)
            return 1
        return 0
    if args.write:
        PAGE.write_text(page)
        print(f"wrote {PAGE.relative_to(ROOT)}", file=sys.stderr)
        return 0
    sys.stdout.write(page)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Issue 46, item 3: what the small bad YAML files cost each command that reads YAML, and what the
loader's limits cost a good file.

    python benchmarks/bench_yaml_limits.py [--repeats 3] [--json FILE]     # targets: < 1 s, < 300 MB, one line < 300 chars

Prints one JSON document:

* ``commands``: for each command of ``tests/bad_yaml.py``'s ``COMMANDS`` and each file of its
  ``LIMIT`` (run in the files' directory, by bare name): the exit status, the lines and characters
  on stderr, the wall time and the CPU time [s] (medians of ``--repeats`` fresh processes:
  interpreter start, imports, the refusal; on a loaded machine the wall time is the CPU time
  plus the wait for a CPU) and the peak resident memory [MB] (the largest of the repeats, from
  ``RUSAGE_CHILDREN`` of a wrapper process that starts the command alone);
* ``reference``: the same measures of ``sappc params paper_tracking``, a command on a good file
  (what the start and the imports cost by themselves);
* ``loader``: in this process, the refusal of each file by ``safe_load_yaml`` [ms] (fastest and
  median of 50), and the largest bundled scenario loaded by ``safe_load_yaml`` and by
  ``yaml.load(..., CSafeLoader)`` alone [ms] (fastest and median of 200, the two interleaved):
  the limits' cost on every good file.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT / "tests"))

import yaml  # noqa: E402

from bad_yaml import COMMANDS, LIMIT, MEASURE, bad_yaml_texts, command_args, write_bad_yaml  # noqa: E402
from gnc_common.validation import ConfigError, safe_load_yaml  # noqa: E402

SAPPC = [sys.executable, "-m", "sappc"]


def _measured(args: list[str], cwd: Path) -> dict[str, float | int]:
    rss_file = cwd / ".peak_rss_kib"
    start = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", MEASURE, str(rss_file), *SAPPC, *args], cwd=cwd, capture_output=True, text=True,
                          timeout=600)
    wall = time.perf_counter() - start
    peak_kib, cpu_s = rss_file.read_text().split()
    return {"exit": proc.returncode, "stderr_lines": proc.stderr.count("\n"), "stderr_chars": len(proc.stderr.rstrip("\n")),
            "wall_s": wall, "cpu_s": float(cpu_s), "peak_rss_mb": int(peak_kib) * 1024 / 1e6}


def _summary(runs: list[dict[str, float | int]]) -> dict[str, float | int]:
    out = dict(runs[0])
    out["wall_s"] = round(statistics.median(r["wall_s"] for r in runs), 3)
    out["cpu_s"] = round(statistics.median(r["cpu_s"] for r in runs), 3)
    out["peak_rss_mb"] = round(max(r["peak_rss_mb"] for r in runs), 1)
    return out


def _ms(f, n: int) -> dict[str, float]:  # type: ignore[no-untyped-def]
    """The fastest and the median of ``n`` calls of ``f`` [ms] (the fastest: the least disturbed by a loaded machine)."""
    times = []
    for _ in range(n):
        t0 = time.perf_counter()
        f()
        times.append(time.perf_counter() - t0)
    return {"min": round(min(times) * 1e3, 3), "median": round(statistics.median(times) * 1e3, 3)}


def _interleaved(calls: dict[str, object], n: int) -> dict[str, dict[str, float]]:
    """:func:`_ms` of each call, the calls taking turns (a change of load hits them alike)."""
    times: dict[str, list[float]] = {k: [] for k in calls}
    for _ in range(n):
        for k, f in calls.items():
            t0 = time.perf_counter()
            f()  # type: ignore[operator]
            times[k].append(time.perf_counter() - t0)
    return {k: {"min": round(min(t) * 1e3, 3), "median": round(statistics.median(t) * 1e3, 3)} for k, t in times.items()}


def _refuse(text: str) -> None:
    try:
        safe_load_yaml(text, source="f.yaml")
    except ConfigError:
        return
    raise AssertionError("a bad file was read")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=3, help="fresh processes per command and file (default 3)")
    ap.add_argument("--json", metavar="FILE", help="also write the document to FILE")
    args = ap.parse_args()

    biggest = max((ROOT / "config" / "scenarios").glob("*.yaml"), key=lambda p: p.stat().st_size)
    good = biggest.read_text()
    loader = {
        "refusal_ms": {name: _ms(lambda t=text: _refuse(t), 50) for name, text in bad_yaml_texts().items()},
        "good_file": f"{biggest.name} ({len(good):,} characters)",
        **_interleaved({"good_safe_load_yaml_ms": lambda: safe_load_yaml(good),
                        "good_csafeloader_alone_ms": lambda: yaml.load(good, Loader=yaml.CSafeLoader)}, 200),
    }
    with tempfile.TemporaryDirectory(prefix="sappc-bench-yaml-") as tmp:
        where = Path(tmp)
        write_bad_yaml(where)
        commands = {command: {name: _summary([_measured(command_args(command, name), where) for _ in range(args.repeats)])
                              for name in sorted(LIMIT)}
                    for command in COMMANDS}
        reference = _summary([_measured(["params", "paper_tracking"], where) for _ in range(args.repeats)])
    doc = {
        "machine": {"node": platform.node(), "cpus": os.cpu_count(), "python": platform.python_version(),
                    "load_average": [round(x, 2) for x in os.getloadavg()], "date": time.strftime("%Y-%m-%d")},
        "repeats": args.repeats,
        "loader": loader,
        "reference": {"params paper_tracking": reference},
        "commands": commands,
        "worst": {"wall_s": max(r["wall_s"] for c in commands.values() for r in c.values()),
                  "cpu_s": max(r["cpu_s"] for c in commands.values() for r in c.values()),
                  "peak_rss_mb": max(r["peak_rss_mb"] for c in commands.values() for r in c.values()),
                  "stderr_chars": max(r["stderr_chars"] for c in commands.values() for r in c.values()),
                  "every_exit_2_one_line": all(r["exit"] == 2 and r["stderr_lines"] == 1 for c in commands.values() for r in c.values())},
    }
    text = json.dumps(doc, indent=2)
    print(text)
    if args.json:
        Path(args.json).write_text(text + "\n")


if __name__ == "__main__":
    main()
